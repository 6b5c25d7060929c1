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


def _paths(path) -> list[Path]:
    paths = [Path(p) for p in (path if isinstance(path, (list, tuple)) else [path])]
    if not paths:
        raise InputError("import: give a recording file")
    for p in paths:
        if not p.exists():
            raise InputError(f"{p}: no such file")
        if recording_format(p) is None:
            if p.is_dir():
                raise InputError(f"{p}: is a folder, not a recording (a rosbag2 folder holds metadata.yaml or .mcap/.db3 files)")
            raise InputError(f"{p}: unknown recording format (expected .csv, .mcap, .db3, .bag, a rosbag2 folder, .mf4 or .mdf)")
    if len(paths) > 1 and len({p.resolve() for p in paths}) < len(paths):
        raise InputError(f"{', '.join(map(str, paths))}: the same file given twice")
    return paths


def inputs_meta(gs, raw, rmap: RecordingMap) -> dict[str, str]:
    """``meta["inputs"]`` of an imported run (the contract in docs/decisions.md, issue 36):
    ``delta`` and ``a_x`` as the map declares them, ``a_x = "derived"`` when the importer
    differentiated the speed, ``v_cmd = "commanded"`` when the run has a speed command. A ROS
    ``a_x`` from the IMU topic is measured, from the Ackermann topic commanded, unless the map
    says otherwise."""
    a_x = rmap.inputs.a_x
    if gs.a_x_source != "column":
        a_x = "derived"
    elif raw.kind == "ros" and "a_x" not in rmap.inputs.model_fields_set:
        a_x = "measured" if "linear_acceleration" in raw.signals["a_x"].origin else "commanded"
    out = {"delta": rmap.inputs.delta, "a_x": a_x}
    if gs.v_cmd is not None:
        out["v_cmd"] = "commanded"
    return out


def import_recording(path, *, track=None, rmap: RecordingMap | None = None,
                     map_path: str | Path | None = None, dt: float = 0.05,
                     log: Callable[[str], None] | None = None, track_smoothing: float | None = None):
    """Read ``path`` (CSV, ROS bag / MCAP, MDF4; or a list of files of one drive), resample at
    ``dt``, project onto ``track``.

    ``track`` is a :class:`~gprace.tracks.Track`, a path, two boundary files or a shipped name;
    None takes the map's ``track``, else a reference line made from the laps of the driven path
    (:mod:`gprace.tracks.laps`). Raises :class:`~gprace.errors.InputError` (one line) on bad
    input; nothing is written here.
    """
    from gprace.io.runs import Run

    paths = _paths(path)
    if not (np.isfinite(dt) and 0 < dt <= 1.0):
        raise InputError(f"--dt must be in (0, 1] s, got {dt}")
    if rmap is None:
        rmap = load_map(map_path)
    if track is None:
        track = rmap.track
    if track_smoothing is None:
        track_smoothing = rmap.track_smoothing
    raw = read_raw(paths if len(paths) > 1 else paths[0], rmap)
    source = raw.source
    gs = global_state(raw, rmap, dt)
    gs.notes[:0] = raw.notes
    m = gs.valid
    if m.sum() < 2:
        raise InputError(f"{source}: no stretch of {2 * dt:g} s where every source has data (gaps everywhere?)")
    speed = np.hypot(gs.v_x[m], gs.v_y[m])
    if not np.any(speed > MOVING):
        raise InputError(f"{source}: no moving sample: the car stands still throughout (largest speed "
                         f"{float(speed.max()):.3g} m/s over {float(gs.t[m][-1] - gs.t[m][0]):.1f} s); nothing to import")
    trk, reference = _reference(track, gs, m, rmap, track_smoothing, f"path of {paths[0].name}", source)
    fr = project(gs, trk, source, origin_at_start=reference == "path")
    if reference == "track":
        cut = off_track(dict(fr, v_x=gs.v_x[m]), trk, speed, gs.t[m], dt, source, rmap, gs.notes)
        if cut.any():
            keep = np.flatnonzero(m)[~cut]
            m = np.zeros_like(m)
            m[keep] = True
            fr = {k: v[~cut] for k, v in fr.items()}
            speed = speed[~cut]
    t = gs.t[m]
    data = {
        "t": t - t[0], "s": fr["s"], "e_y": fr["e_y"], "e_psi": fr["e_psi"], "v_x": gs.v_x[m],
        "v_y": gs.v_y[m], "yaw_rate": gs.yaw_rate[m], "delta": gs.delta[m], "a_x": gs.a_x[m],
        "kappa": fr["kappa"], "lap": fr["lap"], "segment": segments(t, dt),
        "x": gs.x[m], "y": gs.y[m], "yaw": wrap(gs.yaw[m]),
    }
    if gs.v_cmd is not None:
        data["v_cmd"] = gs.v_cmd[m]
    n_gaps = int(data["segment"][-1])
    meta = _run_meta(paths, raw, rmap, gs, trk, reference, track, dt, float(t[0]), n_gaps, int((~m).sum()))
    if log is not None:
        for note in gs.notes:
            log(f"{paths[0].name}: {note}")
        if n_gaps:
            log(f"{paths[0].name}: {n_gaps} gap(s); {meta['rows_dropped']} grid rows left out (column 'segment')")
    return Run(data, meta, source=source), trk


