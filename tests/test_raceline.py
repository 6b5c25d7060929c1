"""Racelines in TUM's and the INI F1TENTH stack's formats: conventions, round trips, bad files (issue 39)."""

from __future__ import annotations

import numpy as np
import pytest
from shared_data import REAL_LOGS, TUM_TRACKS

from gprace.errors import InputError
from gprace.plan.raceline import plan_of_raceline
from gprace.tracks.raceline import (
    FORMATS,
    Raceline,
    project_raceline,
    raceline_of_plan,
    raceline_summary,
    raceline_track,
    read_raceline,
    write_raceline,
)

INI = REAL_LOGS / "ini_f1tenth_ipz20"


def _circle(radius=20.0, n=200, v=10.0, ccw=True) -> Raceline:
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    sign = 1.0 if ccw else -1.0
    x, y = radius * np.cos(sign * th), radius * np.sin(sign * th)
    heading = sign * th + sign * np.pi / 2
    L = 2 * np.pi * radius
    return Raceline(s=th * radius, x=x, y=y, psi=(heading - np.pi / 2 + np.pi) % (2 * np.pi) - np.pi,
                    kappa=np.full(n, sign / radius), vx=np.full(n, v), ax=np.zeros(n), length=L,
                    d_right=np.full(n, 2.0), d_left=np.full(n, 3.0))


def test_heading_zero_points_north_and_loop_closes(tmp_path):
    """On a counter-clockwise circle starting east of the centre the path heads north: psi = 0
    (TUM: zero along +y); the written file repeats its first point with s = the loop length."""
    rl = _circle()
    assert rl.psi[0] == pytest.approx(0.0, abs=1e-12)
    p = write_raceline(tmp_path / "c.csv", rl, "tum", ("made by a test",))
    lines = p.read_text().splitlines()
    assert lines[0] == "# made by a test"
    assert lines[1] == "# s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2"
    first, last = (np.array([float(v) for v in ln.split(";")]) for ln in (lines[2], lines[-1]))
    assert last[0] == pytest.approx(rl.length, abs=1e-6)
    np.testing.assert_allclose(last[1:], first[1:], atol=1e-7)
    back = read_raceline(p)
    assert back.length == pytest.approx(rl.length, abs=1e-6)
    assert back.lap_time == pytest.approx(rl.length / 10.0, rel=1e-9)
    dx, dy = np.roll(rl.x, -1) - np.roll(rl.x, 1), np.roll(rl.y, -1) - np.roll(rl.y, 1)
    np.testing.assert_allclose(np.exp(1j * back.heading), np.exp(1j * np.arctan2(dy, dx)), atol=1e-3)


def test_ipz20_waypoints_round_trip_exactly(tmp_path):
    """The INI file read, written in its own format and read again: the same numbers and header."""
    rl = read_raceline(INI / "IPZ20_wp.csv")
    assert rl.fmt == "f1tenth" and rl.n == 253 and rl.length == pytest.approx(25.217268)
    # its conventions are TUM's: psi is the path heading minus pi/2, kappa its curvature
    dx, dy = np.gradient(rl.x), np.gradient(rl.y)
    off = np.angle(np.exp(1j * (rl.psi - (np.arctan2(dy, dx) - np.pi / 2))))
    assert np.max(np.abs(off)) < 0.05
    out = write_raceline(tmp_path / "wp.csv", rl, "f1tenth")
    assert out.read_text().splitlines()[0] == (INI / "IPZ20_wp.csv").read_text().splitlines()[0]
    back = read_raceline(out)
    for k in ("s", "x", "y", "psi", "kappa", "vx", "ax", "d_right", "d_left"):
        np.testing.assert_allclose(getattr(back, k), getattr(rl, k), atol=1e-6)


def test_plan_to_tum_raceline_and_back_on_a_tum_circuit(tmp_path, audi):
    """A plan of Norisring written as a TUM raceline and read back as a plan: the same line
    (e_y within 1 cm), speeds within 0.1 m/s, lap time within 0.05 %, inside the track."""
    from gprace.model import NominalModel
    from gprace.plan import curvature_plan
    from gprace.tracks import load_track

    track = load_track(TUM_TRACKS / "Norisring.csv")
    model = NominalModel(audi)
    plan = curvature_plan(track, model, ds=6.0, speed_scale=0.7)
    rl = raceline_of_plan(plan, track)
    path = write_raceline(tmp_path / "r.csv", rl, "tum")
    back = plan_of_raceline(read_raceline(path), track, model, ds=6.0)
    assert back.track_hash == plan.track_hash and back.n == plan.n
    assert np.max(np.abs(back.e_y - plan.e_y)) < 0.01
    assert np.max(np.abs(back.v_x - plan.v_x)) < 0.1
    assert back.lap_time == pytest.approx(plan.lap_time, rel=5e-4)
    info = raceline_summary(read_raceline(path), track, 0.5 * audi.width)
    assert info["inside"] and not info["against_track_direction"]


