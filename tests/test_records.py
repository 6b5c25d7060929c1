"""The time trial's iteration record: one schema, versioned; an old layout migrates once (issue 18)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest

from gprace.errors import InputError
from gprace.timetrial.record import RECORD_VERSION, IterationRecord, read_record, write_record

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
    assert (rec["iteration"], rec["trial"], rec["border_hits"], rec["completed"]) == (2, 1, 3, False)
    assert math.isnan(rec["driven"]) and math.isnan(rec["gap"]) and math.isnan(rec["cov_tracking"])
    assert rec["limits"] == [] and rec["replan_failed"] is False and rec["version"] == RECORD_VERSION
    on_disk = json.loads(p.read_text())
    assert on_disk["version"] == RECORD_VERSION and on_disk["driven"] is None
    assert read_record(p) == pytest.approx(rec, nan_ok=True)
    assert capsys.readouterr().err == ""  # migrated once: no second warning


def test_a_record_round_trips_with_nan_as_null(tmp_path):
    rec = IterationRecord(iteration=1, trial=0, alpha=0.5, planned=18.75, driven=float("nan"), completed=False,
                          gap=float("nan"), solve_median_ms=2.0, solve_p99_ms=7.0, border_hits=0, fallbacks=1,
                          samples=300, limits=[10.9, 6.0, 10.3], envelope=[11.3, 1.0, 0.0], utilisation=0.39)
    p = tmp_path / "record.json"
    write_record(p, rec)
    assert json.loads(p.read_text())["driven"] is None
    back = read_record(p)
    assert back == pytest.approx(rec.model_dump(), nan_ok=True)
    assert not list(tmp_path.glob(".*tmp"))  # written atomically


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
