"""``exact`` GP backend: scikit-learn for the hyperparameters, cached factors for prediction.

Fitting: per output (or once for all outputs when ``shared_kernel``), a scikit-learn
``GaussianProcessRegressor`` with ``ConstantKernel * RBF(ARD) + WhiteKernel`` (or
``Matern(nu=1.5)``) maximises the marginal likelihood. Its cost is O(n^3) per likelihood
evaluation, so above ``max_fit_points`` (default 800) the hyperparameters are fitted on a random
subsample of that size (seeded); the posterior is then computed on ALL points with those
hyperparameters. At M = 2000 this cuts the fit from about 60 s to a few seconds while the
length scales and variances, being properties of the function rather than of the sample size,
change little. A fit whose optimum explains the data no better than white noise (length scales
collapsed to their lower bound, :func:`noise_lml`) is optimised again from a smooth start and the
better optimum kept: L-BFGS-B from the default start ends there on some subsamples of data that
have a clear signal (docs/decisions.md, issue 37, stop 64). With ``smooth_start`` (the time trial's
fits) the smooth start is always optimised as well, and its optimum replaces one above white noise
where it is better by more than ``SMOOTH_MARGIN``: from the default start L-BFGS-B also ends in
wiggly optima with short length scales that predict held-out laps barely better than the mean
(stops 71 and 72).

Prediction never calls scikit-learn: the Cholesky factor ``L`` of ``K + sn2 I`` and
``alpha = (K + sn2 I)^-1 y`` are cached per output; a query costs one kernel block
``K* (m x n)``, one product for the mean and one triangular solve for the variance. Outputs
with identical hyperparameters (always, with ``shared_kernel=True``) share one factor, which
halves the cost of a two-output query.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from scipy.linalg import cho_solve, solve_triangular
from scipy.linalg.blas import dtrsv

from gprace.gp.base import BOUNDS, GPBackend, best_start
from gprace.gp.fastkernel import Points, kernel_dot
from gprace.gp.kernels import kernel, scaled_block
from gprace.gp.linalg import cholesky, pack_lower, unpack_lower

_CHUNK = 2048
_FEW = 8  # queries answered by the fast path of the variance


NOISE_GAIN = 0.01   # log marginal likelihood per target value a fit must gain over white noise
SMOOTH_START = (3.0, 1.0, 0.1)  # (length scales, signal, noise) of the second start, normalised units
SMOOTH_MARGIN = 5.0  # log marginal likelihood by which the smooth start's optimum must win (smooth_start=True)


def noise_lml(y: np.ndarray) -> float:
    """Log marginal likelihood of ``y (n,)`` or ``(n, q)`` as independent Gaussian noise of each
    column's own variance: what a GP whose length scales collapse explains."""
    y = np.asarray(y, float).reshape(len(y), -1)
    n = len(y)
    var = np.maximum(y.var(axis=0), 1e-300)
    return float(np.sum(-0.5 * n * (np.log(2.0 * np.pi * var) + 1.0)))


