"""Tracking MPC: chance-constraint tightening, Algorithm 1 in the loop, alpha = 0, GP compensation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from gprace.config import load_plant, load_vehicle
from gprace.errors import ConfigError, InputError
from gprace.explore.algorithm import CandidateGrid, select_target, weighted_variance
from gprace.model import NominalModel
from gprace.mpc.tracking import MPCSettings, TrackingMPC, tightening
from gprace.plan import curvature_plan
from gprace.tracks import load_track


def _A(N=20):
    m = NominalModel(load_vehicle("audi_tt_cup"))
    A, _ = m.jacobians(np.array([30.0, 0.3, 0.2, 0.01, 0.5, 0.0]), np.array([0.02, 0.0]), 0.01, 0.05)
    return np.tile(A, (N, 1, 1))


def test_tightening_zero_variance_is_zero():
    gamma, sig = tightening(_A(), np.zeros((20, 2)), 0.6)
    assert np.all(gamma == 0.0) and np.all(sig == 0.0)


def test_tightening_grows_with_variance_and_uses_inverse_erf():
    A = _A()
    g1, s1 = tightening(A, np.full((20, 2), 1e-4), 0.6)
    g2, s2 = tightening(A, np.full((20, 2), 4e-4), 0.6)
    # e_y is not compensated directly: its variance appears from step 2 on, then grows along the horizon
    assert g1[0] == 0.0 and np.all(g2[1:] > g1[1:]) and np.all(np.diff(g1[1:]) > 0)
    assert np.allclose(g2, 2 * g1)  # sigma scales with the square root of the variance
    assert np.allclose(g1, s1 * norm.ppf(0.6))  # the beta-quantile: sqrt(2) erfinv(2 beta - 1)
    g5, _ = tightening(A, np.full((20, 2), 1e-4), 0.5)
    assert np.allclose(g5, 0.0)
    with pytest.raises(ConfigError):
        tightening(A, np.zeros((20, 2)), 1.0)


def test_algorithm1_extremes_with_S():
    Z = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 0.5, 0.02]])
    var = np.array([[1e-3, 1e-3], [2e-3, 1e-3], [1e-2, 1e-3], [1e-3, 5e-3]])
    scale = np.ones(3)
    # S weighting the yaw-rate output strongly: candidate 3 is the most uncertain in the paper's sense
    g = CandidateGrid(Z, weighted_variance(var, np.array([1.0, 100.0])), scale)
    assert select_target(g, np.array([0.09, 0.0, 0.0]), 0.0) == 1  # nearest
    assert select_target(g, np.array([0.09, 0.0, 0.0]), 1.0) == 3  # highest S-weighted variance
    g_plain = CandidateGrid(Z, weighted_variance(var, np.array([1.0, 0.0])), scale)
    assert select_target(g_plain, np.array([0.09, 0.0, 0.0]), 1.0) == 2


@pytest.fixture(scope="module")
def circle():
    tr = load_track("circle_100")
    m = NominalModel(load_vehicle("audi_tt_cup"))
    return tr, m, curvature_plan(tr, m)


def _gp(center=(0.0, 0.0, 0.0)):
    gpmod = pytest.importorskip("gprace.gp")
    rng = np.random.default_rng(0)
    Z = rng.normal(center, [0.5, 0.2, 0.03], (200, 3))
    Y = np.column_stack([0.01 * np.sin(Z[:, 0]), 0.005 * Z[:, 1]]) + rng.normal(0, 1e-3, (200, 2))
    gp = gpmod.make_gp("exact", optimize=False, length_scale=1.0, noise=1e-2).fit(Z, Y)
    return gp, Z


def _drive_inputs(tr, m, plan, steps, **kw):
    from gprace.plants import make_plant
    from gprace.timetrial.drive import start_state

    mpc = TrackingMPC(m, tr, plan, MPCSettings(), **kw)
    x0, u0 = start_state(plan, tr, m.vehicle)
    plant = make_plant(load_plant("audi_hidden"), tr, 0.05)
    y = plant.reset(x0, u0)
    mpc.reset(u0[0])
    us = []
    for _ in range(steps):
        u, info = mpc.step(y)
        us.append(u)
        y = plant.step(u)
    return np.array(us), mpc


def test_alpha_zero_reproduces_plain_tracking(circle):
    from gprace.timetrial.iterate import make_grid

    tr, m, plan = circle
    gp, Z = _gp((float(plan.v_y.mean()), float(plan.yaw_rate.mean()), float(plan.delta.mean())))
    pred = lambda q: gp.predict(q)  # noqa: E731
    grid = make_grid(gp, Z, MPCSettings(), 5)
    u_plain, _ = _drive_inputs(tr, m, plan, 40, gp=pred)
    u_zero, _ = _drive_inputs(tr, m, plan, 40, gp=pred, grid=grid, alpha=0.0)
    assert np.array_equal(u_plain, u_zero)
    u_expl, mpc = _drive_inputs(tr, m, plan, 40, gp=pred, grid=grid, alpha=0.857)
    assert mpc.last_target is not None and not np.array_equal(u_plain, u_expl)


def test_bad_alpha_and_missing_grid(circle):
    tr, m, plan = circle
    with pytest.raises(ConfigError, match=r"\[0, 1\]"):
        TrackingMPC(m, tr, plan, alpha=1.2)
    with pytest.raises(ConfigError, match="grid"):
        TrackingMPC(m, tr, plan, alpha=0.5)


def test_infeasible_start(circle):
    from dataclasses import replace

    from gprace.timetrial.drive import drive

    tr, m, plan = circle
    bad = replace(plan, e_y=plan.e_y + 20.0)
    with pytest.raises(InputError, match="infeasible start"):
        drive(bad, load_plant("audi_nominal"), tr, m)


def test_model_trained_on_other_features(tmp_path):
    gpmod = pytest.importorskip("gprace.gp")
    from gprace.timetrial.learning import load_predictor

    gp, _ = _gp()
    gpmod.save_model(tmp_path / "g.h5", gp, {"feature_map": "tracking", "input_names": ["v_x", "e_y", "delta"],
                                             "output_names": ["a", "b"]})
    with pytest.raises(InputError, match="inputs"):
        load_predictor(tmp_path / "g.h5", "tracking")
    gpmod.save_model(tmp_path / "h.h5", gp, {"feature_map": "planning", "input_names": ["v_y", "yaw_rate", "delta"],
                                             "output_names": ["a", "b"]})
    with pytest.raises(InputError, match="feature map"):
        load_predictor(tmp_path / "h.h5", "tracking")


def test_gp_compensated_model_predicts_plant_better():
    """Train the tracking GP on one weaving run of the hidden-effects plant, test on another."""
    pytest.importorskip("gprace.gp")
    from gprace.config import SimulateConfig
    from gprace.sim import simulate
    from gprace.timetrial import learning as L

    tr = load_track("circle_100")
    m = NominalModel(load_vehicle("audi_tt_cup"))
    plant = load_plant("audi_hidden")
    train = simulate(plant, tr, SimulateConfig(laps=0.6, speed_scale=0.85, weave_amplitude=0.7, weave_wavelength=60.0, seed=1))
    test = simulate(plant, tr, SimulateConfig(laps=0.4, speed_scale=0.8, weave_amplitude=0.5, weave_wavelength=80.0, seed=2))
    Z, Y = L.features(train, m, tr, "tracking")
    Zt, Yt = L.features(test, m, tr, "tracking")
    gp = L.fit_hyper(Z, Y, max_fit_points=200)
    mean, var = gp.predict(Zt)
    err_gp = np.sqrt(np.mean((Yt - mean) ** 2, axis=0))
    err_nom = np.sqrt(np.mean(Yt**2, axis=0))  # the nominal step predicts zero error
    assert np.all(err_gp < 0.7 * err_nom)


def test_failed_solve_falls_back_to_shifted_solution(circle):
    from gprace.mpc.qp import QPStatus, fail_result
    from gprace.timetrial.drive import start_state

    tr, m, plan = circle
    mpc = TrackingMPC(m, tr, plan, MPCSettings())
    x0, u0 = start_state(plan, tr, m.vehicle)
    mpc.reset(u0[0])
    mpc.step(x0)
    expected = mpc.prev_u[1].copy()

    class Broken:
        def solve(self, pb):
            return fail_result(pb.N, QPStatus.FAILED, "injected")

    mpc.qp = Broken()
    u, info = mpc.step(x0)
    assert info["fallback"] and mpc.fallbacks == 1
    assert np.array_equal(u, np.clip(expected, mpc.u_lo, mpc.u_hi))


def test_the_weave_damping_slows_the_first_steering_step(circle):
    """``steer_damping`` (set by the stability envelope on a weave) solves with the steering-rate
    weight times that factor: from a car off its line the first steering step is smaller (at 1 the
    MPC's own ``qp`` is used: test_failed_solve_falls_back_to_shifted_solution swaps it) (issue 37,
    stop 56)."""
    from gprace.model.dynamics import State
    from gprace.timetrial.drive import start_state

    tr, m, plan = circle
    x0, u0 = start_state(plan, tr, m.vehicle)
    x0 = x0.copy()
    x0[State.E_Y] += 0.8   # off the line: the MPC steers back
    steps = {}
    for f in (1.0, 3.0):
        mpc = TrackingMPC(m, tr, plan, MPCSettings())
        mpc.reset(u0[0])
        mpc.steer_damping = f
        u, info = mpc.step(x0)
        assert not info["fallback"]
        steps[f] = abs(float(u[0] - u0[0]))
    assert 0.0 < steps[3.0] < 0.8 * steps[1.0], steps


def test_linearisation_matches_the_step_and_its_finite_differences(circle):
    """The buffered, compiled linearisation returns per step ``x_next`` = the model's RK4 step
    with the affine curvature, and ``A_k``, ``B_k`` = its central differences (layout check)."""
    tr, m, plan = circle
    mpc = TrackingMPC(m, tr, plan, MPCSettings())
    rng = np.random.default_rng(1)
    N = mpc.N
    X = np.column_stack([rng.uniform(20, 40, N), rng.normal(0, 0.3, N), rng.normal(0, 0.2, N),
                         rng.normal(0, 0.05, N), rng.normal(0, 1, N), np.linspace(10, 60, N)])
    U = np.column_stack([rng.normal(0, 0.03, N), rng.normal(0, 3, N)])
    K = np.column_stack([rng.normal(0.01, 0.005, N), rng.normal(0, 1e-4, N), X[:, 5]])
    xn, A, B = mpc._lin(X, U, K)

    def step(k, x, u):
        return m.rk4(x, u, lambda s: K[k, 0] + K[k, 1] * (s - K[k, 2]), mpc.dt)

    h = 1e-6
    for k in (0, 7, N - 1):
        assert np.allclose(xn[k], step(k, X[k], U[k]), atol=1e-10)
        for j in range(6):
            e = np.eye(6)[j] * h
            assert np.allclose(A[k][:, j], (step(k, X[k] + e, U[k]) - step(k, X[k] - e, U[k])) / (2 * h), atol=1e-5)
        for j in range(2):
            e = np.eye(2)[j] * h
            assert np.allclose(B[k][:, j], (step(k, X[k], U[k] + e) - step(k, X[k], U[k] - e)) / (2 * h), atol=1e-5)