def _reference(track, gs, m: np.ndarray, rmap: RecordingMap, track_smoothing: float | None, path_name: str,
               source: str):
    """The line the recording is projected on and what it is (``"track"`` or ``"path"``): the
    given track (reversed when the car drives it the other way round), else a reference line
    made from the driven path; notes in ``gs.notes``."""
    from gprace.tracks import load_track

    if track is None:
        trk = path_reference(gs.x[m], gs.y[m], smoothing=rmap.reference_smoothing,
                             half_width=rmap.reference_width, name=path_name, source=source)
        gs.notes.append(f"no track: {'a closed line averaged over the laps' if trk.closed else 'an open line along the path'} "
                        f"({trk.length:.4g} m) is the reference")
        return trk, "path"
    trk = load_track(track, smoothing=track_smoothing) if not hasattr(track, "to_frenet") else track
    if _drives_backwards(trk, gs):
        trk = trk.reversed()
        gs.notes.append(f"the car drives track {trk.name} against its direction: the track is reversed (s from its start, the other way round)")
    return trk, "track"


def _run_meta(paths: list[Path], raw, rmap: RecordingMap, gs, trk, reference: str, track, dt: float, t0: float,
              n_gaps: int, rows_dropped: int) -> dict:
    """The imported run's ``meta``: where it came from (files, hashes, map), onto what, and how."""
    track_id = str(getattr(trk, "source", None) or trk.name) if reference == "track" else "path"
    meta = {
        "dt": dt,
        "track": track_id,
        "track_name": trk.name,
        "track_length": trk.length if trk.closed else None,
        "track_reversed": bool(getattr(trk, "is_reversed", False)),
        "reference": reference,
        "source_file": str(paths[0].resolve()),
        "source_sha256": file_hash(paths[0]) if len(paths) == 1 else _files_hash(paths),
        "source_format": raw.kind,
        "map_toml": rmap.to_toml(),
        "map_hash": rmap.digest(),
        "import_version": IMPORT_VERSION,
        "t0": t0,
        "gaps": n_gaps,
        "rows_dropped": rows_dropped,
        "origins": {q: raw.signals[q].origin for q in raw.signals},
        "inputs": inputs_meta(gs, raw, rmap),
        "notes": gs.notes,
    }
    if len(paths) > 1:
        meta["source_files"] = [str(p.resolve()) for p in paths]
    if reference == "track" and isinstance(track, (str, Path)) and Path(track).exists():
        meta["track_sha256"] = file_hash(Path(track))
    return meta


MOVING = 0.1
"""Speed [m/s] above which a sample counts as moving (a 1:10 car crawls at 0.3 m/s)."""


