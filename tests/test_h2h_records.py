"""The head-to-head records: one schema per kind, versioned; an old layout migrates once (issue 18).

No race runs here: records are built from small hand-made arrays, and the old layout is a
checked-in record of a three-step race written by the protocol of before the schema."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from gprace.errors import ArtifactError, InputError
from gprace.h2h import protocol as P
from gprace.h2h.tasks import RaceTask
from gprace.h2h.records import RECORD_VERSION, ErrorAttrs, RaceAttrs, read_record, record_of, write_record

OLD = Path(__file__).parent / "data" / "h2h_race_before_schema.h5"
TASK = {"id": "eval-cv-0", "track": {"kind": "random", "seed": 0, "stretches": 5, "width": 0.75}, "seed": 4,
        "predictor": "cv", "label": "cv", "config": {"max_time": 0.3, "samples": 5}}


def _race_value() -> dict:
    """What the race function returns for a three-step race without an overtake."""
    rng = np.random.default_rng(0)
    attrs = {"track": "random-0", "track_length": 13.7, "seed": 4, "predictor": "cv", "alpha": 0.0,
             "end_reason": "time", "overtake_time": float("nan"), "border_hit": False, "border_hit_opp": True,
             "collision": False, "steps": 3, "fallbacks_ego": 1, "fallbacks_opp": 0, "stalemates": 0, "wall_s": 0.5}
    return {"arrays": {"t": 0.1 * np.arange(4), "ego": rng.normal(size=(4, 6)), "opp": rng.normal(size=(4, 6)),
                       "fallback_ego": np.array([False, True, False])}, "attrs": attrs}


def _written_and_read(path: Path, rec, schema):
    write_record(path, rec)
    return read_record(path, schema)


def _same_attrs(a, b) -> bool:
    """Equal attributes, NaN equal to NaN."""
    return json.dumps(a.model_dump(), sort_keys=True) == json.dumps(b.model_dump(), sort_keys=True)


def _assert_same_arrays(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def _edited(tmp_path: Path, **attrs) -> Path:
    """A copy of the old record with some attributes set."""
    p = tmp_path / "run_00000.h5"
    shutil.copy(OLD, p)
    with h5py.File(p, "a") as f:
        f.attrs.update(attrs)
    return p


def test_a_race_record_round_trips(tmp_path):
    rec = record_of(RaceAttrs, TASK, "abc", True, _race_value(), "")
    back = _written_and_read(tmp_path / "run.h5", rec, RaceAttrs)
    _assert_same_arrays(back.arrays, rec.arrays)
    assert _same_attrs(back.attrs, rec.attrs) and not back.old
    a = back.attrs
    assert math.isnan(a.overtake_time) and a.fallbacks_ego == 1 and a.border_hit_opp is True and a.seed == 4
    assert a.task == TASK and a.task_hash == "abc" and a.version == RECORD_VERSION
    with h5py.File(tmp_path / "run.h5") as f:  # the task is JSON text in the file, as before the schema
        assert json.loads(f.attrs["task"]) == TASK and f.attrs["version"] == RECORD_VERSION


def test_a_failed_task_and_an_error_record_round_trip(tmp_path):
    failed = record_of(RaceAttrs, TASK, "abc", False, None, "Traceback ...\nInputError: missing.h5")
    back = _written_and_read(tmp_path / "failed.h5", failed, RaceAttrs)
    assert back.attrs.ok is False and back.attrs.error == failed.attrs.error and back.arrays == {}
    assert math.isnan(back.attrs.overtake_time) and back.attrs.end_reason == ""  # a race that did not run
    task = {"id": "errors-cv-0", "record": "eval/cv/run_00000.h5", "record_hash": "abc", "seed": 4,
            "models": {"cv": None}, "version": 4}
    errors = {"cv": np.abs(np.random.default_rng(1).normal(size=(9, 2))), "spread_cv": np.zeros((3, 9, 2))}
    rec = record_of(ErrorAttrs, task, "def", True, {"arrays": errors, "attrs": {}}, "")
    back = _written_and_read(tmp_path / "err.h5", rec, ErrorAttrs)
    _assert_same_arrays(back.arrays, errors)
    assert _same_attrs(back.attrs, rec.attrs) and back.attrs.record_hash == "abc"
    with pytest.raises(ArtifactError, match="record_hash"):  # error records name their race
        record_of(ErrorAttrs, {"seed": 4}, "def", True, {"arrays": errors, "attrs": {}}, "")
    with pytest.raises(ArtifactError, match="lap_time: unknown key"):  # a task function's unknown attribute
        record_of(RaceAttrs, TASK, "abc", True, {"arrays": {}, "attrs": {"lap_time": 3.0}}, "")


def test_an_old_record_is_read_with_a_warning_and_not_rewritten(tmp_path, capsys):
    p = tmp_path / "run_00000.h5"
    shutil.copy(OLD, p)
    rec = read_record(p, RaceAttrs)
    assert "layout before version 1" in capsys.readouterr().err and rec.old
    assert p.read_bytes() == OLD.read_bytes()  # a reader that only looks leaves the file as it is
    a = rec.attrs
    assert (a.ok, a.predictor, a.steps, a.end_reason, a.wall_s, a.version) == (True, "cv", 3, "time", 2.5, RECORD_VERSION)
    assert math.isnan(a.overtake_time) and a.task["track"]["kind"] == "random" and rec.arrays["ego"].shape == (4, 6)


def test_the_protocol_migrates_the_old_records_it_reuses_with_one_warning(tmp_path, monkeypatch, capsys):
    old = read_record(OLD, RaceAttrs, warn=False)
    for i in range(3):
        shutil.copy(OLD, tmp_path / f"run_{i:05d}.h5")
    # the fixture's hash is that of the race version it was written with; the reuse is what is tested
    monkeypatch.setattr(P.batches, "task_hash", lambda task: old.attrs.task_hash)

    def no_race(task):
        raise AssertionError("a finished record was raced again")

    st = P.Settings(tracks=3, resume=True)
    recs = P.run_tasks([RaceTask.of(dict(old.attrs.task, id=f"eval-cv-{i}")) for i in range(3)], tmp_path, st, "test", fn=no_race)
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if "layout before version" in ln]
    assert len(warnings) == 1 and "3 records" in warnings[0] and "migrated" in warnings[0]
    for i, rec in enumerate(recs):
        again = read_record(tmp_path / f"run_{i:05d}.h5", RaceAttrs)
        assert not again.old and not rec.old
        _assert_same_arrays(again.arrays, old.arrays)
        assert _same_attrs(again.attrs, old.attrs) and _same_attrs(rec.attrs, old.attrs)
    assert capsys.readouterr().err == ""  # migrated once: no second warning


def test_the_protocol_reruns_an_unreadable_record_and_keeps_a_newer_one(tmp_path, monkeypatch, capsys):
    old = read_record(OLD, RaceAttrs, warn=False)
    monkeypatch.setattr(P.batches, "task_hash", lambda task: old.attrs.task_hash)
    ran = []

    def race(task):
        ran.append(task.id)
        return {"arrays": old.arrays, "attrs": {}}

    st = P.Settings(tracks=1, resume=True)
    _edited(tmp_path, ok="maybe")
    P.run_tasks([RaceTask.of(old.attrs.task)], tmp_path, st, "test", fn=race)
    assert ran == [old.attrs.task["id"]] and "1 unreadable record(s) rerun" in capsys.readouterr().err
    _edited(tmp_path, version=RECORD_VERSION + 1)
    with pytest.raises(InputError, match="newer than this gprace reads"):
        P.run_tasks([RaceTask.of(old.attrs.task)], tmp_path, st, "test", fn=race)
    assert len(ran) == 1  # not overwritten


@pytest.mark.parametrize("change, words", [
    ({"ok": "maybe"}, "ok: Input should be a valid boolean"),
    ({"steps": -1}, "steps"),
    ({"lap_time": 60.0}, "lap_time: unknown key"),
    ({"task": "{not json"}, "task: not JSON"),
    ({"version": "one"}, "version"),
    ({"version": RECORD_VERSION + 1}, "newer than this gprace reads"),
])
def test_a_bad_record_is_one_line_naming_the_field(tmp_path, change, words):
    p = _edited(tmp_path, **change)
    with pytest.raises(InputError, match=words) as exc:
        read_record(p, RaceAttrs)
    assert str(p) in str(exc.value) and "\n" not in str(exc.value)