def test_ipz20_on_its_centre_line_runs_against_it(audi):
    """The INI raceline runs against the direction of the INI centre line file: read back as a
    plan it lies on the reversed track, once round, inside its borders."""
    from pathlib import Path

    from gprace.config import load_vehicle
    from gprace.model import NominalModel
    from gprace.tracks import load_track

    track = load_track(INI / "centerline.csv")
    rl = read_raceline(INI / "IPZ20_wp.csv")
    on = project_raceline(rl, track)
    assert on.reversed
    assert on.s[-1] - on.s[0] == pytest.approx(track.length, rel=0.02)
    vehicle = load_vehicle(Path(__file__).parents[1] / "benchmarks" / "data" / "ini_f1tenth.toml")
    plan = plan_of_raceline(rl, track, NominalModel(vehicle))
    assert plan.meta["reversed"] and plan.track_hash == __import__("gprace.plan", fromlist=["track_hash"]).track_hash(track.reversed())
    assert plan.lap_time == pytest.approx(rl.lap_time, rel=0.05)
    info = raceline_summary(rl, track, 0.5 * vehicle.width)
    assert info["inside"]


def test_f1tenth_file_is_a_track():
    """An F1TENTH waypoint file carries the borders: it loads as a track of its own."""
    from gprace.tracks import load_track

    rl = read_raceline(INI / "IPZ20_wp.csv")
    t = raceline_track(rl)
    assert t.length == pytest.approx(rl.length, rel=1e-3)
    lo, hi = t.width_range
    assert lo == pytest.approx(float(np.min(rl.d_left + rl.d_right)), rel=0.02)
    t2 = load_track(INI / "IPZ20_wp.csv")
    assert t2.length == pytest.approx(t.length)


@pytest.mark.parametrize("header, why", [
    ("# s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps", "missing ax_mps2"),
    ("s_m,x_m,y_m,psi_rad,kappa_radpm,vx_mps,ax_mps2,d_right_iqp,d_left_m", "missing d_left_iqp; unexpected d_left_m"),
    ("# s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2; w_tr_right_m", "unexpected w_tr_right_m"),
])
def test_columns_that_do_not_match_a_format_are_named(tmp_path, header, why):
    n = len(header.lstrip("# ").replace(";", ",").split(","))
    sep = "; " if ";" in header else ","
    rows = [sep.join(["1.0"] * n) for _ in range(6)]
    p = tmp_path / "bad.csv"
    p.write_text(header + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(InputError, match=why):
        read_raceline(p)


def test_a_raceline_of_another_track_is_refused():
    from gprace.tracks import load_track

    rl = read_raceline(INI / "IPZ20_wp.csv")
    with pytest.raises(InputError, match="another track"):
        project_raceline(rl, load_track(TUM_TRACKS / "Norisring.csv"))


def test_formats_are_the_published_ones():
    assert FORMATS["tum"] == ("s_m", "x_m", "y_m", "psi_rad", "kappa_radpm", "vx_mps", "ax_mps2")
    assert FORMATS["f1tenth"][-2:] == ("d_right_iqp", "d_left_iqp")


@pytest.mark.parametrize("command", [
    ["track", "show", "{f}"],
    ["run", "--plan", "{f}", "--track", "{t}", "--vehicle", "audi_tt_cup", "--plant", "audi_nominal", "-o", "{d}/r.h5"],
    ["plan", "--warm-start", "{f}", "--track", "{t}", "--vehicle", "audi_tt_cup", "--ds", "0.5", "-o", "{d}/p.h5"],
])
def test_every_reader_of_a_raceline_refuses_wrong_columns_in_one_line(tmp_path, capsys, command):
    """The IPZ20 waypoints with a renamed speed column, given where gprace reads racelines: exit 2,
    one error line naming the column, nothing written."""
    from gprace.cli import main

    lines = (INI / "IPZ20_wp.csv").read_text().splitlines()
    f = tmp_path / "wp.csv"
    f.write_text("\n".join([lines[0].replace("vx_mps", "speed_mps")] + lines[1:]) + "\n")
    args = [a.format(f=f, t=INI / "centerline.csv", d=tmp_path) for a in command]
    assert main(args) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error:") and "missing vx_mps; unexpected speed_mps" in err[0]
    assert not (tmp_path / "r.h5").exists() and not (tmp_path / "p.h5").exists()
