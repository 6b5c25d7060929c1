"""``gprace iterate``: the paper's iterative double-GP time trial with active exploration.

Per trial (an independent chain with its own seed; trials run in parallel through
:func:`gprace.executor.run_batch`):

- iteration 0: the nominal MPC (no GP) drives the minimum-curvature path at a conservative share
  ``first_speed_scale`` of the nominal model's limits;
- iteration i >= 1 with ``alpha_i`` (the ``--alpha`` list, its last value repeated up to
  ``--iterations``): (1) the measurements of iteration i-1 are streamed into the dictionaries of
  both GPs (``diverse`` selection of the paper or the ``random`` baseline, accumulating over
  iterations); (2) both GPs are retrained (hyperparameters by marginal likelihood on the first
  retrain only, then posterior refits with those hyperparameters fixed; see
  :mod:`gprace.timetrial.learning`), the exploration candidates and their weighted variances are
  computed (iterations with alpha > 0; alpha = 0 never uses them); (3) the lap is re-planned
  with the planning GP, warm-started from the last plan that completed a lap, inside a friction
  ellipse widened from the accelerations measured on the last lap (:mod:`gprace.timetrial.grip`;
  a failed lap narrows it); (4) the tracking MPC with the
  tracking GP drives it with ``alpha_i``. If the re-plan fails (IPOPT reports infeasible or runs
  out of iterations), the last plan that completed a lap is driven again and the record says
  ``replan_failed``.

The oracle lap (``oracle.json``, plants whose physics are known: ``frenet``): the same planner on
the plant's true model (nominal vehicle plus its effects, actuator lags left out), no ellipse,
driven by the tracking MPC of that model. It is what perfect model knowledge would give
(:mod:`gprace.timetrial.oracle`); the summary is :mod:`gprace.timetrial.summary`.

Folder layout (``--out DIR``)::

    settings.json                       the experiment (a rerun must match it)
    heldout.h5                          a weaving run of the plant (GP test set, shared by trials)
    calib.h5                            a weaving run of another design (GP variance calibration, shared)
    trial_<j>/iter_<i>/plan.h5 run.h5 gp_tracking.h5 gp_planning.h5 data_*.h5 [candidates.h5] record.json
    trial_<j>/hyper_tracking.h5 hyper_planning.h5
    oracle.json oracle_plan.h5 oracle_run.h5   the oracle lap (or {"known": false})
    .steps/<name>.done                  written only after the step's artifacts are on disk
    summary.json

Resuming: every step checks its marker first; artifacts are written atomically and the marker
after them, so a run killed anywhere resumes at the first unfinished step without duplicating or
losing data (a step interrupted half-way is simply redone: it rewrites the same files).
"""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field, model_validator

from gprace.config import CommandSettings
from gprace.console import console
from gprace.errors import InputError, RunFailedError, SolverError
from gprace.timetrial.oracle import ORACLE_MARGINS, oracle_lap  # noqa: F401 (importable from here, as before)
from gprace.timetrial.record import IterationRecord, read_record, write_json, write_record
from gprace.timetrial.summary import SUMMARY_COLUMNS, build_summary, failed_laps_text  # noqa: F401 (as before)


