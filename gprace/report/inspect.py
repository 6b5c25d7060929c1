"""Summaries of any gprace result file: HDF5 artifacts of every kind, CSV runs, result JSON.

:func:`describe` never needs to know a stage's code: it reads the artifact layout of
:mod:`gprace.io.artifacts` (root attributes, ``/data``, ``/groups``) with h5py, walking nested
groups (an array stored as ``hyper/z_mean`` is listed under that name), and adds the key results
of the kinds it knows (lap times of plans and runs, dictionary sizes of models and datasets,
outcome of head-to-head races, verdict of a diagnosis). Unknown kinds still get the generic part.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gprace.errors import ArtifactError, GpraceError, InputError
from gprace.io.artifacts import Artifact

RESERVED = ("kind", "schema", "gprace_version", "config_hash", "seed", "created")
UNREADABLE = (GpraceError, OSError)  # what reading a file the report found may raise: it is skipped
ODD_PAYLOAD = (*UNREADABLE, KeyError, IndexError, TypeError, ValueError)  # an artifact of another layout
# what drawing a figure or recomputing from an artifact may raise besides: a missing attribute,
# RuntimeError (CasADi, matplotlib), an overflow
COMPUTE_FAILED = (*ODD_PAYLOAD, AttributeError, RuntimeError, ArithmeticError)


# ----------------------------------------------------------------------------------------------
# reading
def _decode(v: Any) -> Any:
    """An HDF5 attribute as plain Python (the encoding of :mod:`gprace.io.artifacts`)."""
    if isinstance(v, bytes):
        v = v.decode(errors="replace")
    if isinstance(v, str):
        if v == "__none__":
            return None
        if v.startswith("__json__"):
            try:
                return json.loads(v[len("__json__"):])
            except ValueError:
                return v
        if v[:1] in "[{" and v[-1:] in "]}":  # lists/dicts some stages store as plain JSON text
            try:
                return json.loads(v)
            except ValueError:
                return v
        return v
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def _walk(group, prefix: str = "") -> list[tuple[str, Any]]:
    """``(name, h5py.Dataset)`` of every dataset below ``group``, names joined with '/'."""
    import h5py

    out = []
    for k, v in group.items():
        name = f"{prefix}{k}"
        if isinstance(v, h5py.Dataset):
            out.append((name, v))
        elif isinstance(v, h5py.Group):
            out.extend(_walk(v, name + "/"))
    return out


def _open_h5(path: Path):
    import h5py

    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not an artifact")
    try:
        return h5py.File(path, "r")
    except OSError:
        raise ArtifactError(f"{path}: not an HDF5 file (truncated or of another format)") from None


def _h5_kind(path: Path, f) -> str | None:
    """The artifact kind of an open HDF5 file; None for learn's portable GP (no kind, a format);
    an ArtifactError for any other file without a kind."""
    if "kind" not in f.attrs and str(_decode(f.attrs.get("format", ""))) == "gprace portable GP":
        return None
    if "kind" not in f.attrs:
        raise ArtifactError(f"{path}: not a gprace artifact (no 'kind' attribute)")
    return str(_decode(f.attrs["kind"]))


def open_artifact(path: str | Path, kind: str | tuple[str, ...] | None = None, arrays: bool = True) -> Artifact:
    """Read any artifact, nested array groups flattened to ``a/b`` names.

    Like :func:`gprace.io.artifacts.read_artifact` but tolerant of arrays stored under nested
    names; with ``arrays=False`` the arrays are not loaded (their names map to ``None``).
    """
    path = Path(path)
    f = _open_h5(path)
    with f:
        got = _h5_kind(path, f)
        if got is None:
            return _describe_portable(path, f)
        wanted = (kind,) if isinstance(kind, str) else kind
        if wanted is not None and got not in wanted:
            raise ArtifactError(f"{path}: is a {got!r} artifact, expected {' or '.join(map(repr, wanted))}")
        attrs = {k: _decode(v) for k, v in f.attrs.items() if k not in RESERVED}
        arr = {}
        if "data" in f:
            arr = {k: (v[()] if arrays else None) for k, v in _walk(f["data"])}
        groups: dict[str, dict[str, Any]] = {}
        if "groups" in f:
            for gname, sub in f["groups"].items():
                if hasattr(sub, "items"):
                    groups[gname] = {k: (v[()] if arrays else None) for k, v in _walk(sub)}
        return Artifact(
            kind=got, arrays=arr, attrs=attrs, groups=groups,
            config_hash=str(_decode(f.attrs.get("config_hash", ""))), seed=int(_decode(f.attrs.get("seed", 0)) or 0),
            schema=int(_decode(f.attrs.get("schema", 0)) or 0), created=str(_decode(f.attrs.get("created", ""))),
            gprace_version=str(_decode(f.attrs.get("gprace_version", ""))),
        )


def artifact_kind(path: str | Path) -> str | None:
    """The ``kind`` of an HDF5 artifact, or None for any other file (never raises)."""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            k = f.attrs.get("kind")
            return None if k is None else str(_decode(k))
    except (OSError, ValueError):  # any unreadable file is simply not an artifact
        return None


def _has(*keys: str) -> Callable[[Any], bool]:
    return lambda o: isinstance(o, dict) and set(keys) <= set(o)


def _values_have(*keys: str) -> Callable[[Any], bool]:
    """A dict of dicts (one per predictor or dataset), each with ``keys``."""
    return lambda o: (isinstance(o, dict) and bool(o) and all(isinstance(v, dict) and set(keys) <= set(v)
                                                                for v in o.values()))


def _entries_have(*keys: str) -> Callable[[Any], bool]:
    return lambda o: isinstance(o, list) and bool(o) and all(isinstance(v, dict) and set(keys) <= set(v) for v in o)


# Every JSON gprace writes or prints, by the keys its writer always sets (most specific first); what
# a command prints with --json is ``<command>_result``. ``gprace show`` names the kind, the report
# files them by it. A test writes each and checks that none is taken for another.
def _learn_sources(o: Any) -> bool:
    recs = o.get("recordings") if isinstance(o, dict) and set(o) == {"recordings"} else None
    return isinstance(recs, list) and all(isinstance(r, dict) and {"path", "sha256"} <= set(r) for r in recs)


LEARN_STAGES = ("select", "retrain", "grip", "plan", "exports", "prediction")


JSON_KINDS: tuple[tuple[str, Callable[[Any], bool], str], ...] = (
    ("portable_gp_card", _has("format", "kernel", "dictionary_size", "inputs", "formulas"),
     "learn: iter_NN/gp_tracking.card.json"),
    ("learn_record", _has("iteration", "recordings", "limits", "grip", "plan", "prediction"),
     "learn: iter_NN/record.json; gprace learn --json"),
    ("learn_identity", _has("vehicle_hash", "track_hash", "track_spec", "settings"), "learn: learn.json"),
    ("learn_sources", _learn_sources, "learn: iter_NN/sources.json"),
    ("learn_stages", lambda o: isinstance(o, dict) and bool(o) and set(o) <= set(LEARN_STAGES),
     "learn: iter_NN/stages.json"),
    ("eval_learn_result", _has("iteration", "log", "predicted_lap_s", "left_band"), "gprace eval learn --json"),
    ("diagnosis", _has("verdict", "channels"), "gprace diagnose --json"),
    ("h2h_table", lambda o: isinstance(o, dict) and bool({"racing", "ey_error"} & set(o)), "eval head2head: table.json"),
    ("timetrial_summary", _has("rows", "by_iteration"), "iterate: summary.json"),
    ("timetrial_comparison", _has("variants", "per_trial", "oracle"), "gprace eval timetrial --json"),
    ("iterate_settings", _has("alphas", "iterations", "trials"), "iterate: settings.json"),
    ("iteration_record", _has("iteration", "trial", "alpha", "planned", "driven"), "iterate: record.json"),
    ("oracle_lap", lambda o: isinstance(o, dict) and "known" in o and bool({"planned", "why"} & set(o)),
     "iterate: oracle.json"),
    ("h2h_calibration", _values_have("scale", "floor"), "eval head2head: calib/calibration*.json"),
    ("h2h_calibration_passes", _entries_have("pass", "settled", "fitted"), "eval head2head: calib/passes.json"),
    ("show_result", _has("path", "format", "kind", "results"), "gprace show --json"),
    ("simulate_result", _has("output", "samples", "duration_s", "lap_times"), "gprace simulate --json"),
    ("import_result", _has("output", "source", "samples", "reference"), "gprace import --json"),
    ("import_meta", _has("source_file", "source_sha256", "map_toml", "import_version"), "import: <run>.meta.json"),
    ("plan_result", _has("output", "method", "lap_time", "nodes"), "gprace plan --json"),
    ("run_result", _has("output", "lap_time", "planned_lap_time", "completed"), "gprace run --json"),
    ("select_data_result", _has("output", "feature_map", "selection", "points", "max_points"), "gprace select-data --json"),
    ("retrain_result", _has("output", "backend", "kernel", "outputs", "points"), "gprace retrain --json"),
    ("eval_gp_result", _has("model", "run", "feature_map", "outputs", "samples"), "gprace eval gp --json"),
    ("track_show_result", _has("name", "closed", "length_m", "min_radius_m"), "gprace track show --json"),
    ("h2h_train_result", _has("model", "backend", "points", "quality"), "gprace h2h train --json"),
    ("h2h_explore_result", _has("dataset", "points"), "gprace h2h explore --json"),
    ("h2h_collect_result", _values_have("path", "points"), "gprace h2h collect --json"),
)


def json_kind(obj: Any) -> str:
    """Classify a result JSON by :data:`JSON_KINDS` (``json`` for anything else)."""
    for kind, test, _ in JSON_KINDS:
        if test(obj):
            return kind
    return "json"


# ----------------------------------------------------------------------------------------------
# describing
def describe(path: str | Path) -> dict[str, Any]:
    """Summary of one result file as a JSON-ready dict.

    Keys: ``path``, ``format`` (hdf5, csv, json), ``kind``, provenance (``schema``,
    ``gprace_version``, ``config_hash``, ``seed``, ``created``), ``attrs``, ``arrays`` (name ->
    ``{"shape", "dtype"}``), ``groups`` and ``results`` (the key numbers of the kind).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir() and (path / "learn.json").is_file():
        return _describe_learn_folder(path)
    suffix = path.suffix.lower()
    if suffix == ".mcap" and path.is_file():
        channels = _mcap_channels(path)
        if any(schema.startswith("gprace.") for _, schema, _ in channels):  # written by --mcap: to look at
            return _describe_mcap(path, channels)
    from gprace.ingest.dispatch import is_raw_recording

    if is_raw_recording(path):  # ROS bag / MCAP, MDF4, global-frame CSV: read through the importer
        from gprace.ingest.readers import recording_format

        return {**_describe_csv(path), "format": f"{recording_format(path)} recording (imported)"}
    if path.is_dir():
        raise InputError(f"{path}: is a folder; use `gprace report {path}` for a folder")
    if suffix in (".csv", ".txt"):
        return _describe_table(path) or _describe_csv(path)
    if suffix == ".json":
        return _describe_json(path)
    if suffix == ".toml":
        return _describe_toml(path)
    return _describe_h5(path)


