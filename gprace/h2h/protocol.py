"""The paper's head-to-head protocol: collect, train, explore, select, race, tabulate.

Layout of ``--out DIR`` (every file an HDF5 artifact, written atomically)::

    collect/runs/run_<i>.h5       one record per collection race (oracle predictor), kind h2h_run
    collect/dataset.h5            (Z, Y) of all collection runs, kind h2h_dataset
    collect/validation.h5         held-out steps of the collection runs (in no dataset): fit quality
    init/runs/run_<i>.h5          the exploration's start runs (``init_runs`` oracle races on
                                  evaluation-style tracks) when the baseline collects on the
                                  training tracks (the default, ``--baseline-tracks training``)
    init/dataset.h5               the exploration's start: those runs, or the first ``init_runs``
                                  collection runs with ``--baseline-tracks eval``
    explore/runs/run_<i>.h5       exploration episodes on the closed loop (alpha = 0.9)
    explore/dataset.h5            init data + exploration data
    models/{baseline,init,explore,select}.h5   GP models (kind gp_model)
    eval/<predictor>/run_<i>.h5   the races of every predictor on the same scenarios
    errors/<predictor>/run_<i>.h5 offline e_y errors of every offline predictor on those races
                                  (and ``spread_<predictor>``: |s error|, raw std of s and e_y)
    calib/runs/run_<i>.h5         held-out races (oracle predictor, evaluation-style tracks, own
                                  seeds): the first calibration of every predictor's spread
    calib/errors/run_<i>.h5       offline errors and raw spreads of every predictor on them
    calib/<raced>/runs, errors    the second pass: held-out races driven by the raced predictors
    calib/pass<k>/<raced>/...     further passes until the calibration settles (``calib_passes``)
    calib/passes.json             per driven pass: the calibration it drove with, the one fitted, settled
    calib/calibration_oracle.json the first calibration (the second pass drives with it)
    calib/calibration.json        per predictor, step and output: scale and floor of the spread
    table.json                    the comparison table (all seeds)
    seed_<s>/...                  the same layout for chain seed s > 0 (``--seeds``)

Every batch of runs goes through :func:`gprace.executor.run_batch`. Each run record stores a hash
of its task; with ``resume`` a record whose hash matches is kept and only missing or failed runs
are rerun. A run that raises is recorded (``ok = False`` and its error) and skipped by the table.
Records are written and read only through their schemas (:mod:`gprace.h2h.records`: a race, the
offline errors of a race); a reused record of an older layout is migrated.
Datasets and models are reused when present and built from the same inputs (their ``config_hash``).

Every GP fit goes through :func:`gprace.gp.quality.checked_fit`: its quality report (noise,
hyperparameters at bounds, held-out error on ``collect/validation.h5`` against an exact GP on a
subsample) is stored in the model's ``quality`` attribute and printed; a degenerate fit is retried
and otherwise refused (FitError, exit 2), so it is never raced.

Seeds (``--seeds``): chain s repeats collection, training and exploration with every seed shifted
by ``s * CHAIN_STRIDE`` (seed 0 is the single-seed protocol, same runs, same folder) and races the
same evaluation scenarios; :mod:`gprace.h2h.spread` gives every figure's spread over seeds next to
its bootstrap interval over tracks and judges the paper's claims against both.

Conditions (each in the table's settings; a changed condition changes the task hashes of exactly
the runs it affects, so ``--resume`` reruns those): ``sensor_noise`` and ``process_noise`` scale
:data:`SENSOR_STD` and :data:`PROCESS_STD` (both cars, every race; 0 = noiseless, the task then
carries no noise entry); ``baseline_tracks`` (``training``, the default: the short ``curve``
and ``chicane`` tracks of Zhu et al. 2022, alternating, where the paper's baseline data come
from; ``eval``: the random evaluation-style tracks; only the baseline collection runs change, the
exploration's start runs are evaluation-style in both, in ``init/runs`` with ``training``);
``blocking_weight`` (the opponent's, every race; the default adds nothing to the tasks);
``explore_minutes``.

Calibrated spread: before the evaluation, held-out races give every predictor's errors and raw
spreads per step (offline rollouts as for the table's errors; ``calib_runs`` oracle races, then
``calib_runs`` races per pass driven in turn by the raced predictors until the calibration settles,
:func:`calibrate`);
:func:`gprace.h2h.spread.fit_calibration` turns them into a per-step scale (GP predictors) or
floor (constant velocity), carried by the evaluation tasks and applied in the predictors, so the
ellipses are inflated by a spread that covers the real error; the table gives the coverage of the
2-sigma band on the evaluation races, raw and calibrated, per predictor.

Decisions (the paper is silent): each collection run contributes ``points_per_run`` (10) evenly
spaced steps, which gives the paper's "about 5000 points" from 500 runs (all points of the
exploration episodes go to the diverse selection); the exploration GP's "20 runs" are the first 20 runs of the
baseline collection (same mechanism, no extra cost); exploration time is split into episodes of
``episode_seconds`` on the loop, each restarted from a random grid (runs in parallel), with the
loop at the racing width (``explore_width``; measured: exploring the 1.5 m loop for 0.75 m races
gave a 9-step error of 0.064 m against 0.026 m at 0.75 m, docs/decisions.md); the
"selection only" GP is a diverse selection from the baseline data with as many points as the
exploration GP's dictionary; GPs with more than ``exact_max`` points use the ``sparse`` backend.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np
from pydantic import Field, model_validator

from gprace.config import CommandSettings, config_hash
from gprace.errors import InputError
from gprace.h2h.config import opponent_mpc
from gprace.h2h.predictors import FEATURE_MAP, FEATURES, OUTPUTS
from gprace.h2h.records import (ErrorAttrs, RaceAttrs, Record, RecordAttrs, migrate, read_record, record_of,
                                warn_old, write_record)

if TYPE_CHECKING:
    from gprace.h2h.spread import TrackData

DATASET_KIND = "h2h_dataset"
SEED_EVAL, SEED_COLLECT, SEED_EXPLORE, SEED_CALIB = 0, 100_000, 200_000, 300_000
# Noise of 1:10 cars, std per state [v_x m/s, v_y m/s, yaw_rate rad/s, e_psi rad, e_y m, s m]
# (sources and reasoning: docs/decisions.md). Sensor: what an estimator fusing indoor
# positioning (cm-level) or motion capture (mm-level) with IMU and encoders gives a 1:10 car,
# white per 0.1 s step. Process: unmodelled forces (surface, tyre, actuator) as a random change of
# the velocities per 0.1 s step; positions follow through the dynamics.
SENSOR_STD = (0.01, 0.01, 0.02, 0.005, 0.005, 0.005)
PROCESS_STD = (0.01, 0.005, 0.02, 0.0, 0.0, 0.0)
BLOCKING_WEIGHT = opponent_mpc().q_block
BASELINE_TRACKS = ("eval", "training")
# 2: the constant-velocity prediction advances every step; 3: the NMPC stops at its first acceptable
# iterate, and a race ends on the one stop rule (gprace.sim.stop); 4: a failed solve's fallback
# keeps v_x at the NLP's bound and holds the heading after two failures in a row (gprace.h2h.nmpc);
# 5: the NLP's prediction model turns kinematic at a crawl (gprace.h2h.nmpc.blended_rk4); 6: the
# border margin covers the footprint at any heading (gprace.h2h.nmpc.border_margin). Records of an
# older version are rerun.
RACE_VERSION = 6
ERRORS_VERSION = 4  # 2: s errors and raw spreads; 3: one variance per start time; 4: sample_paths (step-0 rounding)
RACED = ("baseline", "explore")
# Backend settings of the opponent GPs (measured on the 5000-point baseline data, docs/decisions.md):
# one kernel for the five outputs (normalised) predicts as well as five kernels at a fifth of the
# rollout cost; the sparse fit starts from the exact optimum on 800 points, polishes it for 50
# iterations and keeps a noise floor (nearly noiseless data made the VFE fit degenerate); its five
# outputs share one kernel too (rollout 3.6 times faster, docs/decisions.md).
GP_SETTINGS: dict[str, dict[str, Any]] = {
    "exact": {"shared_kernel": True},
    "sparse": {"min_noise": 1e-3, "jitter": 1e-6, "max_iter": 50, "init_points": 800, "shared_kernel": True},
}
OFFLINE = ("baseline", "explore", "select", "cv")
CHAIN_STRIDE = 1_000_000  # seeds of chain s: the seeds of chain 0 plus s * CHAIN_STRIDE
VALIDATION_POINTS = 1000
QUALITY_VERSION = 2  # models fitted before the quality reports are refitted (and checked)


class Settings(CommandSettings):
    """The protocol of ``gprace eval head2head`` (defaults: the paper's comparison, REFERENCE.md)."""

    OPTIONS: ClassVar[dict[str, str]] = {"backend": "--gp-backend", "raced": "--predictors"}

    tracks: int = Field(100, ge=1, description="evaluation tracks (one race per predictor on each)")
    runs: int = Field(500, ge=1, description="collection races of the baseline's data")
    init_runs: int = Field(20, ge=1, description="collection races of the exploration's first GP")
    explore_minutes: float = Field(10.0, gt=0, description="simulated minutes of active exploration")
    episode_seconds: float = Field(60.0, gt=0, description="length of one exploration episode [s]")
    explore_width: float | None = Field(None, description="width of the exploration loop [m]; None: the racing "
                                        "width (``width``)")
    alpha: float = Field(0.9, ge=0, le=1, description="exploration weight of the exploring ego")
    dict_size: int = Field(600, ge=2, description="points of the exploration's GP dictionary")
    points_per_run: int = Field(10, ge=1, description="training points drawn from each collection race")
    stretches: int = Field(5, ge=1, description="random stretches of an evaluation track")
    width: float = Field(0.75, description="track width [m]")
    raced: tuple[str, ...] = Field(RACED, description="predictors whose egos race the evaluation tracks")
    offline: tuple[str, ...] = Field(OFFLINE, description="predictors whose open-loop errors are measured")
    backend: str = Field("auto", description="GP backend: exact | sparse | auto (sparse above exact_max points)")
    exact_max: int = Field(1500, ge=1, description="most points the exact GP takes with backend auto")
    inducing: int = Field(200, ge=1, description="inducing points of the sparse GP")
    optimize: bool = Field(True, description="fit the GP hyperparameters (False: the defaults)")
    samples: int = Field(50, ge=1, description="samples of the GP opponent rollout")
    max_time: float = Field(60.0, gt=0, description="longest race [s]")
    # conditions of the comparison (issue 17)
    sensor_noise: float = Field(1.0, ge=0, allow_inf_nan=False, description="scale of SENSOR_STD (0: noiseless)")
    process_noise: float = Field(1.0, ge=0, allow_inf_nan=False, description="scale of PROCESS_STD (0: noiseless)")
    baseline_tracks: str = Field("training", description="where the baseline's races run: " + " | ".join(BASELINE_TRACKS))
    blocking_weight: float = Field(BLOCKING_WEIGHT, ge=0, allow_inf_nan=False, description="the opponent's Q_block")
    calib_runs: int = Field(20, ge=1, description="races of each calibration pass")
    calib_passes: int = Field(3, ge=1, description="at most this many driven calibration passes (:func:`calibrate`)")
    config: dict = Field(default_factory=dict, description="H2HConfig entries of the races")
    # execution (not part of any result)
    workers: int = Field(1, ge=1, description="parallel workers")
    executor: str = Field("local", description="local | dask")
    scheduler: str | None = Field(None, description="address of a Dask scheduler")
    resume: bool = Field(False, description="reuse the records already written")
    seeds: tuple[int, ...] = Field((0,), description="chains of the whole protocol (``--seeds``)")
    seed: int = Field(0, description="the chain being run (set per chain by :func:`head2head`)")

    @model_validator(mode="after")
    def _check(self) -> Settings:
        if not self.seeds or min(self.seeds) < 0 or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"--seeds: a list of distinct seeds >= 0, got {list(self.seeds)}")
        if self.init_runs > self.runs:
            raise ValueError(f"--init-runs ({self.init_runs}) cannot exceed --runs ({self.runs})")
        if self.explore_width is not None:
            from gprace.h2h.geometry import loop_track

            try:
                loop_track(float(self.explore_width))  # the loop's own validity check, before any work
            except InputError as exc:
                raise ValueError(f"--explore-width: {exc}") from None
        from gprace.h2h.config import H2HConfig

        car = 2.0 * H2HConfig().ego.border_margin
        if not self.width > car:
            raise ValueError(f"--width must exceed {car:g} m (the car's footprint kept inside the borders), got {self.width}")
        if self.baseline_tracks not in BASELINE_TRACKS:
            raise ValueError(f"--baseline-tracks must be one of {', '.join(BASELINE_TRACKS)}, got {self.baseline_tracks!r}")
        if self.backend != "auto":
            from gprace.backends import gps

            gps.get(self.backend)  # an unknown name lists the registered ones
        from gprace.gp.selection import dictionary_bytes
        from gprace.resources import check_size

        check_size(f"--dict-size {self.dict_size}", self.dict_size,
                   lambda m: dictionary_bytes(m, len(OUTPUTS), len(FEATURES)), " points")
        # the records of a batch are held together (the table, the datasets): RACE_NUMBERS per step and car
        cfg = H2HConfig()
        race = 8.0 * RACE_NUMBERS * 2 * (self.max_time / cfg.dt + 1)
        for option, n, per, unit in (("--tracks", self.tracks, race * max(len(self.raced), 1), " tracks"),
                                     ("--runs", self.runs, race, " races")):
            check_size(f"{option} {n} with --max-time {self.max_time:g}", n, lambda k, per=per: k * per, unit)
        check_size(f"--samples {self.samples}", self.samples,
                   lambda k: 8.0 * RACE_NUMBERS * k * cfg.horizon * max(self.workers, 1), " samples")
        known = set(OFFLINE) | {"init", "oracle"}
        for p in (*self.raced, *self.offline):
            if p not in known:
                from gprace.errors import UnknownBackendError

                raise UnknownBackendError(f"unknown predictor {p!r}; available: {', '.join(sorted(known))}")
        return self

    def race_config(self) -> dict:
        """The races' :class:`H2HConfig` entries; a condition at its noiseless / default value adds
        nothing (the tasks of such runs keep their hashes)."""
        cfg = dict(self.config, max_time=self.max_time, samples=self.samples)
        if self.sensor_noise > 0:
            cfg["sensor_std"] = [self.sensor_noise * v for v in SENSOR_STD]
        if self.process_noise > 0:
            cfg["process_std"] = [self.process_noise * v for v in PROCESS_STD]
        if self.blocking_weight != BLOCKING_WEIGHT:
            cfg["opponent"] = opponent_mpc().model_copy(update={"q_block": float(self.blocking_weight)}).model_dump(mode="json")
        return cfg

    def conditions(self) -> dict:
        """The conditions of the comparison as the table prints them."""
        return {"sensor_std": [self.sensor_noise * v for v in SENSOR_STD],
                "process_std": [self.process_noise * v for v in PROCESS_STD],
                "baseline_tracks": self.baseline_tracks, "blocking_weight": self.blocking_weight,
                "explore_minutes": self.explore_minutes}


