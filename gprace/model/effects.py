"""The effect catalogue: named, parametric physics a nominal model may leave out.

The same classes let the ``frenet`` plant include an effect (with its true parameters) and let
``gprace diagnose`` test for it (fitting the parameters). Each effect hooks into the stages of
:func:`gprace.model.dynamics.dynamics` it changes (``inputs``, ``loads``, ``tire``, ``forces``),
may carry internal states (actuator lags) and may act on the measurement (sensor bias).
Adding an effect is one small class here, decorated with :func:`effect`.

Parameter conventions: every parameter has a default that means "no effect" where one exists,
bounds used by fitting, a unit and a description. Window effects (``road_grade``, ``road_bank``,
``friction_patch``) act over ``s_start <= s <= s_end`` with smooth logistic edges of width
``ramp`` (so they are differentiable for fitting); windows do not wrap over the start line.

Profile effects (``road_bank_profile``, ``road_grade_profile``, ``friction_profile``) are the same
physics as the windows, varying along the whole lap: the quantity is given at ``knots`` (track
position [m]) by ``values`` and interpolated linearly between them, periodically over
``lap_length`` (``lap_length = 0``: an open track, the end values held beyond the ends). Knots and
values are lists in TOML (``knots = [0.0, 12.5, ...]``), so the profile that ``gprace diagnose``
fitted is evaluated again exactly by the ``frenet`` plant and by :class:`~gprace.model.NominalModel`
(numpy and CasADi).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np

from gprace.config import EffectConfig
from gprace.errors import ConfigError


@dataclass(frozen=True)
class ParamSpec:
    default: float | None  # None: required
    lower: float
    upper: float
    unit: str
    description: str


class Effect:
    """Base class. Subclasses set the class variables and override the stage hooks they need."""

    name: ClassVar[str]
    description: ClassVar[str]
    channels: ClassVar[tuple[str, ...]]
    params: ClassVar[dict[str, ParamSpec]]
    n_states: ClassVar[int] = 0
    window: ClassVar[bool] = False
    profile: ClassVar[bool] = False

    def __init__(self, **values: Any) -> None:
        unknown = set(values) - set(self.params)
        if unknown:
            raise ConfigError(
                f"effect {self.name!r}: unknown parameter(s) {', '.join(sorted(unknown))}; "
                f"valid: {', '.join(self.params)}"
            )
        self.values: dict[str, Any] = {}
        for k, spec in self.params.items():
            if k in values:
                self.values[k] = values[k]
            elif spec.default is None:
                raise ConfigError(f"effect {self.name!r}: parameter {k!r} is required ({spec.description})")
            else:
                self.values[k] = spec.default
        for k, v in self.values.items():
            spec = self.params[k]
            if isinstance(v, (list, tuple)):  # a list parameter (a profile's knots and values)
                bad = [x for x in v if not (spec.lower <= x <= spec.upper)]
                if bad:
                    raise ConfigError(f"effect {self.name!r}: {k} has {bad[0]} outside "
                                      f"[{spec.lower}, {spec.upper}] {spec.unit}")
            elif isinstance(v, (int, float)) and not (spec.lower <= v <= spec.upper):
                raise ConfigError(
                    f"effect {self.name!r}: {k} = {v} outside [{spec.lower}, {spec.upper}] {spec.unit}"
                )
        self.z0 = 0  # index of this effect's first state inside the effect-state block

    def __getattr__(self, item: str) -> Any:
        values = self.__dict__.get("values")
        if values is not None and item in values:
            return values[item]
        raise AttributeError(item)

    def __repr__(self) -> str:
        return f"{self.name}({', '.join(f'{k}={v!r}' for k, v in self.values.items())})"

    def config(self) -> EffectConfig:
        return EffectConfig(name=self.name, params={
            k: tuple(float(x) for x in v) if isinstance(v, (list, tuple, np.ndarray)) else float(v)
            for k, v in self.values.items()})

    # stage hooks (no-ops by default) ---------------------------------------------------------
    def inputs(self, c: SimpleNamespace) -> None: ...
    def loads(self, c: SimpleNamespace) -> None: ...
    def tire(self, c: SimpleNamespace) -> None: ...
    def forces(self, c: SimpleNamespace) -> None: ...

    def derivative(self, c: SimpleNamespace) -> list[Any]:
        return []

    def initial_states(self, u: np.ndarray) -> np.ndarray:
        """Effect states at the start, given the first input ``u`` (n, 2)."""
        return np.zeros((len(u), self.n_states))

    def measure(self, y: dict[str, Any]) -> None:
        """Sensor effects change the measured channels in place."""

    # helpers ---------------------------------------------------------------------------------
    def _window(self, c: SimpleNamespace) -> Any:
        ops, r = c.ops, self.values["ramp"]
        return ops.sigmoid((c.s - self.values["s_start"]) / r) * ops.sigmoid((self.values["s_end"] - c.s) / r)


EFFECTS: dict[str, type[Effect]] = {}


def effect(cls: type[Effect]) -> type[Effect]:
    if cls.name in EFFECTS:
        raise ConfigError(f"effect {cls.name!r} defined twice")
    EFFECTS[cls.name] = cls
    return cls


def make_effect(cfg: EffectConfig | str, **values: Any) -> Effect:
    name = cfg if isinstance(cfg, str) else cfg.name
    if not isinstance(cfg, str):
        values = {**cfg.params, **values}
    try:
        cls = EFFECTS[name]
    except KeyError:
        raise ConfigError(f"unknown effect {name!r}; catalogue: {', '.join(EFFECTS)}") from None
    return cls(**values)


_WINDOW = {
    "s_start": ParamSpec(None, -1e6, 1e6, "m", "start of the window along s"),
    "s_end": ParamSpec(None, -1e6, 1e6, "m", "end of the window along s"),
    "ramp": ParamSpec(1.0, 1e-3, 100.0, "m", "width of the smooth window edges"),
}


# --------------------------------------------------------------------------------------------
# longitudinal


@effect
class AeroDrag(Effect):
    name = "aero_drag"
    description = "extra wind drag c_d v_x^2 (drag missing or mis-set in the nominal model)"
    channels = ("v_x",)
    params = {"c_d": ParamSpec(None, -5.0, 50.0, "kg/m", "extra drag coefficient in F = c_d v_x^2")}

    def forces(self, c):
        c.fxw = c.fxw + self.c_d * c.vx * c.vx


@effect
class RollingResistance(Effect):
    name = "rolling_resistance"
    description = "extra constant rolling resistance c_rr m g"
    channels = ("v_x",)
    params = {"c_rr": ParamSpec(None, -0.1, 0.3, "-", "extra rolling resistance coefficient")}

    def forces(self, c):
        c.rx = c.rx + self.c_rr * c.p.m * c.p.g


@effect
class RoadGrade(Effect):
    name = "road_grade"
    description = "road slope over a window of s (positive uphill)"
    channels = ("v_x",)
    params = {"angle": ParamSpec(None, -0.3, 0.3, "rad", "slope angle (positive uphill)"), **_WINDOW}
    window = True

    def forces(self, c):
        c.grade = c.grade + self.angle * self._window(c)


@effect
class DrivetrainLag(Effect):
    name = "drivetrain_lag"
    description = "first-order lag between commanded and delivered a_x"
    channels = ("v_x",)
    params = {"tau": ParamSpec(None, 1e-3, 2.0, "s", "time constant of the drivetrain")}
    n_states = 1

    def inputs(self, c):
        c.ax = c.z[self.z0]

    def derivative(self, c):
        return [(c.ax_cmd - c.z[self.z0]) / self.tau]

    def initial_states(self, u):
        return u[:, 1:2].copy()


# --------------------------------------------------------------------------------------------
# lateral: loads and tires


@effect
class Downforce(Effect):
    name = "downforce"
    description = "aero load c_l v_x^2 on the axles (front share 'balance'), raising tire force"
    channels = ("v_y", "yaw_rate")
    params = {
        "c_l": ParamSpec(None, -5.0, 100.0, "N s^2/m^2", "downforce coefficient in F_z,aero = c_l v_x^2"),
        "balance": ParamSpec(0.45, 0.0, 1.0, "-", "share of the downforce on the front axle"),
    }

    def loads(self, c):
        f = self.c_l * c.vx * c.vx
        c.fz_f = c.fz_f + self.balance * f
        c.fz_r = c.fz_r + (1.0 - self.balance) * f


@effect
class LoadTransfer(Effect):
    name = "load_transfer"
    description = "longitudinal load transfer m a_x h / L from the rear to the front under braking"
    channels = ("v_y", "yaw_rate")
    params = {"cog_height": ParamSpec(None, 0.0, 2.0, "m", "CoG height driving the load transfer")}

    def loads(self, c):
        d = c.p.m * c.ax * self.cog_height / (c.p.lf + c.p.lr)
        c.fz_f = c.fz_f - d
        c.fz_r = c.fz_r + d


@effect
class TireLoadSensitivity(Effect):
    name = "tire_load_sensitivity"
    description = "friction falling with normal load: mu_i = mu (1 - k (F_z,i - F_z0)/F_z0), F_z0 = m g / 2"
    channels = ("v_y", "yaw_rate")
    params = {"k": ParamSpec(None, -1.0, 1.0, "-", "load sensitivity of the friction")}

    def tire(self, c):
        fz0 = 0.5 * c.p.m * c.p.g
        c.mu_f = c.mu_f * (1.0 - self.k * (c.fz_f - fz0) / fz0)
        c.mu_r = c.mu_r * (1.0 - self.k * (c.fz_r - fz0) / fz0)


@effect
class TireFriction(Effect):
    name = "tire_friction"
    description = "peak friction of an axle mis-set (factor on mu)"
    channels = ("v_y", "yaw_rate")
    params = {
        "front": ParamSpec(1.0, 0.2, 3.0, "-", "factor on the front axle's mu"),
        "rear": ParamSpec(1.0, 0.2, 3.0, "-", "factor on the rear axle's mu"),
    }

    def tire(self, c):
        c.mu_f = c.mu_f * self.front
        c.mu_r = c.mu_r * self.rear


@effect
class CorneringStiffness(Effect):
    name = "cornering_stiffness"
    description = "tire stiffness factor B of an axle mis-set (factor on B)"
    channels = ("v_y", "yaw_rate")
    params = {
        "front": ParamSpec(1.0, 0.2, 5.0, "-", "factor on the front axle's B"),
        "rear": ParamSpec(1.0, 0.2, 5.0, "-", "factor on the rear axle's B"),
    }

    def tire(self, c):
        c.b_f = c.b_f * self.front
        c.b_r = c.b_r * self.rear


@effect
class FrictionPatch(Effect):
    name = "friction_patch"
    description = "lower friction (factor on mu of both axles) over a window of s"
    channels = ("v_y", "yaw_rate")
    params = {"factor": ParamSpec(None, 0.1, 1.5, "-", "friction factor inside the window"), **_WINDOW}
    window = True

    def tire(self, c):
        f = 1.0 + (self.factor - 1.0) * self._window(c)
        c.mu_f = c.mu_f * f
        c.mu_r = c.mu_r * f


@effect
class CombinedSlip(Effect):
    name = "combined_slip"
    description = (
        "lateral grip lost to longitudinal force on the friction ellipse: F_y scaled by "
        "sqrt(1 - k (F_x/(mu F_z))^2); drive on the rear axle, braking split in proportion to the "
        "current axle loads (an ideally balanced brake; the static split when no load effect is active)"
    )
    channels = ("v_y", "yaw_rate")
    params = {"k": ParamSpec(1.0, 0.0, 2.0, "-", "strength of the coupling (1: full friction ellipse)")}

    def forces(self, c):
        ops, p = c.ops, c.p
        fx = p.m * c.ax
        brake = ops.fmin(fx, 0.0)
        share_f = c.fz_f / (c.fz_f + c.fz_r)  # loads after load transfer and downforce
        fx_r = ops.fmax(fx, 0.0) + brake * (1.0 - share_f)
        fx_f = brake * share_f
        floor = 0.05
        c.fy_f = c.fy_f * ops.sqrt(ops.fmax(1.0 - self.k * (fx_f / (c.mu_f * c.fz_f)) ** 2, floor))
        c.fy_r = c.fy_r * ops.sqrt(ops.fmax(1.0 - self.k * (fx_r / (c.mu_r * c.fz_r)) ** 2, floor))


@effect
class RoadBank(Effect):
    name = "road_bank"
    description = "bank angle over a window of s (positive: left edge higher, pushes the car right)"
    channels = ("v_y",)
    params = {"angle": ParamSpec(None, -0.3, 0.3, "rad", "bank angle (positive: left side higher)"), **_WINDOW}
    window = True

    def forces(self, c):
        c.f_lat = c.f_lat - c.p.m * c.p.g * c.ops.sin(self.angle * self._window(c))


# --------------------------------------------------------------------------------------------
# steering, inertia, sensors


@effect
class SteeringLag(Effect):
    name = "steering_lag"
    description = "first-order lag between commanded and actual steering angle"
    channels = ("v_y", "yaw_rate")
    params = {"tau": ParamSpec(None, 1e-3, 1.0, "s", "time constant of the steering actuator")}
    n_states = 1

    def inputs(self, c):
        c.delta = c.z[self.z0]

    def derivative(self, c):
        return [(c.delta_cmd - c.z[self.z0]) / self.tau]

    def initial_states(self, u):
        return u[:, 0:1].copy()


@effect
class SteeringOffset(Effect):
    name = "steering_offset"
    description = "constant bias between commanded and actual steering angle"
    channels = ("v_y", "yaw_rate")
    params = {"offset": ParamSpec(None, -0.1, 0.1, "rad", "steering bias added to the command")}

    def inputs(self, c):
        c.delta = c.delta + self.offset


@effect
class YawInertia(Effect):
    name = "yaw_inertia"
    description = "yaw inertia mis-set (factor on I_zz)"
    channels = ("yaw_rate",)
    params = {"factor": ParamSpec(None, 0.2, 5.0, "-", "factor on the nominal I_zz")}

    def forces(self, c):
        c.iz = c.iz * self.factor


@effect
class GyroBias(Effect):
    name = "gyro_bias"
    description = "constant offset of the yaw-rate sensor (acts on the measurement only)"
    channels = ("yaw_rate",)
    params = {"bias": ParamSpec(None, -0.5, 0.5, "rad/s", "offset added to the measured yaw rate")}

    def measure(self, y):
        y["yaw_rate"] = y["yaw_rate"] + self.bias


@effect
class VelocityMisalignment(Effect):
    name = "velocity_misalignment"
    description = (
        "the velocity sensor's frame (a GNSS/INS heading) turned by a small angle against the car's body: "
        "measured v_y = v_y cos(a) + v_x sin(a), v_x = v_x cos(a) - v_y sin(a) (acts on the measurement only)"
    )
    channels = ("v_y",)
    params = {"angle": ParamSpec(None, -0.05, 0.05, "rad", "angle of the velocity frame against the body (left +)")}

    def measure(self, y):
        ca, sa = np.cos(self.angle), np.sin(self.angle)
        vx, vy = y["v_x"], y["v_y"]
        y["v_x"] = vx * ca - vy * sa
        y["v_y"] = vy * ca + vx * sa

# --------------------------------------------------------------------------------------------
# effects that vary along the lap (profiles)


_PROFILE = {
    "knots": ParamSpec(None, 0.0, 1e6, "m", "track positions of the profile's knots (strictly increasing)"),
    "lap_length": ParamSpec(0.0, 0.0, 1e6, "m", "period of the profile (the lap length); 0: an open track, "
                            "the end values held beyond the end knots"),
}


class ProfileEffect(Effect):
    """Base of the profile effects: a quantity given at ``knots`` by ``values``, linear in between
    and periodic over ``lap_length``. Subclasses set ``params["values"]`` (unit and bounds of the
    quantity), ``window_of`` (the window effect with the same physics) and apply :meth:`value`."""

    profile = True
    window_of: ClassVar[str]

    def __init__(self, **values: Any) -> None:
        super().__init__(**values)
        k = np.asarray(self.values["knots"], dtype=float)
        v = np.asarray(self.values["values"], dtype=float)
        L = float(self.values["lap_length"])
        if k.ndim != 1 or k.shape != v.shape or len(k) < 2:
            raise ConfigError(f"effect {self.name!r}: knots and values must be lists of the same length "
                              f"(at least 2); got {k.size} knots and {v.size} values")
        if np.any(np.diff(k) <= 0):
            raise ConfigError(f"effect {self.name!r}: knots must be strictly increasing")
        if L > 0 and k[-1] >= L:
            raise ConfigError(f"effect {self.name!r}: knot at s = {k[-1]:g} m is not inside the lap "
                              f"(lap_length {L:g} m)")
        self._knots, self._vals, self._period = k, v, L
        self._lookup = None  # CasADi interpolant, built on first symbolic use

    def value(self, c: SimpleNamespace) -> Any:
        """The profile at the car's position ``c.s`` (numpy arrays or a CasADi expression)."""
        k, v, L = self._knots, self._vals, self._period
        if c.ops.name == "numpy":
            if L > 0:
                return np.interp(np.mod(c.s, L), k, v, period=L)
            return np.interp(c.s, k, v)
        import casadi as ca

        if self._lookup is None:
            if L > 0:  # one knot more on each side: the interpolation wraps like np.interp's period
                grid = np.concatenate([[k[-1] - L], k, [k[0] + L]])
                vals = np.concatenate([[v[-1]], v, [v[0]]])
            else:
                grid, vals = k, v
            self._lookup = ca.interpolant(f"{self.name}_lookup", "linear", [grid.tolist()], vals.tolist())
        if L > 0:
            return self._lookup(ca.fmod(ca.fmod(c.s, L) + L, L))
        return self._lookup(ca.fmin(ca.fmax(c.s, float(k[0])), float(k[-1])))


