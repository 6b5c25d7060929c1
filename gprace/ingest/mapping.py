"""The recording map: where each quantity sits in a recording, its unit and its sign.

A small TOML file (``gprace import --map MAP.toml``), parsed into the frozen model
:class:`RecordingMap` (unknown keys rejected, errors name the TOML path). Every key has a
default, so an empty map (or no map) reads recordings that use gprace's own names and SI units;
``gprace import --print-map`` prints the defaults as a TOML to copy and edit::

    [columns]            # CSV columns and MDF4 channels (a quantity absent from the file is skipped)
    t = "t"  x = "x"  y = "y"  yaw = "yaw" ...
    [topics]             # ROS 1/2 bags and MCAP
    odometry = "/odom"  imu = "/imu"  pose = "/pose"  ackermann = "/drive"
    [units]              # unit of each quantity in the file, converted to SI on reading
    yaw = "rad"  speed = "m/s" ...
    [signs]              # +1 or -1: flips a quantity whose sign convention differs from gprace's
    yaw_rate = 1 ...
    [inputs]             # what the input columns hold (docs/decisions.md, issue 36)
    a_x = "commanded"    # or "measured" (an IMU); delta likewise (servo command or measured)
    [long]               # long-format files: one row per channel sample (name, value, time)
    name = "name"  value = "value"
    [clocks."imu.csv"]   # per-file time column, unit and offset when a drive is split in files
    column = "stamp"  unit = "ns"  offset = 0.0

Paths in a map (``track``) are relative to the map's folder.

Conventions after conversion (gprace's): ``x`` east / ``y`` north (any local metric frame),
``yaw`` counter-clockwise from the x axis, ``yaw_rate`` positive to the left, ``v_y`` positive to
the left, ``delta`` positive to the left (road-wheel angle), ``a_x`` forward.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

from gprace.config import Frozen, dumps_toml, read_toml, validate

QUANTITIES = (
    "t", "x", "y", "yaw", "lat", "lon", "v_x", "v_y", "speed", "course", "v_east", "v_north",
    "yaw_rate", "delta", "steering_wheel", "a_x", "v_cmd",
)
"""Quantities a recording may hold (names of the ``[columns]`` keys)."""

# unit name -> factor to SI, per physical dimension
UNITS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9},
    "length": {"m": 1.0, "km": 1e3, "ft": 0.3048},
    "angle": {"rad": 1.0, "deg": math.pi / 180.0},
    "rate": {"rad/s": 1.0, "deg/s": math.pi / 180.0},
    "speed": {"m/s": 1.0, "km/h": 1.0 / 3.6, "mph": 0.44704},
    "accel": {"m/s^2": 1.0, "g": 9.80665},
}
DIMENSION = {
    "t": "time", "x": "length", "y": "length", "yaw": "angle", "lat": "angle", "lon": "angle",
    "v_x": "speed", "v_y": "speed", "speed": "speed", "course": "angle", "v_east": "speed",
    "v_north": "speed", "yaw_rate": "rate", "delta": "angle", "steering_wheel": "angle", "a_x": "accel",
    "v_cmd": "speed",
}

TimeUnit = Literal["s", "ms", "us", "ns"]
LengthUnit = Literal["m", "km", "ft"]
AngleUnit = Literal["rad", "deg"]
RateUnit = Literal["rad/s", "deg/s"]
SpeedUnit = Literal["m/s", "km/h", "mph"]
AccelUnit = Literal["m/s^2", "g"]
Sign = Literal[1, -1]


class Columns(Frozen):
    """Names of the CSV columns / MDF4 channels holding each quantity (absent ones are skipped)."""

    t: str = Field("t", description="time stamps (not needed for MDF4: each channel has its own)")
    x: str = Field("x", description="position east (or any local metric x)")
    y: str = Field("y", description="position north (or any local metric y)")
    yaw: str = Field("yaw", description="heading of the car's x axis, counter-clockwise from x")
    lat: str = Field("lat", description="latitude (WGS84), used when x/y are absent")
    lon: str = Field("lon", description="longitude (WGS84), used when x/y are absent")
    v_x: str = Field("v_x", description="longitudinal body velocity")
    v_y: str = Field("v_y", description="lateral body velocity (left positive)")
    speed: str = Field("speed", description="speed over ground, used when v_x is absent")
    course: str = Field("course", description="heading of the velocity (with speed), counter-clockwise from x")
    v_east: str = Field("v_east", description="world-frame velocity along x (GNSS), used when v_x is absent")
    v_north: str = Field("v_north", description="world-frame velocity along y (GNSS)")
    yaw_rate: str = Field("yaw_rate", description="yaw rate (left positive)")
    delta: str = Field("delta", description="road-wheel steering angle (left positive)")
    steering_wheel: str = Field("steering_wheel", description="steering-wheel angle, divided by steering_ratio when delta is absent")
    a_x: str = Field("a_x", description="longitudinal acceleration (or its command, [inputs] a_x); derived from speed when absent")
    v_cmd: str = Field("v_cmd", description="speed command (F1TENTH stacks: translational_control)")


class Topics(Frozen):
    """ROS topics (ROS 1 bags, ROS 2 bags in sqlite3 or MCAP)."""

    odometry: str = Field("/odom", description="nav_msgs/msg/Odometry: pose, body twist")
    pose: str = Field("/pose", description="geometry_msgs/msg/PoseStamped: used when odometry is absent")
    imu: str = Field("/imu", description="sensor_msgs/msg/Imu: yaw rate (angular_velocity.z), a_x (linear_acceleration.x)")
    ackermann: str = Field("/drive", description="ackermann_msgs/msg/AckermannDriveStamped: steering_angle, acceleration")
    yaw_rate_from: Literal["imu", "odometry"] = Field("imu", description="source of yaw_rate (falls back to the other)")
    a_x_from: Literal["ackermann", "imu", "speed"] = Field("ackermann", description="source of a_x (falls back: ackermann -> imu -> speed)")
    stamp: Literal["header", "log"] = Field("header", description="time of a message: its header stamp or the bag's log time")


class Units(Frozen):
    """Unit of each quantity in the recording (converted to SI on reading)."""

    t: TimeUnit = "s"
    x: LengthUnit = "m"
    y: LengthUnit = "m"
    yaw: AngleUnit = "rad"
    lat: AngleUnit = "deg"
    lon: AngleUnit = "deg"
    v_x: SpeedUnit = "m/s"
    v_y: SpeedUnit = "m/s"
    speed: SpeedUnit = "m/s"
    course: AngleUnit = "rad"
    v_east: SpeedUnit = "m/s"
    v_north: SpeedUnit = "m/s"
    yaw_rate: RateUnit = "rad/s"
    delta: AngleUnit = "rad"
    steering_wheel: AngleUnit = "rad"
    a_x: AccelUnit = "m/s^2"
    v_cmd: SpeedUnit = "m/s"


class Signs(Frozen):
    """+1, or -1 for a quantity whose sign convention is the opposite of gprace's."""

    yaw: Sign = 1
    v_y: Sign = 1
    yaw_rate: Sign = 1
    delta: Sign = 1
    steering_wheel: Sign = 1
    a_x: Sign = 1


