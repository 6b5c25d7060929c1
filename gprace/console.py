"""One console wrapper: results to stdout, progress and diagnostics to stderr.

Progress bars appear only when stderr is a terminal and ``quiet`` is off, so scripts and tests
see deterministic output.
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
        sys.stdout.write(json.dumps(obj, indent=2, default=_json_default) + "\n")
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
        """Context manager yielding an object with ``advance(n=1)``; silent off-terminal."""
        if self.quiet or not sys.stderr.isatty():
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


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


console = Console()
