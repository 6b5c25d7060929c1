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


class CellError(InputError):
    """A cell that is not a number: the file, its row and line, column and text (readers that
    word it their own way catch it)."""

    def __init__(self, path, row: int, line: int, column: str, text: str) -> None:
        self.path, self.row, self.line, self.column, self.text = path, row, line, column, text
        super().__init__(f"{path}: column {column!r} {at_row(row, line)}: {text!r} is not a number")


def is_number(cell: str) -> bool:
    return bool(_NUMBER.match(cell.strip()))


@dataclass
class Table:
    """Layout of a delimited text file (module docstring) and its body.

    The body is kept as one text (``body_text``, from the first data line on); ``body_lines``
    are the 1-based file lines of its data rows (blank and comment lines are not rows)."""

    path: Path
    names: list[str]  # column names (``"1".."n"`` when headerless)
    has_header: bool
    header_line: int | None  # 1-based file line of the header (a comment line or D)
    sep: str | None  # None: runs of blanks
    decimal: str
    body_text: str
    first_line: int  # 1-based file line where body_text starts

    def __post_init__(self) -> None:
        self._rows: np.ndarray | None = None  # (n, 2) character offsets of the data rows

    @property
    def rows(self) -> np.ndarray:
        """``(n, 2)`` start and end offsets in ``body_text`` of every data row (vectorised)."""
        if self._rows is None:
            self._rows, self._lines = _rows(self.body_text)
        return self._rows

    @property
    def body_lines(self) -> np.ndarray:
        self.rows
        return self._lines + self.first_line

    @property
    def n(self) -> int:
        return len(self.rows)

    def row_text(self, r: int) -> str:
        a, b = self.rows[r]
        return self.body_text[a:b]

    def index(self, name: str) -> int:
        return self.names.index(name)

    def split(self, line: str) -> list[str]:
        return line.split(self.sep) if self.sep is not None else line.split()

    def data_text(self) -> str:
        """The body without comment lines (blank lines are left: the parser skips them)."""
        if "#" not in self.body_text:
            return self.body_text
        return "\n".join(ln if not ln.lstrip().startswith("#") else "" for ln in self.body_text.split("\n"))


