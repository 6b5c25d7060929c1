"""Frozen pydantic configuration models, loaded from TOML.

Every model forbids unknown keys; :func:`load_toml` turns a validation failure into a
:class:`~gprace.errors.ConfigError` whose message names the file and the TOML path
(``vehicle.tire.b_front``) at fault. Units are SI throughout.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import math
import tomllib
from pathlib import Path
from typing import Any, Callable, ClassVar, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_serializer, model_validator

from gprace.errors import ConfigError, InputError, UnknownBackendError
from gprace.registry import plants  # plant modules load (and import this one) only when a kind is looked up

G = 9.81
"""Gravitational acceleration [m/s^2]."""

M = TypeVar("M", bound="Frozen")

MAX_LENGTH = 30.0
"""Longest physically possible vehicle dimension [m] (axle distances, width, length, CoG height)."""


# Plausible vehicles (VehicleConfig._plausible): outside POSSIBLE a value is refused, outside
# PLAUSIBLE it is warned. The ranges hold road cars, racing cars (a 790 kg Dallara of the Indy
# Autonomous Challenge, an F1 car) and 1:10 model cars (the shipped barc_1_10).
MU_POSSIBLE = (0.05, 3.0)
"""Tire-road friction ratios that exist: about 0.1 on ice, 1.7 for racing slicks; 3 is already far
beyond any tire (downforce belongs in an effect, not in mu)."""
MU_PLAUSIBLE = (0.3, 2.0)
K_PLAUSIBLE = (0.25, 0.7)
"""Radius of gyration about the vertical axis, ``sqrt(I_zz / m)``, as a share of the wheelbase: road
and racing cars 0.45 to 0.6 (shipped: audi 0.54, bmw 0.50), the 1:10 car 0.34."""
K_POSSIBLE_MIN = 0.1
"""Below this share of the wheelbase the four wheels alone (a tenth of the mass at the axles)
would give more yaw inertia: the mass or the inertia is in other units."""
WHEELBASE_SHARE_MIN = 0.4
"""Wheelbase over length: cars 0.55 to 0.7; a 1:10 car's footprint can be its wheelbase (1.0)."""
AXLE_SHARE_MAX = 0.8
"""l_f / wheelbase between 0.2 and 0.8 (mid-engined cars about 0.55, front-heavy ones 0.4)."""

_WARNED: set[str] = set()


def _warn_once(text: str) -> None:
    """A plausibility warning, once per process (a vehicle is validated each time it is loaded)."""
    if text not in _WARNED:
        _WARNED.add(text)
        from gprace.console import console

        console.warn(text)


def physical(value: float, limit: float, unit: str, probable: str) -> float:
    """``value`` if at most ``limit``; else a ValueError naming the value and the probable unit slip
    (pydantic adds the field's TOML path, :func:`validate` the file)."""
    if value > limit:
        raise ValueError(f"{value:g} {unit} is physically impossible (at most {limit:.4g}); {probable}?")
    return value


class Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    def digest(self) -> str:
        """Stable hash of the configuration (stored in artifacts as ``config_hash``)."""
        return config_hash(self.model_dump(mode="json"))

    def to_toml(self) -> str:
        return dumps_toml(self.model_dump(mode="json", exclude_none=True))


