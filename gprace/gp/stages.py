"""The GP stages behind the CLI: ``select-data``, ``retrain``, ``evaluate gp``.

Each takes paths and options, does the work through the library (features, selection, backends)
and returns a summary dict; the commands in :mod:`gprace.cli.gp` only parse and print.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from gprace.console import console
from gprace.errors import ConfigError, InputError

SELECTIONS = ("diverse", "random")
QUICK_FIT_POINTS = 300


def _load_vehicle(vehicle: str | None):
    if vehicle is None:
        return None
    from gprace.model import load_vehicle

    return load_vehicle(vehicle)


def select_data(
    inputs: list[str | Path],
    output: str | Path,
    gp: str = "tracking",
    max_points: int = 2000,
    selection: str = "diverse",
    vehicle: str | None = None,
    model: str | Path | None = None,
    kernel: str = "se",
    step: str = "euler",
    outlier_kappa: float | None = 4.0,
    seed: int = 0,
    features: str = "paper",
    read=None,
) -> dict[str, Any]:
    """Features of the runs among ``inputs`` streamed into a dictionary of at most ``max_points``.

    ``inputs`` are runs (HDF5 or CSV) and at most one existing dataset to continue from (its
    points are the initial dictionary, and for ``diverse`` its selection hyperparameters are
    reused). Hyperparameters for ``diverse`` come, in this order, from ``model`` (a gp_model),
    the continued dataset, or a quick exact-GP fit on at most 300 points of all the data.
    ``read``: the reader of a run path (default :func:`gprace.io.runs.read_run`; the CLI passes
    :func:`gprace.ingest.dispatch.read_any`, which imports raw recordings first).
    """
    from gprace.gp.dataset import GPDataset, write_dataset
    from gprace.gp.features import dyn_feature_set, feature_map
    from gprace.gp.kernels import check_kernel

    fmap = feature_map(gp)
    if gp == "opponent":
        raise ConfigError("select-data builds single-car datasets (tracking, planning); the opponent GP's data come from `gprace h2h collect`")
    if selection not in SELECTIONS:
        raise ConfigError(f"unknown selection {selection!r}; available: {', '.join(SELECTIONS)}")
    if max_points < 1:
        raise ConfigError(f"--max-points must be >= 1, got {max_points}")
    check_kernel(kernel)
    if not inputs:
        raise InputError("select-data: no RUN given")
    input_names = list(dyn_feature_set(features))
    veh = _load_vehicle(vehicle)

    previous, Zs, Ys, sources, dts, envelopes = _read_inputs(inputs, gp, input_names, features, step, veh, read)
    dt = dts[0]
    bad = [s for s, d in zip(sources, dts) if abs(d - dt) > 1e-6 * dt]
    prev_dt = previous.attrs.get("dt") if previous is not None else None
    if bad or (prev_dt and abs(float(prev_dt) - dt) > 1e-6 * dt):
        raise InputError(f"runs with different periods cannot share one dataset (dt {dt} s vs {bad or prev_dt})")
    Znew, Ynew = np.concatenate(Zs), np.concatenate(Ys)

    t0 = time.perf_counter()
    Z, Y, n_seen, stats, hyper = _stream(selection, previous, Znew, Ynew, max_points, seed, model, gp, kernel,
                                         outlier_kappa)
    elapsed = time.perf_counter() - t0

    attrs = {
        "selection": selection,
        "max_points": int(max_points),
        "n_seen": int(n_seen),
        "dt": float(dt),
        "step": step,
        "vehicle": veh.name if veh is not None else "",
        "sources": (list(previous.attrs.get("sources", [])) if previous is not None else []) + sources,
        "outlier_kappa": outlier_kappa if outlier_kappa is not None else 0.0,
        "stats": stats,
        "excluded_samples": int(sum(e.samples_excluded for e in envelopes)),
    }
    write_dataset(output, GPDataset(Z, Y, gp, input_names, list(fmap.output_names), attrs, hyper),
                  seed=seed)
    return {"output": str(output), "feature_map": gp, "selection": selection, "points": int(len(Z)),
            "max_points": int(max_points), "new_samples": int(len(Znew)), "n_seen": int(n_seen),
            "continued_from": previous.source if previous is not None else None, "seconds": elapsed,
            "stats": stats, "envelope": [e.to_dict() for e in envelopes], "notes": _notes(envelopes)}


def _read_inputs(inputs, gp: str, input_names: list[str], features: str, step: str, veh, read=None):
    """The features of every run among ``inputs``, and the one dataset to continue from (if any),
    checked against the requested feature map, inputs and step."""
    from gprace.gp.dataset import GPDataset, is_dataset, read_dataset
    from gprace.gp.features import run_features
    from gprace.io.envelope import envelope
    from gprace.io.runs import read_run

    previous: GPDataset | None = None
    Zs, Ys, sources, dts, envelopes = [], [], [], [], []
    for path in inputs:
        path = Path(path)
        if is_dataset(path):
            if previous is not None:
                raise InputError(f"{path}: only one existing dataset can be continued (already have {previous.source})")
            previous = read_dataset(path)
            if previous.feature_map and previous.feature_map != gp:
                raise InputError(f"{path}: dataset of feature map {previous.feature_map!r}, but --gp {gp}")
            if list(previous.input_names) != input_names:
                raise InputError(f"{path}: dataset with inputs {list(previous.input_names)}, but --features {features} ({input_names})")
            if previous.attrs.get("step", step) != step:
                raise InputError(f"{path}: dataset built with the {previous.attrs.get('step')} step, but --step {step}")
            continue
        run = (read or read_run)(path)
        keep, env = envelope(run.data, str(path), veh.wheelbase if veh is not None else None)
        Z, Y = run_features(run, gp, veh, step, features, keep)
        if len(Z) == 0:
            raise InputError(f"{path}: no usable sample pairs (need consecutive samples at the run's period "
                             f"inside the model's envelope; {env.samples_excluded} of {env.samples} samples outside)")
        envelopes.append(env)
        Zs.append(Z)
        Ys.append(Y)
        sources.append(str(path))
        dts.append(run.dt)
    if not Zs:
        raise InputError("select-data: no RUN among the inputs (only a dataset)")
    return previous, Zs, Ys, sources, dts, envelopes


def _stream(selection: str, previous, Znew, Ynew, max_points: int, seed: int, model, gp: str, kernel: str,
            outlier_kappa):
    """The new points streamed into the (continued) dictionary: ``Z, Y, n_seen, stats, hyper``
    (``hyper`` is None for random selection)."""
    if selection == "random":
        from gprace.gp.selection import random_subsample, reservoir_merge

        if previous is not None and len(previous.Z):
            Z, Y, n_seen = reservoir_merge(previous.Z, previous.Y, previous.n_seen, Znew, Ynew, max_points, seed)
        else:
            Z, Y = random_subsample(Znew, Ynew, max_points, seed)
            n_seen = len(Znew)
        return Z, Y, n_seen, {"seen": int(len(Znew))}, None
    from gprace.gp.selection import select_diverse

    hyper, hyper_source = _selection_hyper(model, previous, gp, kernel, Znew, Ynew, seed)
    initial = (previous.Z, previous.Y) if previous is not None and len(previous.Z) else None
    Z, Y, st = select_diverse(hyper, Znew, Ynew, max_points, outlier_kappa, initial=initial,
                              what=f"--max-points {max_points}")
    stats = {**st.as_dict(), "hyperparameters_from": hyper_source}
    return Z, Y, (previous.n_seen if previous is not None else 0) + len(Znew), stats, hyper


def _notes(envelopes) -> list[str]:
    """One line per recording with samples outside the model's envelope (how many, where, why)."""
    return [e.note() for e in envelopes if e.excluded]


