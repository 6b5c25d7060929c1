"""Calibrate: fit the nominal parameters no team knows exactly, before naming missing physics.

A vehicle file holds figures a team published or guessed: cornering stiffness per axle, yaw
inertia, steering offset and ratio, drag, rolling resistance, the time constant of its speed
controller. Real recordings rarely match them exactly, and a mis-set stiffness leaves structured
error that no catalogue effect should be blamed for. So the diagnosis first fits these parameters
(issue 36), each inside stated physical bounds (:data:`PARAMS`), by the same multi-step
prediction error the naming uses, and only where the recordings identify them:

- every parameter the inputs allow is fitted jointly (bounded least squares, the Jacobian of all
  parameters in one batched model evaluation);
- its 95 % interval comes from the fit's Jacobian with a cluster (2-s block) sandwich covariance
  (overlapping windows correlate the residuals), computed in units of the parameter's prior
  spread (a uniform prior over its bounds, standard deviation ``(upper - lower)/sqrt(12)``) with a
  tiny ridge, so a direction the data do not see keeps its prior spread instead of vanishing;
- a parameter is *identified* when the data shrink that spread at least :data:`IDENTIFIED`-fold
  (its posterior-to-prior spread ratio is below ``1/IDENTIFIED``): cornering stiffness from the
  linear range, peak friction only where the tires reach their limit (in the linear range it trades
  off exactly with the stiffness), a drag only where the speed varies. The least identified one is
  fixed at its nominal value and the rest refitted, until every parameter left is identified.

Whether the calibration is *applied* is decided like a named effect: by its held-out gain over
the nominal model (cross-validated by lap), in :mod:`gprace.diagnose.diagnose`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gprace.config import G, K_POSSIBLE_MIN, MU_POSSIBLE, VehicleConfig
from gprace.diagnose.core import DYNAMIC, batched_least_squares, errors, lag_states, predict
from gprace.diagnose.locate import blocks
from gprace.model import State

IDENTIFIED = 5.0
"""A parameter is identified when the recordings shrink its prior spread at least this many times
(posterior sd below a fifth of the prior's: the data carry over 96 % of the information)."""
RIDGE = 1e-8
"""Ridge on the information matrix in prior units: an unseen direction keeps about its prior spread."""
MAX_NFEV = 40
RELEVANT = 0.01
"""A calibrated value counts as a finding (``changed``) when putting it back to nominal costs more
than this share of the noise floor's mean square (the naming's MIN_GAIN)."""


@dataclass(frozen=True)
class CalParam:
    """A nominal parameter the diagnosis may calibrate.

    Fitted coordinate: ``log`` of a factor on the nominal value (``relative``), ``log`` of the
    value (``log`` and not relative), or the value itself. Positive scale parameters are fitted on
    a log scale, so their prior over the bounds is log-uniform and a factor 2 weighs alike up and
    down. The car's speed loop is fitted as its *rate* ``1/tau_v`` and *authority* ``k_v/tau_v``
    (the acceleration per m/s of command), which the data separate far better than ``tau_v`` and
    ``k_v`` themselves (``a_x = authority v_cmd - rate v_x``)."""

    name: str  # key in the result
    field: str  # VehicleConfig field (dotted for the tire)
    unit: str
    description: str
    relative: bool  # bounds are factors on the nominal value
    log: bool  # fitted on a log scale
    lower: float
    upper: float
    needs: str  # "lateral" | "longitudinal" (force model on v_x) | "speed" (speed command)
    supersedes: str | None = None  # catalogue effect that only re-sets this parameter
    natural_lower: bool = False  # the lower bound is a physical limit (no drag), not a plausible range


PARAMS: tuple[CalParam, ...] = (
    CalParam("cornering_stiffness_front", "tire.b_front", "N/rad",
             "front axle's cornering stiffness mu F_z B C (the linear range's slope; written as B)", True, True,
             0.2, 5.0, "lateral", "cornering_stiffness"),
    CalParam("cornering_stiffness_rear", "tire.b_rear", "N/rad",
             "rear axle's cornering stiffness mu F_z B C (the linear range's slope; written as B)", True, True,
             0.2, 5.0, "lateral", "cornering_stiffness"),
    CalParam("steering_offset", "steering_offset", "rad",
             "offset of the road-wheel angle from the steering input", False, False, -0.1, 0.1, "lateral",
             "steering_offset"),
    CalParam("steering_gain", "steering_gain", "-",
             "road-wheel angle per unit of the steering input (steering ratio error)", False, True, 0.5, 2.0, "lateral"),
    CalParam("yaw_inertia", "yaw_inertia", "kg m^2", "yaw moment of inertia I_zz", True, True, 0.2, 5.0,
             "lateral", "yaw_inertia"),
    CalParam("drag_coefficient", "drag_coefficient", "kg/m", "wind drag C_xw in F = C_xw v_x^2", False, False,
             0.0, np.nan, "longitudinal", "aero_drag", True),
    CalParam("rolling_resistance", "rolling_resistance", "-", "rolling resistance coefficient c_rr", False, False,
             0.0, 0.1, "longitudinal", "rolling_resistance", True),
    CalParam("speed_loop_rate", "speed_loop_tau", "1/s",
             "rate 1/tau_v of the car's speed controller (near 0: the command sets an acceleration)", False, True,
             0.01, 50.0, "speed", natural_lower=True),
    CalParam("speed_loop_authority", "speed_loop_gain", "1/s",
             "acceleration per m/s of speed command, k_v / tau_v, of the car's speed controller", False, True,
             0.05, 100.0, "speed"),
    CalParam("peak_friction", "mu", "-", "tire-road friction ratio mu: the peak of the tire curve, at the "
             "cornering stiffness of the two parameters above", True, True, 0.5, 2.0, "lateral"),
)
"""In priority order: when several parameters are not identified, the last of them is fixed first
(peak friction before the stiffness it trades off with in the linear range)."""
BY_NAME = {p.name: p for p in PARAMS}
DRAG_DECEL_G = 0.5
"""Upper bound of a calibrated drag: at the recording's top speed it decelerates by half a g."""
_ATTR = {"tire.b_front": "bf", "tire.b_rear": "br", "steering_offset": "steer_offset", "steering_gain": "steer_gain",
         "yaw_inertia": "iz", "drag_coefficient": "cxw", "rolling_resistance": "crr", "mu": "mu"}


def applicable(longitudinal: str) -> list[CalParam]:
    """The parameters the recordings' inputs let the diagnosis test: the lateral ones always,
    drag and rolling resistance when v_x follows the force model (not a measured a_x), the speed
    loop with a speed command."""
    need = {"lateral"} | ({"longitudinal"} if longitudinal in ("force", "speed") else set())
    need |= {"speed"} if longitudinal == "speed" else set()
    return [p for p in PARAMS if p.needs in need]


def _field(vehicle: VehicleConfig, f: str) -> float:
    obj = vehicle
    for part in f.split("."):
        obj = getattr(obj, part)
    return float(obj)


def nominal_value(vehicle: VehicleConfig, p: CalParam) -> float:
    """The parameter's nominal value in its own unit (the speed loop's rate and authority from
    the vehicle's ``speed_loop_tau`` and ``speed_loop_gain``)."""
    if p.name == "speed_loop_rate":
        return 1.0 / vehicle.speed_loop_tau
    if p.name == "speed_loop_authority":
        return vehicle.speed_loop_gain / vehicle.speed_loop_tau
    if p.name.startswith("cornering_stiffness_"):
        axle = p.name.rsplit("_", 1)[1]
        return _slope(vehicle, axle, vehicle.mu, getattr(vehicle.tire, f"b_{axle}"))
    return _field(vehicle, p.field)


def _axle_load(vehicle: VehicleConfig, axle: str) -> float:
    other = vehicle.l_r if axle == "front" else vehicle.l_f
    return vehicle.mass * G * other / (vehicle.l_f + vehicle.l_r)


def _slope(vehicle: VehicleConfig, axle: str, mu, b):
    """The axle's cornering stiffness mu F_z B C [N/rad] (static load)."""
    return mu * _axle_load(vehicle, axle) * b * getattr(vehicle.tire, f"c_{axle}")


def to_coord(p: CalParam, value: np.ndarray | float, nominal: float) -> np.ndarray:
    v = np.asarray(value, dtype=float) / (nominal if p.relative else 1.0)
    return np.log(v) if p.log else v


def from_coord(p: CalParam, z: np.ndarray | float, nominal: float) -> np.ndarray:
    v = np.exp(z) if p.log else np.asarray(z, dtype=float)
    return v * (nominal if p.relative else 1.0)


def possible(vehicle: VehicleConfig, name: str) -> tuple[float, float]:
    """The values of a parameter that a car can have at all (what ``VehicleConfig`` refuses
    beyond): a yaw inertia whose radius of gyration lies between what the wheels alone give and
    half the car's diagonal, a peak friction among the tire-road ratios that exist. A calibrated
    value stays inside them, so the calibrated vehicle always loads."""
    if name == "yaw_inertia":
        L, k_max = vehicle.wheelbase, 0.5 * float(np.hypot(vehicle.length, vehicle.width))
        return vehicle.mass * (K_POSSIBLE_MIN * L) ** 2, vehicle.mass * k_max**2
    if name == "peak_friction":
        return MU_POSSIBLE
    return -np.inf, np.inf


def bounds(vehicle: VehicleConfig, params: list[CalParam], v_top: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the fitted coordinates: the parameter's stated range (:data:`PARAMS`) inside
    what is possible for the car (:func:`possible`; the nominal value always is)."""
    lo, hi = [], []
    for p in params:
        upper = p.upper
        if p.name == "drag_coefficient":  # half a g at the top speed, and never below the nominal
            upper = max(DRAG_DECEL_G * vehicle.mass * G / max(v_top, 1.0) ** 2, 1.5 * vehicle.drag_coefficient)
        nom = nominal_value(vehicle, p)
        a, b = (p.lower * nom, upper * nom) if p.relative else (p.lower, upper)
        pa, pb = possible(vehicle, p.name)
        a, b = max(a, min(pa * (1 + 1e-9), nom)), min(b, max(pb * (1 - 1e-9), nom))
        lo.append(float(to_coord(p, a, nom))), hi.append(float(to_coord(p, b, nom)))
    return np.array(lo), np.array(hi)


def start(vehicle: VehicleConfig, params: list[CalParam]) -> np.ndarray:
    """The nominal vehicle in fitted coordinates."""
    return np.array([float(to_coord(p, nominal_value(vehicle, p), nominal_value(vehicle, p))) for p in params])


def values(vehicle: VehicleConfig, params: list[CalParam], z: np.ndarray) -> dict[str, float]:
    """Fitted coordinates -> parameter values in their own units (by name)."""
    return {p.name: float(from_coord(p, zi, nominal_value(vehicle, p))) for p, zi in zip(params, z)}


def vehicle_fields(vehicle: VehicleConfig, vals: dict[str, np.ndarray | float]) -> dict[str, np.ndarray | float]:
    """Parameter values (by name; arrays allowed) -> VehicleConfig field values; the speed loop's
    rate and authority become ``speed_loop_tau`` and ``speed_loop_gain``; an axle's cornering
    stiffness its ``B`` at the (calibrated) peak friction, and a calibrated peak friction keeps the
    slope of an axle whose stiffness is not calibrated (only the tire's limit moves)."""
    out = {BY_NAME[n].field: v for n, v in vals.items()
           if not n.startswith("speed_loop_") and not n.startswith("cornering_stiffness_")}
    mu = vals.get("peak_friction", vehicle.mu)
    for axle in ("front", "rear"):
        key = f"cornering_stiffness_{axle}"
        c_nom = _slope(vehicle, axle, vehicle.mu, getattr(vehicle.tire, f"b_{axle}"))
        if key in vals or "peak_friction" in vals:
            out[f"tire.b_{axle}"] = np.asarray(vals.get(key, c_nom)) / _slope(vehicle, axle, np.asarray(mu), 1.0)
    if "speed_loop_rate" in vals or "speed_loop_authority" in vals:
        rate = vals.get("speed_loop_rate", 1.0 / vehicle.speed_loop_tau)
        auth = vals.get("speed_loop_authority", vehicle.speed_loop_gain / vehicle.speed_loop_tau)
        out["speed_loop_tau"] = 1.0 / np.asarray(rate)
        out["speed_loop_gain"] = np.asarray(auth) / np.asarray(rate)
    return out


def params_update(vehicle: VehicleConfig, vals: dict[str, np.ndarray | float]) -> dict[str, np.ndarray | float]:
    """Parameter values (by name) -> :class:`~gprace.model.dynamics.Params` attributes."""
    out = {}
    for f, v in vehicle_fields(vehicle, vals).items():
        out[{"speed_loop_tau": "speed_tau", "speed_loop_gain": "speed_gain"}.get(f) or _ATTR[f]] = v
    return out


def with_values(vehicle: VehicleConfig, vals: dict[str, float]) -> VehicleConfig:
    """The vehicle with calibrated values written into its fields (the tire's nested)."""
    top, tire = {}, {}
    for f, v in vehicle_fields(vehicle, vals).items():
        if f.startswith("tire."):
            tire[f.split(".", 1)[1]] = float(v)
        else:
            top[f] = float(v)
    data = vehicle.model_dump()
    data.update(top)
    if tire:
        data["tire"] = {**data["tire"], **tire}
    return type(vehicle).model_validate(data)


# --------------------------------------------------------------------------------------------
# the batched fit


def residual_sets(prob, params: list[CalParam], X: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(k, m, H, 3) normalised multi-step errors of the model with ``k`` parameter vectors ``X``
    (fitted coordinates) in ONE batch: the parameters become per-window arrays of
    :class:`~gprace.model.dynamics.Params` (the model's effects, ``prob.base``, included)."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    k, m = X.shape[0], len(starts)
    veh = prob.vehicle
    vals = {p.name: from_coord(p, X[:, j], nominal_value(veh, p)) for j, p in enumerate(params)}
    per_set = params_update(veh, vals)  # attribute -> (k,) values
    model = prob.model()
    base = model.params
    model.params = replace(base, **{a: np.repeat(np.broadcast_to(v, (k,)), m) for a, v in per_set.items()})
    Z0 = None
    if model.nx > 6:  # actuator lags start from the command history of each parameter set
        Z0 = []
        for i in range(k):
            mi = prob.model()
            mi.params = replace(base, **{a: float(np.broadcast_to(v, (k,))[i]) for a, v in per_set.items()})
            Z0.append(lag_states(mi, prob.data)[starts])
        Z0 = np.vstack(Z0)
    S = np.tile(starts, k)
    E = errors(prob.data, S, predict(model, prob.data, S, prob.H, prob._substeps(model), Z0=Z0))
    return (E[..., list(DYNAMIC)] / prob.scale).reshape(k, m, prob.H, 3)


@dataclass
class CalFit:
    """A calibration fit: parameters, fitted coordinates, and what the covariance says."""

    params: list[CalParam]
    x: np.ndarray  # fitted coordinates
    cost: float = np.inf
    jac: np.ndarray | None = None
    res: np.ndarray | None = None
    win: np.ndarray | None = None
    cov: np.ndarray | None = None  # in fitted coordinates (zero rows for parameters at a bound)
    ratio: np.ndarray | None = None  # posterior / prior spread per parameter
    at_bound: np.ndarray | None = None  # (p,) bool
    dropped: dict[str, str] = field(default_factory=dict)  # not identified -> why
    lo: np.ndarray | None = None  # bounds of the fitted coordinates
    hi: np.ndarray | None = None
    profile: np.ndarray | None = None  # d(loss)/d(coordinate offset^2) with the others refitted
    sd_bound: np.ndarray | None = None  # (p,) spread of a parameter at a bound were it free (one-sided interval)
    windows_used: float = 1.0  # share of the windows whose predictions respond smoothly (the covariance's)

    def sd(self) -> np.ndarray:
        if self.cov is None:
            return np.full(len(self.x), np.nan)
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    def relevance(self, vehicle: VehicleConfig) -> np.ndarray:
        """Per parameter: how much the mean normalised squared error per residual would grow if it
        were put back to its nominal value and the others refitted (the profile of the linearised
        cost: ``delta^2 / (J^T J)^-1_ii / N``), in units of the noise floor."""
        if self.profile is None:
            return np.full(len(self.x), np.nan)
        return (self.x - start(vehicle, self.params)) ** 2 * self.profile

    def report(self, vehicle: VehicleConfig) -> list[dict]:
        """Per parameter: value and 95 % interval in its own unit, nominal, bounds, flags.
        ``changed``: the interval excludes the nominal value AND putting it back would cost more
        than :data:`RELEVANT` of the noise floor (a 0.1 % steering gain the data resolve is
        real but no finding)."""
        out = []
        rel = self.relevance(vehicle)
        for i, (p, z, sd, r, b) in enumerate(zip(self.params, self.x, self.sd(), self.ratio, self.at_bound)):
            nom = nominal_value(vehicle, p)
            lo, hi = float(from_coord(p, z - 1.96 * sd, nom)), float(from_coord(p, z + 1.96 * sd, nom))
            if b and self.lo is not None:  # pressed against a bound: one-sided, from the bound inwards
                low_side = z - self.lo[i] < self.hi[i] - z
                z = self.lo[i] if low_side else self.hi[i]
                w = 1.96 * float(self.sd_bound[i]) if self.sd_bound is not None else np.inf
                inner = float(np.clip(z + w if low_side else z - w, self.lo[i], self.hi[i]))
                lo, hi = sorted((float(from_coord(p, z, nom)), float(from_coord(p, inner, nom))))
            value = float(from_coord(p, z, nom))
            out.append({"name": p.name, "field": p.field, "unit": p.unit, "nominal": nom, "value": value,
                        "ci95": [lo, hi], "spread_ratio": float(r), "at_bound": bool(b),
                        "relevance": float(rel[i]),
                        "changed": bool(not (lo <= nom <= hi) and abs(value - nom) > 1e-9 * max(abs(nom), 1.0)
                                        and rel[i] > RELEVANT)})
        return out


def fit(prob, params: list[CalParam], x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, starts: np.ndarray,
        max_nfev: int = MAX_NFEV) -> CalFit:
    """Bounded least squares of the calibration coordinates on the windows ``starts``."""
    sd_prior = (hi - lo) / np.sqrt(12.0)

    def batch(X):
        R = residual_sets(prob, params, np.asarray(X), starts).reshape(len(X), -1)
        return np.where(np.isfinite(R), R, 1e3)

    sol = batched_least_squares(batch, x0, lo, hi, sd_prior, max_nfev)
    return CalFit(list(params), sol.x, float(np.mean(sol.fun**2)), np.asarray(sol.jac), sol.fun, starts,
                  lo=np.asarray(lo, float), hi=np.asarray(hi, float))


SMOOTH_STEP = 1e-3
"""Second finite-difference step of :func:`smooth_windows`, in units of the prior spread."""
SMOOTH_TOL = 0.25
"""A window's response is smooth when its two finite-difference Jacobians agree to this share."""


def smooth_windows(prob, f: CalFit, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(m,) bool: the fit's windows whose predictions respond smoothly to the parameters.

    The fit's Jacobian (steps of 1e-8) is compared per window with a second one of steps
    :data:`SMOOTH_STEP` of the prior spread: where the open-loop prediction diverges (the model
    spins off in the window: a tiny change of a stiffness moves it by several noise floors, and
    it saturates), the two disagree by orders of magnitude. Such a window carries no local
    information about the parameters, yet its huge derivatives would make the interval of every
    parameter collapse to zero width (INI F1TENTH, new-user import: Jacobian columns of 1e8
    from 5 of 400 windows, intervals [1.0976, 1.0976]). Left out of the covariance only."""
    p, m = len(f.x), len(f.win)
    d = SMOOTH_STEP * (hi - lo) / np.sqrt(12.0)
    d = np.where(f.x + d > hi, -d, d)
    R = residual_sets(prob, f.params, f.x[None, :] + np.diag(d), f.win).reshape(p, m, -1)
    R = np.where(np.isfinite(R), R, 1e3)
    r0 = f.res.reshape(m, -1)
    J2 = (R - r0[None]) / d[:, None, None]  # (p, m, n)
    J1 = np.transpose(f.jac.reshape(m, -1, p), (2, 0, 1))
    diff = np.linalg.norm(J1 - J2, axis=2)
    size = np.linalg.norm(J1, axis=2) + np.linalg.norm(J2, axis=2)
    floor = 1e-6 * np.median(size, axis=1, keepdims=True) + 1e-12
    return np.all(diff <= SMOOTH_TOL * size + floor, axis=0)


def covariance(prob, f: CalFit, lo: np.ndarray, hi: np.ndarray) -> CalFit:
    """Cluster-sandwich covariance of ``f`` (2-s blocks) in prior units with a tiny ridge; sets
    ``cov`` (fitted coordinates), ``ratio`` (posterior / prior spread) and ``at_bound``, over the
    windows whose predictions respond smoothly (:func:`smooth_windows`).

    A parameter the fit pressed against a bound is held there (the sandwich is not a spread at a
    bound, where the gradient does not vanish): it counts as determined by the data, the others'
    covariance is that of the fit with it fixed, and its interval is one-sided, from the bound
    inwards by the spread it would have were it free (``sd_bound``)."""
    sd_prior = (hi - lo) / np.sqrt(12.0)
    tol = 1e-4 * (hi - lo)
    at = (f.x - lo < tol) | (hi - f.x < tol)
    free = np.flatnonzero(~at)
    p = len(f.x)
    cov = np.zeros((p, p))
    ratio = np.zeros(p)
    per = prob.H * 3
    ok = smooth_windows(prob, f, lo, hi) if p else np.ones(len(f.win), bool)
    if not ok.any():  # nothing responds smoothly: nothing is determined
        ok[:] = True
        jac_ok = np.zeros_like(f.jac)
    else:
        jac_ok = f.jac
    rows = np.repeat(ok, per)
    Jall, res = jac_ok[rows], f.res[rows]
    bid = np.repeat(blocks(prob.data, f.win[ok]), per)
    _, inv = np.unique(bid, return_inverse=True)

    def sandwich(cols):
        J = Jall[:, cols] * sd_prior[cols]  # d residual / d (parameter in prior units)
        Gb = np.zeros((inv.max() + 1, J.shape[1]))
        np.add.at(Gb, inv, J * res[:, None])
        A = J.T @ J
        A = A + RIDGE * max(float(np.trace(A)), 1.0) * np.eye(len(A))
        Ai = np.linalg.inv(A)
        cov_s = Ai @ (Gb.T @ Gb) @ Ai
        r = np.sqrt(np.maximum(np.diag(cov_s), 0.0))
        # a direction the data do not see keeps its prior spread (not the ridge's artefact)
        evals, evecs = np.linalg.eigh(A)
        blind = evals < 1e-6 * max(float(evals.max()), 1e-300)
        if blind.any():
            r = np.maximum(r, np.abs(evecs[:, blind]).max(axis=1))
        return cov_s, r

    if len(free):
        cov_s, r = sandwich(free)
        ratio[free] = r
        cov[np.ix_(free, free)] = cov_s * np.outer(sd_prior[free], sd_prior[free])
    sd_bound = np.zeros(p)
    if at.any():  # the spread each would have were it free (the others as fitted)
        _, r_all = sandwich(np.arange(p))
        sd_bound[at] = r_all[at] * sd_prior[at]
    f.cov, f.ratio, f.at_bound, f.sd_bound, f.windows_used = cov, ratio, at, sd_bound, float(ok.mean())
    Af = Jall.T @ Jall  # the profile of the linearised cost (all parameters, at a bound too)
    Af = Af + RIDGE * max(float(np.trace(Af)), 1e-300) * np.eye(p)
    f.profile = 1.0 / np.maximum(np.diag(np.linalg.inv(Af)), 1e-300) / max(len(res), 1)
    return f


def identify(prob, params: list[CalParam], x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, starts: np.ndarray,
             log=lambda s: None, max_nfev: int = MAX_NFEV) -> CalFit:
    """Fit every parameter, then fix the least identified one at its nominal value and refit,
    until each parameter left is identified (module doc). Returns the last fit with ``dropped``."""
    params, x, lo_, hi_ = list(params), np.array(x0, float), np.array(lo, float), np.array(hi, float)
    dropped: dict[str, str] = {}
    veh = prob.vehicle
    nfev = max_nfev
    while params:
        f = covariance(prob, fit(prob, params, x, lo_, hi_, starts, nfev), lo_, hi_)
        nfev = max_nfev
        edge = [i for i in range(len(params)) if f.at_bound[i]
                and not (params[i].natural_lower and f.x[i] - lo_[i] < hi_[i] - f.x[i])]
        bad = [i for i in range(len(params)) if not f.ratio[i] < 1.0 / IDENTIFIED]
        if not bad and not edge:
            f.dropped = dropped
            return f
        i = max(edge or bad)  # beyond its plausible range first, then the last in priority order
        q = params[i]
        nom = nominal_value(veh, q)
        a, b = (float(from_coord(q, lo_[i], nom)), float(from_coord(q, hi_[i], nom)))
        if edge:
            dropped[q.name] = (f"the fit presses it against the edge of its plausible range {a:.3g}..{b:.3g} "
                               f"{q.unit}: the error it would absorb is something else")
        else:
            dropped[q.name] = (f"the recordings narrow its stated range {a:.3g}..{b:.3g} {q.unit} only "
                               f"{1.0 / max(f.ratio[i], 1e-9):.1f}-fold (identified from {IDENTIFIED:.0f}-fold)")
        log(f"diagnose: calibration: {q.name} not identified ({dropped[q.name]})")
        keep = [j for j in range(len(params)) if j != i]
        params = [params[j] for j in keep]
        x, lo_, hi_ = f.x[keep], lo_[keep], hi_[keep]
    f = CalFit([], np.zeros(0), ratio=np.zeros(0), at_bound=np.zeros(0, bool), cov=np.zeros((0, 0)))
    f.dropped = dropped
    return f


def as_effects(parameters: list[dict]) -> dict[str, dict[str, float]]:
    """The catalogue effects that changed calibrated parameters stand for, with the effect's
    parameter values (``cornering_stiffness`` front/rear factors, ``yaw_inertia`` factor,
    ``steering_offset``, ``aero_drag`` c_d and ``rolling_resistance`` c_rr as differences from
    the nominal): what a diagnosis without the calibration stage would have named."""
    out: dict[str, dict[str, float]] = {}
    for d in parameters:
        q = BY_NAME.get(d["name"])
        if q is None or not q.supersedes or not d.get("changed"):
            continue
        nom, v = d["nominal"], d["value"]
        if q.supersedes == "cornering_stiffness":
            e = out.setdefault("cornering_stiffness", {"front": 1.0, "rear": 1.0})
            e["front" if q.name.endswith("front") else "rear"] = v / nom
        elif q.supersedes == "yaw_inertia":
            out["yaw_inertia"] = {"factor": v / nom}
        elif q.supersedes == "steering_offset":
            out["steering_offset"] = {"offset": v - nom}
        elif q.supersedes == "aero_drag":
            out["aero_drag"] = {"c_d": v - nom}
        elif q.supersedes == "rolling_resistance":
            out["rolling_resistance"] = {"c_rr": v - nom}
    return out


def v_top(data) -> float:
    """The recording's top speed (99th percentile of v_x)."""
    return float(np.quantile(np.abs(data.Y[:, State.V_X]), 0.99))
