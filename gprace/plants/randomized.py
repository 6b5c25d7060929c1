"""``randomized`` plant: a car drawn, by seed, from a documented family around the nominal vehicle.

The drawn car has physics the nominal bicycle and its effect catalogue lack (the model:
:mod:`gprace.plants.double_track`; the distribution and why each range: ``docs/plants.md``):
per-axle grip, downforce, longitudinal and lateral load transfer on load-sensitive tires, the
friction ellipse with a capped longitudinal force, a steering actuator with lag and rate limit,
tire relaxation, yaw inertia, drag and a measurement delay.

* **draw**: one uniform number per parameter, in the fixed order of :data:`DRAW_ORDER`, from
  ``numpy.random.default_rng(options.seed)``; overriding one range leaves the other draws as they
  were. ``options.seed`` is the car; ``PlantConfig.seed`` seeds only the sensor noise, which
  ``simulate`` and ``iterate`` vary per run (the car must stay the same car).
* **steering actuator**: a first-order lag ``tau`` whose rate is clipped to ``rate``, the command
  clipped to the nominal ``steering_max``; held over a period its path is known in closed form
  (:func:`steering_path`), evaluated at every RK4 stage.
* **integration**: one compiled CasADi function per control period, classical RK4 with
  ``max(substeps, ceil(dt / h))`` substeps, ``h`` at most 1.5 times the shortest relaxation time
  ``sigma / (1.1 v_max)`` (RK4 is stable to 2.8 times a time constant); curvature re-evaluated at
  every stage from the track's B-spline.
* **measurement**: the true Frenet state ``d`` periods ago (``d`` drawn, fractional delays linear
  between the two neighbouring periods), plus the configured sensor noise.

``describe()`` returns the drawn car; :meth:`RandomizedPlant.approximate` the nominal-model car
closest to it (the oracle's model) and what that leaves out.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from pydantic import BeforeValidator, Field, ValidationInfo, field_validator

from gprace.config import G, EffectConfig, Frozen, PlantConfig, VehicleConfig, plant_options
from gprace.errors import ConfigError, InputError, SolverError
from gprace.plants import double_track as dt_model
from gprace.plants.base import Approximation, Plant
from gprace.model.dynamics import State
from gprace.plants.double_track import CarParams

FULL_SIZE_WHEELBASE = 2.5
"""Lengths of the default ranges are for a full-size car; a shorter wheelbase scales them [m]."""

TRACK_SHARE = 0.85
"""Wheel track as a share of the chassis width (road and cup cars: 0.83 to 0.88)."""

TYPICAL_DOWNFORCE_SHARE = 0.25
"""Typical downforce: this share of the car's weight at ``TYPICAL_DOWNFORCE_SPEED`` of its top speed."""

TYPICAL_DOWNFORCE_SPEED = 0.7