@effect
class RoadBankProfile(ProfileEffect):
    name = "road_bank_profile"
    description = "bank angle varying along the lap (positive: left edge higher, pushes the car right)"
    channels = ("v_y",)
    params = {"values": ParamSpec(None, -0.6, 0.6, "rad", "bank angle at each knot (positive: left side higher)"),
              **_PROFILE}
    window_of = "road_bank"

    def forces(self, c):
        c.f_lat = c.f_lat - c.p.m * c.p.g * c.ops.sin(self.value(c))


@effect
class RoadGradeProfile(ProfileEffect):
    name = "road_grade_profile"
    description = "road slope varying along the lap (positive uphill)"
    channels = ("v_x",)
    params = {"values": ParamSpec(None, -0.3, 0.3, "rad", "slope angle at each knot (positive uphill)"), **_PROFILE}
    window_of = "road_grade"

    def forces(self, c):
        c.grade = c.grade + self.value(c)


@effect
class FrictionProfile(ProfileEffect):
    name = "friction_profile"
    description = "friction factor on mu of both axles varying along the lap"
    channels = ("v_y", "yaw_rate")
    params = {"values": ParamSpec(None, 0.1, 1.5, "-", "friction factor at each knot"), **_PROFILE}
    window_of = "friction_patch"

    def tire(self, c):
        f = self.value(c)
        c.mu_f = c.mu_f * f
        c.mu_r = c.mu_r * f
