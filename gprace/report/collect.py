"""Find gprace results under a folder; the :class:`Section` a domain fills; shared helpers.

Scanning is by content, not by file name: HDF5 files by their ``kind`` attribute, JSON files by
their keys (:func:`gprace.report.inspect.json_kind`). Each domain's collector
(:mod:`gprace.report.sections`) returns a :class:`Section` with its figures and tables and, for
anything it expected but did not find or could not read, a one-line note; nothing raises on a
partial or odd folder.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from gprace.report.inspect import COMPUTE_FAILED, artifact_kind, json_kind


@dataclass
class Item:
    caption: str
    figure: Any = None  # matplotlib Figure
    html: str = ""  # a table or text block (already escaped)
    name: str = ""  # file stem for --png


@dataclass
class Section:
    key: str
    title: str
    items: list[Item] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)

    def add_figure(self, name: str, caption: str, make: Callable[[], Any]) -> None:
        """Add ``make()``; a figure that fails becomes a note naming the error, never a crash."""
        try:
            self.items.append(Item(caption, figure=make(), name=name))
        except COMPUTE_FAILED as exc:  # a report shows what it can
            self.missing.append(f"{caption}: could not be drawn ({type(exc).__name__}: {exc})")


@dataclass
class Found:
    """Result files under a folder, by kind (``kind -> [paths]``) and parsed JSON (path -> obj)."""

    root: Path
    files: dict[str, list[Path]] = field(default_factory=dict)
    json: dict[Path, Any] = field(default_factory=dict)

    def of(self, *kinds: str) -> list[Path]:
        out: list[Path] = []
        for k in kinds:
            out += self.files.get(k, [])
        return sorted(set(out))

    def kinds_like(self, part: str) -> list[Path]:
        return sorted({p for k, ps in self.files.items() if part in k for p in ps})


def scan(root: str | Path) -> Found:
    """Every artifact (``*.h5``, ``*.hdf5``) and result JSON below ``root``, skipping hidden and
    temporary files (an interrupted atomic write leaves ``.name.tmp``)."""
    root = Path(root)
    found = Found(root)
    for p in sorted(root.rglob("*")):
        if not p.is_file() or any(part.startswith(".") for part in p.relative_to(root).parts):
            continue
        suf = p.suffix.lower()
        if suf in (".h5", ".hdf5"):
            k = artifact_kind(p)
            if k is not None:
                found.files.setdefault(k, []).append(p)
        elif suf == ".json":
            try:
                obj = json.loads(p.read_text())
            except (OSError, UnicodeDecodeError, ValueError):
                continue
            found.json[p] = obj
            found.files.setdefault(json_kind(obj), []).append(p)
    return found


# ----------------------------------------------------------------------------------------------
# helpers
ITER_RE = r"^iter_(\d+)$"  # the folders of `gprace iterate`: trial_<j>/iter_<i>/
TRIAL_RE = r"^trial_(\d+)$"


def path_number(path: Path, pattern: str) -> int | None:
    """The number in the last path component matching ``pattern`` (e.g. ``iter_03`` -> 3)."""
    for part in reversed(path.parts):
        m = re.search(pattern, part)
        if m:
            return int(m.group(1))
    return None


def table(headers: list[str], rows: list[list[Any]]) -> str:
    import html

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "-" if not np.isfinite(v) else f"{v:.4g}"
        if isinstance(v, (list, tuple)):
            return ", ".join(cell(x) for x in v)
        return html.escape(str(v))

    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def load_track(name: Any, override: str | None):
    from gprace.report.single import try_track

    return try_track(override) if override else try_track(name)
