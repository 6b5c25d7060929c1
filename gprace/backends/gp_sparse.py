"""``sparse`` GP backend: inducing points with Titsias' variational (VFE) bound.

- Inducing inputs: ``n_inducing`` (default 200) points of the training data chosen by k-means++
  seeding on the normalised inputs (:func:`gprace.gp.inducing.kmeanspp_indices`), shared by all
  outputs and kept fixed. With ``n <= n_inducing`` every distinct data point is an inducing
  point and the model equals the exact GP.
- Hyperparameters: per output, the collapsed VFE bound (:func:`gprace.gp.objectives.vfe_bound`)
  is maximised with scipy's L-BFGS-B on its analytic gradient, in log space within the bounds of
  :data:`gprace.gp.base.BOUNDS`. One evaluation costs O(n m^2).
- ``shared_kernel``: one kernel and one noise for all (normalised) outputs, fitted on the sum of
  their VFE bounds; a query then costs one kernel block and one product for every output
  instead of one each (the opponent rollouts, docs/decisions.md).
- ``min_noise`` raises the lower bound of the (normalised) noise variance. On nearly noiseless
  data (simulated opponents: exact-GP noise at its 1e-6 floor) the VFE matrices become so badly
  conditioned that the fit degenerates to the prior mean; a floor of 1e-3 (the noise also absorbs
  the inducing-point approximation error) restored a one-step error equal to the exact GP's.
- Prediction from cached arrays: mean ``K*u w`` and latent variance
  ``sf2 - rowsum((K*u Q) * K*u)`` with ``w = Lu^-T LB^-T c`` and ``Q = Kuu^-1 - (Kuu +
  Kuf Kfu / sn2)^-1`` (computed as ``Lu^-T (I - B^-1) Lu^-1``), O(m^2) per query point; outputs
  with identical hyperparameters share one ``Q`` (stored once per group; files with one ``Q`` per
  output load as before).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import cho_solve, solve_triangular
from scipy.optimize import minimize

from gprace.errors import SolverError
from gprace.gp.base import GPBackend, best_start, optimisation_bounds
from gprace.gp.fastkernel import Points, kernel_dot
from gprace.gp.inducing import kmeanspp_indices
from gprace.gp.kernels import scaled_block
from gprace.gp.linalg import cholesky
from gprace.gp.objectives import vfe_bound

_CHUNK = 8192


class SparseGP(GPBackend):
    """Inducing-point GP (VFE) for tens of thousands of points."""

    NAME = "sparse"

    def __init__(self, *args: Any, n_inducing: int = 200, max_iter: int = 200, jitter: float = 1e-8,
                 init_points: int = 500, min_noise: float = 1e-6, shared_kernel: bool = False, **base: Any) -> None:
        """``n_inducing``: inducing points (k-means++ on the inputs); ``max_iter``: L-BFGS
        iterations of the bound; ``jitter``: added to the inducing covariance's diagonal;
        ``init_points``: the bound is first maximised on this many random points; ``min_noise``:
        floor of the noise variance (normalised); ``shared_kernel``: one kernel and noise for all
        (normalised) outputs. The base settings as in :class:`~gprace.gp.base.GPBackend`."""
        super().__init__(*args, **base)
        self.n_inducing, self.max_iter, self.jitter = n_inducing, max_iter, jitter
        self.init_points, self.min_noise, self.shared_kernel = init_points, min_noise, shared_kernel

    def _prepare(self, Zn, Yn):
        self.Zu_ = np.ascontiguousarray(Zn[kmeanspp_indices(Zn, int(self.n_inducing), int(self.seed))])

    def _fit_hyperparameters(self, Zn, Yn, log_ls, log_sf2, log_sn2):
        n, d = Zn.shape
        bounds = optimisation_bounds(d)
        bounds[-1] = (max(bounds[-1][0], float(np.log(self.min_noise))), bounds[-1][1])
        log_ls, log_sf2, log_sn2 = log_ls.copy(), log_sf2.copy(), log_sn2.copy()
        rng = np.random.default_rng(self.seed)
        sub = np.sort(rng.choice(n, min(n, int(self.init_points)), replace=False))
        p = Yn.shape[1]
        for g in ([list(range(p))] if self.shared_kernel else [[o] for o in range(p)]):
            y = np.ascontiguousarray(Yn[:, g])  # (n, q): the q outputs share theta, bounds summed
            o = g[0]
            theta0 = np.concatenate([log_ls[o], [log_sf2[o], log_sn2[o]]])
            theta0 = best_start(self.kernel, theta0, Zn[sub], y[sub])
            theta0 = _exact_init(self.kernel, theta0, Zn[sub], y[sub], bounds)

            def neg(theta: np.ndarray) -> tuple[float, np.ndarray]:
                v, grad = vfe_bound(self.kernel, theta, Zn, y, self.Zu_, self.jitter)
                return -v, -grad

            res = minimize(neg, theta0, jac=True, method="L-BFGS-B", bounds=bounds,
                           options={"maxiter": int(self.max_iter)})
            theta = res.x if np.all(np.isfinite(res.x)) else theta0
            log_ls[g], log_sf2[g], log_sn2[g] = theta[:d], theta[d], theta[d + 1]
        return log_ls, log_sf2, log_sn2

    def _fit_posterior(self, Zn, Yn):
        h = self.hyper_
        m = self.Zu_.shape[0]
        groups = h.groups()
        self.w_ = np.empty((h.p, m))
        self.Q_ = np.empty((len(groups), m, m))
        for gi, g in enumerate(groups):
            o = g[0]
            sf2, sn = h.sf2(o), np.sqrt(h.sn2(o))
            Kuu = h.k(o, self.Zu_, self.Zu_)
            Kuu[np.diag_indices(m)] += self.jitter * sf2
            Lu = cholesky(Kuu, "inducing-point kernel matrix")
            B = np.eye(m)
            Ay = np.zeros((m, len(g)))
            for s in range(0, Zn.shape[0], _CHUNK):  # accumulate A A^T and A y without storing A
                A = solve_triangular(Lu, h.k(o, self.Zu_, Zn[s:s + _CHUNK]), lower=True, check_finite=False)
                A /= sn
                B += A @ A.T
                Ay += A @ Yn[s:s + _CHUNK][:, g]
            LB = cholesky(B, "VFE matrix B")
            c = solve_triangular(LB, Ay, lower=True, check_finite=False) / sn
            t = solve_triangular(LB, c, lower=True, trans="T", check_finite=False)
            self.w_[g] = solve_triangular(Lu, t, lower=True, trans="T", check_finite=False).T
            X = np.eye(m) - cho_solve((LB, True), np.eye(m), check_finite=False)
            S = solve_triangular(Lu, X, lower=True, trans="T", check_finite=False)
            S = solve_triangular(Lu, S.T, lower=True, trans="T", check_finite=False)
            self.Q_[gi] = 0.5 * (S + S.T)
        self._cache()

    def _cache(self) -> None:
        """Derived, not stored: per group of outputs with one kernel, its outputs, the inducing
        inputs divided by its length scales (and their squared norms) and ``[w_g^T, Q_g]`` (one
        product gives the means and the variance's ``K*u Q``)."""
        h = self.hyper_
        groups = h.groups()
        if self.Q_.shape[0] not in (h.p, len(groups)):
            from gprace.errors import ArtifactError

            raise ArtifactError(f"sparse GP model: {self.Q_.shape[0]} Q matrices for {len(groups)} kernels")
        # files from before the groups hold one Q per output
        qi = [g[0] for g in groups] if self.Q_.shape[0] == h.p else range(len(groups))
        self._groups = []
        for g, i in zip(groups, qi):
            self._groups.append((g, Points(self.Zu_ / h.ls(g[0])), np.hstack([self.w_[g].T, self.Q_[i]]),
                                 np.ascontiguousarray(self.w_[g])))

    def _predict_normalised(self, Zn):
        h = self.hyper_
        mm = Zn.shape[0]
        mean = np.empty((mm, h.p))
        var = np.empty((mm, h.p))
        for s in range(0, mm, _CHUNK):
            mean[s:s + _CHUNK], var[s:s + _CHUNK] = self._predict_chunk(Zn[s:s + _CHUNK])
        return mean, var

    def _predict_chunk(self, Zn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and latent variance ``(m, p)`` of normalised queries: per kernel one block ``K*u``
        and one product ``K*u [w, Q]``."""
        h = self.hyper_
        mean = np.empty((Zn.shape[0], h.p))
        var = np.empty((Zn.shape[0], h.p))
        for g, pts, WQ, _ in self._groups:
            o = g[0]
            Ks = scaled_block(h.kernel, Zn / h.ls(o), pts.a, pts.a2, h.sf2(o))
            P = Ks @ WQ
            mean[:, g] = P[:, :len(g)]
            var[:, g] = (h.sf2(o) - np.einsum("ij,ij->i", P[:, len(g):], Ks))[:, None]
        return mean, var

    def _fast_mean_normalised(self, Zn: np.ndarray) -> np.ndarray:
        """The mean alone: one fused kernel product ``K*u w`` per kernel (:mod:`gprace.gp.fastkernel`)."""
        h = self.hyper_
        mean = np.empty((Zn.shape[0], h.p))
        for g, pts, _, wT in self._groups:
            mean[:, g] = kernel_dot(h.kernel, Zn / h.ls(g[0]), pts, wT, h.sf2(g[0]))
        return mean

    def kernel_form(self):
        _, pts, _, wT = self._groups[0]
        return self._form(pts, wT, "quad", self.Q_[0])  # one kernel: Q_[0] is its Q in either file layout

    def _state_arrays(self):
        return {"Zu": self.Zu_, "w": self.w_, "Q": self.Q_}

    def _load_state(self, state):
        try:
            self.Zu_ = np.ascontiguousarray(state["Zu"], dtype=float)
            self.w_ = np.asarray(state["w"], dtype=float)
            self.Q_ = np.asarray(state["Q"], dtype=float)
        except KeyError as exc:
            from gprace.errors import ArtifactError

            raise ArtifactError(f"sparse GP model: missing array {exc.args[0]!r}") from None
        self._cache()


def _exact_init(kernel_name: str, theta0: np.ndarray, Z: np.ndarray, y: np.ndarray, bounds) -> np.ndarray:
    """Start of the VFE optimisation: the exact-GP optimum on a small subsample.

    The collapsed VFE bound has a broad local optimum that explains all data as noise; starting
    from hyperparameters that already describe the signal avoids it at a small cost.
    """
    from gprace.gp.objectives import exact_lml

    def neg(theta: np.ndarray) -> tuple[float, np.ndarray]:
        v, g = exact_lml(kernel_name, theta, Z, y)
        return -v, -g

    try:
        res = minimize(neg, theta0, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": 100})
    except (SolverError, np.linalg.LinAlgError, ValueError):  # a failed warm start is no reason to fail the fit
        return theta0
    return res.x if np.all(np.isfinite(res.x)) else theta0