class CommandSettings(Frozen):
    """Settings a command builds from its options: frozen, validated once when built, and a bad
    value is an :class:`~gprace.errors.InputError` (exit 2) naming the option (``--dict-size``).

    A field's option is ``--`` and its name with dashes unless ``OPTIONS`` says otherwise; checks
    across fields live in ``model_validator(mode="after")`` methods that raise ``ValueError`` with
    the options named in the message.
    """

    OPTIONS: ClassVar[dict[str, str]] = {}
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)  # no setting is infinite or NaN

    def __init__(self, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as exc:
            raise option_error(exc, self.OPTIONS) from None


def option_error(exc: ValidationError, options: dict[str, str] | None = None) -> InputError:
    """A validation error of settings made from command-line options, as one line naming the
    option as the CLI spells it: ``--name`` with dashes, or what ``options`` maps the field to."""
    err = exc.errors()[0]
    msg = err["msg"].removeprefix("Value error, ")
    if not err["loc"]:  # a check across fields names its options itself
        return InputError(msg)
    name = str(err["loc"][0])
    option = (options or {}).get(name, "--" + name.replace("_", "-"))
    if err["type"] == "extra_forbidden":
        return InputError(f"{option}: unknown setting")
    bound = {"greater_than_equal": ">=", "greater_than": ">", "less_than_equal": "<=", "less_than": "<"}
    ctx = err.get("ctx") or {}
    if err["type"] in bound:
        limit = next(iter(ctx.values()))
        return InputError(f"{option} must be {bound[err['type']]} {limit}, got {err['input']!r}")
    return InputError(f"{option}: {msg}, got {err.get('input')!r}")


def from_options(model: type[M], data: dict[str, Any], options: dict[str, str] | None = None) -> M:
    """``model`` (any configuration model) from command-line options, refused as :func:`option_error`."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise option_error(exc, options) from None


class TireConfig(Frozen):
    """Simplified Magic Formula per axle: ``F_y = mu * F_z * sin(C * atan(B * alpha))``."""

    b_front: float = Field(gt=0, description="stiffness factor B of the front axle [1/rad]")
    c_front: float = Field(gt=0, description="shape factor C of the front axle [-]")
    b_rear: float = Field(gt=0, description="stiffness factor B of the rear axle [1/rad]")
    c_rear: float = Field(gt=0, description="shape factor C of the rear axle [-]")


class LimitsConfig(Frozen):
    """Actuator and speed limits used by planners and controllers."""

    steering_max: float = Field(gt=0, description="|delta| bound [rad]")
    steering_rate_max: float = Field(gt=0, description="|d delta/dt| bound [rad/s]")
    accel_min: float = Field(lt=0, description="strongest braking a_x [m/s^2]")
    accel_max: float = Field(gt=0, description="strongest drive a_x [m/s^2]")
    speed_max: float = Field(gt=0, description="top speed [m/s]")

    @field_validator("steering_max")
    @classmethod
    def _steering_in_radians(cls, v: float) -> float:
        return physical(v, 0.5 * math.pi, "rad", "degrees instead of radians")

    @field_validator("steering_rate_max")
    @classmethod
    def _steering_rate_in_radians(cls, v: float) -> float:
        return physical(v, 20.0, "rad/s", "degrees per second instead of rad/s")


class EffectConfig(Frozen):
    """One effect of the catalogue with its parameters (``[[effects]]`` tables in TOML).

    ``params`` keys are the effect's parameter names. The configuration layer does not know the
    catalogue: the names and parameters are checked by :func:`gprace.model.load_vehicle` /
    :func:`gprace.model.load_plant` when a file is loaded for use, and by the model built from it.
    """

    name: str = Field(description="catalogue name, e.g. 'downforce'")
    params: dict[str, float | tuple[float, ...]] = Field(
        default_factory=dict, description="physical parameters (SI); lists for a profile's knots and values")


class VehicleConfig(Frozen):
    """The nominal vehicle model: the paper's Frenet dynamic bicycle with MF tires.

    ``effects`` lists physics added on top of the paper's model (for example by ``gprace
    diagnose -o``); an empty list is the plain nominal model.
    """

    name: str = Field(description="vehicle name")
    mass: float = Field(gt=0, description="total mass m [kg]")
    yaw_inertia: float = Field(gt=0, description="I_zz [kg m^2]")
    l_f: float = Field(gt=0, description="CoG to front axle [m]")
    l_r: float = Field(gt=0, description="CoG to rear axle [m]")
    width: float = Field(gt=0, description="chassis width [m]")
    length: float = Field(gt=0, description="footprint length [m]")
    cog_height: float = Field(ge=0, description="CoG height h_c [m]")
    mu: float = Field(gt=0, description="tire-road friction ratio [-]")
    drag_coefficient: float = Field(ge=0, description="wind drag C_xw in F = C_xw v_x^2 [kg/m]")
    rolling_resistance: float = Field(ge=0, description="rolling resistance coefficient c_rr, R_x = c_rr m g [-]")
    v_min: float = Field(gt=0, description="speed floor used in slip angles to avoid 0/0 [m/s]")
    tire: TireConfig
    limits: LimitsConfig
    effects: tuple[EffectConfig, ...] = Field(default=(), description="extra physics on the nominal model")
    # inputs as a recording has them (issue 36); left out of dumps at their defaults, so files and
    # hashes of vehicles that do not set them are unchanged
    steering_gain: float = Field(1.0, gt=0, le=10.0, description="road-wheel angle per unit of the steering "
                                 "input (a servo's or column's ratio error) [-]")
    steering_offset: float = Field(0.0, ge=-0.5, le=0.5, description="offset added to the road-wheel angle [rad]")
    speed_loop_tau: float = Field(0.5, gt=0, le=1e4, description="time constant of the car's own speed "
                                  "controller, when a recording's longitudinal input is a speed command [s]")
    speed_loop_gain: float = Field(1.0, gt=0, le=1e4, description="speed the car's controller aims at per unit "
                                   "of the speed command [-]")

    # known delays (issue 37): the tracking MPC predicts over them; None: unknown
    actuator_delay: float | None = Field(None, ge=0, description="known dead time of the steering actuator [s] (a "
                                         "first-order lag: its time constant); the tracking MPC predicts over it. "
                                         "None: unknown (gprace iterate estimates it in the shakedown)")
    measurement_delay: float | None = Field(None, ge=0, description="known age of the measurements when the "
                                            "controller gets them [s]; the tracking MPC predicts over it")

    OPTIONAL_AT_DEFAULT: ClassVar[dict[str, float | None]] = {
        "steering_gain": 1.0, "steering_offset": 0.0, "speed_loop_tau": 0.5, "speed_loop_gain": 1.0,
        "actuator_delay": None, "measurement_delay": None}

    @model_serializer(mode="wrap")
    def _drop_defaults(self, handler):
        """The fields added by issues 36 and 37 stay out of a dump while they hold their defaults."""
        out = handler(self)
        for k, d in self.OPTIONAL_AT_DEFAULT.items():
            if k in out and out[k] == d:
                del out[k]
        return out

    @field_validator("l_f", "l_r", "width", "length", "cog_height")
    @classmethod
    def _length_in_metres(cls, v: float) -> float:
        return physical(v, MAX_LENGTH, "m", "millimetres or centimetres instead of metres")

    @field_validator("mass", "yaw_inertia", "l_f", "l_r", "width", "length", "cog_height", "mu", "drag_coefficient",
                     "rolling_resistance", "v_min")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError(f"{v} is not a finite number")
        return v

    @field_validator("mu")
    @classmethod
    def _friction_possible(cls, v: float) -> float:
        lo, hi = MU_POSSIBLE
        if not lo <= v <= hi:
            raise ValueError(f"{v:g} is no tire-road friction ratio (possible {lo:g} to {hi:g}: ice about 0.1, dry "
                             "asphalt about 1, racing slicks about 1.7; downforce is an effect, not mu)")
        return v

    @model_validator(mode="after")
    def _plausible(self) -> VehicleConfig:
        """Values that no car has are refused; values that a real car could have but few do are
        warned, with the plausible range (see ``PLAUSIBLE`` for the ranges and where they come from)."""
        L, k = self.wheelbase, math.sqrt(self.yaw_inertia / self.mass)
        if L > self.length * (1 + 1e-6):
            raise ValueError(f"l_f + l_r = {L:.4g} m (the wheelbase) is longer than the car's length {self.length:.4g} m")
        k_max = 0.5 * math.hypot(self.length, self.width)
        lo, hi = K_PLAUSIBLE
        rng = f"plausible {self.mass * (lo * L) ** 2:.4g} to {self.mass * (hi * L) ** 2:.4g} kg m^2 for this mass and wheelbase"
        if k > k_max:
            raise ValueError(f"yaw_inertia {self.yaw_inertia:g} kg m^2 with mass {self.mass:g} kg is a radius of gyration "
                             f"of {k:.3g} m, more than half the car's diagonal ({k_max:.3g} m): impossible ({rng}; "
                             "mass in tonnes or inertia in other units?)")
        if k < K_POSSIBLE_MIN * L:
            raise ValueError(f"yaw_inertia {self.yaw_inertia:g} kg m^2 with mass {self.mass:g} kg is a radius of gyration "
                             f"of {k:.3g} m, {k / L:.2g} times the wheelbase: less than the wheels alone give ({rng}; "
                             "mass in grams or inertia in g cm^2?)")
        if self.cog_height > self.width:
            raise ValueError(f"cog_height {self.cog_height:g} m is above the car's width {self.width:g} m: it would roll "
                             f"over at {self.width / (2 * self.cog_height):.2g} g (no car on wheels is that tall)")
        notes = []
        if not MU_PLAUSIBLE[0] <= self.mu <= MU_PLAUSIBLE[1]:
            notes.append(f"mu {self.mu:g} is outside the usual {MU_PLAUSIBLE[0]:g} to {MU_PLAUSIBLE[1]:g} of tires on a "
                         "road (ice, or slicks with downforce folded into mu?)")
        if not lo <= k / L <= hi:
            notes.append(f"yaw_inertia {self.yaw_inertia:g} kg m^2 is a radius of gyration of {k / L:.2g} times the "
                         f"wheelbase, outside the usual {lo:g} to {hi:g} ({rng})")
        if L < WHEELBASE_SHARE_MIN * self.length:
            notes.append(f"the wheelbase l_f + l_r = {L:.4g} m is {L / self.length:.2g} of the car's length; cars have "
                         f"{WHEELBASE_SHARE_MIN:g} to 1")
        if not 1 - AXLE_SHARE_MAX <= self.l_f / L <= AXLE_SHARE_MAX:
            notes.append(f"the CoG is {self.l_f / L:.2g} of the wheelbase behind the front axle; cars have "
                         f"{1 - AXLE_SHARE_MAX:g} to {AXLE_SHARE_MAX:g}")
        if self.cog_height > 0 and self.width / (2 * self.cog_height) < self.mu:
            notes.append(f"cog_height {self.cog_height:g} m on a {self.width:g} m wide car rolls over at "
                         f"{self.width / (2 * self.cog_height):.2g} g, before the tires slide at mu {self.mu:g} (the "
                         "model has no roll-over)")
        if notes:
            _warn_once(f"vehicle {self.name}: {'; '.join(notes)}")
        return self

    @property
    def wheelbase(self) -> float:
        return self.l_f + self.l_r

    @property
    def known_delay(self) -> float | None:
        """Total delay the controller predicts over [s], or None when neither delay is given."""
        if self.actuator_delay is None and self.measurement_delay is None:
            return None
        return (self.actuator_delay or 0.0) + (self.measurement_delay or 0.0)


class NoiseConfig(Frozen):
    """Standard deviation of white measurement noise per recorded channel (SI units)."""

    v_x: float = Field(0.0, ge=0)
    v_y: float = Field(0.0, ge=0)
    yaw_rate: float = Field(0.0, ge=0)
    e_psi: float = Field(0.0, ge=0)
    e_y: float = Field(0.0, ge=0)
    s: float = Field(0.0, ge=0)


class PlantConfig(Frozen):
    """"The real car": a registered plant, the vehicle it starts from, and what it hides.

    For ``frenet`` the hidden ``effects`` are added to the vehicle's own; ``commonroad-std`` and
    ``commonroad-mb`` use their own BMW 320i parameters and reject ``effects``; ``randomized``
    draws a car around ``vehicle`` (docs/plants.md). ``options`` are the plant kind's own settings
    (``[options]`` in TOML), checked against the kind's ``Options`` model when the file is read.
    """

    kind: str = Field("frenet", description="plant backend name (registry gprace.plant)")
    vehicle: VehicleConfig
    effects: tuple[EffectConfig, ...] = Field(default=(), description="true effects, unknown to the nominal model")
    noise: NoiseConfig = Field(default_factory=NoiseConfig)
    substeps: int = Field(10, ge=1, le=1000, description="RK4 substeps per control period")
    seed: int = Field(0, description="seed of the sensor noise")
    options: dict[str, Any] = Field(default_factory=dict, description="settings of the plant kind (its Options model)")

    @field_validator("options")
    @classmethod
    def _options_of_the_kind(cls, v: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        """Options are checked by the plant kind's nested ``Options`` model (extra keys forbidden);
        an unknown kind is left to the registry (its error lists the kinds)."""
        if not v or "kind" not in info.data:
            return v
        try:
            plant_cls = plants.get(info.data["kind"])
        except UnknownBackendError:
            return v
        plant_options(plant_cls, v)  # ValueError naming the key
        return v

    def digest(self) -> str:
        """As :meth:`Frozen.digest`; empty ``options`` leave the hash of older files unchanged."""
        data = self.model_dump(mode="json")
        if not data["options"]:
            del data["options"]
        return config_hash(data)


def plant_options(plant_cls: type, options: dict[str, Any]) -> BaseModel | None:
    """``options`` validated by ``plant_cls.Options`` (None when the kind has none and none are
    given); a ValueError naming the first bad key otherwise."""
    model = getattr(plant_cls, "Options", None)
    name = getattr(plant_cls, "NAME", plant_cls.__name__)
    if model is None:
        if options:
            raise ValueError(f"plant {name!r} takes no options (got {', '.join(sorted(options))})")
        return None
    try:
        return model.model_validate(options)
    except ValidationError as exc:
        err = next((e for e in exc.errors() if e["type"] == "extra_forbidden"), exc.errors()[0])
        key = ".".join(str(p) for p in err["loc"]) or "(root)"
        if err["type"] == "extra_forbidden":
            valid = ", ".join(model.model_fields)
            close = difflib.get_close_matches(str(err["loc"][0]), list(model.model_fields), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ValueError(f"{key}: unknown key for plant {name!r} ({hint}valid: {valid})") from None
        msg = err["msg"].removeprefix("Value error, ")
        raise ValueError(f"{key}: {msg}, got {err.get('input')!r}") from None


class SimulateConfig(Frozen):
    """Reference controller and recording settings of ``gprace simulate``."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    dt: float = Field(0.05, gt=0, le=1.0, description="control and recording period [s]")
    laps: float = Field(1.0, gt=0, description="laps to drive")
    speed_scale: float = Field(0.8, gt=0, le=1.2, description="fraction of the friction-limited speed")
    weave_amplitude: float = Field(0.0, ge=0, le=1.0, description="lateral weaving amplitude, share of half width [-]")
    weave_wavelength: float = Field(100.0, gt=0, description="weaving wavelength along s [m]")
    seed: int = 0


