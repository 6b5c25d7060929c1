"""The two GPs of the double-GP scheme: their data, training and use (paper, "GP Model" and appendix).

Both GPs take the inputs of a named feature set (:data:`gprace.gp.features.DYN_FEATURE_SETS`):
``paper`` = ``[v_y, yaw_rate, delta]`` (the paper, docs/reference.md#time-trial) or ``full`` = ``[v_x, v_y,
yaw_rate, delta, a_x]`` (the default: with the paper's three inputs braking and driving alias,
docs/decisions.md). A saved model carries its input names; :class:`GPPredictor` builds its own
inputs from states and inputs (:meth:`GPPredictor.at`), so planner and MPC never index features.
Targets, from consecutive samples
``(x_k, u_k) -> x_{k+1}`` of a run:

- ``tracking``: the one-step errors of ``[v_y, yaw_rate]`` of the MPC's prediction step
  (``y = x_{k+1} - step(x_k, u_k)``; the paper's definition with its Euler step, here with the
  MPC's RK4 step so the compensation matches the prediction it corrects);
- ``planning``: the errors of ``d v_y/dt`` and ``d yaw_rate/dt`` of the continuous model, the
  planner's dynamics: the central difference of the measurements minus ``f(x_k, u_k)``.

Samples of a car out of control (``|e_psi| > 0.5`` rad or ``|v_y| > 0.2 |v_x| + 1`` m/s, i.e. a
spin in progress) are left out: the diverse selection otherwise fills the dictionary with them
(they are the most "novel" points) and the compensated MPC then spun on laps the nominal MPC
completed.

Variance that tells the truth (:func:`calibrate`): after every (re)fit the predicted variances
are scaled per output so that the 95 % band covers 95 % of the errors, on two sets: the
leave-one-out errors of the GP's own data (closed form for the exact GP; where data conflict the
scale grows) and the errors on a calibration run, a weaving run of another design than the
held-out test run (split-conformal calibration; the GP's own data cannot show a covariate shift
such as lateral excitation at top speed after one smooth lap, docs/decisions.md). The larger
scale wins; it never shrinks the GP's own variance.

Training (project decision, to fit the 10-minute budget of ``gprace iterate``): hyperparameters
are fitted once, by marginal likelihood on at most ``max_fit_points`` points of the first data
set, with one kernel shared by both outputs; every later retrain keeps them FIXED and only
recomputes the posterior on the current dictionary (a Cholesky factorisation, a fraction of a
second at M = 2000).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprace.errors import InputError
from gprace.gp.features import DYN_OUTPUTS

FEATURE_NAMES = ["v_y", "yaw_rate", "delta"]  # the paper's set (kept for old imports)
SPIN_EPSI = 0.5   # |e_psi| [rad] beyond which a sample counts as out of control
SPIN_SLIP = 0.2   # |v_y| / |v_x| beyond which a sample counts as out of control
SPIN_HORIZON = 1.0  # seconds before the end of a failed lap left out of the GP data (the loss of control)
OUTPUTS = DYN_OUTPUTS


def in_control(X: np.ndarray) -> np.ndarray:
    """Mask (n,) of states ``X (n, >=6)`` of a car in control (not spinning)."""
    return (np.abs(X[:, 3]) < SPIN_EPSI) & (np.abs(X[:, 1]) < SPIN_SLIP * np.abs(X[:, 0]) + 1.0)


def features(run, model, track, kind: str, feature_set: str = "full", step: str = "rk4",
             delay: float = 0.0, keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(Z (n, d), Y (n, 2))`` of one run for the ``tracking`` or ``planning`` GP (vectorised).

    Samples of a car out of control are left out, and so are the last ``SPIN_HORIZON`` seconds
    before a lap that ended in a spin or off the track: the GP compensates the car in control.
    With a total ``delay`` [s] (:mod:`gprace.mpc.delay`) the inputs are those that acted over each
    recorded period (the tracking target: the residual of the delay-aware step the MPC predicts
    with; the input features: their mean over the period), and the first samples, whose acting
    inputs were sent before the recording, are left out.
    ``keep`` (n,) replaces the in-control rule by a mask of usable samples (a recording's envelope,
    :func:`gprace.io.envelope.envelope`: on a small track the heading to the centre line passes
    0.5 rad in every hairpin, which says nothing about control); a sample pair or triple is used
    when all its samples are kept.
    """
    from gprace.gp.features import dyn_feature_set, dyn_inputs
    from gprace.mpc import delay as D

    if kind not in OUTPUTS:
        raise InputError(f"unknown GP feature map {kind!r}; available: tracking, planning")
    names = dyn_feature_set(feature_set)
    X, Usent = run.states(), run.inputs()
    dt = run.dt
    if len(X) < 3:
        return np.zeros((0, len(names))), np.zeros((0, 2))
    U = D.blended(Usent, delay, dt) if delay > 0 else Usent
    t = run["t"]
    if kind == "planning":
        # derivative errors at each interior sample: central difference of the measurement minus f
        ok = (np.abs(t[2:] - t[:-2] - 2 * dt) < 1e-6 * max(dt, 1.0))
        xm, x0, xp, u0 = X[:-2][ok], X[1:-1][ok], X[2:][ok], U[1:-1][ok]
        Y = ((xp - xm) / (2 * dt) - model.f(x0, u0, track.kappa(x0[:, 5])))[:, 1:3]
        t0 = t[1:-1][ok]
        kept = None if keep is None else (keep[:-2] & keep[1:-1] & keep[2:])[ok]
    else:
        ok = np.abs(np.diff(t) - dt) < 1e-6 * max(dt, 1.0)
        x0, u0, x1 = X[:-1][ok], U[:-1][ok], X[1:][ok]
        # the MPC's step: RK4 with the curvature following s through the step (mpc.tracking)
        if delay > 0:
            pred = D.acting_step(model, X[:-1], Usent[:-1], track.kappa, dt, delay)[ok]
        elif step == "rk4":
            pred = model.rk4(x0, u0, track.kappa, dt)
        else:
            pred = model.euler(x0, u0, track.kappa(x0[:, 5]), dt)
        Y = (x1 - pred)[:, 1:3]
        t0 = t[:-1][ok]
        kept = None if keep is None else (keep[:-1] & keep[1:])[ok]
    Z = dyn_inputs(x0, u0, names)
    good = np.all(np.isfinite(Z), axis=1) & np.all(np.isfinite(Y), axis=1)
    # a car out of control (spinning) is not the dynamics the GPs compensate: leave it out
    good &= in_control(x0) if kept is None else kept
    if not run.meta.get("completed", True):
        good &= t0 < t[-1] - SPIN_HORIZON
    if delay > 0:
        good &= t0 >= t[0] + D.skipped(delay, dt) * dt - 1e-9
    return Z[good], Y[good]


