"""The time trial's records: the iteration record (one schema, versioned; an old layout migrates once)
and the run summary built from them (issue 18)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest

from gprace.console import jsonable
from gprace.errors import InputError
from gprace.timetrial.record import (RECORD_VERSION, SUMMARY_VERSION, IterationRecord, read_record, read_summary,
                                    write_json, write_record)

OLD = Path(__file__).parent / "data" / "record_before_schema.json"


def test_an_old_record_is_migrated_once_with_a_warning(tmp_path, capsys):
    p = tmp_path / "record.json"
    shutil.copy(OLD, p)
    rec = read_record(p, migrate=False)  # a reader that only looks leaves the file as it is
    assert "missing fields set to their defaults" in capsys.readouterr().err
    assert p.read_bytes() == OLD.read_bytes()
    rec = read_record(p)
    assert "migrated" in capsys.readouterr().err
    # what the old file held is kept; null is NaN; the fields it lacked take their defaults
    assert (rec.iteration, rec.trial, rec.border_hits, rec.completed) == (2, 1, 3, False)
    assert math.isnan(rec.driven) and math.isnan(rec.gap) and math.isnan(rec.cov_tracking)
    assert rec.limits == [] and rec.replan_failed is False and rec.version == RECORD_VERSION
    on_disk = json.loads(p.read_text())
    assert on_disk["version"] == RECORD_VERSION and on_disk["driven"] is None
    assert jsonable(read_record(p).model_dump()) == jsonable(rec.model_dump())  # NaN as null: equal where both are NaN
    assert capsys.readouterr().err == ""  # migrated once: no second warning


def test_a_record_round_trips_with_nan_as_null(tmp_path):
    rec = IterationRecord(iteration=1, trial=0, alpha=0.5, planned=18.75, driven=float("nan"), completed=False,
                          gap=float("nan"), solve_median_ms=2.0, solve_p99_ms=7.0, border_hits=0, fallbacks=1,
                          samples=300, limits=[10.9, 6.0, 10.3], envelope=[11.3, 1.0, 0.0], utilisation=0.39)
    p = tmp_path / "record.json"
    write_record(p, rec)
    assert json.loads(p.read_text())["driven"] is None
    back = read_record(p)
    assert jsonable(back.model_dump()) == jsonable(rec.model_dump())
    assert not list(tmp_path.glob(".*tmp"))  # written atomically


def test_a_read_record_is_a_frozen_model_and_rewrites_to_the_same_bytes(tmp_path):
    """The reader gives the model, not a dict: nothing can be set on it, a changed copy is
    ``model_copy(update=)``, and writing back what was read gives the file byte for byte."""
    from pydantic import ValidationError

    p, q = tmp_path / "record.json", tmp_path / "again.json"
    shutil.copy(OLD, p)
    rec = read_record(p)  # migrated: now in the writer's layout
    assert isinstance(rec, IterationRecord)
    with pytest.raises(ValidationError):
        rec.driven = 60.0
    with pytest.raises(TypeError):
        rec["driven"] = 60.0  # the read-only key access of the loop's guard functions sets nothing
    assert rec["border_hits"] == rec.border_hits == 3 and rec.get("no such field", 7) == 7
    done = rec.model_copy(update={"driven": 60.0, "completed": True})
    assert (done.driven, done.completed, rec.completed) == (60.0, True, False) and math.isnan(rec.driven)
    write_record(q, read_record(p))
    assert q.read_bytes() == p.read_bytes()


@pytest.mark.parametrize("change, words", [
    ({"iteration": "two"}, "iteration"),
    ({"border_hits": -1}, "border_hits"),
    ({"lap_time": 60.0}, "lap_time"),  # a key the schema does not know
    ({"version": RECORD_VERSION + 1}, "newer than this gprace reads"),
])
def test_a_bad_record_is_one_line_naming_the_field(tmp_path, change, words):
    p = tmp_path / "record.json"
    p.write_text(json.dumps({**json.loads(OLD.read_text()), **change}))
    with pytest.raises(InputError, match=words):
        read_record(p)


# ------------------------------------------------------------------------------------------------
# the run summary (summary.json): built from the records, read through its schema, never guessed

OLD_SUMMARY = Path(__file__).parent / "data" / "summary_before_schema.json"


def _folder_with_records(root: Path) -> Path:
    """An iterate folder: settings.json and the records of two laps of trial 1 (one failed)."""
    from gprace.timetrial.iterate import IterateSettings

    root.mkdir()
    write_json(root / "settings.json", IterateSettings(iterations=2, trials=2).model_dump(mode="json"))
    old = json.loads(OLD.read_text())
    for rec in (dict(old, iteration=0, alpha=0.0, driven=62.8, completed=True, reason=""), old):
        d = root / f"trial_{rec['trial']}" / f"iter_{rec['iteration']:02d}"
        d.mkdir(parents=True)
        write_record(d / "record.json", IterationRecord(**{k: v for k, v in rec.items() if k != "gap"}))
    return root


def test_a_summary_round_trips_through_its_schema(tmp_path):
    from gprace.timetrial.summary import build_summary, summarise

    out = _folder_with_records(tmp_path / "exp")
    summary = build_summary(out)
    assert summary["version"] == SUMMARY_VERSION and [r["iteration"] for r in summary["rows"]] == [0, 2]
    it2 = summary["by_iteration"][1]
    assert it2["completed"] == 0 and it2["failed"][0]["trial"] == 1 and math.isnan(it2["driven_mean"])
    assert it2["err_tracking"] == pytest.approx(0.41) and summary["per_trial"][0]["best_iteration"] is None
    write_json(out / "summary.json", summary)
    back = read_summary(out / "summary.json")
    assert json.dumps(jsonable(back.model_dump())) == json.dumps(jsonable(summary))  # NaN as null
    assert back.by_iteration[1].failed[0].trial == 1 and back.rows[1].iteration == 2
    write_json(tmp_path / "again.json", summarise(out).model_dump())  # the model writes the same file
    assert (tmp_path / "again.json").read_bytes() == (out / "summary.json").read_bytes()


@pytest.mark.parametrize("version", [None, SUMMARY_VERSION + 1])
def test_a_summary_of_another_layout_is_refused_and_the_report_reads_the_records(tmp_path, capsys, version):
    from gprace.cli import main
    from gprace.report.collect import scan
    from gprace.report.sections.timetrial import timetrial_variants

    out = _folder_with_records(tmp_path / "exp")
    old = json.loads(OLD_SUMMARY.read_text())
    (out / "summary.json").write_text(json.dumps(old if version is None else {**old, "version": version}))
    with pytest.raises(InputError, match="summary of layout .* `gprace eval iterate .*` summarises the records"):
        read_summary(out / "summary.json")
    assert main(["show", str(out / "summary.json")]) == 2  # one line, exit code 2
    assert "summary of layout" in capsys.readouterr().err
    v = timetrial_variants(scan(tmp_path))[out]
    assert v["rows_from"] == "record.json files" and [r.iteration for r in v["rows"]] == [0, 2]
    assert v["name"] == "exploration" and any("summary of layout" in n for n in v["notes"])
    assert (out / "summary.json").read_text() == json.dumps(old if version is None else {**old, "version": version})
