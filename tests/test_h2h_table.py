"""The head-to-head table (table.json): built from the race records, one schema, versioned; an old
layout is read with a warning and never rewritten (issue 18)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from gprace.cli import main
from gprace.errors import InputError
from gprace.h2h.records import RaceAttrs, Record
from gprace.h2h.table import (TABLE_VERSION, H2HTable, chain_table, failed_races_text, parse_table, read_table,
                              write_table)

OLD = Path(__file__).parent / "data" / "h2h_table_before_schema.json"


def _race(ok=True, hit=False, ot=float("nan"), ms=(10.0, 12.0), error=""):
    return Record({"ego_solve_ms": np.array(ms)}, RaceAttrs(ok=ok, error=error, border_hit=hit, overtake_time=ot))


def test_the_table_counts_what_the_records_say():
    raced = {"baseline": [_race(ot=4.0), _race(hit=True, ot=6.0), _race(ot=5.0)],
             "explore": [_race(ot=3.0), _race(ot=2.0), _race(ok=False, error="SolverError: NMPC infeasible\ntrace")]}
    E = np.array([[0.01, 0.02, 0.03, 0.04], [0.02, 0.04, 0.06, 0.08]])
    tab = H2HTable.model_validate(chain_table({"tracks": 3}, {}, raced, {"cv": E}, 3))
    # only scenario 0 is finished inside the track by both: the overtake times are over it alone
    assert tab.common_inside == 1
    b, e = tab.racing["baseline"], tab.racing["explore"]
    assert (b.runs, b.failed, b.border_hits, b.overtakes) == (3, 0, 1, 3)
    assert (b.overtake_time_mean, b.overtake_time_std, b.overtake_scenarios) == (4.0, 0.0, 1)
    assert (e.failed, e.overtakes, e.overtake_time_mean) == (1, 2, 3.0)
    assert failed_races_text(e) == "1 of 3: scenario 2: SolverError: NMPC infeasible"
    assert b.ego_solve_ms_median == 11.0
    np.testing.assert_allclose(tab.ey_error["cv"].mean, [0.025, 0.05])
    np.testing.assert_allclose(tab.ey_error["cv"].std, E.std(axis=1))
    assert tab.ey_error["cv"].points == 4


def test_a_table_round_trips_with_nan_kept(tmp_path):
    data = json.loads(OLD.read_text())
    tab = H2HTable.model_validate({**data, "version": TABLE_VERSION})
    dump = write_table(tmp_path / "table.json", tab)
    text = (tmp_path / "table.json").read_text()
    assert '"values": [\n        NaN' in text  # a seed's figure that is not a number stays NaN, as before
    back = read_table(tmp_path / "table.json")
    assert back == tab and math.isnan(back.spread["explore.overtake_time"].values[0])
    assert dump["version"] == TABLE_VERSION and dump["racing"]["explore"]["overtake_time_mean"] is None
    # nothing of the old table lost: every key it had is in the new file with the same value
    new = json.loads(text)

    def same(a, b):
        if isinstance(a, dict):
            return all(k in b and same(v, b[k]) for k, v in a.items())
        if isinstance(a, list):
            return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
        return a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b))

    assert same(data, new)


def test_an_old_table_is_read_with_a_warning_and_not_rewritten(tmp_path, capsys):
    p = tmp_path / "table.json"
    shutil.copy(OLD, p)
    tab = read_table(p)
    assert "layout before version" in capsys.readouterr().err
    assert p.read_bytes() == OLD.read_bytes()
    assert tab.racing["explore"].failed_where[0].scenario == 1 and tab.claims["border_hits"].verdict == "not resolved"
    # a hand-trimmed table: the parts it lacks are empty
    small = parse_table({"racing": {"cv": {"runs": 2}}}, "small")
    assert small.racing["cv"].failed == 0 and small.spread == {} and small.seeds == [0]
    assert main(["show", str(p), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)["results"]
    assert out["explore: failed races"] == "1 of 2: scenario 1: SolverError: NMPC infeasible"


@pytest.mark.parametrize("change, words", [
    ({"version": TABLE_VERSION + 1}, "newer than this gprace reads"),
    ({"racing": {"cv": {"runs": -1}}}, "racing.cv.runs"),
    ({"racing": {"cv": {"runs": 1, "laps": 3}}}, "racing.cv.laps: unknown key"),
    ({"claims": {"x": {"values": [], "mean": None, "seed_std": None, "min": None, "max": None, "ci": [None, None]}}},
     "claims.x.seed_ci: required key missing"),
])
def test_a_bad_table_is_one_line_naming_the_field(tmp_path, capsys, change, words):
    p = tmp_path / "table.json"
    p.write_text(json.dumps({**json.loads(OLD.read_text()), "version": TABLE_VERSION, **change}))
    with pytest.raises(InputError, match=words) as exc:
        read_table(p)
    assert str(p) in str(exc.value) and "\n" not in str(exc.value)
    assert main(["show", str(p)]) == 2
    assert words.split(":")[0] in capsys.readouterr().err
