"""Tracks: geometry checks against closed forms, real circuits, Frenet round trips, loaders."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from gprace.cli import main
from gprace.errors import ConfigError, InputError
from gprace.tracks import DEFAULT_TRACK, Track, load_track, random_track, shipped_tracks
from gprace.tracks.loaders import load_tum_csv
from gprace.tracks.random import random_track_spec

from shared_data import TUM_TRACKS

TUM_DIR = Path(os.environ.get("GPRACE_TUM_TRACKS", TUM_TRACKS))
REAL = sorted(TUM_DIR.glob("*.csv"))


def test_real_circuits_present():
    assert len(REAL) == 25, f"expected the 25 TUM circuits in {TUM_DIR} (set GPRACE_TUM_TRACKS)"


@pytest.fixture
def rebind_console(capsys, monkeypatch):
    """The rich consoles keep the streams of import time; make them follow sys.stdout/stderr."""
    from gprace.console import console

    monkeypatch.setattr(console.out, "_file", None)
    monkeypatch.setattr(console.err, "_file", None)
    monkeypatch.setattr(console.err, "stderr", True)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# ---------------------------------------------------------------------------------------------
# CLI on every real circuit and the shipped tracks


@pytest.mark.parametrize("path", REAL + [Path(n) for n in ("gprace_ring", "h2h_loop", "circle_100")], ids=lambda p: p.stem)
def test_track_show(path, capsys):
    assert main(["track", "show", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["closed"] is True
    assert info["min_radius_m"] > 0 and info["width_min_m"] > 0
    if path.suffix == ".csv":
        raw = np.loadtxt(path, delimiter=",", comments="#")
        assert info["n_points"] == len(raw)
        # the spline length equals the closed polyline length up to chord-vs-arc and smoothing
        poly = np.sum(np.hypot(*np.diff(np.vstack([raw[:, :2], raw[:1, :2]]), axis=0).T))
        assert abs(info["length_m"] - poly) < 2e-3 * poly
        assert 2000 < info["length_m"] < 7500
        assert info["width_min_m"] == pytest.approx((raw[:, 2] + raw[:, 3]).min(), rel=1e-3)


def test_track_show_text_and_plot(tmp_path, capsys, rebind_console):
    png = tmp_path / "suzuka.png"
    assert main(["track", "show", str(TUM_DIR / "Suzuka.csv"), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "Suzuka (closed)" in out and "min radius" in out and "length      5803" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_track_show_bad_file_is_one_line_exit_2(tmp_path, capsys, rebind_console):
    bad = _write(tmp_path, "bad.csv", "# x_m,y_m,w_tr_right_m,w_tr_left_m\n1,2,3,4\n1,2,nan,4\n")
    assert main(["track", "show", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "bad.csv" in err and "row 2 (line 3)" in err and "w_tr_right_m" in err
    assert main(["track", "show", "no_such_track"]) == 2
    assert "gprace_ring" in capsys.readouterr().err  # the message lists the shipped tracks


# ---------------------------------------------------------------------------------------------
# shipped tracks


def test_shipped_tracks():
    assert DEFAULT_TRACK == "gprace_ring"
    assert {"gprace_ring", "h2h_loop", "circle_100"} <= set(shipped_tracks())
    ring = load_track("gprace_ring")
    assert ring.closed and 2000 < ring.length < 2500
    assert ring.min_radius >= 15.0
    assert 10.0 <= ring.width_range[0] <= ring.width_range[1] <= 12.0
    h2h = load_track("h2h_loop")
    assert h2h.closed and 35.0 < h2h.length < 37.0 and h2h.width_range == (1.5, 1.5)
    assert h2h.min_radius >= 0.5
    # a closed loop turns exactly once: the integral of the curvature is 2 pi
    for trk in (ring, h2h):
        s, k = trk.kappa_table()
        assert np.trapezoid(k, s) == pytest.approx(2 * np.pi, abs=1e-3)


def test_circle_curvature_length_and_frenet_closed_form():
    c = load_track("circle_100")
    s = np.linspace(0, c.length, 777)
    assert c.length == pytest.approx(2 * np.pi * 100, rel=1e-9)
    np.testing.assert_allclose(c.kappa(s), 0.01, rtol=1e-5)
    # starts at the origin heading +x turning left: the centre is (0, 100)
    phi = np.linspace(-3, 3, 50)
    rho = np.linspace(95, 105, 50)
    x, y = rho * np.sin(phi), 100 - rho * np.cos(phi)
    s_f, e_f = c.to_frenet(x, y)
    np.testing.assert_allclose(e_f, 100 - rho, atol=1e-6)
    np.testing.assert_allclose(s_f, np.mod(100 * phi, c.length), atol=1e-5)


@pytest.mark.parametrize("angle, sign", [(90.0, 1.0), (-90.0, -1.0)])
def test_arc_curvature_sign_and_heading(tmp_path, angle, sign):
    p = _write(
        tmp_path,
        "bend.toml",
        f"""closed = false
