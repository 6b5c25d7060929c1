"""Laps from the data (issue 36 item 2): gprace.tracks.laps on synthetic paths with known laps,
Frenet recordings whose s runs on, and the two real logs imported without a track."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest

from shared_data import REAL_LOGS, TUM_TRACKS

from gprace.tracks import Track, load_track
from gprace.tracks.laps import driven_distance, path_laps, wrap_frenet


def _drive(track: Track, laps: float, *, speed=(0.4, 1.0), dt_s: float = 0.04, v_max: float = 30.0, noise: float = 0.0,
           stand: float = 0.0, pit: tuple[float, float, float] | None = None, weave: float = 0.0, seed: int = 0):
    """Positions of a car driving ``laps`` laps of ``track`` (speed varying along the lap between
    ``speed`` fractions of ``v_max``), standing ``stand`` seconds first (with the noise), with a
    detour of ``pit = (s_start, length, offset)`` in lap 1, a lateral weave that changes from lap to
    lap, and GNSS-like noise."""
    rng = np.random.default_rng(seed)
    L = track.length
    ds = 0.25
    s = np.arange(0.0, laps * L, ds)
    u = s / L
    v = v_max * (speed[0] + (speed[1] - speed[0]) * 0.5 * (1 + np.sin(2 * np.pi * 3 * u)))
    t = np.concatenate([[0.0], np.cumsum(ds / v[:-1])])
    tg = np.arange(0.0, t[-1], dt_s)
    sg = np.interp(tg, t, s)
    lap = np.floor(sg / L)
    ey = weave * np.sin(2 * np.pi * 5 * sg / L + 1.3 * lap) * (1 + 0.3 * np.cos(lap))
    if pit is not None:
        a, length, off = pit
        x0 = sg - L
        inside = (x0 > a) & (x0 < a + length)
        ramp = np.clip(np.minimum(x0 - a, a + length - x0) / (0.2 * length), 0, 1)
        ey = ey + np.where(inside, off * ramp, 0.0)
    x, y = track.to_global(track.wrap(sg), ey)
    # the mean driven line (pit detour left out), in bins along the lap: what the laps average to
    off = np.zeros(len(sg), dtype=bool) if pit is None else inside
    nb = int(min(1000, len(sg) / (3 * laps)))  # bins of about three samples a lap
    b = (nb * track.wrap(sg[~off]) / L).astype(int)
    mean_ey = np.bincount(b, weights=ey[~off], minlength=nb) / np.maximum(np.bincount(b, minlength=nb), 1)
    if stand > 0:
        n0 = int(stand / dt_s)
        x = np.concatenate([np.full(n0, x[0]), x])
        y = np.concatenate([np.full(n0, y[0]), y])
    x = x + rng.normal(0, noise, len(x))
    y = y + rng.normal(0, noise, len(y))
    return x, y, mean_ey


@pytest.mark.parametrize("case", ["clean", "noisy_standing_start_pit", "small_f1tenth", "partial_last_lap"])
def test_path_laps_recovers_the_period_the_laps_and_the_line(case):
    if case == "small_f1tenth":  # a 1:10 track, 25 m, 3 m/s, 2 cm noise
        th = np.linspace(0, 2 * np.pi, 200, endpoint=False)
        r = 3.5 + 0.8 * np.cos(3 * th)
        trk = Track(r * np.cos(th) * 1.3, r * np.sin(th), np.full(200, 0.8), np.full(200, 0.8), closed=True, smoothing=0.0)
        kw = dict(laps=5.6, v_max=4.0, noise=0.02, stand=2.0, weave=0.15)
    else:
        trk = load_track(TUM_TRACKS / "Norisring.csv")
        kw = {"clean": dict(laps=3.3),
              "noisy_standing_start_pit": dict(laps=3.5, noise=0.5, stand=10.0, weave=1.5, pit=(300.0, 400.0, 12.0)),
              "partial_last_lap": dict(laps=2.15, noise=0.2, weave=1.0)}[case]
    x, y, mean_ey = _drive(trk, **kw)
    pl = path_laps(x, y)
    assert pl is not None
    L = trk.length
    assert abs(pl.lap_length - L) < 0.01 * L, (pl.lap_length, L)
    assert pl.laps == int(kw["laps"])
    # the reference line lies on the mean driven line (what is left of the weave after averaging)
    s, e = trk.to_frenet(pl.x, pl.y)
    nb = len(mean_ey)
    expect = mean_ey[np.clip((nb * s / L).astype(int), 0, nb - 1)]
    tol = 0.05 if case == "small_f1tenth" else 0.35
    assert np.percentile(np.abs(e - expect), 95) < tol, np.percentile(np.abs(e - expect), 95)
    # point 0 sits where the car starts
    assert np.hypot(pl.x[0] - x[0], pl.y[0] - y[0]) < 0.02 * L + 0.1 * kw.get("pit", (0, 0, 0))[2]


def test_path_laps_says_none_for_an_open_path():
    t = np.linspace(0, 1, 2000)
    x, y = 3000 * t, 200 * np.sin(6 * t)  # a stage: never comes back
    assert path_laps(x, y) is None
    # standstill adds no distance
    d = driven_distance(np.r_[np.zeros(50) + np.random.default_rng(0).normal(0, 1e-3, 50), np.arange(100.0)], np.zeros(150))
    assert d[49] < 0.1 and d[-1] == pytest.approx(99.0 + abs(0.0 - 0.0), abs=0.2)


def _frenet_run(track: Track, laps: float, seed: int = 0):
    """s running on over ``laps`` laps, the track's kappa, a lap-to-lap varying e_y and speed."""
    rng = np.random.default_rng(seed)
    L = track.length
    n = int(laps * L / 1.3)
    s = np.cumsum(np.abs(rng.normal(1.3, 0.3, n)))
    k = track.kappa(track.wrap(s))
    v = 30 - 200 * np.abs(track.kappa(track.wrap(s)))
    ey = np.sin(2 * np.pi * 4 * s / L) + 0.1 * rng.normal(size=n)
    return s, k, ey, v


