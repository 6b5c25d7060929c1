"""The diagnosis result: one schema, versioned, with the residual profile stored so that no reader
simulates it again; an old layout is read with a warning (issue 18)."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from gprace.cli import main
from gprace.diagnose.result import RESULT_VERSION, DiagnosisResult, parse_result, read_result
from gprace.errors import InputError

OLD = Path(__file__).parent / "data" / "diagnosis_before_schema.json"
"""``gprace diagnose --json`` of before the schema (the road grade case below, 2 laps)."""


@pytest.fixture(scope="module")
def diag(tmp_path_factory):
    """A road grade hidden in two laps of the 628 m circle, diagnosed through the CLI (~7 s)."""
    from gprace.config import EffectConfig, load_vehicle
    from gprace.diagnose.synth import record
    from gprace.io.runs import write_run
    from gprace.tracks import load_track

    d = tmp_path_factory.mktemp("diag")
    grade = EffectConfig(name="road_grade", params={"angle": 0.06, "s_start": 200.0, "s_end": 350.0})
    rec = write_run(record(load_vehicle("audi_tt_cup"), load_track("circle_100"), [grade], laps=2, seed=3),
                    d / "rec.h5")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["-q", "diagnose", str(rec), "--vehicle", "audi_tt_cup", "--json", "-o", str(d / "aug.toml"),
                     "--plot", str(d / "res.png")])
    assert code == 0
    return {"dir": d, "rec": rec, "text": buf.getvalue()}


def test_the_printed_json_validates_round_trips_and_keeps_every_key(diag, capsys):
    obj = json.loads(diag["text"])
    assert obj["version"] == RESULT_VERSION
    assert set(json.loads(OLD.read_text())) | {"version", "residual_profile", "inputs", "calibration", "partial_effects"} == set(obj)
    assert [e["name"] for e in obj["effects"]] == ["road_grade"]
    assert "heldout_rmse_nominal" not in obj["channels"][3] and "regime" not in obj["channels"][1]  # as before
    r = parse_result(obj, "diagnosis.json")
    assert capsys.readouterr().err == ""  # the current layout: no warning
    assert r.to_json() == obj
    p = diag["dir"] / "diagnosis.json"
    p.write_text(diag["text"])
    assert read_result(p).to_json() == obj
    from gprace.diagnose.report import summary_lines

    assert summary_lines(r) == summary_lines(obj) and summary_lines(r)[0] == "verdict: mismatch"
    assert (diag["dir"] / "res.png").stat().st_size > 10_000  # --plot drew the stored profile


def test_the_stored_profile_is_the_track_profile_of_the_diagnosed_data(diag):
    """Recomputed here from the stages (the report never does): nominal errors and the noise twin
    from the screening, the augmented model from the written vehicle file."""
    from gprace.config import load_vehicle
    from gprace.diagnose.core import CHANNELS, DYNAMIC
    from gprace.diagnose.diagnose import HORIZON, evaluate, prepare, screen
    from gprace.diagnose.locate import BIN_METRES, track_profile
    from gprace.io.runs import read_run
    from gprace.model import NominalModel

    prof = parse_result(json.loads(diag["text"]), "diagnosis.json").residual_profile
    vehicle = load_vehicle("audi_tt_cup")
    p = prepare([read_run(diag["rec"])], HORIZON)
    s = screen(p, vehicle, 0)
    aug = evaluate(p, NominalModel(load_vehicle(diag["dir"] / "aug.toml")), s.sigma, 2, scale=s.scale)
    assert prof.bin_m == BIN_METRES and list(prof.before) == [CHANNELS[c] for c in DYNAMIC]
    for c in DYNAMIC:
        ch = CHANNELS[c]
        sb, before = track_profile(p.data, p.starts, p.H, s.nominal.Ed, c)
        _, after = track_profile(p.data, p.starts, p.H, aug.Ed, c)
        np.testing.assert_allclose(prof.s, sb, rtol=0, atol=0.05)
        np.testing.assert_allclose(prof.before[ch], before, rtol=1e-4, atol=1e-12)  # 5 significant digits
        np.testing.assert_allclose(prof.after[ch], after, rtol=1e-4, atol=1e-12)
        assert prof.noise[ch] == pytest.approx(np.sqrt(np.mean(s.nominal.Et[..., c] ** 2)), rel=1e-4)
    # the grade: v_x slower than the flat-road model inside the window, explained after
    inside = (np.array(prof.s) > 230) & (np.array(prof.s) < 330)
    assert np.nanmean(np.array(prof.before["v_x"])[inside]) < -0.15
    assert np.nanmax(np.abs(np.array(prof.after["v_x"])[inside])) < 0.05


def test_an_old_result_is_read_with_one_warning_and_defaults(tmp_path, capsys):
    p = tmp_path / "diagnosis.json"
    shutil.copy(OLD, p)
    r = read_result(p)
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and f"layout before version {RESULT_VERSION}" in err
    assert p.read_bytes() == OLD.read_bytes()  # read, never rewritten
    assert r.version == RESULT_VERSION and r.residual_profile is None
    old = json.loads(OLD.read_text())
    assert {k: v for k, v in r.to_json().items() if k in old} == old  # what it held is kept
    # a hand-trimmed layout (the report's test data): everything but verdict and channels defaults
    trimmed = parse_result({"verdict": "mismatch", "channels": [
        {"name": "v_x", "structured": True, "statistic": 14.2, "rmse_nominal": 0.21}]}, "trimmed.json")
    assert trimmed.effects == [] and trimmed.notes == [] and trimmed.horizon == 0
    assert trimmed.channels[0].heldout_rmse_nominal is None and np.isnan(trimmed.channels[0].rmse_noise_floor)


def test_the_report_notes_the_missing_profile_instead_of_recomputing(diag, tmp_path, capsys, monkeypatch):
    """The old JSON beside the recording it was made from: the old report recomputed the residuals
    from it; now the page says the result predates the stored profile."""
    from gprace.diagnose import core

    d = tmp_path / "old"
    d.mkdir()
    shutil.copy(OLD, d / "diagnosis.json")
    shutil.copy(diag["rec"], d / "rec.h5")

    def no_simulation(*a, **k):
        raise AssertionError("the report must not simulate")

    monkeypatch.setattr(core, "predict", no_simulation)
    monkeypatch.setattr(core, "build_dataset", no_simulation)
    out = tmp_path / "r.html"
    assert main(["report", str(d), "-o", str(out)]) == 0
    html = out.read_text()
    assert "residual-along-track plot not drawn (the result predates the stored residual profile" in html
    assert "rerun `gprace diagnose ... --json`" in html
    assert "road_grade" in html  # the rest of the result is drawn
    assert capsys.readouterr().err.count(f"layout before version {RESULT_VERSION}") == 1


@pytest.mark.parametrize("change, words", [
    ({"version": RESULT_VERSION + 1}, f"version {RESULT_VERSION + 1} is newer than this gprace reads"),
    ({"verdict": "maybe"}, "verdict"),
    ({"channels": [{"name": "v_x", "structured": True, "statistic": "high", "rmse_nominal": 0.1}]},
     "channels.0.statistic"),
    ({"effects": [{"name": "road_grade", "parameters": {"angle": {"value": 0.05, "ci95": [0.04]}}}]},
     "effects.0.parameters.angle.ci95"),
    ({"runtime": 3.0}, "runtime"),  # a key the schema does not know
])
def test_a_bad_result_is_one_line_and_one_line_in_the_report(tmp_path, change, words):
    data = {**json.loads(OLD.read_text()), **change}
    with pytest.raises(InputError, match=words) as exc:
        parse_result(data, "diagnosis.json")
    assert "\n" not in str(exc.value)
    d = tmp_path / "bad"
    d.mkdir()
    (d / "diagnosis.json").write_text(json.dumps(data))
    out = tmp_path / "r.html"
    assert main(["report", str(d), "-o", str(out)]) == 0  # never a crash
    assert "not read as a diagnosis result" in out.read_text()


def test_the_schema_documents_every_field():
    from pydantic import BaseModel

    seen, todo = set(), [DiagnosisResult]
    while todo:
        m = todo.pop()
        seen.add(m)
        for name, f in m.model_fields.items():
            assert f.description, f"{m.__name__}.{name} has no description"
        todo += [t for t in _models(m) if t not in seen and issubclass(t, BaseModel)]
    assert len(seen) >= 8


def _models(model) -> list[type]:
    """Model classes a model's fields refer to (through lists, dicts and optionals)."""
    import typing

    out = []
    for f in model.model_fields.values():
        stack = [f.annotation]
        while stack:
            t = stack.pop()
            if isinstance(t, type):
                out.append(t)
            stack += list(typing.get_args(t))
    return out
