"""Opponent predictors behind one interface: GP (sampled rollouts), constant velocity, oracle.

``predictor.predict(ctx) -> Prediction`` with ``mean`` (K, 6) predicted opponent Frenet states at
steps 1..K (same layout as the car state; quantities a predictor does not model are held) and
``std`` (K, 2): standard deviations of ``s`` and ``e_y`` in metres (they inflate the ego's ellipses).

GP opponent model (docs/reference.md#head-to-head, Zhu et al. 2022): inputs ``z`` = :data:`FEATURES`, outputs the
one-step change of the opponent's ``[s, e_y, e_psi, v_x, yaw_rate]``. Multi-step prediction draws
``n`` sample paths: at every step each sample gets one draw ``mean + sqrt(var) * eps`` from the GP
(latent variance), with the curvature features recomputed at the sample's own ``s`` and the ego part
of the input taken from the ego's plan at that step. All samples go through one ``predict`` call
per step (no Python loop over samples). The means are each sample's own; the variance of a step is
the GP's at the samples' mean input, shared by all samples: the exact GP's per-sample variance is
a triangular solve against every point (64 % of a 600-point rollout), and on the default
protocol's evaluation races the shared variance gave a 9-step e_y spread 0.98 times the
per-sample one (5 to 95 %: 0.94 to 1.00) and the same error (docs/decisions.md).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gprace.errors import InputError, UnknownBackendError
from gprace.model.dynamics import State

FEATURES = (
    "ey_ego_minus_ey_opp", "epsi_ego", "vx_ego", "s_opp_minus_s_ego", "ey_opp", "epsi_opp",
    "vx_opp", "yaw_rate_opp", "kappa_opp_0", "kappa_opp_0.5", "kappa_opp_1.0",
)
OUTPUTS = ("ds_opp", "dey_opp", "depsi_opp", "dvx_opp", "dyaw_rate_opp")
OUT_STATE = (State.S, State.E_Y, State.E_PSI, State.V_X, State.YAW_RATE)  # state index of each output
LOOKAHEAD = (0.0, 0.5, 1.0)
_LOOKAHEAD = np.asarray(LOOKAHEAD)
_OPP_FEATURES = np.array([State.E_Y, State.E_PSI, State.V_X, State.YAW_RATE])  # the opponent's own features (an index array: no enum conversion per call)
CONTROLLABLE = (0, 3)  # gap in e_y and gap in s: the features the ego can steer
FEATURE_MAP = "opponent"


def gap_s(track, s_opp, s_ego):
    """``s_opp - s_ego``, wrapped to (-L/2, L/2] on a closed track."""
    d = np.asarray(s_opp, float) - np.asarray(s_ego, float)
    if track.closed:
        d = (d + 0.5 * track.length) % track.length - 0.5 * track.length
    return d


def features(track, ego: np.ndarray, opp: np.ndarray) -> np.ndarray:
    """GP inputs (n, 11) from ego states (n, 6) or (6,) and opponent states (n, 6)."""
    opp = np.atleast_2d(opp)
    ego = np.broadcast_to(ego, opp.shape)
    s_o = opp[:, State.S]
    Z = np.empty((opp.shape[0], len(FEATURES)))
    np.subtract(ego[:, State.E_Y], opp[:, State.E_Y], out=Z[:, 0])
    Z[:, 1], Z[:, 2], Z[:, 3] = ego[:, State.E_PSI], ego[:, State.V_X], gap_s(track, s_o, ego[:, State.S])
    Z[:, 4:8] = opp[:, _OPP_FEATURES]
    Z[:, 8:] = track.kappa(s_o[:, None] + _LOOKAHEAD)  # (n, 3): one spline call (kappa wraps s itself)
    return Z


def training_pairs(track, ego: np.ndarray, opp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Z, Y) from closed-loop trajectories (T+1, 6): features at t, opponent change t -> t+1."""
    Z = features(track, ego[:-1], opp[:-1])
    d = opp[1:] - opp[:-1]
    Y = d[:, list(OUT_STATE)]
    return Z, Y


@dataclass
class Prediction:
    mean: np.ndarray  # (K, 6)
    std: np.ndarray  # (K, 2): s, e_y (calibrated when the predictor carries a calibration)
    raw_std: np.ndarray | None = None  # (K, 2) the predictor's own spread before the calibration


def calibrated_std(std: np.ndarray, calibration: dict | None) -> np.ndarray:
    """``scale * std + floor`` per step and output (``calibration``: ``{"scale", "floor"}``, each
    (K, 2), see :func:`gprace.h2h.spread.fit_calibration`); ``std`` itself without one."""
    if not calibration:
        return std
    K = std.shape[-2]  # std (..., K, 2)
    return np.asarray(calibration["scale"], float)[:K] * std + np.asarray(calibration["floor"], float)[:K]