def _rows(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Offsets of the non-blank, non-comment lines of ``text`` and their 0-based line index,
    without a Python loop over lines (a comment line is one whose first non-blank byte is ``#``)."""
    b = np.frombuffer(text.encode("utf-8", errors="surrogatepass"), dtype=np.uint8)
    if len(b) and len(text) != len(b):  # multi-byte characters: offsets in characters differ
        lines = text.split("\n")
        lens = np.fromiter((len(ln) + 1 for ln in lines), dtype=np.int64, count=len(lines))
        starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
        keep = np.fromiter((bool(ln.strip()) and not ln.lstrip().startswith("#") for ln in lines), dtype=bool, count=len(lines))
        idx = np.flatnonzero(keep)
        return np.column_stack([starts[idx], starts[idx] + lens[idx] - 1]), idx
    nl = np.flatnonzero(b == 10)
    starts = np.concatenate([[0], nl + 1])
    ends = np.concatenate([nl, [len(b)]])
    first = b[np.minimum(starts, len(b) - 1)] if len(b) else np.zeros(len(starts), dtype=np.uint8)
    first = np.where(starts < ends, first, 10)
    keep = (first != 10) & (first != 35)  # not empty, not a comment
    lead = np.flatnonzero((first == 32) | (first == 9))
    for i in lead:  # lines that start with blanks (rare): look at their first other byte
        ln = text[starts[i]:ends[i]].lstrip()
        keep[i] = bool(ln) and not ln.startswith("#")
    idx = np.flatnonzero(keep)
    return np.column_stack([starts[idx], ends[idx]]), idx


def read_text(path: Path) -> str:
    """The text of ``path`` (UTF-8, a BOM dropped; line ends made ``\\n``); a binary file is an
    :class:`InputError`."""
    try:
        blob = path.read_bytes()
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not a file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if b"\x00" in blob[:65536]:
        raise InputError(f"{path}: not a text file (binary content)")
    try:
        text = blob.decode("utf-8-sig")
    except UnicodeDecodeError:
        try:
            text = blob.decode("cp1252")  # an old Windows logger; numbers are ASCII either way
        except UnicodeDecodeError:
            raise InputError(f"{path}: not a text file (neither UTF-8 nor Windows-1252)") from None
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


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
        text = head.decode("utf-8-sig", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
        if len(head) == nbytes:
            text = text[: text.rfind("\n") + 1]
        return _layout(Path(path), text, "file")[0]
    except (OSError, InputError):
        return []


def sniff(path: str | Path, what: str = "file") -> Table:
    """The layout of the delimited text file ``path`` (module docstring)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    text = read_text(path)
    names, has_header, header_line, sep, decimal, offset, first_line = _layout(path, text, what)
    tbl = Table(path, names, has_header, header_line, sep, decimal, text[offset:], first_line)
    if tbl.n == 0:
        raise InputError(f"{path}: no data rows after the header")
    return tbl


def _layout(path: Path, text: str, what: str):
    """Names, header flag and line, separator, decimal mark, and where the body starts (character
    offset and file line), from the head of ``text`` only."""
    # the head: enough lines to pass the preamble and see 8 data lines
    pos, kept, lines_seen = 0, [], 0
    data_seen = 0
    while pos < len(text) and data_seen < 9:
        nxt = text.find("\n", pos)
        end = len(text) if nxt < 0 else nxt
        ln = text[pos:end]
        lines_seen += 1
        if ln.strip():
            kept.append((lines_seen, ln, pos))
            if not ln.lstrip().startswith("#"):
                data_seen += 1
        pos = end + 1
    if not kept:
        raise InputError(f"{path}: empty file (no {what} in it)")
    is_comment = [ln.lstrip().startswith("#") for _, ln, _ in kept]
    first = next((k for k, c in enumerate(is_comment) if not c), None)
    if first is None:
        raise InputError(f"{path}: no data rows (only comment lines)")
    sample = [kept[k][1] for k in range(first, len(kept)) if not is_comment[k]][:8]
    # the separator from the data lines (a header may hold ';' or ',' in its names)
    sep = _separator(sample[1:] or sample)
    d_line, d_text, d_pos = kept[first]

    def fields(s: str) -> list[str]:
        return [c.strip() for c in (s.split(sep) if sep is not None else s.split())]

    d_fields = fields(d_text)
    nonempty = [c for c in d_fields if c]
    wordy = sum(not is_number(c) and not _DECIMAL_COMMA.match(c) for c in nonempty)
    if nonempty and wordy > 0.5 * len(nonempty):
        names, header_line = d_fields, d_line
        nxt = text.find("\n", d_pos)
        offset, first_line = (len(text), d_line + 1) if nxt < 0 else (nxt + 1, d_line + 1)
        if len(sample) == 1:  # a header alone: split it like the data would be
            sep = _separator(sample)
            names = fields(d_text)
        body_first = next((kept[k][1] for k in range(first + 1, len(kept)) if not is_comment[k]), None)
    else:
        names, header_line, offset, first_line = None, None, d_pos, d_line
        prev = [k for k in range(first) if is_comment[k]]
        if prev:
            k = prev[-1]
            cand = fields(kept[k][1].lstrip()[1:])
            if len(cand) == len(d_fields) and sum(not is_number(c) for c in cand if c) > 0.5 * max(1, sum(1 for c in cand if c)):
                names, header_line = cand, kept[k][0]
        body_first = d_text
    has_header = names is not None
    if body_first is None:
        raise InputError(f"{path}: no data rows after the header")
    ncol = len(fields(body_first))
    if names is None:
        names = [str(j + 1) for j in range(ncol)]
    names = [c if c else f"_unnamed_{j + 1}" for j, c in enumerate(names)]
    decimal = "."
    if sep == ";" and any(_DECIMAL_COMMA.match(c) for ln in sample[:4] for c in fields(ln)):
        decimal = ","
    return names, has_header, header_line, sep, decimal, offset, first_line


def _field_counts(tbl: Table) -> np.ndarray:
    """Fields of every data row, vectorised over the bytes (separator count + 1)."""
    rows = tbl.rows
    if tbl.sep is None:
        return np.fromiter((len(tbl.row_text(r).split()) for r in range(len(rows))), dtype=np.int64, count=len(rows))
    b = np.frombuffer(tbl.body_text.encode("utf-8", errors="surrogatepass"), dtype=np.uint8)
    if len(b) != len(tbl.body_text):
        return np.fromiter((tbl.row_text(r).count(tbl.sep) + 1 for r in range(len(rows))), dtype=np.int64, count=len(rows))
    pos = np.flatnonzero(b == ord(tbl.sep))
    return np.searchsorted(pos, rows[:, 1]) - np.searchsorted(pos, rows[:, 0]) + 1


def numbers(tbl: Table, columns: list[str] | None = None) -> np.ndarray:
    """The body of ``tbl`` as floats, shape ``(n, len(columns))`` (all columns when None);
    empty cells are NaN. A row with another number of fields than the header, or a cell of a
    requested column that is not a number, is an :class:`InputError` naming row, line, column."""
    cols = tbl.names if columns is None else list(columns)
    idx = [tbl.index(c) for c in cols]
    ncol = len(tbl.names)
    counts = _field_counts(tbl)
    bad = np.flatnonzero(counts != ncol)
    if len(bad):
        r = int(bad[0])
        raise InputError(f"{tbl.path}: {at_row(r + 1, int(tbl.body_lines[r]))} has {counts[r]} fields, "
                         f"the {'header' if tbl.has_header else 'first row'} has {ncol} (truncated file?)")
    import pandas as pd

    src = io.StringIO(tbl.data_text())
    kw = dict(header=None, names=list(range(ncol)), usecols=idx, engine="c" if tbl.sep is not None else "python",
              skip_blank_lines=True, decimal=tbl.decimal)
    kw["sep"] = tbl.sep if tbl.sep is not None else r"\s+"
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
            raise CellError(tbl.path, r + 1, int(tbl.body_lines[r]), tbl.names[j], raw.iloc[r])
        out[:, k] = val
    return out


def strings(tbl: Table, column: str) -> np.ndarray:
    """One column of the body as stripped strings."""
    import pandas as pd

    j = tbl.index(column)
    kw = {"sep": tbl.sep} if tbl.sep is not None else {"sep": r"\s+"}
    df = pd.read_csv(io.StringIO(tbl.data_text()), header=None, names=list(range(len(tbl.names))), usecols=[j],
                     dtype=str, keep_default_na=False, skip_blank_lines=True,
                     engine="c" if tbl.sep is not None else "python", **kw)
    return df[j].str.strip().to_numpy(dtype=object)