class IterateSettings(CommandSettings):
    """The iterative double-GP time trial (``gprace iterate``; defaults: the paper's schedule)."""

    OPTIONS: ClassVar[dict[str, str]] = {"alphas": "--alpha", "dictionary_size": "--dictionary-size"}

    alphas: tuple[float, ...] = Field((0.857, 0.714, 0.0), description="exploration weight of iteration 1, 2, ...; "
                                      "the last holds for the rest")
    iterations: int = Field(7, ge=1, description="GP iterations after the nominal iteration 0")
    trials: int = Field(3, ge=1, description="independent repetitions")
    selection: str = Field("diverse", description="how the dictionary keeps points: diverse | random")
    plant: str = Field("audi_hidden", description="the plant driven (shipped name or TOML path)")
    track: str = Field("gprace_ring", description="track: shipped name or a TUM CSV/TOML path")
    vehicle: str = Field("audi_tt_cup", description="the nominal model's vehicle")
    dictionary_size: int = Field(1000, ge=10, description="points of each GP's dictionary")
    max_fit_points: int = Field(300, ge=1, description="points the hyperparameter fit uses at most")
    plan_ds: float = Field(6.0, gt=0, description="arc-length step of the planner [m]")
    first_speed_scale: float = Field(0.7, gt=0, le=1, description="speed scale of the first, GP-free plan")
    plan_grip: float = Field(1.0, gt=0, description="cap of the widened ellipse: share of the nominal model's limits")
    widen: float = Field(0.05, ge=0, lt=0.5, description="widening of the measured envelope per clean lap")
    widen_max: float = Field(0.15, ge=0, lt=0.5, description="widening per clean lap that used little of the tires' "
                             "slip (gprace.timetrial.grip.widening)")
    features: str = Field("full", description='GP inputs: "full" or "paper" (gprace.gp.features.DYN_FEATURE_SETS)')
    grip: bool = Field(True, description="rear-slip constraint in the tracking MPC")
    oracle: bool = Field(True, description="plan and drive the oracle lap (frenet plants)")
    solver: str = Field("clarabel", description="QP backend of the tracking MPC")
    beta: float = Field(0.6, description="chance-constraint probability of the tracking MPC")
    laps: float = Field(1.0, gt=0, description="laps per trial and iteration")
    seed: int = Field(0, description="seed of trial 0 (trial t: seed + t)")
    grid_values: int = Field(7, ge=2, description="candidate values per exploration dimension")
    heldout_laps: float = Field(1.0, gt=0, description="laps of the held-out reference run")
    heldout_weave: float = Field(0.7, ge=0, description="weave of the held-out run [m]")
    calib_weave: float = Field(0.4, ge=0, description="weave of the calibration run [m]; 0: leave-one-out "
                               "calibration only")
    shakedown: bool = Field(True, description="iteration 0 is a shakedown that widens its limits from what the car "
                            "shows (False: the curvature plan at first_speed_scale)")
    shakedown_start: float = Field(0.5, gt=0, le=1, description="share of the nominal model's limits the shakedown "
                                   "starts at")
    delay: float | None = Field(None, ge=0, description="total steering and measurement delay the MPC predicts over "
                                "[s]; None: the vehicle's known delays, else estimated in the shakedown")
    envelope: bool = Field(True, description="run-time stability envelope (eases the reference when the car leaves "
                           "the band of its own laps)")
    never_worse: bool = Field(True, description="drive a GP plan only if predicted safe; after a lost or slower lap go "
                              "back to the last good plan and limits")
    slower_tolerance: float = Field(0.005, ge=0, description="an alpha-0 lap slower than the best by more than this "
                                    "share counts as slower")

    @model_validator(mode="after")
    def _check(self) -> IterateSettings:
        if not self.alphas:
            raise ValueError("--alpha: give at least one value")
        bad = [a for a in self.alphas if not 0.0 <= a <= 1.0]
        if bad:
            raise ValueError(f"--alpha: values must be in [0, 1], got {bad[0]}")
        if self.selection not in ("diverse", "random"):
            raise ValueError(f"--selection must be diverse or random, got {self.selection!r}")
        from gprace.backends import solvers
        from gprace.gp.features import dyn_feature_set
        from gprace.mpc.tracking import quantile_factor

        dyn_feature_set(self.features)
        solvers.get(self.solver)  # an unknown name lists the registered ones, before any planning
        quantile_factor(self.beta)
        self._check_dictionary_size()
        if self.delay is not None:
            from gprace.errors import ConfigError
            from gprace.mpc.delay import check
            from gprace.mpc.tracking import MPCSettings

            mpc = MPCSettings()
            try:
                check(self.delay, mpc.N, mpc.dt, "--delay")
            except ConfigError as exc:
                raise ValueError(str(exc)) from None
        return self

    def _check_dictionary_size(self) -> None:
        """Both GPs' dictionaries (selection and exact fit) must fit in memory, before any work."""
        from gprace.gp.features import dyn_feature_set, feature_map
        from gprace.gp.selection import dictionary_bytes
        from gprace.resources import check_size

        p, d = sum(len(feature_map(k).output_names) for k in ("tracking", "planning")), len(dyn_feature_set(self.features))
        check_size(f"--dictionary-size {self.dictionary_size}", self.dictionary_size,
                   lambda m: dictionary_bytes(m, p, d), " points")

    def alpha(self, i: int) -> float:
        """alpha of iteration i >= 1."""
        return float(self.alphas[min(i - 1, len(self.alphas) - 1)])


# ------------------------------------------------------------------------------------------------
# step bookkeeping


class Steps:
    def __init__(self, out: Path) -> None:
        self.dir = out / ".steps"
        self.dir.mkdir(parents=True, exist_ok=True)

    def done(self, name: str) -> bool:
        return (self.dir / f"{name}.done").exists()

    def mark(self, name: str) -> None:
        from gprace.io.artifacts import write_text_atomic

        write_text_atomic(self.dir / f"{name}.done", time.strftime("%Y-%m-%dT%H:%M:%S"))


# ------------------------------------------------------------------------------------------------
# the loop


def iterate(settings: IterateSettings, out: str | Path, executor: str = "local", workers: int | None = 1,
            scheduler: str | None = None, progress=None) -> dict:
    """Run (or resume) the experiment in ``out``; return the summary. On a terminal one bar counts
    the laps driven (:func:`lap_markers`), with an ETA; it moves while the trials run in other processes."""
    laps = lap_markers(settings, Path(out))
    bar = lambda: console.polled(f"iterate: {len(laps)} laps", len(laps), lambda: sum(p.exists() for p in laps),  # noqa: E731
                                 unit="laps")
    return iterate_many([(settings, out)], executor, workers, scheduler, bar=bar)[0]


def lap_markers(settings: IterateSettings, out: Path) -> list[Path]:
    """The step markers of every lap an experiment drives: its reference runs, each trial's
    iterations 0..N (``t<j>_i<i>_drive``) and the oracle lap; a lap is done when its marker exists."""
    steps = out / ".steps"
    refs = [name for name in REFERENCE_RUNS if name != "calib" or settings.calib_weave > 0]
    trials = [f"t{j}_i{i}_drive" for j in range(settings.trials) for i in range(settings.iterations + 1)]
    return [steps / f"{name}.done" for name in refs + trials + ["oracle"]]


def iterate_many(experiments, executor: str = "local", workers: int | None = 1, scheduler: str | None = None,
                 bar=None) -> list[dict]:
    """Run (or resume) several experiments ``[(settings, out), ...]`` with all their trials in one batch.

    Experiments on the same plant, track and seed share the held-out run and the oracle lap (the
    first computes them, the others copy them). ``bar``: a context manager factory (a progress
    bar) entered once every experiment is checked, so a refusal stays one line.
    """
    tasks: list[dict] = []
    references: list[dict] = []
    prepared: list[tuple[IterateSettings, Path, Path | None]] = []
    for settings, out in experiments:
        out = Path(out)
        share = next((o for st, o, _ in prepared if _shares_references(st, settings)), None)
        refs, trials = _prepare(settings, out, share)
        references += refs
        tasks += trials
        prepared.append((settings, out, share))
    with bar() if bar is not None else contextlib.nullcontext():
        return _run_prepared(prepared, references, tasks, executor, workers, scheduler)


