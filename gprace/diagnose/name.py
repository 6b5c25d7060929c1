"""Name: fit catalogue effects to the multi-step residuals and select them by held-out gain.

Every candidate effect's physical parameters are fitted with bounds (``scipy.optimize.
least_squares``, trust-region reflective) to the multi-step prediction errors of the dynamic
channels, each channel divided by its noise-floor RMSE. Window effects (``road_grade``,
``road_bank``, ``friction_patch``) are started from every located region of their channels and
their ``s_start``/``s_end`` are fitted together with the amplitude (the logistic edges keep the
cost differentiable); ``ramp`` stays at its catalogue default.

Selection is greedy forward: the candidates are screened by in-sample fit, the best few are
cross-validated (folds by lap when there are at least three laps, otherwise interleaved
five-second segments), and the one with the lowest held-out loss is added if its gain is
significant (paired block t-statistic > :data:`T_GAIN`) and practically relevant
(:data:`MIN_GAIN`, :data:`MIN_EXCESS_SHARE`). Candidates whose held-out loss is within
:data:`AMBIGUOUS_SHARE` of the winner's gain and not significantly worse are reported as
``ambiguous_with``; the named one is the most parsimonious (fewest parameters). Parameter 95%
intervals come from the Jacobian of the fit with a block (cluster) sandwich covariance, because
overlapping windows make the residuals correlated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gprace.diagnose import profiles
from gprace.diagnose.core import CHANNELS, DYNAMIC, Dataset, errors, lag_states, predict
from gprace.diagnose.locate import blocks
from gprace.model import EFFECTS, Effect, NominalModel, State

T_GAIN = 3.0
T_GAIN_STRONG = 2.0
"""Paired-block t needed when the gain removes at least half of the remaining excess."""
MIN_GAIN = 0.01
"""Smallest held-out loss reduction that matters: 1% of the noise floor (losses are normalised so
that pure sensor noise gives 1 per channel)."""
MIN_EXCESS_SHARE = 0.1
"""... and at least this share of the remaining excess over the noise floor."""
AMBIGUOUS_SHARE = 0.1
SCREEN_TOP = 3
PRESCREEN_NFEV = 5
"""Model evaluations per starting point when every candidate is first tried: a true effect
removes most of its excess within a few trust-region steps (its parameters enter smoothly), so
the ranking is settled long before convergence; most of the screening time was spent
converging candidates (and window starting points) that cannot win."""
PRESCREEN_KEEP = 2 * SCREEN_TOP
"""Candidates carried from the prescreen to the full screening fit."""
NAMING_FTOL = 1e-4
"""Relative cost change at which the naming stage's least-squares fits stop (the candidates'
screening and top fits, the chosen effects' refits, a candidate's joint refit with the
calibration): they rank candidates whose held-out gains differ by per cents, and scipy's default
(1e-8) spent the second half of their evaluations on a median 7e-5 of the cost. The calibration's
fits and the final refits of the named effects keep the default (issue 36, stop 46)."""

# starting values (no effect, or a small one where "none" is a bound) per effect parameter
START = {
    ("aero_drag", "c_d"): 0.0, ("rolling_resistance", "c_rr"): 0.0, ("road_grade", "angle"): 0.0,
    ("drivetrain_lag", "tau"): 0.08, ("downforce", "c_l"): 0.0, ("load_transfer", "cog_height"): 0.1,
    ("tire_load_sensitivity", "k"): 0.0, ("friction_patch", "factor"): 0.9,
    ("combined_slip", "k"): 0.3, ("road_bank", "angle"): 0.0, ("steering_lag", "tau"): 0.05,
    ("steering_offset", "offset"): 0.0, ("yaw_inertia", "factor"): 1.0, ("gyro_bias", "bias"): 0.0,
    ("velocity_misalignment", "angle"): 0.0,
}
FIXED = {"ramp"}  # window edge width stays at its default
SCALE = {"s_start": 10.0, "s_end": 10.0}
NEAR_MARGIN = 150.0
"""How far [m] a window edge may move from its located region during one fit."""
WINDOW_CHANNELS = {"road_grade": (0,), "road_bank": (1,), "friction_patch": (1, 2)}


@dataclass
class Fit:
    name: str
    free: list[str]
    x: np.ndarray
    fixed: dict[str, float]
    cost: float = np.inf  # in-sample mean normalised squared error
    jac: np.ndarray | None = None
    res: np.ndarray | None = None
    ci: dict = field(default_factory=dict)
    win: np.ndarray | None = None  # windows the Jacobian and residuals belong to
    profile: Any = None  # a profile effect's basis, smoothing and band (profiles.ProfileFit)

    def values(self) -> dict[str, Any]:
        """The effect's parameters (a profile: its knots, values and lap length as lists)."""
        if self.profile is not None:
            pf = self.profile
            spec = EFFECTS[self.name].params["values"]
            return {"knots": pf.basis.knots.tolist(),
                    "values": np.clip(pf.neutral + self.x, spec.lower, spec.upper).tolist(),
                    "lap_length": float(pf.basis.L)}
        v = dict(self.fixed)
        v.update({k: float(x) for k, x in zip(self.free, self.x)})
        return v

    def scalars(self) -> dict[str, float]:
        """The scalar parameters (reported with intervals); none for a profile."""
        return {} if self.profile is not None else self.values()

    def config_params(self) -> dict[str, Any]:
        """The parameters as an effect's ``params`` in a vehicle TOML."""
        return {k: tuple(float(x) for x in v) if isinstance(v, list) else float(v) for k, v in self.values().items()}

    def profile_json(self) -> dict[str, Any] | None:
        """A profile's knots, values and pointwise 95 % interval for the JSON; None for other effects."""
        if self.profile is None:
            return None
        return profiles.to_json(self, EFFECTS[self.name].params["values"].unit)

    def effect(self):
        return EFFECTS[self.name](**self.values())


