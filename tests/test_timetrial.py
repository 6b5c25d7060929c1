"""gprace iterate: a run killed after a step resumes without losing or duplicating data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gprace.errors import InputError, RunFailedError
from gprace.console import jsonable
from gprace.timetrial.iterate import IterateSettings, Steps, build_summary, iterate

pytest.importorskip("gprace.gp")

TINY = IterateSettings(alphas=(0.5, 0.0), iterations=2, trials=1, track="circle_100", plant="audi_nominal", dictionary_size=150,
                       max_fit_points=80, plan_ds=8.0, heldout_laps=0.3, grid_values=4, oracle=False)


def test_iterate_resumes_after_kill(tmp_path, monkeypatch):
    from gprace.io.artifacts import read_artifact
    from gprace.io.runs import read_run

    out = tmp_path / "exp"
    mark = Steps.mark

    def mark_then_fail(self, name):  # a kill right after this step's marker is written
        mark(self, name)
        if name == "t0_i2_select":
            raise RuntimeError(f"injected failure after step {name}")

    monkeypatch.setattr(Steps, "mark", mark_then_fail)
    with pytest.raises(RunFailedError, match="injected failure"):
        iterate(TINY, out)
    done_before = sorted(p.name for p in (out / ".steps").glob("*.done"))
    assert "t0_i2_select.done" in done_before and "t0_i2_retrain.done" not in done_before
    stamp = (out / "trial_0" / "iter_01" / "run.h5").stat().st_mtime_ns
    monkeypatch.setattr(Steps, "mark", mark)
    summary = iterate(TINY, out)
    # finished steps were not redone
    assert (out / "trial_0" / "iter_01" / "run.h5").stat().st_mtime_ns == stamp
    rows = summary["rows"]
    assert [(r["iteration"], r["trial"]) for r in rows] == [(0, 0), (1, 0), (2, 0)]
    # data: each run's samples entered the accumulated dictionary exactly once
    from gprace.config import load_vehicle
    from gprace.model import NominalModel
    from gprace.timetrial.learning import features
    from gprace.tracks import load_track

    m, tr = NominalModel(load_vehicle("audi_tt_cup")), load_track("circle_100")
    # the loop's features skip the samples whose acting inputs precede the run (its delay)
    delay = json.loads((out / "trial_0/iter_00/record.json").read_text())["delay"]
    n0 = len(features(read_run(out / "trial_0/iter_00/run.h5"), m, tr, "tracking", delay=delay)[0])
    n1 = len(features(read_run(out / "trial_0/iter_01/run.h5"), m, tr, "tracking", delay=delay)[0])
    d1 = read_artifact(out / "trial_0/iter_01/data_tracking.h5", "dataset")
    d2 = read_artifact(out / "trial_0/iter_02/data_tracking.h5", "dataset")
    assert d1.attrs["n_seen"] == n0 and d2.attrs["n_seen"] == n0 + n1
    assert len(d2.arrays["Z"]) <= TINY.dictionary_size
    assert len(np.unique(d2.arrays["Z"], axis=0)) == len(d2.arrays["Z"])
    # the summary on disk and from the folder agree
    assert json.loads((out / "summary.json").read_text())["rows"] == jsonable(build_summary(out)["rows"])
    assert all(np.isfinite(r["planned"]) for r in rows)
    # a lap driven again with its own noise seed is the recorded lap; another seed is a new draw
    # (benchmarks/timetrial_redrive.py)
    from gprace.timetrial.iterate.chain import _chain
    from gprace.timetrial.iterate.driving import drive_lap

    settings = json.loads((out / "settings.json").read_text())
    c = _chain({"out": str(out), "trial": 0, "settings": settings.get("settings", settings)})
    recorded = read_run(out / "trial_0" / "iter_01" / "run.h5")
    again, other = drive_lap(c, 1, TINY.alphas[0]), drive_lap(c, 1, TINY.alphas[0], seed=7920)
    np.testing.assert_array_equal(again.states(), recorded.states())
    n = min(len(other.states()), len(recorded.states()))
    assert not np.array_equal(other.states()[:n], recorded.states()[:n])


def test_iterate_rejects_bad_settings(tmp_path):
    with pytest.raises(InputError, match=r"--alpha: values must be in \[0, 1\]"):
        IterateSettings(alphas=(1.5,))  # validated once, where it is built
    iterate_settings = IterateSettings(alphas=(0.0,), iterations=1, trials=1, track="circle_100")
    (tmp_path / "y").mkdir()
    (tmp_path / "y" / "settings.json").write_text(json.dumps({"alphas": [0.3]}))
    with pytest.raises(InputError, match="other settings"):
        iterate(iterate_settings, tmp_path / "y")


def test_iterate_runs_a_process_per_task_by_default():
    """3 equal trials and the oracle on 2 cores: 4 processes share the cores evenly (2 processes ran
    2 trials, then 1 beside the oracle); an explicit --workers is kept; at most 3 per core."""
    import os

    from gprace.timetrial.iterate import processes

    assert processes(None, 4) == 4 and processes(2, 4) == 2 and processes(None, 1) == 1
    assert processes(None, 10_000) == 3 * (os.cpu_count() or 1)