class ExactGP(GPBackend):
    """Exact GP regression with scikit-learn hyperparameter fitting and a numpy predictor."""

    NAME = "exact"

    def __init__(self, *args: Any, max_fit_points: int = 800, n_restarts: int = 0, shared_kernel: bool = False,
                 smooth_start: bool = False, **base: Any) -> None:
        """``max_fit_points``: hyperparameters are fitted on at most this many random points (the
        posterior uses all); ``n_restarts``: scikit-learn's optimiser restarts; ``shared_kernel``:
        one kernel and noise for all (normalised) outputs; ``smooth_start``: always optimise from
        :data:`SMOOTH_START` as well and keep its optimum where its log marginal likelihood is
        better by more than :data:`SMOOTH_MARGIN` (a wiggly local optimum above white noise, which
        the noise check below misses: docs/decisions.md, issue 37, stops 71 and 72). The base settings (``kernel``,
        ``noise``, ...) as in :class:`~gprace.gp.base.GPBackend`."""
        super().__init__(*args, **base)
        self.max_fit_points = max_fit_points
        self.n_restarts = n_restarts
        self.shared_kernel = shared_kernel
        self.smooth_start = smooth_start

    # -- hyperparameters (scikit-learn) ------------------------------------------------------------
    def _sk_kernel(self, ls0: np.ndarray, sf20: float, sn20: float):
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel, Matern, WhiteKernel

        lb, sb, nb = BOUNDS["length_scale"], BOUNDS["signal_variance"], BOUNDS["noise"]
        if self.kernel == "se":
            base = RBF(length_scale=ls0, length_scale_bounds=lb)
        else:
            base = Matern(length_scale=ls0, length_scale_bounds=lb, nu=1.5)
        return ConstantKernel(sf20, constant_value_bounds=sb) * base + WhiteKernel(sn20, noise_level_bounds=nb)

    def _fit_hyperparameters(self, Zn, Yn, log_ls, log_sf2, log_sn2):
        n, p = Yn.shape
        rng = np.random.default_rng(self.seed)
        if n > self.max_fit_points:
            idx = np.sort(rng.choice(n, self.max_fit_points, replace=False))
            Zs, Ys = Zn[idx], Yn[idx]
        else:
            Zs, Ys = Zn, Yn
        groups = [list(range(p))] if self.shared_kernel else [[o] for o in range(p)]
        log_ls, log_sf2, log_sn2 = log_ls.copy(), log_sf2.copy(), log_sn2.copy()
        d = Zs.shape[1]
        for g in groups:
            o = g[0]
            y = Ys[:, g] if len(g) > 1 else Ys[:, o]
            th = best_start(self.kernel, np.concatenate([log_ls[o], [log_sf2[o], log_sn2[o]]]), Zs, y)
            kf, lml = self._optimise(Zs, y, th, rng)
            noise_like = lml < noise_lml(y) + NOISE_GAIN * y.size
            if self.smooth_start or noise_like:
                # the optimum that explains the data as noise (length scales at their lower bound):
                # measured on the planning data of a randomized BMW's first lap, one subsample of
                # four led L-BFGS-B there from the default start (log marginal likelihood -2265
                # against -1378 for the smooth optimum the others found; held-out error 1.00
                # against 0.59). A second start from a smooth function decides; the better wins.
                # With smooth_start the second start always runs, and above white noise it must win
                # by SMOOTH_MARGIN: a wiggly optimum there (-692 against -443 for the smooth one)
                # made every plan of a trial novel and stalled it (issue 37, stops 71 and 72)
                ls0, sf20, sn20 = SMOOTH_START
                th2 = np.log(np.r_[np.full(d, ls0), sf20, sn20])
                kf2, lml2 = self._optimise(Zs, y, th2, rng)
                if lml2 > lml + (0.0 if noise_like else SMOOTH_MARGIN):
                    kf = kf2
            ls = np.broadcast_to(np.asarray(kf.k1.k2.length_scale, dtype=float), (Zn.shape[1],))
            for q in g:
                log_ls[q] = np.log(ls)
                log_sf2[q] = np.log(kf.k1.k1.constant_value)
                log_sn2[q] = np.log(kf.k2.noise_level)
        return log_ls, log_sf2, log_sn2

    def _optimise(self, Zs: np.ndarray, y: np.ndarray, th: np.ndarray, rng) -> tuple[Any, float]:
        """``(fitted kernel, log marginal likelihood)`` of scikit-learn's optimiser from ``th``."""
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor

        d = Zs.shape[1]
        k = self._sk_kernel(np.exp(th[:d]), float(np.exp(th[d])), float(np.exp(th[d + 1])))
        gpr = GaussianProcessRegressor(
            kernel=k, alpha=1e-10, normalize_y=False, n_restarts_optimizer=self.n_restarts,
            random_state=int(rng.integers(2**31 - 1)), copy_X_train=False,
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            gpr.fit(Zs, y)
        return gpr.kernel_, float(gpr.log_marginal_likelihood_value_)

    # -- posterior -------------------------------------------------------------------------------
    def _groups(self) -> list[list[int]]:
        """Outputs that share identical hyperparameters (and so one factor)."""
        return self.hyper_.groups()

    def _fit_posterior(self, Zn, Yn):
        h = self.hyper_
        n = Zn.shape[0]
        groups = self._groups()
        L = np.empty((len(groups), n, n))
        alpha = np.empty((n, h.p))
        for gi, g in enumerate(groups):
            o = g[0]
            K = kernel(h.kernel, Zn, Zn, h.ls(o), h.sf2(o))
            K[np.diag_indices(n)] += h.sn2(o)
            L[gi] = cholesky(K, "exact GP kernel matrix")
            alpha[:, g] = cho_solve((L[gi], True), Yn[:, g], check_finite=False)
        self.Z_ = np.ascontiguousarray(Zn)
        self.L_ = L
        self.alpha_ = alpha
        self._cache()

    def _cache(self) -> None:
        """Derived, not stored: groups and the inputs divided by each group's length scales."""
        h = self.hyper_
        self._group_list = self._groups()
        self._scaled = [Points(self.Z_ / h.ls(g[0])) for g in self._group_list]
        self._alpha_t = [np.ascontiguousarray(self.alpha_[:, g].T) for g in self._group_list]
        self._L_f = [np.asfortranarray(L) for L in self.L_]  # BLAS's own order: dtrsv without a copy
        self._alpha_z = [np.hstack([self.alpha_[:, g]] + [self.alpha_[:, [q]] * self.Z_ for q in g])
                         for g in self._group_list]
        self._spectra: dict[int, np.ndarray | None] = {}
        self._azw: dict[int, np.ndarray] = {}

    def _block(self, gi: int, Zn: np.ndarray) -> np.ndarray:
        """Kernel block ``K* (m, M)`` of factor group ``gi`` between normalised queries and the data."""
        h = self.hyper_
        o = self._group_list[gi][0]
        pts = self._scaled[gi]
        return scaled_block(h.kernel, Zn / h.ls(o), pts.a, pts.a2, h.sf2(o))

    def _predict_normalised(self, Zn):
        h = self.hyper_
        m = Zn.shape[0]
        mean = np.empty((m, h.p))
        var = np.empty((m, h.p))
        for gi, g in enumerate(self._group_list):
            o = g[0]
            sf2 = h.sf2(o)
            for s in range(0, m, _CHUNK):
                Ks = self._block(gi, Zn[s:s + _CHUNK])
                mean[s:s + _CHUNK, g] = Ks @ self.alpha_[:, g]
                V = solve_triangular(self.L_[gi], Ks.T, lower=True, check_finite=False)
                var[s:s + _CHUNK, g] = (sf2 - np.einsum("ij,ij->j", V, V))[:, None]
        return mean, var

    def _fast_normalised(self, Zn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_predict_normalised` for up to :data:`_FEW` queries (the rollouts' variance at
        the samples' mean input): one BLAS ``dtrsv`` per query against the Fortran-ordered
        Cholesky factor (43 against 84 us for scipy's ``solve_triangular`` on the C-ordered one,
        600 points); the same values to rounding."""
        m = Zn.shape[0]
        if m > _FEW:
            return self._predict_normalised(Zn)
        h = self.hyper_
        mean, var = np.empty((m, h.p)), np.empty((m, h.p))
        for gi, g in enumerate(self._group_list):
            Ks = self._block(gi, Zn)
            mean[:, g] = Ks @ self.alpha_[:, g]
            for i in range(m):
                v = dtrsv(self._L_f[gi], Ks[i], lower=1)
                var[i, g] = h.sf2(g[0]) - v @ v
        return mean, var

    def _fast_mean_normalised(self, Zn: np.ndarray) -> np.ndarray:
        """The posterior mean alone: one fused kernel product per factor group (no kernel block,
        no triangular solve; :mod:`gprace.gp.fastkernel`)."""
        h = self.hyper_
        mean = np.empty((Zn.shape[0], h.p))
        for gi, g in enumerate(self._group_list):
            o = g[0]
            mean[:, g] = kernel_dot(h.kernel, Zn / h.ls(o), self._scaled[gi], self._alpha_t[gi], h.sf2(o))
        return mean

    def kernel_form(self):
        return self._form(self._scaled[0], self._alpha_t[0], "tri", self.L_[0])

    def mean_gradient(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean ``(m, p)`` and its gradient ``(m, p, d)`` with respect to the inputs."""
        mean, _, grad = self.predict_with_gradient(Z, variance="none")
        return mean, grad

    def predict_with_gradient(self, Z: np.ndarray, variance: str = "spectral") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean ``(m, p)``, latent variance ``(m, p)`` and mean gradient ``(m, p, d)``, one kernel block.

        Squared-exponential kernel: ``d k(z, z_i) / d z = -k(z, z_i) (z - z_i) / l^2`` (normalised
        inputs), so the gradient costs one more product with the kernel block. Used by the tracking
        MPC to linearise the GP along with the nominal model. Other kernels: NotImplementedError.

        ``variance``: ``"exact"`` (a triangular solve against all M points, 8 ms at M = 2000 and
        a 20-step horizon), ``"spectral"`` (the real-time path, see :meth:`_spectral`: never below
        the exact variance, its std 1 to 3 % above it on the time-trial GPs, 0.4 ms) or ``"none"`` (zeros).
        """
        h = self._fitted()
        if h.kernel != "se":
            raise NotImplementedError("mean_gradient: squared-exponential kernel only")
        if variance not in ("exact", "spectral", "none"):
            raise ValueError(f"variance must be exact, spectral or none, got {variance!r}")
        Zn = (np.asarray(Z, dtype=float) - h.z_mean) / h.z_scale
        m = Zn.shape[0]
        mean = np.empty((m, h.p))
        var = np.zeros((m, h.p))
        grad = np.empty((m, h.p, h.d))
        for gi, g in enumerate(self._group_list):
            ls, sf2 = h.ls(g[0]), h.sf2(g[0])
            Ks = self._block(gi, Zn)
            # one product for the means, the gradient sums and the spectral variance:
            # Ks @ [alpha_q, alpha_q * Z, W]
            W = self._spectral(gi) if variance == "spectral" else None
            P = Ks @ (self._alpha_z[gi] if W is None else self._alpha_zw(gi))
            for j, q in enumerate(g):
                mean[:, q] = P[:, j]
                grad[:, q, :] = (P[:, len(g) + j * h.d:len(g) + (j + 1) * h.d] - P[:, [j]] * Zn) / ls**2
            if variance == "none":
                continue
            if W is None:
                V = solve_triangular(self.L_[gi], Ks.T, lower=True, check_finite=False)
                var[:, g] = np.maximum(sf2 - np.einsum("ij,ij->j", V, V), 0.0)[:, None]
            else:
                Q = P[:, self._alpha_z[gi].shape[1]:]
                var[:, g] = np.maximum(sf2 - np.einsum("ij,ij->i", Q, Q), 0.0)[:, None]
        return (mean * h.y_scale + h.y_mean, var * h.y_scale**2,
                grad * h.y_scale[None, :, None] / h.z_scale[None, None, :])

    def _spectral(self, gi: int) -> np.ndarray | None:
        """``W (M, r)`` with ``k*^T W W^T k*`` a lower bound of ``k*^T (K + sn2 I)^-1 k*`` (cached).

        From the eigenpairs ``(lam_i, v_i)`` of ``K + sn2 I``: the quadratic form is the sum of
        ``(v_i^T k*)^2 / lam_i``, all terms positive, so keeping only the ``r`` eigenpairs whose
        noise-free eigenvalue ``lam_i - sn2`` exceeds ``tau = 0.03 sqrt(sf2 sn2)`` leaves a
        variance never below the exact one. At a dictionary point a dropped term is at most
        ``(lam_i - sn2)^2 / lam_i < tau^2 / sn2 = 1e-3 sf2``, summed with weights ``v_ij^2`` that
        add to one: the excess is below 0.1 % of the prior variance. A smooth kernel has few large
        eigenvalues (measured on the GPs of the README job: r = 70 to 210 of M = 1000, predicted std 1 to 3 %
        above the exact one in the median, at most 8 %), so a query costs
        one ``(m, M) x (M, r)`` product instead of a triangular solve (8 -> 0.4 ms at M = 2000).
        One eigendecomposition per fit, on first use (0.3 s at M = 1000, 2.5 s at M = 2000).
        ``None`` when more than half the eigenpairs are needed (a rough kernel: short length
        scales): the exact triangular solve is then the cheaper one.
        """
        if gi not in self._spectra:
            h = self.hyper_
            o = self._group_list[gi][0]
            L = self.L_[gi]
            lam, V = np.linalg.eigh(L @ L.T)
            sn2, sf2 = h.sn2(o), h.sf2(o)
            keep = lam - sn2 > 0.03 * np.sqrt(sf2 * sn2)
            self._spectra[gi] = np.ascontiguousarray(V[:, keep] / np.sqrt(lam[keep])) if 2 * keep.sum() <= len(lam) else None
        return self._spectra[gi]

    def _alpha_zw(self, gi: int) -> np.ndarray:
        """``[alpha_q, alpha_q * Z, W]`` of group ``gi`` in one array (one product per query)."""
        if gi not in self._azw:
            self._azw[gi] = np.ascontiguousarray(np.hstack([self._alpha_z[gi], self._spectral(gi)]))
        return self._azw[gi]

    # -- state -----------------------------------------------------------------------------------
    def _state_arrays(self):
        n = self.Z_.shape[0]
        return {
            "Z": self.Z_,
            "alpha": self.alpha_,
            "L_packed": np.stack([pack_lower(self.L_[i]) for i in range(self.L_.shape[0])]),
            "n": np.asarray(n),
        }

    def _load_state(self, state):
        try:
            n = int(state["n"])
            self.Z_ = np.ascontiguousarray(state["Z"], dtype=float)
            self.alpha_ = np.asarray(state["alpha"], dtype=float)
            packed = np.asarray(state["L_packed"], dtype=float)
        except KeyError as exc:
            from gprace.errors import ArtifactError

            raise ArtifactError(f"exact GP model: missing array {exc.args[0]!r}") from None
        self.L_ = np.stack([unpack_lower(packed[i], n) for i in range(packed.shape[0])])
        self._cache()

