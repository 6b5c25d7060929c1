"""Real logs as they come (issue 36 item 1, issue 38 small contracts): comment preambles, header in
a comment line, BOM / CRLF / ``;`` with decimal commas, long-format telemetry, a drive split into
files with their own clocks, the ``[inputs]`` table and the ``meta["inputs"]`` contract.

Every file is written here from one noise-free Norisring lap simulated by ``gprace simulate``
(the ``sim`` fixture of test_import.py); importing it back must give the same Frenet run.
"""

from __future__ import annotations

import numpy as np
import pytest

from test_import import NORIS, T_OFFSET, _bad, _check_whole_lap, _cli, _compare, sim  # noqa: F401 (fixture)

from gprace.io.runs import read_run

COLS = ("t", "x", "y", "yaw", "v_x", "v_y", "yaw_rate", "delta", "a_x")


def _columns(sim) -> dict[str, np.ndarray]:
    r = sim["run"]
    return {"t": r["t"] + T_OFFSET, "x": sim["x"], "y": sim["y"], "yaw": sim["yaw"], "v_x": r["v_x"],
            "v_y": r["v_y"], "yaw_rate": r["yaw_rate"], "delta": r["delta"], "a_x": r["a_x"]}


def _rows(cols: dict, sep: str = ",", decimal: str = ".") -> list[str]:
    arr = np.column_stack(list(cols.values()))
    out = []
    for row in arr:
        cells = [f"{v:.12g}" for v in row]
        if decimal != ".":
            cells = [c.replace(".", decimal) for c in cells]
        out.append(sep.join(cells))
    return out


def _import_ok(sim, rec, tmp_path, *args):
    out = tmp_path / "imp.h5"
    code, _, err = _cli("import", *([rec] if not isinstance(rec, list) else rec), "--track", NORIS, "-o", out, *args)
    assert code == 0, err
    imp = read_run(out)
    e, idx = _compare(imp, sim["run"], sim["track"])
    _check_whole_lap(imp, sim, e, idx)
    return imp, e, err


def test_comment_preamble_then_header(sim, tmp_path):
    """INI F1TENTH style: eight `#` lines, the last "# Data:", then the header (trailing comma)."""
    cols = _columns(sim)
    pre = ["# This is F1TENTH simulation from 16.01.2026", "# Done with git-revision: 846c", '# Starting position :,"[3.62, 6.26, 0.378]"',
           "# Timestep: 0.01 s", "# Speedfactor 1.0", "# Controller: rpgd", "#", "# Data:"]
    rec = tmp_path / "log.csv"
    rec.write_text("\n".join(pre + [",".join(cols) + ","] + [r + "," for r in _rows(cols)]) + "\n")
    imp, e, _ = _import_ok(sim, rec, tmp_path)
    assert max(e["v_x"], e["yaw_rate"]) < 1e-6


def test_header_in_a_comment_line_with_units_in_the_names(sim, tmp_path):
    """IAC style: `# time(s),x(m),...` is the last comment line; the map names the columns."""
    cols = _columns(sim)
    names = ["time(s)", "x(m)", "y(m)", "phi(rad)", "vx(m/s)", "vy(m/s)", "omega(rad/s)", "delta(rad)", "ax(m/s^2)"]
    rec = tmp_path / "log.csv"
    rec.write_text("# " + ",".join(names) + "\n" + "\n".join(_rows(cols)) + "\n")
    mp = tmp_path / "m.toml"
    mp.write_text("[columns]\n" + "".join(f'{q} = "{n}"\n' for q, n in zip(COLS, names)))
    _import_ok(sim, rec, tmp_path, "--map", mp)


def test_bom_crlf_semicolons_and_decimal_commas(sim, tmp_path):
    cols = _columns(sim)
    rec = tmp_path / "log.csv"
    text = "\r\n".join([";".join(cols)] + _rows(cols, ";", ",")) + "\r\n"
    rec.write_bytes(b"\xef\xbb\xbf" + text.encode())
    imp, e, _ = _import_ok(sim, rec, tmp_path)
    assert max(e["v_x"], e["yaw_rate"]) < 1e-6


