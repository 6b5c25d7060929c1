"""The paper's loop through files only, against the built-in loop (issue 39, "How we will know").

A hidden-effects plant is driven through files, ``--rounds`` times in a row:

1. ``gprace run`` drives a lap (round 0: the nominal curvature plan at 0.7 of the model's limits,
   as ``iterate``'s iteration 0 without the shakedown; round k: the TUM raceline of learn's
   iteration k with its tracking GP), with the plant seed ``iterate``'s trial 0 uses in iteration k;
2. the run is exported to a global-frame CSV by code of this script (the centre line sampled
   every 5 cm and interpolated, ``x = c + e_y n``, ``yaw = heading + e_psi``: a logger's file, not
   gprace's);
3. ``gprace learn`` imports that CSV, retrains, re-plans and writes the next TUM raceline;
4. back to 1 with the raceline.

Then ``iterate`` runs the same plant, track and seeds (one trial, ``--rounds`` iterations, alpha
0) with what the file loop's controller has: iteration 0 the curvature plan at 0.7 (no
shakedown), the vehicle's delay (none estimated) (``BUILTIN``; the never-worse guard on in both;
the stability envelope is on in both, ``run`` learns its band inside the lap, ``iterate`` from the
last lap); learn gets iterate's seeds and, in round 0, the plan the car drove (``--driven``: the
widening starts from its limits); the table compares laps and GP errors (normalised RMS on
iterate's held-out weaving run, for both loops' GPs). Prints JSON. Tens of minutes on a 2-core
machine; run with ``nice``; the two loops can run as two processes (``--no-iterate`` and
``--iterate-only``), and a last call without either prints the table from their files::

    nice python benchmarks/learn_loop.py --out /tmp/learn_loop [--track PATH] [--plant audi_hidden] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from shared_data import TUM_TRACKS  # noqa: E402


def export_global(run_path: Path, track, csv: Path) -> None:
    """A run in the global frame as a logger writes it: t, x, y, yaw and the body channels."""
    from gprace.io.runs import read_run

    run = read_run(run_path)
    smp = track.sample(0.05)
    sp = np.append(smp.s, track.length)
    sw = np.mod(run["s"], track.length)
    cx = np.interp(sw, sp, np.append(smp.x, smp.x[0]))
    cy = np.interp(sw, sp, np.append(smp.y, smp.y[0]))
    h = np.interp(sw, sp, np.append(smp.heading, smp.heading[0] + 2 * np.pi * np.sign(smp.heading[-1] - smp.heading[0])))
    cols = {"t": run["t"], "x": cx - np.sin(h) * run["e_y"], "y": cy + np.cos(h) * run["e_y"],
            "yaw": np.angle(np.exp(1j * (h + run["e_psi"]))),
            **{k: run[k] for k in ("v_x", "v_y", "yaw_rate", "delta", "a_x")}}
    np.savetxt(csv, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="", fmt="%.10g")


def gprace(*args: str) -> dict:
    """One gprace command with --json; its result (exit 1, a failed lap, is data)."""
    cmd = [sys.executable, "-m", "gprace.cli", *args, "--json"]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(args[:2])} failed ({p.returncode}): {p.stderr.strip().splitlines()[-1]}")
    try:
        return json.loads(p.stdout)
    except json.JSONDecodeError:
        return {"error": p.stderr.strip().splitlines()[-1] if p.stderr.strip() else "no output"}


def gp_error(pred, Z, Y) -> tuple[float, float]:
    """iterate's held-out metric (RMS per output over its std, averaged) and the worst 95 % coverage."""
    from gprace.timetrial.learning import coverage

    mean, _ = pred(Z)
    sd = np.maximum(Y.std(axis=0), 1e-12)
    return float(np.mean(np.sqrt(np.mean(((mean - Y) / sd) ** 2, axis=0)))), float(np.min(coverage(pred, Z, Y)))


BUILTIN = {"shakedown": False, "delay": 0.0, "oracle": False}
"""iterate's settings that give it the file loop's controller (``run`` with a plan and a GP); the
never-worse guard is on in both (learn applies iterate's rules, ``--never-worse``)."""


def builtin_loop(a, out: Path) -> dict:
    """iterate with one trial, alpha 0, ``BUILTIN``; its summary (resumes from ``out``)."""
    from gprace.timetrial.iterate import IterateSettings, iterate

    st = IterateSettings(alphas=(0.0,), iterations=a.rounds, trials=1, plant=a.plant, track=a.track, vehicle=a.vehicle,
                         seed=a.seed, **BUILTIN)
    return iterate(st, out, workers=1)