def _run_prepared(prepared, references, tasks, executor, workers, scheduler) -> list[dict]:
    """The reference runs, then the trials and the oracle lap, then the summaries (iterate_many)."""
    import shutil

    from gprace.executor import run_batch

    if executor == "local":  # forked trial processes inherit what the parent imported (issue 37)
        from gprace.timetrial.learning import preload_trial_modules

        preload_trial_modules()
    # the reference runs of all experiments in one batch first (each a lap or two of simulate)
    done = run_batch(_reference_task, references, executor=executor, workers=processes(workers, len(references)), scheduler=scheduler,
                     label=f"iterate: {len(references)} reference run(s)") if references else []
    bad = [r for r in done if not r.ok]
    if bad:
        raise RunFailedError(f"iterate: {len(bad)} reference run(s) failed ({bad[0].error.splitlines()[0]}); "
                             "rerun the same command to resume")
    for _, out, share in prepared:
        _share_references(out, share)
    # the oracle lap runs beside the trials (it is one more task of the batch), once per shared set
    tasks.sort(key=lambda t: "oracle" in t)
    label = f"iterate: {sum('oracle' not in t for t in tasks)} trial(s)" + (" and the oracle lap" if tasks[-1:] and "oracle" in tasks[-1] else "")
    results = run_batch(run_chain, tasks, executor=executor, workers=processes(workers, len(tasks)), scheduler=scheduler,
                        label=label)
    for _, out, share in prepared:
        if share is not None and (share / "oracle.json").exists() and not Steps(out).done("oracle"):
            shutil.copy2(share / "oracle.json", out / "oracle.json")
            Steps(out).mark("oracle")
    summaries = []
    for _, out, _ in prepared:
        summary = build_summary(out)
        write_json(out / "summary.json", summary)
        summaries.append(summary)
    failed = [r for r in results if not r.ok]
    if failed:
        first = failed[0].error.splitlines()[0]
        raise RunFailedError(f"iterate: {len(failed)} of {len(tasks)} trials failed ({first}); rerun the same command to resume")
    return summaries


def processes(workers: int | None, tasks: int) -> int:
    """Local worker processes for a batch of ``tasks``: ``workers``, or by default (None) one per
    task, at most 3 per core. The trials are chains of equal length: 3 trials on 2 processes run
    2 then 1 (a core idles for a whole chain), 3 processes share the 2 cores evenly (README job:
    wall time 1.5 instead of 2 chains)."""
    import os

    if workers is not None:
        return int(workers)
    return max(1, min(int(tasks), 3 * (os.cpu_count() or 1)))


def _shares_references(a: IterateSettings, b: IterateSettings) -> bool:
    keys = ("plant", "track", "vehicle", "seed", "heldout_laps", "heldout_weave", "calib_weave", "plan_ds", "laps", "solver", "beta", "grip")
    return all(getattr(a, k) == getattr(b, k) for k in keys)


def _prepare(settings: IterateSettings, out: Path, share: Path | None = None) -> tuple[list[dict], list[dict]]:
    """Check the settings, write or match ``settings.json``; the reference runs to make (none when
    ``share`` has them) and the trial tasks (and the oracle lap's)."""
    from gprace.io.artifacts import check_folder

    _check_start(settings)  # a bad track, plant or vehicle, or a car that cannot start: before anything is written
    check_folder(out)
    mine = settings.model_dump(mode="json")
    sfile = out / "settings.json"
    if sfile.exists():
        old = json.loads(sfile.read_text())
        if old != mine:
            diff = sorted(k for k in set(old) | set(mine) if old.get(k) != mine.get(k))
            raise InputError(f"{out}: holds an experiment with other settings ({', '.join(diff)}); use another --out")
    else:
        out.mkdir(parents=True, exist_ok=True)
        write_json(sfile, mine)
    steps = Steps(out)
    refs = [{"out": str(out), "reference": name, "settings": mine} for name in REFERENCE_RUNS
            if share is None and not steps.done(name) and (name != "calib" or settings.calib_weave > 0)]
    tasks = [{"out": str(out), "trial": j, "settings": mine} for j in range(settings.trials)]
    if share is None and not steps.done("oracle"):
        tasks.append({"out": str(out), "oracle": True, "settings": mine})
    return refs, tasks


def _share_references(out: Path, share: Path | None) -> None:
    """Copy the reference runs an experiment shares with an earlier one (``share``)."""
    import shutil

    if share is None:
        return
    steps = Steps(out)
    for name in REFERENCE_RUNS:
        if not steps.done(name) and (share / f"{name}.h5").exists():
            shutil.copy2(share / f"{name}.h5", out / f"{name}.h5")
            steps.mark(name)


def _reference_task(task: dict) -> str:
    """One reference run of an experiment, written and marked (module-level for pickling)."""
    from gprace.executor import single_thread_blas

    out = Path(task["out"])
    single_thread_blas(_reference_run)(_task_settings(task), out, task["reference"])
    Steps(out).mark(task["reference"])
    return task["reference"]


