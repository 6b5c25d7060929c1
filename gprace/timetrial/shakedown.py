"""Iteration 0 as a shakedown: start where any plausible car is safe, widen from what the car shows.

A team with a new car does not start at a fixed share of its paper limits. Iteration 0 drives the
minimum-curvature line (:func:`gprace.plan.racing_line`) at a speed profile whose friction limits
``(lateral, drive, brake)`` [m/s^2] start at ``start`` (0.5) of the nominal model's own limits
(braking at most ``start_brake_g`` = 0.5 g): on
the documented family of cars (grip per axle down to 0.8 of nominal, a CoG up to 0.6 m with
combined slip, 80 ms of steering lag) that leaves at least a third of the grip unused on every
axis. Every ``every`` seconds of the lap the :class:`Shakedown` (a supervisor of
:func:`gprace.timetrial.drive.drive`) looks at the samples driven since the limits last changed and
widens each axis by ``step`` when

- the car actually used ``reach`` of that axis' limit (the level has been shown, not assumed),
- no tire came near its peak: the robust peak slip angle of either axle stays below ``hold`` of the
  nominal tire's peak slip angle (which does not depend on the friction, so it holds on a car with
  less grip than the model),
- the stability envelope (:mod:`gprace.mpc.stability`) did not intervene, nor did its score come
  to ``calm`` (0.8) of its band: a car that has begun to wobble under braking is at its edge before
  the envelope intervenes (measured on randomized Audis with a high CoG or a light rear: the
  braking widened from 6.5 to 7.2 m/s^2 after windows whose score reached 0.82 to 0.90, and the
  car then spun under braking from 58 m/s or ran wide out of the slide; docs/decisions.md,
  issue 37, stop 49),
- the lateral limit stays below ``safety`` times the grip the car shows: per axle, the force the
  measured accelerations require (from the lateral and yaw balance) over the nominal tire's force
  at the measured slip angle, in every phase (braking, coasting, driving) with enough samples
  (:func:`axle_grip`). A car with a worn rear or with load transfer under braking shows it there
  long before it slides.

An envelope intervention narrows the axis the car was using by ``back`` (the lateral one by at
least half of it; once per plan driven) and ends the widening for the lap.
When the limits change, the speed profile is recomputed on the same line and the MPC tracks it
from the next period (a few milliseconds). So the iteration-0 lap is as fast as the car showed it
can go, and it starts slow. The limits it ends with are the plan's limits (``plan.meta``), from
which the GP iterations widen further (:mod:`gprace.timetrial.grip`).

The delay matters from the first metre: on cars of the randomized family (measurement delay up to
two periods, steering lag up to 80 ms, a rate-limited actuator) the MPC that predicted over no
delay started a growing yaw oscillation on the start straight and spun the car within 4 s at half
the nominal limits; predicting over 80 to 120 ms it completed the lap. So the lap starts with the
known delay, else an estimate from the calibration run the loop already has (weaving at 0.9 of the
reference profile, slower on a car that spins there: :mod:`gprace.timetrial.iterate.data`), else
``DELAY_PRIOR``; at 200, 400, 800 ... periods the delay is estimated again
from the lap so far and the calibration run together (:func:`gprace.mpc.delay.estimate`) and the
MPC predicts over the new value.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from gprace.config import G, Frozen
from gprace.model.dynamics import Input, State
from gprace.mpc.delay import PRIOR


class ShakedownSettings(Frozen):
    """Iteration 0's shakedown (:mod:`gprace.timetrial.shakedown`)."""

    start: float = Field(0.5, gt=0, le=1, description="share of the nominal model's limits at the start")
    start_brake_g: float = Field(0.5, gt=0, description="braking at the start at most this many g")
    step: float = Field(0.1, ge=0, lt=1, description="widening of an axis per update")
    reach: float = Field(0.85, gt=0, le=1, description="share of an axis' limit the car must have used before it widens")
    hold: float = Field(0.8, gt=0, description="slip use (either axle, share of the nominal peak slip angle) that "
                        "stops the widening")
    calm: float = Field(0.8, gt=0, description="stability-envelope score (share of its band) that stops the widening")
    back: float = Field(0.15, ge=0, lt=1, description="narrowing of every axis after an envelope intervention")
    safety: float = Field(0.85, gt=0, le=1, description="share of the shown grip the lateral limit may reach")
    every: float = Field(2.0, gt=0, description="seconds between updates [s]")
    cap: float = Field(1.0, gt=0, description="at most this share of the nominal model's limits")
    estimate_delay: bool = Field(True, description="estimate the total delay from the yaw response during the lap")
    first_estimate: int = Field(200, ge=20, description="period of the first estimate inside the lap (then doubling)")


MIN_SLIP_SAMPLES = 40   # samples of an axle and phase the grip ratio needs
DELAY_PRIOR = PRIOR     # [s] predicted over before anything is known (gprace.mpc.delay.PRIOR)
QUIET_KAPPA = 0.004     # largest centre-line curvature [1/m] over the horizon where a faster profile is taken
DRIVE_LEAD = 0.2        # the drive limit's share of nominal may exceed the lateral one by this much
SLIP_WINDOW = (0.2, 1.5)  # slip angles (share of the nominal peak) the grip ratio uses