InputKind = Literal["commanded", "measured"]


class Inputs(Frozen):
    """What the input columns hold. ``commanded``: what the controller asked for (a powertrain or
    servo command, as gprace's own recordings hold); ``measured``: what a sensor saw (an IMU's
    longitudinal acceleration, a measured road-wheel angle), which explains the motion
    kinematically. Recorded in the run as ``meta["inputs"]``."""

    a_x: InputKind = Field("commanded", description="a_x column: powertrain command or measured (IMU) acceleration")
    delta: InputKind = Field("commanded", description="steering column: servo command or measured road-wheel angle")


class LongFormat(Frozen):
    """Long-format telemetry: one row per channel sample. The ``[columns]`` names are then channel
    names found in the ``name`` column."""

    name: str = Field("name", description="column holding the channel name")
    value: str = Field("value", description="column holding the sample value")
    time: str | None = Field(None, description="column holding the time stamp; default [columns] t")


class Clock(Frozen):
    """The clock of one file of a drive split into several files (``[clocks."imu.csv"]``)."""

    column: str | None = Field(None, description="its time column; default [columns] t")
    unit: TimeUnit | None = Field(None, description="its time unit; default [units] t")
    offset: float = Field(0.0, description="seconds added to its time stamps (after the unit) to put it on the common clock")