def _info(path: Path, fmt: str, kind: str, results: dict[str, Any], arrays: dict | None = None) -> dict[str, Any]:
    """The common layout of :func:`describe` for a file that is not an HDF5 artifact."""
    return {"path": str(path), "format": fmt, "kind": kind, **{k: "" for k in RESERVED[1:]}, "attrs": {},
            "arrays": arrays or {}, "groups": {}, "results": results}


EXPLORE_REFERENCE = ("s_m", "x_m", "y_m", "vx_mps", "explore")
"""Columns every exploration reference of ``learn --alpha`` has (``explore_reference.csv``)."""


def _describe_table(path: Path) -> dict[str, Any] | None:
    """A CSV that is not a run: a raceline (TUM or F1TENTH), an exploration reference, a track's
    centre line; None for anything else (read as a run)."""
    from gprace.io.table import peek_names
    from gprace.tracks.raceline import is_raceline, raceline_summary, read_raceline

    try:
        names = [str(c).strip() for c in peek_names(path)]
    except InputError:
        names = []
    if set(EXPLORE_REFERENCE) <= set(names):
        data = np.genfromtxt(path, delimiter=",", names=True)
        explore = np.asarray(data["explore"], dtype=float)
        return _info(path, "csv", "explore_reference", {
            "points": int(explore.size), "columns": names, "explored_share": float(np.mean(explore > 0)) if explore.size else 0.0,
            "speed_max_mps": float(np.nanmax(data["vx_mps"])) if explore.size else None})
    if is_raceline(path):  # a raceline with wrong columns: read_raceline says what is wrong
        rl = read_raceline(path)
        return _info(path, f"csv ({rl.fmt} raceline)", "raceline", raceline_summary(rl))
    if {"s", "e_y"} <= set(names) or not names:
        return None
    try:  # a centre line (TUM, with or without header): what `track show` says of it
        from gprace.tracks import load_track

        trk = load_track(path)
        return _info(path, "csv", "track", {"name": trk.name, "closed": bool(trk.closed), "length_m": float(trk.length),
                                            "more": f"gprace track show {path}"})
    except (GpraceError, OSError, ValueError):
        pass
    try:  # x, y points only: a path (TUM's racelines) or one border of a track
        from gprace.tracks.bounds import read_polyline

        xy = read_polyline(path)
    except (GpraceError, OSError, ValueError):
        return None
    return _info(path, "csv", "polyline", {"points": len(xy), "length_m": float(np.sum(np.hypot(*np.diff(xy[:, :2], axis=0).T))),
                                           "use": "a path or one border: --track INNER.csv,OUTER.csv takes two borders"})


