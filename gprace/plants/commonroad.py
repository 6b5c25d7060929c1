"""``commonroad-std`` and ``commonroad-mb``: car models of ``commonroad-vehicle-models`` as plants.

Car models nobody on this team wrote, with the BMW 320i parameter set (``parameters_vehicle2``):

* ``commonroad-std``: ``vehicle_dynamics_std``, the single-track drift model (9 states
  ``[x, y, delta, v, psi, yaw_rate, beta, omega_f, omega_r]``: combined-slip Pacejka tires, wheel
  spin, longitudinal load transfer, power-limited drive).
* ``commonroad-mb``: ``vehicle_dynamics_mb``, the multi-body model (29 states: sprung mass with
  roll and pitch, front and rear unsprung masses, four wheels with spin dynamics, Pacejka combined
  slip with camber; ``x[3], x[10]`` are the body velocities ``v_x, v_y``).

Both live in the global frame on the track's geometry (:class:`CommonRoadPlant`):

* **inputs**: our command ``[delta, a_x]`` becomes the package's ``[steering rate, acceleration]``
  through a fast first-order steering servo ``d delta/dt = (delta_cmd - delta) / tau``
  (``tau = 20 ms``) clipped to the car's steering-rate limit (0.4 rad/s); the package applies its
  own steering-angle, acceleration and power limits.
* **placement**: ``reset`` puts the CoG at the Frenet state with the package's own ``init_std`` /
  ``init_mb`` (wheel speeds rolling, suspension at rest).
* **observation** in Frenet coordinates: ``(s, e_y) = track.to_frenet(x, y, s_hint)`` with the
  previous ``s`` as hint (self-crossing tracks resolve to the branch being driven),
  ``e_psi = psi - heading(s)`` wrapped to ``(-pi, pi]``, plus the configuration's sensor noise.

Integration (the wheel-spin equations are stiff: eigenvalue about ``R_w^2 K_x F_z / (I_w u)``):

* std: fixed-step RK4 with substeps of at most 1 ms, shrinking proportionally to the speed
  below ~7 m/s (~9000/u 1/s on the front axle) to stay inside RK4's stability region.
* mb: see :class:`CommonRoadMBPlant` (the choice and its measured accuracy: docs/decisions.md).

A wheel speed never goes below zero (the package's rule). The package enforces it by freezing a
wheel whose speed is negative (its derivative 0 for ever after); the plants instead hold a wheel
at zero while the brake holds it and let it spin up again when the tire's torque wins (the std
plant by clipping after each RK4 substep, the mb plant inside the derivative).

The configured ``vehicle`` (``bmw_320i``) is only the *nominal* approximation that controllers
use; these plants ignore it, and reject hidden ``effects`` (their physics are the package's).
"""

from __future__ import annotations

import math
from typing import Any, Callable, ClassVar

import numpy as np

from gprace.errors import ConfigError, InputError, SolverError
from gprace.plants.base import Plant

STEER_SERVO_TAU = 0.02
"""Time constant of the steering servo that turns an angle command into a steering rate [s]."""

H_MAX = 1e-3
"""Largest RK4 substep of the std plant [s]."""

_STIFF = 1.5e-4
"""Substep bound per unit speed [s per m/s] keeping the std wheel-spin modes stable (module docstring)."""


class CommonRoadPlant(Plant):
    """A commonroad-vehicle-models car in the global frame (module docstring); subclasses name the
    package model and integrate it."""

    MODEL: ClassVar[str]  # module and function name in vehiclemodels, e.g. "vehicle_dynamics_std"
    INIT: ClassVar[str]  # its init function, e.g. "init_std"
    NZ: ClassVar[int]  # number of states
    WHEELS: ClassVar[slice]  # wheel-speed states

    def __init__(self, config, track, dt):
        super().__init__(config, track, dt)
        if config.effects:
            names = ", ".join(e.name for e in config.effects)
            raise ConfigError(f"plant {self.NAME!r} has its own physics; effects ({names}) work only with 'frenet'")
        try:
            import importlib

            from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

            self._f: Callable = getattr(importlib.import_module(f"vehiclemodels.{self.MODEL}"), self.MODEL)
            self._init: Callable = getattr(importlib.import_module(f"vehiclemodels.{self.INIT}"), self.INIT)
        except ImportError as exc:  # pragma: no cover - a declared dependency
            raise ConfigError(f"plant {self.NAME!r} needs commonroad-vehicle-models ({exc})") from None
        self.p = parameters_vehicle2()
        self._rate_max = float(min(self.p.steering.v_max, -self.p.steering.v_min))
        self._z = [0.0] * self.NZ
        self._x = np.zeros(6)
        self._s_cont = 0.0  # unwrapped arc length (hint for the projection)

    # -----------------------------------------------------------------------------------------
    def reset(self, x0, u0=None):
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (6,) or not np.all(np.isfinite(x0)):
            raise InputError(f"{self.NAME} reset: need a finite Frenet state of 6 values, got {x0}")
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
        z = self._advance(list(self._z), float(u[0]), float(u[1]))
        if not all(math.isfinite(q) for q in z):
            raise SolverError(f"{self.NAME}: the state became non-finite; lower dt or check the inputs")
        self._z = z
        self._x = self._observe(z)
        return self._noisy(self._x.copy())

    @property
    def state(self):
        return self._x.copy()

    @property
    def global_state(self) -> np.ndarray:
        """The package's state vector (its layout: module docstring)."""
        return np.array(self._z)

    def describe(self) -> dict[str, Any]:
        return {"kind": self.NAME, "model": f"vehiclemodels.{self.MODEL}", "parameters": "parameters_vehicle2 (BMW 320i)"}

    # -----------------------------------------------------------------------------------------
    def _advance(self, z: list[float], delta_cmd: float, ax: float) -> list[float]:
        """The package state after one period with the command held."""
        raise NotImplementedError

    def _velocity(self, z) -> tuple[float, float]:
        """Body velocities ``(v_x, v_y)`` at the CoG."""
        raise NotImplementedError

    def _deriv(self, z, delta_cmd, ax):
        """The package's derivative under the steering servo's rate for the angle command."""
        rate = (delta_cmd - z[2]) / STEER_SERVO_TAU
        rate = min(max(rate, -self._rate_max), self._rate_max)
        return self._model(z, [rate, ax])

    def _model(self, z, u) -> list[float]:
        """The package's ``f(z, u, p)`` (``u`` = steering rate, acceleration)."""
        return self._f(list(z), u, self.p)  # the package mutates its x argument: copy

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
        vx, vy = self._velocity(z)
        return np.array([vx, vy, z[5], epsi, ey, s])