@dataclass
class Context:
    track: object
    ego_plan: np.ndarray  # (>= K+1, 6), row 0 = current ego state
    opp: np.ndarray  # (6,) current opponent state
    opp_plan: np.ndarray | None = None  # (>= K+1, 6) the opponent's own plan (oracle only)


class Predictor:
    name = "predictor"
    calibration: dict | None = None  # set by make_predictor: the spread that covers the real error

    def __init__(self, steps: int) -> None:
        self.steps = steps

    def predict(self, ctx: Context) -> Prediction:  # pragma: no cover - interface
        raise NotImplementedError


class OraclePredictor(Predictor):
    """The opponent's true open-loop plan at this step (used to collect data)."""

    name = "oracle"

    def predict(self, ctx: Context) -> Prediction:
        if ctx.opp_plan is None:
            raise InputError("oracle predictor: the opponent's plan is not available")
        K = self.steps
        return Prediction(np.array(ctx.opp_plan[1:K + 1], float), np.zeros((K, 2)))


def cv_positions(track, x: np.ndarray, K: int, dt: float) -> np.ndarray:
    """(2, K, n): ``s`` and ``e_y`` at steps 1..K of states x (n, 6) with their Frenet rates held."""
    vx, vy, epsi, ey, s = (x[:, i] for i in (State.V_X, State.V_Y, State.E_PSI, State.E_Y, State.S))
    kap = track.kappa(track.wrap(s))
    sdot = (vx * np.cos(epsi) - vy * np.sin(epsi)) / (1.0 - kap * ey)
    eydot = vx * np.sin(epsi) + vy * np.cos(epsi)
    k = dt * np.arange(1, K + 1)[:, None]
    return np.stack([s[None, :] + k * sdot, ey[None, :] + k * eydot])


class ConstantVelocityPredictor(Predictor):
    """Frenet rates ``ds/dt`` and ``de_y/dt`` held at their current values."""

    name = "cv"

    def predict(self, ctx: Context) -> Prediction:
        """Without a calibration the spread is zero; with one it is the calibration's per-step
        floor (the typical error of this predictor, measured on held-out races)."""
        K, x = self.steps, np.asarray(ctx.opp, float)
        mean = np.tile(x, (K, 1))
        mean[:, State.S], mean[:, State.E_Y] = cv_positions(ctx.track, x[None], K, self.dt)[:, :, 0]  # (2, K) of the one state
        raw = np.zeros((K, 2))
        return Prediction(mean, calibrated_std(raw, self.calibration), raw)

    def __init__(self, steps: int, dt: float = 0.1) -> None:
        super().__init__(steps)
        self.dt = dt


class GPPredictor(Predictor):
    """Sampled multi-step rollouts of a GP opponent model."""

    name = "gp"

    def __init__(self, gp, steps: int, samples: int = 50, seed: int = 0, label: str = "gp") -> None:
        super().__init__(steps)
        self.gp = gp
        self.samples = samples
        self.rng = np.random.default_rng(seed)
        self.name = label

    def rollout(self, track, ego_plan: np.ndarray, opp: np.ndarray, eps: np.ndarray | None = None) -> np.ndarray:
        """Sample paths (n, K, 6); ``eps`` (K, n, 5) standard normal draws (drawn if None)."""
        K, n = self.steps, self.samples
        if eps is None:
            eps = self.rng.standard_normal((K, n, len(OUTPUTS)))
        return sample_paths(self.gp, track, np.asarray(ego_plan, float)[:K, None, :], np.asarray(opp, float)[None, :6], n, eps)

    def predict(self, ctx: Context) -> Prediction:
        paths = self.rollout(ctx.track, ctx.ego_plan, ctx.opp)
        # s stays unwrapped (continuous) on closed tracks, as in the simulation
        mean = paths.mean(axis=0)
        std = np.column_stack([paths[:, :, State.S].std(axis=0), paths[:, :, State.E_Y].std(axis=0)])
        return Prediction(mean, calibrated_std(std, self.calibration), std)