def _mcap_channels(path: Path) -> list[tuple[str, str, int]]:
    """``(topic, schema, messages)`` of every channel of an MCAP file ([] when it is none)."""
    from gprace.ingest.mcap_fast import Unsupported, scan

    try:
        channels, msgs = scan(path)
    except (Unsupported, OSError, ValueError, IndexError, KeyError):  # not an MCAP gprace can scan
        return []
    return sorted((topic, schema, len(msgs.get(cid, ([], []))[0])) for cid, (topic, schema, _) in channels.items())


def _describe_mcap(path: Path, channels: list[tuple[str, str, int]]) -> dict[str, Any]:
    """An MCAP written by ``--mcap`` (recorded and planned laps, GP band, track) for Foxglove."""
    return _info(path, "mcap", "foxglove_mcap", {
        "channels": len(channels), "messages": sum(n for *_, n in channels),
        **{topic: f"{schema} ({n} messages)" for topic, schema, n in channels}})


def _describe_learn_folder(path: Path) -> dict[str, Any]:
    """An ``--out`` folder of ``gprace learn``: its car and track and each iteration's prediction."""
    ident = json.loads((path / "learn.json").read_text())
    res: dict[str, Any] = {"vehicle": ident.get("vehicle"), "track": ident.get("track"),
                           "track_reversed": ident.get("track_reversed")}
    its = sorted(p for p in path.glob("iter_[0-9]*") if (p / "sources.json").exists())
    res["iterations"] = len(its)
    for it in its:
        rec_path = it / "record.json"
        if not rec_path.exists():
            res[it.name] = "unfinished (rerun learn with its recordings to finish it)"
            continue
        rec = json.loads(rec_path.read_text())
        plan = rec.get("plan") or {}
        res[it.name] = (f"{len(rec.get('recordings', []))} recording(s), predicted lap "
                        f"{_short(plan.get('planned_lap_time'))} s, exports {', '.join(rec.get('exports', []))}")
    return _info(path, "folder", "learn_folder", res)


