"""Ctrl-C and SIGTERM: one way to stop, in the command's process and in every worker it started.

The first signal sets a flag of the process (:func:`requested`) and raises ``KeyboardInterrupt``
where the process is: the command unwinds, its output-folder lock is released, and the CLI prints
one line and exits 130. Later signals only set the flag (a second Ctrl-C does not interrupt the
clean-up). A worker process raises only inside a task (an idle worker would print a traceback from
the pool's own code); the executor turns the task into an interrupted result, never a finished one.

Native solvers take the signal themselves: CasADi catches the ``KeyboardInterrupt`` raised inside
an IPOPT iteration, returns a failed solve and prints a warning. So a result is recorded only
after :func:`check` (every artifact and JSON writer of :mod:`gprace.io.artifacts` calls it, and
the solver wrappers after a solve): a solve cut short by the signal is never stored as a result
and is computed again when the command is rerun. From the signal on, the process's stderr is
quiet (the solvers' warnings, Python's "Exception ignored" notes) until the CLI restores it for
its one line.

Tasks on Dask workers run in other processes, usually on other machines: the executor sets a
named Dask event when the command is interrupted, and :func:`requested` in such a task also reads
it (:func:`task_stop`).
"""

from __future__ import annotations

import contextlib
import contextvars
import signal
import sys
from collections.abc import Callable, Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)

_state = {"flag": False, "raised": False, "worker": False, "in_task": False, "stderr": None}
_stop: contextvars.ContextVar[Callable[[], bool] | None] = contextvars.ContextVar("gprace_task_stop", default=None)


class _Quiet:
    """A stderr that swallows what is written to it (after the signal)."""

    def write(self, text: str) -> int:
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


#: What a Dask scheduler that went away raises (connection closed, timed out, client shut down).
LOST_SCHEDULER = (OSError, TimeoutError, EOFError, RuntimeError)

def requested() -> bool:
    """Was this process (or, in a Dask task, its command) interrupted?"""
    if _state["flag"]:
        return True
    stop = _stop.get()
    return bool(stop is not None and stop())


def check() -> None:
    """Raise ``KeyboardInterrupt`` if the command was interrupted (call before recording a result)."""
    if requested():
        raise KeyboardInterrupt


def _handler(signum, frame) -> None:
    _state["flag"] = True
    if _state["stderr"] is None:
        _state["stderr"] = sys.stderr
        sys.stderr = _Quiet()
    if _state["raised"] or (_state["worker"] and not _state["in_task"]):
        return
    _state["raised"] = True
    raise KeyboardInterrupt


@contextlib.contextmanager
def handled(process: bool = False) -> Iterator[None]:
    """Ctrl-C and SIGTERM handled as above for the duration of one command (the CLI's entry).

    Outside the main thread (a caller's own thread) the handlers cannot be installed: Python then
    keeps its default Ctrl-C and the flag is never set by a signal. With ``process`` (the command
    is the whole process, see :func:`exit_process`) the handlers are not given back at the end: a
    signal after the command is only noted (:data:`late`), so it cannot kill the process on its
    way out.
    """
    reset()
    late.clear()
    try:
        old = {s: signal.signal(s, _handler) for s in SIGNALS}
    except ValueError:  # not the main thread of the interpreter
        old = {}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, _note_late if process else h)
        restore_stderr()
        reset()


late: list[int] = []  # the signals received after the command had finished (process mode)


def _note_late(signum, frame) -> None:
    late.append(signum)


def exit_process(code: int, line: Callable[[], None]) -> None:
    """End the process now with ``code``, once what Python runs at exit has run.

    Python's own shutdown of a command's process then frees every module and object one by one,
    which takes about a second after a diagnosis or an iteration (measured: 1.16 s after
    ``diagnose``); a signal in that second would otherwise kill the process without a word. The
    exit functions (``atexit``: logging, Dask, multiprocessing) and the joins of non-daemon
    threads run as at a normal exit; files are closed by the writers themselves. A signal that
    came after the command had finished (:data:`late`) turns a success into exit 130 and
    ``line()`` (the CLI's one line); a refusal keeps its own code and line.
    """
    import atexit
    import os
    import threading

    try:
        getattr(threading, "_shutdown", lambda: None)()  # non-daemon threads joined, as Python does at exit
        atexit._run_exitfuncs()
    finally:
        if late and code == 0:
            restore_stderr()
            line()
            code = 130
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(code)


def reset() -> None:
    _state.update(flag=False, raised=False)


def restore_stderr() -> None:
    """The stderr of before the signal (the CLI prints its line there)."""
    if _state["stderr"] is not None:
        sys.stderr = _state["stderr"]
        _state["stderr"] = None


def worker_init() -> None:
    """Initializer of a local worker process: the signal interrupts a task, never the idle worker."""
    _state.update(worker=True, flag=False, raised=False, in_task=False)
    for s in SIGNALS:
        signal.signal(s, _handler)


@contextlib.contextmanager
def task(stop: Callable[[], bool] | None = None) -> Iterator[None]:
    """The span of one task in a worker; ``stop`` is the remote stop flag of a Dask task."""
    token = _stop.set(stop)
    was = _state["in_task"]
    _state["in_task"] = True
    try:
        if requested():  # signalled before the task began (an idle worker, or a solver swallowed it)
            raise KeyboardInterrupt
        yield
    finally:
        _state["in_task"] = was
        _stop.reset(token)


def task_stop(name: str, every: float = 1.0) -> Callable[[], bool]:
    """A stop flag read from the Dask event ``name`` (at most once per ``every`` seconds)."""
    import time

    seen = {"at": -float("inf"), "set": False}

    def stop() -> bool:
        if not seen["set"] and time.monotonic() - seen["at"] >= every:
            from distributed import Event

            seen["at"] = time.monotonic()
            try:
                seen["set"] = bool(Event(name).is_set())
            except LOST_SCHEDULER:  # no scheduler reachable: nobody can have asked to stop
                seen["set"] = False
        return seen["set"]

    return stop
