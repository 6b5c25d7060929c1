"""The laps: iteration 0 (the shakedown or the curvature plan, with the delay it starts from) and
step (4) of an iteration, the plan driven by the GP-compensated tracking MPC."""

from __future__ import annotations

import numpy as np

from gprace.console import console
from gprace.timetrial.iterate.chain import _Chain
from gprace.timetrial.iterate.data import _calibration_samples, _delay_of
from gprace.timetrial.iterate.evaluation import _lap_extra, _record
from gprace.timetrial.record import write_record


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
    start_delay = c.delay_known if c.delay_known is not None else _delay_before(c.runs.get("calib"))
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
                    supervisor=shake, sensors=c.sensors)
        extra = {"delay": float("nan"), "delay_source": "known" if c.delay_known is not None else "estimated"}
        if c.sensors is not None and not c.sensors.identity:
            extra["sensors"] = c.sensors.as_dict()
            console.info(f"iterate: {c.out.name} trial {c.trial}: the reference run reads a yaw-rate bias of "
                         f"{c.sensors.yaw_rate_bias:+.4f} rad/s and a velocity frame turned by "
                         f"{c.sensors.velocity_angle:+.4f} rad; every lap is corrected by them")
        if shake is not None:
            plan = shake.plan()  # the limits the car was shown to take
            plan.meta["shakedown"] = shake.log
        if c.delay_known is not None:
            extra["delay"] = float(c.delay_known)
        else:
            from gprace.mpc.delay import estimate
            from gprace.timetrial.learning import in_control

            X, U = run.states(), run.inputs()
            dead, lag = estimate(X, U, run.dt, in_control(X) & G.below_peak(X, U, c.model), more=reference)
            extra["delay"] = float(min(dead + lag, c.mpc.N * c.mpc.dt)) if np.isfinite(dead) else start_delay
        plan.write(d0 / "plan.h5")
        write_run(run, d0 / "run.h5")
        write_record(d0 / "record.json", _record(0, 0.0, c, plan, run, None, None,
                                                {**_lap_extra(run, c.model), **extra, "plan_source": what}))
        c.steps.mark(c.tag(0, "drive"))


def _delay_before(calib) -> float:
    """The delay iteration 0 starts with when none is known: estimated from the calibration run
    (``None`` without one), else the shakedown's prior."""
    from gprace.timetrial.shakedown import DELAY_PRIOR

    delay = _delay_of(calib) if calib is not None else float("nan")
    return delay if np.isfinite(delay) else DELAY_PRIOR


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


def drive_lap(c: _Chain, i: int, alpha: float, seed: int | None = None, plan=None):
    """Iteration ``i``'s plan (read from its folder unless given) driven by the GP-compensated
    tracking MPC, exploring with weight ``alpha``, with the iteration's own GP, candidates and
    envelope band: the run. ``seed`` (the sensor noise) defaults to the iteration's own; another one
    drives the same lap on a new draw (``benchmarks/timetrial_redrive.py``)."""
    from gprace.explore.algorithm import CandidateGrid
    from gprace.io.artifacts import read_artifact
    from gprace.plan import read_plan
    from gprace.timetrial import learning as L
    from gprace.timetrial.drive import drive

    di = c.dir(i)
    plan = plan if plan is not None else read_plan(di / "plan.h5", c.track)
    gp_track = L.load_predictor(di / "gp_tracking.h5", "tracking")
    a = read_artifact(di / "candidates.h5", "candidates") if alpha > 0 else None
    grid = CandidateGrid(a.arrays["Z"], a.arrays["v"], a.arrays["scale"]) if a is not None else None
    return drive(plan, c.plant, c.track, c.model, c.drive_settings(c.delay), gp=gp_track, grid=grid, alpha=alpha,
                 seed=c.seed * 100 + i if seed is None else seed, band=_band(c, i), sensors=c.sensors)


def _drive_iteration(c: _Chain, i: int, alpha: float) -> None:
    """(4) The plan driven by the GP-compensated tracking MPC, exploring with weight ``alpha``."""
    from gprace.gp.dataset import read_dataset
    from gprace.io.runs import write_run
    from gprace.plan import read_plan
    from gprace.timetrial import learning as L

    di = c.dir(i)
    plan = read_plan(di / "plan.h5", c.track)
    delay = c.delay
    run = drive_lap(c, i, alpha, plan=plan)
    write_run(run, di / "run.h5")
    gps = {k: L.load_predictor(di / f"gp_{k}.h5", k) for k in ("tracking", "planning")}
    sizes = {k: int(read_dataset(di / f"data_{k}.h5").Z.shape[0]) for k in gps}
    extra = {**_lap_extra(run, c.model), "delay": delay,
             "delay_source": "known" if c.delay_known is not None else "estimated",
             "plan_source": plan.meta.get("source", "replan"), "safety": plan.meta.get("safety") or {}}
    write_record(di / "record.json", _record(i, alpha, c, plan, run, gps, sizes, extra))