def _describe_toml(path: Path) -> dict[str, Any]:
    """A configuration TOML: vehicle, plant, segment track or recording map (by its keys)."""
    import tomllib

    try:
        obj = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"{path}: not a TOML file ({exc})") from None
    keys = set(obj)
    if "kind" in keys and "vehicle" in keys:
        kind, res = "plant_config", {"plant kind": obj["kind"], "vehicle": obj["vehicle"]}
    elif {"mass", "l_f", "l_r"} <= keys:
        kind, res = "vehicle_config", {k: obj[k] for k in ("name", "mass", "l_f", "l_r", "mu") if k in obj}
    elif "segments" in keys:
        kind, res = "track_config", {"segments": len(obj["segments"]), "more": f"gprace track show {path}"}
    elif keys & {"columns", "units", "topics", "signs", "layout"}:
        kind, res = "recording_map", {"tables": sorted(k for k in keys if isinstance(obj[k], dict))}
    else:
        kind, res = "toml", {"keys": sorted(keys)[:30]}
    return _info(path, "toml", kind, res)


def _describe_h5(path: Path) -> dict[str, Any]:
    f = _open_h5(path)
    with f:
        kind = _h5_kind(path, f)
        if kind is None:
            return _describe_portable(path, f)
        info: dict[str, Any] = {"path": str(path), "format": "hdf5", "kind": kind}
        for k in RESERVED[1:]:
            info[k] = _decode(f.attrs.get(k, ""))
        info["attrs"] = {k: _decode(v) for k, v in f.attrs.items() if k not in RESERVED}
        info["arrays"] = {}
        if "data" in f:
            info["arrays"] = {k: {"shape": list(v.shape), "dtype": str(v.dtype)} for k, v in _walk(f["data"])}
        info["groups"] = {}
        if "groups" in f:
            for g, sub in f["groups"].items():
                if hasattr(sub, "items"):
                    info["groups"][g] = {k: {"shape": list(v.shape), "dtype": str(v.dtype)} for k, v in _walk(sub)}
    art = open_artifact(path)
    try:
        info["results"] = key_results(art)
    except ODD_PAYLOAD as exc:  # a summary must not fail on an odd payload
        info["results"] = {"error": f"could not summarise the {art.kind!r} payload: {exc}"}
    return info