class RecordingMap(Frozen):
    """How to read a recording: names, units, signs, and the processing settings of the import."""

    columns: Columns = Field(default_factory=Columns)
    topics: Topics = Field(default_factory=Topics)
    units: Units = Field(default_factory=Units)
    signs: Signs = Field(default_factory=Signs)
    steering_ratio: float = Field(1.0, gt=0, description="steering-wheel angle / road-wheel angle [-]")
    origin: tuple[float, float] | None = Field(None, description="[lat, lon] in degrees of the tangent plane that lat/lon are projected on (the track's frame); default the first fix")
    inputs: Inputs = Field(default_factory=Inputs)
    layout: Literal["auto", "wide", "long"] = Field("auto", description="CSV layout: wide (a column per quantity), long (name, value, time rows), or auto")
    long: LongFormat = Field(default_factory=LongFormat)
    clocks: dict[str, Clock] = Field(default_factory=dict, description="per-file clocks, keyed by file name")
    hold: tuple[str, ...] | None = Field(None, description="quantities resampled by zero-order hold (commands); default the commanded inputs and v_cmd; the others linearly")
    max_gap: float | None = Field(None, gt=0, description="a source silent for longer than this [s] is a gap; default 5 median periods of that source (at least 2 dt)")
    check_units: bool = Field(True, description="cross-check speeds and yaw rate against the positions (robust statistics)")
    reference_smoothing: float | None = Field(None, ge=0, description="Whittaker smoothing length of the path-derived reference line [m]; default from the laps (gprace.tracks.laps)")
    reference_width: float | None = Field(None, gt=0, description="half width given to the path-derived reference line [m]; default from the spread of the laps")
    track: str | tuple[str, str] | None = Field(None, description="track (path, shipped name, or two boundary files) used when no --track is given; relative paths from the map's folder; none: the path-derived reference line")
    track_smoothing: float | None = Field(None, ge=0, description="Whittaker smoothing length of a CSV track [m]; default its point spacing, at most 5 m")
    off_track: Literal["cut", "keep"] = Field("cut", description="stretches of at least 1 s beyond a border of the track (by a quarter of its width): left out (cut) or kept")
    max_off_track: float = Field(0.5, gt=0, le=1, description="largest share of moving samples off the track before the track is refused as another circuit")


    @field_validator("hold")
    @classmethod
    def _known(cls, v: tuple[str, ...] | None) -> tuple[str, ...] | None:
        bad = [q for q in (v or ()) if q not in QUANTITIES]
        if bad:
            raise ValueError(f"unknown quantit{'ies' if len(bad) > 1 else 'y'} {', '.join(bad)} (known: {', '.join(QUANTITIES)})")
        return v

    def held(self) -> frozenset[str]:
        """Quantities resampled by zero-order hold: ``hold`` if given, else the commanded inputs
        (``delta``/``steering_wheel``, ``a_x``) and ``v_cmd``."""
        if self.hold is not None:
            return frozenset(self.hold)
        out = {"v_cmd"}
        if self.inputs.delta == "commanded":
            out |= {"delta", "steering_wheel"}
        if self.inputs.a_x == "commanded":
            out.add("a_x")
        return frozenset(out)

    def explicit_columns(self) -> dict[str, str]:
        """Quantities whose column the map names itself (not a default): quantity -> column."""
        return {q: getattr(self.columns, q) for q in self.columns.model_fields_set}


def load_map(path: str | Path | None) -> RecordingMap:
    """The map in ``path`` (TOML), or the defaults when ``path`` is None. A relative ``track``
    path is taken from the map's folder when it exists there (else as given: a shipped name or a
    path from the working folder)."""
    if path is None:
        return RecordingMap()
    p = Path(path)
    data = read_toml(p)
    rmap = validate(RecordingMap, data, str(p))
    if rmap.track is not None:
        base = p.resolve().parent

        def rel(t: str) -> str:
            q = Path(t)
            if not q.is_absolute() and (base / q).exists():
                return str(base / q)
            if not q.is_absolute() and "," in t and not q.exists():  # "inner.csv,outer.csv" in one string
                return ",".join(rel(x.strip()) for x in t.split(","))
            return t

        track = rel(rmap.track) if isinstance(rmap.track, str) else tuple(rel(t) for t in rmap.track)
        rmap = rmap.model_copy(update={"track": track})
    return rmap


def default_map_toml() -> str:
    """The default map as TOML (``gprace import --print-map``), every key written out."""
    head = (
        "# gprace recording map: where each quantity sits in a recording, its unit and sign.\n"
        "# Every key is optional; these are the defaults. Units: time s|ms|us|ns, length m|km|ft,\n"
        "# angle rad|deg, rate rad/s|deg/s, speed m/s|km/h|mph, accel m/s^2|g. Signs: 1 or -1.\n"
    )
    d = RecordingMap().model_dump(mode="json", exclude_none=True)
    d.pop("clocks", None)
    d["long"].pop("time", None)
    text = dumps_toml(d)
    cut = text.index("\n[") + 1  # top-level keys first: the commented ones belong with them
    return head + text[:cut] + (
        '# max_gap = 0.5          # seconds; default 5 periods of each source\n'
        '# origin = [48.3, 11.6]  # lat, lon [deg] of the tangent plane (the track frame); default the first fix\n'
        '# track = "Monza.csv"    # or ["inner.csv", "outer.csv"]; relative to this map; used without --track\n'
        '# track_smoothing = 0.5  # metres; default the track file\'s point spacing, at most 5 m\n'
        '# hold = ["delta", "a_x", "v_cmd"]  # default: the commanded inputs and v_cmd\n'
        '# reference_smoothing = 2.0  # metres; no track: default from the laps\n'
        '# reference_width = 3.0      # metres; no track: default from the spread of the laps\n\n'
    ) + text[cut:] + (
        '\n# [clocks."imu.csv"]     # a drive split into files: one table per file with its own clock\n'
        '# column = "stamp"\n# unit = "ns"\n# offset = 0.0\n'
    )


def si_factor(quantity: str, unit: str) -> float:
    return UNITS[DIMENSION[quantity]][unit]
