"""The two GPs of the double-GP scheme: their data, training and use (paper, "GP Model" and appendix).

Both GPs take ``z = [v_y, yaw_rate, delta]`` (REFERENCE.md). Targets, from consecutive samples
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

FEATURE_NAMES = ["v_y", "yaw_rate", "delta"]
SPIN_EPSI = 0.5   # |e_psi| [rad] beyond which a sample counts as out of control
SPIN_SLIP = 0.2   # |v_y| / |v_x| beyond which a sample counts as out of control
OUTPUTS = {"tracking": ["v_y", "yaw_rate"], "planning": ["dv_y_dt", "dyaw_rate_dt"]}


def features(run, model, track, kind: str, step: str = "rk4") -> tuple[np.ndarray, np.ndarray]:
    """``(Z (n, 3), Y (n, 2))`` of one run for the ``tracking`` or ``planning`` GP (vectorised)."""
    if kind not in OUTPUTS:
        raise InputError(f"unknown GP feature map {kind!r}; available: tracking, planning")
    X, U = run.states(), run.inputs()
    dt = run.dt
    if len(X) < 3:
        return np.zeros((0, 3)), np.zeros((0, 2))
    t = run["t"]
    if kind == "planning":
        # derivative errors at each interior sample: central difference of the measurement minus f
        ok = (np.abs(t[2:] - t[:-2] - 2 * dt) < 1e-6 * max(dt, 1.0))
        xm, x0, xp, u0 = X[:-2][ok], X[1:-1][ok], X[2:][ok], U[1:-1][ok]
        Y = ((xp - xm) / (2 * dt) - model.f(x0, u0, track.kappa(x0[:, 5])))[:, 1:3]
    else:
        ok = np.abs(np.diff(t) - dt) < 1e-6 * max(dt, 1.0)
        x0, u0, x1 = X[:-1][ok], U[:-1][ok], X[1:][ok]
        kap = track.kappa(x0[:, 5])
        pred = model.rk4(x0, u0, kap, dt) if step == "rk4" else model.euler(x0, u0, kap, dt)
        Y = (x1 - pred)[:, 1:3]
    Z = np.column_stack([x0[:, 1], x0[:, 2], u0[:, 0]])
    good = np.all(np.isfinite(Z), axis=1) & np.all(np.isfinite(Y), axis=1)
    # a car out of control (spinning) is not the dynamics the GPs compensate: leave it out
    good &= (np.abs(x0[:, 3]) < SPIN_EPSI) & (np.abs(x0[:, 1]) < SPIN_SLIP * np.abs(x0[:, 0]) + 1.0)
    return Z[good], Y[good]


class GPPredictor:
    """``Z -> (mean, var)`` of a fitted backend (latent variance), checked for the right features."""

    def __init__(self, gp, kind: str, source: str = "model") -> None:
        self.gp, self.kind, self.source = gp, kind, source

    def __call__(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.gp.predict(Z)


def load_predictor(path, kind: str) -> GPPredictor:
    """A saved GP model for ``kind``; InputError if it was trained on other features."""
    from gprace.gp import load_model

    saved = load_model(path)
    fm = saved.feature_map or ""
    if fm and fm != kind:
        raise InputError(f"{path}: GP trained with feature map {fm!r}, this needs {kind!r} (inputs {FEATURE_NAMES})")
    if list(saved.input_names) != FEATURE_NAMES:
        raise InputError(f"{path}: GP inputs are {saved.input_names}, this needs {FEATURE_NAMES}")
    if len(saved.output_names) != 2:
        raise InputError(f"{path}: GP has {len(saved.output_names)} outputs, this needs 2 ({OUTPUTS[kind]})")
    return GPPredictor(saved.gp, kind, str(path))


def fit_hyper(Z: np.ndarray, Y: np.ndarray, seed: int = 0, max_fit_points: int = 400, backend: str = "exact"):
    """Marginal-likelihood fit (hyperparameters on a subsample, posterior on all points)."""
    from gprace.gp import make_gp

    kw = {"kernel": "se", "optimize": True, "seed": seed}
    if backend == "exact":
        # one kernel for both outputs: one Cholesky factor, half the prediction cost in the MPC loop
        kw.update(max_fit_points=max_fit_points, shared_kernel=True)
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


def save_predictor(path, gp, kind: str, extra: dict | None = None):
    from gprace.gp import save_model

    meta = {"feature_map": kind, "input_names": FEATURE_NAMES, "output_names": OUTPUTS[kind]}
    meta.update(extra or {})
    return save_model(path, gp, meta)


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