def test_long_format_telemetry(sim, tmp_path):
    """One row per channel sample (timestamp, name, value), channels at their own rates, rows
    sorted by time; the map's [columns] are channel names."""
    c = _columns(sim)
    every = {"pos_x": 2, "pos_y": 2, "heading": 2, "vx": 1, "vy": 1, "gyro_z": 1, "steer": 5, "accel": 5}
    src = {"pos_x": c["x"], "pos_y": c["y"], "heading": c["yaw"], "vx": c["v_x"], "vy": c["v_y"],
           "gyro_z": c["yaw_rate"], "steer": c["delta"], "accel": c["a_x"]}
    rows = []
    for name, k in every.items():
        idx = np.arange(0, len(c["t"]), k)
        rows += [(c["t"][i], name, src[name][i]) for i in idx]
    rows.sort(key=lambda r: r[0])
    rec = tmp_path / "long.csv"
    rec.write_text("timestamp,name,value\n" + "".join(f"{t:.12g},{n},{v:.12g}\n" for t, n, v in rows))
    mp = tmp_path / "m.toml"
    mp.write_text('[columns]\nt = "timestamp"\nx = "pos_x"\ny = "pos_y"\nyaw = "heading"\nv_x = "vx"\nv_y = "vy"\n'
                  'yaw_rate = "gyro_z"\ndelta = "steer"\na_x = "accel"\n')
    imp, e, _ = _import_ok(sim, rec, tmp_path, "--map", mp)
    assert e["delta"] < 1e-9 and imp.meta["origins"]["v_x"] == "channel 'vx'"
    # declared explicitly, with other column names
    rec2 = tmp_path / "long2.csv"
    rec2.write_text("stamp;signal;reading\n" + "".join(f"{t:.12g};{n};{v:.12g}\n" for t, n, v in rows))
    mp2 = tmp_path / "m2.toml"
    mp2.write_text('layout = "long"\n' + mp.read_text().replace('t = "timestamp"', 't = "stamp"')
                   + '[long]\nname = "signal"\nvalue = "reading"\n')
    _import_ok(sim, rec2, tmp_path, "--map", mp2)


def test_drive_split_into_files_with_own_clocks(sim, tmp_path):
    """Pose at 50 Hz (seconds), IMU at 100 Hz (nanoseconds, another epoch), commands at 20 Hz
    (milliseconds): merged on one time base through each file's [clocks] table."""
    c = _columns(sim)
    n = len(c["t"])
    pose, imu, cmd = np.arange(0, n, 2), np.arange(n), np.arange(0, n, 5)
    (tmp_path / "pose.csv").write_text("t,x,y,yaw\n" + "".join(
        f"{c['t'][i]:.12g},{c['x'][i]:.12g},{c['y'][i]:.12g},{c['yaw'][i]:.12g}\n" for i in pose))
    epoch_ns = 1_700_000_000_000_000_000
    (tmp_path / "imu.csv").write_text("stamp_ns,v_x,v_y,yaw_rate\n" + "".join(
        f"{epoch_ns + int(round((c['t'][i] - T_OFFSET) * 1e9))},{c['v_x'][i]:.12g},{c['v_y'][i]:.12g},{c['yaw_rate'][i]:.12g}\n" for i in imu))
    (tmp_path / "cmd.csv").write_text("t,delta,a_x\n" + "".join(
        f"{1e3 * c['t'][i]:.12g},{c['delta'][i]:.12g},{c['a_x'][i]:.12g}\n" for i in cmd))
    mp = tmp_path / "m.toml"
    mp.write_text(f'[clocks."imu.csv"]\ncolumn = "stamp_ns"\nunit = "ns"\noffset = {T_OFFSET - epoch_ns * 1e-9!r}\n'
                  '[clocks."cmd.csv"]\nunit = "ms"\n')
    files = [tmp_path / "pose.csv", tmp_path / "imu.csv", tmp_path / "cmd.csv"]
    imp, e, _ = _import_ok(sim, files, tmp_path, "--map", mp)
    assert e["delta"] < 1e-9 and e["yaw_rate"] < 1e-4
    assert imp.meta["origins"]["yaw_rate"].startswith("imu.csv") and len(imp.meta["source_files"]) == 3


