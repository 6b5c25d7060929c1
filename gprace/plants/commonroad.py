"""``commonroad-std`` plant: the single-track drift model of ``commonroad-vehicle-models``.

A car model nobody on this team wrote: ``vehiclemodels.vehicle_dynamics_std`` (combined-slip
Pacejka tires, wheel spin, longitudinal load transfer, power-limited drive) with the BMW 320i
parameter set (``parameters_vehicle2``). It lives in the global frame on the track's geometry:

* **state** (the package's layout): ``[x, y, delta, v, psi, yaw_rate, beta, omega_f, omega_r]``
  with ``(x, y)`` the centre of gravity, ``v`` the speed at the CoG and ``beta`` the side-slip
  angle there; wheel speeds come from ``init_std``.
* **inputs**: our command ``[delta, a_x]`` becomes the package's ``[steering rate, acceleration]``
  through a fast first-order steering servo ``d delta/dt = (delta_cmd - delta) / tau``
  (``tau = 20 ms``) clipped to the car's steering-rate limit (0.4 rad/s); the package applies its
  own steering-angle, acceleration and power limits.
* **integration**: fixed-step RK4 with substeps of at most 1 ms. The wheel-spin equations are
  stiff at low speed (eigenvalue about ``R_w^2 K_x F_z / (I_w u)``, ~9000/u 1/s on the front
  axle), so below ~7 m/s the substep shrinks proportionally to the speed to stay inside RK4's
  stability region.
* **observation** in Frenet coordinates: ``(s, e_y) = track.to_frenet(x, y, s_hint)`` with the
  previous ``s`` as hint (self-crossing tracks resolve to the branch being driven),
  ``v_x = v cos(beta)``, ``v_y = v sin(beta)``, ``e_psi = psi - heading(s)`` wrapped to
  ``(-pi, pi]``, plus the configuration's sensor noise.

The configured ``vehicle`` (``bmw_320i``) is only the *nominal* approximation that controllers
use; this plant ignores it, and rejects hidden ``effects`` (its physics are the package's).
"""

from __future__ import annotations

import math

import numpy as np

from gprace.errors import ConfigError, InputError
from gprace.plants.base import Plant

STEER_SERVO_TAU = 0.02
"""Time constant of the steering servo that turns an angle command into a steering rate [s]."""

H_MAX = 1e-3
"""Largest RK4 substep [s]."""

_STIFF = 1.5e-4
"""Substep bound per unit speed [s per m/s] keeping the wheel-spin modes stable (module docstring)."""


class CommonRoadSTDPlant(Plant):
    NAME = "commonroad-std"

    def __init__(self, config, track, dt):
        super().__init__(config, track, dt)
        if config.effects:
            names = ", ".join(e.name for e in config.effects)
            raise ConfigError(f"plant 'commonroad-std' has its own physics; effects ({names}) work only with 'frenet'")
        try:
            from vehiclemodels.init_std import init_std
            from vehiclemodels.parameters_vehicle2 import parameters_vehicle2
            from vehiclemodels.vehicle_dynamics_std import vehicle_dynamics_std
        except ImportError as exc:  # pragma: no cover - a declared dependency
            raise ConfigError(f"plant 'commonroad-std' needs commonroad-vehicle-models ({exc})") from None
        self._f = vehicle_dynamics_std
        self._init = init_std
        self.p = parameters_vehicle2()
        self._rate_max = float(min(self.p.steering.v_max, -self.p.steering.v_min))
        self._z = [0.0] * 9
        self._x = np.zeros(6)
        self._s_cont = 0.0  # unwrapped arc length (hint for the projection)
        self.substeps_done = 0

    # -----------------------------------------------------------------------------------------
    def reset(self, x0, u0=None):
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (6,) or not np.all(np.isfinite(x0)):
            raise InputError(f"commonroad-std reset: need a finite Frenet state of 6 values, got {x0}")
        delta0 = 0.0 if u0 is None else float(np.asarray(u0, dtype=float)[0])
        vx, vy, r, epsi, ey, s = x0
        px, py = self.track.to_global(s, ey)
        psi = float(self.track.heading(s)) + epsi
        v = math.hypot(vx, vy)
        beta = math.atan2(vy, vx) if v > 0 else 0.0
        self._z = list(self._init([float(px), float(py), delta0, v, psi, float(r), beta], self.p))
        self.lap = 0
        self._s_cont = float(s)
        self._x = x0.copy()
        self._x[5] = float(self.track.wrap(s))
        return self._noisy(self._x.copy())

    def step(self, u):
        u = np.asarray(u, dtype=float)
        delta_cmd, ax = float(u[0]), float(u[1])
        v = abs(self._z[3])
        h_lim = min(H_MAX, max(_STIFF * v, 2e-5))
        n = max(int(math.ceil(self.dt / h_lim - 1e-9)), self.config.substeps)
        h = self.dt / n
        z = self._z
        for _ in range(n):
            z = self._rk4(z, delta_cmd, ax, h)
        if not all(math.isfinite(q) for q in z):
            from gprace.errors import SolverError

            raise SolverError("commonroad-std: the state became non-finite; lower dt or check the inputs")
        self._z = z
        self.substeps_done += n
        self._x = self._observe(z)
        return self._noisy(self._x.copy())

    @property
    def state(self):
        return self._x.copy()

    @property
    def global_state(self) -> np.ndarray:
        """The package's 9-state vector ``[x, y, delta, v, psi, yaw_rate, beta, omega_f, omega_r]``."""
        return np.array(self._z)

    # -----------------------------------------------------------------------------------------
    def _deriv(self, z, delta_cmd, ax):
        rate = (delta_cmd - z[2]) / STEER_SERVO_TAU
        rate = min(max(rate, -self._rate_max), self._rate_max)
        return self._f(list(z), [rate, ax], self.p)  # the package mutates its x argument: copy

    def _rk4(self, z, dc, ax, h):
        k1 = self._deriv(z, dc, ax)
        k2 = self._deriv([a + 0.5 * h * b for a, b in zip(z, k1)], dc, ax)
        k3 = self._deriv([a + 0.5 * h * b for a, b in zip(z, k2)], dc, ax)
        k4 = self._deriv([a + h * b for a, b in zip(z, k3)], dc, ax)
        out = [a + h / 6.0 * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(z, k1, k2, k3, k4)]
        out[7] = max(out[7], 0.0)  # the package forbids negative wheel spin
        out[8] = max(out[8], 0.0)
        return out

    def _observe(self, z) -> np.ndarray:
        tr = self.track
        s, ey = tr.to_frenet(z[0], z[1], s_hint=tr.wrap(self._s_cont))
        s, ey = float(s), float(ey)
        if tr.closed:
            L = tr.length
            prev = self._s_cont - L * math.floor(self._s_cont / L)
            ds = (s - prev + 0.5 * L) % L - 0.5 * L
            self._s_cont += ds
            self.lap = int(math.floor((self._s_cont + 1e-6) / L))  # a hair before the line is on it
            s = max(self._s_cont - L * self.lap, 0.0)
        else:
            self._s_cont = s
        epsi = z[4] - float(tr.heading(s))
        epsi = (epsi + math.pi) % (2.0 * math.pi) - math.pi
        v, beta = z[3], z[6]
        return np.array([v * math.cos(beta), v * math.sin(beta), z[5], epsi, ey, s])