def axle_grip(X: np.ndarray, U: np.ndarray, dt: float, model, ok: np.ndarray) -> dict[str, float]:
    """Per axle and phase, the grip the car shows against the nominal model (vectorised).

    The axle forces the measured accelerations require: ``F_yf cos(delta) + F_yr = m (dv_y/dt +
    r v_x)`` and ``l_f F_yf cos(delta) - l_r F_yr = I_z dr/dt`` (central differences), against the
    nominal tire's force at the measured slip angle on static loads; the ratio is the least-squares
    slope over the samples ``ok`` whose slip angle is inside ``SLIP_WINDOW`` of the nominal peak.
    Keys ``front_brake``, ``rear_coast`` ... (phases by the acceleration command: below -1 m/s^2,
    within +-1, above 1); a phase with fewer than ``MIN_SLIP_SAMPLES`` samples is left out.
    """
    from gprace.model.dynamics import peak_slip
    from gprace.mpc.tracking import front_heading, rear_slip_rows

    p = model.params
    vx, vy, r = X[:, State.V_X], X[:, State.V_Y], X[:, State.YAW_RATE]
    delta, ax = U[:, Input.DELTA], U[:, Input.A_X]
    a_y = np.gradient(vy, dt) + r * vx
    r_dot = np.gradient(r, dt)
    L = p.lf + p.lr
    force = {"rear": (p.lf * p.m * a_y - p.iz * r_dot) / L,
             "front": (p.lr * p.m * a_y + p.iz * r_dot) / L / np.cos(delta)}
    slip = {"front": delta - front_heading(X, p.lf, p.vmin), "rear": rear_slip_rows(X, p.lr, p.vmin)[0]}
    tire = {"front": (p.fz_front, p.bf, p.cf), "rear": (p.fz_rear, p.br, p.cr)}
    phases = {"brake": ax < -1.0, "coast": np.abs(ax) <= 1.0, "drive": ax > 1.0}
    out = {}
    for axle, a in slip.items():
        fz, b, c = tire[axle]
        nominal = p.mu * fz * np.sin(c * np.arctan(b * a))
        use = np.abs(a) / peak_slip(b, c)
        window = ok & (use > SLIP_WINDOW[0]) & (use < SLIP_WINDOW[1])
        for phase, m in phases.items():
            sel = window & m
            if sel.sum() >= MIN_SLIP_SAMPLES:
                out[f"{axle}_{phase}"] = float(np.sum(force[axle][sel] * nominal[sel]) / np.sum(nominal[sel] ** 2))
    return out


def slip_use(X: np.ndarray, U: np.ndarray, model, ok: np.ndarray, quantile: float = 0.99) -> float:
    """Robust peak slip angle of the more used axle over the nominal tire's peak slip angle."""
    from gprace.timetrial.grip import front_use, rear_use

    if ok.sum() < 10:
        return float("nan")
    return float(max(np.quantile(front_use(X[ok], U[ok], model), quantile),
                     np.quantile(rear_use(X[ok], model), quantile)))


