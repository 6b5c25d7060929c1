"""Named feature maps: recordings -> GP inputs ``Z`` and outputs ``Y`` (paper, "GP Model").

- ``tracking``: ``z`` = a named dynamics feature set at sample ``k`` (``DYN_FEATURE_SETS``:
  ``paper`` = ``[v_y, yaw_rate, delta]`` as in the paper, ``full`` = ``[v_x, v_y, yaw_rate,
  delta, a_x]``, the default); ``y`` = one-step error of
  ``[v_y, yaw_rate]``: the measured ``x_{k+1}`` minus the nominal model's step from
  ``(x_k, u_k, kappa_k)`` (the paper's Euler step ``x + f(x, u) dt`` by default; ``step="rk4"``
  matches an MPC that predicts with RK4).
- ``planning``: same ``z``; ``y`` = error of the derivatives, ``(x_{k+1} - x_k) / dt - f(x_k, u_k)``
  for the Euler step (in general: the tracking error divided by ``dt``), in the units of the
  planner's continuous dynamics.
- ``opponent`` (docs/reference.md#head-to-head, Zhu et al. 2022): ``z = [e_y_ego - e_y_opp, e_psi_ego, v_x_ego,
  s_opp - s_ego, e_y_opp, e_psi_opp, v_x_opp, yaw_rate_opp, kappa(s_opp), kappa(s_opp + 0.5),
  kappa(s_opp + 1.0)]``; ``y`` = one-step change of the opponent's ``[s, e_y, e_psi, v_x,
  yaw_rate]``. Arc-length differences are wrapped into ``[-L/2, L/2)`` on closed tracks, so the
  lap line does not produce a jump of ``-L``.

Sample pairs ``(k, k+1)`` whose time step differs from the run's period by more than 1% (gaps,
concatenated recordings) are dropped. Effects with internal states in the nominal vehicle
(actuator lags) start each step at their steady state for the recorded command; sensor effects
are not applied (the recording is the measurement).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from gprace.errors import InputError

DYN_INPUTS = ("v_y", "yaw_rate", "delta")  # the paper's feature set
# Named feature sets of the tracking and planning GPs. ``full`` adds the longitudinal speed and
# command: with the paper's three inputs braking and driving alias (docs/decisions.md, "Time
# trial"), as in Kabzan et al. 2019 and Hewing et al. 2019 the GP needs v_x and a_x to tell them apart.
DYN_FEATURE_SETS: dict[str, tuple[str, ...]] = {
    "paper": DYN_INPUTS,
    "full": ("v_x", "v_y", "yaw_rate", "delta", "a_x"),
}
DEFAULT_DYN_FEATURES = "full"
#: outputs of the time trial's two GPs (targets: :mod:`gprace.timetrial.learning`)
DYN_OUTPUTS: dict[str, list[str]] = {"tracking": ["v_y", "yaw_rate"], "planning": ["dv_y_dt", "dyaw_rate_dt"]}
# where each feature lives: ("x", state index) or ("u", input index)
_DYN_SOURCE = {"v_x": ("x", 0), "v_y": ("x", 1), "yaw_rate": ("x", 2), "delta": ("u", 0), "a_x": ("u", 1)}
OPPONENT_INPUTS = (
    "ey_ego_minus_ey_opp", "epsi_ego", "vx_ego", "s_opp_minus_s_ego", "ey_opp", "epsi_opp",
    "vx_opp", "yaw_rate_opp", "kappa_opp_0", "kappa_opp_0.5", "kappa_opp_1.0",
)
OPPONENT_OUTPUTS = ("ds_opp", "dey_opp", "depsi_opp", "dvx_opp", "dyaw_rate_opp")
OPPONENT_LOOKAHEAD = (0.0, 0.5, 1.0)
_OPP_STATE_COLS = ("s", "e_y", "e_psi", "v_x", "yaw_rate")


@dataclass(frozen=True)
class FeatureMap:
    """A named map with its input and output names (stored with datasets and models)."""

    name: str
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    doc: str


FEATURE_MAPS: dict[str, FeatureMap] = {
    "tracking": FeatureMap("tracking", DYN_INPUTS, ("v_y", "yaw_rate"),
                           "one-step errors of v_y [m/s] and yaw_rate [rad/s] against the nominal step"),
    "planning": FeatureMap("planning", DYN_INPUTS, ("dv_y_dt", "dyaw_rate_dt"),
                           "errors of d v_y/dt [m/s^2] and d yaw_rate/dt [rad/s^2] against the nominal model"),
    "opponent": FeatureMap("opponent", OPPONENT_INPUTS, OPPONENT_OUTPUTS,
                           "one-step change of the opponent's s, e_y, e_psi, v_x, yaw_rate"),
}


def dyn_feature_set(name: str) -> tuple[str, ...]:
    """Input names of a named dynamics feature set; ConfigError naming the valid ones."""
    try:
        return DYN_FEATURE_SETS[name]
    except KeyError:
        from gprace.errors import ConfigError

        raise ConfigError(f"unknown feature set {name!r}; available: {', '.join(DYN_FEATURE_SETS)}") from None


def dyn_set_of(names) -> str:
    """The name of the feature set with these input names; InputError if none has them."""
    names = tuple(names)
    for k, v in DYN_FEATURE_SETS.items():
        if v == names:
            return k
    raise InputError(f"GP inputs {list(names)} are no known feature set ({', '.join(f'{k}: {list(v)}' for k, v in DYN_FEATURE_SETS.items())})")


def dyn_inputs(X: np.ndarray, U: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """GP inputs ``(n, len(names))`` from states ``X (n, >=6)`` and inputs ``U (n, 2)`` (vectorised)."""
    src = {"x": X, "u": U}
    return np.column_stack([src[_DYN_SOURCE[c][0]][:, _DYN_SOURCE[c][1]] for c in names])


def feature_map(name: str) -> FeatureMap:
    try:
        return FEATURE_MAPS[name]
    except KeyError:
        from gprace.errors import ConfigError

        raise ConfigError(f"unknown GP feature map {name!r}; available: {', '.join(FEATURE_MAPS)}") from None


def _regular_pairs(t: np.ndarray, dt: float) -> np.ndarray:
    """Mask over k of pairs (k, k+1) spaced by the run period (within 1%)."""
    return np.abs(np.diff(t) - dt) <= 0.01 * dt


def nominal_step(model, X6: np.ndarray, U: np.ndarray, kappa: np.ndarray, dt: float, step: str = "euler") -> np.ndarray:
    """The nominal model's one-step prediction ``(n, 6)`` from recorded states ``X6 (n, 6)``."""
    X = model.initial_state(X6, U) if getattr(model, "nx", 6) > 6 else X6
    if step == "euler":
        Xn = model.euler(X, U, kappa, dt)
    elif step == "rk4":
        Xn = model.rk4(X, U, kappa, dt)
    else:
        from gprace.errors import ConfigError

        raise ConfigError(f"unknown step {step!r}; available: euler, rk4")
    return np.asarray(Xn)[:, :6]