def _as_range(v: Any) -> Any:
    """A number ``x`` is the range ``[x, x]``; a pair stays a pair."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return (float(v), float(v))
    return v


Range = Annotated[tuple[float, float], BeforeValidator(_as_range)]

# (low, high) physical bounds of each range option; None: unbounded on that side
BOUNDS: dict[str, tuple[float, float]] = {
    "grip_front": (0.05, 3.0), "grip_rear": (0.05, 3.0), "downforce": (0.0, 20.0), "aero_balance": (0.0, 1.0),
    "cog_height": (0.0, 5.0), "roll_stiffness_front": (0.0, 1.0), "load_sensitivity": (0.0, 0.4),
    "drive_rear": (0.0, 1.0), "steering_lag": (0.0, 1.0), "steering_rate": (1e-3, math.inf),
    "relaxation_length": (0.0, 10.0), "yaw_inertia": (0.1, 5.0), "drag": (0.0, 10.0),
    "measurement_delay": (0.0, 10.0), "load_lag": (1e-3, 1.0),
}


class RandomizedOptions(Frozen):
    """``[options]`` of a ``randomized`` plant. Every range is ``[low, high]`` (or one number for a
    fixed value), drawn uniformly; ``null``/absent car-scaled ranges take the defaults of
    docs/plants.md."""

    seed: int = Field(0, description="seed of the drawn car (the sensor noise has PlantConfig.seed)")
    grip_front: Range = Field((0.8, 1.05), description="factor on the nominal mu, front axle [-]")
    grip_rear: Range = Field((0.8, 1.05), description="factor on the nominal mu, rear axle [-]")
    downforce: Range = Field((0.0, 1.5), description="downforce coefficient, factor on the typical one [-]")
    aero_balance: Range | None = Field(None, description="front share of the downforce [-]; default "
                                       "[static front share - 0.15, static front share]")
    cog_height: Range | None = Field(None, description="CoG height for load transfer [m]; default [0.3, 0.6] (scaled)")
    roll_stiffness_front: Range = Field((0.5, 0.65), description="front share of the lateral load transfer [-]")
    load_sensitivity: Range = Field((0.05, 0.2), description="k in mu_w = mu (1 - k dF_z/F_z0) [-]")
    combined_slip: bool = Field(True, description="friction ellipse with a capped longitudinal force")
    drive_rear: Range = Field((1.0, 1.0), description="share of the drive force on the rear axle [-]")
    steering_lag: Range = Field((0.0, 0.08), description="steering actuator time constant [s]")
    steering_rate: Range = Field((0.8, 1.5), description="actuator rate limit, factor on the nominal steering_rate_max [-]")
    relaxation_length: Range | None = Field(None, description="tire relaxation length [m]; default [0, 1.5] (scaled)")
    yaw_inertia: Range = Field((0.75, 1.25), description="factor on the nominal I_zz [-]")
    drag: Range = Field((0.7, 1.5), description="factor on the nominal wind drag C_xw [-]")
    measurement_delay: Range = Field((0.0, 2.0), description="measurement delay [control periods]")
    load_lag: Range = Field((0.05, 0.05), description="time constant of the load transfer (chassis roll/pitch) [s]")

    @field_validator(*BOUNDS, mode="after")
    @classmethod
    def _range(cls, v: tuple[float, float] | None, info: ValidationInfo) -> tuple[float, float] | None:
        if v is None:
            return v
        lo, hi = v
        if math.isnan(lo) or math.isnan(hi):
            raise ValueError("the range must be numbers, not NaN")
        if lo > hi:
            raise ValueError("the range is upside down (low > high); write [low, high]")
        blo, bhi = BOUNDS[info.field_name]
        if lo < blo or hi > bhi:
            raise ValueError(f"the range must lie within [{blo:g}, {bhi:g}]")
        return v


DRAW_ORDER = ("grip_front", "grip_rear", "downforce", "aero_balance", "cog_height", "roll_stiffness_front",
              "load_sensitivity", "drive_rear", "steering_lag", "steering_rate", "relaxation_length",
              "yaw_inertia", "drag", "measurement_delay", "load_lag")
"""The drawn parameters, in the order their uniform numbers are taken from the generator."""


def car_scale(vehicle: VehicleConfig) -> float:
    """Factor on the default length ranges: 1 for a full-size car, wheelbase / 2.5 m for a smaller one."""
    return min(1.0, vehicle.wheelbase / FULL_SIZE_WHEELBASE)


def typical_downforce(vehicle: VehicleConfig) -> float:
    """Typical downforce coefficient [N s^2/m^2]: a quarter of the weight at 70 % of top speed."""
    v = TYPICAL_DOWNFORCE_SPEED * vehicle.limits.speed_max
    return TYPICAL_DOWNFORCE_SHARE * vehicle.mass * G / (v * v)


def ranges(options: RandomizedOptions, vehicle: VehicleConfig) -> dict[str, tuple[float, float]]:
    """Every drawn parameter's range for ``vehicle``, the car-scaled defaults filled in."""
    k = car_scale(vehicle)
    front = vehicle.l_r / vehicle.wheelbase
    defaults = {"aero_balance": (max(front - 0.15, 0.0), front), "cog_height": (0.3 * k, 0.6 * k),
                "relaxation_length": (0.0, 1.5 * k)}
    out = {}
    for name in DRAW_ORDER:
        r = getattr(options, name)
        out[name] = tuple(map(float, defaults[name] if r is None else r))
    return out


@dataclass(frozen=True)
class DrawnCar:
    """One car of the family: the drawn ``values`` (factors as drawn, plus absolute values) and the
    model parameters."""

    values: dict[str, Any]
    params: CarParams
    steering_lag: float  # [s]
    steering_rate: float  # [rad/s]
    steering_max: float  # [rad]
    delay: float  # [control periods]