RACE_NUMBERS = 40
"""Numbers kept per race step and car (states, measurements, inputs, predictions, the GP's
training pairs), for the size checks of :class:`Settings`."""

PATH_KEYS = ("model", "explore_data", "record", "models")
"""Task entries that are file locations: their contents enter the task as ``*_hash`` entries."""


def _task_hash(task: dict) -> str:
    """Hash of what decides a run's result, with :data:`RACE_VERSION`; file locations are left
    out, so a copied or moved ``--out`` directory is still reused."""
    return config_hash({"race_version": RACE_VERSION, **{k: v for k, v in task.items() if k not in ("id", *PATH_KEYS)}})


# ----------------------------------------------------------------------------------------------
# batches of races
def _record_path(run_dir: Path, i: int) -> Path:
    return run_dir / f"run_{i:05d}.h5"


def race_with_data(task: dict) -> dict:
    """:func:`run_race` plus the GP training pairs of the run (computed in the worker)."""
    from gprace.h2h.geometry import make_track
    from gprace.h2h.predictors import training_pairs
    from gprace.h2h.race import run_race

    import time

    t0 = time.perf_counter()
    out = run_race(task)
    out["attrs"]["wall_s"] = time.perf_counter() - t0
    a = out["arrays"]
    Z, Y = training_pairs(make_track(task["track"]), a.get("ego_meas", a["ego"]), a.get("opp_meas", a["opp"]))
    out["arrays"]["Z"], out["arrays"]["Y"] = Z, Y
    return out


