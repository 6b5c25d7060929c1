"""The planner's grip limits from what the car has shown it can do (not from the nominal model).

Iteration 0 drives a conservative curvature plan. From then on the friction ellipse of the
minimum-time planner (lateral, drive and brake accelerations in m/s^2) starts from the envelope
MEASURED on the last lap and widens it step by step while the car stays clear of the limit, the
scheme of Wischnewski et al. 2019 (start conservative, widen from measured accelerations):

- a completed lap: the next limits are the measured envelope (at most the plan's own limits)
  times ``1 + widen``, unless the rear
  tire already worked near its peak slip angle (``utilisation >= hold``), then the envelope as is
  (an axis the lap used less than half of keeps its previous limit);
- a failed lap (spin, off track): the next limits are the failed plan's times ``1 - 2 widen``, so
  a plan that was not driveable is never driven again unchanged;
- never above ``cap`` (the nominal model's own limits times the planner's grip share), and never
  again at a level whose lap failed (``widen`` below it);
- never cornering harder than the lowest lateral level at which a completed lap came near the
  rear tire's peak (:func:`held_level`: the smaller of the measured and the planned lateral
  acceleration): the hold after such a lap is remembered, not only applied to the next plan.
  Measured on randomized_09 (issue 37 stop 46): its shakedown, planned at 7.75 m/s^2, came to 0.90
  of the peak (measuring 8.45); after a slower built-up lap (0.35 of the peak) the widening went
  on to 8.82 m/s^2, and the alpha-0 lap at that level spun the car in the hairpin. On
  randomized_06 a shakedown planned at 9.87 m/s^2 slid past the peak (1.59 of it, 80 border
  hits) and measured 11.2; the widening to 10.76 then lost the car;
- a widening below the lowest such level at which a lap slid past the peak and needed the
  stability envelope ``EDGE_EVENTS`` times or more (:func:`slid_level`): it completed because the
  envelope caught the car;
- never cornering harder than the lowest lateral level a racing lap asked (its plan's times the
  square of its speed factor) when it needed the stability envelope, an intervention or a weave,
  or an exploration lap asked when it needed it ``EDGE_EVENTS`` times or more (:func:`eased_level`);
- such a lap is held at the limits it was driven at, the plan's times the square of the speed
  factor of a build-up or novelty step (:func:`driven_limits`), not at the plan's own;
- never cornering harder than the grip the car has shown (:func:`shown_limit`), with room for the
  amount by which the car's laps corner harder than their plans ask (:func:`overshoot`).

All functions are pure and vectorised over the run's samples.
"""

from __future__ import annotations

import numpy as np

from gprace.model.dynamics import Input, peak_slip
from gprace.mpc.tracking import front_heading, rear_slip_rows

QUANTILE = 0.99  # robust peak of a measured acceleration (one lap has about 1,100 samples)


def envelope(run, in_control) -> np.ndarray:
    """Measured ``(a_lat, a_drive, a_brake)`` [m/s^2] of a run's in-control samples."""
    X = run.states()
    return envelope_of(X, run.inputs(), run["t"], in_control(X))


def envelope_of(X: np.ndarray, U: np.ndarray, t: np.ndarray, ok: np.ndarray, quantile: float = QUANTILE) -> np.ndarray:
    """``(a_lat, a_drive, a_brake)`` [m/s^2]: robust peaks of the samples ``ok`` of states ``X`` and inputs ``U``.

    The lateral acceleration is ``v_x r + dv_y/dt`` (central differences): ``v_x r`` alone counts
    a yaw oscillation in a fast chicane (r = 1 rad/s at 55 m/s) as 55 m/s^2 of grip.
    """
    if ok.sum() < 10:
        return np.full(3, np.nan)
    vy_dot = np.gradient(X[:, 1], t)
    a_lat = np.abs(X[ok, 0] * X[ok, 2] + vy_dot[ok])
    ax = U[ok, 1]
    return np.array([np.quantile(a_lat, quantile), np.quantile(np.maximum(ax, 0.0), quantile),
                     np.quantile(np.maximum(-ax, 0.0), quantile)])