def dynamics_features(run, model, kind: str = "tracking", step: str = "euler",
                      features: str = "paper", keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``Z (n, d)``, ``Y (n, 2)`` of one run for the ``tracking`` or ``planning`` map.

    ``run`` is a :class:`gprace.io.runs.Run`; ``model`` a :class:`gprace.model.NominalModel`
    (or anything with ``euler``/``rk4``/``initial_state``). Curvature is the run's ``kappa``
    column, the period ``run.dt``. ``keep`` (n,) bool: only pairs of two kept samples are used
    (the envelope mask of :func:`gprace.io.envelope.envelope`).
    """
    if kind not in ("tracking", "planning"):
        raise InputError(f"feature map {kind!r} is not a single-car map; use tracking or planning")
    names = dyn_feature_set(features)
    X, U = run.states(), run.inputs()
    dt = run.dt
    ok = _regular_pairs(run["t"], dt)
    if keep is not None:
        ok &= keep[:-1] & keep[1:]
    if not ok.any():
        return np.zeros((0, len(names))), np.zeros((0, 2))
    x0, u0, x1, kap = X[:-1][ok], U[:-1][ok], X[1:][ok], run["kappa"][:-1][ok]
    pred = nominal_step(model, x0, u0, kap, dt, step)
    Y = (x1 - pred)[:, 1:3]
    if kind == "planning":
        Y = Y / dt
    Z = dyn_inputs(x0, u0, names)
    good = np.all(np.isfinite(Z), axis=1) & np.all(np.isfinite(Y), axis=1)
    return Z[good], Y[good]


def wrap_ds(ds: np.ndarray, length: float | None) -> np.ndarray:
    """Arc-length differences wrapped into ``[-L/2, L/2)`` (unchanged when ``length`` is None)."""
    ds = np.asarray(ds, dtype=float)
    if not length:
        return ds
    return (ds + 0.5 * length) % length - 0.5 * length


def _cols(x: Any, what: str) -> dict[str, np.ndarray]:
    data = x.data if hasattr(x, "data") and isinstance(getattr(x, "data"), Mapping) else x
    try:
        return {c: np.asarray(data[c], dtype=float) for c in _OPP_STATE_COLS}
    except KeyError as exc:
        raise InputError(f"opponent features: {what} has no column {exc.args[0]!r}") from None


def opponent_inputs(ego: Mapping[str, np.ndarray], opp: Mapping[str, np.ndarray],
                    kappa: Callable[[np.ndarray], np.ndarray], length: float | None = None) -> np.ndarray:
    """GP inputs ``(n, 11)`` from aligned ego/opponent columns (``s, e_y, e_psi, v_x, yaw_rate``).

    ``kappa(s)`` is the track curvature (vectorised; periodic on a closed track); ``length`` is
    the lap length of a closed track (None for an open one).
    """
    s_o = opp["s"]
    look = [kappa(s_o + d if not length else np.mod(s_o + d, length)) for d in OPPONENT_LOOKAHEAD]
    return np.column_stack([
        ego["e_y"] - opp["e_y"], ego["e_psi"], ego["v_x"], wrap_ds(s_o - ego["s"], length),
        opp["e_y"], opp["e_psi"], opp["v_x"], opp["yaw_rate"], *look,
    ])


def opponent_features(ego: Any, opp: Any, kappa: Callable[[np.ndarray], np.ndarray],
                      length: float | None = None, t: np.ndarray | None = None,
                      dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``Z (n-1, 11)``, ``Y (n-1, 5)`` of the ``opponent`` map from two aligned recordings.

    ``ego`` and ``opp`` are :class:`~gprace.io.runs.Run` objects or mappings of equal-length
    arrays with columns ``s, e_y, e_psi, v_x, yaw_rate`` sampled at the same instants. ``kappa``
    and ``length`` describe the track (``track.kappa``, ``track.length`` if ``track.closed`` else
    None). With ``t`` (and optionally ``dt``, default its median step) pairs across gaps are
    dropped. ``Y`` is the change from sample ``k`` to ``k+1`` of the opponent's
    ``[s, e_y, e_psi, v_x, yaw_rate]``, with ``s`` wrapped at the lap line.
    """
    e, o = _cols(ego, "ego"), _cols(opp, "opponent")
    n = len(o["s"])
    if len(e["s"]) != n:
        raise InputError(f"opponent features: ego has {len(e['s'])} samples, opponent {n}; they must be aligned")
    if n < 2:
        return np.zeros((0, 11)), np.zeros((0, 5))
    if t is None and hasattr(opp, "data") and "t" in opp.data:
        t = opp.data["t"]
    ok = np.ones(n - 1, dtype=bool)
    if t is not None:
        t = np.asarray(t, dtype=float)
        ok = _regular_pairs(t, float(dt) if dt else float(np.median(np.diff(t))))
    Z = opponent_inputs({k: v[:-1] for k, v in e.items()}, {k: v[:-1] for k, v in o.items()}, kappa, length)
    Y = np.column_stack([np.diff(o[c]) for c in _OPP_STATE_COLS])
    Y[:, 0] = wrap_ds(Y[:, 0], length)
    good = ok & np.all(np.isfinite(Z), axis=1) & np.all(np.isfinite(Y), axis=1)
    return Z[good], Y[good]


def run_features(run, kind: str, vehicle=None, step: str = "euler", features: str = "paper",
                 keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Features of one recording for ``tracking`` or ``planning``; the nominal vehicle comes
    from ``vehicle`` (a VehicleConfig) or the run itself (InputError if neither); ``keep`` as in
    :func:`dynamics_features`."""
    from gprace.model import NominalModel

    veh = vehicle if vehicle is not None else run.vehicle()
    if veh is None:
        raise InputError(f"{run.source}: the recording carries no nominal vehicle; pass --vehicle VEHICLE.toml")
    return dynamics_features(run, NominalModel(veh), kind, step, features, keep)
