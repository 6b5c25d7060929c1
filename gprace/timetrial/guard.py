"""The loop never makes the car worse: lap status, the way back, and a plan's predicted safety.

* **Status of a lap** (:func:`lap_status`): ``lost`` (not completed), ``slower`` (a racing lap,
  alpha 0, slower than the best completed alpha-0 lap so far, iteration 0 included, by more than a
  tolerance) or ``good``. Exploration laps (alpha > 0) are meant to be slower; they are judged only
  by whether they were completed.
* **The way back** (:func:`last_good`): after a lost or slower lap the next iteration re-plans from
  the last good lap's plan and limits (no widening), with all data kept: the GPs have learned from
  the bad lap too. A level that lost the car is not driven again: the way back stays below every
  lost lap's limits (:func:`gprace.timetrial.grip.below_failed`), and the plan it starts from (and
  drives again when the new one is not predicted safe) is the last good one clear of them.
* **Predicted safe** (:func:`plan_safety`): a GP plan is driven only if the models the loop has
  (the nominal model with the planning GP's compensation, the tracking MPC's grip bound) predict
  that it is drivable:

  - the rear slip angle it asks for stays within the tracking MPC's grip bound (``grip_share`` of
    the nominal tire's peak slip angle) and the front one below the nominal peak: beyond them the
    MPC cannot follow the plan without its slack;
  - it stays where the planning GP has data: at most ``novel_share`` of its nodes may have a
    calibrated predictive std of the lateral-acceleration compensation above ``novel_std`` times the
    GP's noise std (a plan that leans on an extrapolated compensation is a guess).

  The loop's planner is held to the same slip angles (:func:`slip_bounds`, as NLP constraints),
  so its plans meet them by construction, up to the solver's tolerance (``SLIP_TOLERANCE``): a
  compensation read on the warm start and held fixed otherwise bought corner speed with steering
  far past the peak, and the same refusal repeated for ever (README job, docs/decisions.md issue
  37 stop 45; halving the widening after each refusal, tried at stop 44, could not help, since the
  limits were not the cause).

  What is driven instead depends on why (:func:`decision`). A plan the slip angles refuse sends
  the loop back: the last good plan is driven again (its limits too), and the record says why. A
  plan refused **for novelty alone** is driven slower (:func:`novelty_step`): the same plan in
  time scaled by the largest factor ``q`` at which it stays where the GP has data, never slower
  than the last good lap. Driving the last good plan again never brings data where the wider plan
  goes, so a refusal for novelty alone would repeat for ever (measured on commonroad_std: five
  iterations at iteration 0's plan); the slower lap on the new line does bring them. Such a lap
  is judged like an exploration lap, by whether it was completed (:func:`lap_status`).

* **Build-up** (:func:`build_up`): a new plan is never driven faster than the best lap driven so
  far allows: its lap time at least that lap's over ``sqrt(1 + widen_max)``, the pace that the
  widest widening of the friction ellipse gives (accelerations scale with the speed squared).
  Faster plans are driven time-scaled on their own line, like a novelty step. The widening works on
  the 99th percentile of what the car showed, but a shakedown lap eased most of its corners: on
  the unseen plants, the first GP plan after one asked for 16 to 19 % less lap time than the lap
  driven (80.3 -> 67.8 s, 81.3 -> 68.8 s), slid at the first braking zone it met faster than before
  and lost the car (randomized_21, commonroad_mb); re-driven at 0.905 of their speed (the
  build-up's factor), both laps complete (docs/decisions.md issue 37 stop 46).

Pure functions over arrays; the iterate loop calls them.
"""

from __future__ import annotations

import numpy as np

NOVEL_STD = 3.0     # predictive std over the GP's noise std above which a plan node counts as novel
NOVEL_SHARE = 0.1   # largest share of novel nodes in a plan that is driven
SLIP_TOLERANCE = 1e-3  # a slip angle within this share above its bound counts as at the bound (solver tolerance)


def slip_bounds(grip_share: float) -> tuple[float, float]:
    """``(front, rear)`` slip bounds of a plan as shares of the nominal tires' peak slip angles: the
    front at its peak, the rear at the tracking MPC's grip bound (what :func:`plan_safety` checks)."""
    return 1.0, grip_share


def speed_step(record) -> float:
    """The speed factor a record's plan was driven at (a build-up or novelty step; 1 at full speed)."""
    return float((record.get("safety") or {}).get("step", 1.0))


def lap_status(record, earlier: list, tolerance: float) -> str:
    """``good``, ``lost`` or ``slower`` for ``record`` given the ``earlier`` records of its trial.

    Records are read by key: the time trial's :class:`~gprace.timetrial.record.IterationRecord`
    (read-only keys) and ``gprace learn``'s lap dicts both are."""
    if not record["completed"]:
        return "lost"
    if record["alpha"] != 0.0 or speed_step(record) < 1.0:
        return "good"  # exploring, or a novelty step (a slower lap on purpose): judged by completion
    best = [r["driven"] for r in earlier if r["completed"] and r["alpha"] == 0.0 and np.isfinite(r["driven"])]
    if best and record["driven"] > min(best) * (1.0 + tolerance):
        return "slower"
    return "good"


