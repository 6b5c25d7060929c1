"""Concealed-effect recordings for tests and the recovery benchmark.

A :class:`~gprace.plants.frenet.FrenetPlant` with hidden effects (catalogue entries or any
:class:`~gprace.model.effects.Effect` object) driven around a real track by a small Frenet
tracking driver that sees only the noisy measurements. The driver follows a speed profile with
braking zones and weaves across the track so that the lateral, longitudinal and combined regimes
are all excited; small coloured perturbations on both commands make actuator dynamics visible.
The recorded inputs are the commands (what a logger on the car sees).

The per-step loop here is a simulation in time (inherently sequential), not a hot path of the
diagnosis.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from gprace.config import G, EffectConfig, NoiseConfig, PlantConfig, VehicleConfig
from gprace.io.runs import Run
from gprace.model import INPUT, Effect, Input, State
from gprace.plants.frenet import FrenetPlant

DEFAULT_NOISE = NoiseConfig(v_x=0.05, v_y=0.03, yaw_rate=0.005, e_psi=0.003, e_y=0.03, s=0.1)
"""Sensor noise of a typical GNSS/IMU state estimator at 20 Hz (1 sigma, SI units)."""


def _speed_profile(track, vehicle: VehicleConfig, speed_scale: float, ds: float = 2.0):
    L = track.length
    n = max(int(L / ds), 50)
    s = np.linspace(0.0, L, n, endpoint=not track.closed)
    h = s[1] - s[0]
    ay = speed_scale * vehicle.mu * G
    k = np.maximum(np.abs(track.kappa(s)), 1e-6)
    v_lat = np.minimum(np.sqrt(ay / k), 0.8 * vehicle.limits.speed_max)
    reps = 3 if track.closed else 1
    v = np.tile(v_lat, reps)
    a_drive, a_brake = 0.8 * vehicle.limits.accel_max, min(0.4 * min(-vehicle.limits.accel_min, ay), 5.0)
    for i in range(1, len(v)):  # one-off forward/backward pass over ~10^3 points
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * h * a_drive))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * h * a_brake))
    if track.closed:
        v = v[n : 2 * n]
    return s, v


class TrackingDriver:
    """Frenet tracking driver: feed-forward curvature steering plus look-ahead PD, speed profile."""

    def __init__(self, vehicle: VehicleConfig, track, dt: float, speed_scale: float = 0.6,
                 weave: float = 0.35, wavelength: float = 150.0, excitation: float = 1.0, seed: int = 0):
        self.v, self.track, self.dt = vehicle, track, dt
        self.s_grid, self.v_grid = _speed_profile(track, vehicle, speed_scale)
        self.wb = vehicle.l_f + vehicle.l_r
        fzf, fzr = vehicle.mass * G * vehicle.l_r / self.wb, vehicle.mass * G * vehicle.l_f / self.wb
        cf = vehicle.mu * fzf * vehicle.tire.b_front * vehicle.tire.c_front
        cr = vehicle.mu * fzr * vehicle.tire.b_rear * vehicle.tire.c_rear
        self.k_us = vehicle.mass * (vehicle.l_r / cf - vehicle.l_f / cr) / self.wb  # understeer gradient
        half = np.minimum(track.width_left(self.s_grid), track.width_right(self.s_grid)) - vehicle.width
        self.amp = weave * float(np.clip(np.min(half), 0.0, None))
        self.wavelength = wavelength
        self.exc = excitation
        self.rng = np.random.default_rng(seed + 7919)
        self.n_d = 0.0
        self.n_a = 0.0
        self.delta_prev = 0.0

    def _interp(self, arr, s):
        if self.track.closed:
            s = s % self.track.length
            return float(np.interp(s, self.s_grid, arr, period=self.track.length))
        return float(np.interp(s, self.s_grid, arr))

    def v_ref(self, s: float) -> float:
        return self._interp(self.v_grid, s)

    def __call__(self, y: np.ndarray) -> np.ndarray:
        vx, vy, r, epsi, ey, s = y
        v = max(vx, 1.0)
        la = max(1.5 * v, 4.0 * self.wb)
        w = 2 * np.pi / self.wavelength
        ey_ref = self.amp * math.sin(w * s)
        chi_ref = math.atan(self.amp * w * math.cos(w * s))
        k_ff = float(self.track.kappa(s + 0.25 * v)) - self.amp * w * w * math.sin(w * (s + 0.25 * v))
        chi = epsi + math.atan2(vy, v) - chi_ref
        delta = (self.wb + self.k_us * v * v) * k_ff - 2 * self.wb * ((ey - ey_ref) + la * chi) / (la * la)
        delta -= 2.0 * self.wb / v * (r - v * k_ff)  # yaw damping: catches oversteer before it spins
        # coloured excitation (first-order filtered white noise, ~1 s correlation)
        a = math.exp(-self.dt / 0.5)
        self.n_d = a * self.n_d + math.sqrt(1 - a * a) * self.rng.standard_normal()
        self.n_a = a * self.n_a + math.sqrt(1 - a * a) * self.rng.standard_normal()
        delta += self.exc * self.wb * 1.2 * self.n_d / max(v, 10.0) ** 2  # ~1 m/s^2 of lateral acceleration
        lim = self.v.limits
        dmax = lim.steering_rate_max * self.dt
        delta = float(np.clip(delta, self.delta_prev - dmax, self.delta_prev + dmax))
        delta = float(np.clip(delta, -lim.steering_max, lim.steering_max))
        self.delta_prev = delta
        vr = self.v_ref(s + 0.4 * v)
        ax = 1.5 * (vr - vx) + self.exc * 0.6 * self.n_a
        # friction circle: less drive and braking while the car is cornering hard
        circle = math.sqrt(max(1.0 - (v * r / (self.v.mu * G)) ** 2, 0.1))
        ax = float(np.clip(ax, max(0.5 * lim.accel_min, -7.0) * circle, 0.9 * lim.accel_max * circle))
        return np.array([delta, ax])


def record(vehicle: VehicleConfig, track, effects: Sequence[EffectConfig | Effect] = (), *,
           laps: float = 2.0, dt: float = 0.05, noise: NoiseConfig = DEFAULT_NOISE, seed: int = 0,
           speed_scale: float = 0.6, weave: float = 0.35, excitation: float = 1.0,
           substeps: int = 10, s0: float = 0.0, plant: str = "frenet") -> Run:
    """Drive ``track`` for ``laps`` laps with hidden ``effects``; return the recording.

    ``effects`` may hold catalogue configs or arbitrary Effect objects (effects outside the
    catalogue, for tests); the recording's embedded vehicle is the nominal one, without them.
    """
    cat = tuple(e for e in effects if isinstance(e, EffectConfig))
    other = [e for e in effects if not isinstance(e, EffectConfig)]
    cfg = PlantConfig(kind=plant, vehicle=vehicle, effects=cat, noise=noise, substeps=substeps, seed=seed)
    if plant == "frenet":
        plant = FrenetPlant(cfg, track, dt)
    else:  # e.g. commonroad-std: physics nobody here wrote, against the nominal ``vehicle``
        from gprace.plants import make_plant

        plant = make_plant(cfg, track, dt)
    if other:  # effects outside the catalogue: rebuild the plant's model and its step
        from gprace.model import NominalModel
        from gprace.plants import frenet

        plant.model = NominalModel(vehicle, list(cat) + other)
        plant._x = np.zeros(plant.model.nx)
        plant._step = frenet.compiled_step(plant.model, track, dt, substeps)
    drv = TrackingDriver(vehicle, track, dt, speed_scale, weave, excitation=excitation, seed=seed)
    v0 = drv.v_ref(s0)
    u0 = np.array([vehicle.l_f * 0 + (vehicle.l_f + vehicle.l_r) * float(track.kappa(s0)), 0.0])
    drv.delta_prev = float(u0[0])
    y = plant.reset(np.array([v0, 0.0, v0 * float(track.kappa(s0)), 0.0, 0.0, s0]), u0)
    L = track.length
    n = int(laps * L / max(np.mean(drv.v_grid), 1.0) / dt * 1.3) + 10
    Y, U, lap = np.empty((n, 6)), np.empty((n, 2)), np.empty(n)
    k = 0
    # stop rules on the car's own scale: off by three half widths, below a quarter of the
    # profile's mean speed (2 m/s for a circuit car, ~0.5 m/s at 1:10), or sliding sideways
    off = 3.0 * float(np.max(track.width_left(drv.s_grid) + track.width_right(drv.s_grid))) / 2.0
    v_stall = 0.25 * float(np.mean(drv.v_grid))
    for k in range(n):
        u = drv(y)
        Y[k], U[k], lap[k] = y, u, plant.lap
        x = plant.state
        if plant.lap * L + x[State.S] - s0 >= laps * L:
            k += 1
            break
        vx = x[State.V_X]
        if abs(x[State.E_Y]) > max(off, 15.0 * (L > 200.0)) or vx < min(2.0, v_stall) \
                or abs(x[State.V_Y]) > 0.25 * max(vx, min(1.0, v_stall)):
            k = max(k - int(2.0 / dt), 2)  # spun or left the track: keep what came before
            break
        y = plant.step(u)
    else:
        k = n
    Y, U = Y[:k], U[:k]
    s = track.wrap(Y[:, State.S]) if track.closed else Y[:, State.S]
    states = ("e_y", "e_psi", "v_x", "v_y", "yaw_rate")  # the recording's column order
    data = {"t": dt * np.arange(k), "s": s, **{n: Y[:, State[n.upper()]] for n in states},
            **{n: U[:, Input[n.upper()]] for n in INPUT},
            "kappa": track.kappa(s), "lap": lap[:k]}
    meta = {"vehicle_toml": vehicle.to_toml(), "track": str(getattr(track, "source", None) or track.name),
            "dt": dt, "plant": cfg.kind, "track_length": float(L)}
    return Run(data, meta, source=f"synthetic({track.name}, seed {seed})")
