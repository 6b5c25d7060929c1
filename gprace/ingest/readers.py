"""Readers: a recording file -> named time series in SI units (:class:`Raw`).

One reader per family, chosen by :func:`recording_format` from the extension:

* ``.csv`` (global-frame log), read as it comes (:mod:`gprace.io.table`: comment preambles,
  a header in the last comment line or none, BOM, CRLF, ``;``). *Wide*: one row per time stamp,
  column names from the map's ``[columns]``; an empty cell means the quantity was not sampled at
  that row (logs that merge sources of different rates), so each quantity keeps its own time
  stamps. *Long*: one row per channel sample (name, value, time; declared with ``layout =
  "long"`` or recognised from its header), the ``[columns]`` names being channel names.
* Several files of one drive (pose, IMU, commands), each with its own clock (``[clocks."f.csv"]``:
  time column, unit, offset), are merged quantity by quantity (:func:`merge_raw`); the import then
  resamples every quantity on one grid as for a single file.
* ROS: ``.mcap``, ``.db3`` and a rosbag2 folder (``metadata.yaml``), or a ROS 1 ``.bag``, through
  ``rosbags`` (pure Python). Message types ``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped``,
  ``sensor_msgs/msg/Imu`` and ``ackermann_msgs/msg/AckermannDriveStamped`` (not in rosbags'
  default typestore: registered from its ``.msg`` definition below).
* ``.mf4`` / ``.mdf`` (MDF4, ASAM) through ``asammdf``: every channel has its own time base;
  a channel's own unit is used when the map does not set one.

Time stamps come out in seconds (the recording's own epoch); nothing is resampled here.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import gprace.ingest.mcap_fast as mcap_fast
from gprace.errors import InputError, at_row
from gprace.ingest.mapping import QUANTITIES, UNITS, DIMENSION, RecordingMap, si_factor

ODOMETRY = "nav_msgs/msg/Odometry"
POSE = "geometry_msgs/msg/PoseStamped"
IMU = "sensor_msgs/msg/Imu"
ACKERMANN = "ackermann_msgs/msg/AckermannDriveStamped"

ACKERMANN_MSGS = {
    "ackermann_msgs/msg/AckermannDrive": (
        "float32 steering_angle\nfloat32 steering_angle_velocity\nfloat32 speed\n"
        "float32 acceleration\nfloat32 jerk\n"
    ),
    "ackermann_msgs/msg/AckermannDriveStamped": "std_msgs/Header header\nackermann_msgs/AckermannDrive drive\n",
}
"""The ``.msg`` definitions of ackermann_msgs (ROS package ``ackermann_msgs``)."""


@dataclass
class Signal:
    """One quantity: time stamps [s] (non-decreasing) and values (SI, gprace's signs)."""

    t: np.ndarray
    v: np.ndarray
    origin: str  # e.g. "column 'v_x'", "topic '/odom' twist.linear.x"


@dataclass
class Raw:
    """Everything a reader found: signals by quantity, and what the file holds (for errors)."""

    source: str
    signals: dict[str, Signal] = field(default_factory=dict)
    present: list[str] = field(default_factory=list)  # columns / topics (type) / channels
    kind: str = "csv"  # csv | ros | mdf
    hints: dict[str, str] = field(default_factory=dict)  # quantity -> where the map looks for it
    units: dict[str, str] = field(default_factory=dict)  # quantity -> unit it was read in
    notes: list[str] = field(default_factory=list)
    origin_file: dict[str, str] = field(default_factory=dict)
    layout: str = "wide"

    def add(self, q: str, t: np.ndarray, v: np.ndarray, origin: str, rmap: RecordingMap, unit: str | None = None) -> None:
        """Store quantity ``q`` converted to SI with the map's sign (``unit`` overrides the map's)."""
        u = unit if unit is not None else getattr(rmap.units, q)
        out = np.asarray(v, dtype=float) * si_factor(q, u)
        sign = getattr(rmap.signs, q, 1)
        self.signals[q] = Signal(np.asarray(t, dtype=float), out * sign if sign != 1 else out, origin)
        self.units[q] = u

    def has(self, q: str) -> bool:
        return q in self.signals

    def missing(self, what: str, quantities: tuple[str, ...]) -> InputError:
        where = ", ".join(dict.fromkeys(self.hints.get(q, q) for q in quantities))
        listing = ", ".join(self.present) if self.present else "nothing"
        noun = {"csv": "columns", "ros": "topics", "mdf": "channels"}[self.kind]
        return InputError(f"{self.source}: no {what} ({where} not found); {noun} present: {listing}")


#: What the binary readers' decoders raise on a damaged file besides their own error class
#: (measured on truncated and random-byte bags, MCAPs and MDF4 files).
BAD_FILE = (ValueError, KeyError, IndexError, EOFError, OSError, struct.error)

def recording_format(path: Path) -> str | None:
    """``csv``, ``ros``, ``mdf`` from the path, or None when it is not a raw-recording path."""
    suf = path.suffix.lower()
    if path.is_dir():
        return "ros" if (path / "metadata.yaml").exists() or any(path.glob("*.mcap")) or any(path.glob("*.db3")) else None
    if suf in (".mcap", ".db3", ".bag"):
        return "ros"
    if suf in (".mf4", ".mdf"):
        return "mdf"
    if suf == ".csv":
        return "csv"
    return None


def read_raw(path: Path | list[Path], rmap: RecordingMap) -> Raw:
    """Every signal of a recording (one file, or the files of one drive merged: :func:`merge_raw`)."""
    if isinstance(path, (list, tuple)):
        return merge_raw([_read_one(Path(p), rmap) for p in path], rmap)
    return merge_raw([_read_one(Path(path), rmap)], rmap)


def _read_one(path: Path, rmap: RecordingMap) -> Raw:
    fmt = recording_format(path)
    if fmt == "csv":
        return read_csv(path, rmap)
    if fmt == "ros":
        return read_ros(path, rmap)
    if fmt == "mdf":
        return read_mdf(path, rmap)
    raise InputError(f"{path}: unknown recording format {path.suffix!r} (expected .csv, .mcap, .db3, .bag, a rosbag2 folder, .mf4 or .mdf)")


def check_time(t: np.ndarray, source: str, what: str, rows: np.ndarray | None = None,
               lines: np.ndarray | None = None) -> None:
    """Time stamps must not go backwards (equal stamps are allowed: the last sample counts).

    ``rows``: the file row (:func:`gprace.errors.at_row`) of each stamp, for a table whose
    quantity was not sampled on every row (``lines``: its file line); without it the stamp is
    counted within ``what``.
    """
    bad = np.flatnonzero(np.diff(t) < 0)
    if len(bad):
        i = int(bad[0])
        where = f"sample {i + 2}" if rows is None else at_row(int(rows[i + 1]), None if lines is None else int(lines[i + 1]))
        raise InputError(
            f"{source}: time stamps go backwards in {what} at {where} "
            f"({t[i + 1]:.6g} s after {t[i]:.6g} s); sort the log or fix the clock"
        )


# ----------------------------------------------------------------------------------------------
# CSV

LONG_NAMES = ("name", "channel", "signal", "field", "key", "topic", "variable")
LONG_VALUES = ("value", "val", "data", "reading")
LONG_TIMES = ("timestamp", "time", "t", "stamp", "time_s", "ts")


def _clock(path: Path, rmap: RecordingMap) -> tuple[str, str, float]:
    """Time column, unit and offset [s] of ``path`` (its ``[clocks."name"]`` table, else the map's)."""
    c = rmap.clocks.get(path.name)
    col = c.column if c is not None and c.column else rmap.columns.t
    unit = c.unit if c is not None and c.unit else rmap.units.t
    return col, unit, (c.offset if c is not None else 0.0)


def _long_layout(tbl, rmap: RecordingMap, time_col: str) -> tuple[str, str, str] | None:
    """``(name, value, time)`` columns when ``tbl`` is long-format telemetry (declared, or a header
    with a channel-name, a value and a time column and no column the map's x/y/lat/lon name)."""
    low = {n.lower(): n for n in tbl.names}
    lf = rmap.long
    if rmap.layout == "wide":
        return None

    def pick(own: str | None, aliases: tuple[str, ...]) -> str | None:
        if own is not None and own in tbl.names:
            return own
        return next((low[a] for a in aliases if a in low), None)

    name = pick(lf.name if "name" in lf.model_fields_set or rmap.layout == "long" else None, LONG_NAMES)
    value = pick(lf.value if "value" in lf.model_fields_set or rmap.layout == "long" else None, LONG_VALUES)
    time = pick(lf.time or time_col, LONG_TIMES)
    found = name is not None and value is not None and time is not None
    if rmap.layout == "long":
        if not found:
            raise InputError(
                f"{tbl.path}: layout = \"long\" but no {'name' if name is None else 'value' if value is None else 'time'} "
                f"column ([long] name = {lf.name!r}, value = {lf.value!r}, time = {lf.time or time_col!r}); columns: {', '.join(tbl.names)}")
        return name, value, time
    cols = rmap.columns
    wide = any(getattr(cols, q) in tbl.names for q in ("x", "y", "lat", "lon"))
    return (name, value, time) if found and not wide and len(tbl.names) <= 6 else None


def read_csv(path: Path, rmap: RecordingMap) -> Raw:
    """A CSV recording as it comes (:mod:`gprace.io.table`): wide (a column per quantity) or
    long (one row per channel sample); each quantity keeps its own time stamps."""
    from gprace.io.table import numbers, sniff, strings

    tbl = sniff(path, "recording")
    cols = rmap.columns
    t_col, t_unit, t_off = _clock(path, rmap)
    long = _long_layout(tbl, rmap, t_col)
    if long is not None:
        n_col, v_col, t_col = long
        chan = strings(tbl, n_col)
        arr = numbers(tbl, [t_col, v_col])
        names = sorted(set(chan))
        raw = Raw(str(path), present=names, kind="csv", hints={q: f"channel {getattr(cols, q)!r}" for q in QUANTITIES})
        raw.layout = "long"
        t_all = arr[:, 0] * si_factor("t", t_unit) + t_off
        raw.units["t"] = t_unit
        for q in QUANTITIES[1:]:
            name = getattr(cols, q)
            sel = (chan == name) & np.isfinite(t_all) & np.isfinite(arr[:, 1])
            if not sel.any():
                continue
            rows = np.flatnonzero(sel)
            t = t_all[rows]
            order = np.argsort(t, kind="stable")
            if np.any(np.diff(order) < 0):  # a long file sorted by channel, not time: fine, sort it
                rows, t = rows[order], t[order]
            check_time(t, str(path), f"channel {name!r}", rows=rows + 1, lines=tbl.body_lines[rows])
            raw.add(q, t, arr[rows, 1], f"channel {name!r}", rmap)
        return raw
    header = tbl.names
    raw = Raw(str(path), present=header, kind="csv", hints={q: f"column {getattr(cols, q)!r}" for q in QUANTITIES})
    if t_col not in header and "t" not in rmap.columns.model_fields_set and path.name not in rmap.clocks:
        low = {n.lower(): n for n in header}
        found = next((low[a] for a in LONG_TIMES + ("time(s)", "time [s]", "time_sec", "seconds") if a in low), None)
        if found is not None:
            raw.notes.append(f"time from column {found!r} (the map names no [columns] t)")
            t_col = found
    if t_col not in header:
        where = f'[clocks."{path.name}"] column' if path.name in rmap.clocks and rmap.clocks[path.name].column else "[columns] t"
        raise InputError(f"{path}: no time column {t_col!r} ({where}); columns present: {', '.join(header)}"
                         + ("" if tbl.has_header else " (no header found: columns are numbered)"))
    wanted = [q for q in QUANTITIES[1:] if getattr(cols, q) in header]
    arr = numbers(tbl, [t_col] + [getattr(cols, q) for q in wanted])
    t_all = arr[:, 0] * si_factor("t", t_unit) + t_off
    raw.units["t"] = t_unit
    keep_t = np.isfinite(t_all)
    for k, q in enumerate(wanted, start=1):
        name = getattr(cols, q)
        v = arr[:, k]
        ok = keep_t & np.isfinite(v)
        if not ok.any():
            continue
        rows = np.flatnonzero(ok)
        check_time(t_all[ok], str(path), f"column {t_col!r}", rows=rows + 1, lines=tbl.body_lines[rows])
        raw.add(q, t_all[ok], v[ok], f"column {name!r}", rmap)
    return raw


def merge_raw(raws: list[Raw], rmap: RecordingMap) -> Raw:
    """One :class:`Raw` from several files of one drive (each quantity from the first file that
    has it; the others are noted). Columns the map names itself must be in some file."""
    if len(raws) == 1:
        out = raws[0]
    else:
        out = Raw(" + ".join(r.source for r in raws), kind=raws[0].kind, hints=raws[0].hints)
        out.present = [f"{Path(r.source).name}: {p}" for r in raws for p in r.present]
        for r in raws:
            for q, sig in r.signals.items():
                if q in out.signals:
                    out.notes.append(f"{q} is in {out.origin_file[q]} and {Path(r.source).name}: the first is used")
                    continue
                out.signals[q] = Signal(sig.t, sig.v, f"{Path(r.source).name} {sig.origin}")
                out.units[q] = r.units.get(q, "")
                out.origin_file[q] = Path(r.source).name
            out.units.setdefault("t", r.units.get("t", "s"))
    if out.kind in ("csv", "mdf"):
        explicit = rmap.explicit_columns()
        lacking = [q for q in explicit if q not in out.signals and not (q == "t" and out.signals)]
        if lacking:
            noun = "channel" if out.kind == "mdf" or getattr(raws[0], "layout", "") == "long" else "column"
            q = lacking[0]
            listing = ", ".join(out.present) if out.present else "nothing"
            raise InputError(f"{out.source}: the map names {noun} {explicit[q]!r} for {q} ([columns] {q}), "
                             f"which the file lacks (or holds no number in); {noun}s present: {listing}")
    return out


# ----------------------------------------------------------------------------------------------
# ROS bags / MCAP


def ros_typestore(ros1: bool = False):
    """rosbags' typestore of a recent ROS distribution plus ackermann_msgs."""
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    for name, text in ACKERMANN_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def read_ros(path: Path, rmap: RecordingMap) -> Raw:
    tp = rmap.topics
    raw = Raw(str(path), kind="ros")
    raw.hints = {
        "x": f"topic {tp.odometry!r} or {tp.pose!r}", "y": f"topic {tp.odometry!r} or {tp.pose!r}",
        "yaw": f"topic {tp.odometry!r} or {tp.pose!r}",
        "delta": f"topic {tp.ackermann!r}", "yaw_rate": f"topic {tp.imu!r} or {tp.odometry!r}",
    }
    wanted = {tp.odometry: ODOMETRY, tp.pose: POSE, tp.imu: IMU, tp.ackermann: ACKERMANN}
    got = None
    mc = mcap_fast.mcap_file(path)
    if mc is not None:
        try:
            topics, got = _ros_fast(mc, wanted, tp.stamp == "header", mcap_fast)
        except mcap_fast.Unsupported:
            got = None
        except InputError:
            raise
        except (struct.error, ValueError, IndexError, OSError):
            got = None  # a damaged file: the general reader gives the error
    if got is None:
        topics, got = _ros_general(path, wanted, tp.stamp == "header")
    raw.present = [f"{k} ({v})" for k, v in sorted(topics.items())]

    def add(q: str, typ: str, key: str, what: str) -> None:
        d = got.get(typ)
        if d is None or key not in d:
            return
        topic = next(k for k, v in wanted.items() if v == typ)
        check_time(d["t"], str(path), f"topic {topic!r}")
        raw.add(q, d["t"], d[key], f"topic {topic!r} {what}", rmap)

    pose_typ = ODOMETRY if ODOMETRY in got else POSE
    add("x", pose_typ, "x", "position.x")
    add("y", pose_typ, "y", "position.y")
    add("yaw", pose_typ, "yaw", "orientation")
    add("v_x", ODOMETRY, "v_x", "twist.linear.x")
    add("v_y", ODOMETRY, "v_y", "twist.linear.y")
    rate_order = (IMU, ODOMETRY) if tp.yaw_rate_from == "imu" else (ODOMETRY, IMU)
    for typ in rate_order:
        if "yaw_rate" not in raw.signals:
            add("yaw_rate", typ, "yaw_rate", "angular_velocity.z" if typ == IMU else "twist.angular.z")
    add("delta", ACKERMANN, "delta", "drive.steering_angle")
    order = {"ackermann": (ACKERMANN, IMU), "imu": (IMU, ACKERMANN), "speed": ()}[tp.a_x_from]
    for typ in order:
        if "a_x" not in raw.signals:
            add("a_x", typ, "a_x", "drive.acceleration" if typ == ACKERMANN else "linear_acceleration.x")
    return raw


def _check_types(path: Path, topics: dict[str, str], wanted: dict[str, str]) -> None:
    for topic, typ in wanted.items():
        if topic in topics and topics[topic] != typ:
            raise InputError(f"{path}: topic {topic!r} has message type {topics[topic]}, expected {typ}")


def _ros_fast(path: Path, wanted: dict[str, str], use_header: bool, mcap_fast):
    """Topics and fields through :mod:`gprace.ingest.mcap_fast` (raises Unsupported)."""
    channels, msgs = mcap_fast.scan(path)
    topics = {topic: typ for topic, typ, _enc in channels.values()}
    _check_types(path, topics, wanted)
    got: dict[str, dict[str, np.ndarray]] = {}
    for topic, typ in wanted.items():
        cids = [c for c, (tpc, _t, enc) in channels.items() if tpc == topic]
        if not cids:
            continue
        if any(channels[c][2] != "cdr" for c in cids):
            raise mcap_fast.Unsupported("not CDR")
        logt = [x for c in cids for x in msgs.get(c, ([], []))[0]]
        data = [x for c in cids for x in msgs.get(c, ([], []))[1]]
        order = np.argsort(np.asarray(logt, dtype=np.int64), kind="stable")
        if np.any(np.diff(order) != 1):
            logt = [logt[i] for i in order]
            data = [data[i] for i in order]
        got[typ] = mcap_fast.decode(typ, data, logt, use_header)
    return topics, got


def _ros_general(path: Path, wanted: dict[str, str], use_header: bool):
    """Topics and fields through rosbags' AnyReader (every bag format, one message at a time)."""
    from rosbags.highlevel import AnyReader, AnyReaderError

    try:
        reader = AnyReader([path], default_typestore=ros_typestore(path.suffix.lower() == ".bag"))
        reader.open()
    except (AnyReaderError, *BAD_FILE) as exc:  # rosbags' own error, or a decoder's on a damaged file
        raise InputError(f"{path}: not a readable ROS bag / MCAP file ({type(exc).__name__}: {exc})") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        _check_types(path, topics, wanted)
        got: dict[str, dict[str, np.ndarray]] = {}
        for topic, typ in wanted.items():
            if topic not in topics:
                continue
            conns = [c for c in reader.connections if c.topic == topic]
            got[typ] = _ros_fields(reader, conns, typ, use_header)
    finally:
        reader.close()
    return topics, got


def _ros_fields(reader, conns, typ: str, use_header: bool) -> dict[str, np.ndarray]:
    """Deserialise every message of ``conns`` and pull the fields gprace uses into arrays."""
    deser = reader.deserialize
    rows = []
    logt = []
    for conn, stamp, data in reader.messages(connections=conns):
        rows.append(deser(data, conn.msgtype))
        logt.append(stamp)
    n = len(rows)
    out: dict[str, np.ndarray] = {}
    if n == 0:
        return {"t": np.zeros(0)}
    hs = np.fromiter((m.header.stamp.sec for m in rows), float, n) + 1e-9 * np.fromiter(
        (m.header.stamp.nanosec for m in rows), float, n)
    lt = 1e-9 * np.asarray(logt, dtype=float)
    out["t"] = hs if use_header and np.all(hs > 0) else lt
    if typ in (ODOMETRY, POSE):
        poses = [m.pose.pose if typ == ODOMETRY else m.pose for m in rows]
        out["x"] = np.fromiter((p.position.x for p in poses), float, n)
        out["y"] = np.fromiter((p.position.y for p in poses), float, n)
        q = np.array([(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w) for p in poses])
        out["yaw"] = np.arctan2(2.0 * (q[:, 3] * q[:, 2] + q[:, 0] * q[:, 1]), 1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2))
    if typ == ODOMETRY:
        tw = np.array([(m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.angular.z) for m in rows])
        out["v_x"], out["v_y"], out["yaw_rate"] = tw[:, 0], tw[:, 1], tw[:, 2]
    elif typ == IMU:
        a = np.array([(m.angular_velocity.z, m.linear_acceleration.x) for m in rows])
        out["yaw_rate"], out["a_x"] = a[:, 0], a[:, 1]
    elif typ == ACKERMANN:
        a = np.array([(m.drive.steering_angle, m.drive.acceleration) for m in rows], dtype=float)
        out["delta"], out["a_x"] = a[:, 0], a[:, 1]
    return out


