"""Data preparation and the vectorised multi-step predictor of ``gprace diagnose``.

All recordings are stacked into one :class:`Dataset`. A *window* starts at a recorded sample
``k`` and predicts ``H`` steps ahead with the model driven by the recorded inputs
``u[k], ..., u[k+H-1]``; every window is computed at once (a batch of windows, one RK4 step for
the whole batch per horizon step), never a Python loop over samples.

Curvature along a predicted path comes from the recordings themselves (their ``kappa`` column,
interpolated over ``s``, periodic when the recording shows lap wraps), so the diagnosis needs no
track file. Sensor effects (``gyro_bias``) are inverted on the initial measurement, and actuator
lag states start from the recorded command history filtered with the lag being tested.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from gprace.errors import InputError
from gprace.io.runs import DEFAULT_INPUTS, Run
from gprace.model import Effect, NominalModel
from gprace.model.dynamics import State, dynamics
from gprace.model.ops import NP

INPUT_KINDS = {"delta": ("commanded", "measured"), "a_x": ("commanded", "measured", "derived", "absent"),
               "v_cmd": ("commanded",)}
"""What each input of a recording is (``run.meta["inputs"]``, written by the importer's map)."""
CHANNELS = ("v_x", "v_y", "yaw_rate", "e_psi", "e_y", "s")
DYNAMIC = (0, 1, 2)  # v_x, v_y, yaw_rate: the channels fitted and tested for structure
TESTED = (0, 1, 2, 3, 4)  # channels with a structure statistic (s is reported via e_psi/e_y)
_OFFSET = 1.0e7  # separates recordings inside one concatenated curvature table
LAG_INPUT = {"steering_lag": 0, "drivetrain_lag": 1}


@dataclass
class Dataset:
    Y: np.ndarray  # (N, 6) measured states
    U: np.ndarray  # (N, 2) recorded commands
    kappa: np.ndarray  # (N,)
    rec: np.ndarray  # (N,) recording index
    lap: np.ndarray  # (N,) global lap id (unique over recordings)
    t: np.ndarray
    dt: float
    L: np.ndarray  # (R,) lap length per recording (inf when no lap wrap)
    sources: list[str]
    ks: np.ndarray = field(repr=False, default=None)  # curvature table (s + rec * _OFFSET)
    kv: np.ndarray = field(repr=False, default=None)
    A: np.ndarray = field(repr=False, default=None)  # (N,) the recorded a_x, whatever its kind (regimes)
    inputs: dict = field(default_factory=lambda: dict(DEFAULT_INPUTS))  # kind of every input
    longitudinal: str = "force"  # how U[:, 1] drives v_x (gprace.model.dynamics.LONGITUDINAL)

    def __post_init__(self) -> None:
        if self.A is None:
            self.A = self.U[:, 1].copy()

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def laps_total(self) -> int:
        return len(np.unique(self.lap))

    def kappa_at(self, s: np.ndarray, rec: np.ndarray) -> np.ndarray:
        L = self.L[rec]
        sw = np.where(np.isfinite(L), np.mod(s, np.where(np.isfinite(L), L, 1.0)), s)
        return np.interp(sw + rec * _OFFSET, self.ks, self.kv)

    def windows(self, H: int) -> np.ndarray:
        """Start indices ``k`` with ``k .. k+H`` inside one recording and without time gaps."""
        N = self.n
        k = np.arange(max(N - H, 0))
        ok = self.rec[k] == self.rec[k + H]
        gap = np.abs(self.t[k + H] - self.t[k] - H * self.dt) < 0.5 * self.dt
        return k[ok & gap]

    def s_unwrapped(self) -> np.ndarray:
        """``s`` continued over lap wraps (per recording), for window geometry."""
        out = self.Y[:, State.S].copy()
        for r in range(len(self.L)):
            m = self.rec == r
            if np.isfinite(self.L[r]):
                lapr = self.lap[m] - self.lap[m].min()
                out[m] = out[m] + lapr * self.L[r]
        return out


def input_kinds(run: Run) -> dict[str, str]:
    """The kind of every input of ``run`` (``meta["inputs"]``; the defaults for runs without it);
    an unknown kind, or a speed command declared without its ``v_cmd`` column, is an InputError."""
    given = run.meta.get("inputs") if isinstance(run.meta, dict) else None
    if isinstance(given, str):  # stored as JSON text by a writer that flattens attributes
        import json

        given = json.loads(given)
    kinds = dict(DEFAULT_INPUTS)
    for k, v in (given or {}).items():
        if k not in INPUT_KINDS or v not in INPUT_KINDS[k]:
            raise InputError(f"{run.source}: input kind {k} = {v!r} unknown (known: "
                             + "; ".join(f"{q}: {', '.join(vs)}" for q, vs in INPUT_KINDS.items()) + ")")
        kinds[k] = v
    if kinds.get("v_cmd") and "v_cmd" not in run.data:
        raise InputError(f"{run.source}: the inputs name a speed command but the recording has no column 'v_cmd'")
    return kinds


def longitudinal_input(kinds: dict[str, str]) -> str:
    """How the recording drives ``v_x`` in the model: a commanded ``a_x`` through the forces
    (``"force"``), else a speed command through the car's speed loop (``"speed"``), else the
    measured or derived ``a_x`` kinematically (``"kinematic"``). Commands come first: they are
    inputs, while a measured acceleration already holds the response the model should predict."""
    if kinds.get("a_x") == "commanded":
        return "force"
    if kinds.get("v_cmd") == "commanded":
        return "speed"
    return "kinematic"


def build_dataset(runs: list[Run], min_samples: int = 200) -> Dataset:
    """Stack recordings; checks period, length, lap structure and that every recording has the
    same kind of inputs (InputError naming the file)."""
    if not runs:
        raise InputError("diagnose: no recording given")
    kinds = input_kinds(runs[0])
    mode = longitudinal_input(kinds)
    for r in runs[1:]:
        k = input_kinds(r)
        if longitudinal_input(k) != mode or k.get("delta") != kinds.get("delta"):
            raise InputError(f"{r.source}: inputs {k} differ from {runs[0].source}'s {kinds}; "
                             "diagnose recordings with the same kind of inputs together")
    dts = [r.dt for r in runs]
    dt = float(dts[0])
    for r, d in zip(runs, dts):
        if not (dt * 0.98 < d < dt * 1.02):
            raise InputError(f"{r.source}: sample period {d:.4g} s differs from {runs[0].source} ({dt:.4g} s)")
    total = sum(r.n for r in runs)
    if total < min_samples:
        raise InputError(
            f"{runs[0].source if len(runs) == 1 else 'recordings'}: {total} samples "
            f"({total * dt:.1f} s); diagnosis needs at least {min_samples} ({min_samples * dt:.0f} s)"
        )
    Ys, Us, As, ks, recs, laps, ts, Ls, tabs_s, tabs_k = [], [], [], [], [], [], [], [], [], []
    lap0 = 0
    for i, r in enumerate(runs):
        Y, U = r.states(), r.inputs()
        As.append(U[:, 1].copy())
        if mode == "speed":
            U[:, 1] = r["v_cmd"]
        s = Y[:, State.S]
        ds = np.diff(s)
        wraps = np.flatnonzero(ds < -0.5 * max(np.ptp(s), 1e-9))
        meta_L = r.meta.get("track_length") if isinstance(r.meta, dict) else None
        if len(wraps):
            sdot = np.median(np.abs(ds[ds > 0])) if np.any(ds > 0) else 0.0
            L = float(np.median(s[wraps] - s[wraps + 1] + sdot))
            if meta_L:
                L = float(meta_L)
            lap = np.concatenate([[0], np.cumsum(ds < -0.5 * np.ptp(s))])
        else:
            L = float(meta_L) if meta_L else np.inf
            lap = np.zeros(len(s), dtype=int)
        Ys.append(Y), Us.append(U), ks.append(r["kappa"]), recs.append(np.full(len(s), i))
        laps.append(lap + lap0)
        lap0 += int(lap.max()) + 1
        ts.append(r["t"] - r["t"][0] + (ts[-1][-1] + 1e3 if ts else 0.0))
        Ls.append(L)
        o = np.argsort(s)
        ss, kk = s[o], r["kappa"][o]
        if np.isfinite(L):
            ss = np.concatenate([ss - L, ss, ss + L])
            kk = np.concatenate([kk, kk, kk])
        tabs_s.append(ss + i * _OFFSET)
        tabs_k.append(kk)
    ds = Dataset(
        Y=np.vstack(Ys), U=np.vstack(Us), kappa=np.concatenate(ks), rec=np.concatenate(recs),
        lap=np.concatenate(laps), t=np.concatenate(ts), dt=dt, L=np.asarray(Ls, dtype=float),
        sources=[r.source for r in runs], A=np.concatenate(As), inputs=kinds, longitudinal=mode,
    )
    ds.ks, ds.kv = np.concatenate(tabs_s), np.concatenate(tabs_k)
    return ds


def model_for(vehicle, data: Dataset, effects=()) -> NominalModel:
    """The vehicle's model driven by the recordings' inputs as they are (``data.longitudinal``)."""
    return NominalModel(vehicle, list(effects), data.longitudinal)


# --------------------------------------------------------------------------------------------
# prediction


def lag_commands(model: NominalModel, data: Dataset) -> np.ndarray:
    """(n, 2) what each actuator lag delays at every sample: the road-wheel angle commanded
    (steering gain and offset applied) and the a_x commanded (a speed command through the speed
    loop, at the recorded speed)."""
    p = model.params
    C = data.U.astype(float, copy=True)
    C[:, 0] = p.steer_gain * C[:, 0] + p.steer_offset
    if p.longitudinal == "speed":
        C[:, 1] = (p.speed_gain * C[:, 1] - data.Y[:, State.V_X]) / p.speed_tau
    return C


def lag_states(model: NominalModel, data: Dataset) -> np.ndarray:
    """Actuator-lag states at every sample: the command history through each lag (exact ZOH)."""
    from scipy.signal import lfilter

    cols = []
    cmd = None
    for e in model.effects:
        if not e.n_states:
            continue
        idx = LAG_INPUT.get(e.name)
        if idx is None or e.n_states != 1:  # unknown stateful effect: start at its default
            cols.append(e.initial_states(data.U))
            continue
        if cmd is None:
            cmd = lag_commands(model, data)
        a = float(np.exp(-data.dt / e.values["tau"]))
        z = np.empty(data.n)
        for r in np.unique(data.rec):
            m = np.flatnonzero(data.rec == r)
            u = cmd[m, idx]
            # z[k+1] = a z[k] + (1-a) u[k], z[0] = u[0]
            y, _ = lfilter([0.0, 1.0 - a], [1.0, -a], u, zi=[u[0]])
            z[m] = y
        cols.append(z[:, None])
    if not cols:
        return np.zeros((data.n, 0))
    return np.hstack(cols)


def initial_states(model: NominalModel, Y0: np.ndarray, Z0: np.ndarray) -> np.ndarray:
    """Model states from measurements: additive sensor offsets removed, effect states appended."""
    X = np.hstack([Y0, Z0]) if model.nx > 6 else Y0.copy()
    if any(type(e).measure is not Effect.measure for e in model.effects):
        off = model.measure(X) - X[:, :6]
        X[:, :6] = X[:, :6] - off
    return X


def predict(model: NominalModel, data: Dataset, starts: np.ndarray, H: int, substeps: int = 2,
            Y0: np.ndarray | None = None, Z: np.ndarray | None = None, Z0: np.ndarray | None = None) -> np.ndarray:
    """Measured predictions ``(m, H, 6)`` of windows starting at ``starts`` (batch over windows).

    ``Z`` (n, nz) are effect states at every sample, ``Z0`` (m, nz) at the window starts (for a
    batch whose windows carry different effect parameters); by default from the command history.
    A window slower than RK4 with ``substeps`` can integrate stably at this period gets more
    substeps (:func:`stiff_substeps`); the others are computed exactly as asked.
    """
    Y0 = data.Y[starts] if Y0 is None else Y0
    if Z0 is None:
        if Z is None:
            Z = lag_states(model, data) if model.nx > 6 else np.zeros((data.n, 0))
        Z0 = Z[starts]
    sub = np.maximum(stiff_substeps(model, data, starts, H), substeps)
    if np.all(sub == substeps):
        return _predict(model, data, starts, H, substeps, Y0, Z0)
    out = np.empty((len(starts), H, 6))
    for k in np.unique(sub):  # a few groups: the slow windows get the substeps they need
        idx = np.flatnonzero(sub == k)
        out[idx] = _predict(_subset(model, idx, len(starts)), data, starts[idx], H, int(k), Y0[idx], Z0[idx])
    return out


STIFF_H_LAMBDA = 2.0
"""RK4 step times the fastest lateral eigenvalue kept below this (RK4 is stable to 2.78 on the
negative real axis): a stiff car at walking pace needs more than one substep per sample."""
MAX_SUBSTEPS = 16


def stiff_substeps(model: NominalModel, data: Dataset, starts: np.ndarray, H: int) -> np.ndarray:
    """(m,) RK4 substeps each window needs for a stable lateral integration at its slowest speed.

    The linearised lateral dynamics' fastest rate is bounded by the trace of their Jacobian,
    ``(C_f + C_r)/(m v) + (l_f^2 C_f + l_r^2 C_r)/(I_z v)`` with the axles' cornering stiffness
    ``C = mu F_z B C`` (1:10 car, 2 m/s: 55/s; a 790 kg car on race tires at 1.6 m/s: 200/s)."""
    p = model.params
    cf = p.mu * p.fz_front * p.bf * p.cf
    cr = p.mu * p.fz_rear * p.br * p.cr
    idx = np.minimum(starts[:, None] + np.arange(H + 1)[None, :], data.n - 1)
    v = np.maximum(np.abs(data.Y[idx, State.V_X]).min(axis=1), p.vmin)
    lam = (cf + cr) / (p.m * v) + (p.lf**2 * cf + p.lr**2 * cr) / (p.iz * v)
    return np.clip(np.ceil(lam * data.dt / STIFF_H_LAMBDA), 1, MAX_SUBSTEPS).astype(int)


def _subset(model: NominalModel, idx: np.ndarray, m: int) -> NominalModel:
    """A copy of ``model`` whose per-window parameter arrays (of length ``m``) keep ``idx``."""
    import copy
    from dataclasses import fields, replace

    def cut(v):
        return v[idx] if isinstance(v, np.ndarray) and v.shape == (m,) else v

    out = copy.copy(model)
    out.params = replace(model.params, **{f.name: cut(getattr(model.params, f.name)) for f in fields(model.params)})
    effects = []
    for e in model.effects:
        e2 = copy.copy(e)
        e2.values = {k: cut(v) for k, v in e.values.items()}
        for k, v in vars(e).items():  # per-window state of a fitting device (a batched profile's sets)
            if k != "values":
                setattr(e2, k, cut(v))
        effects.append(e2)
    out.effects = effects
    return out


COMPILED = True
"""Predict with the compiled kernel (:mod:`gprace.diagnose.fastpredict`) where it runs the model;
False: numpy everywhere (the reference, for tests)."""


def _compiled_states(model: NominalModel, data: Dataset, starts: np.ndarray, H: int, substeps: int,
                     X0: np.ndarray) -> np.ndarray | None:
    if not COMPILED:
        return None
    from gprace.diagnose.fastpredict import predict_states

    return predict_states(model, data, starts, H, substeps, X0, _OFFSET)


def _measured(model: NominalModel, S: np.ndarray) -> np.ndarray:
    """Measured channels (m, H, 6) of model states (m, H, nx)."""
    if not any(type(e).measure is not Effect.measure for e in model.effects):
        return S[..., :6]
    m, H = S.shape[:2]
    # all horizon steps in one call: sensor parameters given per window repeat over its steps
    flat = _subset(model, np.repeat(np.arange(m), H), m) if m > 1 else model
    return flat.measure(S.reshape(m * H, -1)).reshape(m, H, 6)


def _predict(model: NominalModel, data: Dataset, starts: np.ndarray, H: int, substeps: int,
             Y0: np.ndarray, Z0: np.ndarray) -> np.ndarray:
    X = initial_states(model, Y0, Z0)
    S = _compiled_states(model, data, starts, H, substeps, X)
    if S is not None:
        return _measured(model, S)
    X = X.T.copy()  # (nx, m): rows contiguous for the hot loop
    kfun = _kappa_lookup(data, data.rec[starts])
    UT = data.U.T
    sensor = any(type(e).measure is not Effect.measure for e in model.effects)
    out = np.empty((len(starts), H, 6))
    for j in range(H):
        X = rk4_batch(model, X, UT[:, starts + j], kfun, data.dt, substeps)
        out[:, j] = model.measure(X.T) if sensor else X[:6].T
    return out


def _kappa_lookup(data: Dataset, rec: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """``kappa(s)`` for a batch of windows of recordings ``rec`` (the same values as
    :meth:`Dataset.kappa_at`, with the per-window table offsets computed once)."""
    L = data.L[rec]
    off = rec * _OFFSET
    fin = np.isfinite(L)
    if fin.all():
        return lambda s: np.interp(np.mod(s, L) + off, data.ks, data.kv)
    Lr = np.where(fin, L, 1.0)
    return lambda s: np.interp(np.where(fin, np.mod(s, Lr), s) + off, data.ks, data.kv)


def _deriv(model: NominalModel, X: np.ndarray, U: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """``dX/dt`` of states stored as rows ``(nx, m)``, inputs ``(2, m)``: the model's own
    :func:`~gprace.model.dynamics.dynamics` without the per-call reshaping of
    :meth:`NominalModel.f` (this is the innermost call of every fit: thousands per diagnosis)."""
    out = dynamics(list(X), list(U), kappa, model.params, model.effects, NP)
    D = np.empty_like(X)
    for i, o in enumerate(out):
        D[i] = o
    return D


def rk4_batch(model: NominalModel, X: np.ndarray, U: np.ndarray, kfun: Callable[[np.ndarray], np.ndarray],
              dt: float, substeps: int) -> np.ndarray:
    """:meth:`NominalModel.rk4` (same stages, same arithmetic) on states stored as rows ``(nx, m)``."""
    h = dt / substeps
    for _ in range(substeps):
        k1 = _deriv(model, X, U, kfun(X[State.S]))
        x2 = X + 0.5 * h * k1
        k2 = _deriv(model, x2, U, kfun(x2[State.S]))
        x3 = X + 0.5 * h * k2
        k3 = _deriv(model, x3, U, kfun(x3[State.S]))
        x4 = X + h * k3
        k4 = _deriv(model, x4, U, kfun(x4[State.S]))
        X = X + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return X


def errors(data: Dataset, starts: np.ndarray, pred: np.ndarray, target: np.ndarray | None = None) -> np.ndarray:
    """Measured minus predicted, ``(m, H, 6)``; ``s`` differences wrapped to the lap."""
    H = pred.shape[1]
    if target is None:
        target = data.Y[starts[:, None] + np.arange(1, H + 1)[None, :]]
    E = target - pred
    L = data.L[data.rec[starts]][:, None]
    fin = np.isfinite(L)
    Ls = np.where(fin, L, 1.0)
    S = State.S
    E[..., S] = np.where(fin, (E[..., S] + 0.5 * Ls) % Ls - 0.5 * Ls, E[..., S])
    return E


# --------------------------------------------------------------------------------------------
# noise estimate and noise twin


def _robust_std(a: np.ndarray, axis=0) -> np.ndarray:
    med = np.median(a, axis=axis)
    return 1.4826 * np.median(np.abs(a - med), axis=axis)


def one_step_spread(model: NominalModel, data: Dataset, starts: np.ndarray, substeps: int,
                    Y: np.ndarray | None = None, target: np.ndarray | None = None) -> np.ndarray:
    pred = predict(model, data, starts, 1, substeps, Y0=None if Y is None else Y)
    E = errors(data, starts, pred, None if target is None else target)
    return _robust_std(E[:, 0, :])


@dataclass
class Twin:
    """Synthetic recordings of the model itself with the estimated noise ("noise twin")."""

    Y0: np.ndarray  # (R, m, 6) initial measurement of each window, per realisation
    T: np.ndarray  # (R, m, H, 6) measured targets


def make_twin(model: NominalModel, data: Dataset, starts: np.ndarray, H: int, sigma: np.ndarray,
              realisations: int = 2, seed: int = 0, seg: int | None = None, fine: int = 10) -> Twin:
    """Simulate the model (fine RK4, as a plant would) over segments of the recorded inputs.

    Each segment starts at a recorded state and is driven by the recorded commands; the twin's
    measurements are its states plus white noise of standard deviation ``sigma``. Windows are
    then cut from the twin exactly where they are cut from the data.
    """
    seg = seg or 4 * H
    rng = np.random.default_rng(seed)
    # segment anchors: the window start rounded down to a multiple of seg within its recording
    rec = data.rec[starts]
    first = np.zeros(len(data.L), dtype=int)
    for r in range(len(data.L)):
        first[r] = np.flatnonzero(data.rec == r)[0]
    off = starts - first[rec]
    anchor = first[rec] + (off // seg) * seg
    anchors, inv = np.unique(anchor, return_inverse=True)
    steps = seg + H
    N = data.n
    Z = lag_states(model, data) if model.nx > 6 else np.zeros((N, 0))
    X = initial_states(model, data.Y[anchors], Z[anchors])
    traj = np.empty((len(anchors), steps + 1, 6))
    traj[:, 0] = model.measure(X)
    S = _compiled_states(model, data, anchors, steps, fine, X)
    if S is not None:
        traj[:, 1:] = _measured(model, S)
    else:
        X = X.T.copy()
        kfun = _kappa_lookup(data, data.rec[anchors])
        for j in range(steps):
            idx = np.minimum(anchors + j, N - 1)
            X = rk4_batch(model, X, data.U.T[:, idx], kfun, data.dt, fine)
            traj[:, j + 1] = model.measure(X.T)
    pos = starts - anchors[inv]
    Y0s, Ts = [], []
    for _ in range(realisations):
        noisy = traj + sigma * rng.standard_normal(traj.shape)
        Y0s.append(noisy[inv, pos])
        Ts.append(noisy[inv[:, None], pos[:, None] + np.arange(1, H + 1)[None, :]])
    return Twin(np.stack(Y0s), np.stack(Ts))


def twin_errors(model: NominalModel, data: Dataset, starts: np.ndarray, twin: Twin, substeps: int) -> np.ndarray:
    """Multi-step errors of the model on its twin, ``(R, m, H, 6)``."""
    H = twin.T.shape[2]
    out = []
    for r in range(twin.Y0.shape[0]):
        pred = predict(model, data, starts, H, substeps, Y0=twin.Y0[r])
        out.append(errors(data, starts, pred, twin.T[r]))
    return np.stack(out)


def estimate_noise(model: NominalModel, data: Dataset, starts: np.ndarray, H: int, substeps: int,
                   iterations: int = 2, seed: int = 0) -> np.ndarray:
    """Sensor-noise standard deviation per channel, calibrated so the twin's one-step spread
    matches the data's (robust spread, so localised structured error barely moves it)."""
    target = one_step_spread(model, data, starts, substeps)
    sigma = target / np.sqrt(2.0)
    sub = starts[:: max(1, len(starts) // 3000)]
    for _ in range(iterations):
        tw = make_twin(model, data, sub, 1, sigma, realisations=1, seed=seed + 17)
        pred = predict(model, data, sub, 1, substeps, Y0=tw.Y0[0])
        E = errors(data, sub, pred, tw.T[0])
        got = _robust_std(E[:, 0, :])
        sigma = sigma * np.where(got > 0, target / np.maximum(got, 1e-12), 1.0)
    return sigma


# --------------------------------------------------------------------------------------------
# fitting


def batched_least_squares(batch: Callable[[list[np.ndarray]], np.ndarray], x0: np.ndarray, lo: np.ndarray,
                          hi: np.ndarray, x_scale: np.ndarray, max_nfev: int, step: float | None = None,
                          ftol: float = 1e-8):
    """Bounded least squares (scipy's trust-region reflective) of the residual vector
    ``batch([x])[0]``, where ``batch(X)`` evaluates ``k`` parameter vectors in ONE call (``(k, n)``).

    The Jacobian is scipy's forward difference ('2-point' steps, one-sided inside the bounds) with
    every parameter's step in the same batch, and it reuses the residuals ``fun`` has just
    evaluated at that point: a Jacobian costs one model evaluation, not one per parameter.
    ``ftol``: scipy's relative stop on the cost. Returns scipy's ``OptimizeResult``.
    """
    from scipy.optimize import least_squares

    step = float(np.sqrt(np.finfo(float).eps)) if step is None else step
    last: dict = {}  # least_squares asks for fun(x), then jac(x) at the same x

    def fun(x):
        r = batch([x])[0]
        last.update(x=np.array(x, copy=True), r=r)
        return r

    def jac(x):
        sign = np.where(x >= 0, 1.0, -1.0)
        h = step * sign * np.maximum(1.0, np.abs(x))
        h = np.where((x + h > hi) | (x + h < lo), -h, h)
        h = (x + h) - x
        steps = [x + np.eye(len(x))[i] * h[i] for i in range(len(x))]
        if "x" in last and np.array_equal(last["x"], x):
            R0, R = last["r"], batch(steps)
        else:
            R = batch([x] + steps)
            R0, R = R[0], R[1:]
        return ((R - R0) / h[:, None]).T

    x0 = np.clip(np.asarray(x0, dtype=float), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    return least_squares(fun, x0, jac=jac, bounds=(lo, hi), x_scale=x_scale, method="trf", max_nfev=max_nfev,
                         ftol=ftol)