def _check_start(settings: IterateSettings) -> None:
    """Load track, plant and vehicle, and check the car can start on iteration 0's plan (InputError)."""
    from gprace.model import NominalModel, load_plant, load_vehicle
    from gprace.plan import curvature_plan
    from gprace.timetrial.drive import start_state
    from gprace.tracks import load_track

    track = load_track(settings.track)
    load_plant(settings.plant)
    vehicle = load_vehicle(settings.vehicle)
    model = NominalModel(vehicle)
    if not track.closed:
        raise InputError(f"--track {settings.track}: an open track; the time trial needs a closed lap")
    if settings.delay is None and vehicle.known_delay is not None:
        from gprace.mpc.delay import check
        from gprace.mpc.tracking import MPCSettings

        mpc = MPCSettings()
        check(vehicle.known_delay, mpc.N, mpc.dt, f"--vehicle {settings.vehicle}: actuator_delay + measurement_delay")
    start_state(curvature_plan(track, model, ds=settings.plan_ds, speed_scale=settings.first_speed_scale), track, model.vehicle)


# The two reference runs of the reference controller weaving across the track (``simulate``):
# the held-out test run of the GP errors and coverage, and the calibration run of the GP variance
# (learning.calibrate). Their designs differ (speed, weave, wavelength, seed), so the coverage on
# the held-out run tests the calibration instead of repeating it (docs/decisions.md).
REFERENCE_RUNS = {"heldout": {"speed_scale": 0.8, "weave": "heldout_weave", "wavelength": 120.0, "seed": 7919},
                  "calib": {"speed_scale": 0.9, "weave": "calib_weave", "wavelength": 200.0, "seed": 4243}}


# a reference run that loses the car is driven again this much slower (the reference controller
# plans at the nominal vehicle's limits; on cars with less grip than their papers, or with load
# transfer under braking, 0.8 of them spun the car in the first hairpin and left a test set of 90
# samples); the longest run is kept if none completes
REFERENCE_SLOWER = (1.0, 0.85, 0.7)


def _reference_run(settings: IterateSettings, out: Path, name: str) -> None:
    from gprace.config import SimulateConfig, load_plant
    from gprace.io.runs import write_run
    from gprace.sim import simulate
    from gprace.tracks import load_track

    d = REFERENCE_RUNS[name]
    plant, track = load_plant(settings.plant), load_track(settings.track)
    best = None
    for slower in REFERENCE_SLOWER:
        run = simulate(plant, track, SimulateConfig(laps=settings.heldout_laps, speed_scale=d["speed_scale"] * slower,
                                                    weave_amplitude=getattr(settings, d["weave"]),
                                                    weave_wavelength=d["wavelength"], seed=settings.seed + d["seed"]))
        if best is None or run.n > best.n:
            best = run
        if run.meta["completed"]:
            break
    write_run(best, out / f"{name}.h5")


def run_chain(task: dict) -> list[dict]:
    """One trial: iterations 0..N, each step skipped when its marker exists (module-level for pickling).

    BLAS is limited to one thread per chain: chains run one per core (every timing of
    docs/reference.md#measured was taken that way; several multi-threaded chains on two cores only
    fight over them).
    """
    from gprace.executor import single_thread_blas

    return single_thread_blas(_oracle_task if task.get("oracle") else _run_chain)(task)


def _task_settings(task: dict) -> IterateSettings:
    return IterateSettings(**{k: tuple(v) if isinstance(v, list) else v for k, v in task["settings"].items()})


def _oracle_task(task: dict) -> list[dict]:
    out = Path(task["out"])
    st = _task_settings(task)
    res = oracle_lap(st, out)
    write_json(out / "oracle.json", res)
    Steps(out).mark("oracle")
    return [res]


@dataclass
class _Chain:
    """What every step of one trial's chain of iterations reads: settings, folders, the track, the
    nominal model, the plant, the reference runs (held-out and calibration)."""

    st: IterateSettings
    out: Path
    trial: int
    steps: Steps
    track: Any
    model: Any
    plant: Any
    mpc: Any
    seed: int
    runs: dict  # "heldout" / "calib" -> Run or None
    cap: np.ndarray
    _features: dict = field(default_factory=dict)

    @property
    def folder(self) -> Path:
        return self.out / f"trial_{self.trial}"

    def dir(self, i: int) -> Path:
        return self.folder / f"iter_{i:02d}"

    def tag(self, i: int, name: str) -> str:
        return f"t{self.trial}_i{i}_{name}"

    def record(self, i: int) -> IterationRecord:
        return read_record(self.dir(i) / "record.json")

    @property
    def delay(self) -> float:
        """The total delay the GP iterations predict over [s]: the experiment's, the vehicle's known
        delays, else the shakedown's estimate (0 before iteration 0 is recorded)."""
        d = self.delay_known
        if d is not None:
            return d
        if (self.dir(0) / "record.json").exists():
            est = self.record(0).delay
            return float(est) if np.isfinite(est) else 0.0
        return 0.0

    @property
    def delay_known(self) -> float | None:
        return self.st.delay if self.st.delay is not None else self.model.vehicle.known_delay

    def drive_settings(self, delay: float):
        from gprace.mpc.stability import EnvelopeSettings
        from gprace.timetrial.drive import DriveSettings

        return DriveSettings(laps=self.st.laps, mpc=self.mpc.model_copy(update={"delay": delay}),
                             envelope=EnvelopeSettings(enabled=self.st.envelope))

    def data(self, name: str, kind: str):
        """GP features ``(Z, Y)`` of a reference run (None without it), with the chain's delay."""
        from gprace.timetrial import learning as L

        key = (name, kind, self.delay)
        if key not in self._features:
            run = self.runs[name]
            self._features[key] = (None if run is None else
                                   L.features(run, self.model, self.track, kind, self.st.features, delay=self.delay))
        return self._features[key]

    @property
    def heldout(self) -> dict:
        return {k: self.data("heldout", k) for k in ("tracking", "planning")}

    @property
    def calib(self) -> dict:
        return {k: self.data("calib", k) for k in ("tracking", "planning")}