def rear_use(X: np.ndarray, model) -> np.ndarray:
    """``(n,)`` the rear slip angle of states ``X (n, 6)`` over the nominal rear tire's peak slip angle."""
    p = model.params
    a_r, _ = rear_slip_rows(np.asarray(X, float)[:, :6], p.lr, p.vmin)
    return np.abs(a_r) / peak_slip(p.br, p.cr)


def front_use(X: np.ndarray, U: np.ndarray, model) -> np.ndarray:
    """``(n,)`` the front slip angle of states ``X (n, 6)`` steered by ``U (n, 2)`` over the nominal
    front tire's peak slip angle."""
    p = model.params
    X, U = np.asarray(X, float), np.asarray(U, float)
    a_f = U[:, Input.DELTA] - front_heading(X, p.lf, p.vmin)
    return np.abs(a_f) / peak_slip(p.bf, p.cf)


def below_peak(X: np.ndarray, U: np.ndarray, model) -> np.ndarray:
    """Mask ``(n,)`` of the samples whose front and rear slip angles are both below the nominal
    tires' peak: where the yaw rate answers the steering as a linear model says. Past a peak the
    steering moves the yaw little or the wrong way, and the delay estimate of a shakedown lap
    (:func:`gprace.mpc.delay.estimate`) read a slide's counter-steering as the response to the
    steering before it: a randomized Audi whose shakedown slid with the rear at 2.3 times its
    peak was read at the grid's far corner, 0.2 s for its 0.11 s, and every GP lap after it spun
    in a yaw oscillation (docs/decisions.md, issue 37, stop 50)."""
    return (rear_use(X, model) < 1.0) & (front_use(X, U, model) < 1.0)


def utilisation(run, model, in_control) -> float:
    """Robust peak of the rear slip angle over the nominal rear tire's peak slip angle."""
    X = run.states()
    ok = in_control(X)
    if not ok.any():
        return float("nan")
    return float(np.quantile(rear_use(X[ok], model), QUANTILE))


def nominal_cap(model, share: float) -> np.ndarray:
    """``share`` of the nominal model's own limits ``(a_lat, a_drive, a_brake)``."""
    from gprace.plan.curvature import lateral_limit

    lim = model.vehicle.limits
    return share * np.array([lateral_limit(model), lim.accel_max, -lim.accel_min])


def widening(util: float, widen: float, widen_max: float, hold: float = 0.8, low: float = 0.3,
             shape: float | None = None) -> float:
    """Step of the next widening: ``widen_max`` while the rear slip used stays below ``low`` of the
    peak, falling linearly to ``widen`` at ``hold`` (a car far from its limit widens faster); with
    the nominal rear tire's shape factor ``shape`` never more than the force it has left at that
    slip (:func:`force_headroom`)."""
    if not np.isfinite(util):
        return widen
    room = float(np.clip((hold - util) / max(hold - low, 1e-9), 0.0, 1.0))
    step = widen + (max(widen_max, widen) - widen) * room
    return step if shape is None else min(step, force_headroom(util, shape))


def force_headroom(util: float, shape: float) -> float:
    """Lateral force a tire ``sin(C atan(B alpha))`` (``C = shape``) has left at ``util`` of its
    peak slip angle, as a share of the force it gives there: ``1 / sin(C atan(tan(pi / 2C) util)) - 1``
    (0 at and past the peak). The curve is flat near its peak: at 0.7 of the peak slip angle a
    C = 1.35 tire already gives 98 % of its peak force. Measured on the unseen plants (docs/
    decisions.md, issue 37, stop 51): after laps at 0.5 to 0.7 of the peak slip, limits widened by
    5 to 9 % (the headroom there: 2 to 8 %) sent two cars past the peak and lost them. A curve
    without a peak (``C <= 1``) sets no cap (inf)."""
    if not np.isfinite(util) or util >= 1.0:
        return 0.0
    c = float(shape)
    if util <= 0.0 or c <= 1.0:
        return np.inf
    return float(1.0 / np.sin(c * np.arctan(peak_slip(1.0, c) * util)) - 1.0)  # B alpha = B alpha_peak util