def _reusable(tasks: list[dict], run_dir: Path, schema: type[RecordAttrs], what: str) -> dict[int, Record]:
    """The records in ``run_dir`` that finished their task as it is now (same hash), by task index;
    one of an older layout is migrated. One warning for all old records, one for all unreadable
    ones (their tasks are rerun, and so rewritten, like those of the other records not reused)."""
    from gprace.console import console
    from gprace.errors import ArtifactError

    reused, old, unreadable = {}, [], []
    for i, t in enumerate(tasks):
        p = _record_path(run_dir, i)
        if not p.exists():
            continue
        try:
            rec = read_record(p, schema, warn=False)
        except ArtifactError as exc:
            unreadable.append(str(exc))
            continue
        old += [p] if rec.old else []
        if rec.attrs.ok and rec.attrs.task_hash == _task_hash(t):
            reused[i] = migrate(p, rec)
    warn_old(old, migrated=True)
    if unreadable:
        console.warn(f"{what}: {len(unreadable)} unreadable record(s) rerun; the first: {unreadable[0]}")
    return reused


_BUILT: set[str] = set()  # race configurations whose NMPCs this process has had built


def _build_controllers(config: dict, st: Settings) -> None:
    """Build the two cars' NMPCs of a race ``config`` side by side, once per process, before the
    first batch of races with more than one worker: each NLP compiles once per machine (25 to 50 s),
    and workers that all start with the ego would compile the two one after the other."""
    from gprace.executor import run_batch
    from gprace.h2h.race import build_controller

    key = json.dumps(config, sort_keys=True)
    if key in _BUILT or (st.workers == 1 and st.executor == "local"):
        return
    run_batch(build_controller, [{"config": config, "car": car} for car in ("ego", "opponent")],
              executor=st.executor, workers=2, scheduler=st.scheduler, label="building the two cars' NMPCs")
    _BUILT.add(key)


