"""Issue 38, item 5: no claims table says "holds" or "fails" from too few samples."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gprace.verdict import MIN_SAMPLES, TOO_FEW, mean_interval, min_samples, verdict


def test_the_minimum_is_the_sign_tests_smallest_n_at_five_percent():
    assert MIN_SAMPLES == 6 == min_samples(0.95)
    assert 2 * 0.5 ** (MIN_SAMPLES - 1) >= 0.05 > 2 * 0.5**MIN_SAMPLES
    assert min_samples(0.99) == 8  # 2 * 0.5**8 = 0.0078 < 0.01 <= 2 * 0.5**7


def test_two_agreeing_samples_give_an_interval_that_excludes_zero_but_no_verdict():
    """The issue's case: with 2 tracks the bootstrap has 3 distinct means; two negative
    differences give an interval below zero, which said "holds"."""
    ci = mean_interval([-0.003, -0.001], B=2000)
    assert ci[1] < 0
    assert verdict([ci], claimed=-1) == "holds"  # the interval alone
    assert verdict([ci], claimed=-1, n=2) == TOO_FEW
    for n in range(MIN_SAMPLES):
        assert verdict([[-2, -1]], n=n) == TOO_FEW
    assert verdict([[-2, -1]], n=MIN_SAMPLES) == "holds" and verdict([[1, 2]], n=MIN_SAMPLES) == "fails"


def _tracks(n: int, explore: float, baseline: float, seed: int = 0):
    """``n`` tracks raced by both predictors, e_y errors around ``explore`` and ``baseline``."""
    from gprace.h2h.records import RaceAttrs, Record
    from gprace.h2h.spread import track_data

    rng = np.random.default_rng(seed)
    recs = [Record({}, RaceAttrs(ok=True, border_hit=False, collision=False, overtake_time=5.0)) for _ in range(n)]
    errors = {"explore": explore + 0.01 * rng.random((1, n)), "baseline": baseline + 0.01 * rng.random((1, n))}
    return track_data({"explore": recs, "baseline": recs}, errors, np.arange(n), n)


@pytest.mark.parametrize("n", [2, 5, 6, 12])
def test_the_head_to_head_claims_need_enough_tracks(n):
    from gprace.h2h.spread import summarise

    row = summarise([_tracks(n, 0.10, 0.20)], B=500)["diff.ey_error_1"]
    assert row["tracks"] == n and row["ci"][1] < 0  # every track agrees
    assert row["verdict"] == (TOO_FEW if n < MIN_SAMPLES else "holds")
    two = summarise([_tracks(n, 0.10, 0.20), _tracks(n, 0.30, 0.20, seed=1)], B=500)["diff.ey_error_1"]
    assert two["verdict"] == (TOO_FEW if n < MIN_SAMPLES else "seeds disagree")


def test_the_overtake_time_claim_counts_only_the_tracks_where_both_overtook():
    from gprace.h2h.records import RaceAttrs, Record
    from gprace.h2h.spread import summarise, track_data

    n = 10
    times_e = [4.0] * 3 + [np.nan] * 7  # explore overtook on 3 of 10 tracks
    rec = lambda t: Record({}, RaceAttrs(ok=True, border_hit=False, collision=False, overtake_time=t))  # noqa: E731
    td = track_data({"explore": [rec(t) for t in times_e], "baseline": [rec(5.0) for _ in range(n)]},
                    {"explore": np.zeros((1, n)), "baseline": np.ones((1, n))}, np.arange(n), n)
    s = summarise([td], B=300)
    assert s["diff.overtake_time"]["tracks"] == 3 and s["diff.overtake_time"]["verdict"] == TOO_FEW
    assert s["diff.ey_error_1"]["tracks"] == 10 and s["diff.ey_error_1"]["verdict"] == "holds"


def test_the_printed_claims_table_of_two_tracks_gives_no_verdict(capsys):
    """What `eval head2head --tracks 2` prints (its table, through the command's printer), and an
    old table (no count stored) judged on its --tracks."""
    from gprace.cli.h2h import print_table
    from gprace.h2h.spread import summarise
    from gprace.h2h.table import H2HTable

    spread = summarise([_tracks(2, 0.10, 0.20)], B=300)
    tab = H2HTable(settings={"tracks": 2}, seeds=[0],
                   spread={k: v for k, v in spread.items() if not k.startswith("diff.")},
                   claims={k[5:]: v for k, v in spread.items() if k.startswith("diff.")}).model_dump()
    print_table(tab, as_json=False)
    out = capsys.readouterr().out
    rows = [ln for ln in out.splitlines() if "ey_error_1" in ln or "border_hits" in ln]
    assert rows and all("too few samples for a verdict" in r for r in rows) and "│ holds" not in out
    old = json.loads(json.dumps(tab))
    for c in old["claims"].values():
        c.pop("tracks")
        c["verdict"] = "holds"  # as a table of before version 2 stored it
    old.pop("version")
    print_table(old, as_json=False)
    assert "│ holds" not in capsys.readouterr().out


def test_the_time_trial_claim_needs_enough_trials():
    from gprace.timetrial.compare import claims, format_table

    def per_trial(n):
        return {"exploration": [{"trial": j, "best_alpha0": 50.0 - 0.01 * j} for j in range(n)],
                "double_gp": [{"trial": j, "best_alpha0": 51.0} for j in range(n)]}

    three, eight = claims(per_trial(3))["best_alpha0_lap"], claims(per_trial(8))["best_alpha0_lap"]
    assert three["trials"] == 3 and three["ci"][1] < 0 and three["verdict"] == TOO_FEW
    assert eight["verdict"] == "holds"
    text = format_table({"plant": "p", "track": "t", "trials": 3, "iterations": 1, "features": "full", "oracle": None,
                         "variants": {}, "per_trial": per_trial(3), "claims": claims(per_trial(3))})
    assert "over 3 trial(s): too few samples for a verdict" in text


def test_the_study_reports_no_verdict_below_the_minimum(tmp_path):
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("h2h_study", Path(__file__).parents[1] / "benchmarks" / "h2h_study.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    from gprace.h2h.spread import summarise

    spread = summarise([_tracks(3, 0.10, 0.20)], B=200)
    claims = {k[5:]: v for k, v in spread.items() if k.startswith("diff.")}
    claims["ey_error_9"] = claims["ey_error_1"]
    res = study.summary({"settings": {"tracks": 3}, "claims": claims}, tmp_path)
    assert res["claims"]["lower 9-step error"]["verdict"] == TOO_FEW and res["claims"]["lower 9-step error"]["tracks"] == 3


@pytest.mark.slow
def test_eval_head2head_with_two_tracks_gives_no_verdict(tmp_path, capsys):
    from gprace.cli import main

    argv = ["eval", "head2head", "--tracks", "2", "--runs", "6", "--init-runs", "3", "--explore-minutes", "0.1",
            "--episode-seconds", "3", "--calib-runs", "1", "--calib-passes", "1", "--max-time", "3", "--samples", "5",
            "--points-per-run", "5", "--workers", "2", "--out", str(tmp_path / "h2h")]
    assert main(["-q", *argv, "--json"]) == 0
    tab = json.loads(capsys.readouterr().out)
    assert tab["claims"] and all(c["verdict"] == TOO_FEW for c in tab["claims"].values())
    assert {c["tracks"] for c in tab["claims"].values()} <= {0, 1, 2}
