"""Reports and figures: figure functions (axes, labels, units, plotted data), `gprace show` on
every kind, `gprace report` on complete, partial and empty folders."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest

from gprace.cli import main
from gprace.io.artifacts import Artifact, write_artifact
from gprace.report import figures as F
from gprace.report.inspect import describe
from test_report_data import (L, make_dataset, make_diagnosis, make_everything, make_gp_model, make_h2h,
                              make_iterate, make_plan, make_run)


def _labels(fig):
    return [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes if ax.get_visible() and ax.get_label() != "<colorbar>"]


def _unit(text: str) -> str | None:
    m = re.search(r"\[([^\]]+)\]", text)
    return m.group(1) if m else None


@pytest.fixture(scope="module")
def everything(tmp_path_factory) -> Path:
    return make_everything(tmp_path_factory.mktemp("exp"))


# ----------------------------------------------------------------------------------------------
# figure functions
def test_fig_lap_times_mean_and_spread_over_trials():
    it = np.array([0, 0, 0, 1, 1, 1])
    planned = np.array([30.0, 30.0, 30.0, 29.0, 29.0, 29.0])
    driven = np.array([31.0, 32.0, 33.0, 30.0, 30.5, 31.0])
    fig = F.fig_lap_times({"exploration": {"iteration": it, "planned": planned, "driven": driven}})
    axes = fig.axes
    assert len(axes) == 3
    assert [a.get_xlabel() for a in axes] == ["iteration [-]"] * 3
    assert [a.get_ylabel() for a in axes] == ["planned lap time [s]", "driven lap time [s]", "driven - planned lap time [s]"]
    line = axes[1].get_lines()[0]
    np.testing.assert_allclose(line.get_xdata(), [0, 1])
    np.testing.assert_allclose(line.get_ydata(), [32.0, 30.5])  # mean over the three trials
    band = axes[1].collections[0].get_paths()[0].vertices  # +-1 std band
    assert band[:, 1].max() == pytest.approx(32.0 + np.std([31.0, 32.0, 33.0]))
    assert band[:, 1].min() == pytest.approx(30.5 - np.std([30.0, 30.5, 31.0]))
    np.testing.assert_allclose(axes[2].get_lines()[0].get_ydata(), [2.0, 1.5])


def test_fig_run_axes_units_and_plan_overlay():
    s = np.linspace(0, 100, 50)
    data = {c: np.sin(s / 10 + k) for k, c in enumerate(("v_x", "v_y", "yaw_rate", "e_y", "delta", "a_x"))}
    data.update(t=s / 10, s=s)
    fig = F.fig_run(data, "s", plan={"s": s, "v_x": np.ones(50)})
    labs = _labels(fig)
    assert {_unit(y) for _, y in labs} == {"m/s", "rad/s", "m", "rad", "m/s^2"}
    assert labs[-1][0] == "arc length s [m]"
    assert [ln.get_label() for ln in fig.axes[0].get_lines()] == ["driven", "plan"]
    fig_t = F.fig_run(data, "t")
    assert _labels(fig_t)[-1][0] == "time [s]"
    # two laps against s: the line breaks at the start line instead of stroking back across it
    two = {k: np.concatenate([v, v]) for k, v in data.items()}
    xd = F.fig_run(two, "s").axes[0].get_lines()[0].get_xdata()
    assert np.isnan(xd).sum() == 1 and np.all(np.diff(xd[np.isfinite(xd)][:50]) > 0)


def test_fig_track_speed_places_line_on_map_and_marks_hits():
    from gprace.tracks import load_track

    track = load_track("circle_100")
    s = np.linspace(0, L - 1, 300)
    hits = np.zeros(300)
    hits[10:13] = 1
    fig = F.fig_track_speed(track, s, np.full(300, 2.0), np.linspace(10, 20, 300), hits)
    ax = fig.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "y [m]")
    assert "3 border-hit steps" in ax.get_title()
    cbar = fig.axes[1]
    assert cbar.get_ylabel() == "speed v_x [m/s]"
    marks = [ln for ln in ax.get_lines() if ln.get_marker() == "x"][0]
    # e_y = +2 m left of a left-turning circle of radius 100 around (0, 100): radius 98
    r = np.hypot(marks.get_xdata(), np.asarray(marks.get_ydata()) - 100.0)
    np.testing.assert_allclose(r, 98.0, atol=0.05)


def test_fig_pred_errors_one_line_per_predictor():
    e = {"baseline": {"mean": [0.01, 0.02, 0.05], "std": [0.0, 0.01, 0.02]}, "explore": {"mean": [0.01, 0.015, 0.03]}}
    fig = F.fig_pred_errors(e, dt=0.1)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "steps ahead [-] (0.1 s each)"
    assert _unit(ax.get_ylabel()) == "m"
    lines = ax.get_lines()
    assert [ln.get_label() for ln in lines] == ["baseline", "explore"]
    np.testing.assert_allclose(lines[0].get_xdata(), [1, 2, 3])


def test_fig_error_along_run_rows_are_steps_ahead():
    E = np.vstack([np.full(20, k + 1.0) for k in range(9)])
    fig = F.fig_error_along_run(np.arange(20) * 0.1, {"gp": E}, (1, 9))
    a1, a9 = fig.axes
    assert a1.get_ylabel() == "1-step |e_y error| [m]" and a9.get_ylabel() == "9-step |e_y error| [m]"
    assert a9.get_xlabel() == "prediction start time [s]"
    assert np.all(a1.get_lines()[0].get_ydata() == 1.0) and np.all(a9.get_lines()[0].get_ydata() == 9.0)


def test_fig_gp_posterior_over_two_features_with_dictionary(tmp_path):
    from gprace.report.single import load_gp

    path = make_gp_model(tmp_path / "m.h5")
    gp, names_in, names_out, Zd = load_gp(path)
    assert Zd.shape == (40, 3)
    # dictionary points are returned in input units (inside the sampled box, not normalised)
    assert np.abs(Zd[:, 2]).max() <= 0.05 + 1e-12 and np.abs(Zd[:, 0]).max() > 0.3
    fig = F.fig_gp_posterior(gp.predict, Zd, names_in, names_out, 0, 1)
    mean_ax, std_ax, mean_cb, std_cb = fig.axes
    assert (mean_ax.get_xlabel(), mean_ax.get_ylabel()) == ("v_y [m/s]", "yaw_rate [rad/s]")
    assert mean_cb.get_ylabel() == "posterior mean of dv_y" and std_cb.get_ylabel() == "posterior std of dv_y"
    # the colour scale spans the model's own predictions over the grid
    lo, hi = mean_cb.get_ylim()
    m, v = gp.predict(np.column_stack([Zd[:, 0], Zd[:, 1], np.full(40, np.median(Zd[:, 2]))]))
    assert lo <= m[:, 0].min() and m[:, 0].max() <= hi
    # the std is smallest near the data: the box corners are farther from the dictionary
    assert std_cb.get_ylim()[1] > np.sqrt(v[:, 0]).min()
    pts = mean_ax.get_lines()[0]
    np.testing.assert_allclose(pts.get_xdata(), Zd[:, 0])
    assert pts.get_label() == "dictionary (40)"
    assert std_ax.get_title() == "std"


def test_fig_residual_channels_parameters():
    s = np.linspace(0, 500, 100)
    fig = F.fig_residual_track(s, {"v_x": np.ones(100), "yaw_rate": np.zeros(100)}, {"v_x": np.zeros(100)},
                               [{"channel": "v_x", "s_start": 100, "s_end": 200}])
    assert [a.get_ylabel() for a in fig.axes] == ["v_x residual [m/s]", "yaw_rate residual [rad/s]"]
    assert fig.axes[-1].get_xlabel() == "arc length s [m]"
    assert len(fig.axes[0].patches) == 1  # the located window, shaded
    fig = F.fig_residual_track(s, {"v_x": np.ones(100)}, noise={"v_x": 0.2})
    band = fig.axes[0].patches[0].get_path().get_extents().transformed(fig.axes[0].patches[0].get_transform())
    lo, hi = fig.axes[0].transData.inverted().transform([[0, band.y0], [0, band.y1]])[:, 1]
    assert (round(lo, 6), round(hi, 6)) == (-0.2, 0.2)  # the noise twin's +-1 sigma band
    fig = F.fig_channels([{"name": "v_x", "structured": True, "statistic": 9.0},
                          {"name": "v_y", "structured": False, "statistic": 1.0}],
                         [{"channel": "v_x", "s_start": 100, "s_end": 200}])
    bars = fig.axes[0].patches
    assert [b.get_height() for b in bars] == [9.0, 1.0]
    assert fig.axes[0].get_ylabel() == "structure statistic [-]"
    fig = F.fig_parameters([{"name": "downforce", "parameters": {"c_l": {"value": 1.0, "ci95": [0.9, 1.1], "unit": "N s^2/m^2"}}}])
    assert fig.axes[0].get_yticklabels()[0].get_text() == "downforce.c_l [N s^2/m^2]"


# ----------------------------------------------------------------------------------------------
# gprace show
def test_show_every_kind_json(everything, tmp_path, capsys):
    files = {
        "plan": everything / "exploration" / "trial_0" / "iter_01" / "plan.h5",
        "run": everything / "exploration" / "trial_0" / "iter_01" / "run.h5",
        "gp_model": everything / "exploration" / "trial_0" / "iter_02" / "gp_tracking.h5",
        "dataset": everything / "gp" / "dataset.h5",
        "h2h_run": everything / "h2h" / "eval" / "explore" / "run_00000.h5",
        "diagnosis": everything / "diagnosis" / "diagnosis.json",
        "h2h_table": everything / "h2h" / "table.json",
    }
    for kind, f in files.items():
        png = tmp_path / f"{kind}.png"
        assert main(["show", str(f), "--json", "--plot", str(png)]) == 0, kind
        info = json.loads(capsys.readouterr().out)
        assert info["kind"] == kind
        assert png.stat().st_size > 5000, kind
    run = describe(files["run"])
    assert run["results"]["lap_time"] == pytest.approx(L / 19.7)
    assert run["results"]["lap_time_minus_planned_s"] == pytest.approx(L / 19.7 - run["attrs"]["planned_lap_time"])
    assert run["arrays"]["v_x"]["dtype"] == "float64"
    assert describe(files["gp_model"])["results"]["dictionary_size"] == 40
    assert "hyper/log_ls" in describe(files["gp_model"])["arrays"]
    assert describe(files["dataset"])["results"]["points"] == 60
    assert describe(files["plan"])["results"]["nodes"] == 200
    assert describe(files["h2h_run"])["results"]["overtake_time"] == 3.1


def test_show_text_csv_run(tmp_path, capsys):
    from gprace.io.runs import read_run, write_run_csv

    h5 = make_run(tmp_path / "r.h5", 20.0)
    csv = write_run_csv(read_run(h5), tmp_path / "r.csv")
    assert main(["show", str(csv), "--plot", str(tmp_path / "r.png")]) == 0
    out = capsys.readouterr().out
    assert "kind            run" in out and "v_x_max_mps" in out and "plot" in out
    assert (tmp_path / "r.png").exists()
    assert main(["show", str(h5)]) == 0
    out = capsys.readouterr().out
    assert "created" in out and "schema" in out  # provenance shown
    assert "gprace_version" in out and "arrays" in out


def test_show_bad_input(tmp_path, capsys):
    assert main(["show", str(tmp_path / "nope.h5")]) == 2
    assert "no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5 at all")
    assert main(["show", str(bad)]) == 2
    assert "not an HDF5 file" in capsys.readouterr().err
    ds = make_dataset(tmp_path / "d.h5")
    assert main(["show", str(ds), "--plot", str(tmp_path / "x.png"), "--features", "v_y,nonsense"]) == 2
    assert "nonsense" in capsys.readouterr().err
    assert main(["show", str(ds), "--plot", str(tmp_path / "nofolder" / "x.png")]) == 2
    assert "does not exist" in capsys.readouterr().err
    # the folder exists but the file system refuses the name (too long, even for root): one line, exit 2
    assert main(["show", str(ds), "--plot", str(tmp_path / ("x" * 300 + ".png"))]) == 2
    err = capsys.readouterr().err
    assert "refuses this name" in err and err.count("\n") == 1
    assert main(["show", str(ds), "--plot", str(tmp_path / "x.png")]) == 0  # the same writer succeeds
    assert (tmp_path / "x.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ----------------------------------------------------------------------------------------------
# gprace report
def _data_uri_images(html: str) -> list[bytes]:
    return [base64.b64decode(m) for m in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)]


def test_report_complete_folder(everything, tmp_path, capsys):
    out = tmp_path / "report.html"
    assert main(["report", str(everything), "-o", str(out), "--png", str(tmp_path / "png")]) == 0
    html = out.read_text()
    for sec in ("timetrial", "h2h", "diagnosis", "gp", "artifacts"):
        assert f'data-section="{sec}"' in html or f"data-section='{sec}'" in html, sec
    imgs = _data_uri_images(html)
    pngs = sorted((tmp_path / "png").glob("*.png"))
    assert len(imgs) == len(pngs) >= 12
    assert all(b[:8] == b"\x89PNG\r\n\x1a\n" for b in imgs)
    # self-contained: nothing to fetch
    assert not re.search(r'(src|href)="(https?:|//)', html) and "<script" not in html and "<link" not in html
    names = {p.stem for p in pngs}
    for n in ("timetrial_lap_times", "timetrial_gp_errors", "timetrial_exploration_data", "timetrial_driven_line",
              "h2h_opponent_pred_errors", "h2h_race", "h2h_error_along_run", "diagnosis_residual_diagnosis",
              "diagnosis_channels_diagnosis", "diagnosis_parameters_diagnosis"):
        assert n in names, n
    assert "Results table" in html and "road_grade" in html


def test_report_partial_folder_says_what_is_missing(tmp_path, capsys):
    root = tmp_path / "partial"
    d = make_iterate(root, "exploration", iterations=2, trials=1, summary=False)
    # an interrupted atomic write and an iteration that never finished a run
    (d / "trial_0" / "iter_01" / ".run.h5.tmp").write_bytes(b"\x89HDF partial")
    (d / "trial_0" / "iter_02").mkdir()
    make_plan(d / "trial_0" / "iter_02" / "plan.h5")
    out = tmp_path / "r.html"
    assert main(["report", str(root), "-o", str(out)]) == 0
    cap = capsys.readouterr()
    err = cap.err
    html = out.read_text()
    assert "no summary.json" in html and "no summary.json" in err
    # stderr is not a terminal: no progress bar, but one start line per stage; stdout stays clean
    assert "report: collecting results" in err and re.search(r"report: rendering \d+ figures", err)
    assert cap.out.startswith("report ") and "collecting" not in cap.out and "━" not in err
    assert "exploration vs baseline comparison needs both" in html
    assert len(_data_uri_images(html)) >= 2  # lap times from the records, driven line


def test_report_empty_and_bad_folder(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["report", str(empty), "-o", str(tmp_path / "e.html")]) == 0
    assert "no gprace results found" in capsys.readouterr().err
    assert "No gprace results" in (tmp_path / "e.html").read_text()
    assert main(["report", str(tmp_path / "missing"), "-o", str(tmp_path / "m.html")]) == 2
    assert "no such folder" in capsys.readouterr().err


def test_report_diagnosis_only_without_residuals(tmp_path):
    d = make_diagnosis(tmp_path / "x")
    res = json.loads((d / "diagnosis.json").read_text())
    (d / "diagnosis.json").write_text(json.dumps({k: v for k, v in res.items() if k != "residual_profile"}))
    out = tmp_path / "r.html"
    assert main(["report", str(tmp_path / "x"), "-o", str(out)]) == 0
    html = out.read_text()
    assert "residual-along-track plot not drawn" in html
    assert 'data-section="timetrial"' not in html
    # channels, parameters, and the road grade window along the lap (drawn from the effects alone)
    assert len(_data_uri_images(html)) == 3


def test_h2h_only_report(tmp_path):
    d = make_h2h(tmp_path / "e")
    out = tmp_path / "r.html"
    assert main(["report", str(tmp_path / "e"), "-o", str(out)]) == 0
    assert len(_data_uri_images(out.read_text())) == 3
    # interrupted before the table: the race is still drawn, the page says what is missing
    (d / "table.json").unlink()
    assert main(["report", str(tmp_path / "e"), "-o", str(out)]) == 0
    html = out.read_text()
    assert "no table.json (the evaluation did not finish)" in html
    assert len(_data_uri_images(html)) == 2  # the race and the errors along it


def test_report_draws_the_residual_the_diagnosis_stored_without_simulating(tmp_path, capsys, monkeypatch):
    """A recording with a hidden road grade, diagnosed through the CLI: the JSON stores the residual
    along the track (the v_x residual inside the window is large before and near zero after), and
    the report draws it from the JSON alone: no recording next to it, the prediction code broken."""
    from gprace.config import EffectConfig, load_vehicle
    from gprace.diagnose import core
    from gprace.diagnose.synth import record
    from gprace.io.runs import write_run
    from gprace.tracks import load_track

    grade = EffectConfig(name="road_grade", params={"angle": 0.06, "s_start": 200.0, "s_end": 350.0})
    run = record(load_vehicle("audi_tt_cup"), load_track("circle_100"), [grade], laps=2, seed=3)
    rec = write_run(run, tmp_path / "rec.h5")
    capsys.readouterr()
    assert main(["-q", "diagnose", str(rec), "--vehicle", "audi_tt_cup", "--json"]) == 0
    out_json = capsys.readouterr().out
    prof = json.loads(out_json)["residual_profile"]
    s = np.array(prof["s"])
    before = np.array(prof["before"]["v_x"], dtype=float)
    after = np.array(prof["after"]["v_x"], dtype=float)
    inside = (s > 230) & (s < 330) & np.isfinite(before)
    outside = ((s < 170) | (s > 400)) & np.isfinite(before)
    # uphill: the car is slower than the flat-road model predicts, by about g sin(angle) * horizon time / 2
    assert np.mean(before[inside]) < -0.15
    assert abs(np.mean(before[outside])) < 0.05
    assert np.max(np.abs(after[inside])) < 0.25 * abs(np.mean(before[inside]))
    d = tmp_path / "diag"
    d.mkdir()
    (d / "diagnosis.json").write_text(out_json)

    def no_simulation(*a, **k):
        raise AssertionError("the report must not simulate")

    monkeypatch.setattr(core, "predict", no_simulation)
    monkeypatch.setattr(core, "build_dataset", no_simulation)
    out = tmp_path / "r.html"
    assert main(["report", str(d), "-o", str(out), "--png", str(tmp_path / "png")]) == 0
    assert (tmp_path / "png" / "diagnosis_residual_diagnosis.png").exists()
    assert "residual-along-track plot not drawn" not in out.read_text()


@pytest.mark.skipif(__import__("shutil").which("script") is None, reason="needs util-linux `script` for a pseudo-terminal")
def test_report_progress_on_terminal_only(tmp_path):
    """Progress bars appear on a terminal (a pseudo-terminal through `script`), not with
    --quiet (and not off-terminal: see the partial-folder test)."""
    import subprocess

    make_diagnosis(tmp_path / "d")
    cmd = f"gprace {{q}} report {tmp_path / 'd'} -o {tmp_path / 'r.html'}"
    tty = subprocess.run(["script", "-qec", cmd.format(q=""), "/dev/null"], capture_output=True, text=True, timeout=120)
    assert tty.returncode == 0 and re.search(r"report: rendering \d+ figures", tty.stdout)
    quiet = subprocess.run(["script", "-qec", cmd.format(q="--quiet"), "/dev/null"], capture_output=True, text=True,
                           timeout=120)
    assert quiet.returncode == 0 and "report: rendering" not in quiet.stdout


def test_show_plots_unknown_kinds_generically(tmp_path, capsys):
    rng = np.random.default_rng(0)
    cand = write_artifact(tmp_path / "c.h5", Artifact("candidates", arrays={"Z": rng.normal(size=(30, 3)), "v": rng.random(30)}))
    assert main(["show", str(cand), "--plot", str(tmp_path / "c.png")]) == 0
    assert (tmp_path / "c.png").stat().st_size > 5000
    series = write_artifact(tmp_path / "s.h5", Artifact("telemetry", arrays={"t": np.arange(10.0), "load": np.ones(10)}))
    assert main(["show", str(series), "--plot", str(tmp_path / "s.png")]) == 0
    nothing = write_artifact(tmp_path / "n.h5", Artifact("blob", arrays={"x": np.ones((2, 2, 2))}))
    capsys.readouterr()
    assert main(["show", str(nothing), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["arrays"]["x"]["shape"] == [2, 2, 2]
    assert main(["show", str(nothing), "--plot", str(tmp_path / "n.png")]) == 2
    assert "no figure for artifacts of kind 'blob'" in capsys.readouterr().err


def test_report_reads_interrupted_iterate_layout(tmp_path):
    """The `gprace iterate` layout (settings.json, trial_<j>/iter_<i>/ with record.json), killed
    before its summary: a baseline variant, lap times from the records, the missing iterations named."""
    from gprace.report.collect import scan
    from gprace.report.sections.timetrial import timetrial_variants

    root = tmp_path / "loop"
    root.mkdir()
    (root / "settings.json").write_text(json.dumps({"alphas": [0.0], "selection": "random", "iterations": 2, "trials": 2}))
    make_run(root / "heldout.h5", 18.0)  # the weaving GP test run: not a lap of the loop
    for j in range(2):
        d = root / f"trial_{j}" / "iter_00"
        make_plan(d / "plan.h5")
        make_run(d / "run.h5", 19.0 + 0.1 * j, seed=j, planned=31.5)
        (d / "record.json").write_text(json.dumps({"iteration": 0, "trial": j, "alpha": 0.0, "planned": 31.5,
                                                   "driven": L / (19.0 + 0.1 * j), "err_tracking": float("nan"),
                                                   "err_planning": float("nan"), "completed": True}))
    v = timetrial_variants(scan(root))
    assert list(v) == [root] and v[root]["name"] == "baseline"
    assert v[root]["rows_from"] == "record.json files" and len(v[root]["rows"]) == 2
    assert sorted((it, tr) for _, _, it, tr in v[root]["runs"]) == [(0, 0), (0, 1)]
    out = tmp_path / "r.html"
    assert main(["report", str(root), "-o", str(out), "--png", str(tmp_path / "png")]) == 0
    html = out.read_text()
    assert "1 of 3 iterations finished" in html and "lap times taken from the record.json files" in html
    assert "GP prediction errors per iteration: not in any summary.json yet" in html  # all NaN at iteration 0
    assert (tmp_path / "png" / "timetrial_lap_times.png").exists()