def test_wrap_frenet_recovers_the_lap_length():
    trk = load_track(TUM_TRACKS / "Monza.csv")
    s, k, ey, v = _frenet_run(trk, 4.4)
    out = wrap_frenet(s, k, e_y=ey, v=v)
    assert out is not None
    sw, lap, L = out
    assert abs(L - trk.length) < 1e-4 * trk.length
    assert lap.min() == 0 and lap.max() == 4 and np.all(np.diff(lap) >= 0)
    true = s % trk.length
    err = (sw - true + 0.5 * trk.length) % trk.length - 0.5 * trk.length
    assert np.abs(err).max() < 2.0  # within 2 m after four laps
    # noisy curvature (an estimator's): still found, to 0.05 %
    rng = np.random.default_rng(1)
    noisy = k + rng.normal(0, 0.3 * np.std(k), len(k))
    out = wrap_frenet(s, noisy, e_y=ey, v=v)
    assert out is not None and abs(out[2] - trk.length) < 5e-4 * trk.length


def test_wrap_frenet_leaves_what_it_cannot_wrap():
    trk = load_track(TUM_TRACKS / "Monza.csv")
    s, k, ey, v = _frenet_run(trk, 3.0)
    assert wrap_frenet(s % trk.length, k) is None  # already wrapped
    assert wrap_frenet(s[: len(s) // 4], k[: len(s) // 4]) is None  # less than a lap
    assert wrap_frenet(s, np.full(len(s), 0.01)) is None  # a circle has no lap in kappa
    rng = np.random.default_rng(2)
    assert wrap_frenet(s, rng.normal(0, 0.01, len(s))) is None  # noise only


def test_wrap_frenet_half_lap_symmetry_is_resolved_by_the_driving():
    """An oval whose two halves are equal has a kappa period of half a lap; the car's speed and
    line repeat once a lap only."""
    th = np.linspace(0, 2 * np.pi, 800, endpoint=False)
    x, y = 300 * np.cos(th), 120 * np.sin(th)
    trk = Track(x, y, np.full(800, 6.0), np.full(800, 6.0), closed=True, smoothing=0.0)
    s = np.arange(0, 3.5 * trk.length, 1.0)
    k = trk.kappa(trk.wrap(s))
    ph = 2 * np.pi * s / trk.length
    v = 40 + 5 * np.sin(ph)
    ey = 2 * np.cos(ph)
    out = wrap_frenet(s, k, e_y=ey, v=v)
    assert out is not None and abs(out[2] - trk.length) < 1e-3 * trk.length
    half = wrap_frenet(s, k)
    assert half is not None and abs(half[2] - 0.5 * trk.length) < 1e-3 * trk.length


# ------------------------------------------------------------------------------------------------
# the real logs without a track

INI = REAL_LOGS / "ini_f1tenth_ipz20"
IAC = REAL_LOGS / "iac_putnam_park"
MAPS = Path(__file__).parent / "data" / "real_maps"
INI_MAP = (MAPS / "ini_f1tenth.map.toml").read_text()
IAC_MAP = (MAPS / "iac_putnam.map.toml").read_text()


def _import(rec: Path, map_text: str, tmp_path: Path, *extra):
    from gprace.cli import main
    from gprace.io.runs import read_run

    mp = tmp_path / "m.toml"
    mp.write_text(map_text)
    out = tmp_path / "r.h5"
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["import", str(rec), "--map", str(mp), "-o", str(out), "--dt", "0.04", *map(str, extra)])
    assert code == 0, err.getvalue()
    return read_run(out)


def _continuity(run):
    """Largest |step of s - distance driven| within a lap, and the moving samples kept."""
    d = run.data
    L = run.meta["track_length"]
    sc = d["s"] + d["lap"] * L
    v = np.hypot(d["v_x"], d["v_y"])
    same = np.diff(d["segment"]) == 0  # steps inside a piece (not across a gap)
    return float(np.max(np.abs(np.diff(sc) - 0.5 * (v[1:] + v[:-1]) * run.dt)[same])), sc


@pytest.mark.skipif(not INI.exists(), reason="real logs not available")
@pytest.mark.parametrize("name,laps", [("2026-01-16_01-45-24", 4), ("2026-01-16_01-48-12", 4)])
def test_ini_runs_without_a_track(tmp_path, name, laps):
    """4 laps of about 24 m each (lap times 6.6 to 9 s), s continuous to a few cm."""
    run = _import(INI / f"{name}_IPZ20_rpgd_25Hz_physical.csv", INI_MAP, tmp_path)
    assert run.meta["reference"] == "path" and 22.0 < run.meta["track_length"] < 27.0
    assert run["lap"].max() == laps and run["lap"].min() == 0
    jump, sc = _continuity(run)
    assert jump < 0.3
    times = np.diff(run["t"][np.flatnonzero(np.diff(run["lap"])) + 1])
    assert np.all((times > 6.0) & (times < 9.5))
    assert np.abs(run["e_y"]).max() < 1.0
    assert run.meta["inputs"] == {"delta": "commanded", "a_x": "derived", "v_cmd": "commanded"}


@pytest.mark.skipif(not IAC.exists(), reason="real logs not available")
def test_iac_putnam_without_a_track(tmp_path):
    """About 2.6 laps of Putnam Park (2.85 km) from a standing start in the pit lane: 2 completed
    laps, s within [0, L) and continuous within a lap (it ran to 5.7 km before)."""
    run = _import(IAC / "Putnam_park2023_run4_2.csv", IAC_MAP, tmp_path)
    L = run.meta["track_length"]
    assert 2780 < L < 2900
    assert run["lap"].max() == 2 and run["lap"].min() == 0
    assert run["s"].min() >= 0 and run["s"].max() < L
    jump, _ = _continuity(run)
    assert jump < 3.0
    moving = np.hypot(run["v_x"], run["v_y"]) > 1.0
    assert moving.sum() >= 0.9 * 11_300  # the log's moving samples (v > 1 m/s) are all kept


def _moving_in_log(rec: Path, cols: list[str]) -> int:
    from gprace.io.table import numbers, sniff

    v = numbers(sniff(rec), cols)
    return int(np.sum(np.hypot(v[:, 0], v[:, 1]) > 0.1))


@pytest.mark.skipif(not INI.exists(), reason="real logs not available")
def test_ini_run_on_its_centre_line_as_it_comes(tmp_path):
    """The headerless centre line, driven the other way round: reversed, laps counted, >= 90 % of
    the moving samples kept."""
    rec = INI / "2026-01-16_01-45-24_IPZ20_rpgd_25Hz_physical.csv"
    run = _import(rec, INI_MAP, tmp_path, "--track", INI / "centerline.csv")
    assert run.meta["reference"] == "track" and run.meta["track_reversed"]
    assert 28.5 < run.meta["track_length"] < 29.5
    assert run["lap"].max() == 4 and 0 <= run["s"].min() and run["s"].max() < run.meta["track_length"]
    assert np.abs(run["e_y"]).max() < 1.5
    moving = np.hypot(run["v_x"], run["v_y"]) > 0.1
    assert moving.sum() >= 0.9 * _moving_in_log(rec, ["linear_vel_x", "linear_vel_y"])


@pytest.mark.skipif(not IAC.exists(), reason="real logs not available")
def test_iac_on_the_track_from_its_boundaries(tmp_path):
    """The pit lane (18.5 s beyond the borders) is cut with a note; the laps and >= 90 % of the
    moving samples stay."""
    rec = IAC / "Putnam_park2023_run4_2.csv"
    bounds = f"{IAC / 'putnam_inner_bound.csv'},{IAC / 'putnam_outer_bound.csv'}"
    run = _import(rec, IAC_MAP, tmp_path, "--track", bounds)
    assert run["lap"].max() == 2 and 2800 < run.meta["track_length"] < 2900
    assert any("off track" in n and "left out" in n for n in run.meta["notes"])
    moving = np.hypot(run["v_x"], run["v_y"]) > 0.1
    assert moving.sum() >= 0.9 * _moving_in_log(rec, ["vx(m/s)", "vy(m/s)"])
    assert run.meta["inputs"] == {"delta": "measured", "a_x": "measured"}
    jump, _ = _continuity(run)
    assert jump < 3.0 and run.meta["gaps"] == 0  # the pit lane is where the log starts: it begins 18.5 s later
    assert 18.0 < run.meta["t0"] - 1692117187.4638 < 19.0
