"""The tracking QP: the three solver backends agree, and the unconstrained QP is the LQR solution."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.backends import solvers
from gprace.config import load_vehicle
from gprace.model import NominalModel
from gprace.mpc.qp import LtvProblem, QPStatus, Weights

BACKENDS = ["cvxpy-clarabel", "clarabel", "casadi"]


def _problem(N=20, seed=0, tight=True):
    """An LTV problem from the Audi model linearised along a corner, with active bounds."""
    rng = np.random.default_rng(seed)
    m = NominalModel(load_vehicle("audi_tt_cup"))
    dt = 0.05
    x = np.array([30.0, -0.5, 0.3, 0.02, 0.5, 0.0])
    u = np.array([0.03, 1.0])
    A, B, c = [], [], []
    for k in range(N):
        Ak, Bk = m.jacobians(x, u, 0.01, dt)
        xn = m.euler(x, u, 0.01, dt)
        A.append(Ak)
        B.append(Bk)
        c.append(xn - Ak @ x - Bk @ u + np.r_[0, rng.normal(0, 0.02, 2), 0, 0, 0])
        x = xn
    xref = np.array([[31.0, -0.4, 0.32, 0.0, 1.5, 1.55 * (k + 1)] for k in range(N)])
    uref = np.tile([0.035, 2.0], (N, 1))
    hi = np.full(N, 1.2 if tight else 100.0)
    return LtvProblem(np.array(A), np.array(B), np.array(c), np.array([30.0, -0.5, 0.3, 0.02, 0.5, 0.0]), xref, uref,
                      -hi, hi, np.array([-0.35, -14.0]), np.array([0.35, 1.5 if tight else 100.0]), 0.02, Weights())


@pytest.fixture(scope="module")
def qps():
    """The backends at tight tolerance: the agreement checks test the formulations, not the
    real-time default tolerance of clarabel (1e-8)."""
    from gprace.backends.qp_clarabel import ClarabelQP

    out = {name: solvers.create(name, 20, Weights()) for name in BACKENDS}
    out["clarabel"] = ClarabelQP(20, Weights(), tol=1e-10)
    return out


def test_backends_registered():
    assert set(BACKENDS) <= set(solvers.names())


@pytest.mark.parametrize("seed", [0, 1])
def test_backends_agree(qps, seed):
    pb = _problem(seed=seed)
    res = {n: q.solve(pb) for n, q in qps.items()}
    for n, r in res.items():
        assert r.status is QPStatus.SOLVED, (n, r.message)
    ref = res["clarabel"]
    # bounds are active: a_x at its upper bound, lateral slack used
    assert np.isclose(ref.u[:, 1].max(), 1.5, atol=1e-6)
    assert ref.x[:, 4].max() <= 1.2 + ref.eps.max() + 1e-6
    for n in ("cvxpy-clarabel", "casadi"):
        assert np.allclose(res[n].u, ref.u, atol=2e-5, rtol=1e-5), n
        assert np.allclose(res[n].x, ref.x, atol=2e-4, rtol=1e-5), n
        assert abs(res[n].objective - ref.objective) <= 1e-5 * max(1.0, abs(ref.objective)), n


def test_steering_rate_rows_hold_and_backends_agree(qps):
    """With the actuator's rate limit active, every step's steering change stays within it (the
    first one measured from the last applied angle) and the backends agree; without it the same
    problem moves the wheel faster."""
    from dataclasses import replace

    free = _problem(seed=2)
    d_free = np.diff(np.r_[free.delta_prev, qps["clarabel"].solve(free).u[:, 0]])
    step = 0.25 * np.abs(d_free).max()
    pb = replace(free, steer_step=step)
    res = {n: q.solve(pb) for n, q in qps.items()}
    for n, r in res.items():
        assert r.status is QPStatus.SOLVED, (n, r.message)
        d = np.diff(np.r_[pb.delta_prev, r.u[:, 0]])
        assert np.abs(d).max() <= step + 1e-6, n
        assert np.isclose(np.abs(d).max(), step, atol=1e-6), n  # the limit is active
    for n in ("cvxpy-clarabel", "casadi"):
        assert np.allclose(res[n].u, res["clarabel"].u, atol=2e-5, rtol=1e-5), n


def test_repeated_updates_match_fresh_solver(qps):
    """In-place data updates (clarabel) give the same answer as a solver built for that problem."""
    for seed in (3, 4):
        pb = _problem(seed=seed)
        fresh = type(qps["clarabel"])(20, Weights(), tol=1e-10).solve(pb)
        upd = qps["clarabel"].solve(pb)
        assert np.allclose(fresh.u, upd.u, atol=1e-7)


@pytest.mark.parametrize("name", BACKENDS)
def test_unconstrained_is_lqr(name):
    """No active bounds, no steering-rate term, zero reference: u_0 = -K_0 x_0 of the finite Riccati."""
    N = 15
    m = NominalModel(load_vehicle("audi_tt_cup"))
    A, B = m.jacobians(np.array([25.0, 0.2, 0.1, 0.0, 0.0, 0.0]), np.array([0.01, 0.0]), 0.004, 0.05)
    w = Weights(Q=(1.0, 2.0, 5.0, 50.0, 10.0, 0.3), R=(30.0, 0.05), r_delta=0.0, r_accel=0.0)
    Q, R = np.diag(w.Q), np.diag(w.R)
    x0 = np.array([1.0, 0.3, -0.1, 0.05, 0.8, -0.5])
    pb = LtvProblem(np.tile(A, (N, 1, 1)), np.tile(B, (N, 1, 1)), np.zeros((N, 6)), x0, np.zeros((N, 6)), np.zeros((N, 2)),
                    np.full(N, -1e3), np.full(N, 1e3), np.full(2, -1e3), np.full(2, 1e3), 0.0, w)
    r = solvers.create(name, N, w).solve(pb)
    assert r.status is QPStatus.SOLVED
    P = Q.copy()
    Ks = []
    for _ in range(N):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P = Q + A.T @ P @ (A - B @ K)
        Ks.append(K)
    Ks = Ks[::-1]
    x, us = x0.copy(), []
    for k in range(N):
        uk = -Ks[k] @ x
        us.append(uk)
        x = A @ x + B @ uk
    assert np.allclose(r.u, np.array(us), atol=1e-5, rtol=1e-5)
    assert np.allclose(r.eps, 0.0, atol=1e-6)


@pytest.mark.parametrize("name", BACKENDS)
def test_nonfinite_problem_is_a_failed_solve_and_a_bad_shape_is_raised(qps, name):
    """One status table for every backend (issue 40): a model that blew up (NaN in the dynamics)
    is a counted FAILED solve with the same message everywhere; a problem of the wrong shape is a
    bug in the caller and is raised, not hidden as a failed solve."""
    pb = _problem(seed=2)
    pb.c[5, 1] = np.nan
    r = qps[name].solve(pb)
    assert r.status is QPStatus.FAILED and "non-finite problem data" in r.message
    assert np.all(np.isnan(r.u))
    bad = _problem(seed=2)
    bad.A = bad.A[:, :5, :]  # 5 of 6 state rows
    with pytest.raises((ValueError, IndexError, RuntimeError)):
        qps[name].solve(bad)
    assert qps[name].solve(_problem(seed=2)).status is QPStatus.SOLVED  # the backend is still usable
