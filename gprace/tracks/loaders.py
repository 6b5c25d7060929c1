"""Track loaders: centre lines (TUM CSV, headerless or not), two boundary files, segment TOML
files, shipped track names.

* CSV centre line (TUM format): columns ``x_m, y_m, w_tr_right_m, w_tr_left_m`` named in a header
  (``# x_m,...``; the ``#`` is optional, the columns may come in any order, a comment preamble may
  precede it) or, without a header, in that order (x, y, width right, width left; as TUM and the
  F1TENTH stacks keep them). The file is read by :mod:`gprace.io.table` (BOM, CRLF, ``;``).
  The loop is implicitly closed (the last row does not repeat the first, and the ends may be
  several metres apart).
* Two boundary polylines ``"inner.csv,outer.csv"`` (or a pair of paths): x, y (a third column,
  z, is ignored) in either order, direction and start; the centre line and widths are derived
  from them (:mod:`gprace.tracks.bounds`).
* A raceline file with the distances to the borders (the INI F1TENTH waypoint CSV,
  :mod:`gprace.tracks.raceline`): the raceline is the reference line, the distances the widths.
  A TUM raceline has no widths: reading it as a track is an error that says so.
* TOML: a segment description (:mod:`gprace.tracks.segments`).
* A name without a suffix: a track shipped in ``gprace/data/configs/tracks/``.

**Smoothing that scales.** Centre lines from OpenStreetMap polylines (TUM) have kinks at their
vertices, about one point spacing apart; a Whittaker length equal to the median point spacing,
at most :data:`TUM_SMOOTHING` metres, removes them (5 m on the TUM circuits as before, 0.1 m on a
25 m F1TENTH track whose points are 0.1 m apart). When smoothing would move the centre line past
a border (a narrow track), it is halved until it does not (three times at most); when it still
does, the error names the option (``--track-smoothing`` / ``track_smoothing``). The rule lives in
:mod:`gprace.tracks.smoothing`, which the boundary-file loader (:mod:`gprace.tracks.bounds`) shares.

Bad files raise :class:`~gprace.errors.InputError` naming the file, line and column (or
:class:`~gprace.errors.ConfigError` naming the TOML key for a schema error).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from gprace.config import configs_dir, read_toml, validate
from gprace.errors import InputError, at_row
from gprace.tracks.bounds import track_from_bounds
from gprace.tracks.segments import SegmentTrack, build_track
from gprace.tracks.smoothing import (  # noqa: F401 (importable from here, as before)
    SMOOTHING_OPTION,
    TUM_SMOOTHING,
    auto_smoothing,
    smoothed_track,
)
from gprace.tracks.track import Track

DEFAULT_TRACK = "gprace_ring"
"""The shipped full-scale circuit used when no track is given."""

TUM_COLUMNS = ("x_m", "y_m", "w_tr_right_m", "w_tr_left_m")


def tracks_dir() -> Path:
    return configs_dir() / "tracks"


def shipped_tracks() -> list[str]:
    """Names of the tracks shipped with the package."""
    return sorted(p.stem for p in tracks_dir().glob("*.toml"))


def track_paths(spec) -> list[Path] | None:
    """The two boundary files of a track spec (``"a.csv,b.csv"`` or a pair), else None."""
    if isinstance(spec, (list, tuple)):
        if len(spec) == 1:
            return None
        if len(spec) != 2:
            raise InputError(f"a track from boundaries takes two files (inner, outer), got {len(spec)}: {', '.join(map(str, spec))}")
        return [Path(p) for p in spec]
    text = str(spec)
    if "," in text and not Path(text).exists():
        parts = [p.strip() for p in text.split(",")]
        if len(parts) != 2 or not all(parts):
            raise InputError(f"{text}: a track from boundaries is two files separated by one comma (inner.csv,outer.csv)")
        return [Path(p) for p in parts]
    return None


def load_track(name_or_path, *, smoothing: float | None = None) -> Track:
    """A track from a ``.csv`` or ``.toml`` path, a shipped name, or two boundary files
    (``"inner.csv,outer.csv"`` or a pair of paths).

    ``smoothing`` overrides the automatic smoothing length of CSV tracks (ignored for TOML
    tracks). Loaded tracks are cached by path, modification time and size, so repeated loads are
    free.
    """
    if smoothing is not None and not (np.isfinite(smoothing) and smoothing >= 0):
        raise InputError(f"{SMOOTHING_OPTION} must be a length >= 0 [m], got {smoothing}")
    pair = track_paths(name_or_path)
    if pair is not None:
        keys = []
        for p in pair:
            if not p.exists():
                raise InputError(f"{p}: no such file (boundary of the track {name_or_path})")
            if p.is_dir():
                raise InputError(f"{p}: is a folder, not a boundary file")
            st = p.stat()
            keys += [str(p.resolve()), st.st_mtime_ns, st.st_size]
        return _bounds_cached(tuple(keys), smoothing)
    if isinstance(name_or_path, (list, tuple)):
        name_or_path = name_or_path[0]
    p = Path(name_or_path)
    if not p.exists():
        cand = tracks_dir() / (p.name if p.suffix == ".toml" else f"{p.name}.toml")
        if p.parent == Path(".") and cand.exists():
            p = cand
        else:
            shipped = ", ".join(shipped_tracks())
            raise InputError(f"{name_or_path}: no such file, and no shipped track of that name (shipped: {shipped})")
    if p.is_dir():
        raise InputError(f"{p}: is a folder, not a track file")
    st = p.stat()
    return _load_cached(str(p.resolve()), st.st_mtime_ns, st.st_size, smoothing)


@functools.lru_cache(maxsize=64)
def _load_cached(path: str, mtime_ns: int, size: int, smoothing: float | None) -> Track:
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in (".csv", ".txt"):
        from gprace.tracks.raceline import is_raceline, raceline_track, read_raceline

        if is_raceline(p):  # an F1TENTH waypoint file carries its borders: a track of its own
            return raceline_track(read_raceline(p))
        return load_tum_csv(p, smoothing=smoothing)
    if suffix == ".toml":
        return load_segment_toml(p)
    raise InputError(f"{p}: unknown track format {p.suffix!r} (expected .csv or .toml, or two boundary files a.csv,b.csv)")


@functools.lru_cache(maxsize=16)
def _bounds_cached(keys: tuple, smoothing: float | None) -> Track:
    return track_from_bounds(Path(keys[0]), Path(keys[3]), smoothing=smoothing)


# ----------------------------------------------------------------------------------------------
# CSV


def read_tum_csv(path: str | Path) -> dict[str, np.ndarray]:
    """The columns of a TUM track CSV as float arrays, after checking every row."""
    from gprace.io.table import numbers, sniff

    path = Path(path)
    tbl = sniff(path, "track file")
    names = tbl.names
    if not tbl.has_header:
        if len(names) in (2, 3):
            raise InputError(
                f"{path}: {len(names)} columns without a header: a boundary polyline (x, y{', z' if len(names) == 3 else ''})? "
                "give both boundaries as --track inner.csv,outer.csv; a centre line has x, y, width right, width left")
        if len(names) != 4:
            raise InputError(f"{path}: {len(names)} columns and no header; expected '# {','.join(TUM_COLUMNS)}' "
                             "or four headerless columns (x, y, width right, width left)")
        names = list(TUM_COLUMNS)
    head_no = tbl.header_line
    if sorted(names) != sorted(TUM_COLUMNS):
        missing = [c for c in TUM_COLUMNS if c not in names]
        extra = [c for c in names if c not in TUM_COLUMNS]
        detail = "; ".join(
            part
            for part in (
                f"missing column(s) {', '.join(missing)}" if missing else "",
                f"unexpected column(s) {', '.join(extra)}" if extra else "",
            )
            if part
        ) or "duplicate columns"
        raise InputError(f"{path}: line {head_no}: wrong columns ({detail}); expected {','.join(TUM_COLUMNS)}")
    tbl.names = names
    data = numbers(tbl)
    lines = tbl.body_lines
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        what = "empty cell" if np.isnan(data[r, c]) and not tbl.split(tbl.row_text(r))[c].strip() else f"value is not finite ({data[r, c]})"
        raise InputError(f"{path}: {at_row(r + 1, int(lines[r]))}, column {names[c]}: {what}")
    cols = {name: data[:, j] for j, name in enumerate(names)}
    for name in ("w_tr_right_m", "w_tr_left_m"):
        nonpos = cols[name] <= 0
        if nonpos.any():
            r = int(np.argmax(nonpos))
            raise InputError(f"{path}: {at_row(r + 1, int(lines[r]))}, column {name}: width must be positive, got {cols[name][r]}")
    if len(data) < 4:
        raise InputError(f"{path}: only {len(data)} data rows; a track needs at least 4 points")
    step = np.hypot(np.diff(cols["x_m"]), np.diff(cols["y_m"]))
    tiny = 1e-9 * max(np.ptp(cols["x_m"]), np.ptp(cols["y_m"]), 1e-12)
    if np.any(step <= tiny):
        r = int(np.argmax(step <= tiny))
        raise InputError(f"{path}: {at_row(r + 1, int(lines[r]))} and {at_row(r + 2, int(lines[r + 1]))}: the same point twice (degenerate track)")
    return cols


def load_tum_csv(path: str | Path, *, smoothing: float | None = None, name: str | None = None) -> Track:
    """A closed :class:`Track` from a TUM racetrack-database CSV file (automatic smoothing when
    ``smoothing`` is None: module docstring)."""
    path = Path(path)
    c = read_tum_csv(path)
    return smoothed_track(c["x_m"], c["y_m"], c["w_tr_left_m"], c["w_tr_right_m"], closed=True,
                          name=name or path.stem, source=str(path), smoothing=smoothing)


# ----------------------------------------------------------------------------------------------
# TOML


def load_segment_toml(path: str | Path) -> Track:
    """A :class:`Track` from a segment TOML file (:mod:`gprace.tracks.segments`)."""
    path = Path(path)
    data = read_toml(path)
    spec = validate(SegmentTrack, data, str(path))
    return build_track(spec, spec.name or path.stem, str(path))