def run_tasks(tasks: list[dict], run_dir: Path, st: Settings, what: str,
              fn: Callable[[dict], dict] = race_with_data, schema: type[RecordAttrs] = RaceAttrs) -> list[Record]:
    """Run (or reuse, with ``resume``) every task; returns one record per task, written and typed
    by ``schema`` (:mod:`gprace.h2h.records`; ``attrs.ok`` and ``attrs.error`` say how it ran)."""
    from gprace.console import console
    from gprace.executor import run_batch

    run_dir.mkdir(parents=True, exist_ok=True)
    records: list[Record | None] = [None] * len(tasks)
    for i, rec in (_reusable(tasks, run_dir, schema, what) if st.resume else {}).items():
        records[i] = rec
    todo = [i for i, r in enumerate(records) if r is None]
    if todo and schema is RaceAttrs:
        _build_controllers(tasks[todo[0]]["config"], st)

    def done(r) -> None:
        i = todo[r.index]
        p = _record_path(run_dir, i)
        records[i] = write_record(p, record_of(schema, tasks[i], _task_hash(tasks[i]), r.ok, r.value, r.error, str(p)))
        if not r.ok:
            console.warn(f"{what}: run {i} failed and is skipped: {r.error.splitlines()[0]}")

    run_batch(fn, [tasks[i] for i in todo], executor=st.executor, workers=st.workers,
              scheduler=st.scheduler, on_done=done, label=f"{what}: {len(todo)} runs to do ({len(tasks) - len(todo)} reused)")
    return [r for r in records if r is not None]


# ----------------------------------------------------------------------------------------------
# datasets and models
def _write_dataset(path: Path, Z: np.ndarray, Y: np.ndarray, run: np.ndarray, key: dict, attrs: dict) -> Path:
    from gprace.io.artifacts import Artifact, write_artifact

    art = Artifact(DATASET_KIND, arrays={"Z": Z, "Y": Y, "run": run},
                   attrs=dict(attrs, inputs=list(FEATURES), outputs=list(OUTPUTS), n=len(Z)),
                   config_hash=config_hash(key))
    return write_artifact(path, art)