class CommonRoadSTDPlant(CommonRoadPlant):
    NAME = "commonroad-std"
    MODEL, INIT, NZ, WHEELS = "vehicle_dynamics_std", "init_std", 9, slice(7, 9)

    def __init__(self, config, track, dt):
        super().__init__(config, track, dt)
        self.substeps_done = 0

    def _advance(self, z, delta_cmd, ax):
        v = abs(z[3])
        h_lim = min(H_MAX, max(_STIFF * v, 2e-5))
        n = max(int(math.ceil(self.dt / h_lim - 1e-9)), self.config.substeps)
        h = self.dt / n
        for _ in range(n):
            z = rk4_step(self._deriv, z, delta_cmd, ax, h, self.WHEELS)
        self.substeps_done += n
        return z

    def _velocity(self, z):
        return z[3] * math.cos(z[6]), z[3] * math.sin(z[6])


H_MB_MAX = 5e-3
"""Largest RK4 substep of the mb plant [s]: half RK4's stability limit for its fastest
speed-independent mode (about -270 1/s: the compliant joints and the sprung mass)."""

_MB_STIFF = 3e-4
"""mb substep bound per unit speed [s per m/s]: its wheel-spin modes are about -4700/u 1/s."""


def mb_substep(vx: float) -> float:
    """Largest stable RK4 substep of the mb model at body speed ``vx`` [s]: the wheel modes
    scale as 1/u above the package's kinematic switch (|v_x| < 0.1 m/s), where the wheels are slaved."""
    v = abs(vx)
    if v < 0.1:
        return H_MB_MAX
    return min(H_MB_MAX, max(_MB_STIFF * v, 2e-5))


def rk4_step(deriv, z: list[float], delta_cmd: float, ax: float, h: float, wheels: slice) -> list[float]:
    """One classical RK4 step of ``deriv(z, delta_cmd, ax)`` (lists), wheel speeds clipped at 0."""
    k1 = deriv(z, delta_cmd, ax)
    k2 = deriv([a + 0.5 * h * b for a, b in zip(z, k1)], delta_cmd, ax)
    k3 = deriv([a + 0.5 * h * b for a, b in zip(z, k2)], delta_cmd, ax)
    k4 = deriv([a + h * b for a, b in zip(z, k3)], delta_cmd, ax)
    out = [a + h / 6.0 * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(z, k1, k2, k3, k4)]
    for i in range(wheels.start, wheels.stop):  # the package forbids negative wheel spin
        out[i] = max(out[i], 0.0)
    return out


class CommonRoadMBPlant(CommonRoadPlant):
    """The multi-body BMW. Integrated by fixed-step RK4 with substeps of at most 5 ms, shrinking as
    :func:`mb_substep` at low speed (measured against adaptive and implicit scipy integrators:
    docs/decisions.md, benchmarks/bench_plants.py)."""

    NAME = "commonroad-mb"
    MODEL, INIT, NZ, WHEELS = "vehicle_dynamics_mb", "init_mb", 29, slice(23, 27)

    def __init__(self, config, track, dt):
        super().__init__(config, track, dt)
        self.substeps_done = 0

    def _velocity(self, z):
        return z[3], z[10]

    def _model(self, z, u):
        return wheels_held(self._f, z, u, self.p, self.WHEELS)

    def _advance(self, z, delta_cmd, ax):
        n = max(int(math.ceil(self.dt / mb_substep(z[3]) - 1e-9)), self.config.substeps)
        h = self.dt / n
        for _ in range(n):
            z = rk4_step(self._deriv, z, delta_cmd, ax, h, self.WHEELS)
        self.substeps_done += n
        return z


def wheels_held(f, z, u, p, wheels: slice) -> list[float]:
    """``f(z, u, p)`` of a commonroad model with every wheel at or below zero speed held at zero:
    evaluated there, and its speed may only grow (module docstring)."""
    z = list(z)
    locked = [i for i in range(wheels.start, wheels.stop) if z[i] <= 0.0]
    for i in locked:
        z[i] = 0.0
    out = f(z, list(u), p)
    for i in locked:
        out[i] = max(out[i], 0.0)
    return out
