"""One console wrapper: results to stdout, progress and diagnostics to stderr.

Progress bars appear only when stderr is a terminal and ``quiet`` is off, so scripts and tests
see deterministic output. Off a terminal a long stage is not silent: it prints one start line on
stderr (:meth:`Console.info`, which is also what a progress bar becomes there); ``quiet``
silences both. Stdout holds results only, so ``--json`` output stays pure JSON.
"""

from __future__ import annotations

import contextlib
import json
import sys
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
    def progress(self, description: str, total: int | None = None) -> Iterator["_Progress"]:
        """Context manager yielding an object with ``advance(n=1)``: a bar on a terminal, one
        start line (``description``) off it."""
        if self.quiet or not sys.stderr.isatty():
            self.info(description)
            yield _Progress(None, None)
            return
        from rich.progress import Progress

        with Progress(console=self.err, transient=True) as p:
            task = p.add_task(description, total=total)
            yield _Progress(p, task)


class _Progress:
    def __init__(self, progress, task) -> None:
        self._p, self._t = progress, task

    def advance(self, n: int = 1) -> None:
        if self._p is not None:
            self._p.advance(self._t, n)


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