@dataclass
class Problem:
    """What every fit shares: data, windows, horizon, channel scales, the effects already chosen."""

    vehicle: object
    data: Dataset
    H: int
    scale: np.ndarray  # (3,) noise-floor RMSE of the dynamic channels
    substeps: int = 1
    base: list = field(default_factory=list)  # Effect objects already in the model

    def model(self, extra=()) -> NominalModel:
        return NominalModel(self.vehicle, list(self.base) + list(extra), self.data.longitudinal)

    def residuals(self, model: NominalModel, starts: np.ndarray) -> np.ndarray:
        """(m, H, 3) normalised multi-step errors of the dynamic channels."""
        Z = lag_states(model, self.data) if model.nx > 6 else None
        E = errors(self.data, starts, predict(model, self.data, starts, self.H, self._substeps(model), Z=Z))
        return E[..., list(DYNAMIC)] / self.scale

    def _substeps(self, model: NominalModel) -> int:
        sub = self.substeps
        for e in model.effects:  # resolve fast actuator lags: RK4 step no longer than tau
            if "tau" in e.values:
                sub = max(sub, int(np.ceil(self.data.dt / max(float(np.min(e.values["tau"])), 1e-3))))
        return min(sub, 20)

    def residual_sets(self, name: str, sets: list[dict[str, float]], starts: np.ndarray) -> np.ndarray:
        """(k, m, H, 3) normalised errors of the model with effect ``name`` at each of ``k``
        parameter sets, in ONE batch: the effect's parameters are arrays with one value per
        window, so the finite-difference Jacobian of a fit costs one model evaluation, not one
        per parameter (the per-call cost of the vectorised model dominates at a few hundred
        windows). The RK4 substeps are those of the fastest lag among the sets."""
        k, m = len(sets), len(starts)
        vals = {key: np.repeat(np.array([v[key] for v in sets], dtype=float), m) for key in sets[0]}
        model = self.model([EFFECTS[name](**vals)])
        Z0 = None
        if model.nx > 6:  # actuator-lag states from the command history, per parameter set
            Z0 = np.vstack([lag_states(self.model([EFFECTS[name](**v)]), self.data)[starts] for v in sets])
        S = np.tile(starts, k)
        E = errors(self.data, S, predict(model, self.data, S, self.H, self._substeps(model), Z0=Z0))
        return (E[..., list(DYNAMIC)] / self.scale).reshape(k, m, self.H, 3)

    def loss(self, model: NominalModel, starts: np.ndarray) -> np.ndarray:
        """Per-window loss: mean normalised squared error over horizon and channels."""
        return np.mean(self.residuals(model, starts) ** 2, axis=(1, 2))


def free_params(name: str) -> list[str]:
    return [k for k in EFFECTS[name].params if k not in FIXED]