def next_limits(previous: np.ndarray, measured: np.ndarray, completed: bool, util: float, cap: np.ndarray,
                widen: float = 0.05, hold: float = 0.8, failed=(), border_hits: int = 0, interventions: int = 0,
                widen_max: float | None = None, shape: float | None = None) -> np.ndarray:
    """Limits of the next plan from the last plan's ``previous`` limits and the lap it gave.

    A completed lap widens them by ``widen`` (up to ``widen_max`` when the rear slip used was far
    from the peak, :func:`widening`), unless it came near the peak slip (``util >= hold``), touched
    a border (``border_hits > 0``) or made the stability envelope intervene: then they are held.
    Measured on bmw_commonroad (2026-11-24): a lap that completes with border hits is the last
    warning; one Double-GP trial widened past two such laps and lost the car in the hairpin at
    s = 1607 m. ``failed`` are the limits of earlier plans whose laps failed: the next limits stay
    below each of them by ``widen`` (a level that lost the car is not tried again). ``shape``, the
    nominal rear tire's shape factor, caps the widening at the force the rear has left
    (:func:`force_headroom`).
    """
    previous, measured, cap = (np.asarray(a, dtype=float) for a in (previous, measured, cap))
    if not completed or not np.all(np.isfinite(measured)):
        out = previous * (1.0 - 2.0 * widen)
    else:
        # widen from what the car did, never from more than the plan asked: measured peaks above
        # the plan's limits are transients (a yaw oscillation in a fast chicane), not grip shown;
        # an axis the lap hardly used (a partial lap that never braked) tells nothing: keep its limit
        base = np.where(measured >= 0.5 * previous, np.minimum(measured, previous), previous)
        held = (np.isfinite(util) and util >= hold) or border_hits > 0 or interventions > 0
        step = widening(util, widen, widen_max if widen_max is not None else widen, hold, shape=shape)
        out = base if held else base * (1.0 + step)
    return np.minimum(below_failed(out, failed, widen), cap)


EDGE_EVENTS = 3  # envelope events (interventions + weaves) from which an exploration lap's pace counts


def tells_pace(alpha: float, events: int) -> bool:
    """Whether a lap's stability-envelope ``events`` (interventions + weaves) say its plan's pace was
    too much for the car: any event on a racing lap (``alpha`` 0), ``EDGE_EVENTS`` or more on an
    exploration lap, which leaves its plan on purpose.

    Measured (issue 37, stop 60; rule 4's two benchmark runs and 26 new cars, the laps after a GP
    lap with 3 or more events): 61 asked no more lateral acceleration than it did, and none was
    lost; 25, all after exploration laps, asked more, and 2 were lost (randomized_18 seed 0: an
    exploration lap at 11.12 m/s^2 driven at 0.95 of its speed, 10.04 asked, then 10.69 and the
    car lost after the fast chicane; randomized_49: 8.98, then 9.11 on a racing lap, a spin at a
    corner exit)."""
    return events > 0 and (alpha == 0.0 or events >= EDGE_EVENTS)


def driven_limits(limits, step: float, alpha: float, interventions: int) -> np.ndarray:
    """The limits a lap held the car to, as the next widening or hold starts from them: ``limits``
    times ``step^2`` (a plan time-scaled by ``step``, by the build-up or a novelty step, asks
    ``step^2`` of its accelerations) when the lap's stability-envelope events (``interventions``,
    with the weaves) tell about its pace (:func:`tells_pace`), else ``limits`` as planned.

    :func:`next_limits` holds a lap the envelope had to ease at its limits; held at the plan's
    limits, the next lap asked more than the eased one did. Measured (commonroad_mb trial 0, seeds
    0 and 1, two machines): a racing lap at 9.55 m/s^2 driven at 0.97 of its speed (9.0 m/s^2
    asked) needed the envelope five times; the next plan, held at 9.55 m/s^2 and not time-scaled,
    was 5 to 6 % faster than that lap and left the track at s = 1609 to 1626 m. Exploration laps
    (``alpha > 0``) leave their plan on purpose: their interventions say less about its pace, and
    of the 79 eased and time-scaled exploration laps of stop 55's two benchmark runs none was
    followed by a lost lap (docs/decisions.md, issue 37, stop 56); from ``EDGE_EVENTS`` on they
    count (stop 60)."""
    limits = np.asarray(limits, dtype=float)
    if tells_pace(alpha, interventions) and step < 1.0:
        return limits * step**2
    return limits