def _describe_portable(path: Path, f) -> dict[str, Any]:
    """The portable GP of ``learn`` (:mod:`gprace.gp.export`): one HDF5 file beside its JSON card."""
    attrs = {k: _decode(v) for k, v in f.attrs.items()}
    arrays = {k: {"shape": list(v.shape), "dtype": str(v.dtype)} for k, v in _walk(f)}
    res: dict[str, Any] = {"inputs": attrs.get("inputs"), "kernel": attrs.get("kernel"),
                           "dictionary_size": int(f["Z"].shape[0]) if "Z" in f else None}
    card = Path(str(path).removesuffix(".portable.h5") + ".card.json")
    if card.is_file():
        res["card"] = str(card)
    info = _info(path, "hdf5", "portable_gp", res, arrays)
    info["attrs"] = attrs
    return info


def _describe_csv(path: Path) -> dict[str, Any]:
    from gprace.ingest.dispatch import read_any

    run = read_any(path)
    info: dict[str, Any] = {"path": str(path), "format": "csv", "kind": "run"}
    for k in RESERVED[1:]:
        info[k] = ""
    info["attrs"] = {}
    info["arrays"] = {k: {"shape": list(np.shape(v)), "dtype": str(np.asarray(v).dtype)} for k, v in run.data.items()}
    info["groups"] = {}
    info["results"] = _run_results(run.data, run.meta)
    return info