def _chain(task: dict) -> _Chain:
    from gprace.config import load_plant, load_vehicle
    from gprace.io.runs import read_run
    from gprace.model import NominalModel
    from gprace.mpc.tracking import MPCSettings
    from gprace.timetrial import grip as G
    from gprace.tracks import load_track

    st = _task_settings(task)
    out, j = Path(task["out"]), int(task["trial"])
    track, model = load_track(st.track), NominalModel(load_vehicle(st.vehicle))
    mpc = MPCSettings(solver=st.solver, beta=st.beta, grip=st.grip)
    runs = {"heldout": read_run(out / "heldout.h5"), "calib": read_run(out / "calib.h5") if st.calib_weave > 0 else None}
    return _Chain(st=st, out=out, trial=j, steps=Steps(out), track=track, model=model, plant=load_plant(st.plant),
                  mpc=mpc, seed=st.seed * 1000 + j + 1, runs=runs, cap=G.nominal_cap(model, st.plan_grip))


def _iteration_zero(c: _Chain) -> None:
    """The shakedown (or the nominal model's curvature plan at a fixed share), driven."""
    from gprace.io.runs import write_run
    from gprace.plan import curvature_plan, racing_line, read_plan
    from gprace.timetrial import grip as G
    from gprace.timetrial.drive import drive
    from gprace.timetrial.shakedown import Shakedown, ShakedownSettings

    st, d0 = c.st, c.dir(0)
    what = "shakedown" if st.shakedown else "curvature plan"
    if not c.steps.done(c.tag(0, "drive")):
        console.info(f"iterate: {c.out.name} trial {c.trial} iteration 0 (nominal model): {what}, drive")
    nominal = G.nominal_cap(c.model, 1.0)
    shake = None
    reference = _calibration_samples(c)
    start_delay = c.delay_known if c.delay_known is not None else _delay_before(reference, c.mpc.dt)
    if st.shakedown:
        shake = Shakedown(racing_line(c.track, c.model, st.plan_ds), c.model, nominal,
                          ShakedownSettings(start=st.shakedown_start), c.mpc.dt, delay_known=c.delay_known is not None,
                          delay=start_delay, reference=reference)
    if not c.steps.done(c.tag(0, "plan")):
        if shake is not None:
            p0 = shake.plan()
        else:
            p0 = curvature_plan(c.track, c.model, ds=st.plan_ds, speed_scale=st.first_speed_scale)
            # what the curvature plan used: its lateral and braking limits scaled, the drive limit full
            p0.meta["limits"] = (nominal * [st.first_speed_scale, 1.0, st.first_speed_scale]).tolist()
        p0.write(d0 / "plan_start.h5")
        c.steps.mark(c.tag(0, "plan"))
    if not c.steps.done(c.tag(0, "drive")):
        plan = read_plan(d0 / "plan_start.h5", c.track)
        run = drive(plan, c.plant, c.track, c.model, c.drive_settings(start_delay), seed=c.seed * 100,
                    supervisor=shake)
        extra = {"delay": float("nan"), "delay_source": "known" if c.delay_known is not None else "estimated"}
        if shake is not None:
            plan = shake.plan()  # the limits the car was shown to take
            plan.meta["shakedown"] = shake.log
        if c.delay_known is not None:
            extra["delay"] = float(c.delay_known)
        else:
            from gprace.mpc.delay import estimate
            from gprace.timetrial.learning import in_control

            X = run.states()
            dead, lag = estimate(X, run.inputs(), run.dt, in_control(X), more=reference)
            extra["delay"] = float(min(dead + lag, c.mpc.N * c.mpc.dt)) if np.isfinite(dead) else start_delay
        plan.write(d0 / "plan.h5")
        write_run(run, d0 / "run.h5")
        write_record(d0 / "record.json", _record(0, 0.0, c, plan, run, None, None,
                                                {**_lap_extra(run, c.model), **extra, "plan_source": what}))
        c.steps.mark(c.tag(0, "drive"))


def _calibration_samples(c: _Chain) -> tuple:
    """``((X, U, in-control mask),)`` of the calibration run (the reference controller weaving on
    the same car), or ``()`` without one; the held-out run stays a test set."""
    from gprace.timetrial.learning import in_control

    run = c.runs.get("calib")
    if run is None:
        return ()
    X = run.states()
    return ((X, run.inputs(), in_control(X)),)


def _delay_before(reference: tuple, dt: float) -> float:
    """The delay iteration 0 starts with when none is known: estimated from the calibration run,
    else the shakedown's prior."""
    from gprace.mpc.delay import estimate
    from gprace.timetrial.shakedown import DELAY_PRIOR

    if reference:
        X, U, ok = reference[0]
        dead, lag = estimate(X, U, dt, ok)
        if np.isfinite(dead):
            return float(dead + lag)
    return DELAY_PRIOR


