"""Which recordings need the importer when a stage reads them: :func:`read_any` is the reader of
the stages that take a user's file (a gprace run as :func:`gprace.io.runs.read_run` reads it, or
a raw recording imported first).

A raw recording is a ROS bag / MCAP / rosbag2 folder, an MDF4 file, or a CSV whose header (found
as :mod:`gprace.io.table` finds it: after a comment preamble, or in the last comment line)
has global columns (``x, y`` or ``lat, lon``, by the map's names) but no Frenet ones (``s, e_y``). Such a file is imported
with the map next to it (``<name>.map.toml``, else the defaults) at the map's ``track`` (else a
reference line made from the driven path) and period 0.05 s. Kept light: no heavy import here.
"""

from __future__ import annotations

from pathlib import Path

SIDECAR = ".map.toml"
DEFAULT_DT = 0.05


def sidecar_map(path: Path) -> Path:
    return path.with_name(path.name.rsplit(".", 1)[0] + SIDECAR if path.suffix else path.name + SIDECAR)


def is_raw_recording(path: Path) -> bool:
    from gprace.ingest.readers import recording_format

    fmt = recording_format(path)
    if fmt in ("ros", "mdf"):
        return True
    if fmt != "csv":
        return False
    from gprace.io.table import peek_names

    header = set(peek_names(path))
    if {"s", "e_y"} <= header:
        return False
    from gprace.ingest.mapping import load_map

    sc = sidecar_map(path)
    cols = load_map(sc if sc.exists() else None).columns
    return {cols.x, cols.y} <= header or {cols.lat, cols.lon} <= header


def read_recording(path: str | Path):
    """A raw recording as a Run, for stages that take a recording (see module docstring)."""
    from gprace.console import console
    from gprace.ingest.importer import import_recording
    from gprace.ingest.mapping import load_map

    path = Path(path)
    sc = sidecar_map(path)
    rmap = load_map(sc if sc.exists() else None)
    if rmap.track is None:
        console.info(f"{path}: raw recording, no track in a map ({sc.name}): projected on a reference line made from the driven path")
    run, _ = import_recording(path, track=rmap.track, rmap=rmap, dt=DEFAULT_DT)
    return run


def read_any(path: str | Path):
    """A run from any recording a user may give: a raw recording through the importer
    (:func:`read_recording`), a gprace run (HDF5, Frenet CSV) by :func:`gprace.io.runs.read_run`."""
    from gprace.errors import InputError
    from gprace.io.runs import read_run

    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if is_raw_recording(path):
        return read_recording(path)
    return read_run(path)