def _describe_json(path: Path) -> dict[str, Any]:
    try:
        obj = json.loads(path.read_text())
    except (UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path}: not a JSON file ({exc})") from None
    kind = json_kind(obj)
    info: dict[str, Any] = {"path": str(path), "format": "json", "kind": kind}
    for k in RESERVED[1:]:
        info[k] = ""
    info["attrs"] = {}
    info["arrays"] = {}
    info["groups"] = {}
    res: dict[str, Any] = {}
    if kind == "diagnosis":
        from gprace.diagnose.result import parse_result

        d = parse_result(obj, str(path))  # through its schema: a bad or newer file is one line
        res["verdict"] = d.verdict
        res["structured_channels"] = [c.name for c in d.channels if c.structured]
        res["regions"] = len(d.regions)
        res["effects"] = [e.name for e in d.effects]
        res["augmented_vehicle"] = d.augmented_vehicle
    elif kind == "h2h_table":
        from gprace.h2h.table import failed_races_text, parse_table

        tab = parse_table(obj, str(path))  # through its schema: a bad or newer file is one line
        for p, row in tab.racing.items():
            res[f"{p}: failed races"] = failed_races_text(row)
            res[f"{p}: border hits"] = row.border_hits
            res[f"{p}: overtake time [s]"] = row.overtake_time_mean
        for p, e in tab.ey_error.items():
            if e.mean:
                res[f"{p}: e_y error 1-step [m]"] = e.mean[0]
                res[f"{p}: e_y error {len(e.mean)}-step [m]"] = e.mean[-1]
    elif kind == "timetrial_summary" and isinstance(obj, dict) and "by_iteration" in obj:
        from gprace.timetrial.record import read_summary
        from gprace.timetrial.summary import failed_laps_text

        summary = read_summary(path)  # an old layout: one line saying how to rebuild it
        res["laps completed per iteration"] = ", ".join(f"{a.iteration}: {a.completed}/{a.trials}" for a in summary.by_iteration)
        res["failed laps"] = failed_laps_text(summary.model_dump()["by_iteration"]) or "none"
    elif isinstance(obj, dict):
        res["keys"] = sorted(obj)[:30]
    elif isinstance(obj, list):
        res["entries"] = len(obj)
    info["results"] = res
    return info


def _finite(a) -> np.ndarray:
    a = np.asarray(a, dtype=float).ravel()
    return a[np.isfinite(a)]


def _run_results(data: dict[str, np.ndarray], meta: dict[str, Any]) -> dict[str, Any]:
    t = np.asarray(data["t"], dtype=float)
    res: dict[str, Any] = {"samples": int(len(t)), "duration_s": float(t[-1] - t[0]) if len(t) else 0.0}
    if "lap" in data and len(data["lap"]):
        res["laps_started"] = int(np.max(data["lap"]) - np.min(data["lap"]) + 1)
    for k in ("lap_time", "planned_lap_time", "lap_times", "completed", "reason", "track", "plant", "alpha",
              "fallbacks", "border_hit_steps", "solve_time_median", "solve_time_p99"):
        if k in meta:
            res[k] = meta[k]
    if "lap_time" in res and "planned_lap_time" in res:
        try:
            res["lap_time_minus_planned_s"] = float(res["lap_time"]) - float(res["planned_lap_time"])
        except (TypeError, ValueError):
            pass
    if "border_hit" in data and "border_hit_steps" not in res:
        res["border_hit_steps"] = int(np.sum(np.asarray(data["border_hit"]) > 0))
    vx = _finite(data.get("v_x", []))
    if len(vx):
        res["v_x_max_mps"] = float(vx.max())
        res["v_x_mean_mps"] = float(vx.mean())
    ey = _finite(data.get("e_y", []))
    if len(ey):
        res["e_y_range_m"] = [float(ey.min()), float(ey.max())]
    return res


def _dictionary_size(arrays: dict[str, Any], attrs: dict[str, Any]) -> int | None:
    for k in ("n_points", "n_train", "dict_size", "n"):
        if k in attrs and isinstance(attrs[k], (int, float)):
            return int(attrs[k])
    for k in ("state/Z", "state/Zu"):
        if k in arrays and arrays[k] is not None and np.ndim(arrays[k]) == 2:
            return int(np.shape(arrays[k])[0])
    if "n_train" in arrays:
        return int(np.asarray(arrays["n_train"]))
    return None