def test_inputs_table_and_meta_contract_survive_hdf5_and_csv(sim, tmp_path):
    c = _columns(sim)
    rec = tmp_path / "log.csv"
    np.savetxt(rec, np.column_stack(list(c.values())), delimiter=",", header=",".join(c), comments="", fmt="%.12g")
    # defaults: what gprace's recordings hold
    imp, _, _ = _import_ok(sim, rec, tmp_path)
    assert imp.meta["inputs"] == {"delta": "commanded", "a_x": "commanded"}
    # measured a_x and steering, declared in the map; HDF5 and CSV (sidecar) keep it
    mp = tmp_path / "m.toml"
    mp.write_text('[inputs]\na_x = "measured"\ndelta = "measured"\n')
    for out in (tmp_path / "a.h5", tmp_path / "a.csv"):
        code, _, err = _cli("import", rec, "--track", NORIS, "--map", mp, "-o", out)
        assert code == 0, err
        run = read_run(out)
        assert run.meta["inputs"] == {"delta": "measured", "a_x": "measured"}
        assert run.inputs_kind == {"delta": "measured", "a_x": "measured"}
    # a speed command and no a_x: a_x derived, v_cmd kept as a column
    v_cmd = sim["run"]["v_x"] + 0.5
    c2 = {k: v for k, v in c.items() if k != "a_x"} | {"speed_cmd": v_cmd}
    rec2 = tmp_path / "log2.csv"
    np.savetxt(rec2, np.column_stack(list(c2.values())), delimiter=",", header=",".join(c2), comments="", fmt="%.12g")
    mp2 = tmp_path / "m2.toml"
    mp2.write_text('[columns]\nv_cmd = "speed_cmd"\n')
    out = tmp_path / "b.csv"
    code, _, err = _cli("import", rec2, "--track", NORIS, "--map", mp2, "-o", out)
    assert code == 0, err
    run = read_run(out)
    assert run.meta["inputs"] == {"delta": "commanded", "a_x": "derived", "v_cmd": "commanded"}
    idx = np.rint((run["t"] + run.meta["t0"] - T_OFFSET) / 0.01).astype(int)
    assert np.abs(run["v_cmd"] - v_cmd[idx]).max() < 1e-7  # CSV keeps 10 digits
    # a CSV changed after it was written no longer takes its stale sidecar
    text = out.read_text().splitlines()
    out.write_text("\n".join(text[:-1]) + "\n")
    assert "inputs" not in read_run(out).meta
    # a run without the key reads as commanded
    from gprace.io.runs import Run

    assert Run(dict(sim["run"].data), {}, "x").inputs_kind == {"delta": "commanded", "a_x": "commanded"}


def test_map_paths_are_relative_to_the_map(sim, tmp_path, monkeypatch):
    import shutil

    c = _columns(sim)
    (tmp_path / "maps").mkdir()
    shutil.copy(NORIS, tmp_path / "maps" / "circuit.csv")
    mp = tmp_path / "maps" / "m.toml"
    mp.write_text('track = "circuit.csv"\n')
    rec = tmp_path / "log.csv"
    np.savetxt(rec, np.column_stack(list(c.values())), delimiter=",", header=",".join(c), comments="", fmt="%.12g")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    code, out, err = _cli("import", rec, "--map", mp, "-o", tmp_path / "r.h5")
    assert code == 0, err
    run = read_run(tmp_path / "r.h5")
    assert run.meta["reference"] == "track" and run.meta["track_name"] == "circuit"