def lap_bounds(data: Dataset) -> tuple[float, float]:
    """Where a window may lie: inside the lap ``[0, L]`` when the recordings have laps (a window
    never reaches beyond the lap length), else within the recorded stretch of ``s``."""
    if np.all(np.isfinite(data.L)):
        return 0.0, float(np.max(data.L))
    s = data.Y[:, State.S]
    return float(np.nanmin(s)) - 5.0, float(np.nanmax(s)) + 5.0


FRICTION_FACTORS = {("tire_friction", "front"), ("tire_friction", "rear"), ("friction_patch", "factor"),
                    ("friction_profile", "values")}
"""Effect parameters that multiply the peak friction mu: bounded so that mu times the factor stays
among the tire-road ratios that exist (``config.MU_POSSIBLE``, what ``VehicleConfig`` refuses
beyond, as the calibrated peak friction)."""
DOWNFORCE_G = (-0.5, 4.0)
"""Aero load at the recording's top speed in units of the car's weight: at most 4 (beyond any
race car's: an F1 car makes about 3.5 at its top speed), lift at most half the weight."""


def physical_bounds(name: str, key: str, vehicle, data: Dataset | None) -> tuple[float, float]:
    """The bounds of an effect parameter: the catalogue's, narrowed to what the car can have
    physically. A friction factor keeps ``mu x factor`` inside ``MU_POSSIBLE`` (IAC's partial
    tire_friction reached a rear x2.8 on a mu of 1.5, a tire-road ratio of 4.2); a downforce keeps
    its load at the top speed inside :data:`DOWNFORCE_G`; a CoG height driving the load transfer
    stays below the rear lever ``l_r`` (higher, 1 g of braking lifts the rear wheels). Without a
    vehicle, the catalogue's bounds."""
    from gprace.config import G, MU_POSSIBLE

    spec = EFFECTS[name].params[key]
    lo, hi = float(spec.lower), float(spec.upper)
    if vehicle is None:
        return lo, hi
    if (name, key) in FRICTION_FACTORS:
        lo, hi = max(lo, MU_POSSIBLE[0] / vehicle.mu), min(hi, MU_POSSIBLE[1] / vehicle.mu)
    elif (name, key) == ("downforce", "c_l") and data is not None:
        v2 = max(float(np.quantile(np.abs(data.Y[:, State.V_X]), 0.99)), 1.0) ** 2
        w = vehicle.mass * G / v2
        lo, hi = max(lo, DOWNFORCE_G[0] * w), min(hi, DOWNFORCE_G[1] * w)
    elif (name, key) == ("load_transfer", "cog_height"):
        hi = min(hi, vehicle.l_r)
    return lo, hi


def at_bound(name: str, key: str, value, vehicle, data: Dataset | None, rel: float = 1e-3):
    """Is ``value`` pressed against a bound of :func:`physical_bounds` (within ``rel`` of the range,
    the fit's clip active)? A bool, or a bool array for an array of values (a profile's knots)."""
    lo, hi = physical_bounds(name, key, vehicle, data)
    tol = rel * (hi - lo)
    v = np.asarray(value, dtype=float)
    hit = (v <= lo + tol) | (v >= hi - tol)
    return bool(hit) if hit.ndim == 0 else hit


def _bounds(name: str, free: list[str], data: Dataset, vehicle=None):
    cls = EFFECTS[name]
    lo, hi = [], []
    s_lo, s_hi = lap_bounds(data)
    for k in free:
        spec = cls.params[k]
        if k in ("s_start", "s_end"):
            lo.append(s_lo), hi.append(s_hi)
        elif k == "tau":  # lags far below the sample period are not identifiable (and stiff)
            lo.append(max(spec.lower, 0.01)), hi.append(spec.upper)
        else:
            a, b = physical_bounds(name, k, vehicle, data)
            lo.append(a), hi.append(b)
    return np.array(lo), np.array(hi)


def starts_for(name: str, regions: dict[int, list[tuple[float, float]]]) -> list[dict[str, float]]:
    cls = EFFECTS[name]
    base = {}
    for k, spec in cls.params.items():
        if k in FIXED or cls.profile:
            continue
        base[k] = START.get((name, k), spec.default if spec.default is not None else 0.0)
    if cls.profile:  # one start: no effect anywhere on the lap
        return [{}]
    if not cls.window:
        return [base]
    out = []
    amp = "angle" if "angle" in cls.params else "factor"
    spans = []
    for c in WINDOW_CHANNELS[name]:
        rs = regions.get(c, [])
        spans += rs[:2]
        if len(rs) > 1:  # fragments of one window: also try the span around the strongest one
            a0, b0 = rs[0]
            near = [(a, b) for a, b in rs if a < b0 + 300.0 and b > a0 - 300.0]
            spans.append((min(a for a, _ in near), max(b for _, b in near)))
    for (a, b) in dict.fromkeys(spans):
        for sgn in ((1, -1) if amp == "angle" else (1,)):
            d = dict(base)
            d["s_start"], d["s_end"] = a, b
            d[amp] = 0.02 * sgn if amp == "angle" else 0.85
            out.append(d)
    return out


