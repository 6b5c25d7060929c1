"""The protocol's datasets: the collection, the exploration's start and its episodes, validation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gprace.config import config_hash
from gprace.errors import InputError
from gprace.h2h.predictors import FEATURE_MAP, FEATURES, OUTPUTS
from gprace.h2h.protocol.batches import run_tasks
from gprace.h2h.protocol.settings import (CHAIN_STRIDE, SEED_CALIB, SEED_COLLECT, SEED_EVAL,
                                          SEED_EXPLORE, VALIDATION_POINTS, Settings)
from gprace.h2h.records import Record
from gprace.h2h.geometry import TrackSpec
from gprace.h2h.tasks import RaceTask, task_hash

def _write_dataset(path: Path, Z: np.ndarray, Y: np.ndarray, run: np.ndarray, key: dict, attrs: dict) -> Path:
    """The opponent GP's points as a GP dataset (:mod:`gprace.gp.dataset`), with the index of the
    run each point came from (array ``run``) and the hash of what they were built from."""
    from gprace.gp.dataset import GPDataset, write_dataset

    ds = GPDataset(Z, Y, FEATURE_MAP, list(FEATURES), list(OUTPUTS), dict(attrs, n=len(Z)), extra={"run": run})
    return write_dataset(path, ds, config_hash=config_hash(key))


def read_dataset(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(Z, Y)`` of an opponent dataset (:func:`gprace.gp.dataset.read_dataset`, old layouts too);
    an InputError for a dataset of another GP."""
    from gprace.gp.dataset import read_dataset as read

    ds = read(path)
    if ds.feature_map != FEATURE_MAP:
        raise InputError(f"{path}: a dataset of the {ds.feature_map or 'unnamed'!r} GP; the head-to-head needs the "
                         f"{FEATURE_MAP!r} GP's data (from `gprace h2h collect` or `h2h explore`)")
    return ds.Z, ds.Y


def _cached(path: Path, key: dict) -> bool:
    """An artifact at ``path`` built from the same inputs."""
    if not path.exists():
        return False
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return str(f.attrs.get("config_hash", "")) == config_hash(key)
    except OSError:
        return False


def _hash_file(path: Path) -> str:
    import hashlib

    if not Path(path).is_file():
        raise InputError(f"{path}: no such file")
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _kept_steps(n: int, per_run: int | None) -> np.ndarray:
    """The evenly spaced steps a run contributes to a dataset (all of them without ``per_run``)."""
    if per_run is None or n <= per_run:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, per_run).round().astype(int))