def key_results(art: Artifact) -> dict[str, Any]:
    """The numbers an engineer looks at first, by kind (generic for unknown kinds)."""
    a, at = art.arrays, art.attrs
    kind = art.kind
    if kind == "run":
        cols = {k: v for k, v in a.items() if np.ndim(v) == 1}
        if "t" in cols:
            return _run_results(cols, at)
    if kind == "plan":
        res: dict[str, Any] = {}
        for k in ("lap_time", "track", "track_length", "vehicle", "method"):
            if k in at:
                res[k] = at[k]
        if "s" in a:
            res["nodes"] = int(len(a["s"]))
        if "v_x" in a and len(a["v_x"]):
            res["v_x_range_mps"] = [float(np.min(a["v_x"])), float(np.max(a["v_x"]))]
        if "lap_time" in at and "track_length" in at and float(at["lap_time"]) > 0:
            res["mean_speed_mps"] = float(at["track_length"]) / float(at["lap_time"])
        return res
    if kind in ("gp_model", "model"):
        res = {}
        for k in ("backend", "kernel", "feature_map", "input_names", "output_names"):
            if k in at:
                res[k] = at[k]
        n = _dictionary_size(a, at)
        if n is not None:
            res["dictionary_size"] = n
        ls = a.get("hyper/log_ls")
        if ls is not None:
            res["length_scales_normalised"] = np.round(np.exp(np.asarray(ls)), 4).tolist()
        sn = a.get("hyper/log_sn2")
        if sn is not None:
            res["noise_variance_normalised"] = np.round(np.exp(np.asarray(sn)), 6).tolist()
        return res
    if "dataset" in kind:
        from gprace.gp.dataset import dataset_of

        ds = dataset_of(art, "dataset")
        res = {"points": int(len(ds.Z)), "inputs": ds.input_names, "outputs": ds.output_names}
        if len(ds.Y):
            res["output_std"] = np.round(ds.Y.std(axis=0), 6).tolist()
        for k in ("source", "runs", "failed", "selection", "episodes"):
            if k in ds.attrs:
                res[k] = ds.attrs[k]
        return res
    if kind == "h2h_run":
        res = {}
        for k in ("predictor", "track", "track_length", "ok", "error", "end_reason", "overtake_time", "border_hit",
                  "border_hit_opp", "collision", "steps", "fallbacks_ego", "alpha", "stalemates"):
            if k in at:
                res[k] = at[k]
        if "ego_solve_ms" in a and len(a["ego_solve_ms"]):
            res["ego_solve_ms_median"] = float(np.median(a["ego_solve_ms"]))
        return res
    # generic: scalar attributes and array sizes
    res = {k: v for k, v in at.items() if isinstance(v, (int, float, bool)) and not isinstance(v, str)}
    res["arrays"] = len(a)
    return res


# ----------------------------------------------------------------------------------------------
# text rendering
def _short(v: Any, width: int = 90) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)) and all(isinstance(x, float) for x in v):
        s = "[" + ", ".join(f"{x:.4g}" for x in v) + "]"
    elif isinstance(v, (dict, list, tuple)):
        s = json.dumps(v, default=str)
    else:
        s = str(v)
    lines = s.splitlines()
    if len(lines) > 1:
        return f"{lines[0][:width]} ... ({len(lines)} lines, {len(s)} characters)"
    if len(s) > width:
        return f"{s[:width]} ... ({len(s)} characters)"
    return s


def summary_lines(info: dict[str, Any]) -> list[str]:
    """A human-readable summary of :func:`describe`'s dict."""
    out = [f"file            {info['path']} ({info['format']})", f"kind            {info['kind']}"]
    for k in ("schema", "gprace_version", "config_hash", "seed", "created"):
        v = info.get(k)
        if v not in ("", None):
            out.append(f"{k:<16}{v}")
    res = info.get("results") or {}
    if res:
        out.append("results")
        out += [f"  {k:<30}{_short(v)}" for k, v in res.items()]
    if info.get("attrs"):
        out.append("attributes")
        out += [f"  {k:<30}{_short(v)}" for k, v in info["attrs"].items()]
    if info.get("arrays"):
        out.append("arrays")
        out += [f"  {k:<30}{tuple(v['shape'])} {v['dtype']}" for k, v in info["arrays"].items()]
    for g, arrays in (info.get("groups") or {}).items():
        out.append(f"group {g}")
        out += [f"  {k:<30}{tuple(v['shape'])} {v['dtype']}" for k, v in arrays.items()]
    return out
