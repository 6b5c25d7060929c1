"""The stability envelope: ease the reference when the car leaves what it has been seen to do.

Two signals per control period, both errors of what the controller expected:

- **yaw-rate error** ``e_r``: the yaw rate the MPC now starts from (the measurement predicted over
  the delay) minus the one its last solution predicted for this instant (nominal model plus the
  tracking GP's mean): the one-step error of the model the car is being driven with;
- **sideslip error** ``e_beta``: the measured sideslip ``atan(v_y / v_x)`` minus the reference's.

A **band** per signal is learned from the car's own laps (:func:`bands`: a high quantile of the
in-control samples of laps that were not lost, times a factor, between a floor and a cap). Before
the first lap the band is learned inside the lap (:class:`Envelope` keeps the quantile of the
samples so far inside the band, starting from the caps). The cap matters on a car whose normal
driving already has large one-step errors (a lag the model does not know, low grip): a band
learned from its oscillations alone would never trigger. When the larger of ``|e_r| / band_r`` and ``|e_beta| /
band_beta`` exceeds 1 in two periods in a row (or 2 in one) the envelope **intervenes**: the reference speed factor ``rho`` of the MPC
falls by ``ease`` per period (down to ``rho_min``) and the longitudinal command is held inside a
gentle range (neither hard braking nor full drive: a sliding rear needs its grip for cornering, and
in the braking instability of a car with load transfer it is the braking that takes it away), but
never below the braking the plan itself asks for there (an eased car must still make the corner). Once
the signals have been back inside the band for ``hold`` seconds, ``rho`` recovers by ``recover``
per period. The envelope never changes the model: it catches what the model has not learned yet.

Counted per lap: ``interventions`` (onsets, at least ``hold`` apart) and the periods eased.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from gprace.config import Frozen
from gprace.model.dynamics import Input, State


class EnvelopeSettings(Frozen):
    """The run-time stability envelope (:mod:`gprace.mpc.stability`)."""

    enabled: bool = Field(True, description="watch the car and ease the reference when it leaves the band")
    quantile: float = Field(0.995, gt=0.5, lt=1.0, description="quantile of the clean laps' errors the band starts from")
    factor: float = Field(1.6, ge=1.0, description="band = factor x that quantile")
    floor_r: float = Field(0.04, gt=0, description="smallest band of the yaw-rate error [rad/s]")
    floor_beta: float = Field(0.004, gt=0, description="smallest band of the sideslip error [rad]")
    cap_r: float = Field(0.15, gt=0, description="widest band of the yaw-rate error [rad/s] (also the band before "
                         "any lap)")
    cap_beta: float = Field(0.015, gt=0, description="widest band of the sideslip error [rad] (also the band before "
                            "any lap)")
    ease: float = Field(0.02, gt=0, lt=1, description="fall of the speed factor per period while outside the band")
    rho_min: float = Field(0.75, gt=0, le=1, description="lowest speed factor")
    recover: float = Field(0.01, gt=0, description="rise of the speed factor per period once back inside")
    hold: float = Field(0.5, ge=0, description="seconds inside the band before the speed factor recovers [s]")
    gentle_brake: float = Field(0.4, gt=0, le=1, description="share of the braking limit allowed while outside the band "
                                "(more where the plan itself brakes harder)")
    gentle_drive: float = Field(0.3, gt=0, le=1, description="share of the drive limit allowed while outside the band")
    warmup: int = Field(60, ge=0, description="samples before a band learned inside the lap replaces the floors")


def signals(predicted_now: np.ndarray, predicted_before: np.ndarray | None) -> tuple[float, float]:
    """``(e_r, e_beta)`` of one period: the one-step errors of the yaw rate and of the sideslip
    ``v_y / v_x`` (what the MPC starts from now minus what its last solution predicted for now)."""
    if predicted_before is None:
        return 0.0, 0.0
    now, before = predicted_now, predicted_before
    vx = max(abs(float(now[State.V_X])), 1.0)
    return (float(now[State.YAW_RATE] - before[State.YAW_RATE]),
            float(np.arctan2(now[State.V_Y], vx) - np.arctan2(before[State.V_Y], vx)))


def bands(e_r: np.ndarray, e_beta: np.ndarray, settings: EnvelopeSettings) -> tuple[float, float] | None:
    """Bands ``(band_r, band_beta)`` from clean samples' errors (None when fewer than 50)."""
    e_r, e_beta = np.abs(np.asarray(e_r, float)), np.abs(np.asarray(e_beta, float))
    ok = np.isfinite(e_r) & np.isfinite(e_beta)
    if ok.sum() < 50:
        return None
    q, st = settings.quantile, settings
    return (float(np.clip(st.factor * np.quantile(e_r[ok], q), st.floor_r, st.cap_r)),
            float(np.clip(st.factor * np.quantile(e_beta[ok], q), st.floor_beta, st.cap_beta)))