def test_constant_channels_are_named_and_derived(sim, tmp_path):
    """a_x all zeros while v_x changes, a yaw-rate column of zeros: both named, both derived."""
    c = _columns(sim)
    c["a_x"] = np.zeros_like(c["a_x"])
    c["yaw_rate"] = np.zeros_like(c["yaw_rate"])
    rec = tmp_path / "log.csv"
    np.savetxt(rec, np.column_stack(list(c.values())), delimiter=",", header=",".join(c), comments="", fmt="%.12g")
    out = tmp_path / "r.h5"
    code, _, err = _cli("import", rec, "--track", NORIS, "-o", out)
    assert code == 0, err
    assert "column 'a_x' is constant (0): left out, a_x from the change of v_x" in err
    assert "column 'yaw_rate' is constant (0): left out, yaw_rate from the heading" in err
    run = read_run(out)
    assert run.meta["inputs"]["a_x"] == "derived"
    idx = np.rint((run["t"] + run.meta["t0"] - T_OFFSET) / 0.01).astype(int)
    assert np.median(np.abs(run["yaw_rate"] - sim["run"]["yaw_rate"][idx])) < 0.01


@pytest.mark.parametrize("unit,factor", [("ns", 1e9), ("us", 1e6), ("ms", 1e3)])
def test_time_in_ns_us_ms_undeclared_gets_the_hint(sim, tmp_path, unit, factor):
    c = _columns(sim)
    c["t"] = factor * c["t"]
    rec = tmp_path / "log.csv"
    np.savetxt(rec, np.column_stack(list(c.values())), delimiter=",", header=",".join(c), comments="", fmt="%.15g")
    out = tmp_path / "o.h5"
    _bad(_cli("import", rec, "--track", NORIS, "-o", out), out, f"time stamps look like {unit}", f'[units] t = "{unit}"')


def test_map_naming_a_column_the_file_lacks(sim, tmp_path):
    c = _columns(sim)
    rec = tmp_path / "log.csv"
    np.savetxt(rec, np.column_stack(list(c.values())), delimiter=",", header=",".join(c), comments="", fmt="%.12g")
    mp = tmp_path / "m.toml"
    mp.write_text('[columns]\nyaw_rate = "gyro_z"\n')
    out = tmp_path / "o.h5"
    _bad(_cli("import", rec, "--track", NORIS, "--map", mp, "-o", out), out, "'gyro_z'", "[columns] yaw_rate", "lacks", "columns present: t, x")


def test_clock_running_backwards_in_one_file_of_several(sim, tmp_path):
    c = _columns(sim)
    t = c["t"].copy()
    t[300], t[301] = t[301], t[300]
    (tmp_path / "pose.csv").write_text("t,x,y,yaw\n" + "".join(f"{a:.12g},{b:.12g},{d:.12g},{e:.12g}\n" for a, b, d, e in zip(c["t"], c["x"], c["y"], c["yaw"])))
    (tmp_path / "imu.csv").write_text("t,v_x,v_y,yaw_rate,delta,a_x\n" + "".join(
        f"{t[i]:.12g},{c['v_x'][i]:.12g},{c['v_y'][i]:.12g},{c['yaw_rate'][i]:.12g},{c['delta'][i]:.12g},{c['a_x'][i]:.12g}\n" for i in range(len(t))))
    out = tmp_path / "o.h5"
    _bad(_cli("import", tmp_path / "pose.csv", tmp_path / "imu.csv", "--track", NORIS, "-o", out), out,
         "imu.csv", "time stamps go backwards", "row 302 (line 303)")


def test_print_map_documents_the_new_tables():
    code, out, err = _cli("import", "--print-map")
    assert code == 0, err
    assert "[inputs]" in out and 'a_x = "commanded"' in out and "v_cmd" in out and "[clocks." in out