def below_failed(limits, failed=(), widen: float = 0.05) -> np.ndarray:
    """``limits`` kept below each of the ``failed`` limits (plans whose laps were lost) by
    ``widen``: limits at or above a failed level on every axis are cut to ``(1 - widen)`` of it.
    Idempotent; limits it leaves unchanged are clear of every failed level (:func:`clear_of`)."""
    out = np.asarray(limits, dtype=float).copy()
    for f in failed:
        f = np.asarray(f, dtype=float)
        if f.shape == out.shape and np.all(out >= f * (1.0 - widen)):
            out = np.minimum(out, f * (1.0 - widen))
    return out


def clear_of(limits, failed=(), widen: float = 0.05) -> bool:
    """Whether ``limits`` stay below every failed level (:func:`below_failed` leaves them as they are)."""
    if limits is None or len(limits) == 0:
        return not failed
    return bool(np.allclose(below_failed(limits, failed, widen), np.asarray(limits, dtype=float)))


def eased_level(laps) -> float:
    """Lowest lateral level [m/s^2] of the completed ``laps`` (``(limits, step, alpha, events)``: the
    plan's limits, the speed factor it was driven at, its alpha and the stability envelope's
    interventions and weaves) whose events tell about its pace (:func:`tells_pace`): the lateral
    limit it was driven at (:func:`driven_limits`, ``limits[0] step^2``), what the lap asked; inf
    if none did.

    :func:`next_limits` holds the limits after such a lap; this remembers the level, as
    :func:`held_level` does for the rear's peak. A calm lap at the same level otherwise widened the
    next plan past it. Measured (issue 37, stop 58, benchmark seed 0): randomized_05 and
    randomized_07 needed the envelope at 9.73 and 9.53 m/s^2, completed the next lap calm, were
    widened to 10.14 and 10.39 m/s^2 and lost the car at the last corners; re-driven on 3 noise
    seeds, the widened plans are lost on 2 and 3 of them. A weave counts: with the delay lengthened
    at its first weave (:mod:`gprace.mpc.stability`), randomized_05 completed a lap that wove once
    with no intervention, was widened from 9.71 to 10.11 m/s^2 and lost the car at the same corner."""
    levels = [float(driven_limits(limits, step, alpha, events)[0]) for limits, step, alpha, events in laps
              if tells_pace(alpha, events) and limits is not None and len(limits) == 3]
    return min(levels, default=np.inf)


def held_level(laps, hold: float = 0.8) -> float:
    """Lowest lateral level [m/s^2] of the completed ``laps`` (``(envelope, utilisation, limits,
    step)``: measured envelope, rear-slip utilisation, the plan's limits and the speed factor it
    was driven at) whose rear tire came to ``hold`` of its peak slip angle: the smaller of what
    was measured and what the plan asked (``limits[0] step^2``; a lap sliding past the peak
    measures more than the plan asked), inf if no lap did."""
    levels = []
    for env, util, limits, step in laps:
        if env is None or len(env) != 3 or not np.isfinite(util) or util < hold:
            continue
        asked = lateral_asked(limits, step)
        levels.append(min(float(env[0]), asked) if not np.isnan(asked) else float(env[0]))
    return min((v for v in levels if np.isfinite(v)), default=np.inf)