# --------------------------------------------------------------------------------------------
# loading


def load_toml(path: str | Path, model: type[M], section: str | None = None) -> M:
    """Read ``path`` (optionally one top-level ``section`` of it) into ``model``.

    Relative ``vehicle = "file.toml"`` references inside plant files are resolved against the
    including file's folder.
    """
    path = Path(path)
    data = read_toml(path)
    if section is not None:
        if section not in data:
            raise ConfigError(f"{path}: missing section [{section}]")
        data = data[section]
    data = _resolve_includes(data, path.parent)
    return validate(model, data, str(path))


def read_toml(path: Path) -> dict[str, Any]:
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a TOML file")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file") from None


def validate(model: type[M], data: dict[str, Any], where: str, toml: bool = True) -> M:
    """``data`` as ``model``, or a one-line :class:`ConfigError` naming ``where`` and the first bad
    field. ``toml``: accept a vehicle's effects written flat in TOML (records pass False)."""
    data = _effects_from_toml(data) if toml else data
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errs = exc.errors()
        # a misspelt key shows up as "unknown" plus "missing": report the unknown one first
        err = next((e for e in errs if e["type"] == "extra_forbidden"), errs[0])
        loc = ".".join(str(p) for p in err["loc"])
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
            missing = [str(e["loc"][-1]) for e in errs if e["type"] == "missing" and e["loc"][:-1] == err["loc"][:-1]]
            close = difflib.get_close_matches(str(err["loc"][-1]), missing, n=1)
            if close:
                msg += f" (did you mean {close[0]!r}?)"
        elif err["type"] == "missing":
            msg = "required key missing"
        elif err["type"] == "value_error":
            msg = msg.removeprefix("Value error, ")
        more = f" (and {len(exc.errors()) - 1} more)" if len(exc.errors()) > 1 else ""
        raise ConfigError(f"{where}: {loc + ': ' if loc else ''}{msg}{more}") from None