def fit_effect(prob: Problem, name: str, starts: np.ndarray, inits: list[dict[str, float]],
               max_nfev: int = 40, ftol: float = 1e-8) -> Fit | None:
    """Bounded least squares of one effect's parameters (best over the starting points); a
    profile effect by penalised Gauss-Newton (:func:`gprace.diagnose.profiles.fit_profile`, one
    iteration per 10 evaluations allowed, smoothing chosen by cross-validation). ``ftol``: scipy's
    relative stop on the cost (a profile's iterations are counted, it has none)."""
    from scipy.optimize import least_squares

    if EFFECTS[name].profile:
        v0 = next((i["values"] for i in inits if "values" in i), None)
        return profiles.fit_profile(prob, name, starts, v0, iterations=_iterations(max_nfev))
    free = free_params(name)
    fixed = {k: EFFECTS[name].params[k].default for k in EFFECTS[name].params if k in FIXED}
    lo, hi = _bounds(name, free, prob.data, prob.vehicle)
    step = 1e-3 if any(k.startswith("s_") for k in free) else float(np.sqrt(np.finfo(float).eps))
    xs = np.array([SCALE.get(k, max(abs(hi[i] - lo[i]) * 0.05, 1e-3)) for i, k in enumerate(free)])
    best: Fit | None = None

    def sets(X):
        out = []
        for x in X:
            vals = dict(fixed)
            vals.update(zip(free, (float(v) for v in x)))
            if "s_start" in vals and vals["s_end"] < vals["s_start"] + 1.0:
                vals["s_end"] = vals["s_start"] + 1.0
            out.append(vals)
        return out

    def batch(X):
        R = prob.residual_sets(name, sets(X), starts).reshape(len(X), -1)
        return np.where(np.isfinite(R), R, 1e3)

    last: dict = {}  # the residuals at the latest point: least_squares asks for fun(x), then jac(x)

    def fun(x):
        r = batch([x])[0]
        last.update(x=np.array(x, copy=True), r=r, starts=starts)
        return r

    def jac(x):
        """Forward differences (scipy's '2-point' steps, one-sided inside the bounds), all
        parameters in one batched evaluation."""
        sign = np.where(x >= 0, 1.0, -1.0)
        h = step * sign * np.maximum(1.0, np.abs(x))
        h = np.where((x + h > hi) | (x + h < lo), -h, h)
        h = (x + h) - x
        steps = [x + np.eye(len(x))[i] * h[i] for i in range(len(x))]
        if last.get("starts") is starts and np.array_equal(last["x"], x):
            R0, R = last["r"], batch(steps)
        else:
            R = batch([x] + steps)
            R0, R = R[0], R[1:]
        return ((R - R0) / h[:, None]).T

    full = starts
    lo_all, hi_all = lo, hi
    for init in inits:
        where = _start_region(prob, full, free, init, lo_all, hi_all)
        if where is None:
            continue
        starts, lo, hi = where
        x0 = np.clip(np.array([init[k] for k in free], dtype=float), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        try:
            sol = least_squares(fun, x0, jac=jac, bounds=(lo, hi), x_scale=xs, method="trf", max_nfev=max_nfev,
                                ftol=ftol)
        except (ValueError, FloatingPointError):
            continue
        J, res, win = sol.jac, sol.fun, starts
        if len(starts) != len(full):  # cost over all windows (unchanged far from the window)
            starts = full
            cost = float(np.mean(fun(sol.x) ** 2))
        else:
            cost = float(np.mean(sol.fun**2))
        if best is None or cost < best.cost:
            best = Fit(name, free, sol.x, fixed, cost, J, res, win=win)
    return best


def _start_region(prob: Problem, full: np.ndarray, free: list[str], init: dict[str, float],
                  lo_all: np.ndarray, hi_all: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The windows and bounds one starting point is fitted on: all of them, or for a windowed
    effect the windows near its stretch, with the edges kept where those windows see them (None
    when too few windows reach it or the stretch lies outside the lap)."""
    lo, hi = lo_all.copy(), hi_all.copy()
    if "s_start" not in init:
        return full, lo, hi
    a, b = init["s_start"], init["s_end"]
    starts = _near(prob, full, a, b, margin=NEAR_MARGIN)
    if len(starts) < 5:
        return None
    i0, i1 = free.index("s_start"), free.index("s_end")
    lo[i0], hi[i0] = max(a - NEAR_MARGIN, lo_all[i0]), min(max(a + 1.0, 0.5 * (a + b)), hi_all[i0])
    lo[i1], hi[i1] = max(min(b - 1.0, 0.5 * (a + b) + 1.0), lo_all[i1]), min(b + NEAR_MARGIN, hi_all[i1])
    if lo[i0] >= hi[i0] or lo[i1] >= hi[i1]:
        return None
    return starts, lo, hi


def _near(prob: Problem, starts: np.ndarray, a: float, b: float, margin: float = 60.0) -> np.ndarray:
    """Windows whose path can reach the stretch [a - margin, b + margin] (wrapped to the lap)."""
    s0 = prob.data.Y[starts, 5]
    L = prob.data.L[prob.data.rec[starts]]
    reach = np.abs(prob.data.Y[starts, 0]) * prob.H * prob.data.dt
    lo, hi = a - margin - reach, b + margin
    inside = (s0 >= lo) & (s0 <= hi)
    Lf = np.where(np.isfinite(L), L, np.inf)
    inside |= (s0 - Lf >= lo) & (s0 - Lf <= hi)
    return starts[inside]


def refit(prob: Problem, fit: Fit, starts: np.ndarray, max_nfev: int = 20, ftol: float = 1e-8) -> Fit:
    """The fit again on ``starts``, warm-started; a profile keeps its smoothing in a
    cross-validation fold (``max_nfev <= 10``) and chooses it again otherwise."""
    if fit.profile is not None:
        return profiles.refit(prob, fit, starts, iterations=_iterations(max_nfev), keep_smoothing=max_nfev <= 10)
    return fit_effect(prob, fit.name, starts, [fit.values()], max_nfev=max_nfev, ftol=ftol) or fit


def _iterations(max_nfev: int) -> int:
    """Gauss-Newton iterations of a profile fit for an evaluation budget meant for a few scalars."""
    return int(np.clip(max_nfev // 10, 1, 3))


def interval95(prob: Problem, fit: Fit, starts: np.ndarray) -> dict[str, tuple[float, float]]:
    """95% intervals from the fit's Jacobian, cluster-robust over ~2 s blocks of windows (a
    profile: its pointwise band, stored on ``fit.profile``; no scalar intervals)."""
    if fit.profile is not None:
        profiles.interval(prob, fit, starts)
        return {}
    J, r = fit.jac, fit.res
    if J is None or r is None:
        return {}
    J = np.asarray(J.todense() if hasattr(J, "todense") else J)
    per = prob.H * 3
    starts = fit.win if fit.win is not None else starts
    bid = np.repeat(blocks(prob.data, starts), per)
    _, inv = np.unique(bid, return_inverse=True)
    G = np.zeros((inv.max() + 1, J.shape[1]))
    np.add.at(G, inv, J * r[:, None])
    A = J.T @ J
    try:
        Ai = np.linalg.pinv(A)
    except np.linalg.LinAlgError:
        return {}
    cov = Ai @ (G.T @ G) @ Ai
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return {k: (float(x - 1.96 * s), float(x + 1.96 * s)) for k, x, s in zip(fit.free, fit.x, sd)}


MIN_SENSOR_SNR = 0.5
"""Smallest RMS change of the measurement, in units of the channel's noise floor, at which an
effect acting on the measurement only (a gyro bias, a turned velocity frame) is named. Any
structure the model misses projects a little onto a constant offset or onto a term in v_x, and
over thousands of windows even a hundredth of a degree then gains significantly; a sensor error
below half the sensor's noise is no finding about the sensor (issue 36: 0.0004 rad, a quarter of
the v_y noise, named on a plant that has no misalignment)."""


def sensor_snr(prob: Problem, fit: Fit) -> float | None:
    """RMS over the recordings of what ``fit``'s effect changes in the measured dynamic channels,
    divided by each channel's noise floor (the largest over its channels); None for an effect
    that acts on the dynamics (the held-out test alone judges those)."""
    cls = EFFECTS[fit.name]
    if fit.profile is not None or cls.measure is Effect.measure:
        return None
    Y = prob.data.Y
    y = {c: Y[:, i].copy() for i, c in enumerate(CHANNELS)}
    fit.effect().measure(y)
    d = np.stack([y[CHANNELS[i]] - Y[:, i] for i in DYNAMIC], axis=1)
    return float(np.max(np.sqrt(np.mean(d**2, axis=0)) / prob.scale))


# --------------------------------------------------------------------------------------------
# cross-validation


TWO_LAP_SHARE = 0.25
"""Two laps are folds only when the shorter holds a quarter of the windows: its fold's refit is on
the longer lap alone, the longer lap's refit on the shorter one, which must carry enough of it."""

