"""GP mathematics: kernels, likelihood gradients, the VFE bound, sparse == exact at the data."""

from __future__ import annotations

import numpy as np
import pytest
from gp_contract import smooth_data

from gprace.gp import make_gp
from gprace.gp.kernels import kernel, kernel_and_grad_factor, scaled_sqdiff
from gprace.gp.objectives import exact_lml, vfe_bound

KERNELS = ["se", "matern15"]


def _fd(f, theta, h=1e-6):
    return np.array([(f(theta + h * e) - f(theta - h * e)) / (2 * h) for e in np.eye(len(theta))])


@pytest.mark.parametrize("name", KERNELS)
def test_kernels_match_scikit_learn(name):
    from sklearn.gaussian_process.kernels import RBF, Matern

    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(7, 3)), rng.normal(size=(5, 3))
    ls, sf2 = np.array([0.5, 1.3, 2.0]), 1.7
    ref = (RBF(ls) if name == "se" else Matern(ls, nu=1.5))(A, B) * sf2
    np.testing.assert_allclose(kernel(name, A, B, ls, sf2), ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.diag(kernel(name, A, A, ls, sf2)), sf2)


@pytest.mark.parametrize("name", KERNELS)
def test_kernel_length_scale_derivative(name):
    rng = np.random.default_rng(1)
    A, B = rng.normal(size=(6, 3)), rng.normal(size=(4, 3))
    ls, sf2 = np.array([0.7, 1.1, 0.4]), 2.0
    _, F = kernel_and_grad_factor(name, A, B, ls, sf2)
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1e-6
        fd = (kernel(name, A, B, ls * np.exp(e), sf2) - kernel(name, A, B, ls * np.exp(-e), sf2)) / 2e-6
        np.testing.assert_allclose(F * scaled_sqdiff(A, B, ls, j), fd, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("name", KERNELS)
def test_exact_likelihood_and_gradient(name):
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, Matern, WhiteKernel
    from sklearn.gaussian_process import GaussianProcessRegressor

    Z, Y = smooth_data(n=40)
    y = Y[:, 0] - Y[:, 0].mean()
    theta = np.array([0.2, -0.1, 0.4, 0.3, np.log(0.02)])
    value, grad = exact_lml(name, theta, Z, y)
    np.testing.assert_allclose(grad, _fd(lambda t: exact_lml(name, t, Z, y)[0], theta), rtol=1e-6, atol=1e-6)
    # same value as scikit-learn's (its theta order: constant, length scales, noise)
    base = RBF(np.ones(3)) if name == "se" else Matern(np.ones(3), nu=1.5)
    sk = GaussianProcessRegressor(ConstantKernel() * base + WhiteKernel(), alpha=0.0, optimizer=None).fit(Z, y)
    sk_theta = np.concatenate([[theta[3]], theta[:3], [theta[4]]])
    assert value == pytest.approx(sk.log_marginal_likelihood(sk_theta), rel=1e-10)


@pytest.mark.parametrize("name", KERNELS)
def test_vfe_gradient_matches_finite_differences(name):
    Z, Y = smooth_data(n=60)
    y = Y[:, 1] - Y[:, 1].mean()
    Zu = Z[::4]
    theta = np.array([0.3, -0.2, 0.1, 0.2, np.log(0.05)])
    _, grad = vfe_bound(name, theta, Z, y, Zu)
    fd = _fd(lambda t: vfe_bound(name, t, Z, y, Zu)[0], theta)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("name", KERNELS)
def test_vfe_is_a_lower_bound_that_is_tight_at_the_data(name):
    Z, Y = smooth_data(n=50)
    y = Y[:, 0] - Y[:, 0].mean()
    theta = np.array([0.0, 0.3, 0.5, 0.0, np.log(0.01)])
    exact = exact_lml(name, theta, Z, y)[0]
    at_data, g_data = vfe_bound(name, theta, Z, y, Z, jitter=1e-12)
    assert at_data == pytest.approx(exact, rel=1e-7)
    np.testing.assert_allclose(g_data, exact_lml(name, theta, Z, y)[1], rtol=1e-4, atol=1e-4)
    previous = -np.inf
    for m in (5, 15, 30):  # more inducing points (nested sets): the bound rises towards the evidence
        bound = vfe_bound(name, theta, Z, y, Z[:m])[0]
        assert previous <= bound <= exact
        previous = bound


@pytest.mark.parametrize("name", KERNELS)
def test_sparse_with_inducing_points_at_data_equals_exact(name):
    Z, Y = smooth_data(n=70)
    settings = dict(kernel=name, optimize=False, length_scale=[[0.8, 1.5, 3.0], [2.0, 0.9, 1.2]],
                    signal_variance=[1.3, 0.7], noise=[1e-2, 3e-3])
    exact = make_gp("exact", **settings).fit(Z, Y)
    sparse = make_gp("sparse", n_inducing=100, jitter=1e-12, **settings).fit(Z, Y)
    assert sparse.Zu_.shape[0] == len(Z)
    Zt, _ = smooth_data(n=50, seed=3)
    (me, ve), (ms, vs) = exact.predict(Zt), sparse.predict(Zt)
    np.testing.assert_allclose(ms, me, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(vs, ve, rtol=1e-4, atol=1e-8)


def test_sparse_approaches_exact_with_more_inducing_points():
    Z, Y = smooth_data(n=400)
    settings = dict(optimize=False, length_scale=1.0, noise=1e-2)
    me, _ = make_gp("exact", **settings).fit(Z, Y).predict(Z[:100])
    errs = [np.max(np.abs(make_gp("sparse", n_inducing=m, **settings).fit(Z, Y).predict(Z[:100])[0] - me))
            for m in (10, 40, 160)]
    assert errs[0] > errs[1] > errs[2]


def test_exact_predictor_matches_scikit_learn_without_noise_term():
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    Z, Y = smooth_data(n=50)
    gp = make_gp("exact").fit(Z, Y[:, :1])
    h = gp.hyper_
    k = ConstantKernel(np.exp(h.log_sf2[0])) * RBF(np.exp(h.log_ls[0])) + WhiteKernel(np.exp(h.log_sn2[0]))
    sk = GaussianProcessRegressor(k, alpha=0.0, optimizer=None).fit(h.zn(Z), h.yn(Y[:, :1])[:, 0])
    Zt, _ = smooth_data(n=20, seed=4)
    mean_sk, std_sk = sk.predict(h.zn(Zt), return_std=True)
    mean, var = gp.predict(Zt)
    np.testing.assert_allclose(mean[:, 0], mean_sk * h.y_scale[0] + h.y_mean[0], rtol=1e-8, atol=1e-10)
    # scikit-learn's std includes the white-noise term; ours is the latent function's
    np.testing.assert_allclose(var[:, 0] + gp.noise_[0], (std_sk * h.y_scale[0]) ** 2, rtol=1e-6)


@pytest.mark.parametrize("backend", ["exact", "sparse"])
def test_recovers_irrelevant_input(backend):
    """ARD: an input the outputs do not depend on gets a much longer length scale."""
    rng = np.random.default_rng(7)
    Z = rng.uniform(-2, 2, (100, 3))
    Y = np.column_stack([np.sin(2 * Z[:, 0]) + 0.5 * Z[:, 1] ** 2])
    Y = Y + 0.02 * rng.standard_normal(Y.shape)
    gp = make_gp(backend, n_inducing=40) if backend == "sparse" else make_gp(backend)
    ls = np.exp(gp.fit(Z, Y).hyper_.log_ls[0])
    assert ls[2] > 10 * max(ls[0], ls[1])
    noise_std = np.sqrt(gp.noise_[0])
    assert 0.01 < noise_std < 0.04


def test_sparse_noise_floor_on_noiseless_data():
    """Noise-free data drive the exact optimum to the noise bound; the sparse fit keeps its floor
    and still predicts the smooth function (relative error far below the 1 of a prior-mean fit)."""
    Z, Y = smooth_data(n=300, noise=0.0)
    Zt, Yt = smooth_data(n=200, seed=5, noise=0.0)
    gp = make_gp("sparse", n_inducing=50, max_iter=30, init_points=200, min_noise=1e-3, jitter=1e-6).fit(Z, Y)
    assert np.all(gp.hyper_.log_sn2 >= np.log(1e-3) - 1e-9)
    rel = np.sqrt(((gp.predict(Zt)[0] - Yt) ** 2).mean(axis=0)) / Yt.std(axis=0)
    assert np.all(rel < 0.1), rel