def _resolve_includes(data: dict[str, Any], base: Path) -> dict[str, Any]:
    """``vehicle = "path.toml"`` -> the parsed vehicle table (relative to the including file)."""
    out = dict(data)
    v = out.get("vehicle")
    if isinstance(v, str):
        p = Path(v)
        if not p.is_absolute():
            p = base / p
        if not p.exists():
            p = builtin_config("vehicles", v)
        out["vehicle"] = read_toml(p)
    return out


def _effects_from_toml(data: Any) -> Any:
    """Accept effects written flat in TOML: ``[[effects]] name = "downforce"  c_l = 1.2``."""
    if not isinstance(data, dict):
        return data
    out = {}
    for k, v in data.items():
        if k == "effects" and isinstance(v, list):
            eff = []
            for e in v:
                if isinstance(e, dict) and "params" not in e:
                    e = {"name": e.get("name"), "params": {a: b for a, b in e.items() if a != "name"}}
                eff.append(e)
            out[k] = eff
        else:
            out[k] = _effects_from_toml(v)
    return out


def configs_dir() -> Path:
    """The shipped ``configs/`` folder (inside the package so an installed wheel has it)."""
    return Path(__file__).parent / "data" / "configs"


def builtin_config(kind: str, name: str) -> Path:
    """Resolve a shipped config by name (``audi_tt_cup``) or path; error lists what exists."""
    p = Path(name)
    if p.exists():
        return p
    folder = configs_dir() / kind
    cand = folder / (name if name.endswith(".toml") else f"{name}.toml")
    if cand.exists():
        return cand
    avail = ", ".join(sorted(q.stem for q in folder.glob("*.toml")))
    raise InputError(f"{name}: no such file, and no shipped {kind} config of that name (shipped: {avail})")


