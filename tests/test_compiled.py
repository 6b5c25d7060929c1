"""Compiled NLP solvers: same optimum as the interpreted solver, compiled once, safe fallback."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from gprace.backends import compiled

OPTS = {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes", "tol": 1e-10}}


def rosenbrock(n: int = 4) -> dict:
    """Parametric chained Rosenbrock with a ball constraint: minimum at x = (a, a^2, ...) when a = 1."""
    x = ca.SX.sym("x", n)
    a = ca.SX.sym("a")
    f = sum(100 * (x[i + 1] - x[i] ** 2) ** 2 + (a - x[i]) ** 2 for i in range(n - 1))
    return {"x": x, "p": a, "f": f, "g": ca.sumsqr(x)}


def solve(solver, a: float) -> np.ndarray:
    res = solver(x0=np.zeros(4), p=a, lbg=0, ubg=10.0)
    return np.asarray(res["x"]).ravel()


@pytest.mark.skipif(compiled.compiler() is None, reason="no C compiler")
def test_compiled_solver_matches_interpreted_and_is_built_once(tmp_path, monkeypatch):
    monkeypatch.setenv("GPRACE_CACHE", str(tmp_path))
    nlp = rosenbrock()
    first = compiled.compiled_nlpsol("rb_test", "ipopt", nlp, OPTS)
    libs = sorted(tmp_path.glob("rb_test_*.so"))
    assert len(libs) == 1
    stamp = libs[0].stat().st_mtime_ns
    again = compiled.compiled_nlpsol("rb_test", "ipopt", rosenbrock(), OPTS)
    assert libs[0].stat().st_mtime_ns == stamp  # reused, not rebuilt
    plain = ca.nlpsol("rb_plain", "ipopt", nlp, OPTS)
    for a in (1.0, 0.7):
        ref = solve(plain, a)
        np.testing.assert_allclose(solve(first, a), ref, atol=1e-8)
        np.testing.assert_allclose(solve(again, a), ref, atol=1e-8)
    np.testing.assert_allclose(solve(first, 1.0), np.ones(4), atol=1e-6)  # analytic optimum


def test_failed_build_falls_back_to_the_interpreted_solver(tmp_path, monkeypatch):
    monkeypatch.setenv("GPRACE_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    solver = compiled.compiled_nlpsol("rb_fallback", "ipopt", rosenbrock(), OPTS)
    np.testing.assert_allclose(solve(solver, 1.0), np.ones(4), atol=1e-6)
    assert not list(tmp_path.glob("*.so"))


@pytest.mark.skipif(compiled.compiler() is None, reason="no C compiler")
def test_compiled_function_is_bit_identical_and_falls_back(tmp_path, monkeypatch):
    """The MPC's linearisation (an RK4 step and its Jacobians, mapped over a horizon) compiled to C
    returns exactly what the interpreted function does; without a compiler it is that function."""
    monkeypatch.setenv("GPRACE_CACHE", str(tmp_path))
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    f_c = lambda z: ca.vertcat(z[1], -ca.sin(z[0]) + u)  # noqa: E731
    k1 = f_c(x)
    k2 = f_c(x + 0.05 * k1)
    xn = x + 0.05 * (k1 + k2) / 2
    f = ca.Function("pend_lin", [x, u], [xn, ca.jacobian(xn, x)]).map(7)
    X, U = np.random.default_rng(0).normal(size=(2, 7)), np.linspace(-1, 1, 7)[None, :]
    fast = compiled.compiled_function(f)
    assert fast is not f and len(list(tmp_path.glob("*.so"))) == 1
    for a, b in zip(f(X, U), fast(X, U)):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("GPRACE_CACHE", str(tmp_path / "other"))
    assert compiled.compiled_function(f) is f


@pytest.mark.parametrize("name", ["se", "matern15"])
@pytest.mark.parametrize("M", [1, 37, 600])  # fewer points than one vector block, a remainder, the rollouts' 600
def test_compiled_kernel_product_equals_the_kernel_block_times_weights(name, M, tmp_path, monkeypatch):
    """The rollouts' fused kernel product K(b, a) w agrees with the numpy kernel block times w to
    rounding, for both kernels and any number of points; without a compiler it is that product."""
    from gprace.gp import fastkernel
    from gprace.gp.kernels import kernel

    rng = np.random.default_rng(M)
    b, a = rng.normal(size=(50, 11)), rng.normal(size=(M, 11))
    ls = rng.uniform(0.5, 3.0, 11)
    w = rng.normal(size=(M, 5)) * 1e3  # large weights of nearly noiseless fits
    ref = kernel(name, b, a, ls, 0.7) @ w
    pts = fastkernel.Points(a / ls)
    wT = np.ascontiguousarray(w.T)
    for cc in (None, str(tmp_path / "no-such-compiler")):
        fastkernel._library.cache_clear()
        monkeypatch.setenv("GPRACE_CACHE", str(tmp_path / str(cc is None)))
        if cc:
            monkeypatch.setenv("CC", cc)
        elif compiled.compiler() is None:
            continue
        got = fastkernel.kernel_dot(name, b / ls, pts, wT, 0.7)
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(w).sum())
        assert bool(list((tmp_path / "True").glob("gp_kernel_dot_*.so"))) == (compiled.compiler() is not None)
        # loading it leaves the process's floating point alone: subnormals are not flushed to zero
        assert (np.array([5e-324]) * 1.0)[0] > 0
    fastkernel._library.cache_clear()
