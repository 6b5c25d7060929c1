"""``import_recording``: a raw recording file -> a Frenet :class:`~gprace.io.runs.Run` with provenance."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Callable

import numpy as np

from gprace.errors import InputError
from gprace.ingest.mapping import RecordingMap, load_map
from gprace.ingest.process import global_state, project, segments, wrap
from gprace.ingest.readers import read_raw, recording_format
from gprace.ingest.refline import path_reference

IMPORT_VERSION = 1


def file_hash(path: Path) -> str:
    """sha256 of a file, or of every file in a folder (sorted by name; rosbag2 folders)."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        if path.is_dir():
            h.update(str(f.relative_to(path)).encode())
        with f.open("rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def import_recording(path: str | Path, *, track=None, rmap: RecordingMap | None = None,
                     map_path: str | Path | None = None, dt: float = 0.05,
                     log: Callable[[str], None] | None = None):
    """Read ``path`` (CSV, ROS bag / MCAP, MDF4), resample at ``dt``, project onto ``track``.

    ``track`` is a :class:`~gprace.tracks.Track`, a path or shipped name, or None for a reference
    line made from the driven path. Raises :class:`~gprace.errors.InputError` (one line) on bad
    input; nothing is written here.
    """
    from gprace.io.runs import Run
    from gprace.tracks import load_track

    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if not (np.isfinite(dt) and 0 < dt <= 1.0):
        raise InputError(f"--dt must be in (0, 1] s, got {dt}")
    if recording_format(path) is None:
        raise InputError(f"{path}: unknown recording format (expected .csv, .mcap, .db3, .bag, a rosbag2 folder, .mf4 or .mdf)")
    if rmap is None:
        rmap = load_map(map_path)
    raw = read_raw(path, rmap)
    gs = global_state(raw, rmap, dt)
    m = gs.valid
    if m.sum() < 2:
        raise InputError(f"{path}: no stretch of {2 * dt:g} s where every source has data (gaps everywhere?)")
    if track is None:
        trk = path_reference(gs.x[m], gs.y[m], smoothing=rmap.reference_smoothing,
                             half_width=rmap.reference_width, name=f"path of {path.name}", source=str(path))
        reference = "path"
    else:
        trk = load_track(track) if isinstance(track, (str, Path)) else track
        reference = "track"
    fr = project(gs, trk, str(path), origin_at_start=reference == "path")
    t = gs.t[m]
    data = {
        "t": t - t[0], "s": fr["s"], "e_y": fr["e_y"], "e_psi": fr["e_psi"], "v_x": gs.v_x[m],
        "v_y": gs.v_y[m], "yaw_rate": gs.yaw_rate[m], "delta": gs.delta[m], "a_x": gs.a_x[m],
        "kappa": fr["kappa"], "lap": fr["lap"], "segment": segments(t, dt),
        "x": gs.x[m], "y": gs.y[m], "yaw": wrap(gs.yaw[m]),
    }
    n_gaps = int(data["segment"][-1])
    track_id = str(getattr(trk, "source", None) or trk.name) if reference == "track" else "path"
    meta = {
        "dt": dt,
        "track": track_id,
        "track_name": trk.name,
        "track_length": trk.length if trk.closed else None,
        "reference": reference,
        "source_file": str(path.resolve()),
        "source_sha256": file_hash(path),
        "source_format": raw.kind,
        "map_toml": rmap.to_toml(),
        "map_hash": rmap.digest(),
        "import_version": IMPORT_VERSION,
        "t0": float(t[0]),
        "gaps": n_gaps,
        "rows_dropped": int((~m).sum()),
        "origins": {q: raw.signals[q].origin for q in raw.signals},
        "notes": gs.notes,
    }
    if reference == "track" and isinstance(track, (str, Path)) and Path(track).exists():
        meta["track_sha256"] = file_hash(Path(track))
    if log is not None:
        for note in gs.notes:
            log(f"{path.name}: {note}")
        if n_gaps:
            log(f"{path.name}: {n_gaps} gap(s); {meta['rows_dropped']} grid rows left out (column 'segment')")
    return Run(data, meta, source=str(path)), trk


def import_hash(run) -> str:
    """The config hash written with an imported run: source, map, track and period."""
    from gprace.config import config_hash

    m = run.meta
    return config_hash([m.get("source_sha256"), m.get("map_hash"), m.get("track"), m.get("dt")])