width = 6.0
[[segments]]
type = "straight"
length = 30.0
[[segments]]
type = "arc"
radius = 20.0
angle_deg = {angle}
[[segments]]
type = "straight"
length = 30.0
""",
    )
    t = load_track(p)
    assert not t.closed and t.length == pytest.approx(60 + 10 * np.pi, rel=1e-4)
    assert t.kappa(30 + 5 * np.pi) == pytest.approx(sign / 20, rel=1e-3)
    assert t.kappa(10.0) == pytest.approx(0.0, abs=1e-6)
    assert t.heading(t.length) - t.heading(0.0) == pytest.approx(sign * np.pi / 2, abs=1e-6)
    # e_y > 0 is to the left: for a left turn the inside of the bend
    sm = 30 + 5 * np.pi
    x, y = t.to_global(sm, 2.0)
    cx, cy = t.to_global(sm, 1 / t.kappa(sm))  # centre of curvature
    assert np.hypot(x - cx, y - cy) == pytest.approx(20 - sign * 2, rel=1e-3)
    # open track: points beyond the ends continue along the end tangents
    s = np.array([-3.0, 1.0, t.length - 1, t.length + 4])
    e = np.array([0.5, -1.0, 2.0, -0.5])
    s2, e2 = t.to_frenet(*t.to_global(s, e))
    np.testing.assert_allclose(s2, s, atol=1e-7)
    np.testing.assert_allclose(e2, e, atol=1e-7)


def test_segment_curvature_is_exact_inside_arcs_and_ramped_at_joins():
    ring = load_track("gprace_ring")
    # hairpin R 18 starts at 413.758376 + 35*95deg + 90 + 120*35deg + 150*30deg + 180 + 70*90deg
    #   + 250 + chicane(2*30*25deg + 12) + 150 + 50*90deg + 60
    arcs = np.deg2rad([95, 35, 30, 90, 25, 25, 90]) * np.array([35, 120, 150, 70, 30, 30, 50])
    start = 413.758376 + 90 + 180 + 250 + 12 + 150 + 60 + arcs.sum()
    mid = start + 18 * np.pi / 2
    s = mid + np.linspace(-20, 20, 41)
    np.testing.assert_allclose(ring.kappa(s), 1 / 18, rtol=2e-3)
    # no overshoot of the spline at the curvature ramps
    assert ring.max_abs_kappa <= (1 / 18) * 1.015


# ---------------------------------------------------------------------------------------------
# Frenet <-> global on real tracks


def _inside_points(track: Track, n: int, rng, share: float = 0.9):
    s = rng.uniform(0, track.length, n)
    f = rng.uniform(-share, share, n)
    e = np.where(f > 0, f * track.width_left(s), f * track.width_right(s))
    k = track.kappa(s)
    e = np.where(e * k > 0.8, 0.8 / k, e)  # stay on the near side of the centre of curvature
    return s, e


@pytest.mark.parametrize("path", REAL, ids=lambda p: p.stem)
def test_frenet_round_trip_real(path):
    rng = np.random.default_rng(len(path.stem))
    t = load_track(path)
    s, e = _inside_points(t, 400, rng)
    x, y = t.to_global(s, e)
    hint = t.wrap(s + rng.uniform(-5, 5, len(s)))
    s2, e2 = t.to_frenet(x, y, s_hint=hint)
    assert np.max(np.abs(t._ds(s2, s))) < 1e-3
    assert np.max(np.abs(e2 - e)) < 1e-3
    if path.stem != "Suzuka":  # without a hint only where the centre line does not cross itself
        s3, e3 = t.to_frenet(x, y)
        assert np.max(np.abs(t._ds(s3, s))) < 1e-3 and np.max(np.abs(e3 - e)) < 1e-3
    # global -> Frenet -> global returns the point for any projection
    xb, yb = t.to_global(s2, e2)
    assert np.max(np.hypot(xb - x, yb - y)) < 1e-6


def test_suzuka_crossing_follows_path_order():
    t = load_track(TUM_DIR / "Suzuka.csv")
    smp = t.sample(1.0)
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.column_stack([smp.x, smp.y])).query_pairs(3.0, output_type="ndarray")
    far = pairs[np.abs(t._ds(smp.s[pairs[:, 0]], smp.s[pairs[:, 1]])) > 500]
    assert len(far) > 0, "Suzuka's centre line should cross itself"
    i, j = far[np.argmin(np.hypot(smp.x[far[:, 0]] - smp.x[far[:, 1]], smp.y[far[:, 0]] - smp.y[far[:, 1]]))]
    sa, sb = smp.s[i], smp.s[j]
    # points around the crossing on branch A and on branch B, each with its own branch as hint
    d = np.linspace(-15, 15, 31)
    for s0 in (sa, sb):
        s = t.wrap(s0 + d)
        e = np.linspace(-3, 3, 31)
        x, y = t.to_global(s, e)
        s2, e2 = t.to_frenet(x, y, s_hint=t.wrap(s + 2.0))
        np.testing.assert_allclose(t._ds(s2, s), 0, atol=1e-3)
        np.testing.assert_allclose(e2, e, atol=1e-3)
    # the same point at the crossing resolves to the branch of the hint
    x, y = t.to_global(sa, 0.0)
    assert abs(t._ds(t.to_frenet(x, y, s_hint=sa)[0], sa)) < 1e-3
    assert abs(t._ds(t.to_frenet(x, y, s_hint=sb)[0], sb)) < 5.0


def test_frenet_shapes_and_scalars():
    t = load_track("h2h_loop")
    s, e = t.to_frenet(*t.to_global(3.0, 0.2))
    assert np.shape(s) == () and s == pytest.approx(3.0, abs=1e-9) and e == pytest.approx(0.2, abs=1e-9)
    S = np.linspace(0, t.length, 12).reshape(3, 4)
    x, y = t.to_global(S, 0.1)
    s2, e2 = t.to_frenet(x, y, s_hint=S)
    assert s2.shape == (3, 4) and np.allclose(t._ds(s2, t.wrap(S)), 0, atol=1e-9)
    assert np.all(t.wrap([-1.0, t.length + 1.0]) == pytest.approx([t.length - 1.0, 1.0]))


# ---------------------------------------------------------------------------------------------
# smoothing and tables


def test_smoothing_keeps_a_noisy_circle_radius():
    """OSM-like points (5 m apart, 5 cm noise) on a circle of 40 m: curvature recovered to 1 %."""
    rng = np.random.default_rng(3)
    phi = np.linspace(0, 2 * np.pi, int(2 * np.pi * 40 / 5), endpoint=False)
    x = 40 * np.cos(phi) + rng.normal(0, 0.05, len(phi))
    y = 40 * np.sin(phi) + rng.normal(0, 0.05, len(phi))
    w = np.full(len(phi), 5.0)
    raw = Track(x, y, w, w, closed=True, smoothing=0.0)
    smooth = Track(x, y, w, w, closed=True, smoothing=5.0)
    k_raw, k_s = raw.sample(0.5).kappa, smooth.sample(0.5).kappa
    assert np.mean(k_s) == pytest.approx(1 / 40, rel=1e-2)
    assert np.max(np.abs(k_s - 1 / 40)) < 0.3 * np.max(np.abs(k_raw - 1 / 40))
    # the borders stay where the points put them: widths absorb the moved centre line
    assert smooth.smoothing_shift > 0.02
    smp = smooth.sample(1.0)
    for sign, w in ((1, smp.wl), (-1, smp.wr)):
        s_b, e_b = raw.to_frenet(*smooth.to_global(smp.s, sign * w))
        err = np.abs(sign * e_b - 5.0)  # without the width correction it would be the shift
        assert np.max(err) < 0.2 * smooth.smoothing_shift and np.median(err) < 5e-3


def test_smoothing_keeps_borders_of_a_real_track():
    path = TUM_DIR / "Monza.csv"
    raw = np.loadtxt(path, delimiter=",", comments="#")
    t = load_tum_csv(path)
    assert t.smoothing_shift > 0.05  # the smoothing really moved the line
    p = raw[:, :2]
    tang = np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)
    tang /= np.hypot(*tang.T)[:, None]
    nrm = np.column_stack([-tang[:, 1], tang[:, 0]])
    for sign, col, fn in ((1, 3, t.width_left), (-1, 2, t.width_right)):
        border = p + sign * raw[:, col][:, None] * nrm
        s_b, e_b = t.to_frenet(border[:, 0], border[:, 1])
        err = np.abs(sign * e_b - fn(s_b))
        assert np.median(err) < 0.02 and np.percentile(err, 95) < 0.15


def test_sample_is_arc_length_and_heading_integrates_kappa():
    t = load_track(TUM_DIR / "Spa.csv")
    smp = t.sample(0.5)
    ds = np.diff(smp.s)
    chord = np.hypot(np.diff(smp.x), np.diff(smp.y))
    km = 0.5 * (smp.kappa[1:] + smp.kappa[:-1])
    np.testing.assert_allclose(chord, ds * (1 - (km * ds) ** 2 / 24), rtol=2e-4)
    np.testing.assert_allclose(np.diff(smp.heading), 0.5 * ds * (smp.kappa[1:] + smp.kappa[:-1]), atol=2e-4)
    assert abs(smp.heading[-1] - smp.heading[0]) == pytest.approx(2 * np.pi, abs=0.02)  # Spa runs clockwise
    x, y = t.to_global(smp.s, 0.0)
    assert np.allclose(x, smp.x) and np.allclose(y, smp.y)


def test_kappa_table_and_casadi_interpolant():
    t = load_track("h2h_loop")
    s, k = t.kappa_table()
    assert s[0] == 0 and s[-1] == pytest.approx(t.length) and k[0] == k[-1]
    f = t.casadi_kappa()
    q = np.random.default_rng(0).uniform(0, t.length, 300)
    got = np.array(f(q.reshape(1, -1))).ravel()
    assert np.max(np.abs(got - t.kappa(q))) < 0.02 * t.max_abs_kappa
    lin = t.casadi_kappa(method="linear")
    assert float(lin(s[7])) == pytest.approx(k[7])
    with pytest.raises(InputError):
        t.casadi_kappa(method="cubic")


# ---------------------------------------------------------------------------------------------
# random tracks


def test_random_track_is_deterministic_and_in_range():
    a, b, c = random_track(11), random_track(11), random_track(12)
    assert not a.closed and a.name == "random-11"
    for u, v in zip(a.sample(0.05), b.sample(0.05)):
        assert np.array_equal(u, v)
    assert a.length != c.length
    for seed in range(20):
        spec = random_track_spec(seed)
        segs = spec.segments
        assert segs[0].type == "straight" and segs[0].length == 2.0
        for g in segs[1:]:
            if g.type == "arc":
                assert 0.39 <= g.radius <= 0.79 and np.pi / 5 <= abs(g.theta) <= np.pi / 1.2
            elif g.type == "chicane":
                assert 0.375 <= g.radius <= 1.5 and np.pi / 7 <= abs(g.theta) <= np.pi / 3 and g.gap == 0.5
        t = random_track(seed, width=0.75)
        assert t.width_range == (0.75, 0.75)
        assert t.min_radius >= 0.375 * 0.98
    sides = {np.sign(g.theta) for s in range(20) for g in random_track_spec(s).segments if g.type != "straight"}
    assert sides == {-1.0, 1.0}


def test_random_track_bad_arguments():
    with pytest.raises(InputError, match="n_stretches"):
        random_track(0, n_stretches=0)
    with pytest.raises(InputError, match="unknown stretch kind"):
        random_track(0, kinds=("loop",))


# ---------------------------------------------------------------------------------------------
# bad input: CSV

HEADER = "# x_m,y_m,w_tr_right_m,w_tr_left_m\n"
ROWS = "".join(f"{10 * np.cos(a):.6f},{10 * np.sin(a):.6f},2.0,2.5\n" for a in np.linspace(0, 6, 12))


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "empty file"),
        ("\n\n", "empty file"),
        (HEADER, "no data rows"),
        ("".join(",".join(r.split(",")[:3]) + "\n" for r in ROWS.splitlines()), "3 columns without a header: a boundary polyline"),
        ("1,2,3,4,5\n2,3,4,5,6\n", "5 columns and no header"),
        ("# x_m,y_m,w_tr_right_m\n1,2,3\n", "missing column.*w_tr_left_m"),
        ("# x_m,y_m,w_right,w_left\n1,2,3,4\n", "wrong columns"),
        (HEADER + ROWS + "3.0,4.0\n", r"row 13 \(line 14\) has 2 fields, the header has 4 \(truncated"),
        (HEADER + ROWS + "3.0,4.0,1.0,", r"row 13 \(line 14\), column w_tr_left_m: empty cell"),
        (HEADER + ROWS.replace("2.0,2.5", "nan,2.5", 1), r"row 1 \(line 2\), column w_tr_right_m: value is not finite"),
        (HEADER + ROWS.replace("2.0,2.5", "2.0,inf", 1), r"row 1 \(line 2\), column w_tr_left_m: value is not finite"),
        (HEADER + ROWS.replace("10.000000,", "-Infinity,", 1), r"row 1 \(line 2\), column x_m: value is not finite"),
        (HEADER + ROWS.replace("10.000000,", "abc,", 1), r"column 'x_m' row 1 \(line 2\): 'abc' is not a number"),
        (HEADER + ROWS.replace("2.0,2.5", "0.0,2.5", 1), r"row 1 \(line 2\), column w_tr_right_m: width must be positive"),
        (HEADER + "0,0,1,1\n1,0,1,1\n1,1,1,1\n", "only 3 data rows"),
        (HEADER + ROWS.splitlines(True)[0] + ROWS, r"row 1 \(line 2\) and row 2 \(line 3\): the same point twice"),
    ],
)
def test_csv_bad_input(tmp_path, text, match):
    p = _write(tmp_path, "t.csv", text)
    with pytest.raises(InputError, match=match) as exc:
        load_track(p)
    assert str(p) in str(exc.value) and "\n" not in str(exc.value)


def test_csv_formats_accepted(tmp_path):
    # header without '#', columns reordered, ends several metres apart (implicitly closed),
    # or the first point repeated at the end: all the same loop
    pts = [(10 * np.cos(a), 10 * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 40, endpoint=False)]
    a = _write(tmp_path, "a.csv", HEADER + "".join(f"{x},{y},2,3\n" for x, y in pts))
    b = _write(tmp_path, "b.csv", "w_tr_left_m, x_m, y_m, w_tr_right_m\n" + "".join(f"3,{x},{y},2\n" for x, y in pts))
    c = _write(tmp_path, "c.csv", HEADER + "".join(f"{x},{y},2,3\n" for x, y in pts + pts[:1]))
    ta, tb, tc = (load_tum_csv(p, smoothing=0.0) for p in (a, b, c))
    for t in (tb, tc):
        assert t.length == pytest.approx(ta.length, rel=1e-12)
        assert t.width_left(1.0) == pytest.approx(3.0) and t.width_right(1.0) == pytest.approx(2.0)
    assert ta.length == pytest.approx(2 * np.pi * 10, rel=1e-4)


def test_unknown_suffix_and_folder(tmp_path):
    with pytest.raises(InputError, match="unknown track format"):
        load_track(_write(tmp_path, "t.json", HEADER + ROWS))
    with pytest.raises(InputError, match="folder"):
        load_track(tmp_path)


def test_track_constructor_bad_input():
    x = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    y = np.array([0.0, 0.5, 0.0, -0.5, 0.0])
    w = np.ones(5)
    with pytest.raises(InputError, match="not finite"):
        Track(x, np.where(x == 2, np.nan, y), w, w, closed=False)
    with pytest.raises(InputError, match="coincide"):
        Track(np.r_[x[:2], x[1:]], np.r_[y[:2], y[1:]], np.ones(6), np.ones(6), closed=False)
    with pytest.raises(InputError, match="at least 4"):
        Track(x[:3], y[:3], w[:3], w[:3], closed=False)
    with pytest.raises(InputError, match="width_left must be positive"):
        Track(x, y, -w, w, closed=False)


# ---------------------------------------------------------------------------------------------
# bad input: TOML

GOOD = """closed = true
width = 4.0
[[segments]]
type = "straight"
length = 50.0
[[segments]]
type = "arc"
radius = 10.0
angle_deg = 180.0
[[segments]]
type = "straight"
length = 50.0
[[segments]]
type = "arc"
radius = 10.0
angle = 3.141592653589793
"""


def test_toml_good_oval(tmp_path):
    t = load_track(_write(tmp_path, "oval.toml", GOOD))
    assert t.name == "oval" and t.closed
    assert t.length == pytest.approx(100 + 20 * np.pi, rel=1e-4)
    assert t.kappa(50 + 5 * np.pi) == pytest.approx(0.1, rel=1e-3)


@pytest.mark.parametrize(
    "text, exc, match",
    [
        ("", ConfigError, "closed: required key missing"),
        (GOOD[: GOOD.index("radius = 10.0\nangle =")] + "radius = ", ConfigError, "not valid TOML"),
        (GOOD.replace("length = 50.0", "length = 40.0", 1), InputError, "do not close.*10.000 m"),
        (GOOD.replace("angle_deg = 180.0", "angle_deg = 170.0"), InputError, "do not close"),
        (GOOD.replace("closed = true", "closed = true\ncolour = 'red'"), ConfigError, "colour: unknown key"),
        (GOOD.replace("width = 4.0", ""), ConfigError, "needs width"),
        (GOOD.replace("width = 4.0", "width = -4.0"), ConfigError, "width"),
        (GOOD.replace("radius = 10.0", "radius = 0.0", 1), ConfigError, "segments.1.arc.radius"),
        (GOOD.replace('type = "straight"', 'type = "loop"', 1), ConfigError, "segments.0"),
        (GOOD.replace("angle_deg = 180.0", "angle_deg = 180.0\nangle = 3.14"), ConfigError, "exactly one of angle"),
        (GOOD.replace("length = 50.0", "length = nan", 1), ConfigError, "segments.0.straight.length"),
        (GOOD.replace("length = 50.0", "length = inf", 1), ConfigError, "segments.0.straight.length"),
        ("closed = true\nwidth = 3.0\nsegments = []\n", ConfigError, "segments"),
    ],
)
def test_toml_bad_input(tmp_path, text, exc, match):
    p = _write(tmp_path, "bad.toml", text)
    with pytest.raises(exc, match=match) as e:
        load_track(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)


def test_toml_open_track_need_not_close(tmp_path):
    t = load_track(_write(tmp_path, "open.toml", GOOD.replace("closed = true", "closed = false").replace("length = 50.0", "length = 40.0", 1)))
    assert not t.closed and t.length == pytest.approx(90 + 20 * np.pi, rel=1e-4)


# ---------------------------------------------------------------------------------------------
# tracks as they come (issue 36): headerless centre lines, two boundary files, scale

from shared_data import REAL_LOGS  # noqa: E402

INI_CENTRE = REAL_LOGS / "ini_f1tenth_ipz20" / "centerline.csv"
PUTNAM = [REAL_LOGS / "iac_putnam_park" / f"putnam_{k}_bound.csv" for k in ("inner", "outer")]


def test_headerless_centre_line_equals_the_one_with_header(tmp_path):
    raw = np.loadtxt(TUM_DIR / "Norisring.csv", delimiter=",", comments="#")
    bare = tmp_path / "bare.csv"
    np.savetxt(bare, raw, delimiter=",", fmt="%.6f")
    ta, tb = load_track(TUM_DIR / "Norisring.csv"), load_track(bare)
    assert tb.length == pytest.approx(ta.length, rel=1e-6) and tb.smoothing == pytest.approx(ta.smoothing)
    s = np.linspace(0, ta.length, 500)
    assert np.allclose(tb.width_left(s), ta.width_left(s), atol=1e-4) and np.allclose(tb.kappa(s), ta.kappa(s), atol=1e-4)


@pytest.mark.skipif(not INI_CENTRE.exists(), reason="real logs not available")
def test_a_25_m_and_a_5_km_track_load_with_the_same_command(capsys):
    """The F1TENTH centre line as it comes (no header, points 0.1 m apart, widths ~1 m) and a TUM
    circuit: smoothing follows the point spacing (0.1 m vs 5 m) and keeps every border."""
    infos = []
    for path in (INI_CENTRE, TUM_DIR / "Spa.csv"):
        assert main(["track", "show", str(path), "--json"]) == 0
        infos.append(json.loads(capsys.readouterr().out))
    ini, spa = infos
    assert 25 < ini["length_m"] < 32 and ini["smoothing_m"] == pytest.approx(0.1, rel=0.01)
    assert 6900 < spa["length_m"] < 7100 and spa["smoothing_m"] == pytest.approx(5.0, rel=0.01)
    # the file's widths survive the smoothing: centre +- width lands where the file puts the borders
    raw = np.loadtxt(INI_CENTRE, delimiter=",")
    t = load_track(INI_CENTRE)
    s, e = t.to_frenet(raw[:, 0], raw[:, 1])
    assert np.abs(e).max() < 0.01


def _ring_bounds(n_a=700, n_b=500, noise=0.0, seed=0):
    """Inner and outer boundary of a kidney-shaped loop with a varying width, and its true centre."""
    rng = np.random.default_rng(seed)
    u = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
    r = 60 + 15 * np.cos(2 * u) + 8 * np.sin(3 * u)
    c = np.column_stack([r * np.cos(u), r * np.sin(u)])
    d = np.gradient(c, axis=0)
    t = d / np.hypot(*d.T)[:, None]
    nrm = np.column_stack([-t[:, 1], t[:, 0]])
    w = 5 + 1.5 * np.sin(u)
    left, right = c + w[:, None] * nrm, c - w[:, None] * nrm

    def pick(p, n):
        i = np.sort(rng.choice(len(p), n, replace=False))
        return p[i] + rng.normal(0, noise, (n, 2))

    return pick(left, n_a), pick(right, n_b), c, w


@pytest.mark.parametrize("variant", ["plain", "reversed", "rolled", "swapped", "noisy", "first_reversed"])
def test_track_from_two_boundaries(tmp_path, variant):
    """Centre line and widths from boundary files in either order, direction and start, point
    counts differing; recovered to a few cm (the true centre is known)."""
    left, right, c, w = _ring_bounds(noise=0.03 if variant == "noisy" else 0.0)
    a, b = left, right
    if variant == "reversed":
        b = b[::-1]
    if variant == "rolled":
        b = np.roll(b, 137, axis=0)
    if variant == "swapped":
        a, b = right, left
    if variant == "first_reversed":
        a = a[::-1]
    pa, pb = tmp_path / "a.csv", tmp_path / "b.csv"
    np.savetxt(pa, np.column_stack([a, np.full(len(a), -34.0)]), delimiter=",")  # a z column, as IAC's
    np.savetxt(pb, b, delimiter=",", header="x_m,y_m", comments="# ")
    trk = load_track(f"{pa},{pb}")
    assert trk.closed
    s, e = trk.to_frenet(c[:, 0], c[:, 1])
    tol = 0.12 if variant == "noisy" else 0.05
    assert np.abs(e).max() < tol
    assert np.abs(trk.width_left(s) + trk.width_right(s) - 2 * w).max() < 2 * tol + 0.05
    # the first file sets the direction (counter-clockwise unless it runs the other way)
    smp = trk.sample(1.0)
    area = np.sum(smp.x * np.roll(smp.y, -1) - np.roll(smp.x, -1) * smp.y)
    assert (area > 0) == (variant != "first_reversed")
    # the pair syntax of `track show` (two arguments) gives the same track
    assert main(["track", "show", str(pa), str(pb), "--json"]) == 0


def test_crossing_boundary_files_are_refused(tmp_path, capsys):
    left, right, _, _ = _ring_bounds()
    bad = left.copy()
    k = slice(100, 160)
    bad[k] = right[np.clip(np.searchsorted(np.linspace(0, 1, len(right)), np.linspace(0, 1, len(left))[k]), 0, len(right) - 1)] * 1.02
    pa, pb = tmp_path / "inner.csv", tmp_path / "outer.csv"
    np.savetxt(pa, bad, delimiter=",")
    np.savetxt(pb, right, delimiter=",")
    with pytest.raises(InputError, match="the boundary files cross each other") as exc:
        load_track([pa, pb])
    assert "\n" not in str(exc.value)
    assert main(["track", "show", f"{pa},{pb}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cross each other" in err[0]


@pytest.mark.skipif(not PUTNAM[0].exists(), reason="real logs not available")
def test_putnam_park_from_its_boundary_files():
    """IAC's files as they come: x, y, z without a header, the "inner" file being the outer loop."""
    trk = load_track(PUTNAM)
    assert trk.closed and 2800 < trk.length < 2900
    lo, hi = trk.width_range
    assert 7.0 < lo and hi < 12.0
    for p in PUTNAM:  # every boundary point lies on a border of the derived track
        xy = np.loadtxt(p, delimiter=",")[:, :2]
        s, e = trk.to_frenet(xy[:, 0], xy[:, 1])
        border = np.where(e > 0, trk.width_left(s), -trk.width_right(s))
        assert np.percentile(np.abs(e - border), 95) < 0.3