def last_good(records: list, clear=None) -> int | None:
    """Index of the last record whose lap was good (None if none was); with ``clear`` (a predicate
    on a record's ``limits``) the last good one whose limits it accepts, else the last good one."""
    good = [k for k, r in enumerate(records) if r.get("status", "good" if r["completed"] else "lost") == "good"]
    if clear is not None:
        safe = [k for k in good if clear(records[k].get("limits"))]
        if safe:
            return safe[-1]
    return good[-1] if good else None


def plan_safety(plan, model, gp_plan=None, grip_share: float = 0.9, novel_std: float = NOVEL_STD,
                novel_share: float = NOVEL_SHARE) -> dict:
    """``{"safe": bool, "why": str, "slip_rear", "slip_front", "novel"}`` of a plan (vectorised over its nodes).

    ``slip_*`` are the plan's robust peak slip angles over their bounds (1 = at the bound),
    ``novel`` the share of nodes where the planning GP extrapolates.
    """
    from gprace.timetrial.grip import front_use, rear_use

    X, U = plan.states(), plan.inputs()
    front, rear = slip_bounds(grip_share)
    slip_rear = float(np.quantile(rear_use(X, model), 0.99) / rear)
    slip_front = float(np.quantile(front_use(X, U, model), 0.99) / front)
    novel = 0.0
    if gp_plan is not None:
        novel = float(np.mean(gp_plan.novelty(X, U) > novel_std))
    why = []
    if slip_rear > 1.0 + SLIP_TOLERANCE:
        why.append(f"rear slip {slip_rear:.2f} of the MPC's bound")
    if slip_front > 1.0 + SLIP_TOLERANCE:
        why.append(f"front slip {slip_front:.2f} of the nominal peak")
    if novel > novel_share:
        why.append(f"{100 * novel:.0f} % of the plan where the planning GP has no data")
    return {"safe": not why, "why": "; ".join(why), "slip_rear": slip_rear, "slip_front": slip_front, "novel": novel}


def decision(safety: dict) -> str:
    """What to drive for a plan of :func:`plan_safety`: ``drive`` (predicted safe), ``step`` (refused
    only because the planning GP has no data along part of it: drive it slower, :func:`novelty_step`)
    or ``back`` (its slip angles are beyond what the tracking MPC can follow: the last good plan)."""
    if safety.get("safe", True):
        return "drive"
    if max(safety.get("slip_rear", 0.0), safety.get("slip_front", 0.0)) <= 1.0 + SLIP_TOLERANCE:
        return "step"
    return "back"


def time_scaled(plan, q: float):
    """``plan`` run ``q`` times as fast along the same line (speeds and yaw rate times ``q``, the
    longitudinal acceleration times ``q^2``, times over ``q``): the scaling the stability envelope
    eases the reference with."""
    from dataclasses import replace

    return replace(plan, v_x=q * plan.v_x, v_y=q * plan.v_y, yaw_rate=q * plan.yaw_rate, a_x=q * q * plan.a_x,
                   t=plan.t / q, lap_time=plan.lap_time / q, meta={**plan.meta, "time_scale": float(q)})


def novelty_step(plan, check, floor_lap_time: float, novel_share: float = NOVEL_SHARE, step: float = 0.02):
    """``(scaled plan, q, its safety)``: the plan at the largest speed factor ``q`` (from 1 down in
    steps of ``step``) whose share of novel nodes, by ``check(plan) -> plan_safety dict``, is at
    most ``novel_share``, and never slower than ``floor_lap_time`` (the last good plan's lap: at
    that pace the lap is still driven when novelty remains, to bring data along the new line)."""
    q_floor = min(1.0, plan.lap_time / floor_lap_time) if floor_lap_time > 0 else 1.0
    qs = np.arange(1.0 - step, q_floor, -step)
    for q in [*qs, q_floor]:
        scaled = time_scaled(plan, float(q))
        safety = check(scaled)
        if safety["novel"] <= novel_share or q == q_floor:
            return scaled, float(q), safety
    raise AssertionError("unreachable")


def build_up(plan, best_driven: float, widen_max: float):
    """``(plan, q)``: ``plan`` time-scaled by the largest ``q <= 1`` at which its lap time is at
    least ``best_driven / sqrt(1 + widen_max)`` (module docstring); ``q = 1`` when it already is,
    or when no lap has been driven (``best_driven`` not finite)."""
    floor = best_driven / np.sqrt(1.0 + widen_max)
    if not np.isfinite(floor) or plan.lap_time >= floor:
        return plan, 1.0
    q = float(plan.lap_time / floor)
    return time_scaled(plan, q), q