def read_dataset(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    from gprace.io.artifacts import read_artifact

    art = read_artifact(path, DATASET_KIND)
    return art.arrays["Z"], art.arrays["Y"]


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


def _track_spec(st: Settings, seed: int, kind: str = "eval") -> dict:
    if kind == "training":
        return {"kind": "training", "seed": seed, "width": st.width}
    return {"kind": "random", "seed": seed, "stretches": st.stretches, "width": st.width}


def collect_tasks(st: Settings, n: int, tracks: str | None = None) -> list[dict]:
    """Oracle races of the collection on ``tracks`` (default ``st.baseline_tracks``)."""
    base = SEED_COLLECT + CHAIN_STRIDE * st.seed
    kind = tracks or st.baseline_tracks
    return [{"id": f"collect-{i}", "track": _track_spec(st, base + i, kind), "seed": base + i,
             "predictor": "oracle", "config": st.race_config()} for i in range(n)]


def calib_tasks(st: Settings, predictor: str = "oracle", model: Path | None = None,
                calibration: dict | None = None, first: int = 0, n: int | None = None) -> list[dict]:
    """Held-out races on evaluation-style tracks (seeds no other stage uses): ``n`` (default
    ``calib_runs``) races from seed offset ``first``, the ego driving with the oracle predictor, or
    with a raced ``predictor``, its ``model`` and ``calibration`` as in :func:`eval_tasks`."""
    base = SEED_CALIB + CHAIN_STRIDE * st.seed
    seeds = [base + first + i for i in range(st.calib_runs if n is None else n)]
    if predictor == "oracle":  # the first pass's tasks as before (no label): their hashes, and so their runs, are kept
        return [{"id": f"calib-{sd - base}", "track": _track_spec(st, sd), "seed": sd, "predictor": "oracle",
                 "config": st.race_config()} for sd in seeds]
    return [{**t, "id": f"calib-{predictor}-{sd - base}", "track": _track_spec(st, sd), "seed": sd}
            for t, sd in zip(eval_tasks(st.model_copy(update={"tracks": len(seeds)}), predictor, model, calibration), seeds)]


def collect(st: Settings, out: Path) -> dict[str, Path]:
    """Baseline collection (``runs`` random tracks, oracle predictor), the initial subset and the
    validation set (:data:`VALIDATION_POINTS` random steps of the collection runs that no dataset
    keeps; the held-out points of every fit's quality report)."""
    tasks = collect_tasks(st, st.runs)
    own_init = st.baseline_tracks != "eval"  # the exploration starts from evaluation-style runs
    init_tasks = collect_tasks(st, st.init_runs, "eval") if own_init else tasks[: st.init_runs]
    paths = {"collect": out / "collect" / "dataset.h5", "init": out / "init" / "dataset.h5",
             "validation": out / "collect" / "validation.h5"}
    key = {"tasks": [_task_hash(t) for t in tasks], "per_run": st.points_per_run}
    key_init = {"tasks": [_task_hash(t) for t in init_tasks], "per_run": st.points_per_run}
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


def train(dataset: Path, model: Path, st: Settings, size: int | None = None, hyper_model: Path | None = None,
          initial: Path | None = None, seed: int = 0, validation: Path | None = None) -> Path:
    """Fit the opponent GP (Matern 1.5) on a dataset, checked by :func:`gprace.gp.quality.checked_fit`.

    With ``size``, the points are first streamed through the GP layer's diverse selection
    (:func:`gprace.gp.selection.select_diverse`) with the hyperparameters of ``hyper_model``,
    starting from the dictionary ``initial`` (a dataset) when given; the GP is then refitted on
    the selected dictionary. The fit's quality report (held-out points: ``validation``, a dataset)
    is stored in the model's ``quality`` attribute; a degenerate fit is retried and then refused
    (:class:`~gprace.errors.FitError`), and no model file is written.
    """
    from gprace.gp.quality import checked_fit
    from gprace.h2h.predictors import load_opponent_gp, save_opponent_gp

    key = {"data": _hash_file(dataset), "size": size, "backend": st.backend, "exact_max": st.exact_max,
           "inducing": st.inducing, "seed": seed, "optimize": st.optimize,
           "hyper": _hash_file(hyper_model) if hyper_model else None, "initial": _hash_file(initial) if initial else None,
           "validation": _hash_file(validation) if validation else None, "quality": QUALITY_VERSION,
           "gp_settings": GP_SETTINGS}
    if _cached(model, key):
        return model
    Z, Y = read_dataset(dataset)
    extra = {}
    if size is not None:
        from gprace.gp.selection import select_diverse

        if hyper_model is None:
            raise InputError("diverse selection needs a fitted GP for its hyperparameters")
        hyper = load_opponent_gp(hyper_model).hyper_
        init = read_dataset(initial) if initial is not None else None
        Z, Y, stats = select_diverse(hyper, Z, Y, size, initial=init)
        extra = {f"selection_{k}": int(v) for k, v in stats.as_dict().items()}
    backend = st.backend if st.backend != "auto" else ("exact" if len(Z) <= st.exact_max else "sparse")
    settings: dict[str, Any] = {"kernel": "matern15", "seed": seed, "optimize": st.optimize}
    settings.update(GP_SETTINGS.get(backend, {}))
    if backend == "sparse":
        settings["n_inducing"] = min(st.inducing, len(Z))
    import time

    from gprace.console import console

    console.info(f"h2h train: fitting the {backend} opponent GP on {len(Z)} points ({model.name})")
    t0 = time.perf_counter()
    Zv, Yv = read_dataset(validation) if validation is not None else (None, None)
    gp, quality = checked_fit(backend, settings, Z, Y, Zv, Yv, outputs=OUTPUTS, inputs=FEATURES, what=str(model))
    meta = {"fit_s": time.perf_counter() - t0, "feature_map": FEATURE_MAP, "input_names": list(FEATURES), "output_names": list(OUTPUTS),
            "n_points": len(Z), "y_std": json.dumps(Y.std(axis=0).tolist()), "quality": quality.to_json(), **extra}
    model.parent.mkdir(parents=True, exist_ok=True)
    return save_opponent_gp(model, gp, meta, config_hash=config_hash(key), seed=seed)


def fit_report(model: Path | dict):
    """The :class:`~gprace.gp.quality.FitQuality` stored with a model (its path, or its attributes
    already read), None for a model from before the reports."""
    from gprace.gp.quality import FitQuality
    from gprace.h2h.predictors import read_opponent_gp

    attrs = model if isinstance(model, dict) else read_opponent_gp(model)[1]
    text = attrs.get("quality")
    return FitQuality.from_json(str(text)) if text else None


def _hash_file(path: Path) -> str:
    import hashlib

    if not Path(path).is_file():
        raise InputError(f"{path}: no such file")
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def explore(st: Settings, out: Path, init_model: Path, init_data: Path) -> Path:
    """Exploration episodes on the closed loop with alpha; returns the exploration dataset."""
    from gprace.h2h.predictors import load_opponent_gp

    load_opponent_gp(init_model)  # a wrong file fails here, before any run
    read_dataset(init_data)
    n_ep = max(1, int(round(st.explore_minutes * 60.0 / st.episode_seconds)))
    loop = {"kind": "loop", "width": st.width if st.explore_width is None else st.explore_width}
    model_hash, data_hash = _hash_file(init_model), _hash_file(init_data)
    base = SEED_EXPLORE + CHAIN_STRIDE * st.seed
    tasks = [{"id": f"explore-{i}", "track": loop, "seed": base + i, "predictor": "gp",
              "model": str(init_model), "alpha": st.alpha, "explore_data": str(init_data),
              "duration": st.episode_seconds, "config": st.race_config(), "model_hash": model_hash,
              "data_hash": data_hash}
             for i in range(n_ep)]
    path = out / "explore" / "dataset.h5"
    key = {"tasks": [_task_hash(t) for t in tasks], "init": data_hash}
    if _cached(path, key):
        return path
    recs = run_tasks(tasks, out / "explore" / "runs", st, "explore")
    Ze, Ye, Re = dataset_from_records(recs)
    stal = sum(r.attrs.stalemates for r in recs if r.attrs.ok)
    _write_dataset(path, Ze, Ye, Re, key, {"episodes": n_ep, "stalemates": stal, "source": "explore"})
    return path


def models(st: Settings, out: Path) -> dict[str, Path]:
    """All GP models of the protocol (cached): baseline (all collection data), init (first
    ``init_runs``), explore (diverse selection of init + exploration data, init's hyperparameters),
    select (diverse selection of the baseline data, baseline's hyperparameters, same size). Every
    fit is checked against the validation set (see :func:`train`; :func:`report_fits` prints them)."""
    d = collect(st, out)
    m = out / "models"
    fit = dict(seed=st.seed, validation=d["validation"])
    paths = {"baseline": train(d["collect"], m / "baseline.h5", st, **fit), "init": train(d["init"], m / "init.h5", st, **fit)}
    ex = explore(st, out, paths["init"], d["init"])
    paths["explore"] = train(ex, m / "explore.h5", st, size=st.dict_size, hyper_model=paths["init"], initial=d["init"], **fit)
    from gprace.h2h.predictors import read_opponent_gp

    n_explore = int(read_opponent_gp(paths["explore"])[1].get("n_points", st.dict_size))
    paths["select"] = train(d["collect"], m / "select.h5", st, size=n_explore, hyper_model=paths["baseline"], **fit)
    return paths


def report_fits(paths: dict[str, Path], seed: int = 0) -> dict[str, Any]:
    """Read every model's quality report once, print one line per model (and its warnings);
    ``{name: report as a dict}``."""
    from gprace.console import console

    out = {}
    for name, path in paths.items():
        q = fit_report(path)
        out[name] = asdict(q)
        worst = int(np.argmax(np.asarray(q.heldout) / np.asarray(q.reference)))
        console.info(f"fit {name}{'' if seed == 0 else f' (seed {seed})'}: held-out error "
                     f"{' '.join(f'{h:.3f}' for h in q.heldout)} (exact GP on {q.reference_points} points: "
                     f"{' '.join(f'{r:.3f}' for r in q.reference)}), noise max {max(q.noise):.2g}, worst "
                     f"{q.outputs[worst]}, attempts {q.attempts}")
        if q.cautions():
            console.warn(f"fit {name}: {q.cautions()}")
    return out


# ----------------------------------------------------------------------------------------------
# evaluation
def eval_tasks(st: Settings, predictor: str, model: Path | None, calibration: dict | None = None) -> list[dict]:
    kind = predictor if predictor in ("cv", "oracle") else "gp"
    gp = {} if model is None else {"model": str(model), "model_hash": _hash_file(model)}  # read once
    cal = {"calibration": {k: calibration[k] for k in ("scale", "floor")}} if calibration else {}
    return [{"id": f"eval-{predictor}-{i}", "track": _track_spec(st, SEED_EVAL + i), "seed": SEED_EVAL + i,
             "predictor": kind, "label": predictor, "config": st.race_config(), **gp, **cal} for i in range(st.tracks)]


def race_predictors(st: Settings, out: Path, model_paths: dict[str, Path],
                    calibration: dict[str, dict] | None = None) -> dict[str, list[Record]]:
    res = {}
    for p in st.raced:
        tasks = eval_tasks(st, p, model_paths.get(p), (calibration or {}).get(p))
        res[p] = run_tasks(tasks, out / "eval" / p, st, f"race {p}")
    return res


def offline_errors_task(task: dict) -> dict:
    from gprace.executor import single_thread_blas

    return single_thread_blas(_offline_errors)(task)


def _offline_errors(task: dict) -> dict:
    """Prediction errors of every offline predictor on one closed-loop opponent trajectory.

    Rollouts start at every step t of the record, from the opponent state the ego saw (the
    measured one under sensor noise), with the ego's closed-loop trajectory as seen by the ego as
    the ego part of the input; all start times and samples go through one GP call per step; the
    errors are against the true opponent states. Returns ``{"arrays": {name: (K, n_t) |mean e_y -
    true e_y|, "spread_<name>": (3, K, n_t) |mean s - true s|, raw std of s, raw std of e_y}}``
    (the spread of the constant-velocity predictor is zero).
    """
    from gprace.h2h.config import H2HConfig
    from gprace.h2h.geometry import make_track
    from gprace.h2h.predictors import cv_positions, make_predictor, sample_paths

    cfg = H2HConfig(**task.get("config", {}))
    K = cfg.pred_steps
    track = make_track(task["track"])
    a = read_record(Path(task["record"]), RaceAttrs, warn=False).arrays  # run_tasks read (and migrated) it before
    O = a["opp"]
    E, Om = a.get("ego_meas", a["ego"]), a.get("opp_meas", O)
    T = len(O) - K
    out = {}
    if T <= 0:
        return {"arrays": {**{name: np.zeros((K, 0)) for name in task["models"]},
                           **{f"spread_{name}": np.zeros((3, K, 0)) for name in task["models"]}}, "attrs": {}}
    truth = np.stack([O[k + 1:k + 1 + T, 4] for k in range(K)])  # (K, T)
    truth_s = np.stack([O[k + 1:k + 1 + T, 5] for k in range(K)])
    for name, path in task["models"].items():
        if name == "cv":  # ConstantVelocityPredictor for every start time at once
            mean_s, mean = cv_positions(track, Om[:T], K, cfg.dt)
            std_s = std_ey = np.zeros((K, T))
        else:  # the GP rollout for every start time at once (n samples each)
            gp = make_predictor("gp", K, cfg.dt, path, cfg.samples).gp
            n = cfg.samples
            # ego part: the closed-loop ego states from each start time t; draws in the order of
            # one (T n, 5) block per step
            eps = np.random.default_rng(int(task["seed"])).standard_normal((K, T * n, len(OUTPUTS)))
            ego = np.stack([E[k:k + T] for k in range(K)])
            paths = sample_paths(gp, track, ego, Om[:T, :6], n, eps).reshape(T, n, K, 6)
            mean, mean_s = paths[..., 4].mean(axis=1).T, paths[..., 5].mean(axis=1).T
            std_ey, std_s = paths[..., 4].std(axis=1).T, paths[..., 5].std(axis=1).T
        out[name] = np.abs(mean - truth)
        out[f"spread_{name}"] = np.stack([np.abs(mean_s - truth_s), std_s, std_ey])
    return {"arrays": out, "attrs": {}}


def offline_errors(st: Settings, out: Path, raced: dict[str, list[Record]], model_paths: dict[str, Path]) -> dict:
    """Offline e_y errors ``{offline predictor: (K, start times)}`` over every closed-loop race;
    one task per race, recorded under ``errors/`` and reused like the races."""
    return offline_error_columns(st, out, raced, model_paths)[0]


def offline_error_columns(st: Settings, out: Path, raced: dict[str, list[Record]],
                          model_paths: dict[str, Path]) -> tuple[dict, np.ndarray]:
    """:func:`offline_errors` and the evaluation track of every column (start time)."""
    return offline_error_data(st, out, raced, model_paths)[:2]


def _rollout_errors(st: Settings, records: list[Record], rec_dir: Path, err_dir: Path, names: list[str],
                    model_paths: dict[str, Path], what: str) -> tuple[list[int], list[dict]]:
    """Offline errors of the predictors ``names`` on every successful record (one recorded task
    per record, reused like the races): the indices of those records and their error arrays."""
    models = {p: (str(model_paths[p]) if p != "cv" else None) for p in names}
    hashes = {p: _hash_file(Path(v)) for p, v in models.items() if v is not None}
    tasks, index = [], []
    for i, rec in enumerate(records):
        if rec.attrs.ok:
            t = rec.attrs.task
            tasks.append({"id": f"errors-{rec_dir.name}-{i}", "record": str(_record_path(rec_dir, i)),
                          "record_hash": rec.attrs.task_hash, "track": t["track"], "seed": t["seed"],
                          "config": t["config"], "models": models, "model_hashes": hashes,
                          "version": ERRORS_VERSION})
            index.append(i)
    recs = run_tasks(tasks, err_dir, st, what, fn=offline_errors_task, schema=ErrorAttrs)
    ok = [(i, r.arrays) for i, r in zip(index, recs) if r.attrs.ok]
    return [i for i, _ in ok], [a for _, a in ok]


def _stack(arrays: list[dict], key: str, empty: tuple[int, ...]) -> np.ndarray:
    got = [a[key] for a in arrays if key in a]
    return np.concatenate(got, axis=-1) if got else np.zeros(empty)


def offline_error_data(st: Settings, out: Path, raced: dict[str, list[Record]],
                       model_paths: dict[str, Path]) -> tuple[dict, np.ndarray, dict]:
    """:func:`offline_errors`, the evaluation track of every column (start time) and the spread
    data ``{offline predictor: (3, K, columns)}`` (|s error|, raw std of s and of e_y)."""
    K = H2H_K(st)
    arrays: list[dict] = []
    tracks: list[np.ndarray] = []
    for p in st.raced:
        index, arr = _rollout_errors(st, raced[p], out / "eval" / p, out / "errors" / p, list(st.offline),
                                     model_paths, f"offline errors {p}")
        arrays += arr
        tracks += [np.full(a[st.offline[0]].shape[1] if st.offline else 0, i) for i, a in zip(index, arr)]
    return ({p: _stack(arrays, p, (K, 0)) for p in st.offline},
            np.concatenate(tracks) if tracks else np.zeros(0, int),
            {p: _stack(arrays, f"spread_{p}", (3, K, 0)) for p in st.offline})


def calibrated_names(st: Settings, model_paths: dict[str, Path]) -> list[str]:
    """The predictors whose spread is calibrated: every raced or offline one but the oracle."""
    return [p for p in dict.fromkeys((*st.raced, *st.offline)) if p == "cv" or p in model_paths]


def calibrate(st: Settings, out: Path, model_paths: dict[str, Path]) -> dict[str, dict]:
    """Calibration of every predictor's spread on held-out races (evaluation-style tracks, seeds of
    their own; no model is trained on them and the evaluation does not use them), in passes:

    1. ``calib_runs`` races with the oracle predictor (``calib/runs``) give a first calibration;
    2. ``calib_runs`` more races, shared in turn by the raced predictors, each driving with the
       calibration of the pass before (``calib/<predictor>/runs``, pass k > 2 in
       ``calib/pass<k>/<predictor>``), give the next one, fitted on them alone; passes repeat, at
       most ``calib_passes`` of them, until the races confirm the calibration they drove with
       (:func:`gprace.h2h.spread.settled`). A raced predictor's final calibration is the larger of
       the one its last pass drove with and the one fitted on it (:func:`gprace.h2h.spread.at_least`),
       the others' the fit of the last pass.

    Why: the errors depend on who drives. Behind an oracle ego the opponent blocks less; the
    baseline's 9-step e_y error there was half its error in the evaluation races (0.012 vs 0.021 m),
    and a calibration from oracle races alone covered 83 % of its evaluation errors instead of 94 %;
    one driven pass with the oracle calibration still left exploration at 88.7 % (docs/decisions.md).
    Returns ``{predictor: calibration}``, also written to ``calib/calibration.json`` (the first pass
    to ``calib/calibration_oracle.json``, the history of the passes to ``calib/passes.json``)."""
    from gprace.h2h.spread import at_least, settled
    from gprace.io.artifacts import write_text_atomic

    names = calibrated_names(st, model_paths)
    if not names:
        return {}
    folder = out / "calib"
    cal = _fit_calibration(st, _calibration_errors(st, folder, calib_tasks(st), names, model_paths, "calibration"), names)
    drivers = [p for p in st.raced if p in names][: st.calib_runs]
    if drivers:
        write_text_atomic(folder / "calibration_oracle.json", json.dumps(cal, indent=1))
        first, driving, history = st.calib_runs, cal, []
        for k in range(2, 2 + st.calib_passes):
            sub, arrays = folder if k == 2 else folder / f"pass{k}", []
            for j, p in enumerate(drivers):
                n = len(range(j, st.calib_runs, len(drivers)))  # calib_runs shared out in turn
                tasks = calib_tasks(st, p, model_paths.get(p), driving.get(p), first, n)
                arrays += _calibration_errors(st, sub / p, tasks, names, model_paths, f"calibration pass {k} {p}")
                first += n
            fitted = _fit_calibration(st, arrays, names)
            done = all(settled(driving[p], fitted[p]) for p in drivers)
            history.append({"pass": k, "settled": done, "drove_with": {p: driving[p] for p in drivers},
                            "fitted": {p: fitted[p] for p in drivers}})
            if done or k == 1 + st.calib_passes:
                break
            driving = fitted
        if not done:
            from gprace.console import console

            console.warn(f"calibration: not settled after {st.calib_passes} driven passes; the raced predictors keep "
                         f"the larger of the last two calibrations (see {folder / 'passes.json'})")
        cal = {p: at_least(driving[p], fitted[p]) if p in drivers else fitted[p] for p in names}
        write_text_atomic(folder / "passes.json", json.dumps(history, indent=1))
    write_text_atomic(folder / "calibration.json", json.dumps(cal, indent=1))
    return cal


def _calibration_errors(st: Settings, folder: Path, tasks: list[dict], names: list[str],
                        model_paths: dict[str, Path], what: str) -> list[dict]:
    """Race the calibration tasks in ``folder/runs`` and return the predictors' error arrays."""
    recs = run_tasks(tasks, folder / "runs", st, f"{what} races")
    _, arrays = _rollout_errors(st, recs, folder / "runs", folder / "errors", names, model_paths, f"{what} errors")
    if not arrays:
        raise InputError(f"{what}: no calibration race succeeded; see the records in {folder / 'runs'}")
    return arrays


def _fit_calibration(st: Settings, arrays: list[dict], names: list[str]) -> dict[str, dict]:
    from gprace.h2h.spread import fit_calibration

    K = H2H_K(st)
    cal = {}
    for p in names:
        ey, sp = _stack(arrays, p, (K, 0)), _stack(arrays, f"spread_{p}", (3, K, 0))
        cal[p] = fit_calibration(np.stack([sp[0], ey]), sp[1:])
    return cal


def coverage(spread: dict[str, np.ndarray], errors: dict[str, np.ndarray], calibration: dict[str, dict]) -> dict:
    """Per offline predictor: the share of its errors on the evaluation races inside the 2-sigma
    band, per step, of e_y and s, with the calibrated and with the raw spread."""
    from gprace.h2h.spread import band_coverage

    res = {}
    for p, sp in spread.items():
        err, std = np.stack([sp[0], errors[p]]), sp[1:]
        cal, raw = band_coverage(err, std, calibration.get(p)), band_coverage(err, std)
        res[p] = {"s": cal[0].tolist(), "ey": cal[1].tolist(), "s_raw": raw[0].tolist(), "ey_raw": raw[1].tolist(),
                  "points": int(err.shape[2]), "calibrated": p in calibration}
    return res


def H2H_K(st: Settings) -> int:
    from gprace.h2h.config import H2HConfig

    return H2HConfig(**st.race_config()).pred_steps


def table(st: Settings, raced: dict[str, list[Record[RaceAttrs]]], errors: dict[str, np.ndarray]) -> dict:
    """The paper's table of one seed (:func:`gprace.h2h.table.chain_table`): racing results per
    raced predictor and offline e_y errors per predictor, with the settings and conditions."""
    from gprace.h2h.table import chain_table

    settings = {k: v for k, v in st.model_dump(mode="json").items() if k not in ("workers", "executor", "scheduler", "resume")}
    return chain_table(settings, st.conditions(), {p: raced[p] for p in st.raced}, errors, st.tracks)


def chain_dir(out: Path, seed: int) -> Path:
    """Folder of one chain: ``out`` itself for seed 0 (the single-seed layout), else ``out/seed_<s>``."""
    return out if seed == 0 else out / f"seed_{seed}"


def run_chain(st: Settings, out: Path) -> tuple[dict, "TrackData", dict]:
    """One seed of the whole chain (collection, training, exploration, evaluation) in ``out``:
    its table, its results per track and its fit reports."""
    from gprace.h2h.spread import track_data

    paths = models(st, out)
    cal = calibrate(st, out, paths)
    raced = race_predictors(st, out, paths, cal)
    errors, tracks, spread = offline_error_data(st, out, raced, paths)
    fits = report_fits(paths, st.seed)
    tab = table(st, raced, errors)
    tab["coverage"], tab["calibration"] = coverage(spread, errors, cal), cal
    return tab, track_data(raced, errors, tracks, st.tracks), fits


def head2head(st: Settings, out: Path) -> dict:
    """The protocol over ``st.seeds``: one chain per seed (:func:`chain_dir`), every batch through
    the executor; the table of the first seed plus ``per_seed`` tables, ``fits`` (quality reports),
    ``spread`` (every figure over seeds and its bootstrap interval over tracks) and ``claims``."""
    from gprace.h2h.spread import summarise
    from gprace.h2h.table import H2HTable, write_table

    tables, data, fits = {}, [], {}
    for s in st.seeds:
        tab, td, fit = run_chain(st.model_copy(update={"seed": s}), chain_dir(out, s))
        tables[str(s)], fits[str(s)] = tab, fit
        data.append(td)
    spread = summarise(data)
    first = tables[str(st.seeds[0])]
    tab = {**first, "seeds": list(st.seeds), "per_seed": tables, "fits": fits,
           "spread": {k: v for k, v in spread.items() if not k.startswith("diff.")},
           "claims": {k[len("diff."):]: v for k, v in spread.items() if k.startswith("diff.")}}
    tab["settings"] = {k: v for k, v in first["settings"].items() if k != "seed"}
    return write_table(out / "table.json", H2HTable.model_validate(tab))


def parse_seeds(text: str | int) -> tuple[int, ...]:
    """``--seeds``: a count N (seeds 0..N-1) or a comma-separated list of seeds (``"0,4,7"``, ``"5,"``)."""
    t = str(text).strip()
    try:
        if "," not in t:
            n = int(t)
            if n < 1:
                raise InputError(f"--seeds must be a count >= 1 or a list of seeds, got {text!r}")
            return tuple(range(n))
        seeds = tuple(int(x) for x in t.split(",") if x.strip())
    except ValueError:
        raise InputError(f"--seeds must be a count or a comma-separated list of integers, got {text!r}") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise InputError(f"--seeds: a list of distinct seeds >= 0, got {text!r}")
    return seeds