def load_vehicle(name_or_path: str | Path, check: Callable[[Any, str], None] | None = None) -> VehicleConfig:
    """A vehicle file (a shipped name or a path) through :class:`VehicleConfig`; ``check(cfg, path)``
    then checks what this layer cannot (:func:`gprace.model.load_vehicle` passes the effect catalogue's)."""
    p = builtin_config("vehicles", str(name_or_path))
    data = read_toml(p)
    if "vehicle" in data and isinstance(data["vehicle"], dict) and "mass" not in data:
        data = data["vehicle"]  # an augmented plant-style file
    cfg = validate(VehicleConfig, data, str(p))
    if check is not None:
        check(cfg, str(p))
    return cfg


def load_plant(name_or_path: str | Path, check: Callable[[Any, str], None] | None = None) -> PlantConfig:
    """A plant file through :class:`PlantConfig`, ``check(cfg, path)`` as in :func:`load_vehicle`
    (:func:`gprace.model.load_plant`), then its kind looked up in the plugin registry."""
    p = builtin_config("plants", str(name_or_path))
    cfg = load_toml(p, PlantConfig)
    if check is not None:
        check(cfg, str(p))
    plants.get(cfg.kind)  # an unknown kind is refused when the config loads, before any work
    return cfg


# --------------------------------------------------------------------------------------------
# hashing and writing


def config_hash(obj: Any) -> str:
    blob = json.dumps(obj, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def dumps_toml(data: dict[str, Any]) -> str:
    """TOML text of a config (tomli-w); effects in the flat form users write (``name`` beside the
    parameters, not under ``params``)."""
    import tomli_w

    return tomli_w.dumps(_flat_effects(data))


def _flat_effects(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: (_flatten_effects_list(v) if k == "effects" else _flat_effects(v)) for k, v in data.items()}
    return data


def _flatten_effects_list(items: Any) -> Any:
    if not isinstance(items, list):
        return items
    return [{"name": e["name"], **e["params"]} if isinstance(e, dict) and "params" in e else e for e in items]
