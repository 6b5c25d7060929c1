"""``gprace iterate``: the paper's iterative double-GP time trial with active exploration.

Per trial (an independent chain with its own seed; trials run in parallel through
:func:`gprace.executor.run_batch`):

- iteration 0: the nominal MPC (no GP) drives the minimum-curvature path at a conservative share
  ``first_speed_scale`` of the nominal model's limits;
- iteration i >= 1 with ``alpha_i`` (the ``--alpha`` list, its last value repeated up to
  ``--iterations``): (1) the measurements of iteration i-1 are streamed into the dictionaries of
  both GPs (``diverse`` selection of the paper or the ``random`` baseline, accumulating over
  iterations); (2) both GPs are retrained (hyperparameters by marginal likelihood on the first
  retrain only, then posterior refits with those hyperparameters fixed; see
  :mod:`gprace.timetrial.learning`), the exploration candidates and their weighted variances are
  computed (iterations with alpha > 0; alpha = 0 never uses them); (3) the lap is re-planned
  with the planning GP, warm-started from the last plan that completed a lap, inside a friction
  ellipse widened from the accelerations measured on the last lap (:mod:`gprace.timetrial.grip`;
  a failed lap narrows it); (4) the tracking MPC with the
  tracking GP drives it with ``alpha_i``. If the re-plan fails (IPOPT reports infeasible or runs
  out of iterations), the last plan that completed a lap is driven again and the record says
  ``replan_failed``.

One module per concern (issue 40; every name is still importable from ``gprace.timetrial.iterate``):
:mod:`.settings` (the settings and the start check), :mod:`.chain` (step markers and what every
step of a trial reads), :mod:`.data` (the reference runs and step 1, the dictionaries),
:mod:`.training` (step 2, the GP fits and exploration candidates), :mod:`.planning` (step 3),
:mod:`.driving` (iteration 0 and step 4) and :mod:`.evaluation` (a lap's record: GP errors,
coverage, envelope, status). This module runs the batch and the chain's steps in order.

The oracle lap (``oracle.json``, plants whose physics are known: ``frenet``): the same planner on
the plant's true model (nominal vehicle plus its effects, actuator lags left out), no ellipse,
driven by the tracking MPC of that model. It is what perfect model knowledge would give
(:mod:`gprace.timetrial.oracle`); the summary is :mod:`gprace.timetrial.summary`.

Folder layout (``--out DIR``)::

    settings.json                       the experiment (a rerun must match it)
    heldout.h5                          a weaving run of the plant (GP test set, shared by trials)
    calib.h5                            a weaving run of another design (GP variance calibration, shared)
    trial_<j>/iter_<i>/plan.h5 run.h5 gp_tracking.h5 gp_planning.h5 data_*.h5 [candidates.h5] record.json
    trial_<j>/hyper_tracking.h5 hyper_planning.h5
    oracle.json oracle_plan.h5 oracle_run.h5   the oracle lap (or {"known": false})
    .steps/<name>.done                  written only after the step's artifacts are on disk
    summary.json

Resuming: every step checks its marker first; artifacts are written atomically and the marker
after them, so a run killed anywhere resumes at the first unfinished step without duplicating or
losing data (a step interrupted half-way is simply redone: it rewrites the same files).
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

from gprace.console import console
from gprace.errors import InputError, RunFailedError
from gprace.timetrial.iterate.chain import Steps, _Chain, _chain, _task_settings  # noqa: F401 (importable from here)
from gprace.timetrial.iterate.data import (  # noqa: F401 (importable from here, as before the split)
    MIN_FIT_SAMPLES,
    REFERENCE_RUNS,
    REFERENCE_SLOWER,
    _calibration_samples,
    _reference_run,
    _reference_task,
    _select,
    _share_references,
    _shares_references,
)
from gprace.timetrial.iterate.driving import _band, _delay_before, _drive_iteration, _iteration_zero  # noqa: F401
from gprace.timetrial.iterate.evaluation import _coverage, _gp_error, _lap_extra, _record  # noqa: F401
from gprace.timetrial.iterate.planning import _grip_shown, _replan  # noqa: F401
from gprace.timetrial.iterate.settings import IterateSettings, _check_start  # noqa: F401
from gprace.timetrial.iterate.training import _retrain, make_grid  # noqa: F401
from gprace.timetrial.oracle import ORACLE_MARGINS, oracle_lap  # noqa: F401 (importable from here, as before)
from gprace.timetrial.record import IterationRecord, read_record, write_json, write_record  # noqa: F401
from gprace.timetrial.summary import SUMMARY_COLUMNS, build_summary, failed_laps_text  # noqa: F401 (as before)


def iterate(settings: IterateSettings, out: str | Path, executor: str = "local", workers: int | None = 1,
            scheduler: str | None = None, progress=None) -> dict:
    """Run (or resume) the experiment in ``out``; return the summary. On a terminal one bar counts
    the laps driven (:func:`lap_markers`), with an ETA; it moves while the trials run in other processes."""
    laps = lap_markers(settings, Path(out))
    bar = lambda: console.polled(f"iterate: {len(laps)} laps", len(laps), lambda: sum(p.exists() for p in laps),  # noqa: E731
                                 unit="laps")
    return iterate_many([(settings, out)], executor, workers, scheduler, bar=bar)[0]


def lap_markers(settings: IterateSettings, out: Path) -> list[Path]:
    """The step markers of every lap an experiment drives: its reference runs, each trial's
    iterations 0..N (``t<j>_i<i>_drive``) and the oracle lap; a lap is done when its marker exists."""
    steps = out / ".steps"
    refs = [name for name in REFERENCE_RUNS if name != "calib" or settings.calib_weave > 0]
    trials = [f"t{j}_i{i}_drive" for j in range(settings.trials) for i in range(settings.iterations + 1)]
    return [steps / f"{name}.done" for name in refs + trials + ["oracle"]]


def iterate_many(experiments, executor: str = "local", workers: int | None = 1, scheduler: str | None = None,
                 bar=None) -> list[dict]:
    """Run (or resume) several experiments ``[(settings, out), ...]`` with all their trials in one batch.

    Experiments on the same plant, track and seed share the held-out run and the oracle lap (the
    first computes them, the others copy them). ``bar``: a context manager factory (a progress
    bar) entered once every experiment is checked, so a refusal stays one line.
    """
    tasks: list[dict] = []
    references: list[dict] = []
    prepared: list[tuple[IterateSettings, Path, Path | None]] = []
    for settings, out in experiments:
        out = Path(out)
        share = next((o for st, o, _ in prepared if _shares_references(st, settings)), None)
        refs, trials = _prepare(settings, out, share)
        references += refs
        tasks += trials
        prepared.append((settings, out, share))
    with bar() if bar is not None else contextlib.nullcontext():
        return _run_prepared(prepared, references, tasks, executor, workers, scheduler)


def _run_prepared(prepared, references, tasks, executor, workers, scheduler) -> list[dict]:
    """The reference runs, then the trials and the oracle lap, then the summaries (iterate_many)."""
    import shutil

    from gprace.executor import run_batch

    if executor == "local":  # forked trial processes inherit what the parent imported (issue 37)
        from gprace.timetrial.learning import preload_trial_modules

        preload_trial_modules()
    # the reference runs of all experiments in one batch first (each a lap or two of simulate)
    done = run_batch(_reference_task, references, executor=executor, workers=processes(workers, len(references)), scheduler=scheduler,
                     label=f"iterate: {len(references)} reference run(s)") if references else []
    bad = [r for r in done if not r.ok]
    if bad:
        raise RunFailedError(f"iterate: {len(bad)} reference run(s) failed ({bad[0].error.splitlines()[0]}); "
                             "rerun the same command to resume")
    for _, out, share in prepared:
        _share_references(out, share)
    # the oracle lap runs beside the trials (it is one more task of the batch), once per shared set
    tasks.sort(key=lambda t: "oracle" in t)
    label = f"iterate: {sum('oracle' not in t for t in tasks)} trial(s)" + (" and the oracle lap" if tasks[-1:] and "oracle" in tasks[-1] else "")
    results = run_batch(run_chain, tasks, executor=executor, workers=processes(workers, len(tasks)), scheduler=scheduler,
                        label=label)
    for _, out, share in prepared:
        if share is not None and (share / "oracle.json").exists() and not Steps(out).done("oracle"):
            shutil.copy2(share / "oracle.json", out / "oracle.json")
            Steps(out).mark("oracle")
    summaries = []
    for _, out, _ in prepared:
        summary = build_summary(out)
        write_json(out / "summary.json", summary)
        summaries.append(summary)
    failed = [r for r in results if not r.ok]
    if failed:
        first = failed[0].error.splitlines()[0]
        raise RunFailedError(f"iterate: {len(failed)} of {len(tasks)} trials failed ({first}); rerun the same command to resume")
    return summaries


def processes(workers: int | None, tasks: int) -> int:
    """Local worker processes for a batch of ``tasks``: ``workers``, or by default (None) one per
    task, at most 3 per core. The trials are chains of equal length: 3 trials on 2 processes run
    2 then 1 (a core idles for a whole chain), 3 processes share the 2 cores evenly (README job:
    wall time 1.5 instead of 2 chains)."""
    import os

    if workers is not None:
        return int(workers)
    return max(1, min(int(tasks), 3 * (os.cpu_count() or 1)))


def _prepare(settings: IterateSettings, out: Path, share: Path | None = None) -> tuple[list[dict], list[dict]]:
    """Check the settings, write or match ``settings.json``; the reference runs to make (none when
    ``share`` has them) and the trial tasks (and the oracle lap's)."""
    from gprace.io.artifacts import check_folder

    _check_start(settings)  # a bad track, plant or vehicle, or a car that cannot start: before anything is written
    check_folder(out)
    mine = settings.model_dump(mode="json")
    sfile = out / "settings.json"
    if sfile.exists():
        old = json.loads(sfile.read_text())
        if old != mine:
            diff = sorted(k for k in set(old) | set(mine) if old.get(k) != mine.get(k))
            raise InputError(f"{out}: holds an experiment with other settings ({', '.join(diff)}); use another --out")
    else:
        out.mkdir(parents=True, exist_ok=True)
        write_json(sfile, mine)
    steps = Steps(out)
    refs = [{"out": str(out), "reference": name, "settings": mine} for name in REFERENCE_RUNS
            if share is None and not steps.done(name) and (name != "calib" or settings.calib_weave > 0)]
    tasks = [{"out": str(out), "trial": j, "settings": mine} for j in range(settings.trials)]
    if share is None and not steps.done("oracle"):
        tasks.append({"out": str(out), "oracle": True, "settings": mine})
    return refs, tasks


def run_chain(task: dict) -> list[dict]:
    """One trial: iterations 0..N, each step skipped when its marker exists (module-level for pickling).

    BLAS is limited to one thread per chain: chains run one per core (every timing of
    docs/reference.md#measured was taken that way; several multi-threaded chains on two cores only
    fight over them).
    """
    from gprace.executor import single_thread_blas

    return single_thread_blas(_oracle_task if task.get("oracle") else _run_chain)(task)


def _oracle_task(task: dict) -> list[dict]:
    out = Path(task["out"])
    st = _task_settings(task)
    res = oracle_lap(st, out)
    write_json(out / "oracle.json", res)
    Steps(out).mark("oracle")
    return [res]


def _run_chain(task: dict) -> list[dict]:
    """One trial: iteration 0, then per iteration select, retrain, plan, drive; each step once
    (a rerun resumes after the last step marked done)."""
    c = _chain(task)
    _iteration_zero(c)
    for i in range(1, c.st.iterations + 1):
        alpha = c.st.alpha(i)
        if not c.steps.done(c.tag(i, "drive")):
            console.info(f"iterate: {c.out.name} trial {c.trial} iteration {i} (alpha {alpha:g}): select, retrain, "
                         "plan, drive")
        for name, step in (("select", _select), ("retrain", _retrain), ("plan", _replan)):
            if not c.steps.done(c.tag(i, name)):
                step(c, i)
                c.steps.mark(c.tag(i, name))
        if not c.steps.done(c.tag(i, "drive")):
            _drive_iteration(c, i, alpha)
            c.steps.mark(c.tag(i, "drive"))
    return [c.record(i) for i in range(c.st.iterations + 1)]