def sample_paths(gp, track, ego: np.ndarray, opp: np.ndarray, n: int, eps: np.ndarray,
                 compiled: bool = True) -> np.ndarray:
    """Sampled rollouts of ``G`` start states at once: ``n`` samples from each opponent state
    ``opp (G, 6)``, with the ego part of the input ``ego (K, G, 6)`` at steps 0..K-1 and standard
    normal draws ``eps (K, G n, 5)``; returns paths ``(G n, K, 6)``, the samples of start g in rows
    ``g n .. g n + n - 1``. Each sample's mean is its own; the variance of a step is the GP's at
    the mean input of the start's samples (see the module doc). At step 0 a start's samples share
    their state, so one prediction per start serves them all. ``compiled``: one call of
    :func:`gprace.h2h.fastroll.rollout` where it applies (the same values to rounding), this
    numpy loop otherwise."""
    if compiled:
        from gprace.h2h.fastroll import rollout

        paths = rollout(gp.kernel_form(), track, ego, opp, n, eps, _LOOKAHEAD, OUT_STATE)
        if paths is not None:
            return paths
    K, G = ego.shape[0], opp.shape[0]
    S = np.repeat(opp, n, axis=0)
    out = np.empty((G * n, K, 6))
    idx = list(OUT_STATE)
    for k in range(K):
        if k == 0:
            mu, var = gp.fast_predict(features(track, ego[0], opp))
            mu = np.repeat(mu, n, axis=0)
        else:
            Z = features(track, np.repeat(ego[k], n, axis=0), S)
            mu = gp.fast_mean(Z)
            var = gp.fast_predict(Z.reshape(G, n, -1).mean(axis=1))[1]
        S[:, idx] += mu + np.sqrt(np.maximum(np.repeat(var, n, axis=0), 0.0)) * eps[k]
        out[:, k] = S
    return out


# ----------------------------------------------------------------------------------------------
PREDICTORS = ("gp", "cv", "oracle")


def save_opponent_gp(path: str | Path, gp, meta: dict, config_hash: str = "", seed: int = 0) -> Path:
    """Write a fitted GP as a ``gp_model`` artifact with the opponent feature layout."""
    from gprace.gp import save_model

    layout = {"feature_map": FEATURE_MAP, "input_names": list(FEATURES), "output_names": list(OUTPUTS)}
    extra = {k: v for k, v in meta.items() if k not in layout}
    return save_model(path, gp, {**layout, **extra}, config_hash=config_hash, seed=seed)


def read_opponent_gp(path: str | Path):
    """(gp, attrs) of a saved GP; InputError naming the mismatch if the layout is not the opponent's."""
    from gprace.gp import load_model

    saved = load_model(path)
    names, outs = tuple(saved.input_names), tuple(saved.output_names)
    if names != FEATURES or outs != OUTPUTS:
        raise InputError(
            f"{path}: GP model has inputs {list(names)} and outputs {list(outs)}; the opponent "
            f"predictor needs the '{FEATURE_MAP}' layout inputs {list(FEATURES)} -> outputs {list(OUTPUTS)}"
        )
    return saved.gp, {"backend": saved.backend, **saved.attrs}


def load_opponent_gp(path: str | Path):
    """A saved GP with the opponent feature layout; InputError naming the mismatch otherwise."""
    return read_opponent_gp(path)[0]


def make_predictor(kind: str, steps: int, dt: float = 0.1, model: str | Path | None = None, samples: int = 50,
                   seed: int = 0, label: str | None = None, calibration: dict | None = None) -> Predictor:
    """A predictor; ``calibration`` (``{"scale", "floor"}``, (K, 2) each) maps its spread to one
    that covers the real error (gp and cv; the oracle's plan is the truth of the collection)."""
    if kind == "oracle":
        return OraclePredictor(steps)
    if kind == "cv":
        pred: Predictor = ConstantVelocityPredictor(steps, dt)
    elif kind == "gp":
        if model is None:
            raise InputError("gp predictor: needs a GP model file")
        pred = GPPredictor(_cached_gp(str(model)), steps, samples, seed, label or "gp")
    else:
        raise UnknownBackendError(f"unknown predictor {kind!r}; available: {', '.join(sorted(PREDICTORS))}")
    if calibration:
        for key in ("scale", "floor"):
            a = np.asarray(calibration.get(key), float)
            if a.ndim != 2 or a.shape[1] != 2 or len(a) < steps or not np.all(np.isfinite(a)) or np.any(a < 0):
                raise InputError(f"{kind} predictor: calibration {key!r} must be >= 0 with shape (>= {steps}, 2), "
                                 f"got {calibration.get(key)!r}")
        pred.calibration = calibration
    return pred


def _cached_gp(path: str):
    """The opponent GP of a model file, loaded once per file version (the last 8 files kept)."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{path}: no such GP model file")
    return _load_gp(str(p.resolve()), p.stat().st_mtime_ns)


@functools.lru_cache(maxsize=8)
def _load_gp(path: str, mtime_ns: int):
    return load_opponent_gp(path)