def draw_car(config: PlantConfig) -> DrawnCar:
    """The car of ``config.options.seed`` around ``config.vehicle`` (no track needed)."""
    return draw(options_of(config), config.vehicle)


def with_seed(config: PlantConfig, seed: int) -> PlantConfig:
    """``config`` with car ``seed`` (its other options kept), checked as a file would be; write it
    with ``config.to_toml()`` for commands that take a plant file."""
    return PlantConfig.model_validate({**config.model_dump(), "options": {**config.options, "seed": int(seed)}})


def options_of(config: PlantConfig) -> RandomizedOptions:
    """``config.options`` validated (a config changed by ``model_copy`` skipped the check)."""
    try:
        return plant_options(RandomizedPlant, config.options) or RandomizedOptions()
    except ValueError as exc:
        raise ConfigError(f"plant 'randomized': options: {exc}") from None


def draw(options: RandomizedOptions, vehicle: VehicleConfig) -> DrawnCar:
    """The car of ``options.seed``: one uniform number per parameter of :data:`DRAW_ORDER`."""
    rng = np.random.default_rng(options.seed)
    u = rng.random(len(DRAW_ORDER))
    rg = ranges(options, vehicle)
    d = {name: float(lo if lo == hi else lo + ui * (hi - lo)) for (name, (lo, hi)), ui in zip(rg.items(), u)}
    scale = car_scale(vehicle)
    sigma = d["relaxation_length"] if d["relaxation_length"] >= dt_model.SIGMA_MIN * scale else 0.0
    c_l = float(d["downforce"] * typical_downforce(vehicle))
    cxw = float(d["drag"] * vehicle.drag_coefficient)
    params = CarParams(
        m=vehicle.mass, iz=vehicle.yaw_inertia * d["yaw_inertia"], lf=vehicle.l_f, lr=vehicle.l_r,
        track_f=TRACK_SHARE * vehicle.width, track_r=TRACK_SHARE * vehicle.width, h=d["cog_height"],
        mu_f=vehicle.mu * d["grip_front"], mu_r=vehicle.mu * d["grip_rear"],
        bf=vehicle.tire.b_front / d["grip_front"], cf=vehicle.tire.c_front,
        br=vehicle.tire.b_rear / d["grip_rear"], cr=vehicle.tire.c_rear,
        cxw=cxw, crr=vehicle.rolling_resistance, c_l=c_l, aero_front=d["aero_balance"],
        roll_front=d["roll_stiffness_front"], k_load=d["load_sensitivity"], sigma=sigma,
        combined=1.0 if options.combined_slip else 0.0, drive_rear=d["drive_rear"], load_lag=d["load_lag"],
        vmin=vehicle.v_min,
    )
    rate = d["steering_rate"] * vehicle.limits.steering_rate_max
    values = {
        "seed": options.seed, "nominal": vehicle.name, **d,
        "combined_slip": options.combined_slip, "downforce_c_l": c_l, "typical_c_l": typical_downforce(vehicle),
        "drag_coefficient": cxw, "yaw_inertia_kg_m2": float(params.iz), "steering_rate_rad_s": float(rate),
        "relaxation_length_used": float(sigma), "wheel_track": float(params.track_f),
    }
    return DrawnCar(values, params, d["steering_lag"], rate, vehicle.limits.steering_max, d["measurement_delay"])


def steering_path(delta0: float, cmd: float, tau: float, rate: float, t: np.ndarray) -> np.ndarray:
    """Road-wheel angle at times ``t`` (from the period start) of a first-order actuator with time
    constant ``tau`` (0: none) whose rate is clipped to ``rate``, commanded to ``cmd`` from ``delta0``.

    While ``|cmd - delta| > rate tau`` the actuator slews at ``rate``; from then on the error decays
    as ``exp(-t / tau)`` (its rate stays below the limit); with ``tau = 0`` it stops at ``cmd``.
    """
    e0 = cmd - delta0
    sgn = 1.0 if e0 >= 0 else -1.0
    band = rate * tau  # error below which the lag, not the rate limit, sets the motion
    t_sat = max(abs(e0) - band, 0.0) / rate
    if math.isinf(rate):
        return np.full_like(t, cmd) if tau <= 0 else cmd - e0 * np.exp(-t / tau)  # a step: its right limit
    slew = delta0 + sgn * rate * np.minimum(t, t_sat)
    if tau <= 0:
        return np.where(t < t_sat, slew, cmd)
    e_sat = sgn * min(abs(e0), band)
    return np.where(t < t_sat, slew, cmd - e_sat * np.exp(-np.maximum(t - t_sat, 0.0) / tau))


