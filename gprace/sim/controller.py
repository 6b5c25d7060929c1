"""A simple, robust reference driver: speed profile plus lateral feedback in Frenet coordinates.

It is what produces recordings before the MPCs exist, so it has to work on any shipped car and
track without tuning:

* **Speed profile** (:func:`speed_profile`): the friction-limited speed of the path,
  ``v^2 |kappa_path| <= a_y,max = speed_scale * mu * g``, then a forward pass (drive limit
  ``0.8 accel_max``) and a backward pass (braking limit ``0.8 min(-accel_min, a_y,max)``; the
  remaining 20 % leave the speed feedback authority to catch up), both on the
  friction circle ``a_x <= a_lim sqrt(1 - (a_y/a_y,max)^2)``. Closed tracks are solved on three
  tiled laps and the middle one kept, so the profile is periodic. (docs/reference.md#measured: a profile limited
  only by curvature makes the car spin; braking must start before the corner.)
* **Weaving** (optional, to excite the lateral dynamics): the target line
  ``e_y,ref(s) = A h(s) sin(2 pi s / lambda)`` with ``h = min(w_left, w_right) - width/2`` the
  usable half width; its curvature ``e_y,ref''`` is added to the track's in the speed profile.
* **Lateral law**: steady-state feed-forward ``delta_ff = L kappa_path + K_us v^2 kappa_path``
  (curvature read ``T_FF = 0.2 s`` ahead: the yaw rate builds up after the wheels turn)
  (understeer gradient ``K_us = m (l_r/C_f - l_f/C_r) / L`` of the nominal linear tires,
  ``C = mu F_z B C``) plus a pure-pursuit-like PD on the lateral error and the course-angle error
  ``chi = e_psi + atan(v_y/v_x) - e_psi,ref`` at a look-ahead ``L_a = max(v T_la, 3 L)``:
  ``delta = delta_ff - 2 L (e_y - e_y,ref + L_a chi) / L_a^2``. The gains fall with speed as
  ``1/v^2`` and ``1/v``, which keeps the closed loop damped from parking speed to 70 m/s.
  A yaw-rate feedback ``-k_r (r - v kappa_path)`` with ``k_r = 4 I_z / (l_f C_f)`` (about 4 1/s of
  extra yaw damping) keeps a car stable that is oversteering (above its critical speed), as a
  car with hidden rear-grip loss under heavy braking is.
* **Longitudinal law**: ``a_x = v dv_ref/ds + k_v (v_ref - v_x)`` with the reference read
  ``T_v`` seconds ahead (the car cannot brake instantly).

Steering is clipped to ``steering_max`` and rate-limited to ``steering_rate_max``; ``a_x`` to
``[accel_min, accel_max]`` and to the friction circle at the measured lateral acceleration
``v_x r`` (at least 30 % of the limits stay available, so the car can always slow down). Track data are tabulated once, so one call costs a few microseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gprace.config import G, VehicleConfig

T_LOOKAHEAD = 0.5
"""Look-ahead time of the lateral law [s]."""

T_SPEED_PREVIEW = 0.3
"""How far ahead the speed reference is read [s]."""

T_FF = 0.2
"""Preview of the curvature feed-forward [s] (yaw builds up after the steering moves)."""

K_SPEED = 2.0
"""Speed-error gain [1/s]."""

LONG_MARGIN = 0.8
"""Share of the longitudinal limits the speed profile plans with (the rest is feedback authority)."""

MIN_LONG_SHARE = 0.3
"""Share of the longitudinal limits always available, even at full lateral acceleration."""

YAW_DAMPING = 16.0
"""Rate [1/s] of the yaw-rate feedback ``-k_r (r - v kappa_path)``, ``k_r = rate I_z / (l_f C_f)``."""


@dataclass(frozen=True)
class Profile:
    """Tabulated reference along the track (uniform ``s`` grid covering ``[0, L]``)."""

    s: np.ndarray
    v: np.ndarray
    dvds: np.ndarray
    kappa: np.ndarray  # track curvature
    kappa_path: np.ndarray  # curvature of the (weaving) target line
    ey_ref: np.ndarray
    epsi_ref: np.ndarray
    wl: np.ndarray
    wr: np.ndarray


def weave_line(track, s: np.ndarray, vehicle: VehicleConfig, amplitude: float, wavelength: float):
    """``(e_y_ref, de/ds, d2e/ds2)`` of the weaving target line at ``s`` (zeros when amplitude 0)."""
    h = np.maximum(np.minimum(track.width_left(s), track.width_right(s)) - 0.5 * vehicle.width, 0.0)
    w = 2.0 * np.pi / wavelength
    a = amplitude * h
    return a * np.sin(w * s), a * w * np.cos(w * s), -a * w * w * np.sin(w * s)


def speed_profile(s: np.ndarray, kappa_path: np.ndarray, vehicle: VehicleConfig, speed_scale: float, closed: bool) -> np.ndarray:
    """Friction-circle forward-backward speed profile on the uniform grid ``s`` (see module doc)."""
    lim = vehicle.limits
    ay_max = speed_scale * vehicle.mu * G
    ak = np.maximum(np.abs(kappa_path), 1e-9)
    v_lat = np.minimum(np.sqrt(ay_max / ak), lim.speed_max)
    a_drive = LONG_MARGIN * lim.accel_max
    a_brake = LONG_MARGIN * min(-lim.accel_min, ay_max)
    n = len(s)
    reps = 3 if closed else 1
    vl = np.tile(v_lat, reps)
    kk = np.tile(ak, reps)
    ds = np.diff(s).mean()
    # the recurrences are sequential by nature; this runs once per simulation on ~10^3 points
    v = vl.copy()
    for i in range(1, len(v)):
        r = 1.0 - (v[i - 1] ** 2 * kk[i - 1] / ay_max) ** 2
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2.0 * ds * a_drive * math.sqrt(max(r, 0.0))))
    for i in range(len(v) - 2, -1, -1):
        r = 1.0 - (v[i + 1] ** 2 * kk[i + 1] / ay_max) ** 2
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * ds * a_brake * math.sqrt(max(r, 0.0))))
    return v[n : 2 * n] if closed else v


def build_profile(track, vehicle: VehicleConfig, speed_scale: float, weave_amplitude: float = 0.0,
                  weave_wavelength: float = 100.0) -> Profile:
    L = track.length
    n = int(np.clip(round(L / 1.0), 400, 20000))  # ~1 m spacing on a circuit, >= 400 points on small tracks
    s = np.linspace(0.0, L, n + 1)
    kappa = track.kappa(s)
    ey, dey, d2ey = weave_line(track, s, vehicle, weave_amplitude, weave_wavelength)
    kp = kappa + d2ey
    if track.closed:
        kappa[-1], kp[-1] = kappa[0], kp[0]
    v = speed_profile(s[:-1] if track.closed else s, kp[:-1] if track.closed else kp, vehicle, speed_scale, track.closed)
    if track.closed:
        v = np.append(v, v[0])
    dvds = np.gradient(v, s)
    return Profile(s, v, dvds, kappa, kp, ey, np.arctan(dey), track.width_left(s), track.width_right(s))


class ReferenceController:
    """``u = controller(y)`` for a measured Frenet state ``y`` (6,), see the module docstring."""

    def __init__(self, vehicle: VehicleConfig, track, dt: float, speed_scale: float = 0.8,
                 weave_amplitude: float = 0.0, weave_wavelength: float = 100.0) -> None:
        self.vehicle = vehicle
        self.track = track
        self.dt = float(dt)
        self.profile = build_profile(track, vehicle, speed_scale, weave_amplitude, weave_wavelength)
        p = vehicle
        self.L = p.l_f + p.l_r
        fzf = p.mass * G * p.l_r / self.L
        fzr = p.mass * G * p.l_f / self.L
        cf = p.mu * fzf * p.tire.b_front * p.tire.c_front
        cr = p.mu * fzr * p.tire.b_rear * p.tire.c_rear
        self.k_us = p.mass * (p.l_r / cf - p.l_f / cr) / self.L
        self.k_beta = p.mass * p.l_f / (cr * self.L)
        self.k_r = YAW_DAMPING * p.yaw_inertia / (p.l_f * cf)
        self.la_min = 3.0 * self.L
        self.ay_max = speed_scale * p.mu * G
        self.a_brake = min(-p.limits.accel_min, self.ay_max)
        self.v_floor = max(p.v_min, 0.05 * p.limits.speed_max)
        self.delta_prev: float | None = None

    def _at(self, arr: np.ndarray, s: float) -> float:
        pr = self.profile
        if self.track.closed:
            s = s % self.track.length
        return float(np.interp(s, pr.s, arr))

    def reference_speed(self, s: float) -> float:
        return self._at(self.profile.v, s)

    def initial_state(self, s0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """A flying start on the target line at the reference speed: ``(x0 (6,), u0 (2,))``."""
        v0 = self.reference_speed(s0)
        kp = self._at(self.profile.kappa_path, s0)
        x0 = np.array([v0, 0.0, v0 * kp, self._at(self.profile.epsi_ref, s0), self._at(self.profile.ey_ref, s0), s0])
        delta0 = float(np.clip(self.L * kp + self.k_us * v0 * v0 * kp, -self.vehicle.limits.steering_max,
                               self.vehicle.limits.steering_max))
        self.delta_prev = delta0
        return x0, np.array([delta0, 0.0])

    def __call__(self, y: np.ndarray) -> np.ndarray:
        lim = self.vehicle.limits
        vx, vy, r, epsi, ey, s = (float(q) for q in y)
        v = max(vx, self.v_floor)
        pr = self.profile
        # lateral
        kp = self._at(pr.kappa_path, s + v * T_FF)
        beta_ss = self.vehicle.l_r * kp - self.k_beta * v * v * kp  # steady-state side slip
        chi = epsi + beta_ss - self._at(pr.epsi_ref, s)
        e = ey - self._at(pr.ey_ref, s)
        la = max(v * T_LOOKAHEAD, self.la_min)
        delta = (self.L * kp + self.k_us * v * v * kp - 2.0 * self.L * (e + la * chi) / (la * la)
                 - self.k_r * (r - v * kp))
        delta = min(max(delta, -lim.steering_max), lim.steering_max)
        if self.delta_prev is not None:
            dmax = lim.steering_rate_max * self.dt
            delta = min(max(delta, self.delta_prev - dmax), self.delta_prev + dmax)
        self.delta_prev = delta
        # longitudinal
        sp = s + v * T_SPEED_PREVIEW
        if not self.track.closed:
            sp = min(sp, self.track.length)
        v_ref = self._at(pr.v, sp)
        ax = v * self._at(pr.dvds, sp) + K_SPEED * (v_ref - vx)
        # friction circle at the current lateral acceleration: no full braking at full cornering
        r_lat = min(abs(v * r) / self.ay_max, 1.0)
        room = max(math.sqrt(1.0 - r_lat * r_lat), MIN_LONG_SHARE)
        ax = min(max(ax, -self.a_brake * room), lim.accel_max * room)
        return np.array([delta, ax])