def _selection_hyper(model, previous, gp: str, kernel: str, Z: np.ndarray, Y: np.ndarray, seed: int):
    from gprace.gp.base import load_model, make_gp

    if model is not None:
        saved = load_model(model)
        if saved.feature_map and saved.feature_map != gp:
            raise InputError(f"{model}: GP of feature map {saved.feature_map!r}, but --gp {gp}")
        if saved.gp.n_inputs_ != Z.shape[1] or saved.gp.n_outputs_ != Y.shape[1]:
            raise InputError(f"{model}: GP has {saved.gp.n_inputs_} inputs / {saved.gp.n_outputs_} outputs, data {Z.shape[1]} / {Y.shape[1]}")
        return saved.gp.hyper_, f"model {model}"
    if previous is not None and previous.hyper is not None:
        return previous.hyper, f"dataset {previous.source}"
    pool_Z = Z if previous is None else np.concatenate([previous.Z, Z])
    pool_Y = Y if previous is None else np.concatenate([previous.Y, Y])
    n = len(pool_Z)
    idx = np.sort(np.random.default_rng(seed).choice(n, min(n, QUICK_FIT_POINTS), replace=False))
    console.info(f"select-data: quick GP fit on {len(idx)} points for the selection's hyperparameters")
    quick = make_gp("exact", kernel=kernel, seed=seed, max_fit_points=QUICK_FIT_POINTS).fit(pool_Z[idx], pool_Y[idx])
    return quick.hyper_, f"quick fit on {len(idx)} points"