def _select(c: _Chain, i: int) -> None:
    """(1) The last run's samples streamed into each GP's dictionary (hyperparameters fitted once,
    on the first run's data)."""
    from gprace.gp.dataset import loop_dataset, read_dataset, write_dataset
    from gprace.io.runs import read_run
    from gprace.timetrial import learning as L

    st, di, dp, tdir = c.st, c.dir(i), c.dir(i - 1), c.folder
    prev_run = read_run(dp / "run.h5")
    for kind in ("tracking", "planning"):
        Znew, Ynew = L.features(prev_run, c.model, c.track, kind, st.features, delay=c.delay)
        hyper_path = tdir / f"hyper_{kind}.h5"
        if not hyper_path.exists():
            Zh, Yh = Znew, Ynew
            if len(Zh) < MIN_FIT_SAMPLES:
                # a first lap lost at once: the hyperparameters come from the reference runs (the
                # loop goes on and learns from what it has)
                ref = [c.data(name, kind) for name in ("heldout", "calib") if c.runs[name] is not None]
                Zh, Yh = np.vstack([Zh] + [z for z, _ in ref]), np.vstack([Yh] + [y for _, y in ref])
            if len(Zh) < MIN_FIT_SAMPLES:
                raise RunFailedError(f"trial {c.trial}: only {len(Zh)} usable samples in iteration {i - 1} and the "
                                     "reference runs; cannot train the GPs")
            gp0 = L.fit_hyper(Zh, Yh, seed=c.seed, max_fit_points=st.max_fit_points)
            L.save_predictor(hyper_path, gp0, kind, feature_set=st.features)
        hyper = L.load_predictor(hyper_path, kind).gp
        old = None
        if i > 1:
            a = read_dataset(dp / f"data_{kind}.h5")
            old = L.Dictionary(a.Z, a.Y, a.n_seen)
        d, stats = L.update_dictionary(old, Znew, Ynew, st.dictionary_size, st.selection, hyper.hyper_, seed=c.seed + i)
        write_dataset(di / f"data_{kind}.h5", loop_dataset(kind, st.features, d.Z, d.Y,
                                                           {"n_seen": int(d.n_seen), "selection": st.selection, "stats": stats}))


MIN_FIT_SAMPLES = 20  # samples a hyperparameter fit needs


def _retrain(c: _Chain, i: int) -> None:
    """(2) Both GPs on their dictionaries, calibrated; the exploration candidates of the tracking GP
    (only where the iteration explores: alpha > 0)."""
    from gprace.gp.dataset import read_dataset
    from gprace.io.artifacts import Artifact, write_artifact
    from gprace.timetrial import learning as L

    di = c.dir(i)
    for kind in ("tracking", "planning"):
        a = read_dataset(di / f"data_{kind}.h5")
        hyper = L.load_predictor(c.folder / f"hyper_{kind}.h5", kind).gp
        gp = L.refit_fixed(hyper, a.Z, a.Y)
        L.save_predictor(di / f"gp_{kind}.h5", gp, kind, {"iteration": i, "trial": c.trial}, c.st.features,
                         L.calibrate(gp, calib=c.calib[kind]))
        if kind == "tracking" and c.st.alpha(i) > 0:  # alpha = 0 never uses the candidates (issue 37)
            grid = make_grid(gp, a.Z, c.mpc, c.st.grid_values)
            write_artifact(di / "candidates.h5", Artifact("candidates", {"Z": grid.Z, "v": grid.v, "scale": grid.scale}))


