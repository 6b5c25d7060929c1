"""Track loaders: TUM racetrack-database CSV files, segment TOML files, shipped track names.

* CSV (TUM format): a header ``# x_m,y_m,w_tr_right_m,w_tr_left_m`` (the ``#`` is optional, the
  columns may come in any order), then one centre-line point per row. The loop is implicitly
  closed (the last row does not repeat the first, and the ends may be several metres apart).
  These centre lines come from OpenStreetMap polylines with visible kinks, so they are smoothed
  with a Whittaker length of :data:`TUM_SMOOTHING` metres (see :mod:`gprace.tracks.track`); the
  borders are kept where the file puts them.
* TOML: a segment description (:mod:`gprace.tracks.segments`).
* A name without a suffix: a track shipped in ``gprace/data/configs/tracks/``.

Bad files raise :class:`~gprace.errors.InputError` naming the file, line and column (or
:class:`~gprace.errors.ConfigError` naming the TOML key for a schema error).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from gprace.config import configs_dir, read_toml, validate
from gprace.errors import InputError, at_row
from gprace.tracks.segments import SegmentTrack, build_track
from gprace.tracks.track import Track

DEFAULT_TRACK = "gprace_ring"
"""The shipped full-scale circuit used when no track is given."""

TUM_COLUMNS = ("x_m", "y_m", "w_tr_right_m", "w_tr_left_m")
TUM_SMOOTHING = 5.0
"""Whittaker smoothing length [m] applied to TUM CSV centre lines."""


def tracks_dir() -> Path:
    return configs_dir() / "tracks"


def shipped_tracks() -> list[str]:
    """Names of the tracks shipped with the package."""
    return sorted(p.stem for p in tracks_dir().glob("*.toml"))


def load_track(name_or_path: str | Path, *, smoothing: float | None = None) -> Track:
    """A track from a ``.csv`` or ``.toml`` path, or the name of a shipped track.

    ``smoothing`` overrides the CSV smoothing length (ignored for TOML tracks). Loaded tracks
    are cached by path, modification time and size, so repeated loads are free.
    """
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
    if suffix == ".csv":
        return load_tum_csv(p, smoothing=TUM_SMOOTHING if smoothing is None else smoothing)
    if suffix == ".toml":
        return load_segment_toml(p)
    raise InputError(f"{p}: unknown track format {p.suffix!r} (expected .csv or .toml)")


# ----------------------------------------------------------------------------------------------
# CSV


def read_tum_csv(path: str | Path) -> dict[str, np.ndarray]:
    """The columns of a TUM track CSV as float arrays, after checking every row."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    lines = [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())]
    lines = [(i, ln) for i, ln in lines if ln]
    if not lines:
        raise InputError(f"{path}: empty file (expected header '# {','.join(TUM_COLUMNS)}' and rows)")
    head_no, head = lines[0]
    names = [c.strip() for c in head.lstrip("#").split(",")]
    if _is_number(names[0]):
        raise InputError(f"{path}: line {head_no}: missing header '# {','.join(TUM_COLUMNS)}'")
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
    rows = [(i, ln) for i, ln in lines[1:] if not ln.startswith("#")]
    if not rows:
        raise InputError(f"{path}: no data rows after the header")
    cells = [ln.split(",") for _, ln in rows]
    for r, ((i, _), c) in enumerate(zip(rows, cells)):
        if len(c) != len(names):
            raise InputError(
                f"{path}: {at_row(r + 1, i)}: expected {len(names)} values, got {len(c)} (truncated or malformed row)"
            )
    try:
        data = np.array(cells, dtype=float)
    except ValueError:
        for r, ((i, _), c) in enumerate(zip(rows, cells)):
            for name, v in zip(names, c):
                if not _is_number(v):
                    raise InputError(f"{path}: {at_row(r + 1, i)}, column {name}: not a number: {v.strip()!r}") from None
        raise  # pragma: no cover - np.array failed for a reason the loop did not find
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(f"{path}: {at_row(r + 1, rows[r][0])}, column {names[c]}: value is not finite ({data[r, c]})")
    cols = {name: data[:, j] for j, name in enumerate(names)}
    for name in ("w_tr_right_m", "w_tr_left_m"):
        nonpos = cols[name] <= 0
        if nonpos.any():
            r = int(np.argmax(nonpos))
            raise InputError(f"{path}: {at_row(r + 1, rows[r][0])}, column {name}: width must be positive, got {cols[name][r]}")
    if len(data) < 4:
        raise InputError(f"{path}: only {len(data)} data rows; a track needs at least 4 points")
    step = np.hypot(np.diff(cols["x_m"]), np.diff(cols["y_m"]))
    tiny = 1e-9 * max(np.ptp(cols["x_m"]), np.ptp(cols["y_m"]), 1e-12)
    if np.any(step <= tiny):
        r = int(np.argmax(step <= tiny))
        raise InputError(f"{path}: {at_row(r + 1, rows[r][0])} and {at_row(r + 2, rows[r + 1][0])}: the same point twice (degenerate track)")
    return cols


def load_tum_csv(path: str | Path, *, smoothing: float = TUM_SMOOTHING, name: str | None = None) -> Track:
    """A closed :class:`Track` from a TUM racetrack-database CSV file."""
    path = Path(path)
    c = read_tum_csv(path)
    return Track(
        c["x_m"],
        c["y_m"],
        c["w_tr_left_m"],
        c["w_tr_right_m"],
        closed=True,
        name=name or path.stem,
        smoothing=smoothing,
        source=str(path),
    )


def _is_number(v: str) -> bool:
    try:
        float(v)
    except ValueError:
        return False
    return True


# ----------------------------------------------------------------------------------------------
# TOML


def load_segment_toml(path: str | Path) -> Track:
    """A :class:`Track` from a segment TOML file (:mod:`gprace.tracks.segments`)."""
    path = Path(path)
    data = read_toml(path)
    spec = validate(SegmentTrack, data, str(path))
    return build_track(spec, spec.name or path.stem, str(path))