class Shakedown:
    """The supervisor of iteration 0's drive: widens the speed profile's limits from what the car shows.

    ``line`` is the racing line, ``nominal`` the nominal model's limits ``(lateral, drive, brake)``.
    Call :meth:`plan` for the first plan; the drive loop calls the object every period.
    """

    def __init__(self, line, model, nominal, settings: ShakedownSettings, dt: float, delay_known: bool = False,
                 delay: float = float("nan"), reference: tuple = ()) -> None:
        self.line, self.model, self.settings, self.dt = line, model, settings, float(dt)
        self.nominal = np.asarray(nominal, dtype=float)
        self.limits = settings.start * self.nominal
        # braking starts at most at start_brake_g: under braking, load transfer takes the rear's
        # grip, and a car with a light, worn rear diverges in yaw on a straight (measured: a
        # rear at 0.8, CoG 0.6 m, 80 ms lag spun at -7 m/s^2 from 48 m/s, half the Audi's -14)
        self.limits[2] = min(self.limits[2], settings.start_brake_g * G)
        self.cap = settings.cap * self.nominal
        self.every = max(int(round(settings.every / dt)), 1)
        self.since = 0            # first sample at the current limits
        self.frozen = False       # an intervention ended the widening for this lap
        self.interventions = 0
        self.delay_known = delay_known
        self.delay = float(delay)  # the latest estimate (NaN: none yet)
        self.reference = reference  # ((X, U, mask), ...) of earlier recordings of the car (the calibration run)
        self.log: list[dict] = []  # one entry per change of the limits
        self.pending = None  # a plan waiting for a quiet stretch of track
        self.swapped = 0  # period the current plan was taken
        self.next_estimate = settings.first_estimate  # period of the next delay estimate
        self.seen_onsets = 0

    def plan(self):
        from gprace.plan import line_plan

        return line_plan(self.line, self.model, self.limits, {"shakedown": True})

    def __call__(self, k: int, Y: np.ndarray, U: np.ndarray, mpc, env) -> None:
        from gprace.timetrial.learning import in_control

        if self.pending is not None and self._quiet(Y[k - 1], mpc):
            mpc.set_plan(self.pending)
            self.pending = None
            self.swapped = k
        if k % self.every:
            return
        st = self.settings
        ok = in_control(Y)
        if len(env.onsets) > self.seen_onsets:  # the car left the band: back off, stop widening
            new = env.onsets[self.seen_onsets:]
            self.seen_onsets = len(env.onsets)
            if self.pending is None and k - self.swapped >= self.every:
                # once per plan actually driven (a narrower plan waiting for a straight is not yet
                # the car's fault): the axis the car was using when it left the band backs off
                self._change(k, self.limits * (1.0 - st.back * self._blame(U[new])), "envelope intervention", mpc)
            self.frozen = True
            return
        if st.estimate_delay and not self.delay_known and k >= self.next_estimate:
            self.next_estimate *= 2  # at 200, 400, 800 ... periods: each estimate takes ~0.1 s
            from gprace.mpc.delay import estimate
            from gprace.timetrial.grip import below_peak

            dead, lag = estimate(Y, U, self.dt, ok & below_peak(Y, U, self.model), more=self.reference)
            if np.isfinite(dead):
                self.delay = dead + lag
                mpc.set_delay(min(self.delay, mpc.N * mpc.dt))
        if self.frozen:
            return
        win = slice(self.since, k)
        Yw, Uw, okw = Y[win], U[win], ok[win]
        if okw.sum() < self.every // 2:
            return
        from gprace.timetrial.grip import envelope_of

        shown = envelope_of(Yw, Uw, self.dt * np.arange(len(Yw)), okw)
        use = slip_use(Yw, Uw, self.model, okw)
        if not np.all(np.isfinite(shown)) or not np.isfinite(use) or use >= st.hold:
            return
        if max(env.scores[win], default=0.0) >= st.calm:  # the car came near the edge of its band
            return
        grip = axle_grip(Y[:k], U[:k], self.dt, self.model, ok)
        lat_cap = st.safety * min(grip.values()) * self.nominal[0] if grip else np.inf
        new = np.where(shown >= st.reach * self.limits, self.limits * (1.0 + st.step), self.limits)
        new[0] = min(new[0], max(lat_cap, self.limits[0]))  # the shown grip may stop the widening
        # drive takes lateral grip from the driven axle (combined slip): on straights the drive
        # limit is always "reached", so it may lead the lateral level by DRIVE_LEAD only
        share = new / self.nominal
        new[1] = min(new[1], (share[0] + DRIVE_LEAD) * self.nominal[1])
        new = np.minimum(new, self.cap)
        if lat_cap < self.limits[0]:  # the car shows less grip than the level asks: lower it now
            new[0] = max(lat_cap, 0.6 * st.start * self.nominal[0])
        if np.any(np.abs(new - self.limits) > 1e-9):
            self._change(k, new, "widened" if np.all(new >= self.limits) else "grip shown", mpc, grip=grip, use=use)

    def _blame(self, u: np.ndarray) -> np.ndarray:
        """Per axis (lateral, drive, brake), how much of the back-off it takes: the axis the car was
        using at the interventions' onsets fully, the lateral one at least half (a slide is lateral)."""
        ax = u[:, Input.A_X]
        share = np.array([0.5, np.mean(ax > 0.3 * self.limits[1]), np.mean(ax < -0.3 * self.limits[2])])
        share[0] = max(0.5, 1.0 - share[1] - share[2])
        return share

    def _change(self, k: int, limits: np.ndarray, why: str, mpc, **extra) -> None:
        self.limits = np.asarray(limits, dtype=float)
        self.since = k
        self.log.append({"t": k * self.dt, "limits": [float(v) for v in self.limits], "why": why,
                         **{key: v for key, v in extra.items()}})
        self.pending = self.plan()

    def _quiet(self, y: np.ndarray, mpc) -> bool:
        """A new speed profile is taken on a straight that is not a braking zone: switched in a
        corner, the reference's steady-state sideslip and heading jump and the car wobbles
        (measured: yaw swings of +-0.4 rad/s on audi_hidden after a switch at a hairpin's exit).
        A narrower one waits too: the envelope has already eased the reference meanwhile."""
        s = float(y[State.S])
        ahead = s + max(float(y[State.V_X]), 1.0) * mpc.N * mpc.dt * np.linspace(0.0, 1.0, 12)
        if np.max(np.abs(mpc.track.kappa(ahead))) > QUIET_KAPPA:
            return False
        _, U = mpc.plan.at_time(mpc.plan.time_at(s) + mpc.dt * np.arange(mpc.N))
        return bool(U[:, Input.A_X].min() >= 0.0)