def _replan(c: _Chain, i: int) -> None:
    """(3) The minimum-time plan with the planning GP inside the widened friction envelope, driven
    only if predicted safe (:mod:`gprace.timetrial.guard`); after a lost or slower lap it starts
    again from the last good plan and limits."""
    from gprace.plan import PlanSettings, curvature_plan, plan_min_time, read_plan
    from gprace.timetrial import grip as G
    from gprace.timetrial import guard
    from gprace.timetrial import learning as L

    st, track, model = c.st, c.track, c.model
    records = [c.record(k) for k in range(i)]
    rec = records[-1]
    back = st.never_worse and rec.status != "good"
    failed = [r.limits for r in records if not r.completed and r.limits]
    ref = guard.last_good(records) if st.never_worse else None
    if back and ref is not None:
        # a lost or slower lap: the last good plan's limits again (no widening), but never a level
        # that lost the car (measured: a randomized BMW lost at [9.1, 3.5, 4.8] m/s^2 and sent back
        # to the same limits was lost again three iterations later); the data stay
        limits = G.below_failed(records[ref].limits or c.cap, failed, st.widen)
        source = f"back to iteration {ref}" + ("" if G.clear_of(records[ref].limits, failed, st.widen)
                                               else ", below the limits of the lost laps")
    else:
        last = read_plan(c.dir(i - 1) / "plan.h5", track)
        limits = G.next_limits(last.meta.get("limits", c.cap), rec.envelope, rec.completed, rec.utilisation,
                               c.cap, st.widen, failed=failed, border_hits=rec.border_hits,
                               interventions=rec.interventions if i > 1 else 0, widen_max=st.widen_max)
        source = "replan"
        limits[0] = min(limits[0], G.held_level([(r.envelope, r.utilisation) for r in records if r.completed]))
        shown = _grip_shown(c, i)
        if shown is not None:  # never plan corners faster than the grip the car has shown
            limits[0] = min(limits[0], max(shown * G.nominal_cap(model, 1.0)[0], np.asarray(last.meta.get("limits", limits))[0]))
    if st.never_worse:  # the plan started from, and driven again if the new one is unsafe: clear of the lost laps
        ref = guard.last_good(records, clear=lambda lim: G.clear_of(lim, failed, st.widen))
    good = [k for k in range(i - 1, -1, -1) if records[k].completed]
    start = ref if ref is not None else (good[0] if good else None)
    warm = read_plan(c.dir(start) / "plan.h5", track) if start is not None else None
    gp_plan = L.load_predictor(c.dir(i) / "gp_planning.h5", "planning")
    safety: dict = {}
    try:
        # with the guard on, the plan keeps the slip angles the guard holds it to (front at the
        # nominal peak, rear at the tracking MPC's grip bound): the GP compensation, read on the
        # warm start and held fixed, otherwise buys corner speed with steering far past the peak
        slip = guard.slip_bounds(c.mpc.grip_share) if st.never_worse else None
        plan = plan_min_time(track, model, PlanSettings(ds=st.plan_ds, limits=tuple(limits), slip_max=slip),
                             warm=warm or read_plan(c.dir(i - 1) / "plan.h5", track),
                             mu_plan=lambda X, U: gp_plan.at(X, U)[0])
        if st.never_worse:
            check = lambda p: guard.plan_safety(p, model, gp_plan, c.mpc.grip_share)  # noqa: E731
            safety = check(plan)
            if guard.decision(safety) == "step" and warm is not None:
                # refused for novelty alone: the new line, slower, so that data arrive where it goes
                plan, q, after = guard.novelty_step(plan, check, float(warm.lap_time))
                safety = {**safety, "step": q, "novel_step": after["novel"]}
                step = f"new plan driven at {q:.2f} of its speed ({safety['why']})"
                source = f"{source}; {step}" if back else step
            elif not safety["safe"] and warm is not None:
                plan, limits = warm, warm.meta.get("limits", limits)
                plan.meta = {**plan.meta, "unsafe": safety["why"]}
                unsafe = f"last good plan (iteration {start}) driven: the new plan was not predicted safe ({safety['why']})"
                source = f"{source}; {unsafe}" if back else unsafe
        if st.never_worse and plan is not warm:
            plan, q = guard.build_up(plan, _best_driven(records), st.widen_max)
            if q < 1.0:
                safety = {**safety, "step": safety.get("step", 1.0) * q}
                source = f"{source}; built up: driven at {q:.2f} of its speed"
    except SolverError as exc:
        # a failed re-plan must not end the experiment: drive the last plan that completed a
        # lap again (never a plan that failed), or a slower curvature plan if none did
        scale = st.first_speed_scale * (1 - 2 * st.widen)
        plan = warm or curvature_plan(track, model, ds=st.plan_ds, speed_scale=scale)
        # the limits of the plan actually driven, not the ones tried: the next widening
        # starts from what was driven (measured: two widenings at once after a failed
        # re-plan, then a spin at s = 2266 m)
        limits = plan.meta.get("limits", G.nominal_cap(model, 1.0) * [scale, 1.0, scale])
        plan.meta = {**plan.meta, "replan_failed": str(exc)}
        source = "replan failed: the last plan that completed a lap"
    plan.meta["limits"] = [float(v) for v in limits]
    plan.meta["source"] = source
    plan.meta["safety"] = {k: v for k, v in safety.items() if k != "safe"}
    plan.write(c.dir(i) / "plan.h5")


def _best_driven(records) -> float:
    """The best lap driven so far in a trial (any alpha, iteration 0 included; inf before any)."""
    return min((r.driven for r in records if r.completed and r.driven is not None and np.isfinite(r.driven)),
               default=np.inf)


def _grip_shown(c: _Chain, i: int) -> float | None:
    """The weakest axle's grip against the nominal tire (any phase; :func:`gprace.timetrial.
    shakedown.axle_grip`) over the completed laps before iteration ``i``, or None without data.

    Measured on a BMW with a worn rear (grip 0.80): widened by 10 % past the lateral limit this
    caps, the GP plan of iteration 2 spun the car at the hairpin whatever the MPC did (with and
    without GP, exploring or not, with and without the envelope)."""
    from gprace.io.runs import read_run
    from gprace.mpc.delay import blended
    from gprace.timetrial.learning import in_control
    from gprace.timetrial.shakedown import axle_grip

    ratios = []
    for k in range(i):
        if c.record(k).completed:
            run = read_run(c.dir(k) / "run.h5")
            X = run.states()
            g = axle_grip(X, blended(run.inputs(), c.delay, run.dt), run.dt, c.model, in_control(X))
            ratios += list(g.values())
    return float(min(ratios)) if ratios else None


def _band(c: _Chain, i: int):
    """The stability envelope's bands for iteration ``i``: from the last completed lap's clean samples."""
    from gprace.io.runs import read_run
    from gprace.mpc.stability import SIGNALS, EnvelopeSettings, bands
    from gprace.timetrial.learning import in_control

    for k in range(i - 1, -1, -1):
        if c.record(k).completed:
            run = read_run(c.dir(k) / "run.h5")
            if any(name not in run.data for name in SIGNALS):
                return None
            ok = in_control(run.states()) & (run["envelope"] <= 1.0)
            return bands(np.column_stack([run[name][ok] for name in SIGNALS]), EnvelopeSettings())
    return None


