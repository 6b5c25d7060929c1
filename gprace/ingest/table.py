"""Text tables as loggers write them: preambles, header rules, separators, BOM, CRLF.

One sniffer for every delimited text file gprace reads as it comes (raw recordings, track centre
lines, boundary polylines):

* **Encoding and line ends**: UTF-8 with or without a byte-order mark; LF, CRLF or CR.
* **Comments**: lines starting with ``#`` (after blanks) are comments wherever they are; blank
  lines are skipped.
* **Separator**: ``,``, ``;``, tab or ``|``, whichever splits the first data lines into the same
  number (> 1) of fields; else runs of blanks. With ``;`` and numbers like ``1,5`` the decimal
  mark is the comma.
* **Header rule**: let D be the first line that is neither blank nor a comment. D is the header
  when more than half of its non-empty fields are not numbers. Otherwise D is data, and the header
  is the *last comment line* before it if that line splits into as many fields as D (``# time(s),
  x(m),...`` as the IAC logs have it; ``# x_m,y_m,...`` as TUM's tracks); when it does not (a
  preamble ending in ``# Data:``), the table has no header and its columns are named ``1, 2, ...``.

:func:`sniff` reads the layout, :func:`numbers` the body as floats (empty cells NaN) and
:func:`strings` a column as text (long-format channel names). Errors name the file, the row and
line (:func:`gprace.errors.at_row`) and the column.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gprace.errors import InputError, at_row

SEPARATORS = (",", ";", "\t", "|")
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf|infinity)$", re.IGNORECASE)
_DECIMAL_COMMA = re.compile(r"^[+-]?\d+,\d+([eE][+-]?\d+)?$")


def is_number(cell: str) -> bool:
    return bool(_NUMBER.match(cell.strip()))


@dataclass
class Table:
    """Layout of a delimited text file (module docstring) and its body lines."""

    path: Path
    names: list[str]  # column names (``"1".."n"`` when headerless)
    has_header: bool
    header_line: int | None  # 1-based file line of the header (a comment line or D)
    sep: str | None  # None: runs of blanks
    decimal: str
    body: list[str]  # data lines (no comments, no blanks), in file order
    body_lines: np.ndarray  # (n,) 1-based file line of each body line

    @property
    def n(self) -> int:
        return len(self.body)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def split(self, line: str) -> list[str]:
        return line.split(self.sep) if self.sep is not None else line.split()


def read_text(path: Path) -> str:
    """The text of ``path`` (UTF-8, a BOM dropped); a binary file is an :class:`InputError`."""
    try:
        blob = path.read_bytes()
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not a file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if b"\x00" in blob[:65536]:
        raise InputError(f"{path}: not a text file (binary content)")
    try:
        return blob.decode("utf-8-sig")
    except UnicodeDecodeError:
        try:
            return blob.decode("cp1252")  # an old Windows logger; numbers are ASCII either way
        except UnicodeDecodeError:
            raise InputError(f"{path}: not a text file (neither UTF-8 nor Windows-1252)") from None


def _separator(lines: list[str]) -> str | None:
    """The separator that splits every sample line into the same number (> 1) of fields."""
    best, best_n = None, 1
    for sep in SEPARATORS:
        counts = {ln.count(sep) for ln in lines}
        if len(counts) == 1 and (n := counts.pop() + 1) > best_n:
            best, best_n = sep, n
    if best is not None:
        return best
    counts = {len(ln.split()) for ln in lines}
    return None if len(counts) == 1 and counts.pop() > 1 else ","


def peek_names(path: str | Path, nbytes: int = 1 << 16) -> list[str]:
    """Column names of a delimited text file from its first ``nbytes`` (cheap: for dispatch);
    an empty list when it cannot tell."""
    try:
        with Path(path).open("rb") as fh:
            head = fh.read(nbytes)
        text = head.decode("utf-8-sig", errors="replace")
        lines = text.splitlines()[:-1] if len(head) == nbytes else text.splitlines()
        return _layout(Path(path), lines, "file")[0]
    except (OSError, InputError):
        return []


def sniff(path: str | Path, what: str = "file") -> Table:
    """The layout of the delimited text file ``path`` (module docstring)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    text = read_text(path)
    names, has_header, header_line, sep, decimal, body = _layout(path, text.splitlines(), what)
    return Table(path, names, has_header, header_line, sep, decimal, [ln for _, ln in body],
                 np.fromiter((i for i, _ in body), dtype=np.int64, count=len(body)))


