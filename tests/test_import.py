"""``gprace import`` and the raw-recording readers (issue 15).

Every recording here is written by the test itself (tmp_path) from a run ``gprace simulate``
recorded on a TUM circuit (read in place from the shared database, never copied): global-frame
CSV, an MCAP with Odometry + Imu + Ackermann messages at different rates, an MDF4 with its own
channel names and units. Importing them back must reproduce the Frenet run.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from gprace.cli import main
from gprace.errors import InputError
from gprace.ingest.dispatch import read_any
from gprace.io.runs import read_run, write_run_csv

from shared_data import TUM_TRACKS as TRACKS
NORIS = TRACKS / "Norisring.csv"
pytestmark = pytest.mark.skipif(not NORIS.exists(), reason="TUM racetrack database not available")

DT_SIM = 0.01  # the simulated run; the imports resample it at 0.05 s


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("GPRACE_DEBUG", raising=False)


def _cli(*args) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """One noise-free lap (and a bit) of Norisring at 100 Hz, through ``gprace simulate``."""
    d = tmp_path_factory.mktemp("sim")
    plant = d / "plant.toml"
    plant.write_text('kind = "frenet"\nvehicle = "audi_tt_cup"\nsubsteps = 4\n')  # no sensor noise
    code, out, err = _cli("-q", "simulate", "--plant", plant, "--track", NORIS, "--laps", "1.03",
                          "--dt", DT_SIM, "--weave", "0.4", "-o", d / "run.h5")
    assert code == 0, err
    run = read_run(d / "run.h5")
    from gprace.tracks import load_track

    track = load_track(NORIS)
    s, ey = run["s"], run["e_y"]
    x, y = track.to_global(s, ey)
    yaw = np.angle(np.exp(1j * (track.heading(s) + run["e_psi"])))
    return {"run": run, "track": track, "x": x, "y": y, "yaw": yaw, "dir": d}


def _compare(imported, original, track, dt=0.05):
    """Max errors of an imported run against the original at the same times (wrapped s)."""
    t_orig = original["t"]
    idx = np.rint((imported["t"] + imported.meta["t0"] - _t_offset(imported)) / DT_SIM).astype(int)
    assert np.allclose(t_orig[idx], imported["t"] + imported.meta["t0"] - _t_offset(imported), atol=1e-6)
    L = track.length
    ds = (imported["s"] - original["s"][idx] + 0.5 * L) % L - 0.5 * L
    err = {"s": np.abs(ds).max(), "e_y": np.abs(imported["e_y"] - original["e_y"][idx]).max(),
           "e_psi": np.abs(np.angle(np.exp(1j * (imported["e_psi"] - original["e_psi"][idx])))).max()}
    for c in ("v_x", "v_y", "yaw_rate", "delta", "a_x"):
        err[c] = np.abs(imported[c] - original[c][idx]).max()
    return err, idx


T_OFFSET = 1000.0  # recordings carry their own epoch


def _t_offset(run) -> float:
    return T_OFFSET if run.meta.get("source_format") in ("csv", "ros") else 0.0


def _check_whole_lap(imp, sim, err, idx):
    run = sim["run"]
    assert err["s"] <= 0.1 and err["e_y"] <= 0.05 and err["e_psi"] <= 0.01, err
    # the whole lap: the imported run covers the start, the lap line and beyond
    assert imp["t"][-1] >= run["t"][-1] - 0.1
    assert imp["lap"].min() == 0 and imp["lap"].max() == 1
    # lap counter: the same as the simulator's everywhere except a hair at the line itself
    near_line = np.minimum(run["s"][idx], sim["track"].length - run["s"][idx]) < 0.1
    assert np.array_equal(imp["lap"][~near_line], run["lap"][idx][~near_line])
    assert np.allclose(imp["kappa"], sim["track"].kappa(imp["s"]))


# ------------------------------------------------------------------------------------------
# writers of the three formats (test fixtures, small)


def write_global_csv(sim, path: Path, keep: np.ndarray | None = None, **replace) -> Path:
    r = sim["run"]
    cols = {"t": r["t"] + T_OFFSET, "x": sim["x"], "y": sim["y"], "yaw": sim["yaw"], "v_x": r["v_x"],
            "v_y": r["v_y"], "yaw_rate": r["yaw_rate"], "delta": r["delta"], "a_x": r["a_x"]}
    cols.update(replace)
    arr = np.column_stack(list(cols.values()))
    if keep is not None:
        arr = arr[keep]
    np.savetxt(path, arr, delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
    return path


def write_mcap(sim, path: Path, topics=("/odom", "/imu", "/drive"), types=None, every=(3, 1, 5), storage="mcap") -> Path:
    """rosbag2 (MCAP storage): Odometry every 3rd sample (33 Hz), Imu at 100 Hz, Ackermann at 20 Hz."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from gprace.ingest.readers import ros_typestore

    ros1 = storage == "ros1"
    store = ros_typestore(ros1=ros1)
    M = store.types
    r = sim["run"]
    t = r["t"] + T_OFFSET
    V3 = M["geometry_msgs/msg/Vector3"]
    zeros36, zeros9 = np.zeros(36), np.zeros(9)
    extra = {"seq": 0} if ros1 else {}  # ROS 1 headers carry a sequence number

    def hdr(k):
        sec = int(np.floor(t[k]))
        return M["std_msgs/msg/Header"](**extra, stamp=M["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t[k] - sec) * 1e9))), frame_id="map")

    def odom(k):
        yaw = sim["yaw"][k]
        pose = M["geometry_msgs/msg/Pose"](
            position=M["geometry_msgs/msg/Point"](x=float(sim["x"][k]), y=float(sim["y"][k]), z=0.0),
            orientation=M["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2))))
        tw = M["geometry_msgs/msg/Twist"](linear=V3(x=float(r["v_x"][k]), y=float(r["v_y"][k]), z=0.0),
                                          angular=V3(x=0.0, y=0.0, z=float(r["yaw_rate"][k])))
        return M["nav_msgs/msg/Odometry"](
            header=hdr(k), child_frame_id="base_link",
            pose=M["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=zeros36),
            twist=M["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=zeros36))

    def imu(k):
        return M["sensor_msgs/msg/Imu"](
            header=hdr(k), orientation=M["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=zeros9, angular_velocity=V3(x=0.0, y=0.0, z=float(r["yaw_rate"][k])),
            angular_velocity_covariance=zeros9, linear_acceleration=V3(x=float(r["a_x"][k]), y=0.0, z=9.81),
            linear_acceleration_covariance=zeros9)

    def ack(k):
        return M["ackermann_msgs/msg/AckermannDriveStamped"](
            header=hdr(k), drive=M["ackermann_msgs/msg/AckermannDrive"](
                steering_angle=float(r["delta"][k]), steering_angle_velocity=0.0, speed=float(r["v_x"][k]),
                acceleration=float(r["a_x"][k]), jerk=0.0))

    makers = {"/odom": ("nav_msgs/msg/Odometry", odom), "/imu": ("sensor_msgs/msg/Imu", imu),
              "/drive": ("ackermann_msgs/msg/AckermannDriveStamped", ack)}
    shutil.rmtree(path, ignore_errors=True)
    if ros1:
        from rosbags.rosbag1 import Writer as Writer1

        path.unlink(missing_ok=True)
        writer, ser = Writer1(path), store.serialize_ros1
    else:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer, ser = Writer(path, version=8, storage_plugin=plugin), store.serialize_cdr
    with writer as w:
        for topic, step in zip(("/odom", "/imu", "/drive"), every):
            if topic not in topics:
                continue
            typ, fn = makers[topic]
            name = (types or {}).get(topic, topic)  # publish under another topic name (wrong type test)
            conn = w.add_connection(name, typ, typestore=store)
            for k in range(0, len(t), step):
                w.write(conn, int(round(t[k] * 1e9)), ser(fn(k), typ))
    if ros1:
        return path
    return path / f"{path.name}.{'mcap' if storage == 'mcap' else 'db3'}"


def write_mdf(sim, path: Path) -> Path:
    """MDF4 with logger-style channel names, three time bases, km/h and degrees in the channels."""
    from asammdf import MDF, Signal

    r = sim["run"]
    t = r["t"]
    a, b, c = slice(0, None, 2), slice(0, None, 1), slice(0, None, 5)
    mdf = MDF(version="4.10")
    mdf.append([Signal(sim["x"][a], t[a], name="PosX", unit="m"), Signal(sim["y"][a], t[a], name="PosY", unit="m"),
                Signal(np.degrees(sim["yaw"][a]), t[a], name="Heading", unit="deg")])
    mdf.append([Signal(3.6 * r["v_x"][b], t[b], name="VelX", unit="km/h"), Signal(r["v_y"][b], t[b], name="VelY", unit="m/s"),
                Signal(r["yaw_rate"][b], t[b], name="YawRate", unit="rad/s")])
    mdf.append([Signal(15.0 * r["delta"][c], t[c], name="SWA", unit="rad"), Signal(r["a_x"][c], t[c], name="AccX", unit="m/s^2")])
    mdf.save(str(path), overwrite=True)
    mdf.close()
    return path


MDF_MAP = """steering_ratio = 15.0
[columns]
x = "PosX"
y = "PosY"
yaw = "Heading"
v_x = "VelX"
v_y = "VelY"
yaw_rate = "YawRate"
steering_wheel = "SWA"
a_x = "AccX"
"""


# ------------------------------------------------------------------------------------------
# round trips


def test_csv_with_uneven_time_stamps_round_trips(sim, tmp_path):
    n = sim["run"].n
    rng = np.random.default_rng(3)
    keep = rng.random(n) < 0.7  # rows dropped at random: uneven stamps, 10..40 ms apart
    keep[:: 5] = True  # (the 0.05 s grid still meets original samples, for the comparison)
    keep[-3:] = True
    rec = write_global_csv(sim, tmp_path / "log.csv", keep)
    out = tmp_path / "imp.h5"
    code, stdout, err = _cli("import", rec, "--track", NORIS, "-o", out, "--dt", "0.05")
    assert code == 0, err
    imp = read_run(out)
    assert imp.dt == 0.05 and np.allclose(np.diff(imp["t"]), 0.05)
    e, idx = _compare(imp, sim["run"], sim["track"])
    _check_whole_lap(imp, sim, e, idx)
    assert max(e["v_x"], e["v_y"], e["yaw_rate"]) < 1e-6 and e["delta"] < 1e-9
    # provenance
    m = imp.meta
    import hashlib

    assert m["source_sha256"] == hashlib.sha256(rec.read_bytes()).hexdigest()
    assert m["source_file"] == str(rec.resolve()) and Path(m["track"]).resolve() == NORIS.resolve() and m["reference"] == "track"
    assert m["track_sha256"] == hashlib.sha256(NORIS.read_bytes()).hexdigest()
    assert 'a_x = "a_x"' in m["map_toml"] and m["dt"] == 0.05 and m["gaps"] == 0
    assert "wrote" in stdout and "1 lap crossing" in stdout


def test_mcap_with_three_rates_round_trips(sim, tmp_path):
    bag = write_mcap(sim, tmp_path / "bag")
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", bag, "--track", NORIS, "-o", out)
    assert code == 0, err
    imp = read_run(out)
    e, idx = _compare(imp, sim["run"], sim["track"])
    _check_whole_lap(imp, sim, e, idx)
    o = imp.meta["origins"]
    assert o["x"].startswith("topic '/odom'") and o["yaw_rate"].startswith("topic '/imu'")
    assert o["delta"].startswith("topic '/drive'") and o["a_x"].startswith("topic '/drive'")
    # commands (20 Hz, held) are exact at the grid; the 33 Hz odometry is interpolated
    assert e["delta"] < 1e-6 and e["a_x"] < 1e-5 and e["yaw_rate"] < 1e-6
    assert e["v_x"] < 0.05
    # the rosbag2 folder reads the same as the .mcap inside it
    code, _, err = _cli("import", bag.parent, "--track", NORIS, "-o", tmp_path / "imp2.csv")
    assert code == 0, err
    imp2 = read_run(tmp_path / "imp2.csv")
    assert np.allclose(imp2["e_y"], imp["e_y"]) and np.allclose(imp2["s"], imp["s"])
    prov = json.loads((tmp_path / "imp2.meta.json").read_text())
    assert prov["source_format"] == "ros" and len(prov["source_sha256"]) == 64


def test_mdf4_with_own_names_and_units_round_trips(sim, tmp_path):
    rec = write_mdf(sim, tmp_path / "log.mf4")
    mp = tmp_path / "map.toml"
    mp.write_text(MDF_MAP)
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", rec, "--track", NORIS, "--map", mp, "-o", out)
    assert code == 0, err
    imp = read_run(out)
    e, idx = _compare(imp, sim["run"], sim["track"])
    _check_whole_lap(imp, sim, e, idx)
    # the channel's own units (km/h, deg) were applied; steering wheel / ratio gives delta
    assert e["v_x"] < 1e-6 and e["delta"] < 1e-9
    assert imp.meta["map_file"] == str(mp) and "steering_ratio = 15.0" in imp.meta["map_toml"]


def test_rosbag2_sqlite_db3_round_trips(sim, tmp_path):
    db3 = write_mcap(sim, tmp_path / "bag", storage="sqlite3")
    assert db3.suffix == ".db3"
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", db3, "--track", NORIS, "-o", out)
    assert code == 0, err
    imp = read_run(out)
    e, idx = _compare(imp, sim["run"], sim["track"])
    _check_whole_lap(imp, sim, e, idx)


def test_ros1_bag_round_trips(sim, tmp_path):
    bag = write_mcap(sim, tmp_path / "log.bag", storage="ros1")
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", bag, "--track", NORIS, "-o", out)
    assert code == 0, err
    imp = read_run(out)
    e, idx = _compare(imp, sim["run"], sim["track"])
    _check_whole_lap(imp, sim, e, idx)


def test_tangent_plane_matches_the_textbook_radii():
    """East along a parallel = N cos(lat) sin(dlon); north along a meridian = M dlat (to 1 cm at 1 km)."""
    from gprace.ingest.process import enu_from_latlon

    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    lat0, lon0 = np.radians(48.1), np.radians(11.5)
    N = a / np.sqrt(1 - e2 * np.sin(lat0) ** 2)
    M = a * (1 - e2) / (1 - e2 * np.sin(lat0) ** 2) ** 1.5
    dlon, dlat = 1000.0 / (N * np.cos(lat0)), 1000.0 / M
    e, n = enu_from_latlon(np.array([lat0, lat0 + dlat]), np.array([lon0 + dlon, lon0]), lat0, lon0)
    assert abs(e[0] - N * np.cos(lat0) * np.sin(dlon)) < 1e-3 and abs(n[1] - 1000.0) < 0.01
    # the parallel bends towards the pole in the tangent plane by x^2 tan(lat) / 2N (8.7 cm at 1 km)
    assert abs(e[1]) < 1e-6 and abs(n[0] - 1000.0**2 * np.tan(lat0) / (2 * N)) < 1e-3


def _latlon_of(x, y, lat0, lon0):
    """Inverse of the tangent-plane projection by Newton steps on it (test helper)."""
    from gprace.ingest.process import enu_from_latlon

    R = 6378137.0
    la = lat0 + y / R
    lo = lon0 + x / (R * np.cos(lat0))
    for _ in range(5):
        e, n = enu_from_latlon(la, lo, lat0, lon0)
        h = 1e-7
        e_la, n_la = enu_from_latlon(la + h, lo, lat0, lon0)
        e_lo, n_lo = enu_from_latlon(la, lo + h, lat0, lon0)
        J = np.stack([[(e_la - e) / h, (e_lo - e) / h], [(n_la - n) / h, (n_lo - n) / h]])
        det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
        rx, ry = x - e, y - n
        la = la + (J[1, 1] * rx - J[0, 1] * ry) / det
        lo = lo + (-J[1, 0] * rx + J[0, 0] * ry) / det
    return np.degrees(la), np.degrees(lo)


def test_gnss_log_lat_lon_speed_course_steering_wheel(sim, tmp_path):
    """A GNSS-style CSV: lat/lon in the track's tangent plane, speed + course over ground, the
    steering-wheel angle in degrees, yaw rate in deg/s, no a_x (derived from speed)."""
    r = sim["run"]
    lat0, lon0 = 49.4271, 11.1022
    lat, lon = _latlon_of(sim["x"], sim["y"], np.radians(lat0), np.radians(lon0))
    beta = np.arctan2(r["v_y"], r["v_x"])
    cols = {"time_ms": 1e3 * r["t"], "lat": lat, "lon": lon, "heading": np.degrees(sim["yaw"]),
            "gps_speed": 3.6 * np.hypot(r["v_x"], r["v_y"]), "cog": np.degrees(sim["yaw"] + beta),
            "gyro_z": np.degrees(r["yaw_rate"]), "swa": np.degrees(14.0 * r["delta"])}
    rec = tmp_path / "gnss.csv"
    np.savetxt(rec, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
    mp = tmp_path / "gnss.toml"
    mp.write_text(f"""steering_ratio = 14.0
origin = [{lat0}, {lon0}]
[columns]
t = "time_ms"
yaw = "heading"
speed = "gps_speed"
course = "cog"
yaw_rate = "gyro_z"
steering_wheel = "swa"
[units]
t = "ms"
yaw = "deg"
speed = "km/h"
course = "deg"
yaw_rate = "deg/s"
steering_wheel = "deg"
""")
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", rec, "--track", NORIS, "--map", mp, "-o", out)
    assert code == 0, err
    assert "no a_x: from the change of v_x" in err
    imp = read_run(out)
    idx = np.rint(imp["t"] / DT_SIM).astype(int)
    L = sim["track"].length
    ds = (imp["s"] - r["s"][idx] + 0.5 * L) % L - 0.5 * L
    assert np.abs(ds).max() < 0.1 and np.abs(imp["e_y"] - r["e_y"][idx]).max() < 0.05
    assert np.abs(imp["e_psi"] - r["e_psi"][idx]).max() < 0.01
    assert np.abs(imp["v_x"] - r["v_x"][idx]).max() < 1e-6 and np.abs(imp["v_y"] - r["v_y"][idx]).max() < 1e-6
    assert np.abs(imp["delta"] - r["delta"][idx]).max() < 1e-9
    # a_x from the change of speed less r v_y (the body's longitudinal acceleration, as the
    # model's kinematic v_x equation reads it: dv_x/dt = a_x + r v_y), where it is smooth
    dv = (np.gradient(r["v_x"], DT_SIM) - r["yaw_rate"] * r["v_y"])[idx]
    assert np.median(np.abs(imp["a_x"] - dv)) < 0.1


def test_without_track_a_reference_line_from_the_path(sim, tmp_path):
    rec = write_global_csv(sim, tmp_path / "log.csv")
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", rec, "-o", out)
    assert code == 0, err
    imp = read_run(out)
    assert imp.meta["reference"] == "path" and imp.meta["track"] == "path"
    L = imp.meta["track_length"]
    # the path closes: a closed line about as long as the centre line (the car weaves and cuts)
    assert L is not None and abs(L - sim["track"].length) < 0.03 * sim["track"].length
    assert imp["lap"].max() == 1 and imp["s"][0] < 1.0
    # the driven line is the reference: the car stays close to it, curvature like the track's
    assert np.abs(imp["e_y"]).max() < 3.0
    r = sim["run"]
    assert np.corrcoef(imp["kappa"], r["kappa"][::5][: imp.n])[0, 1] > 0.9


def test_gaps_stay_gaps(sim, tmp_path):
    r = sim["run"]
    t = r["t"]
    keep = ~((t > 20.0) & (t < 22.5))  # every source silent for 2.5 s
    rec = write_global_csv(sim, tmp_path / "log.csv", keep)
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", rec, "--track", NORIS, "-o", out)
    assert code == 0, err
    imp = read_run(out)
    t_abs = imp["t"]  # the grid starts at the first sample (t = 0)
    assert not np.any((t_abs > 20.0 + 1e-6) & (t_abs < 22.5 - 1e-6))  # no invented rows
    assert imp["segment"].max() == 1 and np.diff(imp["t"]).max() > 2.0
    e, idx = _compare(imp, r, sim["track"])
    assert e["e_y"] < 0.05 and e["s"] < 0.1  # rows either side of the gap are exact


def test_one_silent_source_is_a_gap_too(sim, tmp_path):
    """Empty cells: the gyro drops out for 1.5 s while everything else keeps logging."""
    r = sim["run"]
    t = r["t"]
    rate = r["yaw_rate"].copy()
    rate[(t > 30.0) & (t < 31.5)] = np.nan
    rec = write_global_csv(sim, tmp_path / "log.csv", yaw_rate=rate)
    rec.write_text(rec.read_text().replace(",nan,", ",,"))
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", rec, "--track", NORIS, "-o", out)
    assert code == 0, err
    imp = read_run(out)
    assert not np.any((imp["t"] > 30.0 + 1e-6) & (imp["t"] < 31.5 - 1e-6))
    assert imp["segment"].max() == 1 and imp.meta["gaps"] == 1
    # the grid rows on either side are still there: 30.00 and 31.50 fall on gyro samples
    assert np.any(np.isclose(imp["t"], 30.0)) and np.any(np.isclose(imp["t"], 31.5))
    assert imp.meta["rows_dropped"] == 29


def test_read_any_imports_raw_recordings_read_run_does_not(sim, tmp_path):
    """Every stage reading a user's recording takes the raw formats too (map's track, else the
    path) through ``read_any``; ``read_run`` reads gprace runs only (issue 40: the ingest layer
    decides when a file is imported)."""
    bag = write_mcap(sim, tmp_path / "bag")
    (tmp_path / "bag.map.toml").write_text(f'track = "{NORIS}"\n')
    run = read_any(bag.parent)
    assert run.meta["reference"] == "track" and run.dt == 0.05
    e, _ = _compare(run, sim["run"], sim["track"])
    assert e["e_y"] < 0.05 and e["s"] < 0.1
    csv = write_global_csv(sim, tmp_path / "log.csv")
    run2 = read_any(csv)  # no map: the reference line from the path
    assert run2.meta["reference"] == "path" and set(run2.data) >= {"s", "e_y", "kappa"}
    with pytest.raises(InputError, match="is a folder"):
        read_run(bag.parent)
    with pytest.raises(InputError, match="missing column"):
        read_run(csv)
    # a Frenet CSV is read as before
    write_run_csv(sim["run"], tmp_path / "frenet.csv")
    assert "reference" not in read_any(tmp_path / "frenet.csv").meta
    np.testing.assert_array_equal(read_any(tmp_path / "frenet.csv")["v_x"], read_run(tmp_path / "frenet.csv")["v_x"])
    code, out, err = _cli("-q", "select-data", bag.parent, "--gp", "tracking", "--max-points", "50",
                          "--selection", "random", "--vehicle", "audi_tt_cup", "-o", tmp_path / "data.h5")
    assert code == 0, err
    assert f"from {run.n - 1} new samples" in out  # every consecutive pair of the 0.05 s grid
    code, out, err = _cli("show", bag.parent, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["format"] == "ros recording (imported)" and info["arrays"]["e_y"]["shape"] == [run.n]


# ------------------------------------------------------------------------------------------
# diagnose on imported recordings


@pytest.mark.slow  # ~40 s on a shared 2-core machine
def test_diagnose_gives_the_same_verdict_on_the_imported_recording(tmp_path):
    from gprace.config import EffectConfig, load_vehicle
    from gprace.diagnose.synth import record
    from gprace.io.runs import write_run
    from gprace.tracks import load_track

    veh = load_vehicle("audi_tt_cup")
    track = load_track(NORIS)
    r = record(veh, track, [EffectConfig(name="aero_drag", params={"c_d": 0.3})], laps=1.3, seed=5, substeps=5)
    orig = write_run(r, tmp_path / "orig.h5")
    x, y = track.to_global(r["s"], r["e_y"])
    yaw = track.heading(r["s"]) + r["e_psi"]
    cols = {"t": r["t"], "x": x, "y": y, "yaw": yaw, "v_x": r["v_x"], "v_y": r["v_y"],
            "yaw_rate": r["yaw_rate"], "delta": r["delta"], "a_x": r["a_x"]}
    raw = tmp_path / "car.csv"
    np.savetxt(raw, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
    code, _, err = _cli("import", raw, "--track", NORIS, "-o", tmp_path / "imp.h5")
    assert code == 0, err
    reports = []
    for f in (orig, tmp_path / "imp.h5"):
        code, out, err = _cli("-q", "diagnose", f, "--vehicle", "audi_tt_cup", "--json")
        assert code == 0, err
        reports.append(json.loads(out))
    a, b = reports
    assert a["verdict"] == b["verdict"] == "mismatch"
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]] == ["aero_drag"]
    pa, pb = a["effects"][0]["parameters"]["c_d"]["value"], b["effects"][0]["parameters"]["c_d"]["value"]
    assert abs(pa - 0.3) < 0.05 and abs(pa - pb) < 0.01


@pytest.mark.slow  # the commonroad plant integrates at 1 ms in Python: ~60 s
def test_commonroad_recording_in_the_global_frame_imports_and_diagnoses(tmp_path):
    """x, y, yaw, speed and course from the commonroad model's own state, nothing from gprace's
    Frenet code on the way out; imported and diagnosed against the nominal BMW."""
    from gprace.config import PlantConfig, load_vehicle
    from gprace.diagnose.synth import TrackingDriver
    from gprace.plants import make_plant
    from gprace.tracks import load_track

    veh = load_vehicle("bmw_320i")
    track = load_track(NORIS)
    dt = 0.05
    plant = make_plant(PlantConfig(kind="commonroad-std", vehicle=veh, substeps=1), track, dt)
    drv = TrackingDriver(veh, track, dt, 0.5, 0.3, excitation=1.0, seed=2)
    v0 = drv.v_ref(0.0)
    u0 = np.array([veh.wheelbase * float(track.kappa(0.0)), 0.0])
    drv.delta_prev = float(u0[0])
    y = plant.reset(np.array([v0, 0.0, v0 * float(track.kappa(0.0)), 0.0, 0.0, 0.0]), u0)
    n = int(15.0 / dt)  # 300 samples: diagnose needs 200
    Z, U, X = np.empty((n, 9)), np.empty((n, 2)), np.empty((n, 6))
    for k in range(n):  # a time simulation (sequential by nature)
        u = drv(y)
        Z[k], U[k], X[k] = plant.global_state, u, plant.state  # X only to compare with, below
        y = plant.step(u)
    # x, y, delta, v, psi, yaw_rate, beta: the package's own state
    cols = {"t": dt * np.arange(n), "x": Z[:, 0], "y": Z[:, 1], "yaw": Z[:, 4], "speed": Z[:, 3],
            "course": Z[:, 4] + Z[:, 6], "yaw_rate": Z[:, 5], "delta": U[:, 0], "a_x": U[:, 1]}
    rec = tmp_path / "bmw.csv"
    np.savetxt(rec, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
    out = tmp_path / "bmw.h5"
    code, _, err = _cli("import", rec, "--track", NORIS, "-o", out)
    assert code == 0, err
    imp = read_run(out)
    assert imp.n == n
    # body velocities from speed and course: v_y = v sin(beta)
    assert np.allclose(imp["v_y"], Z[:, 3] * np.sin(Z[:, 6]), atol=1e-9)
    # the same Frenet state as the plant's own observation (noise-free)
    assert np.abs(imp["e_y"] - X[:, 4]).max() < 1e-3 and np.abs(imp["s"] - X[:, 5]).max() < 1e-3
    assert np.abs(np.angle(np.exp(1j * (imp["e_psi"] - X[:, 3])))).max() < 1e-6
    assert np.abs(imp["v_x"] - X[:, 0]).max() < 1e-9 and np.abs(imp["yaw_rate"] - X[:, 2]).max() < 1e-9
    assert np.all(np.diff(imp["s"]) > 0)  # less than a lap, always forward
    code, o, err = _cli("-q", "diagnose", out, "--vehicle", "bmw_320i", "--json")
    assert code == 0, err
    rep = json.loads(o)
    assert rep["verdict"] in ("mismatch", "no significant mismatch", "match") or rep["verdict"]
    ch = {c["name"]: c for c in rep["channels"]}
    assert set(ch) >= {"v_x", "v_y", "yaw_rate"}


# ------------------------------------------------------------------------------------------
# bad input: one line, exit 2, no file written


def _bad(result, out_file, *needles):
    """``result`` of :func:`_cli`: exit 2, one line naming ``needles``, no output file."""
    code_, stdout, err = result
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert code_ == 2, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], (n, lines[0])
    assert not out_file.exists()
    assert not list(out_file.parent.glob(f".{out_file.name}*"))
    return lines[0]


def test_missing_topic_lists_the_topics_present(sim, tmp_path):
    bag = write_mcap(sim, tmp_path / "bag", topics=("/odom", "/imu"))
    out = tmp_path / "o.h5"
    line = _bad(_cli("import", bag, "--track", NORIS, "-o", out), out, "no steering angle", "'/drive'")
    assert "/imu (sensor_msgs/msg/Imu)" in line and "/odom (nav_msgs/msg/Odometry)" in line


def test_wrong_message_type(sim, tmp_path):
    bag = write_mcap(sim, tmp_path / "bag", topics=("/imu", "/drive"), types={"/imu": "/odom"})
    out = tmp_path / "o.h5"
    _bad(_cli("import", bag, "--track", NORIS, "-o", out), out,
         "topic '/odom' has message type sensor_msgs/msg/Imu, expected nav_msgs/msg/Odometry")


def test_missing_mdf_channel_lists_the_channels(sim, tmp_path):
    rec = write_mdf(sim, tmp_path / "log.mf4")
    mp = tmp_path / "map.toml"
    mp.write_text(MDF_MAP.replace('"PosX"', '"Pos_X"'))
    out = tmp_path / "o.h5"
    _bad(_cli("import", rec, "--track", NORIS, "--map", mp, "-o", out), out,
         "channel 'Pos_X'", "[columns] x", "lacks", "PosX", "VelX")


def test_time_going_backwards(sim, tmp_path):
    t = sim["run"]["t"] + T_OFFSET
    t[400], t[401] = t[401], t[400]
    rec = write_global_csv(sim, tmp_path / "log.csv", t=t)
    out = tmp_path / "o.h5"
    _bad(_cli("import", rec, "--track", NORIS, "-o", out), out, "time stamps go backwards", "at row 402 ")


def test_recording_never_on_the_track(sim, tmp_path):
    rec = write_global_csv(sim, tmp_path / "log.csv", x=sim["x"] + 5000.0)
    out = tmp_path / "o.h5"
    line = _bad(_cli("import", rec, "--track", NORIS, "-o", out), out, "never comes within track 'Norisring'")
    dist = float(line.split("closest point is ")[1].split(" m")[0])
    assert 4000.0 < dist < 6000.0


def test_map_with_unknown_key(sim, tmp_path):
    rec = write_global_csv(sim, tmp_path / "log.csv")
    mp = tmp_path / "map.toml"
    mp.write_text('[columns]\nyaw_rat = "gyro_z"\n')
    out = tmp_path / "o.h5"
    _bad(_cli("import", rec, "--map", mp, "-o", out), out, "map.toml", "columns.yaw_rat: unknown key")


@pytest.mark.parametrize("column,factor,unit,dimension_hint", [
    ("v_x", 3.6, "km/h", "speed from successive positions"),
    ("yaw_rate", 180.0 / np.pi, "deg/s", "heading change"),
    ("yaw", 180.0 / np.pi, "deg", "heading change of the path"),
    ("a_x", 1.0 / 9.80665, "g", "change of speed"),
])
def test_wrong_units_name_column_and_probable_unit(sim, tmp_path, column, factor, unit, dimension_hint):
    r = sim["run"]
    base = {"v_x": r["v_x"], "yaw_rate": r["yaw_rate"], "yaw": np.unwrap(sim["yaw"]), "a_x": r["a_x"]}[column]
    rec = write_global_csv(sim, tmp_path / "log.csv", **{column: factor * base})
    out = tmp_path / "o.h5"
    line = _bad(_cli("import", rec, "--track", NORIS, "-o", out), out,
                f"column '{column}'", dimension_hint, f"looks like {unit}", f'[units] {column} = "{unit}"')
    ratio = float(line.split("by a factor ")[1].split(" ")[0])
    assert abs(ratio / factor - 1.0) < 0.1


def test_time_stamps_in_ms_are_named(sim, tmp_path):
    rec = write_global_csv(sim, tmp_path / "log.csv", t=1e3 * sim["run"]["t"])
    out = tmp_path / "o.h5"
    _bad(_cli("import", rec, "--track", NORIS, "-o", out, "--dt", "50"), out, "--dt")  # 50 s: rejected first
    _bad(_cli("import", rec, "--track", NORIS, "-o", out, "--dt", "0.05"), out,
         "time stamps look like ms", '[units] t = "ms"')


def test_map_hold_names_are_checked(tmp_path):
    from gprace.errors import ConfigError
    from gprace.ingest.mapping import load_map

    p = tmp_path / "m.toml"
    p.write_text('hold = ["delta", "steer"]\n')
    with pytest.raises(ConfigError, match="hold: unknown quantity steer"):
        load_map(p)


def test_missing_odometry_and_pose(sim, tmp_path):
    bag = write_mcap(sim, tmp_path / "bag", topics=("/imu", "/drive"))
    out = tmp_path / "o.h5"
    line = _bad(_cli("import", bag, "--track", NORIS, "-o", out), out, "no position (topic '/odom' or '/pose' not found)")
    assert "/drive (ackermann_msgs/msg/AckermannDriveStamped)" in line


def test_flipped_yaw_rate_sign_is_named(sim, tmp_path):
    rec = write_global_csv(sim, tmp_path / "log.csv", yaw_rate=-sim["run"]["yaw_rate"])
    out = tmp_path / "o.h5"
    _bad(_cli("import", rec, "--track", NORIS, "-o", out), out, "column 'yaw_rate'", "[signs] yaw_rate = -1")


def test_print_map_is_valid_and_round_trips(tmp_path):
    code, out, err = _cli("import", "--print-map")
    assert code == 0, err
    p = tmp_path / "m.toml"
    p.write_text(out)
    from gprace.ingest.mapping import RecordingMap, load_map

    assert load_map(p) == RecordingMap()


def test_mcap_fast_path_equals_rosbags_deserialisation(sim, tmp_path):
    """The vectorised CDR decoder reads the same numbers as rosbags' per-message deserialiser."""
    from gprace.ingest import mcap_fast
    from gprace.ingest.readers import ACKERMANN, IMU, ODOMETRY, _ros_fast, _ros_general

    bag = write_mcap(sim, tmp_path / "bag")
    wanted = {"/odom": ODOMETRY, "/imu": IMU, "/drive": ACKERMANN}
    t_fast, fast = _ros_fast(bag, wanted, True, mcap_fast)
    t_gen, gen = _ros_general(bag, wanted, True)
    assert t_fast == t_gen
    for typ in wanted.values():
        assert set(fast[typ]) == set(gen[typ])
        for k in gen[typ]:
            assert np.array_equal(fast[typ][k], gen[typ][k]), (typ, k)
    assert len(fast[ODOMETRY]["t"]) == len(range(0, sim["run"].n, 3))


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_mcap_fast_path_reads_compressed_chunks(sim, tmp_path, compression):
    """Chunks compressed as `ros2 bag record` writes them decode to the same numbers."""
    import struct

    from gprace.ingest import mcap_fast
    from gprace.ingest.readers import ACKERMANN, IMU, ODOMETRY, _ros_fast

    plain = write_mcap(sim, tmp_path / "bag")
    if compression == "zstd":
        from backports import zstd as z

        squeeze = z.compress
    else:
        import lz4.frame

        squeeze = lz4.frame.compress
    buf = plain.read_bytes()
    out, off = [buf[:8]], 8
    while off + 9 <= len(buf) - 8:  # rewrite every chunk record with compressed records
        op, ln = struct.unpack_from("<BQ", buf, off)
        body = buf[off + 9 : off + 9 + ln]
        if op == 0x06:
            head = body[:28]
            (clen,) = struct.unpack_from("<I", body, 28)
            assert body[32 : 32 + clen] == b""  # rosbags writes uncompressed chunks
            (rlen,) = struct.unpack_from("<Q", body, 32)
            records = squeeze(body[40 : 40 + rlen])
            name = compression.encode()
            body = head + struct.pack("<I", len(name)) + name + struct.pack("<Q", len(records)) + records
        out.append(struct.pack("<BQ", op, len(body)) + body)
        off += 9 + ln
    out.append(buf[off:])
    packed = tmp_path / "packed.mcap"
    packed.write_bytes(b"".join(out))
    assert packed.stat().st_size < 0.8 * plain.stat().st_size
    wanted = {"/odom": ODOMETRY, "/imu": IMU, "/drive": ACKERMANN}
    _, a = _ros_fast(plain, wanted, True, mcap_fast)
    _, b = _ros_fast(packed, wanted, True, mcap_fast)
    for typ in wanted.values():
        for k in a[typ]:
            assert np.array_equal(a[typ][k], b[typ][k]), (typ, k)