class Envelope:
    """Watches one run; :meth:`update` is called once per period after the MPC's step."""

    def __init__(self, settings: EnvelopeSettings, dt: float, band: tuple[float, float] | None = None) -> None:
        self.settings, self.dt = settings, float(dt)
        self.fixed = band is not None  # a band from earlier laps; else learned inside this lap
        self.band = np.array(band if band is not None else (settings.cap_r, settings.cap_beta), float)
        self.rho = 1.0
        self.inside_for = np.inf  # seconds since the signals were last outside the band
        self.interventions = 0
        self.eased = 0
        self._seen: list[tuple[float, float]] = []
        self.active = False
        self._last = 0.0
        self.period = -1   # periods seen
        self.onsets: list[int] = []  # period of each intervention's onset

    def update(self, e_r: float, e_beta: float, in_control: bool = True) -> float:
        """Score of this period (``max |e| / band``); moves ``rho`` and counts onsets."""
        st = self.settings
        self.period += 1
        score = max(abs(e_r) / self.band[0], abs(e_beta) / self.band[1])
        # a slide persists, sensor noise does not: outside means two periods in a row, or twice the band
        outside = (score > 1.0 and self._last > 1.0) or score > 2.0
        self._last = score
        if not st.enabled:
            if not outside and not self.fixed and in_control:
                self._learn(e_r, e_beta)
            return score
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
                self.rho = min(1.0, self.rho + st.recover)
            if not self.fixed and in_control:
                self._learn(e_r, e_beta)
        if self.rho < 1.0:
            self.eased += 1
        return score

    def _learn(self, e_r: float, e_beta: float) -> None:
        """The band inside the first lap: from the clean samples so far (updated every 20)."""
        self._seen.append((e_r, e_beta))
        n = len(self._seen)
        if n >= self.settings.warmup and n % 20 == 0:
            a = np.asarray(self._seen)
            b = bands(a[:, 0], a[:, 1], self.settings)
            if b is not None:
                self.band = np.array(b)

    def input_bounds(self, u_lo: np.ndarray, u_hi: np.ndarray, plan_brake: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The MPC's input bounds for the next period: the longitudinal range narrowed while active.

        ``plan_brake`` is the hardest braking the plan itself asks for over the horizon (before
        any easing): that much braking stays allowed, so a car eased at a corner's entry still
        makes the corner. Measured: with braking held to half the limit the oracle lap of
        audi_hidden ran off at the hairpin (s = 450 m); with no limit a worn-rear BMW sliding out
        of a corner braked at full force for the eased speed and spun (s = 1562 m).
        """
        if not self.active:
            return u_lo, u_hi
        lo, hi = u_lo.copy(), u_hi.copy()
        lo[Input.A_X] = max(u_lo[Input.A_X], min(self.settings.gentle_brake * u_lo[Input.A_X], plan_brake))
        hi[Input.A_X] = self.settings.gentle_drive * u_hi[Input.A_X]
        return lo, hi