FOLDS_MAX = 3
"""Folds of the cross-validation by lap: laps ``i mod 3`` (was 4: with 5 short laps, as the INI
F1TENTH log has, every refit costs a fold more; recordings of 2-3 laps had 3 folds already)."""


def folds(data: Dataset, starts: np.ndarray, k_max: int = FOLDS_MAX) -> np.ndarray:
    """Fold id per window: by lap when there are >= 3 laps, or 2 laps each holding at least
    :data:`TWO_LAP_SHARE` of the windows; else interleaved 5 s segments.

    Two laps are folded by lap too (issue 36, stop 47): a profile over lap position refitted
    without a 5 s segment is drawn through it by the same lap's neighbouring segments, so
    interleaved segments accept a profile that follows one lap's own deviation (IAC laps 0-1:
    a bank profile at 59.7 % held-out gain by segments, 44.5 % by lap and not chosen, and no
    gain on lap 2). Every candidate and the calibration share these folds."""
    laps = data.lap[starts]
    ul, cnt = np.unique(laps, return_counts=True)
    if len(ul) >= 3 or (len(ul) == 2 and cnt.min() >= TWO_LAP_SHARE * len(laps)):
        K = min(k_max, len(ul))
        rank = np.searchsorted(ul, laps)
        return rank % K
    seg = blocks(data, starts, seconds=5.0)
    _, inv = np.unique(seg, return_inverse=True)
    return inv % 3


