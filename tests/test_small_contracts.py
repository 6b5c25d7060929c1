"""Issue 38, item 7 (and the sizes of item 2): `show` tells every file kind apart, options are named
as the CLI spells them, -q works after the subcommand, simulate names its plant, every command's
outputs are declared, and no size reaches the user as a MemoryError or OverflowError."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gprace.cli import main


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("GPRACE_DEBUG", raising=False)


def run_json(capsys, argv) -> dict:
    assert main(["-q", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A small set of real outputs: a run, a plan, a dataset and a model, and an iterate folder."""
    from test_report_data import make_iterate

    d = tmp_path_factory.mktemp("kinds")
    assert main(["-q", "simulate", "--track", "circle_100", "--laps", "0.4", "--weave", "0.3", "-o", str(d / "run.h5")]) == 0
    assert main(["-q", "select-data", str(d / "run.h5"), "--vehicle", "audi_tt_cup", "--selection", "random",
                 "--max-points", "60", "-o", str(d / "data.h5")]) == 0
    assert main(["-q", "retrain", str(d / "data.h5"), "-o", str(d / "model.h5")]) == 0
    make_iterate(d, "it", iterations=2, trials=1)
    return d


def test_show_tells_every_json_kind_apart(made, tmp_path, capsys):
    """Every JSON gprace writes or prints gets its own kind (settings.json and a simulate --json
    were both 'timetrial_summary' before)."""
    from gprace.h2h.spread import fit_calibration
    from gprace.report.inspect import JSON_KINDS, json_kind
    from gprace.timetrial.iterate import oracle_lap, IterateSettings
    from gprace.timetrial.record import write_json

    d = made
    printed = {
        "simulate_result": ["simulate", "--track", "circle_100", "--laps", "0.2", "-o", tmp_path / "s.h5"],
        "plan_result": ["plan", "--curvature", "--track", "circle_100", "-o", tmp_path / "p.h5"],
        "select_data_result": ["select-data", d / "run.h5", "--vehicle", "audi_tt_cup", "--selection", "random",
                               "-o", tmp_path / "d.h5"],
        "retrain_result": ["retrain", d / "data.h5", "-o", tmp_path / "m.h5"],
        "eval_gp_result": ["eval", "gp", d / "model.h5", d / "run.h5"],
        "track_show_result": ["track", "show", "circle_100"],
        "show_result": ["show", d / "run.h5"],
    }
    files = {kind: run_json(capsys, argv) for kind, argv in printed.items()}
    files["iterate_settings"] = json.loads((d / "it" / "settings.json").read_text())
    files["iteration_record"] = json.loads((d / "it" / "trial_0" / "iter_01" / "record.json").read_text())
    files["timetrial_summary"] = json.loads((d / "it" / "summary.json").read_text())
    files["oracle_lap"] = oracle_lap(IterateSettings(plant="bmw_commonroad", vehicle="bmw_320i"))  # unknown physics
    rng = np.random.default_rng(0)
    cal = fit_calibration(rng.random((2, 3, 20)), rng.random((2, 3, 20)))
    files["h2h_calibration"] = {"cv": cal, "baseline": cal}
    files["h2h_calibration_passes"] = [{"pass": 2, "settled": True, "drove_with": {"cv": cal}, "fitted": {"cv": cal}}]
    for kind, obj in files.items():
        path = tmp_path / f"{kind}.json"
        write_json(path, obj)
        assert json_kind(json.loads(path.read_text())) == kind, kind
        assert main(["show", str(path), "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["kind"] == kind
    assert len({k for k, _, _ in JSON_KINDS}) == len(JSON_KINDS)
    assert json_kind({"anything": 1}) == "json"


def test_the_report_still_finds_an_interrupted_iterate_folder_by_its_settings(made, tmp_path):
    import shutil

    from gprace.report.collect import scan
    from gprace.report.sections.timetrial import timetrial_variants

    d = tmp_path / "it"
    shutil.copytree(made / "it", d)
    (d / "summary.json").unlink()  # interrupted before its summary
    v = timetrial_variants(scan(tmp_path))
    assert list(v) == [d] and v[d]["rows_from"] == "record.json files"


def test_quiet_after_the_subcommand(capsys, tmp_path):
    assert main(["simulate", "--track", "circle_100", "--laps", "0.2", "-o", str(tmp_path / "r.h5"), "-q"]) == 0
    assert capsys.readouterr().err == ""  # no start line
    assert main(["simulate", "--track", "circle_100", "--laps", "0.2", "-o", str(tmp_path / "r.h5")]) == 0
    assert "simulate: driving" in capsys.readouterr().err


def test_simulate_names_the_plant_as_configured(capsys, tmp_path):
    assert main(["-q", "simulate", "--plant", "audi_hidden", "--track", "circle_100", "--laps", "0.2",
                 "-o", str(tmp_path / "r.h5")]) == 0
    assert "plant audi_hidden (frenet)" in capsys.readouterr().out
    res = run_json(capsys, ["simulate", "--plant", "audi_hidden", "--track", "circle_100", "--laps", "0.2",
                            "-o", tmp_path / "r.h5"])
    assert res["plant"] == "audi_hidden" and res["plant_kind"] == "frenet"


@pytest.mark.parametrize("argv,needle", [
    (["iterate", "--dictionary-size", "0"], "--dictionary-size must be >= 10"),
    (["iterate", "--alpha", "nan"], "--alpha"),
    (["run", "--plan", "p.h5", "--alpha", "nan"], "--alpha"),
    (["run", "--plan", "p.h5", "--beta", "1.5"], "--beta must be < 1"),
    (["simulate", "--weave", "1.5"], "--weave must be <= 1"),
    (["eval", "head2head", "--max-time", "inf"], "--max-time"),
])
def test_messages_name_the_options_as_the_cli_spells_them(capsys, tmp_path, argv, needle):
    if argv[0] in ("simulate", "run"):
        argv = [*argv, "-o", str(tmp_path / "x.h5")]
    else:
        argv = [*argv, "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err
    assert not (tmp_path / "o").exists()


def _commands(cmd, path=()):
    for name, sub in (getattr(cmd, "commands", None) or {}).items():
        yield from _commands(sub, (*path, name))
    if not getattr(cmd, "commands", None):
        yield " ".join(path), cmd


def _is_path(param) -> bool:
    """A parameter typed as a path (typer's annotation where it keeps one, click's type otherwise)."""
    annotation = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    if annotation is not None:
        return "Path" in str(annotation)
    return "path" in getattr(getattr(param, "type", None), "name", "").lower()


def test_every_path_of_every_command_is_declared_input_or_output():
    """A new command (or option) that writes must say so in gprace.cli.OUTPUTS, so its output is
    checked before any work and its run folder locked."""
    import typer

    from gprace.cli import INPUTS, OUTPUTS, registered

    root = typer.main.get_command(registered())
    undeclared, seen = [], 0
    for name, cmd in _commands(root):
        if name.startswith("evaluate "):
            continue  # the hidden old name of eval
        for p in cmd.params:
            if _is_path(p) or p.name in ("out", "output", "csv", "plot", "png"):
                seen += 1
                if p.name not in OUTPUTS.get(name, {}) and p.name not in INPUTS.get(name, ()):
                    undeclared.append(f"{name} {p.name}")
    assert not undeclared, undeclared
    assert seen >= 30  # the paths of every command (46 in the 2026-11 CLI), not an empty walk
    assert set(OUTPUTS) <= {n for n, _ in _commands(root)}


@pytest.mark.parametrize("argv,needles", [
    (["simulate", "--laps", "inf", "-o", "{d}/r.h5"], ("--laps", "finite")),
    (["simulate", "--laps", "1e9", "-o", "{d}/r.h5"], ("--laps 1e+09", "of memory", "laps fit")),
    (["simulate", "--dt", "1e-9", "-o", "{d}/r.h5"], ("--dt 1e-09", "of memory")),
    (["iterate", "--dictionary-size", "1000000000", "--out", "{d}/it"], ("--dictionary-size 1000000000", "points fit")),
    (["eval", "timetrial", "--dictionary-size", "1000000000", "--out", "{d}/tt"], ("--dictionary-size", "points fit")),
    (["eval", "head2head", "--dict-size", "1000000000", "--out", "{d}/h"], ("--dict-size 1000000000", "points fit")),
])
def test_sizes_beyond_the_machine_are_refused_before_any_work(capsys, tmp_path, argv, needles):
    assert main([a.format(d=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    for n in needles:
        assert n in err[0], (n, err[0])
    assert list(tmp_path.iterdir()) == []


def test_the_largest_size_named_is_the_largest_that_fits(monkeypatch):
    from gprace import resources
    from gprace.errors import InputError
    from gprace.gp.selection import selector_bytes

    monkeypatch.setattr(resources, "available_memory", lambda: 50_000_000)
    need = lambda m: selector_bytes(m, 2, 3)  # noqa: E731
    with pytest.raises(InputError, match="at most") as exc:
        resources.check_size("--max-points 100000", 100_000, need, " points")
    top = int(str(exc.value).split("at most ")[1].split(" ")[0].replace(",", ""))
    assert need(top) <= 0.8 * 50_000_000 < need(top + 1)
    resources.check_size("--max-points 100", 100, need)  # fits: no error


def test_a_dictionary_larger_than_the_data_keeps_all_of_it_at_the_cost_of_the_data(monkeypatch):
    """select-data --max-points 100000 on a recording of 1,604 samples raised MemoryError: the
    selector made room for 100000 points. It now makes room for the points there are, and keeps
    them all, as a dictionary below its size always did."""
    from gprace.gp.base import GPHyper
    from gprace.gp import selection

    rng = np.random.default_rng(1)
    Z, Y = rng.normal(size=(300, 3)), rng.normal(size=(300, 2))
    hyper = GPHyper(kernel="se", log_ls=np.zeros((2, 3)), log_sf2=np.zeros(2), log_sn2=np.full(2, -4.0),
                    z_mean=np.zeros(3), z_scale=np.ones(3), y_mean=np.zeros(2), y_scale=np.ones(2))
    made = []
    real = selection.DiverseSelector

    class Spy(real):
        def __init__(self, hyper, M, *a, **k):
            made.append(M)
            super().__init__(hyper, M, *a, **k)

    monkeypatch.setattr(selection, "DiverseSelector", Spy)
    Zb, Yb, st = selection.select_diverse(hyper, Z, Y, 100_000, outlier_kappa=None)
    Zs, Ys, _ = selection.select_diverse(hyper, Z, Y, 300, outlier_kappa=None)
    assert made == [300, 300] and len(Zb) == 300 and st.inserted == 300
    np.testing.assert_array_equal(Zb, Zs)


def test_show_tells_the_kinds_of_learn_apart(made, tmp_path, capsys):
    """The files of issue 39 (racelines in both formats, the portable GP and its card, the MCAP of
    --mcap, a learn folder and its JSON) and the inputs beside them (a centre line, an x/y path,
    the configuration TOMLs), each written by its real writer, get a kind of their own."""
    from gprace.config import configs_dir, load_vehicle
    from gprace.gp.export import export_gp
    from gprace.io.foxglove import write_runs
    from gprace.io.runs import read_run
    from gprace.learn.workflow import LearnSettings, car_identity, write_json
    from gprace.model import NominalModel
    from gprace.plan import curvature_plan
    from gprace.timetrial.learning import load_predictor
    from gprace.tracks import load_track
    from gprace.tracks.raceline import raceline_of_plan, write_raceline

    tr, d = load_track("circle_100"), tmp_path
    plan = curvature_plan(tr, NominalModel(load_vehicle("audi_tt_cup")), ds=5.0, speed_scale=0.7)
    rl = raceline_of_plan(plan, tr)
    files = {write_raceline(d / "a_tum.csv", rl, "tum"): "raceline", write_raceline(d / "a_f1.csv", rl, "f1tenth"): "raceline"}
    try:
        export_gp(load_predictor(made / "model.h5", "tracking"), d / "gp.portable.h5", d / "gp.card.json", dt=0.05)
        files |= {d / "gp.portable.h5": "portable_gp", d / "gp.card.json": "portable_gp_card"}
    except Exception as exc:  # noqa: BLE001 -- the model of `made` must export; say why if not
        pytest.fail(f"the portable GP could not be written: {exc}")
    files[write_runs(d / "laps.mcap", tr, {"lap": read_run(made / "run.h5")})] = "foxglove_mcap"
    out = d / "learned"
    (out / "iter_01").mkdir(parents=True)
    write_json(out / "learn.json", car_identity(load_vehicle("audi_tt_cup"), tr, LearnSettings(track="circle_100",
                                                                                                 vehicle="audi_tt_cup")))
    write_json(out / "iter_01" / "sources.json", {"recordings": [{"path": "lap.csv", "sha256": "0" * 64}]})
    files |= {out: "learn_folder", out / "learn.json": "learn_identity", out / "iter_01" / "sources.json": "learn_sources"}
    smp = tr.sample(5.0)
    np.savetxt(d / "centre.csv", np.column_stack([smp.x, smp.y, tr.width_right(smp.s), tr.width_left(smp.s)]),
               delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m", fmt="%.4f")
    np.savetxt(d / "path.csv", np.column_stack([smp.x, smp.y]), delimiter=",", header="x_m,y_m", fmt="%.4f")
    files |= {d / "centre.csv": "track", d / "path.csv": "polyline"}
    (d / "map.toml").write_text('[columns]\nyaw_rate = "gyro_z"\n')
    files |= {configs_dir() / "vehicles" / "audi_tt_cup.toml": "vehicle_config", configs_dir() / "plants" / "audi_hidden.toml":
              "plant_config", configs_dir() / "tracks" / "circle_100.toml": "track_config", d / "map.toml": "recording_map"}
    for path, kind in files.items():
        assert main(["show", str(path), "--json"]) == 0, capsys.readouterr().err
        assert json.loads(capsys.readouterr().out)["kind"] == kind, path
    assert main(["show", str(out / "iter_01")]) == 2  # a folder that is not a learn folder: the report's
    assert "gprace report" in capsys.readouterr().err