# ------------------------------------------------------------------------------------------------
# projections that can be trusted (issue 38 item 4) and bad input (issue 36)


def _write(cols: dict, path):
    np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
    return path


def test_a_log_of_another_circuit_is_refused(sim, tmp_path):
    from test_import import TRACKS

    rec = _write(_columns(sim), tmp_path / "log.csv")
    out = tmp_path / "o.h5"
    line = _bad(_cli("import", rec, "--track", TRACKS / "Monza.csv", "-o", out), out, "'Monza'", "another circuit")
    assert "lie off track" in line or "does not drive along" in line


def test_position_glitch_and_lasting_jump(sim, tmp_path):
    """A 450 m glitch of one sample is dropped; a lasting 450 m jump (a re-fix in another frame)
    for the last fifth of the drive is cut as off the track; s stays continuous before it."""
    c = _columns(sim)
    n = len(c["t"])
    x = c["x"].copy()
    x[5 * (n // 15)] += 450.0  # on a sample the 0.05 s grid meets
    x[int(0.8 * n):] += 450.0
    c["x"] = x
    rec = _write(c, tmp_path / "log.csv")
    out = tmp_path / "r.h5"
    code, _, err = _cli("import", rec, "--track", NORIS, "-o", out)
    assert code == 0, err
    assert "positions jump 3 time(s) further than the speed allows (largest 45" in err
    assert "1 glitch sample(s) left out, 1 break(s)" in err and "off track Norisring" in err and "left out" in err
    run = read_run(out)
    assert run["t"][-1] < 0.8 * (sim["run"]["t"][-1]) + 0.1  # the jumped part is gone
    e, _ = _compare(run, sim["run"], sim["track"])
    assert e["e_y"] < 0.05 and e["s"] < 0.1  # what is kept is exact
    assert abs(run.n - 0.8 * n / 5) < 3


def test_pit_lane_stretch_is_cut_with_a_note(sim, tmp_path):
    c = _columns(sim)
    t = sim["run"]["t"]
    r = sim["run"]
    trk = sim["track"]
    ramp = np.clip(np.minimum(t - 19.0, 27.0 - t), 0.0, 1.0)  # 1 s in, 6 s out there, 1 s back
    off = ramp * (trk.width_left(r["s"]) + trk.width_right(r["s"]))  # half a width beyond the border
    h = trk.heading(r["s"])
    c["x"] = c["x"] - np.sin(h) * off
    c["y"] = c["y"] + np.cos(h) * off
    rec = _write(c, tmp_path / "log.csv")
    out = tmp_path / "r.h5"
    code, _, err = _cli("import", rec, "--track", NORIS, "-o", out)
    assert code == 0, err
    assert "1 stretch(es) off track Norisring" in err and "a pit lane?) left out" in err
    run = read_run(out)
    assert not np.any((run["t"] > 20.2) & (run["t"] < 25.8)) and run.meta["gaps"] >= 1
    keep = (tmp_path / "k.toml")
    keep.write_text('off_track = "keep"\n')
    code, _, err = _cli("import", rec, "--track", NORIS, "--map", keep, "-o", tmp_path / "k.h5")
    assert code == 0 and "kept (off_track" in err


def test_a_recording_with_no_moving_sample(sim, tmp_path):
    c = _columns(sim)
    for q in ("x", "y", "yaw"):
        c[q] = np.full_like(c[q], c[q][0])
    for q in ("v_x", "v_y", "yaw_rate", "a_x"):
        c[q] = np.zeros_like(c[q])
    rec = _write(c, tmp_path / "log.csv")
    out = tmp_path / "o.h5"
    _bad(_cli("import", rec, "--track", NORIS, "-o", out), out, "no moving sample", "stands still")
    _bad(_cli("import", rec, "-o", out), out, "no moving sample")
