"""One executor for batches of independent tasks (tracks, trials, seeds).

``run_batch(fn, tasks, executor="local"|"dask", workers=N, scheduler=ADDRESS)`` calls the
module-level function ``fn(task)`` for every task and returns one :class:`TaskResult` per task in
task order. Each task carries its own seed, so results do not depend on which executor or worker
ran it. A task that raises is recorded as failed with its error message and the batch goes on.

Ctrl-C or SIGTERM (:mod:`gprace.interrupt`) ends the batch: the local workers are interrupted and,
if they do not stop within ``STOP_GRACE`` seconds, killed; Dask tasks are cancelled and told to
stop. The batch then raises ``KeyboardInterrupt``, and only after every local worker is gone, so
the output folder's lock outlives them. A task that saw the signal is never returned as finished.

``workers=1`` with the local executor runs in-process (no pickling), which tests and debuggers like.
"""

from __future__ import annotations

import functools
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from gprace import interrupt
from gprace.errors import ConfigError, InputError

STOP_GRACE = 10.0
"""Seconds interrupted local workers get to unwind (remove their temporary files) before they are killed."""


@dataclass
class TaskResult:
    index: int
    ok: bool
    value: Any = None
    error: str = ""
    interrupted: bool = False


def single_thread_blas(fn: Callable) -> Callable:
    """Run ``fn`` with one BLAS thread in every BLAS library of the process.

    Batches already run one task per core, and the tasks' small matrix products are 10 to 60
    times slower with threaded BLAS on a busy 2-core machine (measured on the GP rollout: 0.57 ms
    vs 15 to 37 ms per predict call). SciPy ships its own OpenBLAS, loaded only when
    ``scipy.linalg`` is first imported: it is imported here before the limit is set, otherwise the
    first task of a process would run threaded and round differently from the later ones (a race
    is chaotic enough to turn that 1e-16 into another outcome).
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        import scipy.linalg  # noqa: F401 -- loads SciPy's BLAS before the limit (see above)
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1):
            return fn(*args, **kwargs)

    return wrapper


def _call(fn: Callable[[Any], Any], index: int, task: Any, stop: str | None = None) -> TaskResult:
    """One task; ``stop``: the Dask event that says the command was interrupted."""
    try:
        with interrupt.task(interrupt.task_stop(stop) if stop else None):
            value = fn(task)
            interrupt.check()  # a result computed across the signal (a solver swallowed it) is not a result
        return TaskResult(index, True, value)
    except KeyboardInterrupt:
        return TaskResult(index, False, None, "interrupted", interrupted=True)
    except Exception as exc:  # recorded, not fatal
        tb = traceback.format_exc(limit=3)
        return TaskResult(index, False, None, f"{type(exc).__name__}: {exc}\n{tb}")


def check_execution(executor: str, workers: int = 1, scheduler: str | None = None, timeout: float = 3.0) -> None:
    """``--executor``, ``--workers`` and ``--scheduler``, checked before any work: a Dask scheduler
    that cannot be reached fails fast, with nothing run and finished artifacts kept."""
    if executor not in ("local", "dask"):
        raise ConfigError(f"unknown executor {executor!r}; available: local, dask")
    if workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    if executor != "dask":
        return
    if not scheduler:
        raise ConfigError("--executor dask needs --scheduler tcp://HOST:PORT")
    import socket
    from urllib.parse import urlparse

    u = urlparse(scheduler if "://" in scheduler else f"tcp://{scheduler}")
    if not u.hostname or not u.port:
        raise InputError(f"--scheduler {scheduler!r}: expected tcp://HOST:PORT")
    try:
        socket.create_connection((u.hostname, u.port), timeout=timeout).close()
    except OSError as exc:
        raise InputError(f"cannot reach Dask scheduler {scheduler}: {exc}; nothing was run and finished artifacts are kept") from None


def run_batch(
    fn: Callable[[Any], Any],
    tasks: Sequence[Any],
    executor: str = "local",
    workers: int = 1,
    scheduler: str | None = None,
    on_done: Callable[[TaskResult], None] | None = None,
    label: str = "tasks",
) -> list[TaskResult]:
    """Run ``fn`` over ``tasks``; ``on_done`` is called as each finishes (for saving).

    A progress bar named ``label`` counts finished tasks on a terminal (silent otherwise).
    """
    from gprace.console import console

    if executor not in ("local", "dask") or workers < 1:
        check_execution(executor, workers)  # raises
    results: list[TaskResult | None] = [None] * len(tasks)

    with console.progress(label, total=len(tasks)) as bar:

        def done(r: TaskResult) -> None:
            if r.interrupted:
                raise KeyboardInterrupt
            results[r.index] = r
            if on_done is not None:
                on_done(r)
            bar.advance()

        if executor == "dask":
            _dask(fn, tasks, scheduler, done)
        elif workers == 1 or len(tasks) <= 1:
            for i, t in enumerate(tasks):
                done(_call(fn, i, t))
        else:
            _local(fn, tasks, workers, done)
    return [r for r in results if r is not None]


def _local(fn: Callable[[Any], Any], tasks: Sequence[Any], workers: int, done: Callable[[TaskResult], None]) -> None:
    pool = ProcessPoolExecutor(max_workers=workers, initializer=interrupt.worker_init)
    finished = False
    try:
        futs = [pool.submit(_call, fn, i, t) for i, t in enumerate(tasks)]
        for fut in as_completed(futs):
            done(fut.result())
        finished = True
    finally:
        if finished:
            pool.shutdown()
        else:  # Ctrl-C or a failure in the caller's callback: the workers must not run on
            _stop_workers(pool)


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Interrupt the pool's workers, give them ``STOP_GRACE`` seconds, then kill those left."""
    import os
    import signal

    procs = list((getattr(pool, "_processes", None) or {}).values())  # no public accessor before Python 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            os.kill(p.pid, signal.SIGINT)
        except (ProcessLookupError, TypeError):
            pass
    end = time.monotonic() + STOP_GRACE
    for p in procs:
        p.join(timeout=max(end - time.monotonic(), 0.0))
    for p in procs:
        if p.is_alive():
            p.kill()
            p.join(timeout=5.0)


def _dask(fn: Callable[[Any], Any], tasks: Sequence[Any], scheduler: str | None,
          done: Callable[[TaskResult], None]) -> None:
    import uuid

    if not scheduler:
        raise ConfigError("--executor dask needs --scheduler tcp://HOST:PORT")
    from dask.distributed import Client, Event, as_completed as dask_completed

    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise InputError(f"cannot reach Dask scheduler {scheduler}: {exc}") from None
    stop = f"gprace-stop-{uuid.uuid4().hex}"
    futs = []
    finished = False
    try:
        futs = [client.submit(_call, fn, i, t, stop, pure=False) for i, t in enumerate(tasks)]
        for fut in dask_completed(futs):
            done(fut.result())
        finished = True
    finally:
        if not finished:
            # running tasks cannot be killed from here: they read the event before they record anything
            try:
                Event(stop, client=client).set()
                client.cancel(futs, force=True)
            except interrupt.LOST_SCHEDULER:  # its tasks are gone anyway; the interrupt goes on
                pass
        client.close()
