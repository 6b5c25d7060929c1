"""One console wrapper: results to stdout, progress and diagnostics to stderr.

Progress bars appear only when stderr is a terminal and ``quiet`` is off, so scripts and tests
see deterministic output. A bar counts units of work (``unit``: laps, stages, tasks) and shows an
ETA at the rate of this session (work already done when the bar started, e.g. on a resume, does
not count towards the rate). One bar at a time: a bar opened while another is shown becomes a
line above it, so an outer bar (``iterate``'s laps) is not replaced by an inner one (the batch's
tasks). :meth:`Console.polled` reads its count from a function, for work done in other processes. Off a terminal a long stage is not silent: it prints one start line on
stderr (:meth:`Console.info`, which is also what a progress bar becomes there); ``quiet``
silences both. Stdout holds results only, so ``--json`` output stays pure JSON.
"""

from __future__ import annotations

import contextlib
import json
import sys
import threading
from collections.abc import Iterable, Iterator
from typing import Any

from rich.console import Console as _RichConsole
from rich.table import Table


class Console:
    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet
        # no file= binding: rich looks up sys.stdout/sys.stderr at print time, so redirection
        # (pytest's capsys, shell pipes set up later) always sees the output
        self.out = _RichConsole(highlight=False, soft_wrap=True)
        self.err = _RichConsole(stderr=True, highlight=False, soft_wrap=True)
        self._live = False  # a bar is shown

    # results -----------------------------------------------------------------
    def result(self, text: str = "") -> None:
        self.out.print(text, markup=False)

    def json(self, obj: Any) -> None:
        """Strict JSON: a non-finite number is ``null``, never a bare ``NaN`` that parsers reject."""
        sys.stdout.write(json.dumps(jsonable(obj), indent=2, default=json_default, allow_nan=False) + "\n")
        sys.stdout.flush()

    def table(self, title: str, columns: list[str], rows: Iterable[Iterable[Any]]) -> None:
        t = Table(title=title)
        for c in columns:
            t.add_column(c)
        for r in rows:
            t.add_row(*[_fmt(v) for v in r])
        # off-terminal (pipes, logs, files) rich assumes 80 columns and truncates cells; there
        # tables get their natural width (up to 200 columns)
        out = self.out if self.out.is_terminal else _RichConsole(highlight=False, soft_wrap=True, width=200)
        out.print(t)

    # diagnostics --------------------------------------------------------------
    def info(self, text: str) -> None:
        if not self.quiet:
            self.err.print(text, markup=False)

    def warn(self, text: str) -> None:
        self.err.print(f"warning: {text}", markup=False)

    def error(self, text: str) -> None:
        self.err.print(f"error: {text}", markup=False)

    @contextlib.contextmanager
    def progress(self, description: str, total: int | None = None, completed: int = 0,
                 unit: str = "") -> Iterator["_Progress"]:
        """Context manager yielding an object with ``advance(n=1)`` and ``update(completed=,
        description=)``: a bar on a terminal (``completed`` of ``total`` ``unit``, ETA), one start
        line (``description``) off it or inside another bar."""
        if self.quiet or not sys.stderr.isatty() or self._live:
            self.info(description)
            yield _Progress(None, None)
            return
        from rich.progress import BarColumn, Progress, TextColumn

        count, eta = _columns()
        columns = (TextColumn("[progress.description]{task.description}"), BarColumn(), count(), eta())
        self._live = True
        try:
            with Progress(*columns, console=self.err, transient=True) as p:
                task = p.add_task(description, total=total, completed=completed, base=completed, unit=unit)
                yield _Progress(p, task)
        finally:
            self._live = False

    @contextlib.contextmanager
    def polled(self, description: str, total: int, count, unit: str = "", interval: float = 1.0) -> Iterator["_Progress"]:
        """:meth:`progress` whose count is ``count()``, read every ``interval`` seconds in a thread
        (work finished by other processes, seen as files on disk) and once more at the end."""
        with self.progress(description, total, completed=count(), unit=unit) as bar:
            if not bar.live:
                yield bar
                return
            stop = threading.Event()

            def poll() -> None:
                while not stop.wait(interval):
                    with contextlib.suppress(OSError):
                        bar.update(completed=count())

            th = threading.Thread(target=poll, name="gprace-progress", daemon=True)
            th.start()
            try:
                yield bar
            finally:
                stop.set()
                th.join()
                with contextlib.suppress(OSError):
                    bar.update(completed=count())


class _Progress:
    def __init__(self, progress, task) -> None:
        self._p, self._t = progress, task

    @property
    def live(self) -> bool:
        """A bar is shown (a terminal, not quiet, not inside another bar)."""
        return self._p is not None

    def advance(self, n: int = 1) -> None:
        if self._p is not None:
            self._p.advance(self._t, n)

    def update(self, completed: float | None = None, description: str | None = None) -> None:
        if self._p is not None:
            self._p.update(self._t, completed=completed, description=description)


def eta_seconds(done_here: float, remaining: float | None, elapsed: float | None) -> float | None:
    """Seconds left at this session's rate (``elapsed`` seconds for the ``done_here`` units done
    since the bar started); None before the first unit is done or without a total."""
    if done_here <= 0 or remaining is None or elapsed is None:
        return None
    return elapsed / done_here * max(remaining, 0.0)


def _hms(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}"


def _columns():
    from rich.progress import ProgressColumn
    from rich.text import Text

    class Count(ProgressColumn):
        """``done/total unit``."""

        def render(self, task):
            total = "?" if task.total is None else f"{task.total:.0f}"
            unit = task.fields.get("unit", "")
            return Text(f"{task.completed:.0f}/{total}" + (f" {unit}" if unit else ""), style="progress.download")

    class Eta(ProgressColumn):
        """``ETA h:mm:ss`` at the rate of this session (:func:`eta_seconds`)."""

        max_refresh = 1.0

        def render(self, task):
            eta = eta_seconds(task.completed - task.fields.get("base", 0), task.remaining, task.elapsed)
            return Text("ETA " + ("-:--:--" if eta is None else _hms(eta)), style="progress.remaining")

    return Count, Eta


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def jsonable(obj: Any) -> Any:
    """``obj`` with every non-finite float as None (strict JSON: ``null``, never a bare NaN);
    numpy scalars and arrays become Python numbers and lists."""
    import math

    import numpy as np

    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def json_default(o: Any) -> Any:
    """What :func:`json.dumps` cannot write: numpy scalars and arrays as numbers and lists, the rest as text."""
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


console = Console()