def gain_test(l0: np.ndarray, l1: np.ndarray, bid: np.ndarray) -> tuple[float, float]:
    """(relative gain, paired block t-statistic) of loss l1 against l0.

    Blocks where the two models predict identically (a window effect far from its window) carry
    no information about the difference and are left out of the t-statistic.
    """
    d = _block_differences(l0, l1, bid)
    nb = len(d)
    se = np.std(d, ddof=1) / np.sqrt(nb) if nb > 1 else np.inf
    t = float(np.mean(d) / se) if se > 0 else 0.0
    return float((l0.mean() - l1.mean()) / max(l0.mean(), 1e-300)), t


def _block_differences(l0: np.ndarray, l1: np.ndarray, bid: np.ndarray) -> np.ndarray:
    """Mean loss difference per block, blocks where the two models predict alike left out."""
    _, inv = np.unique(bid, return_inverse=True)
    nb = inv.max() + 1
    cnt = np.bincount(inv, minlength=nb)
    d = (np.bincount(inv, l0 - l1, nb)) / np.maximum(cnt, 1)
    moved = np.bincount(inv, np.abs(l0 - l1) > 1e-9 * max(float(np.mean(l0)), 1e-300), nb) > 0
    return d[moved] if moved.sum() >= 2 else d


def rank_test(l0: np.ndarray, l1: np.ndarray, bid: np.ndarray) -> float:
    """One-sided Wilcoxon signed-rank test of the block gains of l1 over l0, as a normal z.

    The paired t of :func:`gain_test` assumes light tails. The gains of an effect that acts at
    one place are heavy-tailed: a car that slides at the limit through a low-grip patch gains
    100x more in the lap where it nearly spun than in the lap where it stayed in its slip range,
    and the one huge block inflates the standard error until t < 2 although every block gains.
    The signed-rank test asks only that the gains be consistently positive (ranks, not sizes)."""
    from scipy.stats import norm, wilcoxon

    d = _block_differences(l0, l1, bid)
    if len(d) < 6 or not np.any(d):
        return 0.0
    p = float(wilcoxon(d, alternative="greater").pvalue)
    return float(norm.isf(max(p, 1e-300)))
