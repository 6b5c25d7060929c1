"""The experiment's data: the reference runs (held-out and calibration, shared between experiments)
and step (1) of an iteration, the last lap's samples streamed into each GP's dictionary."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gprace.errors import RunFailedError
from gprace.timetrial.iterate.chain import Steps, _Chain, _task_settings
from gprace.timetrial.iterate.settings import IterateSettings


def _shares_references(a: IterateSettings, b: IterateSettings) -> bool:
    keys = ("plant", "track", "vehicle", "seed", "heldout_laps", "heldout_weave", "calib_weave", "plan_ds", "laps", "solver", "beta", "grip")
    return all(getattr(a, k) == getattr(b, k) for k in keys)


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
# ... and further down this ladder while the longest run is too short to estimate the delay from
# (a car with 0.18 s of delay spins on the Nürburgring's first braking from 60 m/s at 0.7; the
# speed scale lowers the straight's speed only through its braking limit, so the ladder goes down
# to 0.22: docs/decisions.md, issue 37, stop 69)
REFERENCE_SLOWEST = (0.5, 0.33, 0.22)


def _delay_of(run) -> float:
    """The delay (dead time + lag) [s] estimated from a reference run, NaN when it is too short."""
    from gprace.mpc.delay import estimate
    from gprace.timetrial.learning import in_control

    X = run.states()
    dead, lag = estimate(X, run.inputs(), run.meta["dt"], in_control(X))
    return float(dead + lag)


def _reference_run(settings: IterateSettings, out: Path, name: str) -> None:
    from gprace.config import SimulateConfig, load_plant
    from gprace.io.runs import write_run
    from gprace.sim import simulate
    from gprace.tracks import load_track

    d = REFERENCE_RUNS[name]
    plant, track = load_plant(settings.plant), load_track(settings.track)
    best = None
    for k, slower in enumerate(REFERENCE_SLOWER + REFERENCE_SLOWEST):
        if k >= len(REFERENCE_SLOWER) and np.isfinite(_delay_of(best)):
            break
        run = simulate(plant, track, SimulateConfig(laps=settings.heldout_laps, speed_scale=d["speed_scale"] * slower,
                                                    weave_amplitude=getattr(settings, d["weave"]),
                                                    weave_wavelength=d["wavelength"], seed=settings.seed + d["seed"]))
        if best is None or run.n > best.n:
            best = run
        if run.meta["completed"]:
            break
    write_run(best, out / f"{name}.h5")


def _calibration_samples(c: _Chain) -> tuple:
    """``((X, U, in-control mask),)`` of the calibration run (the reference controller weaving on
    the same car), or ``()`` without one; the held-out run stays a test set. (Its samples past a
    tire's peak stay: :func:`gprace.timetrial.grip.below_peak` is for the loop's own laps,
    docs/decisions.md, issue 37, stop 50.)"""
    from gprace.timetrial.learning import in_control

    run = c.runs.get("calib")
    if run is None:
        return ()
    X = run.states()
    return ((X, run.inputs(), in_control(X)),)


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
