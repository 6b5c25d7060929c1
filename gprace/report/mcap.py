"""``run --mcap`` and ``iterate --mcap``: a plan and its run, or every lap of an iterate folder,
gathered with the tracking GP's band and written by :func:`gprace.io.foxglove.write_runs`."""

from __future__ import annotations

from pathlib import Path

from gprace.io.foxglove import write_runs


def write_plan_run(path, track, plan, run, model=None, gp=None, dt: float = 0.05, horizon: int = 15,
                   notes=()) -> Path:
    """``run --mcap``: the track, the plan driven (with the tracking GP's band when ``gp`` drove
    it) and the run."""
    from gprace.learn.predict import plan_along

    along, band = plan_along(plan, track, model, gp, dt, horizon, plan.meta.get("limits"))
    return write_runs(path, track, {"run": run}, {"plan": (plan, along, band)}, notes)

def write_iterate(out, path) -> Path:
    """``iterate --mcap``: every finished lap of an iterate folder (``trial_<j>/iter_<i>``: plan,
    run, the band of its tracking GP from iteration 1 on) and the oracle lap, with the track."""
    import json

    from gprace.model import load_vehicle
    from gprace.io.runs import read_run
    from gprace.learn.predict import plan_along
    from gprace.model import NominalModel
    from gprace.mpc.tracking import MPCSettings
    from gprace.plan import read_plan
    from gprace.timetrial.learning import load_predictor
    from gprace.timetrial.record import read_record
    from gprace.tracks import load_track

    out = Path(out)
    st = json.loads((out / "settings.json").read_text())
    track, model, mpc = load_track(st["track"]), NominalModel(load_vehicle(st["vehicle"])), MPCSettings()
    plans, runs, notes = {}, {}, [f"gprace iterate {out}: plant {st['plant']}, track {track.name}"]
    for rec_path in sorted(out.glob("trial_*/iter_*/record.json")):
        d = rec_path.parent
        if not (d / "run.h5").exists():
            continue
        rec = read_record(rec_path)
        name = f"{d.parent.name}/{d.name}"
        plan = read_plan(d / "plan.h5", track)
        gp = load_predictor(d / "gp_tracking.h5", "tracking") if (d / "gp_tracking.h5").exists() else None
        along, band = plan_along(plan, track, model, gp, mpc.dt, mpc.N, rec.limits or None)
        plans[name], runs[name] = (plan, along, band), read_run(d / "run.h5")
        notes.append(f"{name}: alpha {rec.alpha:g}, planned {rec.planned:.3f} s, driven {rec.driven:.3f} s"
                     + ("" if rec.completed else f" (lost: {rec.reason or 'not completed'})"))
    if (out / "oracle_plan.h5").exists() and (out / "oracle_run.h5").exists():
        oracle = read_plan(out / "oracle_plan.h5", track)
        plans["oracle"] = (oracle, plan_along(oracle, track)[0], None)
        runs["oracle"] = read_run(out / "oracle_run.h5")
    return write_runs(path, track, runs, plans, notes)