def dataset_from_records(records: list[Record], per_run: int | None = None,
                         held_out: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stack the (Z, Y) pairs of the successful runs; ``per_run`` keeps that many evenly spaced
    steps of each run (the paper's baseline: about 5000 points from 500 runs); ``held_out`` keeps
    the other steps instead (points no model of the protocol is trained on)."""
    Zs, Ys, R = [], [], []
    for i, r in enumerate(records):
        if r.attrs.ok and "Z" in r.arrays and len(r.arrays["Z"]):
            Z, Y = r.arrays["Z"], r.arrays["Y"]
            keep = _kept_steps(len(Z), per_run)
            if held_out:
                keep = np.setdiff1d(np.arange(len(Z)), keep)
            Zs.append(Z[keep])
            Ys.append(Y[keep])
            R.append(np.full(len(keep), i))
    if not Zs or not sum(len(z) for z in Zs):
        raise InputError("no successful run produced data; see the failed-run records")
    return np.vstack(Zs), np.vstack(Ys), np.concatenate(R)


def _track_spec(st: Settings, seed: int, kind: str = "eval") -> TrackSpec:
    if kind == "training":
        return TrackSpec(kind="training", seed=seed, width=st.width)
    return TrackSpec(kind="random", seed=seed, stretches=st.stretches, width=st.width)


def collect_tasks(st: Settings, n: int, tracks: str | None = None) -> list[RaceTask]:
    """Oracle races of the collection on ``tracks`` (default ``st.baseline_tracks``)."""
    base = SEED_COLLECT + CHAIN_STRIDE * st.seed
    kind = tracks or st.baseline_tracks
    return [RaceTask(id=f"collect-{i}", track=_track_spec(st, base + i, kind), seed=base + i, predictor="oracle",
                     config=st.race_config()) for i in range(n)]


def calib_tasks(st: Settings, predictor: str = "oracle", model: Path | None = None,
                calibration: dict | None = None, first: int = 0, n: int | None = None) -> list[RaceTask]:
    """Held-out races on evaluation-style tracks (seeds no other stage uses): ``n`` (default
    ``calib_runs``) races from seed offset ``first``, the ego driving with the oracle predictor, or
    with a raced ``predictor``, its ``model`` and ``calibration`` as in :func:`eval_tasks`."""
    base = SEED_CALIB + CHAIN_STRIDE * st.seed
    seeds = [base + first + i for i in range(st.calib_runs if n is None else n)]
    if predictor == "oracle":  # the first pass's tasks as before (no label): their hashes, and so their runs, are kept
        return [RaceTask(id=f"calib-{sd - base}", track=_track_spec(st, sd), seed=sd, predictor="oracle",
                         config=st.race_config()) for sd in seeds]
    return [t.model_copy(update={"id": f"calib-{predictor}-{sd - base}", "track": _track_spec(st, sd), "seed": sd})
            for t, sd in zip(eval_tasks(st.model_copy(update={"tracks": len(seeds)}), predictor, model, calibration), seeds)]


def eval_tasks(st: Settings, predictor: str, model: Path | None, calibration: dict | None = None) -> list[RaceTask]:
    """The evaluation races of one predictor: the same tracks and starts for every predictor."""
    kind = predictor if predictor in ("cv", "oracle") else "gp"
    gp = {} if model is None else {"model": str(model), "model_hash": _hash_file(model)}  # read once
    cal = {"calibration": {k: calibration[k] for k in ("scale", "floor")}} if calibration else {}
    return [RaceTask(id=f"eval-{predictor}-{i}", track=_track_spec(st, SEED_EVAL + i), seed=SEED_EVAL + i,
                     predictor=kind, label=predictor, config=st.race_config(), **gp, **cal) for i in range(st.tracks)]


def collect(st: Settings, out: Path) -> dict[str, Path]:
    """Baseline collection (``runs`` random tracks, oracle predictor), the initial subset and the
    validation set (:data:`VALIDATION_POINTS` random steps of the collection runs that no dataset
    keeps; the held-out points of every fit's quality report)."""
    tasks = collect_tasks(st, st.runs)
    own_init = st.baseline_tracks != "eval"  # the exploration starts from evaluation-style runs
    init_tasks = collect_tasks(st, st.init_runs, "eval") if own_init else tasks[: st.init_runs]
    paths = {"collect": out / "collect" / "dataset.h5", "init": out / "init" / "dataset.h5",
             "validation": out / "collect" / "validation.h5"}
    key = {"tasks": [task_hash(t) for t in tasks], "per_run": st.points_per_run}
    key_init = {"tasks": [task_hash(t) for t in init_tasks], "per_run": st.points_per_run}
    key_val = {**key, "validation": VALIDATION_POINTS}
    if _cached(paths["collect"], key) and _cached(paths["init"], key_init) and _cached(paths["validation"], key_val):
        return paths
    # the datasets are reused whatever --resume says; so are the finished runs behind them
    reuse = st.model_copy(update={"resume": True}) if _cached(paths["collect"], key) else st
    recs = run_tasks(tasks, out / "collect" / "runs", reuse, "collect")
    Z, Y, R = dataset_from_records(recs, st.points_per_run)
    n_failed = sum(not r.attrs.ok for r in recs)
    _write_dataset(paths["collect"], Z, Y, R, key, {"runs": len(recs), "failed": n_failed, "source": "collect"})
    if own_init:
        init_reuse = st.model_copy(update={"resume": True}) if _cached(paths["init"], key_init) else st
        Zi, Yi, Ri = dataset_from_records(run_tasks(init_tasks, out / "init" / "runs", init_reuse, "collect init"),
                                          st.points_per_run)
    else:
        m = R < st.init_runs
        if not m.any():
            raise InputError(f"none of the first {st.init_runs} collection runs succeeded")
        Zi, Yi, Ri = Z[m], Y[m], R[m]
    _write_dataset(paths["init"], Zi, Yi, Ri, key_init, {"runs": st.init_runs, "source": "init"})
    Zv, Yv, Rv = dataset_from_records(recs, st.points_per_run, held_out=True)
    pick = np.sort(np.random.default_rng(SEED_COLLECT + st.seed).permutation(len(Zv))[:VALIDATION_POINTS])
    _write_dataset(paths["validation"], Zv[pick], Yv[pick], Rv[pick], key_val, {"runs": len(recs), "source": "validation"})
    return paths


def explore(st: Settings, out: Path, init_model: Path, init_data: Path) -> Path:
    """Exploration episodes on the closed loop with alpha; returns the exploration dataset."""
    from gprace.h2h.predictors import load_opponent_gp

    load_opponent_gp(init_model)  # a wrong file fails here, before any run
    read_dataset(init_data)
    n_ep = max(1, int(round(st.explore_minutes * 60.0 / st.episode_seconds)))
    loop = TrackSpec(kind="loop", width=st.width if st.explore_width is None else st.explore_width)
    model_hash, data_hash = _hash_file(init_model), _hash_file(init_data)
    base = SEED_EXPLORE + CHAIN_STRIDE * st.seed
    tasks = [RaceTask(id=f"explore-{i}", track=loop, seed=base + i, predictor="gp", model=str(init_model),
                      alpha=st.alpha, explore_data=str(init_data), duration=st.episode_seconds,
                      config=st.race_config(), model_hash=model_hash, data_hash=data_hash)
             for i in range(n_ep)]
    path = out / "explore" / "dataset.h5"
    key = {"tasks": [task_hash(t) for t in tasks], "init": data_hash}
    if _cached(path, key):
        return path
    recs = run_tasks(tasks, out / "explore" / "runs", st, "explore")
    Ze, Ye, Re = dataset_from_records(recs)
    stal = sum(r.attrs.stalemates for r in recs if r.attrs.ok)
    _write_dataset(path, Ze, Ye, Re, key, {"episodes": n_ep, "stalemates": stal, "source": "explore"})
    return path