class RandomizedPlant(Plant):
    NAME = "randomized"
    Options = RandomizedOptions

    def __init__(self, config, track, dt):
        super().__init__(config, track, dt)
        if config.effects:
            names = ", ".join(e.name for e in config.effects)
            raise ConfigError(f"plant 'randomized' draws its own physics; effects ({names}) work only with 'frenet'")
        self.car = draw(options_of(config), config.vehicle)
        p = self.car.params
        h = self.dt / config.substeps
        if p.relaxed:
            h = min(h, 1.5 * p.sigma / (1.1 * config.vehicle.limits.speed_max))
        self.substeps = max(config.substeps, int(math.ceil(self.dt / h - 1e-9)))
        self._times = np.linspace(0.0, self.dt, 2 * self.substeps + 1)  # RK4 stage times
        self._step = compiled_period(p, track, self.dt, self.substeps)
        self._x = np.zeros(dt_model.NX)
        self._delta = 0.0
        self._hist: deque[np.ndarray] = deque(maxlen=int(math.ceil(self.car.delay)) + 2)

    # -----------------------------------------------------------------------------------------
    def reset(self, x0, u0=None):
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (6,) or not np.all(np.isfinite(x0)):
            raise InputError(f"randomized reset: need a finite Frenet state of 6 values, got {x0}")
        u0 = np.zeros(2) if u0 is None else np.asarray(u0, dtype=float)
        self._delta = float(np.clip(u0[0], -self.car.steering_max, self.car.steering_max))
        self._x = np.array(dt_model.initial_state(x0, self._delta, float(u0[1]), self.car.params))
        self.lap = 0
        self._x = self._wrap(self._x)
        self._hist.clear()
        self._hist.extend([self._unwrapped()] * self._hist.maxlen)
        return self._noisy(self._delayed())

    def step(self, u):
        u = np.asarray(u, dtype=float)
        car = self.car
        cmd = float(np.clip(u[0], -car.steering_max, car.steering_max))
        path = steering_path(self._delta, cmd, car.steering_lag, car.steering_rate, self._times)
        x = np.asarray(self._step(self._x, path, float(u[1]))).ravel()
        if not np.all(np.isfinite(x)):
            raise SolverError("randomized: the state became non-finite; lower dt or check the inputs")
        self._delta = float(path[-1])
        self._x = self._wrap(x)
        self._hist.append(self._unwrapped())
        return self._noisy(self._delayed())

    @property
    def state(self):
        return self._x[:6].copy()

    @property
    def full_state(self) -> np.ndarray:
        """The model state (``State`` then ``double_track.Extra``) and the road-wheel angle."""
        return np.append(self._x, self._delta)

    def describe(self) -> dict[str, Any]:
        return {"kind": self.NAME, **self.car.values, "measurement_delay_s": self.car.delay * self.dt,
                "substeps": self.substeps}

    # -----------------------------------------------------------------------------------------
    def _unwrapped(self) -> np.ndarray:
        y = self._x[:6].copy()
        if self.track.closed:
            y[State.S] += self.lap * self.track.length
        return y

    def _delayed(self) -> np.ndarray:
        """The true Frenet state ``delay`` periods ago (linear between periods), ``s`` wrapped."""
        d = self.car.delay
        j = int(math.floor(d))
        frac = d - j
        a = self._hist[-1 - j]
        y = a if frac == 0.0 else (1.0 - frac) * a + frac * self._hist[-2 - j]
        y = y.copy()
        if self.track.closed:
            y[State.S] = float(np.mod(y[State.S], self.track.length))
        return y

    @classmethod
    def approximate(cls, config: PlantConfig) -> Approximation:
        return approximation(draw_car(config), config.vehicle)