def lateral_asked(limits, step: float) -> float:
    """The lateral acceleration [m/s^2] a plan with ``limits`` driven at speed factor ``step`` asks:
    ``limits[0] step^2`` (accelerations scale with the speed squared); nan without plan limits."""
    if limits is None or len(limits) != 3:
        return float("nan")
    return float(limits[0]) * step**2


def slid_level(laps, widen: float = 0.05) -> float:
    """``(1 - widen)`` of the lowest lateral level [m/s^2] (as :func:`held_level` reads it) of the
    completed ``laps`` (``(envelope, utilisation, limits, step, events)``, with the stability
    envelope's interventions and weaves) whose rear slid past its peak slip angle (utilisation
    1 or more) and that needed the envelope ``EDGE_EVENTS`` times or more; inf if none did. Such a
    level completed only because the envelope caught the car: the next plans stay a widening
    below it, as below a lost lap's (:func:`below_failed`).

    Measured (issue 37, stop 60): rule 4's edge laps (3 or more events, both benchmark seeds),
    re-driven on two more noise seeds each (``benchmarks/timetrial_redrive.py``), lost the car on
    4 of the 24 draws that followed a lap past the peak with 3 or more events, and on 2 of the
    other 122 (randomized_10 trial 0 after its shakedown slid to 2.28 of the peak, randomized_25
    trial 1 after three laps at 8.44 m/s^2 at 1.1 of the peak with 5 and 6 events each)."""
    return (1.0 - widen) * held_level([(env, util, limits, step) for env, util, limits, step, events in laps
                                       if events >= EDGE_EVENTS], hold=1.0)


OVERSHOOT_MAX = 1.15  # largest overshoot read from a car's laps (a lap sliding past its plan says little)


def overshoot(laps) -> float:
    """How much harder than their plans the car's completed laps cornered: the median over ``laps``
    (``(envelope, limits, step)``, as :func:`held_level` reads them: the measured envelope,
    :func:`envelope_of`, the plan's limits and the speed factor it was driven at) of the measured
    lateral peak over what the plan asked (``limits[0] step^2``), kept within ``[1, OVERSHOOT_MAX]``;
    1 without laps (a lap with no envelope or no plan limits tells nothing).

    A plan's lateral limit is a steady level on its line; the car tracking it turns in a little late,
    sits a little inside or outside the line and rotates through transients. Measured on the 29
    plants of seed 0 and the 26 new cars (stop 64's benchmarks, 547 completed GP laps): the peak is
    1.046 times the plan's on calm racing laps (10 %: 1.026, 90 %: 1.059) and 1.056 on exploration
    laps."""
    ratios = [float(env[0]) / asked for env, limits, step in laps
              if env is not None and len(env) == 3 and (asked := lateral_asked(limits, step)) > 0]
    ratios = [r for r in ratios if np.isfinite(r)]
    return float(np.clip(np.median(ratios), 1.0, OVERSHOOT_MAX)) if ratios else 1.0


def shown_limit(shown: float, nominal_lateral: float, over: float, floor: float) -> float:
    """The largest lateral limit [m/s^2] the grip the car has shown allows: ``shown`` (the weakest
    axle's force over the nominal tire's, :func:`gprace.timetrial.shakedown.axle_grip`) times the
    nominal model's lateral limit, divided by the car's overshoot ``over`` (:func:`overshoot`), so that
    the lap driven, not only its plan, stays within that grip; never below ``floor`` (the last plan's
    lateral limit: the cap stops a widening, it does not narrow).

    Measured (issue 37, stop 65): randomized_27 (rear grip 0.88, CoG 0.58 m) showed 0.846 of the
    nominal grip, and the cap without the overshoot let its plan ask 8.80 m/s^2, exactly that grip. The
    lap cornered at up to 9.35 m/s^2 (v_x r) where its plan asked 8.67, the rear slid and the car
    spun (4 of 4 noise draws). The same plan time-scaled to ask 8.62 and 8.50 m/s^2 completed on 4
    of 4 draws each."""
    return max(shown * nominal_lateral / over, floor)
