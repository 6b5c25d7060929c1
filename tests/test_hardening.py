"""Issue 16: bad settings and bad data are refused where a command starts (exit 2, one line naming
the culprit), before any file is written; no confident wrong answer."""

from __future__ import annotations

import contextlib
import io
import json

import pytest

from gprace.cli import main
from gprace.config import configs_dir


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("GPRACE_DEBUG", raising=False)


def refused(capsys, argv, *needles) -> str:
    """Run ``gprace argv``; assert exit 2 and one stderr line holding every needle."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def nothing_written(tmp_path) -> None:
    assert sorted(p.name for p in tmp_path.iterdir()) == [], list(tmp_path.iterdir())


# ------------------------------------------------------------------------------------------------
# item 4: every setting checked where the command starts

SETTINGS = [
    (["plan", "--ds", "5000", "-o", "{out}/p.h5"], ("--ds 5000", "nodes")),
    (["plan", "--ds", "0.001", "-o", "{out}/p.h5"], ("--ds 0.001", "nodes")),
    (["plan", "--grip", "-0.5", "-o", "{out}/p.h5"], ("--grip", "-0.5")),
    (["plan", "--grip", "1.5", "-o", "{out}/p.h5"], ("--grip", "1.5")),
    (["simulate", "--weave", "1.5", "-o", "{out}/r.h5"], ("--weave must be <= 1", "1.5")),
    (["run", "--plan", "{out}/none.h5", "--explore-radius", "-1", "-o", "{out}/r.h5"], ("--explore-radius", "-1")),
    (["run", "--plan", "{out}/none.h5", "--solver", "gurobi", "-o", "{out}/r.h5"], ("gurobi", "clarabel")),
    (["run", "--plan", "{out}/none.h5", "--beta", "1.5", "-o", "{out}/r.h5"], ("--beta", "1.5")),
    (["select-data", "{out}/none.h5", "--outlier-kappa", "-1", "-o", "{out}/d.h5"], ("--outlier-kappa", "-1")),
    (["eval", "head2head", "--gp-backend", "foo", "--out", "{out}/h2h"], ("'foo'", "exact, sparse")),
    (["eval", "head2head", "--width", "0", "--out", "{out}/h2h"], ("--width", "0")),
    (["eval", "head2head", "--max-time", "-1", "--out", "{out}/h2h"], ("--max-time", "-1")),
    (["h2h", "collect", "--width", "-1", "--out", "{out}/h2h"], ("--width", "-1")),
    (["h2h", "collect", "--points-per-run", "0", "--out", "{out}/h2h"], ("--points-per-run", "0")),
    (["iterate", "--solver", "gurobi", "--out", "{out}/it"], ("gurobi", "clarabel")),
    (["iterate", "--executor", "foo", "--out", "{out}/it"], ("executor 'foo'", "local, dask")),
    (["iterate", "--workers", "0", "--out", "{out}/it"], ("--workers", "0")),
    (["eval", "timetrial", "--executor", "dask", "--out", "{out}/tt"], ("--scheduler",)),
]


@pytest.mark.parametrize("argv,needles", SETTINGS, ids=[" ".join(a[:3]) for a, _ in SETTINGS])
def test_setting_refused_before_any_work(capsys, tmp_path, argv, needles):
    refused(capsys, [a.format(out=tmp_path) for a in argv], *needles)
    nothing_written(tmp_path)


def _vehicle(tmp_path, old: str, new: str):
    text = (configs_dir() / "vehicles" / "audi_tt_cup.toml").read_text()
    assert old in text
    f = tmp_path / "car.toml"
    f.write_text(text.replace(old, new))
    return f


@pytest.mark.parametrize("old,new,needles", [
    ("steering_max = 0.35", "steering_max = 20.05", ("limits.steering_max", "20.05 rad", "degrees")),
    ("steering_rate_max = 1.0", "steering_rate_max = 57.3", ("limits.steering_rate_max", "57.3", "degrees per second")),
    ("l_f = 1.0234", "l_f = 1023.4", ("l_f", "1023.4 m", "millimetres")),
    ("l_r = 1.4826", "l_r = 1482.6", ("l_r", "1482.6 m", "millimetres")),
])
def test_vehicle_in_wrong_units_is_refused_when_loaded(capsys, tmp_path, old, new, needles):
    car = _vehicle(tmp_path, old, new)
    refused(capsys, ["plan", "--vehicle", car, "-o", tmp_path / "p.h5"], "car.toml", *needles)
    assert not (tmp_path / "p.h5").exists()


def test_plant_with_a_vehicle_in_millimetres_names_the_path(capsys, tmp_path):
    _vehicle(tmp_path, "l_r = 1.4826", "l_r = 1482.6")
    plant = tmp_path / "plant.toml"
    plant.write_text('vehicle = "car.toml"\n')
    refused(capsys, ["simulate", "--plant", plant, "-o", tmp_path / "r.h5"], "plant.toml", "vehicle.l_r", "millimetres")


def test_shipped_vehicles_pass_the_range_checks():
    from gprace.config import load_vehicle

    for f in (configs_dir() / "vehicles").glob("*.toml"):
        assert load_vehicle(f).limits.steering_max < 1.6


# ------------------------------------------------------------------------------------------------
# item 5: nothing left behind by a refused command


def test_iterate_on_a_three_point_track_leaves_no_folder(capsys, tmp_path):
    tri = tmp_path / "tri.csv"
    tri.write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,5,5\n100,0,5,5\n50,80,5,5\n")
    for cmd in (["iterate"], ["eval", "timetrial"]):
        refused(capsys, [*cmd, "--track", tri, "--out", tmp_path / "out"], "tri.csv", "at least 4 points")
        assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------------------
# item 6: what used to be an internal error (exit 1) is a one-line exit 2

OUT_IS_A_FILE = [["iterate"], ["eval", "timetrial"], ["eval", "head2head"], ["h2h", "collect"]]


@pytest.mark.parametrize("cmd", OUT_IS_A_FILE, ids=" ".join)
def test_out_that_is_a_file(capsys, tmp_path, cmd):
    f = tmp_path / "taken.h5"
    f.write_bytes(b"x")
    refused(capsys, [*cmd, "--out", f], "--out", "taken.h5: is a file, not a folder")
    refused(capsys, [*cmd, "--out", f / "sub"], "--out", "taken.h5 is a file, not a folder")
    assert f.read_bytes() == b"x" and [p.name for p in tmp_path.iterdir()] == ["taken.h5"]


def test_artifact_below_a_file(capsys, tmp_path):
    f = tmp_path / "taken.h5"
    f.write_bytes(b"x")
    refused(capsys, ["simulate", "--laps", "0.01", "--track", "circle_100", "-o", f / "r.h5"], "r.h5", "a file is in the way")


def test_report_png_that_is_a_file(capsys, tmp_path):
    f = tmp_path / "taken.png"
    f.write_bytes(b"x")
    refused(capsys, ["report", tmp_path, "--png", f, "-o", tmp_path / "r.html"], "--png", "is a file, not a folder")
    assert not (tmp_path / "r.html").exists()


def test_vehicle_that_is_a_folder(capsys, tmp_path):
    refused(capsys, ["diagnose", tmp_path / "run.h5", "--vehicle", tmp_path], "is a folder, not a TOML file")


def test_h2h_train_without_its_dataset(capsys, tmp_path):
    refused(capsys, ["h2h", "train", tmp_path / "none.h5", tmp_path / "m.h5"], "none.h5", "no such file")
    nothing_written(tmp_path)


@pytest.mark.parametrize("opt,needles", [("max_fit_points=abc", ("max_fit_points", "a number", "'abc'")),
                                         ("optimize=yes", ("optimize", "true or false"))])
def test_retrain_option_of_the_wrong_type(capsys, tmp_path, opt, needles):
    refused(capsys, ["retrain", tmp_path / "none.h5", "--opt", opt, "-o", tmp_path / "m.h5"], "'exact'", *needles)
    nothing_written(tmp_path)


# ------------------------------------------------------------------------------------------------
# item 7: strict JSON, a failed run exits 1, --json on simulate / plan / run


def strict(text: str):
    def no_constant(name):
        raise AssertionError(f"bare {name} in JSON output")

    return json.loads(text, parse_constant=no_constant)


@pytest.fixture(scope="module")
def spun(tmp_path_factory):
    """A curvature plan of circle_100 driven by a car on ice: it leaves the track within a second."""
    d = tmp_path_factory.mktemp("spun")
    text = (configs_dir() / "vehicles" / "audi_tt_cup.toml").read_text()
    assert "mu = 1.5" in text
    (d / "ice.toml").write_text(text.replace("mu = 1.5", "mu = 0.4"))
    (d / "plant.toml").write_text('kind = "frenet"\nvehicle = "ice.toml"\n')
    assert main(["plan", "--curvature", "--track", "circle_100", "-o", str(d / "plan.h5")]) == 0
    return d


def test_run_that_leaves_the_track_exits_1_with_strict_json(capsys, spun):
    out = spun / "run.h5"
    capsys.readouterr()
    code = main(["run", "--plan", str(spun / "plan.h5"), "--plant", str(spun / "plant.toml"), "--laps", "0.3",
                 "-o", str(out), "--json"])
    cap = capsys.readouterr()
    # a start line, then the one error line (a fresh machine also says once that it compiles the
    # MPC's linearisation: machine-level information, not part of the command's contract)
    lines = [ln for ln in cap.err.splitlines() if ln.strip() and not ln.startswith("compiling ")]
    assert code == 1 and len(lines) == 2 and lines[0].startswith("run: driving ") and "left the track" in lines[1], cap.err
    res = strict(cap.out)
    assert res["completed"] is False and res["lap_time"] is None
    assert out.exists()  # the failed run is kept for inspection
    # show --json of that partial lap: null, not NaN
    assert main(["show", str(out), "--json"]) == 0
    info = strict(capsys.readouterr().out)
    assert info["results"]["completed"] is False and info["results"]["lap_time"] is None


def test_plan_and_simulate_print_json(capsys, tmp_path):
    assert main(["plan", "--curvature", "--track", "circle_100", "-o", str(tmp_path / "p.h5"), "--json"]) == 0
    res = strict(capsys.readouterr().out)
    assert res["nodes"] > 20 and res["lap_time"] > 0
    assert main(["simulate", "--track", "circle_100", "--laps", "0.02", "-o", str(tmp_path / "r.h5"), "--json"]) == 0
    res = strict(capsys.readouterr().out)
    assert res["samples"] > 2 and res["lap_times"] == []


def test_console_json_writes_null_for_non_finite_numbers(capsys):
    import numpy as np

    from gprace.console import console

    console.json({"a": float("nan"), "b": [np.float64(np.inf), 1.5], "c": np.array([np.nan, 2.0]), "d": np.bool_(True)})
    assert strict(capsys.readouterr().out) == {"a": None, "b": [None, 1.5], "c": [None, 2.0], "d": True}


# ------------------------------------------------------------------------------------------------
# item 2: samples outside the model's envelope are excluded and reported by select-data and eval gp


@pytest.fixture(scope="module")
def spin_run(tmp_path_factory):
    """A weaving 0.6 lap of circle_100 with a spin in the middle (31 samples of v_y 15 m/s,
    yaw_rate 3 rad/s), and the clean run it came from."""
    import numpy as np

    from gprace.io.runs import Run, read_run, write_run

    d = tmp_path_factory.mktemp("spin")
    clean = d / "clean.h5"
    assert main(["simulate", "--track", "circle_100", "--laps", "0.6", "--weave", "0.3", "-o", str(clean)]) == 0
    r = read_run(clean)
    data = {k: np.array(v) for k, v in r.data.items()}
    a = r.n // 2
    data["v_y"][a:a + 31], data["yaw_rate"][a:a + 31] = 15.0, 3.0
    write_run(Run(data, dict(r.meta), "spin"), d / "spin.h5")
    return d


def test_select_data_and_eval_gp_leave_out_a_spin(capsys, spin_run, tmp_path):
    from gprace.gp.dataset import read_dataset

    def select(name):
        capsys.readouterr()
        out = tmp_path / f"{name}_data.h5"
        assert main(["select-data", str(spin_run / f"{name}.h5"), "--selection", "random", "-o", str(out), "--json"]) == 0
        cap = capsys.readouterr()
        return strict(cap.out), cap.err, read_dataset(out)

    res, err, _ = select("clean")
    assert res["envelope"][0]["samples_excluded"] == 0 and err == ""
    n_clean = res["points"]
    res, err, ds = select("spin")
    env = res["envelope"][0]
    assert env["samples_excluded"] >= 31 and env["excluded"][0]["reason"] == "spin"
    assert res["points"] <= n_clean - 31
    iv = list(ds.input_names).index("v_y")
    assert ds.Z[:, iv].max() < 15.0  # not one spin sample used
    assert err.count("\n") == 1 and "outside the model's envelope" in err and "spin:" in err and "s 1" in err
    # eval gp scores only the samples inside the envelope, and says so
    assert main(["retrain", str(tmp_path / "clean_data.h5"), "--opt", "optimize=false", "-o", str(tmp_path / "m.h5")]) == 0
    capsys.readouterr()
    assert main(["eval", "gp", str(tmp_path / "m.h5"), str(spin_run / "spin.h5"), "--json"]) == 0
    cap = capsys.readouterr()
    res = strict(cap.out)
    assert res["samples"] <= n_clean - 31 and res["envelope"]["samples_excluded"] == env["samples_excluded"]
    assert "outside the model's envelope" in cap.err


# ------------------------------------------------------------------------------------------------
# item 8: help texts


def _commands(cmd, path=()):
    sub = getattr(cmd, "commands", None)
    if sub:
        for name, c in sub.items():
            yield from _commands(c, (*path, name))
    else:
        yield " ".join(path), cmd


def test_every_option_has_help():
    import typer

    from gprace.cli import app

    root = typer.main.get_command(app)
    missing = [f"{name} {p.opts[0]}" for name, cmd in _commands(root) for p in cmd.params
               if p.param_type_name == "option" and not (p.help or "").strip()]
    assert missing == []
    explore = dict(_commands(root))["h2h explore"]
    width_help = next(p.help for p in explore.params if p.opts[0] == "--explore-width")
    assert "--width" not in width_help and not any(p.opts[0] == "--width" for p in explore.params)
    gp_help = next(p.help for p in dict(_commands(root))["select-data"].params if p.opts[0] == "--gp")
    assert "opponent" in gp_help and "h2h collect" in gp_help


def test_eval_is_one_group_and_evaluate_its_hidden_old_name(capsys, tmp_path):
    import typer

    from gprace.cli import app

    root = typer.main.get_command(app)
    ev, old = root.commands["eval"], root.commands["evaluate"]
    assert sorted(ev.commands) == ["gp", "head2head", "iterate", "learn", "timetrial"]
    assert old.hidden and not ev.hidden and sorted(old.commands) == sorted(ev.commands)
    panels = {n: c.rich_help_panel for n, c in ev.commands.items()}
    assert panels["head2head"] == panels["timetrial"] != panels["gp"] == panels["iterate"] == panels["learn"]
    assert main(["--help"]) == 0
    listed = capsys.readouterr().out
    assert "│ eval " in listed and "evaluate" not in listed.split("│ eval ")[0]
    # every command line of the old name still runs the same command, with one warning more
    for group, lines in (("eval", 1), ("evaluate", 2)):
        code = main([group, "iterate", str(tmp_path / "none")])
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert code == 2 and len(err) == lines and err[-1].startswith("error: ") and "none" in err[-1], err
    assert "`gprace evaluate` is now `gprace eval`" in err[0]


def test_flags_are_shown_without_a_value(capsys, monkeypatch):
    """No `<bool>` beside a flag (--json, --resume, --help ...) in the help of any command."""
    import typer

    from gprace.cli import app

    monkeypatch.setenv("COLUMNS", "160")
    assert main(["h2h", "collect", "--help"]) == 0
    rows = {ln.split()[1]: ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("│ --")}
    assert "<bool>" not in rows["--json"] and "<bool>" not in rows["--resume"] and "<int>" in rows["--runs"]
    assert "<bool>" not in rows["--help"]
    for name, _ in [("", None), *_commands(typer.main.get_command(app))]:
        assert main([*name.split(), "--help"]) == 0
        assert "<bool>" not in capsys.readouterr().out, name


def test_one_row_number_for_one_sample_in_every_csv_error(tmp_path):
    """The same sample of a CSV run is 'row 2 (line 3)' whether its value is text or NaN."""
    import numpy as np

    from gprace.errors import InputError
    from gprace.io.runs import RUN_COLUMNS, read_run

    rows = np.tile(np.arange(1.0, 1.0 + len(RUN_COLUMNS)), (4, 1))
    rows[:, 0] = np.arange(4) * 0.05

    def write(cell: str):
        lines = [",".join(RUN_COLUMNS)] + [",".join(f"{v:g}" for v in r) for r in rows]
        cols = lines[2].split(",")
        cols[RUN_COLUMNS.index("v_y")] = cell
        lines[2] = ",".join(cols)
        p = tmp_path / "r.csv"
        p.write_text("\n".join(lines) + "\n")
        return p

    for cell in ("abc", "nan"):
        with pytest.raises(InputError, match=r"'v_y'.* row 2\b") as exc:
            read_run(write(cell))
        assert "row 3" not in str(exc.value)


def test_track_and_raw_csv_readers_count_rows_as_the_run_reader(tmp_path):
    """A track CSV (comment header) and a raw global-frame CSV name their second sample
    'row 2 (line 3)', as the run reader does."""
    from gprace.errors import InputError
    from gprace.ingest.mapping import RecordingMap
    from gprace.ingest.readers import read_csv
    from gprace.tracks import load_track

    track = tmp_path / "t.csv"
    track.write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,5,5\n100,abc,5,5\n100,80,5,5\n0,80,5,5\n")
    with pytest.raises(InputError, match=r"column 'y_m' row 2 \(line 3\): 'abc' is not a number"):
        load_track(track)
    raw = tmp_path / "log.csv"
    raw.write_text("time,x,y\n0,0,0\n0.1,abc,0\n0.2,2,0\n")
    with pytest.raises(InputError, match=r"column 'x' row 2 \(line 3\): 'abc' is not a number"):
        read_csv(raw, RecordingMap.model_validate({"columns": {"t": "time"}}))


def test_gp_settings_check_leaves_arrays_and_numbers_alone():
    import numpy as np

    from gprace.gp.base import make_gp

    gp = make_gp("exact", length_scale=np.ones((2, 3)), noise=np.full(2, 1e-2), max_fit_points=50, optimize=False)
    assert gp.max_fit_points == 50


# ------------------------------------------------------------------------------------------------
# item 9: failures are not hidden in the lap-time summary figure


def test_lap_time_figure_counts_failed_laps_per_iteration():
    import numpy as np

    from gprace.report import figures as F

    nan = float("nan")
    it = np.array([0, 0, 0, 1, 1, 1, 2, 2, 2])
    planned = np.full(9, 30.0)
    driven = np.array([31.0, 32.0, 33.0, nan, nan, nan, 30.0, nan, nan])  # iteration 1: 0 of 3; 2: 1 of 3
    fig = F.fig_lap_times({"exploration": {"iteration": it, "planned": planned, "driven": driven}})
    for ax in fig.axes[1:]:
        texts = sorted(t.get_text() for t in ax.texts)
        assert texts == ["2/3 failed", "3/3 failed"], texts
        assert any("failed laps (5 of 9)" in t.get_text() for t in ax.get_legend().get_texts())
    np.testing.assert_allclose(fig.axes[1].get_lines()[0].get_xdata(), [0, 2])  # no mean where none finished
    clean = F.fig_lap_times({"exploration": {"iteration": it[:3], "planned": planned[:3], "driven": driven[:3]}})
    assert not clean.axes[1].texts


def test_long_gp_stages_say_they_started(capsys, tmp_path):
    """Off a terminal there is no progress bar: the quick fit and the GP fit each print a start line
    (and -q silences them)."""
    data, run = tmp_path / "d.h5", tmp_path / "r.h5"
    assert main(["simulate", "--track", "circle_100", "--laps", "0.15", "--weave", "0.3", "-o", str(run)]) == 0
    assert main(["select-data", str(run), "--max-points", "30", "-o", str(data)]) == 0
    assert "select-data: quick GP fit on" in capsys.readouterr().err
    assert main(["retrain", str(data), "--opt", "optimize=false", "-o", str(tmp_path / "m.h5")]) == 0
    assert "retrain: fitting the exact GP on 30 points" in capsys.readouterr().err
    try:
        assert main(["-q", "retrain", str(data), "--opt", "optimize=false", "-o", str(tmp_path / "m.h5")]) == 0
        assert capsys.readouterr().err == ""
    finally:
        from gprace.console import console

        console.quiet = False


def test_a_long_stage_prints_one_start_line_off_a_terminal_and_json_stays_pure(capsys, tmp_path):
    """Off a terminal: a start line per stage on stderr (also what a progress bar becomes), stdout
    pure JSON with --json; -q silences the start lines."""
    from gprace.console import Console, console

    c = Console()
    with c.progress("report: rendering 3 figures", total=3) as bar:
        bar.advance()
    assert capsys.readouterr().err == "report: rendering 3 figures\n"
    argv = ["plan", "--curvature", "--track", "circle_100", "-o", str(tmp_path / "p.h5"), "--json"]
    assert main(argv) == 0
    cap = capsys.readouterr()
    assert strict(cap.out)["nodes"] > 20
    assert cap.err == "plan: minimum-curvature path on 105 nodes of circle_100\n"
    try:
        assert main(["-q", *argv]) == 0
        cap = capsys.readouterr()
        assert cap.err == "" and strict(cap.out)["nodes"] > 20
    finally:
        console.quiet = False


# ------------------------------------------------------------------------------------------------
# item 9: every table that summarises laps or races says how many failed and where

SPIN = "the car spun at s = 427.6 m (e_psi = 0.36 rad, v_y = -18.5 m/s)"


def _laps():
    """Two trials, iterations 0 and 1; iteration 1 trial 0 spun."""
    rows = [{"iteration": i, "trial": j, "alpha": 0.0, "planned": 50.0, "driven": 52.0 if (i, j) != (1, 0) else None,
             "completed": (i, j) != (1, 0), "reason": SPIN if (i, j) == (1, 0) else ""}
            for i in (0, 1) for j in (0, 1)]
    by_it = [{"iteration": i, "alpha": 0.0, "trials": 2, "completed": 2 - i,
              "failed": [{"trial": 0, "reason": SPIN}] if i else []} for i in (0, 1)]
    return rows, by_it


def test_lap_tables_count_and_place_failed_laps(capsys, tmp_path):
    from gprace.report import collect
    from gprace.report.sections.timetrial import timetrial_section
    from gprace.cli.timetrial import _print_summary
    from gprace.timetrial.compare import COLUMNS, format_table
    from gprace.timetrial.iterate import IterateSettings, build_summary, failed_laps_text
    from gprace.timetrial.record import IterationRecord, write_json, write_record

    rows, by_it = _laps()
    want = f"iteration 1: 1 of 2 laps failed: trial 0: {SPIN}"
    assert failed_laps_text(by_it) == [want]
    # eval iterate: the per-iteration table is followed by the failed laps
    _print_summary({"rows": rows, "by_iteration": by_it, "oracle": None, "per_trial": []}, False)
    assert want in capsys.readouterr().out
    # eval timetrial
    vrows = [{**{k: 1.0 for _, k in COLUMNS}, **a, "laps": a["trials"]} for a in by_it]
    text = format_table({"plant": "p", "track": "t", "trials": 2, "iterations": 1, "features": "full", "oracle": None,
                         "variants": {"exploration": vrows}})
    assert f"  {want}" in text
    # show summary.json (the folder of `gprace iterate`: settings, records, the summary built from them)
    d = tmp_path / "exploration"
    d.mkdir()
    write_json(d / "settings.json", IterateSettings(alphas=(0.0,), iterations=1, trials=2).model_dump(mode="json"))
    for r in rows:
        (d / f"trial_{r['trial']}" / f"iter_{r['iteration']:02d}").mkdir(parents=True)
        write_record(d / f"trial_{r['trial']}" / f"iter_{r['iteration']:02d}" / "record.json",
                     IterationRecord(**{**r, "driven": float("nan") if r["driven"] is None else r["driven"]}))
    write_json(d / "summary.json", build_summary(d))
    assert build_summary(d)["by_iteration"][1]["failed"] == by_it[1]["failed"]
    assert main(["show", str(d / "summary.json"), "--json"]) == 0
    res = strict(capsys.readouterr().out)["results"]
    assert res["laps completed per iteration"] == "0: 2/2, 1: 1/2" and res["failed laps"] == [want]
    # the report's lap table: a count per iteration in its title, and where in the failed row
    sec = timetrial_section(collect.scan(tmp_path))
    item = next(it for it in sec.items if it.caption.startswith("Lap times per iteration and trial"))
    assert "failed laps per iteration: exploration iteration 1: 1/2" in item.caption
    assert f"failed: {SPIN}" in item.html and item.html.count("completed") == 3


def test_race_tables_count_and_place_failed_races(capsys, tmp_path):
    from gprace.cli.h2h import print_table
    from gprace.h2h.table import TABLE_VERSION, RacingRow, failed_races_text

    row = {"runs": 3, "failed": 1, "failed_where": [{"scenario": 2, "reason": "SolverError: NMPC infeasible"}],
           "border_hits": 0, "collisions": 0, "overtakes": 1, "overtake_time_mean": 3.0, "overtake_time_std": 0.1,
           "overtake_scenarios": 1, "fallbacks_ego": 0, "ego_solve_ms_median": 2.0}
    assert failed_races_text(RacingRow(**row)) == "1 of 3: scenario 2: SolverError: NMPC infeasible"
    tab = {"version": TABLE_VERSION, "settings": {}, "common_inside": 2, "racing": {"explore": row}, "ey_error": {}}
    print_table(tab, False)
    assert "explore: failed races 1 of 3: scenario 2: SolverError: NMPC infeasible" in capsys.readouterr().out
    (tmp_path / "table.json").write_text(json.dumps(tab))
    assert main(["show", str(tmp_path / "table.json"), "--json"]) == 0
    res = strict(capsys.readouterr().out)["results"]
    assert res["explore: failed races"] == failed_races_text(RacingRow(**row))


def test_a_signal_after_the_command_is_one_line_and_exit_130_not_a_silent_kill():
    """Python's own shutdown of a command's process took about a second (freeing every module);
    a SIGTERM in that second killed it without a word (exit -15). The CLI now ends the process
    itself once the command has ended: a signal after the command is noted and turned into exit
    130 and one line; without one the command's code stands."""
    import subprocess
    import sys

    code = ("import os, signal, sys\n"
            "from gprace import interrupt\n"
            "with interrupt.handled(process=True):\n"
            "    pass\n"
            "if sys.argv[1] == 'late':\n"
            "    os.kill(os.getpid(), signal.SIGTERM)\n"
            "    os.kill(os.getpid(), signal.SIGINT)\n"
            "interrupt.exit_process(int(sys.argv[2]), lambda: print('error: interrupted; finished', file=sys.stderr))\n"
            "print('not reached')\n")
    for when, given, want, lines in (("late", 0, 130, ["error: interrupted; finished"]), ("none", 0, 0, []),
                                     ("late", 2, 2, []), ("none", 2, 2, [])):
        r = subprocess.run([sys.executable, "-c", code, when, str(given)], capture_output=True, text=True, timeout=60)
        assert (r.returncode, r.stderr.splitlines(), r.stdout) == (want, lines, ""), (when, given, r)


def test_brackets_in_help_texts_are_shown():
    """Help texts are rendered as rich markup, which dropped a unit (`resampled to [s]` read
    `resampled to .`) or a list of inputs with its brackets."""
    import re

    from gprace.cli import main

    for argv, needle in ((["learn", "--help"], "[s]"), (["import", "--help"], "track [m]"),
                         (["select-data", "--help"], "[v_y, yaw_rate, delta]")):
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            assert main(argv) == 0
        text = re.sub(r"\s*│\s*", " ", buf.getvalue())
        assert needle in text and "\\[" not in text, (argv, needle)
