"""Issue 38, item 1: Ctrl-C and SIGTERM end every long command with exit 130 and one line; a solve
cut short by the signal is never recorded as a result, and the resumed run equals an
uninterrupted one.

The CLI tests start the command as a terminal would (its own session, the signal to the whole
process group as Ctrl-C sends it, or SIGTERM to the command alone), wait for the command's start
line and interrupt it. The resume tests interrupt a real IPOPT solve from inside (a timer sends
the signal while the solver iterates) so the moment is the same on every machine.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from gprace import interrupt
from gprace.cli import main

ENTRY = "import sys; from gprace.cli import main; sys.exit(main())"


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("GPRACE_DEBUG", raising=False)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("interrupts") / "run.csv"
    assert main(["-q", "simulate", "--track", "gprace_ring", "--laps", "0.7", "--weave", "0.3", "-o", str(path)]) == 0
    return path


def _session_alive(sid: int) -> list[int]:
    """Processes still running in session ``sid`` (the command's workers, if any outlived it)."""
    alive = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            alive.append(int(stat.parent.name))
    return alive


def interrupted(argv: list[str], wait_for: str, cwd: Path, sig: int = signal.SIGINT, group: bool = True,
                delay: float = 0.0) -> tuple[int, list[str]]:
    """Run ``gprace argv`` in a new session; once a stderr line holds ``wait_for`` (and ``delay``
    seconds more), send ``sig`` to the process group (Ctrl-C) or the command alone. Returns the
    exit code and the stderr lines, after checking no process of the session outlived it."""
    p = subprocess.Popen([sys.executable, "-c", ENTRY, *map(str, argv)], cwd=cwd, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    lines: list[str] = []
    seen = threading.Event()

    def read() -> None:
        for line in p.stderr:
            lines.append(line.rstrip("\n"))
            if wait_for in line:
                seen.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert seen.wait(300), f"no start line {wait_for!r}: {lines}"
        time.sleep(delay)
        assert p.poll() is None, f"the command ended before the signal: {lines}"
        os.killpg(p.pid, sig) if group else p.send_signal(sig)
        code = p.wait(120)
        reader.join(10)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    if sys.platform.startswith("linux"):
        assert not _session_alive(p.pid), "a worker outlived the command"
    return code, lines


def one_line(code: int, lines: list[str], *needles: str) -> str:
    """Exit 130, and after the start lines exactly one line: the interrupt's, naming ``needles``."""
    assert code == 130, lines
    text = "\n".join(lines)
    assert not any(w in text for w in ("Traceback", "KeyboardInterrupt", "CasADi", "Exception ignored")), text
    errors = [ln for ln in lines if ln.startswith(("error:", "warning:"))]
    assert errors == [lines[-1]] and lines[-1].startswith("error: interrupted; "), text
    for n in needles:
        assert n in lines[-1], (n, lines[-1])
    return lines[-1]


def test_diagnose_interrupted_writes_nothing_and_says_so(recording, tmp_path):
    out = tmp_path / "car.toml"
    code, lines = interrupted(["diagnose", recording, "--vehicle", "audi_tt_cup", "-o", out], "diagnose:", tmp_path)
    one_line(code, lines, "nothing was written", str(out), "rerun")
    assert not out.exists() and not list(tmp_path.glob(".*tmp"))


def test_select_data_stops_at_sigterm_too(recording, tmp_path):
    out = tmp_path / "d.h5"
    code, lines = interrupted(["select-data", recording, "--vehicle", "audi_tt_cup", "-o", out], "select-data:",
                              tmp_path, sig=signal.SIGTERM, group=False)
    one_line(code, lines, "nothing was written")
    assert not out.exists()


def test_iterate_interrupted_keeps_finished_steps_and_its_workers_end(tmp_path):
    out = tmp_path / "it"
    argv = ["iterate", "--iterations", "1", "--trials", "1", "--track", "circle_100", "--dictionary-size", "150",
            "--workers", "2", "--out", out]
    code, lines = interrupted(argv, "iteration 0", tmp_path, delay=1.0)
    one_line(code, lines, f"kept in {out}", "rerun the same command to resume")
    assert not (out / ".gprace.lock").exists()
    steps = {p.stem for p in (out / ".steps").glob("*.done")}
    assert ("oracle" in steps) == (out / "oracle.json").exists()  # no oracle recorded without its step, nor after it


def test_head2head_interrupted_says_how_to_resume(tmp_path):
    out = tmp_path / "h2h"
    code, lines = interrupted(["eval", "head2head", "--tracks", "2", "--runs", "4", "--init-runs", "2", "--max-time", "2",
                               "--samples", "5", "--workers", "2", "--out", out], "runs to do", tmp_path, delay=0.5)
    one_line(code, lines, str(out), "--resume")
    assert not (out / ".gprace.lock").exists()


# ------------------------------------------------------------------------------------------------
# a solve cut short by the signal is not a result; the resumed run equals an uninterrupted one


def _signal_soon(after: float = 0.3) -> None:
    """SIGINT to this process ``after`` seconds from now (while the caller is inside a solver)."""
    threading.Timer(after, os.kill, (os.getpid(), signal.SIGINT)).start()


def _without_times(obj):
    if isinstance(obj, dict):
        return {k: _without_times(v) for k, v in obj.items() if "solve" not in k and k != "wall_s"}
    if isinstance(obj, list):
        return [_without_times(v) for v in obj]
    return obj


def _ipopt_signalled_at(monkeypatch, iteration: int = 3) -> dict:
    """The next NLP that IPOPT solves (once ``state["armed"]``) gets SIGINT at its ``iteration``-th
    iteration, from inside the solver (an IPOPT iteration callback): the moment is the same on
    every machine. ``state["status"]`` collects the return status of that solve."""
    import casadi as ca

    class SignalAt(ca.Callback):
        def __init__(self, nx: int, ng: int, npar: int) -> None:
            ca.Callback.__init__(self)
            self.n, self.sizes = 0, {"x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "lam_p": npar}
            self.construct("signal_at", {})

        def get_n_in(self):
            return ca.nlpsol_n_out()

        def get_n_out(self):
            return 1

        def get_name_in(self, i):
            return ca.nlpsol_out(i)

        def get_name_out(self, i):
            return "ret"

        def get_sparsity_in(self, i):
            name = ca.nlpsol_out(i)
            return ca.Sparsity.scalar() if name == "f" else ca.Sparsity.dense(self.sizes[name]) \
                if self.sizes.get(name) else ca.Sparsity(0, 0)

        def eval(self, arg):
            self.n += 1
            if self.n == iteration:
                os.kill(os.getpid(), signal.SIGINT)
            return [0]

    real = ca.nlpsol
    state = {"armed": False, "status": [], "callbacks": []}

    class Solver:
        def __init__(self, solver) -> None:
            self.solver = solver

        def __call__(self, **args):
            try:
                return self.solver(**args)
            finally:
                state["status"].append(self.solver.stats()["return_status"])

        def stats(self):
            return self.solver.stats()

    def nlpsol(name, plugin, nlp, opts=None):
        if not state["armed"] or not isinstance(nlp, dict):
            return real(name, plugin, nlp, opts or {})
        state["armed"] = False
        cb = SignalAt(nlp["x"].numel(), nlp["g"].numel(), nlp["p"].numel() if "p" in nlp else 0)
        state["callbacks"].append(cb)  # CasADi keeps no reference to a Python callback
        return Solver(real(name, plugin, nlp, {**(opts or {}), "iteration_callback": cb}))

    monkeypatch.setattr(ca, "nlpsol", nlpsol)
    return state


def test_an_oracle_solve_cut_short_is_recomputed_on_resume(tmp_path, monkeypatch):
    """The issue's case: IPOPT stopped by Ctrl-C returned "did not converge" and the oracle was
    stored as that. Now nothing of the oracle is recorded and the resume computes the same
    oracle as an uninterrupted run."""
    import gprace.plan as plan_module
    from gprace.timetrial.iterate import IterateSettings, iterate, oracle_lap

    st = IterateSettings(alphas=(0.5, 0.0), iterations=1, trials=1, track="circle_100", plant="audi_hidden",
                         dictionary_size=150, max_fit_points=80, plan_ds=8.0, heldout_laps=0.3, grid_values=4)
    real = plan_module.plan_min_time
    state = _ipopt_signalled_at(monkeypatch)

    def interrupted_plan(track, model, settings, *a, **k):
        if model.effects and not state["status"]:  # the oracle plans on the true physics: its first IPOPT solve
            state["armed"] = True
        return real(track, model, settings, *a, **k)

    monkeypatch.setattr(plan_module, "plan_min_time", interrupted_plan)
    out = tmp_path / "it"
    with interrupt.handled(), pytest.raises(KeyboardInterrupt):
        iterate(st, out)
    assert state["status"] == ["User_Requested_Stop"]  # stopped inside IPOPT, and not tried again
    assert not (out / "oracle.json").exists() and not (out / ".steps" / "oracle.done").exists()
    assert (out / ".steps" / "t0_i1_drive.done").exists()  # the trial finished before the oracle started
    monkeypatch.setattr(plan_module, "plan_min_time", real)
    summary = iterate(st, out)
    assert _without_times(summary["oracle"]) == _without_times(oracle_lap(st)) and summary["oracle"]["completed"]
    assert json.loads((out / "oracle.json").read_text())["planned"] == pytest.approx(summary["oracle"]["planned"])


def test_a_race_cut_short_is_not_recorded_and_the_resumed_table_equals_an_uninterrupted_one(tmp_path, monkeypatch):
    import gprace.h2h.race as race_module
    from gprace.h2h import protocol as P

    tiny = dict(tracks=2, raced=("cv",), offline=("cv",), max_time=4.0, samples=5, workers=1, resume=True)
    st = P.Settings(**tiny)
    ref = P.table(st, P.race_predictors(st, tmp_path / "ref", {}), {})
    real = race_module.run_race

    def interrupted_race(task):
        if task.id.endswith("-1"):  # the second race: stopped inside its NMPC solves
            _signal_soon(0.2)
        return real(task)

    monkeypatch.setattr(race_module, "run_race", interrupted_race)
    out = tmp_path / "out"
    with interrupt.handled(), pytest.raises(KeyboardInterrupt):
        P.race_predictors(st, out, {})
    assert sorted(p.name for p in (out / "eval" / "cv").iterdir()) == ["run_00000.h5"]
    monkeypatch.setattr(race_module, "run_race", real)
    again = P.table(st, P.race_predictors(st, out, {}), {})
    assert _without_times(again) == _without_times(ref)


@pytest.mark.slow  # a local Dask cluster: about 30 s
def test_dask_tasks_are_cancelled_and_nothing_is_recorded_after_the_signal(tmp_path, monkeypatch):
    from dask.distributed import LocalCluster

    import gprace.h2h.race as race_module
    from gprace.h2h import protocol as P

    real = race_module.run_race

    def interrupted_race(task):
        if task.id.endswith("-0"):
            _signal_soon(0.2)
        return real(task)

    monkeypatch.setattr(race_module, "run_race", interrupted_race)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        st = P.Settings(tracks=2, raced=("cv",), offline=("cv",), max_time=4.0, samples=5, executor="dask",
                        scheduler=cluster.scheduler_address)
        with interrupt.handled(), pytest.raises(KeyboardInterrupt):
            P.race_predictors(st, tmp_path, {})
    assert not list((tmp_path / "eval" / "cv").glob("run_*.h5"))


# ------------------------------------------------------------------------------------------------
# the whole CLI chain, resumed against an uninterrupted run (long: minutes)


@pytest.mark.slow
def test_iterate_resumed_after_ctrl_c_equals_an_uninterrupted_run(tmp_path):
    argv = ["iterate", "--iterations", "1", "--trials", "1", "--track", "circle_100", "--dictionary-size", "150",
            "--workers", "2"]
    code, lines = interrupted([*argv, "--out", tmp_path / "a"], "iteration 1", tmp_path, delay=1.0)
    one_line(code, lines)
    summaries = []
    for name in ("a", "b"):
        r = subprocess.run([sys.executable, "-c", ENTRY, "-q", *argv, "--out", str(tmp_path / name), "--json"],
                           capture_output=True, text=True, check=True)
        summaries.append(_without_times(json.loads(r.stdout)))
    assert summaries[0] == summaries[1] and summaries[0]["oracle"]["known"]


@pytest.mark.slow
def test_head2head_resumed_after_ctrl_c_equals_an_uninterrupted_run(tmp_path):
    argv = ["eval", "head2head", "--tracks", "2", "--runs", "6", "--init-runs", "3", "--explore-minutes", "0.1",
            "--episode-seconds", "3", "--calib-runs", "1", "--calib-passes", "1", "--max-time", "3", "--samples", "5",
            "--points-per-run", "5", "--workers", "2"]
    code, lines = interrupted([*argv, "--out", tmp_path / "a"], "exploration", tmp_path, delay=2.0)
    one_line(code, lines, "--resume")
    tables = []
    for name, extra in (("a", ["--resume"]), ("b", [])):
        r = subprocess.run([sys.executable, "-c", ENTRY, "-q", *argv, *extra, "--out", str(tmp_path / name), "--json"],
                           capture_output=True, text=True, check=True)
        tab = _without_times(json.loads(r.stdout))
        tab.pop("fits", None)  # fit reports hold wall-clock seconds
        tables.append(tab)
    assert tables[0] == tables[1]
    np.testing.assert_equal(tables[0]["claims"], tables[1]["claims"])
