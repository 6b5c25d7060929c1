"""Step (3) of an iteration: the minimum-time plan with the planning GP inside the widened
friction envelope, checked by the guard before it is driven."""

from __future__ import annotations

import numpy as np

from gprace.errors import SolverError
from gprace.timetrial.iterate.chain import _Chain


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
        eased = rec.envelope_events if i > 1 else 0  # the shakedown's own envelope is not the plan's
        asked = G.driven_limits(last.meta.get("limits", c.cap), guard.speed_step(rec), rec.alpha, eased)
        limits = G.next_limits(asked, rec.envelope, rec.completed, rec.utilisation,
                               c.cap, st.widen, failed=failed, border_hits=rec.border_hits,
                               interventions=eased, widen_max=st.widen_max,
                               shape=model.params.cr)
        source = "replan"
        limits[0] = min(limits[0], G.held_level([(r.envelope, r.utilisation, r.limits, guard.speed_step(r))
                                                 for r in records if r.completed]),
                        G.slid_level([(r.envelope, r.utilisation, r.limits, guard.speed_step(r), r.envelope_events)
                                      for r in records if r.completed], st.widen),
                        G.eased_level([(r.limits, guard.speed_step(r), r.alpha, r.envelope_events)
                                       for r in records[1:] if r.completed]))  # the laps after the shakedown
        shown = _grip_shown(c, i)
        if shown is not None:  # never plan corners faster than the grip the car has shown
            over = G.overshoot([(r.envelope, r.limits, guard.speed_step(r)) for r in records if r.completed])
            limits[0] = min(limits[0], G.shown_limit(shown, G.nominal_cap(model, 1.0)[0], over,
                                                     np.asarray(last.meta.get("limits", limits))[0]))
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
        plan = plan_min_time(track, model, PlanSettings(ds=st.plan_ds, limits=tuple(limits), slip_max=slip,
                                                             barrier="adaptive"),
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
            plan, safety, source = _built_up(plan, safety, source, records, st.widen_max)
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


def _built_up(plan, safety: dict, source: str, records, widen_max: float):
    """``(plan, safety, source)`` with the plan held to the build-up from the best lap driven so far
    in the trial (any alpha, iteration 0 included; :func:`gprace.timetrial.guard.build_up`); a
    time-scaled plan is a slower lap on purpose (``safety["step"]``, judged by completion)."""
    from gprace.timetrial import guard

    best = min((r.driven for r in records if r.completed and r.driven is not None and np.isfinite(r.driven)),
               default=np.inf)
    plan, q = guard.build_up(plan, best, widen_max)
    if q < 1.0:
        safety = {**safety, "step": safety.get("step", 1.0) * q}
        source = f"{source}; built up: driven at {q:.2f} of its speed"
    return plan, safety, source


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