def replay(a) -> dict:
    """learn on iterate's laps: iteration k's lap exported (as in the file loop) and learned; the
    limits, plan and GP errors of learn's iteration k + 1 next to iterate's iteration k + 1."""
    from gprace.config import load_vehicle
    from gprace.io.runs import read_run
    from gprace.model import NominalModel
    from gprace.timetrial.learning import features, load_predictor
    from gprace.tracks import load_track

    track, model = load_track(a.track), NominalModel(load_vehicle(a.vehicle))
    it, out = a.out / "iterate" / "trial_0", a.out / "replay"
    out.mkdir(parents=True, exist_ok=True)
    held = read_run(a.out / "iterate" / "heldout.h5")
    H = {kind: features(held, model, track, kind, "full") for kind in ("tracking", "planning")}
    rows = []
    for k in range(a.rounds):
        csv = out / f"log{k}.csv"
        if not csv.exists():
            export_global(it / f"iter_{k:02d}" / "run.h5", track, csv)
        driven = ["--driven", str(it / "iter_00" / "plan.h5")] if k == 0 else []
        res = gprace("learn", str(csv), "--track", a.track, "--vehicle", a.vehicle, "--out", str(out / "learn"), "--dt",
                     "0.05", "--seed", str(a.seed * 1000 + 1), *driven)
        i = json.loads((it / f"iter_{k + 1:02d}" / "record.json").read_text())
        row = {"iteration": k + 1, "learn_limits": res.get("plan", {}).get("limits"), "iterate_limits": i["limits"],
               "learn_planned": res.get("plan", {}).get("planned_lap_time"), "iterate_planned": i["planned"],
               "learn_unsafe": res.get("plan", {}).get("unsafe"), "iterate_source": i.get("plan_source"),
               "iterate_err_tracking": i["err_tracking"], "iterate_err_planning": i["err_planning"]}
        d = out / "learn" / f"iter_{k + 1:02d}"
        for kind in ("tracking", "planning"):
            row[f"learn_err_{kind}"], row[f"learn_cov_{kind}"] = gp_error(load_predictor(d / f"gp_{kind}.h5", kind), *H[kind])
        rows.append(row)
    return {"replay": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--track", default=str(TUM_TRACKS / "Norisring.csv"))
    ap.add_argument("--plant", default="audi_hidden")
    ap.add_argument("--vehicle", default="audi_tt_cup")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-iterate", action="store_true", help="the file loop only")
    ap.add_argument("--iterate-only", action="store_true", help="the built-in loop only")
    ap.add_argument("--replay", action="store_true", help="learn on iterate's own laps (after --iterate-only): "
                    "the same data in both, so what differs is learn's logic and the import, not the laps driven")
    a = ap.parse_args()
    if a.replay:
        print(json.dumps(replay(a), indent=1))
        return
    if a.iterate_only:
        a.out.mkdir(parents=True, exist_ok=True)
        builtin_loop(a, a.out / "iterate")
        return

    from gprace.config import load_vehicle
    from gprace.io.runs import read_run
    from gprace.model import NominalModel
    from gprace.plan import curvature_plan
    from gprace.timetrial import grip as G
    from gprace.timetrial.learning import features, load_predictor
    from gprace.tracks import load_track

    out = a.out
    out.mkdir(parents=True, exist_ok=True)
    track = load_track(a.track)
    model = NominalModel(load_vehicle(a.vehicle))
    common = ["--track", a.track, "--vehicle", a.vehicle]
    t0 = time.perf_counter()
    rows = []
    # round 0: iterate's iteration 0 (curvature plan at 0.7 of the nominal limits), driven by run
    p0 = out / "plan0.h5"
    if not p0.exists():
        plan = curvature_plan(track, model, ds=6.0, speed_scale=0.7)
        plan.meta["limits"] = (G.nominal_cap(model, 1.0) * [0.7, 1.0, 0.7]).tolist()
        plan.write(p0)
    plan_file = p0
    for k in range(a.rounds + 1):
        run_k = out / f"run{k}.h5"
        if not run_k.exists():
            extra = ["--model", str(out / "learn" / f"iter_{k:02d}" / "gp_tracking.h5")] if k else []
            # iterate's trial 0 drives iteration k with plant seed (1000 seed + 1) 100 + k
            gprace("run", "--plan", str(plan_file), *common, "--plant", a.plant, "--seed", str((a.seed * 1000 + 1) * 100 + k),
                   "-o", str(run_k), *extra)
        r = read_run(run_k).meta
        rows.append({"round": k, "plan": str(plan_file.name), "planned": r["planned_lap_time"], "driven": r["lap_time"],
                     "completed": r["completed"], "reason": r.get("reason", ""), "border_hits": r["border_hit_steps"]})
        if k == a.rounds:
            break
        csv = out / f"log{k}.csv"
        if not csv.exists():
            export_global(run_k, track, csv)
        # the seed of iterate's trial 0 (its hyperparameter fit and selection); round 0 names the
        # plan it drove (its limits start the widening, as iterate's iteration 0 plan)
        driven = ["--driven", str(p0)] if k == 0 else []
        res = gprace("learn", str(csv), *common, "--out", str(out / "learn"), "--dt", "0.05", "--seed",
                     str(a.seed * 1000 + 1), *driven)
        rows[-1]["learn_planned"] = res.get("plan", {}).get("planned_lap_time")
        rows[-1]["learn_replan_failed"] = res.get("plan", {}).get("replan_failed")
        rows[-1]["learn_warm_start"] = res.get("plan", {}).get("warm_start")
        plan_file = out / "learn" / f"iter_{k + 1:02d}" / "raceline_tum.csv"
    table = {"file_loop": rows, "seconds_file_loop": time.perf_counter() - t0}
    if not a.no_iterate:
        t1 = time.perf_counter()
        summ = builtin_loop(a, out / "iterate")
        table["seconds_iterate"] = time.perf_counter() - t1
        it = {r["iteration"]: r for r in summ.get("rows", [])}
        held = read_run(out / "iterate" / "heldout.h5")
        H = {kind: features(held, model, track, kind, "full") for kind in ("tracking", "planning")}
        for row in rows:
            k = row["round"]
            i = it.get(k, {})
            row.update({"iterate_planned": i.get("planned"), "iterate_driven": i.get("driven"),
                        "iterate_completed": i.get("completed"), "iterate_err_tracking": i.get("err_tracking"),
                        "iterate_err_planning": i.get("err_planning"), "iterate_cov_tracking": i.get("cov_tracking")})
            if k:
                d = out / "learn" / f"iter_{k:02d}"
                for kind in ("tracking", "planning"):
                    e, c = gp_error(load_predictor(d / f"gp_{kind}.h5", kind), *H[kind])
                    row[f"learn_err_{kind}"], row[f"learn_cov_{kind}"] = e, c
    print(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
