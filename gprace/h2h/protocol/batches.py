"""Batches of runs: every task through the executor, one record per task, reused by its hash."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from gprace.h2h.protocol.settings import Settings
from gprace.h2h.records import RaceAttrs, Record, RecordAttrs, migrate, read_record, record_of, warn_old, write_record
from gprace.h2h.tasks import BuildTask, RaceTask, Task, task_hash

def _record_path(run_dir: Path, i: int) -> Path:
    return run_dir / f"run_{i:05d}.h5"


def race_with_data(task: RaceTask | dict) -> dict:
    """:func:`run_race` plus the GP training pairs of the run (computed in the worker)."""
    from gprace.h2h.geometry import make_track
    from gprace.h2h.predictors import training_pairs
    from gprace.h2h.race import run_race

    import time

    task = RaceTask.of(task)
    t0 = time.perf_counter()
    out = run_race(task)
    out["attrs"]["wall_s"] = time.perf_counter() - t0
    a = out["arrays"]
    Z, Y = training_pairs(make_track(task.track), a.get("ego_meas", a["ego"]), a.get("opp_meas", a["opp"]))
    out["arrays"]["Z"], out["arrays"]["Y"] = Z, Y
    return out


def _reusable(tasks: list[Task], run_dir: Path, schema: type[RecordAttrs], what: str) -> dict[int, Record]:
    """The records in ``run_dir`` that finished their task as it is now (same hash), by task index;
    one of an older layout is migrated. One warning for all old records, one for all unreadable
    ones (their tasks are rerun, and so rewritten, like those of the other records not reused)."""
    from gprace.console import console
    from gprace.errors import ArtifactError

    reused, old, unreadable = {}, [], []
    for i, t in enumerate(tasks):
        p = _record_path(run_dir, i)
        if not p.exists():
            continue
        try:
            rec = read_record(p, schema, warn=False)
        except ArtifactError as exc:
            unreadable.append(str(exc))
            continue
        old += [p] if rec.old else []
        if rec.attrs.ok and rec.attrs.task_hash == task_hash(t):
            reused[i] = migrate(p, rec)
    warn_old(old, migrated=True)
    if unreadable:
        console.warn(f"{what}: {len(unreadable)} unreadable record(s) rerun; the first: {unreadable[0]}")
    return reused


_BUILT: set[str] = set()  # race configurations whose NMPCs this process has had built


def _build_controllers(config: dict, st: Settings) -> None:
    """Build the two cars' NMPCs of a race ``config`` side by side, once per process, before the
    first batch of races with more than one worker: each NLP compiles once per machine (25 to 50 s),
    and workers that all start with the ego would compile the two one after the other."""
    from gprace.executor import run_batch
    from gprace.h2h.race import build_controller

    key = json.dumps(config, sort_keys=True)
    if key in _BUILT or (st.workers == 1 and st.executor == "local"):
        return
    run_batch(build_controller, [BuildTask(config=config, car=car) for car in ("ego", "opponent")],
              executor=st.executor, workers=2, scheduler=st.scheduler, label="building the two cars' NMPCs")
    _BUILT.add(key)


def run_tasks(tasks: list[Task], run_dir: Path, st: Settings, what: str,
              fn: Callable[[Task], dict] = race_with_data, schema: type[RecordAttrs] = RaceAttrs) -> list[Record]:
    """Run (or reuse, with ``resume``) every task; returns one record per task, written and typed
    by ``schema`` (:mod:`gprace.h2h.records`; ``attrs.ok`` and ``attrs.error`` say how it ran)."""
    from gprace.console import console
    from gprace.executor import run_batch

    run_dir.mkdir(parents=True, exist_ok=True)
    records: list[Record | None] = [None] * len(tasks)
    for i, rec in (_reusable(tasks, run_dir, schema, what) if st.resume else {}).items():
        records[i] = rec
    todo = [i for i, r in enumerate(records) if r is None]
    if todo and schema is RaceAttrs:
        _build_controllers(tasks[todo[0]].config, st)

    def done(r) -> None:
        i = todo[r.index]
        p = _record_path(run_dir, i)
        records[i] = write_record(p, record_of(schema, tasks[i].as_dict(), task_hash(tasks[i]), r.ok, r.value, r.error, str(p)))
        if not r.ok:
            console.warn(f"{what}: run {i} failed and is skipped: {r.error.splitlines()[0]}")

    run_batch(fn, [tasks[i] for i in todo], executor=st.executor, workers=st.workers,
              scheduler=st.scheduler, on_done=done, label=f"{what}: {len(todo)} runs to do ({len(tasks) - len(todo)} reused)")
    return [r for r in records if r is not None]