def parse_opts(opts: list[str]) -> dict[str, Any]:
    """``--opt key=value`` pairs; values parsed as JSON (numbers, booleans, lists) or kept as text."""
    import json

    out: dict[str, Any] = {}
    for item in opts:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--opt {item!r}: expected key=value")
        try:
            out[key.strip()] = json.loads(value)
        except ValueError:
            out[key.strip()] = value
    return out


def retrain(data: str | Path, output: str | Path, backend: str = "exact", kernel: str = "se", seed: int = 0,
            options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Fit a GP backend (hyperparameters and posterior) on a dataset and save it as a gp_model."""
    from gprace.gp.base import make_gp, save_model
    from gprace.gp.dataset import read_dataset

    settings = {"kernel": kernel, "seed": seed, **(options or {})}
    gp = make_gp(backend, **settings)  # settings checked before the data are read
    ds = read_dataset(data)
    console.info(f"retrain: fitting the {backend} GP on {len(ds.Z)} points")  # the long stage: say it started
    t0 = time.perf_counter()
    gp.fit(ds.Z, ds.Y)
    elapsed = time.perf_counter() - t0
    meta = {"feature_map": ds.feature_map, "input_names": ds.input_names, "output_names": ds.output_names,
            "dataset": str(data), "n_train": int(len(ds.Z)), "fit_seconds": float(elapsed),
            "step": str(ds.attrs.get("step", "euler")), "dt": float(ds.attrs.get("dt", 0.0) or 0.0)}
    save_model(output, gp, meta, seed=seed)
    h = gp.hyper_
    outputs = {}
    for o, name in enumerate(ds.output_names):
        outputs[name] = {
            "length_scales": dict(zip(ds.input_names, (np.exp(h.log_ls[o]) * h.z_scale).tolist())),
            "signal_std": float(np.sqrt(np.exp(h.log_sf2[o])) * h.y_scale[o]),
            "noise_std": float(np.sqrt(gp.noise_[o])),
        }
    return {"output": str(output), "backend": backend, "kernel": kernel, "feature_map": ds.feature_map,
            "points": int(len(ds.Z)), "seconds": elapsed, "outputs": outputs}


def evaluate_gp(model: str | Path, run: str | Path, vehicle: str | None = None, read=None) -> dict[str, Any]:
    """Per-output error metrics of a saved tracking/planning GP on one recording."""
    from gprace.gp.base import load_model
    from gprace.gp.evaluate import gp_metrics
    from gprace.gp.features import dyn_set_of, run_features
    from gprace.io.envelope import envelope
    from gprace.io.runs import read_run

    saved = load_model(model)
    fm = saved.feature_map
    if fm not in ("tracking", "planning"):
        raise InputError(f"{model}: GP of feature map {fm or 'unknown'!r}; evaluate gp handles tracking and planning GPs")
    rec = (read or read_run)(run)
    step = str(saved.attrs.get("step", "euler"))
    veh = _load_vehicle(vehicle)
    keep, env = envelope(rec.data, str(run), veh.wheelbase if veh is not None else None)
    Z, Y = run_features(rec, fm, veh, step, dyn_set_of(saved.input_names), keep)
    if len(Z) == 0:
        raise InputError(f"{run}: no usable sample pairs inside the model's envelope "
                         f"({env.samples_excluded} of {env.samples} samples outside)")
    model_dt = float(saved.attrs.get("dt", 0.0) or 0.0)
    if model_dt and fm == "tracking" and abs(model_dt - rec.dt) > 1e-6 * model_dt:
        raise InputError(f"{run}: period {rec.dt} s, but the tracking GP learned {model_dt} s steps")
    return {"model": str(model), "run": str(run), "feature_map": fm, "samples": int(len(Z)),
            "outputs": gp_metrics(saved.gp, Z, Y, saved.output_names), "envelope": env.to_dict(), "notes": _notes([env])}