def off_track(fr: dict, trk, speed: np.ndarray, t: np.ndarray, dt: float, source: str, rmap: RecordingMap,
              notes: list[str]) -> np.ndarray:
    """Samples to cut: stretches of at least 1 s beyond a border by more than a quarter of the
    local width (a pit lane, a paddock, positions after a re-fix). More than
    ``rmap.max_off_track`` of the moving samples off the track: the log is of another circuit
    (or another frame) and the track is refused. Shorter excursions are kept and counted."""
    s_track = trk.wrap(fr["s"]) if trk.closed else fr["s"]
    wl, wr = trk.width_left(s_track), trk.width_right(s_track)
    beyond = np.maximum(fr["e_y"] - wl, -fr["e_y"] - wr)
    off = beyond > 0.25 * (wl + wr)
    moving = speed > MOVING
    share = float(off[moving].mean()) if moving.any() else 0.0
    if share > rmap.max_off_track:
        far = float(np.median(beyond[off & moving])) if (off & moving).any() else float(np.median(beyond))
        raise InputError(
            f"{source}: {100 * share:.0f} % of the moving samples lie off track {trk.name!r} (beyond a border by more "
            f"than a quarter of its width; median {far:.3g} m beyond): a log of another circuit, or positions in "
            f"another frame? (give the right --track, or max_off_track in the map)")
    # the track's direction: a car on its circuit drives along it (|e_psi| < 60 degrees but in a
    # hairpin skip or a spin) and s advances about as far as it drives (0.8..1.3)
    # (over the samples on the track: what is off it is judged above, or cut below)
    on = ~off
    fwd = on & (fr.get("v_x", speed) > 0.25 * max(float(np.percentile(fr.get("v_x", speed), 90)), 1e-9))
    across = float(np.mean(np.abs(fr["e_psi"][fwd]) > np.pi / 3)) if fwd.sum() >= 10 else 0.0
    pair = on[1:] & on[:-1]
    driven = float(np.sum(0.5 * (speed[1:] + speed[:-1])[pair]) * dt)
    progress = 1.0
    if trk.closed and driven > 0:
        s_cont = fr["s"] + fr["lap"] * trk.length
        progress = float(np.sum(np.diff(s_cont)[pair]) / driven)
    if across > 0.3 or (not 0.5 < progress < 2.0 and driven > 0.5 * trk.length):
        raise InputError(
            f"{source}: the car does not drive along track {trk.name!r}: {100 * across:.0f} % of the moving samples head "
            f"more than 60 degrees off its direction, and s advances {progress:.2f} m per metre driven: a log of "
            "another circuit, or positions in another frame? (give the right --track)")
    if not off.any():
        return off
    # stretches of consecutive off-track samples
    edges = np.diff(np.concatenate([[0], off.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    dur = t[np.maximum(ends - 1, starts)] - t[starts] + dt
    long_ = dur >= 1.0
    cut = np.zeros(len(off), dtype=bool)
    if rmap.off_track == "cut":
        for a, b in zip(starts[long_], ends[long_]):  # a loop over stretches, not samples
            cut[a:b] = True
    n_short = int(np.sum(~long_))
    if long_.any():
        what = "left out" if rmap.off_track == "cut" else "kept (off_track = \"keep\")"
        notes.append(f"{int(long_.sum())} stretch(es) off track {trk.name} ({int(np.sum(dur[long_] / dt))} samples, "
                     f"{float(dur[long_].sum()):.1f} s; {100 * share:.1f} % of the moving samples; a pit lane?) {what}")
    if n_short:
        notes.append(f"{n_short} brief excursion(s) beyond a border of {trk.name} (under 1 s) kept")
    if cut.all():
        raise InputError(f"{source}: every sample lies off track {trk.name!r}; wrong track?")
    return cut


def _files_hash(paths: list[Path]) -> str:
    h = hashlib.sha256()
    for p in paths:
        h.update(file_hash(p).encode())
    return h.hexdigest()


def _drives_backwards(trk, gs) -> bool:
    """Whether the car runs against the track's direction (median step of the projected ``s``
    over moving samples, about 400 of them)."""
    m = gs.valid & (np.hypot(gs.v_x, gs.v_y) > 0.1 * max(float(np.percentile(np.abs(gs.v_x[gs.valid]), 90)), 1e-9))
    idx = np.flatnonzero(m)
    if len(idx) < 10:
        return False
    idx = idx[:: max(1, len(idx) // 400)]
    s, _ = trk.to_frenet(gs.x[idx], gs.y[idx])
    ds = trk._ds(s[1:], s[:-1]) if trk.closed else np.diff(s)
    ok = np.abs(ds) < 0.25 * trk.length
    return bool(ok.sum() >= 5 and np.median(ds[ok]) < 0)


def import_hash(run) -> str:
    """The config hash written with an imported run: source, map, track and period."""
    from gprace.config import config_hash

    m = run.meta
    return config_hash([m.get("source_sha256"), m.get("map_hash"), m.get("track"), m.get("dt")])
