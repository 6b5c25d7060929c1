"""Speed of ``gprace import``: a 30-minute log at 100 Hz (180,000 samples per channel).

The log is made up (kinematically consistent) on a TUM circuit: arc length from a smooth speed
profile, a lateral weave, slip; positions, heading, body velocities, yaw rate, steering and a_x
from those. It is written as a global-frame CSV, an MDF4 file (three time bases) and, with
``--mcap``, a rosbag2 MCAP (Odometry and Imu at 100 Hz, Ackermann at 50 Hz; writing it takes a
while). Each is imported end to end (read, resample at 0.05 s, unit checks, projection, HDF5
written), timed with ``time.perf_counter``. Prints a JSON table.

With ``--real`` it also imports the shared real logs (INI F1TENTH, IAC Putnam Park) as they
come, with the maps in tests/data/real_maps and the shipped track files (a headerless centre
line; two boundary files), and without a track (laps from the path): one row each with laps, s
range, max |e_y|, samples kept against the moving samples of the log, seconds; and the time to
load a 25 m and a 5 km track with the same call.

Usage: python benchmarks/import_bench.py [--minutes 30] [--rate 100] [--mcap] [--track PATH] [--real]
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

def _shared() -> Path:
    """``shared/data`` above the checkout (or a worktree of it)."""
    for parent in Path(__file__).resolve().parents:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return Path(__file__).resolve().parents[2] / "shared" / "data"


TRACK = _shared() / "tumftm-racetrack-database" / "tracks" / "Norisring.csv"


def _arg(name: str, default: str) -> str:
    return sys.argv[sys.argv.index(name) + 1] if name in sys.argv else default


def make_log(track, minutes: float, rate: float) -> dict[str, np.ndarray]:
    n = int(minutes * 60 * rate)
    t = np.arange(n) / rate
    L = track.length
    # speed 25..45 m/s varying along the lap, integrated on a fine grid
    v = 35.0 + 10.0 * np.sin(2 * np.pi * 3 * t / (L / 35.0))
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / rate)])
    e_y = 1.5 * np.sin(2 * np.pi * s / 180.0)
    x, y = track.to_global(s, e_y)
    vx_w, vy_w = np.gradient(x, t), np.gradient(y, t)
    course = np.unwrap(np.arctan2(vy_w, vx_w))
    beta = 0.02 * np.sin(2 * np.pi * s / 250.0)
    yaw = course - beta
    speed = np.hypot(vx_w, vy_w)
    return {
        "t": t, "x": x, "y": y, "yaw": np.angle(np.exp(1j * yaw)), "v_x": speed * np.cos(beta),
        "v_y": speed * np.sin(beta), "yaw_rate": np.gradient(yaw, t),
        "delta": 2.7 * track.kappa(s) + 0.01 * np.sin(t), "a_x": np.gradient(speed, t),
    }


def write_csv(log, path: Path) -> Path:
    np.savetxt(path, np.column_stack(list(log.values())), delimiter=",", header=",".join(log), comments="", fmt="%.10g")
    return path


def write_mdf(log, path: Path) -> Path:
    from asammdf import MDF, Signal

    t = log["t"]
    mdf = MDF(version="4.10")
    mdf.append([Signal(log[c], t, name=c) for c in ("x", "y", "yaw")])
    mdf.append([Signal(log[c][::2], t[::2], name=c) for c in ("v_x", "v_y", "yaw_rate")])  # 50 Hz
    mdf.append([Signal(log[c][::4], t[::4], name=c) for c in ("delta", "a_x")])  # 25 Hz
    mdf.save(str(path), overwrite=True)
    mdf.close()
    return path


def write_mcap(log, path: Path) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer

    from gprace.ingest.readers import ros_typestore

    store = ros_typestore()
    M = store.types
    V3, Q = M["geometry_msgs/msg/Vector3"], M["geometry_msgs/msg/Quaternion"]
    Time, Header = M["builtin_interfaces/msg/Time"], M["std_msgs/msg/Header"]
    z36, z9 = np.zeros(36), np.zeros(9)
    t = log["t"]
    ns = np.rint(t * 1e9).astype(np.int64)

    def hdr(k):
        return Header(stamp=Time(sec=int(ns[k] // 10**9), nanosec=int(ns[k] % 10**9)), frame_id="map")

    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        c_o = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        c_i = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        c_a = w.add_connection("/drive", "ackermann_msgs/msg/AckermannDriveStamped", typestore=store)
        for k in range(len(t)):  # writing the test file; the import is what is timed
            yaw = log["yaw"][k]
            pose = M["geometry_msgs/msg/Pose"](position=M["geometry_msgs/msg/Point"](x=float(log["x"][k]), y=float(log["y"][k]), z=0.0),
                                               orientation=Q(x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2))))
            tw = M["geometry_msgs/msg/Twist"](linear=V3(x=float(log["v_x"][k]), y=float(log["v_y"][k]), z=0.0), angular=V3(x=0.0, y=0.0, z=float(log["yaw_rate"][k])))
            od = M["nav_msgs/msg/Odometry"](header=hdr(k), child_frame_id="base", pose=M["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=z36),
                                            twist=M["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=z36))
            w.write(c_o, int(ns[k]), store.serialize_cdr(od, "nav_msgs/msg/Odometry"))
            im = M["sensor_msgs/msg/Imu"](header=hdr(k), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=z9,
                                          angular_velocity=V3(x=0.0, y=0.0, z=float(log["yaw_rate"][k])), angular_velocity_covariance=z9,
                                          linear_acceleration=V3(x=float(log["a_x"][k]), y=0.0, z=9.81), linear_acceleration_covariance=z9)
            w.write(c_i, int(ns[k]), store.serialize_cdr(im, "sensor_msgs/msg/Imu"))
            if k % 2 == 0:
                ak = M["ackermann_msgs/msg/AckermannDriveStamped"](header=hdr(k), drive=M["ackermann_msgs/msg/AckermannDrive"](
                    steering_angle=float(log["delta"][k]), steering_angle_velocity=0.0, speed=float(log["v_x"][k]),
                    acceleration=float(log["a_x"][k]), jerk=0.0))
                w.write(c_a, int(ns[k]), store.serialize_cdr(ak, "ackermann_msgs/msg/AckermannDriveStamped"))
    return path


def timed_import(path: Path, track, out: Path, label: str, samples: int) -> dict:
    from gprace.ingest.importer import import_hash, import_recording
    from gprace.io.runs import write_run

    t0 = time.perf_counter()
    run, _ = import_recording(path, track=track, dt=0.05)
    write_run(run, out, config_hash=import_hash(run))
    sec = time.perf_counter() - t0
    size = sum(p.stat().st_size for p in path.rglob("*")) if path.is_dir() else path.stat().st_size
    return {"format": label, "samples_per_channel": samples, "file_mb": round(size / 1e6, 1),
            "rows_out": run.n, "laps": int(run["lap"].max()), "seconds": round(sec, 2), "within_10s": sec <= 10.0}


REAL = _shared() / "real"
MAPS = Path(__file__).resolve().parents[1] / "tests" / "data" / "real_maps"


def real_rows() -> list[dict]:
    """Import rows of the shared real logs (module docstring)."""
    from gprace.ingest.importer import import_recording
    from gprace.ingest.mapping import load_map
    from gprace.io.table import numbers, sniff
    from gprace.tracks import load_track

    ini, iac = REAL / "ini_f1tenth_ipz20", REAL / "iac_putnam_park"
    cases = []
    for run in sorted(ini.glob("*_physical.csv")):
        for track in (str(ini / "centerline.csv"), None):
            cases.append((run, "ini_f1tenth.map.toml", track, ("linear_vel_x", "linear_vel_y")))
    rec = iac / "Putnam_park2023_run4_2.csv"
    for track in (f"{iac / 'putnam_inner_bound.csv'},{iac / 'putnam_outer_bound.csv'}", None):
        cases.append((rec, "iac_putnam.map.toml", track, ("vx(m/s)", "vy(m/s)")))
    rows = []
    for rec, mp, track, vcols in cases:
        v = numbers(sniff(rec), list(vcols))
        moving_log = int(np.sum(np.hypot(v[:, 0], v[:, 1]) > 0.1))
        t0 = time.perf_counter()
        run, trk = import_recording(rec, track=track, rmap=load_map(MAPS / mp), dt=0.04)
        sec = time.perf_counter() - t0
        d = run.data
        moving = int(np.sum(np.hypot(d["v_x"], d["v_y"]) > 0.1))
        rows.append({"log": rec.name, "track": "path" if track is None else trk.name, "reversed": run.meta["track_reversed"],
                     "lap_length_m": round(trk.length, 2), "laps": int(d["lap"].max()),
                     "s_m": [round(float(d["s"].min()), 2), round(float(d["s"].max()), 2)],
                     "e_y_abs_max_m": round(float(np.abs(d["e_y"]).max()), 2), "samples": run.n,
                     "moving_kept": moving, "moving_in_log": moving_log, "kept_share": round(moving / moving_log, 3),
                     "gaps": run.meta["gaps"], "inputs": run.meta["inputs"], "seconds": round(sec, 2)})
    for path in (ini / "centerline.csv", _shared() / "tumftm-racetrack-database" / "tracks" / "Spa.csv"):
        from gprace.tracks.loaders import _load_cached

        _load_cached.cache_clear()
        t0 = time.perf_counter()
        trk = load_track(path)
        rows.append({"track_file": path.name, "length_m": round(trk.length, 2), "min_radius_m": round(trk.min_radius, 2),
                     "smoothing_m": round(trk.smoothing, 3), "seconds": round(time.perf_counter() - t0, 2)})
    return rows


def main() -> None:
    from gprace.tracks import load_track

    minutes = float(_arg("--minutes", "30"))
    rate = float(_arg("--rate", "100"))
    track = load_track(_arg("--track", str(TRACK)))
    log = make_log(track, minutes, rate)
    n = len(log["t"])
    rows = []
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        rows.append(timed_import(write_csv(log, d / "log.csv"), track, d / "a.h5", "csv", n))
        rows.append(timed_import(write_mdf(log, d / "log.mf4"), track, d / "b.h5", "mdf4", n))
        if "--mcap" in sys.argv:
            rows.append(timed_import(write_mcap(log, d / "bag"), track, d / "c.h5", "mcap", n))
        # without a track: the reference line from the path
        rows.append({**timed_import(d / "log.csv", None, d / "d.h5", "csv (path reference)", n)})
    out = {"benchmark": "import", "minutes": minutes, "rate_hz": rate, "track": track.name, "dt_out": 0.05, "rows": rows}
    if "--real" in sys.argv:
        out["real_logs"] = real_rows()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
