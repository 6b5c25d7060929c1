"""Every example in examples/ runs as a user would run it (in a fresh folder) and gives a
sensible result, so the examples cannot rot.

The time-trial example runs a whole pipeline (IPOPT plans, MPC laps, GP hyperparameter fits) and
takes minutes on two cores even with its tiny settings: it is ``slow``. The diagnosis and
head-to-head examples (about 30 s with the compiled NMPC, once it is compiled) run by default.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _run(cmd: list[str], cwd: Path, timeout: float = 1200) -> subprocess.CompletedProcess:
    env = dict(os.environ, GPRACE_DEBUG="0")
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    assert r.returncode == 0, f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


def _sections(html: str) -> set[str]:
    return set(re.findall(r'<section id="([a-z0-9_]+)"', html)) | set(re.findall(r"<section id='([a-z0-9_]+)'", html))


def test_examples_are_listed_and_uniform():
    files = sorted(p.name for p in EXAMPLES.iterdir() if p.suffix in (".sh", ".py"))
    assert {"timetrial.sh", "head2head.sh", "diagnose_recording.py"} <= set(files)
    for p in EXAMPLES.glob("*.sh"):
        text = p.read_text()
        assert text.startswith("#!/usr/bin/env bash") and "set -euo pipefail" in text, p.name
        assert "gprace report" in text, f"{p.name} should end with a report of its results"
    readme = (EXAMPLES / "README.md").read_text()
    for f in files:
        assert f in readme, f"{f} is not described in examples/README.md"


def test_diagnose_recording_example(tmp_path):
    r = _run([sys.executable, str(EXAMPLES / "diagnose_recording.py"), "out"], tmp_path)
    rep = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert rep["verdict"] == "mismatch"
    names = [e["name"] for e in rep["effects"]]
    assert names == ["road_grade"], names
    p = rep["effects"][0]["parameters"]
    assert p["angle"]["value"] == pytest.approx(0.06, rel=0.1)
    assert p["s_start"]["value"] == pytest.approx(200.0, abs=15.0) and p["s_end"]["value"] == pytest.approx(350.0, abs=15.0)
    assert "effect:  road_grade" in r.stdout
    html = (tmp_path / "out" / "report.html").read_text()
    assert "diagnosis" in _sections(html)
    assert "residual along the track" in html.lower() or "Residual along the track" in html
    assert "residual-along-track plot not drawn" not in html
    assert (tmp_path / "out" / "augmented.toml").read_text().count('name = "road_grade"') == 1


@pytest.mark.slow
def test_timetrial_example(tmp_path):
    _run(["bash", str(EXAMPLES / "timetrial.sh"), "out"], tmp_path)
    out = tmp_path / "out"
    from gprace.io.artifacts import read_artifact

    run = read_artifact(out / "run.h5", "run").attrs
    assert run["completed"] and abs(run["lap_time"] - run["planned_lap_time"]) < 0.1 * run["planned_lap_time"]
    summary = json.loads((out / "exploration" / "summary.json").read_text())
    assert sorted({r["iteration"] for r in summary["rows"]}) == [0, 1]
    assert (out / "run.png").stat().st_size > 5000
    html = (out / "report.html").read_text()
    assert {"timetrial", "gp", "artifacts"} <= _sections(html)
    r = _run([sys.executable, str(EXAMPLES / "lap_times.py"), str(out / "exploration"), str(out / "laps.png")], tmp_path)
    assert "iteration 0" in r.stdout and (out / "laps.png").exists()


def test_head2head_example(tmp_path):
    _run(["bash", str(EXAMPLES / "head2head.sh"), "out"], tmp_path)
    tab = json.loads((tmp_path / "out" / "h2h" / "table.json").read_text())
    assert set(tab["racing"]) == {"baseline", "explore"}
    for row in tab["racing"].values():
        assert row["runs"] == 2
    fits = tab["fits"]["0"]  # every model's quality report, read once per chain
    assert set(fits) == {"baseline", "init", "explore", "select"}
    assert all(len(f["heldout"]) == len(f["outputs"]) == 5 and f["attempts"] >= 1 for f in fits.values())
    html = (tmp_path / "out" / "report.html").read_text()
    assert {"h2h", "gp", "artifacts"} <= _sections(html)
