"""The stability envelope: ease the reference when the car leaves what it has been seen to do.

Four signals per control period (:data:`SIGNALS`), two errors of what the controller expected and
two deviations from what the plan asked:

- ``e_r``, ``e_beta``: the **one-step errors** of the yaw rate and of the sideslip ``v_y / v_x``:
  the state the MPC now starts from (the measurement predicted over the delay) minus the one its
  last solution predicted for this instant (nominal model plus the tracking GP's mean);
- ``d_r``, ``d_beta``: the **deviations** of the yaw rate and of the sideslip ``atan(v_y / v_x)``
  from the reference. The sideslip counts only beyond the reference's (its distance from the
  interval between 0 and the reference's sideslip): a car that slides less than a plan that drifts
  is not losing its rear (measured: audi_hidden on the nominal circle_100 plan, which drifts at
  0.14 rad, was held eased for the whole lap by a deviation that never came back). A growing yaw oscillation under braking (load transfer, a measurement delay)
  shows here seconds before it shows in the one-step errors, which the model partly predicts
  (measured on a randomized Audi: yaw swings of +-0.3 rad/s on a straight for 2 s before the
  one-step error left its band, then a spin).

A **band** per signal is learned from the car's own laps (:func:`bands`: a high quantile of the
in-control samples of laps that were not lost, times a factor, between a floor and a cap). Before
the first lap the band is learned inside the lap (:class:`Envelope` keeps the quantile of the
samples so far inside the band, starting from the caps). The cap matters on a car whose normal
driving already has large errors (a lag the model does not know, low grip): a band learned from
its oscillations alone would never trigger. When the largest ``|signal| / band`` exceeds 1 in two
periods in a row (or 2 in one) the envelope **intervenes**: the reference speed factor ``rho`` of
the MPC falls by ``ease`` per period (down to ``rho_min``) and the longitudinal command is held
inside a gentle range (neither hard braking nor full drive: a sliding rear needs its grip for
cornering, and in the braking instability of a car with load transfer it is the braking that takes
it away), with at least ``plan_brake_share`` of the braking the plan itself asks for there (an
eased car must still make the corner), and the braking the corners ahead need from the speed the
car has (:func:`braking_needed`). Once the signals have been back inside the band for
``hold`` seconds, ``rho`` recovers by ``recover`` per period, except while the car, in a corner, is
slower than the eased reference (:func:`lagging_in_corner`). The envelope never changes the model:
it catches what the model has not learned yet. While it is active the tracking MPC predicts with
the nominal model alone where the tracking GP extrapolates (``nominal_when_active``; the test is
``gprace.timetrial.drive._novel``; the GPs still learn from the lap): on randomized BMWs with a
light rear, a GP trained on slower laps kept steering the sliding car into the 18 m hairpin of
gprace_ring and spun it, while on audi_hidden, whose nominal model lacks its downforce, switching
a well-fed GP off left the track (docs/decisions.md, issue 37, stops 44 and 45).

**A weave damps the steering.** Easing the speed does not stop a weave: the steering loop
itself going unstable, as it does on a car whose delay the controller predicts over is read too
short (a dead time tolerates about -0.015 to +0.03 s of error at 50 m/s, the shakedown's estimate
is off by 0.02 s RMS over the randomized family). :func:`weaving` watches the yaw-rate deviation
``d_r`` for six half-cycles of 0.15 to 0.45 s with a growing amplitude; while it sees one, and
``weave_seconds`` after, the tracking MPC's steering-rate weight is ``weave_damping`` times its
own (:attr:`Envelope.steer_damping`). Measured (issue 37, stops 55 and 56): a randomized Audi
with 0.1 s of measurement delay, read as 0.08 s, wove with a period of 0.5 to 0.6 s at 45 to
50 m/s, the amplitude growing from 0.03 to 0.5 rad/s over 3 s while the envelope eased the speed,
and spun (its shakedown) or left the track (a GP lap); the weave is seen at 0.08 to 0.09 rad/s,
on the shakedown that spun 0.7 s before the envelope's band was left. Damping the steering for
every intervention instead made one of four laps of a high-CoG Audi, which needs the loop's
bandwidth under braking, slide. A weave seen late (at 0.3 rad/s) went on growing damped: noise
near the zero crossings can restart the count of half-cycles (docs/decisions.md, stop 56). The
first weave also lengthens the delay the MPC predicts over by ``weave_delay`` for the rest of the
run (``gprace.timetrial.drive``; the loop's own estimate is unchanged): a weave is the car's sign
that its delay was read short. Measured (stop 58): randomized_05's lap lost at the braking for the
last corner, its 0.101 s read as 0.081 s, wove 3 to 5 times a lap and was lost on 1 of 4 noise
seeds; with 0.02 s added at the first weave it wove 1 or 2 times and completed on 4 of 4, on its
plan's time.

Counted per lap: ``interventions`` (onsets, at least ``hold`` apart), the periods eased and the
``weaves`` seen.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from pydantic import Field

from gprace.config import Frozen
from gprace.model.dynamics import Input, State


SIGNALS = ("e_r", "e_beta", "d_r", "d_beta")
D_R = SIGNALS.index("d_r")


class EnvelopeSettings(Frozen):
    """The run-time stability envelope (:mod:`gprace.mpc.stability`)."""

    enabled: bool = Field(True, description="watch the car and ease the reference when it leaves the band")
    quantile: float = Field(0.995, gt=0.5, lt=1.0, description="quantile of the clean laps' signals the band starts from")
    factor: float = Field(1.6, ge=1.0, description="band = factor x that quantile")
    floors: tuple[float, float, float, float] = Field((0.04, 0.004, 0.1, 0.03), description="smallest bands of "
                                                      "e_r [rad/s], e_beta [rad], d_r [rad/s], d_beta [rad]")
    caps: tuple[float, float, float, float] = Field((0.15, 0.015, 0.3, 0.06), description="widest bands (also the "
                                                    "bands before any lap), same order")
    ease: float = Field(0.02, gt=0, lt=1, description="fall of the speed factor per period while outside the band")
    rho_min: float = Field(0.75, gt=0, le=1, description="lowest speed factor")
    recover: float = Field(0.01, gt=0, description="rise of the speed factor per period once back inside")
    hold: float = Field(0.5, ge=0, description="seconds inside the band before the speed factor recovers [s]")
    recover_corner: float | None = Field(0.5, gt=0, description="the speed factor does not rise while the car is "
                                         "slower than the eased reference and uses more than this share of the "
                                         "plan's lateral limit (:func:`lagging_in_corner`; None: it always rises)")
    gentle_brake: float = Field(0.4, gt=0, le=1, description="share of the braking limit allowed while outside the band")
    plan_brake_share: float = Field(0.8, ge=0, le=1, description="share of the plan's own braking always allowed")
    gentle_drive: float = Field(0.3, gt=0, le=1, description="share of the drive limit allowed while outside the band")
    nominal_when_active: bool = Field(True, description="while the envelope is active, the tracking MPC predicts "
                                      "with the nominal model alone where the tracking GP extrapolates")
    warmup: int = Field(60, ge=0, description="samples before a band learned inside the lap replaces the caps")
    weave_damping: float = Field(3.0, ge=1.0, description="the tracking MPC's steering-rate weight is multiplied by "
                                 "this while the yaw rate weaves (:func:`weaving`; 1: never)")
    weave_delay: float = Field(0.02, ge=0, description="seconds added, once a weave is seen, to the delay the "
                               "tracking MPC predicts over, for the rest of the run (0: never)")
    weave_seconds: float = Field(2.0, ge=0, description="seconds the steering stays damped after the last weave "
                                 "detected [s]")


def signals(predicted_now: np.ndarray, predicted_before: np.ndarray | None, ref: np.ndarray) -> np.ndarray:
    """:data:`SIGNALS` of one period: the one-step errors of the yaw rate and the sideslip (what
    the MPC starts from now minus what its last solution predicted for now; 0 at the first period)
    and their deviations from the reference state ``ref``."""
    now = predicted_now
    vx = max(abs(float(now[State.V_X])), 1.0)
    beta = np.arctan2(now[State.V_Y], vx)
    out = np.zeros(4)
    if predicted_before is not None:
        out[0] = now[State.YAW_RATE] - predicted_before[State.YAW_RATE]
        out[1] = beta - np.arctan2(predicted_before[State.V_Y], vx)
    out[2] = now[State.YAW_RATE] - ref[State.YAW_RATE]
    beta_ref = np.arctan2(ref[State.V_Y], max(abs(float(ref[State.V_X])), 1.0))
    out[3] = beta - np.clip(beta, min(0.0, beta_ref), max(0.0, beta_ref))  # slip beyond the reference's only
    return out


def bands(samples: np.ndarray, settings: EnvelopeSettings) -> np.ndarray | None:
    """Bands (4,) from clean samples ``(n, 4)`` of the signals (None when fewer than 50)."""
    a = np.abs(np.asarray(samples, float))
    a = a[np.all(np.isfinite(a), axis=1)]
    if len(a) < 50:
        return None
    return np.clip(settings.factor * np.quantile(a, settings.quantile, axis=0), settings.floors, settings.caps)


WEAVE_CYCLES = 6             # consecutive half-cycles of the yaw-rate deviation that make a weave
WEAVE_HALF = (0.15, 0.45)    # their half-periods [s]: the steering loop's own mode (0.5 to 0.6 s measured)
WEAVE_GROWTH = 1.5           # the last half-cycle's amplitude over the first's
WEAVE_FLOOR = 0.08           # [rad/s] the last half-cycle's amplitude at least (sensor noise is below 0.01)
WEAVE_WINDOW = 4.0           # [s] of yaw-rate deviations kept (6 half-cycles of 0.45 s fit)


def weaving(d_r: np.ndarray, dt: float) -> bool:
    """Whether the yaw-rate deviations ``d_r`` (oldest first) end in a growing oscillation: the last
    ``WEAVE_CYCLES`` complete half-cycles (between sign changes) each last ``WEAVE_HALF`` seconds,
    the last amplitude is at least ``WEAVE_FLOOR`` and ``WEAVE_GROWTH`` times the first, the last
    three amplitudes grow, and the half-cycle under way is not yet longer than ``WEAVE_HALF``
    allows (vectorised over the window)."""
    d_r = np.asarray(d_r, float)
    sign = np.where(d_r >= 0.0, 1, -1)
    cross = np.flatnonzero(np.diff(sign)) + 1   # first sample of each new half-cycle
    if len(cross) < WEAVE_CYCLES + 1 or (len(d_r) - cross[-1]) * dt > WEAVE_HALF[1]:
        return False  # too few half-cycles, or the oscillation has stopped
    edges = cross[-WEAVE_CYCLES - 1:]
    half = np.diff(edges) * dt
    amp = np.maximum.reduceat(np.abs(d_r), edges[:-1])  # peak of each complete half-cycle
    return bool(np.all((half >= WEAVE_HALF[0]) & (half <= WEAVE_HALF[1])) and amp[-1] >= WEAVE_FLOOR
                and amp[-1] >= WEAVE_GROWTH * amp[0] and np.all(np.diff(amp[-3:]) > 0.0))


class Envelope:
    """Watches one run; :meth:`update` is called once per period after the MPC's step."""

    def __init__(self, settings: EnvelopeSettings, dt: float, band=None) -> None:
        self.settings, self.dt = settings, float(dt)
        self.fixed = band is not None and len(band) == len(SIGNALS)  # from earlier laps; else learned here
        self.band = np.array(band if self.fixed else settings.caps, float)
        self.rho = 1.0
        self.inside_for = np.inf  # seconds since the signals were last outside the band
        self.interventions = 0
        self.eased = 0
        self._seen: list[np.ndarray] = []
        self.active = False
        self._last = 0.0
        self.period = -1   # periods seen
        self.onsets: list[int] = []  # period of each intervention's onset
        self.scores: list[float] = []  # score of every period (the shakedown reads how calm the car was)
        self._d_r = deque(maxlen=int(round(WEAVE_WINDOW / self.dt)))  # the last WEAVE_WINDOW seconds of d_r
        self.weaves = 0               # weaves detected (onsets, at least weave_seconds apart)
        self.damped_for = 0.0         # seconds the steering stays damped

    def update(self, sig: np.ndarray, in_control: bool = True, lagging: bool = False) -> float:
        """Score of this period (``max |signal| / band``); moves ``rho`` and counts onsets. ``rho``
        does not rise while the car is ``lagging`` behind the eased reference in a corner
        (:func:`lagging_in_corner`)."""
        st = self.settings
        self.period += 1
        score = float(np.max(np.abs(sig) / self.band))
        self.scores.append(score)
        # a slide persists, sensor noise does not: outside means two periods in a row, or twice the band
        outside = (score > 1.0 and self._last > 1.0) or score > 2.0
        self._last = score
        if not outside and not self.fixed and in_control:
            self._learn(sig)
        if not st.enabled:
            return score
        self._watch_weave(float(sig[D_R]))
        if outside:
            if not self.active and self.inside_for >= st.hold:
                self.interventions += 1
                self.onsets.append(self.period)
            self.active = True
            self.inside_for = 0.0
            self.rho = max(st.rho_min, self.rho - st.ease)
        else:
            self.inside_for += self.dt
            if self.inside_for >= st.hold:
                self.active = False
                if not lagging:
                    self.rho = min(1.0, self.rho + st.recover)
        if self.rho < 1.0:
            self.eased += 1
        return score

    @property
    def steer_damping(self) -> float:
        """Factor on the tracking MPC's steering-rate weight this period (``weave_damping`` while a
        weave was seen in the last ``weave_seconds``, else 1)."""
        return self.settings.weave_damping if self.damped_for > 0.0 else 1.0

    def _watch_weave(self, d_r: float) -> None:
        """Keep the last ``WEAVE_WINDOW`` seconds of ``d_r``; a weave (:func:`weaving`) damps the steering."""
        self._d_r.append(d_r)
        self.damped_for = max(0.0, self.damped_for - self.dt)
        if weaving(np.fromiter(self._d_r, float, len(self._d_r)), self.dt):
            if self.damped_for == 0.0:
                self.weaves += 1
            self.damped_for = self.settings.weave_seconds

    def _learn(self, sig: np.ndarray) -> None:
        """The band inside the first lap: from the clean samples so far (updated every 20)."""
        self._seen.append(np.asarray(sig, float))
        n = len(self._seen)
        if n >= self.settings.warmup and n % 20 == 0:
            b = bands(np.asarray(self._seen), self.settings)
            if b is not None:
                self.band = b

    def input_bounds(self, u_lo: np.ndarray, u_hi: np.ndarray, plan_brake: float = 0.0,
                     lateral: float = 0.0, lateral_limit: float = np.inf, rear: float = 0.0,
                     brake_limit: float | None = None, needed: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The MPC's input bounds for the next period: the longitudinal range narrowed while active.

        Braking follows the friction ellipse of the plan (:func:`brake_share`): ``lateral`` is the
        lateral acceleration the car uses now (``|v_x r|``, m/s^2), ``lateral_limit`` the plan's
        lateral limit and ``brake_limit`` its braking limit (what the car has been shown to take; None:
        the command's bound); the braking left by cornering stays allowed, never less than
        ``gentle_brake`` of the limit, and ``plan_brake_share`` of the hardest braking the plan
        asks for over the horizon (before any easing) always, so an eased car still makes the
        corner; and the braking ``needed`` for the plan's corners ahead from the speed the car has
        (:func:`braking_needed`) always: the plan's share assumes a car at the plan's speed.
        Measured on a randomized Audi (randomized_26, CoG 0.54 m) eased after a 57 m/s flick: held
        to 0.8 of the plan's braking it reached the hairpin 6 m/s faster than the plan and left the
        track (docs/decisions.md, issue 37, stop 51). Measured: with braking held to half the limit
        the oracle lap of audi_hidden ran off at the hairpin (s = 450 m); with no limit a worn-rear
        BMW sliding out of a corner braked at full force for the eased speed and spun (s = 1562 m);
        with braking held to 0.4 of the limit whatever the car did, audi_hidden on the circle_100
        plan could not slow to the eased speed on the straight-running moments and left the track
        (docs/decisions.md, issue 37, tt3).
        The ellipse is the plan's, not the nominal tire's circle: a shakedown plan at 7.1 m/s^2
        lateral and 4.0 braking (a randomized BMW, rear grip 0.88, CoG 0.58 m) was eased in the
        18 m hairpin, and the nominal circle (10.3 m/s^2) let the MPC brake at 3.7 m/s^2 while the
        car turned at 5.7: the rear let go and the car spun, where the plan's ellipse allows 2.4
        (docs/decisions.md, issue 37, stop 64).

        A rear axle past its peak (``rear``, the rear slip angle over the nominal tire's peak slip
        angle, at least 1) is an exception: it has no grip left for braking, and braking moves load
        off it. Braking is then held to ``gentle_brake`` of the braking limit, and neither the
        plan's own braking nor the braking ``needed`` is kept. ``|v_x r|`` cannot see this: in a
        slide the car's speed falls, ``|v_x r|`` falls with it and the friction circle widened the
        braking while the rear stayed saturated.
        Measured on the shakedown of a randomized Audi with a light rear (grip 0.85 of the front's
        1.04) entering the 18 m hairpin of gprace_ring: with the circle the eased MPC braked at 5 to
        6.4 m/s^2 through a slide of v_y = -4.7 m/s and spun the car; held to 0.4 of the plan's 6.1
        m/s^2 while the rear was past its peak, the lap completed (docs/decisions.md, issue 37, stop 49).
        """
        if not self.active:
            return u_lo, u_hi
        st = self.settings
        lo, hi = u_lo.copy(), u_hi.copy()
        limit = -u_lo[Input.A_X] if brake_limit is None else min(float(brake_limit), -u_lo[Input.A_X])
        if rear >= 1.0:
            lo[Input.A_X] = -st.gentle_brake * limit
        else:
            share = brake_share(lateral, lateral_limit, st.gentle_brake)
            lo[Input.A_X] = max(u_lo[Input.A_X], min(-share * limit, st.plan_brake_share * plan_brake, -needed))
        hi[Input.A_X] = st.gentle_drive * u_hi[Input.A_X]
        return lo, hi


def lagging_in_corner(x: np.ndarray, x_ref: np.ndarray, lateral_limit: float, corner: float | None) -> bool:
    """Whether the car (state ``x``, the measurement predicted over the delay) is slower than the
    eased reference ``x_ref`` (its next state) while it uses more than ``corner`` of the plan's
    ``lateral_limit`` [m/s^2] (``|v_x r|``); False when ``corner`` is None.

    A rising speed factor makes the reference accelerate by ``v dr/dt`` (0.2 times the speed per
    second) on top of the plan. In a corner the car cannot follow (the friction ellipse holds its
    drive) and the gap it falls behind grows; the MPC then drives to close it at the apex, where
    combined slip takes the grip the rear needs. Measured on a randomized BMW with a light rear
    (randomized_09, rear grip 0.87 of the front's 1.02): eased on the way into the 18 m hairpin,
    the factor rose from 0.75 to 1 in 1.25 s while the car fell 1 to 1.5 m/s behind, the MPC asked
    for +1.4 m/s^2 at a lateral 0.55 of the limit and the rear let go at the apex, on 3 of 3 noise
    seeds; with the rise held while the car lags in a corner the lap completes on 3 of 3 (71 to
    72 s for a 70.1 s plan). Held wherever the car lags, the factor stayed at 0.75 along a whole
    straight, where a car at full drive always lags a plan at its drive limit: 76 s
    (docs/decisions.md, issue 37, stop 58)."""
    if corner is None or x[State.V_X] >= x_ref[State.V_X]:
        return False
    return abs(float(x[State.V_X] * x[State.YAW_RATE])) > corner * lateral_limit


def brake_share(lateral: float, grip: float, gentle: float) -> float:
    """Share of the braking limit the friction circle leaves to a car using ``lateral`` m/s^2 of
    ``grip`` m/s^2 sideways: ``sqrt(1 - (lateral / grip)^2)``, at least ``gentle``. A car running
    straight may brake fully; one at the limit of grip (a slide) only gently."""
    use = min(1.0, abs(float(lateral)) / float(grip)) if grip > 0 else 1.0
    return max(float(gentle), float(np.sqrt(1.0 - use * use)))


def corners(s_plan: np.ndarray, v_plan: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(s, v)`` of a plan's corners: the local minima of its speed ``v_plan(s_plan)`` (a run of
    equal speeds counts from its first sample)."""
    v_plan = np.asarray(v_plan, float)
    start = np.r_[0, np.flatnonzero(np.diff(v_plan)) + 1]  # first sample of each run of equal speeds
    vals = v_plan[start]
    corner = start[(vals < np.roll(vals, 1)) & (vals < np.roll(vals, -1))]
    return np.asarray(s_plan, float)[corner], v_plan[corner]


def braking_needed(plan_corners: tuple[np.ndarray, np.ndarray], length: float, s: float, v: float, reach: float,
                   near: float = 0.0) -> float:
    """Constant deceleration [m/s^2, >= 0] that brings a car at ``s`` with speed ``v`` down to the
    speed of each of the plan's corners (:func:`corners`) between ``near`` and ``reach`` metres
    ahead (the track closes after ``length``): the largest ``(v^2 - v_c^2) / (2 d)``. Only the
    corners count: a car slightly faster than the plan right now need not match it metre by metre
    (that would ask for any braking at all); nor a corner closer than ``near``, which the car is
    already turning into (braking for it there takes the grip the corner needs)."""
    s_c, v_c = plan_corners
    d = np.mod(s_c - s, length)
    ahead = (d > max(near, 0.0)) & (d <= reach)
    if not ahead.any():
        return 0.0
    return float(max(0.0, np.max((v * v - v_c[ahead] ** 2) / (2.0 * d[ahead]))))