def _layout(path: Path, lines: list[str], what: str):
    kept = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]
    if not kept:
        raise InputError(f"{path}: empty file (no {what} in it)")
    is_comment = [ln.lstrip().startswith("#") for _, ln in kept]
    first = next((k for k, c in enumerate(is_comment) if not c), None)
    if first is None:
        raise InputError(f"{path}: no data rows (only comment lines)")
    sample = [kept[k][1] for k in range(first, min(len(kept), first + 8)) if not is_comment[k]]
    # the separator from the data (or the header and data) lines; a header may hold ';' or ','
    # in its names, so it is tried with the data first and alone last
    sep = _separator(sample[1:] or sample)
    d_line, d_text = kept[first]

    def fields(s: str) -> list[str]:
        return [c.strip() for c in (s.split(sep) if sep is not None else s.split())]

    d_fields = fields(d_text)
    nonempty = [c for c in d_fields if c]
    wordy = sum(not is_number(c) and not _DECIMAL_COMMA.match(c) for c in nonempty)
    if nonempty and wordy > 0.5 * len(nonempty):
        names, header_line, start = d_fields, d_line, first + 1
        if len(sample) == 1:  # a header alone: split it like the data would be
            sep = _separator(sample)
            names = fields(d_text)
    else:
        names, header_line, start = None, None, first
        prev = [k for k in range(first) if is_comment[k]]
        if prev:
            k = prev[-1]
            cand = fields(kept[k][1].lstrip()[1:])
            if len(cand) == len(d_fields) and sum(not is_number(c) for c in cand if c) > 0.5 * max(1, sum(1 for c in cand if c)):
                names, header_line = cand, kept[k][0]
    has_header = names is not None
    body = [(i, ln) for k, (i, ln) in enumerate(kept[start:], start=start) if not is_comment[k]]
    if not body:
        raise InputError(f"{path}: no data rows after the header")
    ncol = len(fields(body[0][1]))
    if names is None:
        names = [str(j + 1) for j in range(ncol)]
    names = [c if c else f"_unnamed_{j + 1}" for j, c in enumerate(names)]
    decimal = "."
    if sep == ";" and any(_DECIMAL_COMMA.match(c) for ln in sample[:4] for c in fields(ln)):
        decimal = ","
    return names, has_header, header_line, sep, decimal, body


def numbers(tbl: Table, columns: list[str] | None = None) -> np.ndarray:
    """The body of ``tbl`` as floats, shape ``(n, len(columns))`` (all columns when None);
    empty cells are NaN. A row with another number of fields than the header, or a cell of a
    requested column that is not a number, is an :class:`InputError` naming row, line, column."""
    cols = tbl.names if columns is None else list(columns)
    idx = [tbl.index(c) for c in cols]
    ncol = len(tbl.names)
    if tbl.sep is not None:
        counts = np.fromiter((ln.count(tbl.sep) for ln in tbl.body), dtype=np.int64, count=tbl.n) + 1
    else:
        counts = np.fromiter((len(ln.split()) for ln in tbl.body), dtype=np.int64, count=tbl.n)
    bad = np.flatnonzero(counts != ncol)
    if len(bad):
        r = int(bad[0])
        raise InputError(f"{tbl.path}: {at_row(r + 1, int(tbl.body_lines[r]))} has {counts[r]} fields, "
                         f"the {'header' if tbl.has_header else 'first row'} has {ncol} (truncated file?)")
    import pandas as pd

    src = io.StringIO("\n".join(tbl.body))
    kw = dict(header=None, names=list(range(ncol)), usecols=idx, engine="c" if tbl.sep is not None else "python",
              skip_blank_lines=True, decimal=tbl.decimal)
    if tbl.sep is None:
        kw["sep"] = r"\s+"
    else:
        kw["sep"] = tbl.sep
    try:
        df = pd.read_csv(src, dtype=float, **kw)
        return df[idx].to_numpy(dtype=float)
    except (ValueError, pd.errors.ParserError):
        pass  # a cell that is not a number: find it
    src.seek(0)
    df = pd.read_csv(src, dtype=str, keep_default_na=False, **kw)
    out = np.empty((tbl.n, len(idx)))
    for k, j in enumerate(idx):
        raw = df[j].str.strip()
        if tbl.decimal == ",":
            raw = raw.str.replace(",", ".", regex=False)
        val = pd.to_numeric(raw.where(raw != "", None), errors="coerce").to_numpy(dtype=float)
        wrong = np.isnan(val) & (raw != "").to_numpy() & ~raw.str.lower().isin(["nan", "+nan", "-nan"]).to_numpy()
        if wrong.any():
            r = int(np.argmax(wrong))
            raise InputError(f"{tbl.path}: column {tbl.names[j]!r} {at_row(r + 1, int(tbl.body_lines[r]))}: "
                             f"{raw.iloc[r]!r} is not a number")
        out[:, k] = val
    return out


def strings(tbl: Table, column: str) -> np.ndarray:
    """One column of the body as stripped strings."""
    import pandas as pd

    j = tbl.index(column)
    kw = {"sep": tbl.sep} if tbl.sep is not None else {"sep": r"\s+"}
    df = pd.read_csv(io.StringIO("\n".join(tbl.body)), header=None, names=list(range(len(tbl.names))), usecols=[j],
                     dtype=str, keep_default_na=False, engine="c" if tbl.sep is not None else "python", **kw)
    return df[j].str.strip().to_numpy(dtype=object)
