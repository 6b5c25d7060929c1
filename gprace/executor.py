"""One executor for batches of independent tasks (tracks, trials, seeds).

``run_batch(fn, tasks, executor="local"|"dask", workers=N, scheduler=ADDRESS)`` calls the
module-level function ``fn(task)`` for every task and returns one :class:`TaskResult` per task in
task order. Each task carries its own seed, so results do not depend on which executor or worker
ran it. A task that raises is recorded as failed with its error message and the batch goes on.

``workers=1`` with the local executor runs in-process (no pickling), which tests and debuggers like.
"""

from __future__ import annotations

import functools
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

from gprace.errors import ConfigError, InputError


@dataclass
class TaskResult:
    index: int
    ok: bool
    value: Any = None
    error: str = ""


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


def _call(fn: Callable[[Any], Any], index: int, task: Any) -> TaskResult:
    try:
        return TaskResult(index, True, fn(task))
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
            results[r.index] = r
            if on_done is not None:
                on_done(r)
            bar.advance()

        if executor == "dask":
            for r in _dask(fn, tasks, scheduler):
                done(r)
        elif workers == 1 or len(tasks) <= 1:
            for i, t in enumerate(tasks):
                done(_call(fn, i, t))
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                futs = [pool.submit(_call, fn, i, t) for i, t in enumerate(tasks)]
                for fut in as_completed(futs):
                    done(fut.result())
    return [r for r in results if r is not None]


def _dask(fn: Callable[[Any], Any], tasks: Sequence[Any], scheduler: str | None) -> Iterable[TaskResult]:
    if not scheduler:
        raise ConfigError("--executor dask needs --scheduler tcp://HOST:PORT")
    from dask.distributed import Client, as_completed as dask_completed

    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise InputError(f"cannot reach Dask scheduler {scheduler}: {exc}") from None
    try:
        futs = [client.submit(_call, fn, i, t, pure=False) for i, t in enumerate(tasks)]
        for fut in dask_completed(futs):
            yield fut.result()
    finally:
        client.close()