def test_reversed_track_is_the_same_geometry():
    t = load_track(TUM_DIR / "Norisring.csv")
    r = t.reversed()
    s = np.linspace(0, t.length, 700, endpoint=False)
    sr = r.wrap(t.length - s)
    x, y = t.position(s)
    xr, yr = r.position(sr)
    assert r.length == pytest.approx(t.length, rel=1e-6) and r.is_reversed and not t.is_reversed
    assert np.hypot(x - xr, y - yr).max() < 1e-3
    assert np.abs(t.kappa(s) + r.kappa(sr)).max() < 1e-3
    assert np.abs(t.width_left(s) - r.width_right(sr)).max() < 0.05


def test_smoothing_option_is_named_when_it_fails(tmp_path, capsys):
    pts = [(10 * np.cos(a), 10 * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 40, endpoint=False)]
    p = _write(tmp_path, "narrow.csv", "".join(f"{x},{y},0.05,0.05\n" for x, y in pts))
    assert main(["track", "show", str(p), "--smoothing", "20"]) == 2
    err = capsys.readouterr().err
    assert "--smoothing" in err and "moves the centre line outside" in err
    assert main(["track", "show", str(p)]) == 0  # the automatic smoothing (point spacing) fits


@pytest.mark.parametrize("name", ["Norisring", "Suzuka", "Spa"])
def test_boundaries_of_real_circuits(tmp_path, name):
    """Borders of TUM circuits (Suzuka's cross at the bridge) written as two files, the second
    reversed, rolled, 5 cm noisy, the first with 30 % of its points dropped: the derived centre
    is the midline between the borders (to 5 cm at the 95th percentile; TUM's own line sits
    (w_left - w_right) / 2 off it) and the total width right to 15 cm."""
    rng = np.random.default_rng(7)
    t = load_track(TUM_DIR / f"{name}.csv")
    smp = t.sample(2.0)
    (xl, yl), (xr, yr) = t.borders(2.0)
    a = np.column_stack([xl, yl])[rng.random(len(xl)) > 0.3]
    b = np.roll(np.column_stack([xr, yr])[::-1], 333, axis=0) + rng.normal(0, 0.05, (len(xr), 2))
    pa, pb = tmp_path / "left.csv", tmp_path / "right.csv"
    np.savetxt(pa, a, delimiter=",")
    np.savetxt(pb, b, delimiter=",")
    tb = load_track([pa, pb])
    assert abs(tb.length - t.length) < 0.005 * t.length
    s, e = tb.to_frenet(smp.x, smp.y, s_hint=smp.s * tb.length / t.length)
    assert np.percentile(np.abs(e + 0.5 * (smp.wl - smp.wr)), 95) < 0.05
    assert np.percentile(np.abs(tb.width_left(s) + tb.width_right(s) - smp.wl - smp.wr), 95) < 0.15