class GPPredictor:
    """``Z -> (mean, var)`` of a fitted backend (latent variance times ``var_scale``).

    ``inputs`` are the feature names the GP was trained on; :meth:`at` builds them from states
    and inputs. ``var_scale`` (p,) is the calibration of :func:`calibrate` (1 = the GP's own).
    """

    def __init__(self, gp, kind: str, source: str = "model", inputs=tuple(FEATURE_NAMES), var_scale=None) -> None:
        self.gp, self.kind, self.source = gp, kind, source
        self.inputs = tuple(inputs)
        self.var_scale = np.ones(2) if var_scale is None else np.asarray(var_scale, dtype=float)

    def __call__(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mean, var = self.gp.predict(Z)
        return mean, var * self.var_scale

    def at(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance at states ``X (n, 6)`` and inputs ``U (n, 2)``."""
        from gprace.gp.features import dyn_inputs

        return self(dyn_inputs(X, U, self.inputs))

    def at_with_gradient(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean ``(n, 2)``, variance ``(n, 2)`` and mean gradient ``(n, 2, d)`` w.r.t. the inputs.

        The exact backend computes all three from one kernel block, with its spectral variance
        (an upper bound of the exact variance, within 0.1 % of the prior at the data; the MPC's real-time
        path, ``ExactGP._spectral``); other backends: their variance and central differences of
        the mean.
        """
        from gprace.gp.features import dyn_inputs

        Z = dyn_inputs(X, U, self.inputs)
        try:
            mean, var, grad = self.gp.predict_with_gradient(Z)
            return mean, var * self.var_scale, grad
        except (AttributeError, NotImplementedError):
            pass
        mean, var = self(Z)
        h = 1e-4 * np.maximum(np.std(Z, axis=0), 1e-3)
        grad = np.empty(mean.shape + (Z.shape[1],))
        for j in range(Z.shape[1]):  # d = 3 or 5 evaluations of a short horizon
            e = np.zeros(Z.shape[1])
            e[j] = h[j]
            grad[:, :, j] = (self.gp.predict(Z + e)[0] - self.gp.predict(Z - e)[0]) / (2 * h[j])
        return mean, var, grad

    def predictive(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance of a new measurement (latent plus noise, calibrated)."""
        mean, var = self.gp.predict(Z)
        return mean, (var + self.gp.noise_) * self.var_scale

    def extrapolation(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """``(m,)`` the largest over the outputs of the latent std over its prior std at states ``X``
        and inputs ``U``: 0 on dense data, 1 where the GP knows nothing (its prior). Unlike
        :meth:`novelty` it reaches 1 whatever the GP's signal-to-noise ratio (a GP whose signal std
        is 1.3 times its noise std never reads a novelty above 1.65); NaN for a backend that does
        not expose its prior variance (``signal_``)."""
        return self.extrapolation_of(self.at(X, U)[1])

    def extrapolation_of(self, var: np.ndarray) -> np.ndarray:
        """:meth:`extrapolation` from a variance ``(m, 2)`` that :meth:`at` or
        :meth:`at_with_gradient` returned (no second prediction; the real-time path's spectral
        variance reads 1 to 3 % above the exact one)."""
        prior = getattr(self.gp, "signal_", None)
        if prior is None:
            return np.full(len(var), np.nan)
        latent = np.asarray(var, float) / self.var_scale
        return np.sqrt(latent / np.maximum(np.asarray(prior, float), 1e-300)).max(axis=1)

    def novelty(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """``(m,)`` the largest over the outputs of a new measurement's predictive std over the
        noise std at states ``X`` and inputs ``U``: about 1 where the GP has data, large where it
        extrapolates."""
        from gprace.gp.features import dyn_inputs

        _, var = self.predictive(dyn_inputs(X, U, self.inputs))
        noise = np.asarray(self.gp.noise_, float) * self.var_scale
        return np.sqrt(var / np.maximum(noise, 1e-12)).max(axis=1)


def load_predictor(path, kind: str) -> GPPredictor:
    """A saved GP model for ``kind``; InputError if it was trained on another map or unknown inputs."""
    from gprace.gp import load_model
    from gprace.gp.features import dyn_set_of

    saved = load_model(path)
    fm = saved.feature_map or ""
    if fm and fm != kind:
        raise InputError(f"{path}: GP trained with feature map {fm!r}, this needs {kind!r}")
    dyn_set_of(saved.input_names)  # a known feature set, or a one-line error
    if len(saved.output_names) != 2:
        raise InputError(f"{path}: GP has {len(saved.output_names)} outputs, this needs 2 ({OUTPUTS[kind]})")
    scale = saved.attrs.get("var_scale")
    return GPPredictor(saved.gp, kind, str(path), saved.input_names, scale)


def calibrate(gp, level: float = 0.95, calib: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Variance scale (p,) >= 1 per output: the larger of the leave-one-out and the calibration-run scale.

    Leave-one-out: with ``K = K_f + s_n^2 I`` on the (normalised) training data, the LOO residual
    of point i is ``[K^-1 y]_i / [K^-1]_ii`` and its predictive variance ``1 / [K^-1]_ii``
    (Rasmussen & Williams eq. 5.12), so the LOO z-score is ``[K^-1 y]_i / sqrt([K^-1]_ii)``
    (backends without a cached Cholesky factor: none). Calibration run ``calib = (Z, Y)``: the
    z-scores of its errors under the GP's predictive variance (latent plus noise); fewer than
    ``MIN_CALIB`` samples are ignored. Each scale is the squared ratio of the ``level`` quantile
    of |z| to the Gaussian one.
    """
    p = gp.n_outputs_
    scale = np.ones(p)
    for z in (_loo_z(gp), _calib_z(gp, calib)):
        if z is not None:
            scale = np.maximum(scale, _z_scale(z, level))
    return scale


MIN_CALIB = 50  # samples of a calibration run below which it is not used


def _z_scale(z: np.ndarray, level: float) -> np.ndarray:
    from scipy.stats import norm

    q = np.quantile(np.abs(z), level, axis=0)
    return (q / norm.ppf(0.5 + level / 2)) ** 2


def _loo_z(gp) -> np.ndarray | None:
    """Leave-one-out z-scores (n, p) of the exact GP's training outputs, or None."""
    from scipy.linalg import solve_triangular

    L, alpha = getattr(gp, "L_", None), getattr(gp, "alpha_", None)
    if L is None or alpha is None:
        return None
    z = np.empty_like(alpha)
    for gi, g in enumerate(gp._groups()):
        Linv = solve_triangular(L[gi], np.eye(L.shape[1]), lower=True, check_finite=False)
        kinv_diag = np.einsum("ij,ij->j", Linv, Linv)
        z[:, g] = alpha[:, g] / np.sqrt(kinv_diag)[:, None]
    return z


def _calib_z(gp, calib) -> np.ndarray | None:
    """z-scores (n, p) of a calibration run's errors under the GP's predictive spread, or None."""
    if calib is None or len(calib[0]) < MIN_CALIB:
        return None
    mean, var = gp.predict(calib[0])
    return (calib[1] - mean) / np.sqrt(var + gp.noise_)


def coverage(pred: GPPredictor, Z: np.ndarray, Y: np.ndarray, level: float = 0.95) -> np.ndarray:
    """Share (p,) of the errors ``Y`` inside the predictor's two-sided ``level`` band (latent + noise)."""
    from scipy.stats import norm

    if len(Z) == 0:
        return np.full(Y.shape[1] if Y.ndim == 2 else 2, np.nan)
    mean, var = pred.predictive(Z)
    k = norm.ppf(0.5 + level / 2)
    return np.mean(np.abs(Y - mean) <= k * np.sqrt(var), axis=0)


def fit_hyper(Z: np.ndarray, Y: np.ndarray, seed: int = 0, max_fit_points: int = 400, backend: str = "exact"):
    """Marginal-likelihood fit (hyperparameters on a subsample, posterior on all points)."""
    from gprace.gp import make_gp

    kw = {"kernel": "se", "optimize": True, "seed": seed}
    if backend == "exact":
        # one kernel for both outputs: one Cholesky factor, half the prediction cost in the MPC loop;
        # a smooth second start: a wiggly optimum made every plan of a trial "novel" and stalled it
        # at 68.45 s where the smooth fit reaches 59.70 s (docs/decisions.md, issue 37, stops 71-72)
        kw.update(max_fit_points=max_fit_points, shared_kernel=True, smooth_start=True)
    return make_gp(backend, **kw).fit(Z, Y)


def refit_fixed(ref, Z: np.ndarray, Y: np.ndarray, backend: str = "exact"):
    """Posterior on ``(Z, Y)`` with the hyperparameters of ``ref`` held fixed.

    Length scales are kept in physical units (the inputs are re-standardised on the new data);
    signal and noise variances are kept relative to the outputs' spread (the backend standardises
    the outputs), so outputs that shared one kernel still share one Cholesky factor.
    """
    from gprace.gp import make_gp
    from gprace.gp.base import fit_scalers

    h = ref.hyper_
    ls_phys = np.exp(h.log_ls) * h.z_scale[None, :]
    _, z_scale, _, _ = fit_scalers(np.asarray(Z, float), np.asarray(Y, float))
    kw = {"shared_kernel": bool(getattr(ref, "shared_kernel", False))} if backend == "exact" else {}
    gp = make_gp(backend, kernel=h.kernel, optimize=False, seed=ref.seed, length_scale=ls_phys / z_scale[None, :],
                 signal_variance=np.exp(h.log_sf2), noise=np.maximum(np.exp(h.log_sn2), 1e-8), **kw)
    return gp.fit(Z, Y)


def save_predictor(path, gp, kind: str, extra: dict | None = None, feature_set: str = "full", var_scale=None):
    from gprace.gp import save_model
    from gprace.gp.features import dyn_feature_set

    meta = {"feature_map": kind, "input_names": list(dyn_feature_set(feature_set)), "output_names": OUTPUTS[kind]}
    if var_scale is not None:
        meta["var_scale"] = [float(v) for v in var_scale]
    meta.update(extra or {})
    return save_model(path, gp, meta)


# what a trial process imports beyond what the parent has when it forks the trials (measured on
# the README job: scikit-learn's GP with pandas and joblib, scipy.stats and scipy.signal; 3 to 4 s
# of CPU in each trial process)
TRIAL_MODULES = ("sklearn.gaussian_process", "scipy.stats", "scipy.signal", "gprace.gp.selection",
                 "gprace.explore.algorithm", "gprace.timetrial.drive", "gprace.timetrial.shakedown")


def preload_trial_modules() -> bool:
    """Import :data:`TRIAL_MODULES` once in a parent whose worker processes are forked, so every
    trial process inherits them instead of importing them again (issue 37: the README job's time).
    Nothing is done (False) where workers do not fork (spawn, forkserver)."""
    import importlib
    import multiprocessing

    if multiprocessing.get_start_method(allow_none=False) != "fork":
        return False
    for name in TRIAL_MODULES:
        importlib.import_module(name)
    return True


@dataclass
class Dictionary:
    """A GP's training set across iterations, plus how many points it has seen."""

    Z: np.ndarray
    Y: np.ndarray
    n_seen: int = 0


def update_dictionary(d: Dictionary | None, Znew: np.ndarray, Ynew: np.ndarray, M: int, selection: str,
                      hyper=None, seed: int = 0) -> tuple[Dictionary, dict]:
    """Stream new data into the dictionary: ``diverse`` (paper) or ``random`` (uniform, baseline)."""
    from gprace.gp.selection import reservoir_merge, select_diverse

    if selection == "random":
        if d is None or len(d.Z) == 0:
            from gprace.gp.selection import random_subsample

            Z, Y = random_subsample(Znew, Ynew, M, seed)
            return Dictionary(Z, Y, len(Znew)), {"seen": len(Znew)}
        Z, Y, n = reservoir_merge(d.Z, d.Y, d.n_seen, Znew, Ynew, M, seed)
        return Dictionary(Z, Y, n), {"seen": len(Znew)}
    if selection != "diverse":
        raise InputError(f"unknown selection {selection!r}; available: diverse, random")
    initial = (d.Z, d.Y) if d is not None and len(d.Z) else None
    Z, Y, stats = select_diverse(hyper, Znew, Ynew, M, initial=initial)
    return Dictionary(Z, Y, (d.n_seen if d else 0) + len(Znew)), stats.as_dict()


def stream_step(hyper_path, previous, Znew: np.ndarray, Ynew: np.ndarray, kind: str, size: int, selection: str,
                feature_set: str, seed: int, max_fit_points: int, select_seed: int) -> tuple[Dictionary, dict]:
    """The select step of the loop: the hyperparameters fitted once, on the first data
    (``hyper_path`` is written then and read afterwards), and the new samples streamed into the
    previous dictionary (``previous``: a dataset artifact, or None at the first step). The caller
    checks that there are enough samples to fit on. ``seed`` seeds the fit, ``select_seed`` the
    random baseline's draw."""
    from pathlib import Path

    from gprace.io.artifacts import read_artifact

    if not Path(hyper_path).exists():
        gp0 = fit_hyper(Znew, Ynew, seed=seed, max_fit_points=max_fit_points)
        save_predictor(hyper_path, gp0, kind, feature_set=feature_set)
    hyper = load_predictor(hyper_path, kind).gp
    old = None
    if previous is not None:
        a = read_artifact(previous, "dataset")
        old = Dictionary(a.arrays["Z"], a.arrays["Y"], int(a.attrs["n_seen"]))
    return update_dictionary(old, Znew, Ynew, size, selection, hyper.hyper_, seed=select_seed)