# ----------------------------------------------------------------------------------------------
# MDF4


def read_mdf(path: Path, rmap: RecordingMap) -> Raw:
    try:
        from asammdf import MDF
        from asammdf.blocks.utils import MdfException
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise InputError(f"{path}: reading MDF4 needs asammdf ({exc})") from None
    try:
        mdf = MDF(str(path))
    except (MdfException, *BAD_FILE) as exc:  # asammdf's own error, or a decoder's on a damaged file
        raise InputError(f"{path}: not a readable MDF4 file ({type(exc).__name__}: {exc})") from None
    cols = rmap.columns
    raw = Raw(str(path), kind="mdf", hints={q: f"channel {getattr(cols, q)!r}" for q in QUANTITIES})
    try:
        names = [n for n in mdf.channels_db if not n.lower().startswith("time") and n != "t"]
        raw.present = sorted(set(names))
        explicit = rmap.units.model_fields_set
        for q in QUANTITIES[1:]:
            name = getattr(cols, q)
            if name not in mdf.channels_db:
                continue
            sig = mdf.get(name)
            unit = None
            own = (sig.unit or "").strip().replace("°", "deg").replace("m/s²", "m/s^2")
            if q not in explicit and own in UNITS[DIMENSION[q]]:
                unit = own  # the channel says what it is and the map does not override it
            t = np.asarray(sig.timestamps, dtype=float)
            v = np.asarray(sig.samples, dtype=float)
            check_time(t, str(path), f"channel {name!r}")
            raw.add(q, t, v, f"channel {name!r}", rmap, unit)
    finally:
        mdf.close()
    return raw