def _drive_iteration(c: _Chain, i: int, alpha: float) -> None:
    """(4) The plan driven by the GP-compensated tracking MPC, exploring with weight ``alpha``."""
    from gprace.explore.algorithm import CandidateGrid
    from gprace.gp.dataset import read_dataset
    from gprace.io.artifacts import read_artifact
    from gprace.io.runs import write_run
    from gprace.plan import read_plan
    from gprace.timetrial import learning as L
    from gprace.timetrial.drive import drive

    di = c.dir(i)
    plan = read_plan(di / "plan.h5", c.track)
    gp_track = L.load_predictor(di / "gp_tracking.h5", "tracking")
    a = read_artifact(di / "candidates.h5", "candidates") if alpha > 0 else None
    grid = CandidateGrid(a.arrays["Z"], a.arrays["v"], a.arrays["scale"]) if a is not None else None
    delay = c.delay
    run = drive(plan, c.plant, c.track, c.model, c.drive_settings(delay), gp=gp_track, grid=grid, alpha=alpha,
                seed=c.seed * 100 + i, band=_band(c, i))
    write_run(run, di / "run.h5")
    gps = {k: L.load_predictor(di / f"gp_{k}.h5", k) for k in ("tracking", "planning")}
    sizes = {k: int(read_dataset(di / f"data_{k}.h5").Z.shape[0]) for k in gps}
    extra = {**_lap_extra(run, c.model), "delay": delay,
             "delay_source": "known" if c.delay_known is not None else "estimated",
             "plan_source": plan.meta.get("source", "replan"), "safety": plan.meta.get("safety") or {}}
    write_record(di / "record.json", _record(i, alpha, c, plan, run, gps, sizes, extra))


def _run_chain(task: dict) -> list[dict]:
    """One trial: iteration 0, then per iteration select, retrain, plan, drive; each step once
    (a rerun resumes after the last step marked done)."""
    c = _chain(task)
    _iteration_zero(c)
    for i in range(1, c.st.iterations + 1):
        alpha = c.st.alpha(i)
        if not c.steps.done(c.tag(i, "drive")):
            console.info(f"iterate: {c.out.name} trial {c.trial} iteration {i} (alpha {alpha:g}): select, retrain, "
                         "plan, drive")
        for name, step in (("select", _select), ("retrain", _retrain), ("plan", _replan)):
            if not c.steps.done(c.tag(i, name)):
                step(c, i)
                c.steps.mark(c.tag(i, name))
        if not c.steps.done(c.tag(i, "drive")):
            _drive_iteration(c, i, alpha)
            c.steps.mark(c.tag(i, "drive"))
    return [c.record(i) for i in range(c.st.iterations + 1)]


def make_grid(gp, Z: np.ndarray, mpc, n_values: int):
    """Algorithm 1's candidates from typical values of the data, with ``S``-weighted variances.

    ``S = diag(Q_vy, Q_r)``: the MPC's weights on the two compensated states.
    """
    from gprace.explore.algorithm import CandidateGrid, candidate_grid, weighted_variance

    C = candidate_grid(Z, n_values)
    _, var = gp.predict(C)
    S = np.array([mpc.weights.Q[1], mpc.weights.Q[2]])
    scale = np.maximum(Z.std(axis=0), 1e-9)
    return CandidateGrid(C, weighted_variance(var, S), scale)


def _lap_extra(run, model) -> dict:
    """What the next plan's limits are made from: the measured envelope and the rear-slip use."""
    from gprace.timetrial import grip as G
    from gprace.timetrial.learning import in_control

    return {"envelope": G.envelope(run, in_control).tolist(), "utilisation": G.utilisation(run, model, in_control)}


def _gp_error(pred, data) -> float:
    """RMS prediction error on the held-out run, each output normalised by its spread, averaged."""
    Z, Y = data
    if pred is None or len(Z) == 0:
        return float("nan")
    mean, _ = pred(Z)
    sd = np.maximum(Y.std(axis=0), 1e-12)
    return float(np.mean(np.sqrt(np.mean(((mean - Y) / sd) ** 2, axis=0))))


def _coverage(pred, data) -> float:
    """Smallest share over the outputs of held-out errors inside the predicted 95 % band."""
    from gprace.timetrial.learning import coverage

    Z, Y = data
    if pred is None or len(Z) == 0:
        return float("nan")
    return float(np.min(coverage(pred, Z, Y)))


def _record(i, alpha, c: _Chain, plan, run, gps, sizes, extra) -> IterationRecord:
    from gprace.timetrial.guard import lap_status

    m, H, trial = run.meta, c.heldout, c.trial
    rec = {
        "iteration": i, "trial": trial, "alpha": alpha, "planned": float(plan.lap_time),
        "driven": float(m["lap_time"]), "completed": bool(m["completed"]), "reason": m.get("reason", ""),
        "gap": float(m["lap_time"] - plan.lap_time), "solve_median_ms": 1e3 * m["solve_time_median"],
        "solve_p99_ms": 1e3 * m["solve_time_p99"], "border_hits": int(m["border_hit_steps"]), "fallbacks": int(m["fallbacks"]),
        "samples": int(run.n), "replan_failed": bool(plan.meta.get("replan_failed")),
    }
    for k in ("tracking", "planning"):
        rec[f"err_{k}"] = _gp_error(gps[k] if gps else None, H[k])
        rec[f"dict_{k}"] = int(sizes[k]) if sizes else 0
        rec[f"cov_{k}"] = _coverage(gps[k] if gps else None, H[k])
    rec["limits"] = [float(v) for v in plan.meta.get("limits", [])]
    rec["interventions"] = int(m.get("interventions", 0))
    rec["eased_steps"] = int(m.get("eased_steps", 0))
    rec["band"] = [float(v) for v in m.get("band", [])]
    draft = IterationRecord(**rec, **extra)
    return draft.model_copy(update={"status": lap_status(draft, [c.record(k) for k in range(i)], c.st.slower_tolerance)})
