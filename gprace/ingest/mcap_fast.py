"""Fast path for MCAP files with CDR messages of the four supported types.

rosbags deserialises one message at a time in Python (about 100 us each: 45 s for a 30-minute
log of three topics at 100 Hz). Here the MCAP records are walked once (a few struct unpacks per
message; chunks may be uncompressed, zstd or lz4) and the messages of one topic, which all have
the same byte length when their frame ids do (the normal case), are stacked into one
``(n, length)`` byte array; every field is then read for all messages at once at its CDR offset.
Anything else (another encoding, frame ids that change length, an unknown compression) raises
:class:`Unsupported` and the caller uses rosbags.

CDR (XCDR1, what ROS 2 writes): after a 4-byte encapsulation header (``00 01`` little endian,
``00 00`` big endian), each primitive is aligned to its size (at most 8) relative to the payload
start; a string is a uint32 length (with the terminating NUL) and its bytes.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

MAGIC = b"\x89MCAP0\r\n"

# layouts: (field name or None, kind); kinds: i4 u4 f4 f8 str, or ("f8", n) for a fixed array
_HEADER = [("sec", "i4"), ("nanosec", "u4"), (None, "str")]
_POSE = [("x", "f8"), ("y", "f8"), (None, "f8"), ("qx", "f8"), ("qy", "f8"), ("qz", "f8"), ("qw", "f8")]
LAYOUTS = {
    "nav_msgs/msg/Odometry": _HEADER + [(None, "str")] + _POSE + [(None, ("f8", 36)),
                                                                 ("v_x", "f8"), ("v_y", "f8"), (None, "f8"),
                                                                 (None, "f8"), (None, "f8"), ("yaw_rate", "f8"),
                                                                 (None, ("f8", 36))],
    "geometry_msgs/msg/PoseStamped": _HEADER + _POSE,
    "sensor_msgs/msg/Imu": _HEADER + [(None, ("f8", 4)), (None, ("f8", 9)), (None, "f8"), (None, "f8"),
                                      ("yaw_rate", "f8"), (None, ("f8", 9)), ("a_x", "f8"), (None, "f8"),
                                      (None, "f8"), (None, ("f8", 9))],
    "ackermann_msgs/msg/AckermannDriveStamped": _HEADER + [("delta", "f4"), (None, "f4"), (None, "f4"),
                                                           ("a_x", "f4"), (None, "f4")],
}
_SIZE = {"i4": 4, "u4": 4, "f4": 4, "f8": 8}


class Unsupported(Exception):
    """This file or topic needs the general (rosbags) reader."""


def _decompress(kind: str, data: bytes, size: int) -> bytes:
    if kind == "":
        return data
    if kind == "zstd":
        try:
            import zstandard

            return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        except ImportError:
            try:
                from backports import zstd as _z  # shipped with rosbags
            except ImportError:
                try:
                    from compression import zstd as _z  # Python >= 3.14
                except ImportError:
                    raise Unsupported("no zstd decompressor") from None
            return _z.decompress(data)
    if kind == "lz4":
        try:
            import lz4.frame
        except ImportError:
            raise Unsupported("no lz4 decompressor") from None
        return lz4.frame.decompress(data)
    raise Unsupported(f"chunk compression {kind!r}")


def _str(buf, off: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, off)
    return bytes(buf[off + 4 : off + 4 + n]).decode(), off + 4 + n


def scan(path: Path) -> tuple[dict[int, tuple[str, str, str]], dict[int, tuple[list, list]]]:
    """Channels ``{id: (topic, schema name, message encoding)}`` and messages per channel
    ``{id: ([log_time ns], [payload bytes])}`` in file order."""
    buf = memoryview(path.read_bytes())
    if bytes(buf[:8]) != MAGIC:
        raise Unsupported("not an MCAP file")
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[int, str, str]] = {}
    msgs: dict[int, tuple[list, list]] = {}
    unpack_rec = struct.Struct("<BQ").unpack_from
    unpack_msg = struct.Struct("<HIQQ").unpack_from

    def walk(b, start: int, end: int, top: bool) -> None:
        off = start
        while off + 9 <= end:
            op, ln = unpack_rec(b, off)
            body = off + 9
            off = body + ln
            if op == 0x05:  # Message
                cid, _seq, logt, _pub = unpack_msg(b, body)
                lst = msgs.get(cid)
                if lst is None:
                    lst = msgs[cid] = ([], [])
                lst[0].append(logt)
                lst[1].append(b[body + 22 : off])
            elif op == 0x06 and top:  # Chunk
                _t0, _t1, usize, _crc = struct.unpack_from("<QQQI", b, body)
                comp, p = _str(b, body + 28)
                (rlen,) = struct.unpack_from("<Q", b, p)
                data = _decompress(comp, bytes(b[p + 8 : p + 8 + rlen]), usize)
                inner = memoryview(data)
                walk(inner, 0, len(inner), False)
            elif op == 0x03:  # Schema
                (sid,) = struct.unpack_from("<H", b, body)
                name, _ = _str(b, body + 2)
                schemas[sid] = name
            elif op == 0x04:  # Channel
                cid, sid = struct.unpack_from("<HH", b, body)
                topic, p = _str(b, body + 4)
                enc, _ = _str(b, p)
                channels[cid] = (sid, topic, enc)
            elif op == 0x0F and top:  # DataEnd: the summary repeats what we have
                break

    walk(buf, 8, len(buf) - 8, True)
    return {cid: (topic, schemas.get(sid, ""), enc) for cid, (sid, topic, enc) in channels.items()}, msgs


def decode(msgtype: str, payloads: list, logt: list, use_header: bool) -> dict[str, np.ndarray]:
    """Fields of ``msgtype`` for every payload, by offsets (module docstring)."""
    layout = LAYOUTS[msgtype]
    n = len(payloads)
    if n == 0:
        return {"t": np.zeros(0)}
    lens = np.fromiter((len(p) for p in payloads), int, n)
    if np.any(lens != lens[0]):
        raise Unsupported("messages of different lengths")
    arr = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(n, lens[0])
    if arr[0, 1] not in (0, 1) or np.any(arr[:, 1] != arr[0, 1]):
        raise Unsupported("not plain CDR")
    end = "<" if arr[0, 1] == 1 else ">"
    first = bytes(arr[0])
    out: dict[str, np.ndarray] = {}
    off = 0  # relative to the payload after the 4-byte encapsulation header
    for name, kind in layout:
        if kind == "str":
            off += (-off) % 4
            (ln,) = struct.unpack_from(end + "I", first, 4 + off)
            col = arr[:, 4 + off : 8 + off].copy().view(end + "u4")[:, 0]
            if np.any(col != ln):
                raise Unsupported("strings of different lengths")
            off += 4 + ln
            continue
        if isinstance(kind, tuple):
            size, count = _SIZE[kind[0]], kind[1]
        else:
            size, count = _SIZE[kind], 1
        off += (-off) % min(size, 8)
        if name is not None:
            dt = np.dtype(end + {"i4": "i4", "u4": "u4", "f4": "f4", "f8": "f8"}[kind])
            out[name] = arr[:, 4 + off : 4 + off + size].copy().view(dt)[:, 0].astype(float)
        off += size * count
    if 4 + off != lens[0]:
        raise Unsupported(f"{msgtype}: layout does not match the message length")
    stamp = out.pop("sec") + 1e-9 * out.pop("nanosec")
    lt = 1e-9 * np.asarray(logt, dtype=float)
    out["t"] = stamp if use_header and np.all(stamp > 0) else lt
    if "qw" in out:
        qx, qy, qz, qw = (out.pop(k) for k in ("qx", "qy", "qz", "qw"))
        out["yaw"] = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy**2 + qz**2))
    return out


def mcap_file(path: Path) -> Path | None:
    """The MCAP file of ``path`` (itself, or the single one in a rosbag2 folder), or None."""
    if path.is_dir():
        files = sorted(path.glob("*.mcap"))
        return files[0] if len(files) == 1 else None
    return path if path.suffix.lower() == ".mcap" else None
