"""Opponent rollout fast path (issue 17, item 4): shared-kernel objectives and sparse GP, the
unchecked prediction path, and the rollout against a plain loop over ``GPBackend.predict``."""

from __future__ import annotations

import numpy as np
import pytest
from gp_contract import smooth_data

from gprace.gp import load_model, make_gp, save_model
from gprace.gp.objectives import exact_lml, vfe_bound
from gprace.h2h.geometry import make_track
from gprace.h2h.predictors import FEATURES, LOOKAHEAD, OUT_STATE, OUTPUTS, GPPredictor, features

KERNELS = ["se", "matern15"]


def _fd(f, theta, h=1e-6):
    return np.array([(f(theta + h * e) - f(theta - h * e)) / (2 * h) for e in np.eye(len(theta))])


@pytest.mark.parametrize("name", KERNELS)
def test_shared_objectives_are_sums_over_outputs_with_their_gradients(name):
    Z, Y = smooth_data(n=50)
    Y = Y - Y.mean(axis=0)
    Zu = Z[::3]
    theta = np.array([0.3, -0.2, 0.1, 0.2, np.log(0.05)])
    for f, extra in ((exact_lml, ()), (vfe_bound, (Zu,))):
        value, grad = f(name, theta, Z, Y, *extra)
        singles = [f(name, theta, Z, Y[:, i], *extra) for i in range(Y.shape[1])]
        assert value == pytest.approx(sum(v for v, _ in singles), rel=1e-12)
        np.testing.assert_allclose(grad, sum(g for _, g in singles), rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(grad, _fd(lambda t: f(name, t, Z, Y, *extra)[0], theta), rtol=1e-5, atol=1e-5)


def test_shared_sparse_fit_has_one_kernel_and_equals_exact_at_the_data():
    Z, Y = smooth_data(n=60)
    fixed = dict(kernel="matern15", optimize=False, length_scale=[0.9, 1.4, 2.5], signal_variance=1.2, noise=3e-3)
    sparse = make_gp("sparse", n_inducing=100, jitter=1e-12, shared_kernel=True, **fixed).fit(Z, Y)
    exact = make_gp("exact", shared_kernel=True, **fixed).fit(Z, Y)
    assert sparse.Q_.shape == (1, 60, 60)  # one Q for both outputs
    Zq = np.random.default_rng(3).uniform(-2, 2, (25, 3))
    for a, b in zip(sparse.predict(Zq), exact.predict(Zq)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    fitted = make_gp("sparse", n_inducing=20, max_iter=20, shared_kernel=True).fit(Z, Y)
    h = fitted.hyper_
    assert len(h.groups()) == 1 and np.all(h.log_ls == h.log_ls[0]) and np.all(h.log_sn2 == h.log_sn2[0])


@pytest.mark.parametrize("shared", [False, True])
def test_sparse_fast_predict_and_files_with_one_q_per_output(tmp_path, shared):
    Z, Y = smooth_data(n=80)
    gp = make_gp("sparse", n_inducing=25, max_iter=15, shared_kernel=shared).fit(Z, Y)
    Zq = np.random.default_rng(4).uniform(-2, 2, (30, 3))
    mean, var = gp.predict(Zq)
    fm, fv = gp.fast_predict(Zq)
    np.testing.assert_allclose(fm, mean, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(fv, var, rtol=1e-12, atol=1e-14)
    loaded = load_model(save_model(tmp_path / "m.h5", gp)).gp
    np.testing.assert_array_equal(loaded.predict(Zq)[1], var)
    # a file from before the groups: one Q per output, even where the outputs share a kernel
    arrays = gp.to_arrays()
    arrays["state/Q"] = np.stack([gp.Q_[0 if shared else o] for o in range(gp.hyper_.p)])
    old = type(gp).from_arrays(arrays, gp.get_params())
    np.testing.assert_allclose(old.predict(Zq)[1], var, rtol=1e-12, atol=1e-14)


def test_features_one_spline_call_equals_one_per_lookahead():
    track = make_track({"kind": "random", "seed": 2, "width": 0.75})
    rng = np.random.default_rng(0)
    opp = np.column_stack([rng.uniform(0.5, 1.5, 20), np.zeros((20, 3)), rng.uniform(-0.2, 0.2, 20),
                           rng.uniform(0, 2 * track.length, 20)])
    Z = features(track, opp[0] + 0.1, opp)
    for j, d in enumerate(LOOKAHEAD):
        np.testing.assert_array_equal(Z[:, len(FEATURES) - 3 + j], track.kappa(track.wrap(opp[:, 5] + d)))


def _opponent_gp(backend: str, kernel: str = "matern15", **kw):
    """A GP on opponent features of random states (a real fit: the shapes and scales of the protocol)."""
    track = make_track({"kind": "random", "seed": 5, "width": 0.75})
    rng = np.random.default_rng(1)
    n = 120
    opp = np.column_stack([rng.uniform(0.6, 1.4, n), rng.normal(0, 0.05, n), rng.normal(0, 0.3, n),
                           rng.normal(0, 0.05, n), rng.uniform(-0.2, 0.2, n), rng.uniform(0, track.length, n)])
    ego = opp + rng.normal(0, 0.1, opp.shape)
    Z = features(track, ego, opp)
    Y = 0.1 * np.column_stack([opp[:, 0], -0.3 * opp[:, 4], Z[:, 8], -0.1 * opp[:, 0], Z[:, 9]])
    Y = Y + 1e-3 * rng.standard_normal(Y.shape)
    return track, make_gp(backend, kernel=kernel, shared_kernel=True, **kw).fit(Z, Y)


@pytest.mark.parametrize("backend, kw", [("exact", {}), ("sparse", {"n_inducing": 40, "max_iter": 15})])
def test_rollout_equals_a_plain_loop_over_predict(backend, kw):
    track, gp = _opponent_gp(backend, **kw)
    pred = GPPredictor(gp, steps=9, samples=50, seed=0)
    ego_plan = np.tile([1.1, 0, 0, 0.05, 0.1, 3.0], (10, 1))
    ego_plan[:, 5] += 0.11 * np.arange(10)
    opp = np.array([1.0, 0.0, 0.1, 0.0, -0.05, 3.3])
    eps = np.random.default_rng(7).standard_normal((9, 50, len(OUTPUTS)))
    paths = pred.rollout(track, ego_plan, opp, eps)
    S, idx = np.tile(opp, (50, 1)), list(OUT_STATE)
    for k in range(9):  # the plain path: checked predict of every sample at every step
        Z = np.column_stack([features(track, ego_plan[k], S[:, :])[:, :8]]
                            + [track.kappa(track.wrap(S[:, 5] + d)) for d in LOOKAHEAD])
        mu = gp.predict(Z)[0]
        var = gp.predict(Z.mean(axis=0, keepdims=True))[1]  # one variance per step: at the samples' mean input
        S[:, idx] += mu + np.sqrt(var) * eps[k]
        np.testing.assert_allclose(paths[:, k], S, rtol=1e-7, atol=1e-9)  # BLAS rounding (1 vs 50 rows)


def test_rollout_samples_have_the_gp_mean_and_variance_at_the_first_step():
    track, gp = _opponent_gp("exact")
    pred = GPPredictor(gp, steps=1, samples=20000, seed=3)
    ego_plan = np.tile([1.1, 0, 0, 0.05, 0.1, 3.0], (2, 1))
    opp = np.array([1.0, 0.0, 0.1, 0.0, -0.05, 3.3])
    step = pred.rollout(track, ego_plan, opp)[:, 0, list(OUT_STATE)] - opp[list(OUT_STATE)]
    mu, var = gp.predict(features(track, ego_plan[0], opp[None, :]))
    assert var.min() > 0
    se = np.sqrt(var[0] / 20000)  # standard error of the sample mean
    assert np.all(np.abs(step.mean(axis=0) - mu[0]) < 5 * se)
    np.testing.assert_allclose(step.var(axis=0), var[0], rtol=0.05)  # chi2 with 20000 dof: 1 % sd


@pytest.mark.parametrize("backend, kw", [("exact", {}), ("sparse", {"n_inducing": 40, "max_iter": 15})])
def test_fast_mean_is_the_mean_of_predict(backend, kw):
    track, gp = _opponent_gp(backend, **kw)
    Z = features(track, np.tile([1.1, 0, 0, 0.05, 0.1, 3.0], (30, 1)),
                 np.column_stack([np.linspace(0.8, 1.2, 30), np.zeros((30, 3)), np.linspace(-0.1, 0.1, 30),
                                  np.linspace(3.0, 4.0, 30)]))
    np.testing.assert_allclose(gp.fast_mean(Z), gp.predict(Z)[0], rtol=1e-10, atol=1e-12)


def test_batched_paths_equal_one_rollout_per_start():
    """The offline errors' batch of start states gives each start the paths of its own rollout."""
    from gprace.h2h.predictors import sample_paths

    track, gp = _opponent_gp("exact")
    rng = np.random.default_rng(5)
    G, n, K = 3, 20, 9
    opp = np.column_stack([rng.uniform(0.9, 1.1, G), np.zeros((G, 3)), rng.uniform(-0.1, 0.1, G), 3.0 + 0.2 * np.arange(G)])
    ego = np.tile([1.1, 0, 0, 0.05, 0.1, 2.5], (K, G, 1))
    ego[..., 5] += 0.11 * np.arange(K)[:, None] + 0.2 * np.arange(G)[None, :]
    eps = rng.standard_normal((K, G * n, len(OUTPUTS)))
    paths = sample_paths(gp, track, ego, opp, n, eps)
    pred = GPPredictor(gp, steps=K, samples=n)
    for g in range(G):
        own = pred.rollout(track, ego[:, g], opp[g], eps[:, g * n:(g + 1) * n])
        np.testing.assert_allclose(paths[g * n:(g + 1) * n], own, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("backend, kw", [("exact", {}), ("sparse", {"n_inducing": 40, "max_iter": 15})])
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("track_spec", [{"kind": "random", "seed": 5, "width": 0.75}, {"kind": "loop"}])
def test_compiled_rollout_equals_the_numpy_loop(backend, kw, kernel, track_spec):
    """One C call (features, mean, variance, update) gives the numpy loop's paths to rounding, on an
    open and a closed track (the gap in s wraps, s passes the start line), several starts at once."""
    from gprace.gp.fastkernel import KernelForm
    from gprace.h2h.fastroll import _library, applies
    from gprace.h2h.predictors import sample_paths

    if _library() is None:
        pytest.skip("no C compiler: the rollout runs in numpy")
    _, gp = _opponent_gp(backend, kernel, **kw)
    track = make_track(track_spec)
    assert isinstance(gp.kernel_form(), KernelForm) and applies(gp.kernel_form(), track)  # compiled vs numpy, not numpy twice
    rng = np.random.default_rng(9)
    G, n, K = 3, 30, 9
    s0 = track.length - 0.6 if track.closed else 2.0  # a closed track's samples cross s = L
    opp = np.column_stack([rng.uniform(0.9, 1.1, G), rng.normal(0, 0.05, G), rng.normal(0, 0.2, G),
                           rng.normal(0, 0.05, G), rng.uniform(-0.1, 0.1, G), s0 + 0.1 * np.arange(G)])
    ego = np.tile([1.1, 0, 0, 0.05, 0.1, s0 - 0.3], (K, G, 1))
    ego[..., 5] += 0.11 * np.arange(K)[:, None]
    eps = rng.standard_normal((K, G * n, len(OUTPUTS)))
    fast = sample_paths(gp, track, ego, opp, n, eps)
    slow = sample_paths(gp, track, ego, opp, n, eps, compiled=False)
    assert np.ptp(fast[:, -1, 5]) > 0.01  # the samples spread: the variance is not zero
    np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-10)


def test_kernel_form_only_for_one_kernel():
    Z, Y = smooth_data(n=40)
    assert make_gp("exact", shared_kernel=False).fit(Z, Y).kernel_form() is None
    assert make_gp("exact", shared_kernel=True).fit(Z, Y).kernel_form().variance == "tri"