def compiled_period(p: CarParams, track, dt: float, substeps: int):
    """``casadi.Function`` ``(x (NX), delta at the 2 substeps + 1 stage times, a_x) -> x after dt``
    by classical RK4, curvature re-evaluated at every stage."""
    import casadi as ca

    from gprace.model.nominal import _casadi_ops
    from gprace.plants.frenet import casadi_kappa_of_s

    kappa = casadi_kappa_of_s(track)
    ops = _casadi_ops()
    x0 = ca.SX.sym("x", dt_model.NX)
    D = ca.SX.sym("delta", 2 * substeps + 1)
    ax = ca.SX.sym("a_x")

    def f(x, delta):
        return ca.vertcat(*dt_model.derivative([x[i] for i in range(dt_model.NX)], delta, ax, kappa(x[State.S]), p, ops))

    h = dt / substeps
    x = x0
    for i in range(substeps):
        d0, dm, d1 = D[2 * i], D[2 * i + 1], D[2 * i + 2]
        k1 = f(x, d0)
        k2 = f(x + 0.5 * h * k1, dm)
        k3 = f(x + 0.5 * h * k2, dm)
        k4 = f(x + h * k3, d1)
        x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("randomized_period", [x0, D, ax], [x])


# ---------------------------------------------------------------------------------------------
# the oracle's model

def approximation(car: DrawnCar, vehicle: VehicleConfig) -> Approximation:
    """The nominal-model car closest to ``car``, exact where the catalogue has the physics.

    Catalogue effects: ``tire_friction`` per axle = grip factor times the loss of the axle's two
    load-sensitive tires under the lateral load transfer at the limit lateral acceleration
    (``1 - k q^2``, ``q`` the transfer over the rated wheel load ``m g / 4``, at most the axle's
    static wheel load: wheel lift); ``cornering_stiffness`` 1 / grip factor (the drawn car keeps
    the nominal stiffness); ``tire_load_sensitivity`` with the drawn ``k`` (the same law on axle
    loads); ``downforce``; ``load_transfer`` with the drawn CoG height (instantaneous); the
    friction ellipse ``combined_slip``; ``steering_lag`` (when at least 1 ms). Yaw inertia and drag
    go into the vehicle. ``missing`` lists what stays out.
    """
    p = car.params
    L = p.lf + p.lr
    a_lim = min(p.mu_f, p.mu_r) * p.g
    fz_rated = 0.25 * p.m * p.g
    loss = []
    for share, axle_static, t in ((p.roll_front, p.lr / L, p.track_f), (1.0 - p.roll_front, p.lf / L, p.track_r)):
        dlat = min(share * p.m * p.h * a_lim / t, 0.5 * axle_static * p.m * p.g)
        loss.append(1.0 - p.k_load * (dlat / fz_rated) ** 2)
    grip = (p.mu_f / vehicle.mu, p.mu_r / vehicle.mu)
    clip = lambda f: float(np.clip(f, 0.2, 3.0))  # noqa: E731 - the catalogue's range of factors
    effects = [
        EffectConfig(name="tire_friction", params={"front": clip(grip[0] * loss[0]), "rear": clip(grip[1] * loss[1])}),
        EffectConfig(name="cornering_stiffness", params={"front": clip(1.0 / grip[0]), "rear": clip(1.0 / grip[1])}),
    ]
    if p.k_load > 0:
        effects.append(EffectConfig(name="tire_load_sensitivity", params={"k": p.k_load}))
    if p.c_l > 0:
        effects.append(EffectConfig(name="downforce", params={"c_l": p.c_l, "balance": p.aero_front}))
    if p.h > 0:
        effects.append(EffectConfig(name="load_transfer", params={"cog_height": p.h}))
    if p.combined:
        effects.append(EffectConfig(name="combined_slip", params={"k": 1.0}))
    if car.steering_lag >= 1e-3:
        effects.append(EffectConfig(name="steering_lag", params={"tau": car.steering_lag}))
    missing = ["lateral load transfer (folded into tire_friction at the limit)", "load-transfer lag"]
    missing += ["tire relaxation"] * (p.sigma > 0) + ["steering rate limit"]
    missing += ["measurement delay"] * (car.delay > 0)
    missing += ["longitudinal friction limit of each wheel"] * bool(p.combined)
    missing += ["drive on the front axle"] * (p.drive_rear < 1.0)
    veh = vehicle.model_copy(update={"yaw_inertia": p.iz, "drag_coefficient": p.cxw, "effects": ()})
    return Approximation(known=True, vehicle=veh, effects=tuple(effects), exact=False, missing=tuple(missing),
                         delay_periods=float(car.delay))
