"""Readers: a recording file -> named time series in SI units (:class:`Raw`).

One reader per family, chosen by :func:`recording_format` from the extension:

* ``.csv`` (global-frame log): one row per time stamp, column names from the map's
  ``[columns]``; an empty cell means the quantity was not sampled at that row (logs that merge
  sources of different rates), so each quantity keeps its own time stamps.
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


def read_raw(path: Path, rmap: RecordingMap) -> Raw:
    fmt = recording_format(path)
    if fmt == "csv":
        return read_csv(path, rmap)
    if fmt == "ros":
        return read_ros(path, rmap)
    if fmt == "mdf":
        return read_mdf(path, rmap)
    raise InputError(f"{path}: unknown recording format {path.suffix!r} (expected .csv, .mcap, .db3, .bag, a rosbag2 folder, .mf4 or .mdf)")


def check_time(t: np.ndarray, source: str, what: str, rows: np.ndarray | None = None) -> None:
    """Time stamps must not go backwards (equal stamps are allowed: the last sample counts).

    ``rows``: the file row (:func:`gprace.errors.at_row`) of each stamp, for a table whose
    quantity was not sampled on every row; without it the stamp is counted within ``what``.
    """
    bad = np.flatnonzero(np.diff(t) < 0)
    if len(bad):
        i = int(bad[0])
        where = f"sample {i + 2}" if rows is None else at_row(int(rows[i + 1]))
        raise InputError(
            f"{source}: time stamps go backwards in {what} at {where} "
            f"({t[i + 1]:.6g} s after {t[i]:.6g} s); sort the log or fix the clock"
        )


# ----------------------------------------------------------------------------------------------
# CSV


def read_csv(path: Path, rmap: RecordingMap) -> Raw:
    try:
        with path.open() as fh:
            header_line = fh.readline()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV file") from None
    header = [h.strip() for h in header_line.lstrip("#").strip().split(",")]
    if not header or header == [""]:
        raise InputError(f"{path}: empty file")
    arr = _csv_numbers(path, header)
    if len(arr) == 0:
        raise InputError(f"{path}: no data rows after the header")
    cols = rmap.columns
    raw = Raw(str(path), present=header, kind="csv", hints={q: f"column {getattr(cols, q)!r}" for q in QUANTITIES})
    if cols.t not in header:
        raise raw.missing("time stamps", ("t",))
    t_all = arr[:, header.index(cols.t)] * si_factor("t", rmap.units.t)
    raw.units["t"] = rmap.units.t
    keep_t = np.isfinite(t_all)
    for q in QUANTITIES[1:]:
        name = getattr(cols, q)
        if name not in header:
            continue
        v = arr[:, header.index(name)]
        ok = keep_t & np.isfinite(v)
        if not ok.any():
            continue
        t = t_all[ok]
        check_time(t, str(path), f"column {cols.t!r}", rows=np.flatnonzero(ok) + 1)
        raw.add(q, t, v[ok], f"column {name!r}", rmap)
    return raw


def _csv_numbers(path: Path, header: list[str]) -> np.ndarray:
    """The body of a CSV as floats (empty cells NaN), fast; errors name the row and column."""
    try:
        import pandas as pd
    except ImportError:  # pragma: no cover - pandas comes with asammdf
        pd = None
    if pd is not None:
        try:
            df = pd.read_csv(path, header=None, skiprows=1, names=header, dtype=float, engine="c",
                             skip_blank_lines=True)
            return df.to_numpy(dtype=float)
        except (ValueError, pd.errors.ParserError):
            pass  # fall through to the slow path, which names the bad cell
    lines = [(n, ln) for n, ln in enumerate(path.read_text().splitlines(), start=1) if ln.strip()][1:]
    rows = [ln.split(",") for _, ln in lines]
    out = np.full((len(rows), len(header)), np.nan)
    for i, r in enumerate(rows):
        where = at_row(i + 1, lines[i][0])
        if len(r) != len(header):
            raise InputError(f"{path}: {where} has {len(r)} fields, header has {len(header)} (truncated file?)")
        for j, c in enumerate(r):
            c = c.strip()
            if not c:
                continue
            try:
                out[i, j] = float(c)
            except ValueError:
                raise InputError(f"{path}: column {header[j]!r} {where}: {c!r} is not a number") from None
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
    from gprace.ingest import mcap_fast

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
    from rosbags.highlevel import AnyReader

    try:
        reader = AnyReader([path], default_typestore=ros_typestore(path.suffix.lower() == ".bag"))
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds on bad files
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
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise InputError(f"{path}: reading MDF4 needs asammdf ({exc})") from None
    try:
        mdf = MDF(str(path))
    except Exception as exc:  # noqa: BLE001 - asammdf raises several kinds on bad files
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
