"""Blind recovery benchmark of ``gprace diagnose`` (issue 6, "Prove it").

Concealed-effect recordings from the ``frenet`` plant (every catalogue effect at several realistic
magnitudes, random real circuits from the TUM database, sensor noise, several seeds), null
recordings, a few pairs of effects, and ``commonroad-std`` recordings against the nominal bicycle.
Each is diagnosed blind; the script prints one JSON object with exact-set recovery, precision,
recall, false-alarm rate on nulls, parameter errors, window IoU, the confusion between effects and
runtimes, plus the per-case rows.

    python benchmarks/diagnose_recovery.py [--quick] [--workers 2] [--seed 0]

Parameter error: ``|fitted - true| / |true - neutral|`` for each parameter that the truth moves
away from its neutral value (0, or 1 for factors), i.e. relative to the size of the effect.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

TRACKS = Path("/work/shared/data/tumftm-racetrack-database/tracks")
CIRCUITS = ["Norisring", "Oschersleben", "Zandvoort", "BrandsHatch", "Hockenheim", "Budapest", "Spielberg"]

# (name, [magnitudes]) with realistic sizes; window effects get a random window per case
MAGNITUDES = {
    "aero_drag": [{"c_d": 0.15}, {"c_d": 0.4}],
    "rolling_resistance": [{"c_rr": 0.015}, {"c_rr": 0.04}],
    "road_grade": [{"angle": 0.03}, {"angle": 0.06}],
    "drivetrain_lag": [{"tau": 0.15}, {"tau": 0.4}],
    "downforce": [{"c_l": 1.0}, {"c_l": 3.0}],
    "load_transfer": [{"cog_height": 0.35}, {"cog_height": 0.55}],
    "tire_load_sensitivity": [{"k": 0.1}, {"k": 0.25}],
    "tire_friction": [{"front": 0.85, "rear": 1.0}, {"front": 1.0, "rear": 0.85}],
    "cornering_stiffness": [{"front": 0.75, "rear": 1.0}, {"front": 1.0, "rear": 1.3}],
    "friction_patch": [{"factor": 0.75}, {"factor": 0.55}],
    "combined_slip": [{"k": 0.6}, {"k": 1.0}],
    "road_bank": [{"angle": 0.05}, {"angle": 0.1}],
    "steering_lag": [{"tau": 0.06}, {"tau": 0.15}],
    "steering_offset": [{"offset": 0.002}, {"offset": 0.005}],
    "yaw_inertia": [{"factor": 1.3}, {"factor": 0.7}],
    "gyro_bias": [{"bias": 0.01}, {"bias": 0.03}],
}
PAIRS = [("aero_drag", "steering_lag"), ("downforce", "gyro_bias"), ("road_grade", "steering_offset"),
         ("rolling_resistance", "yaw_inertia")]
NEUTRAL_ONE = {"front", "rear", "factor"}


def _window(rng, L):
    a = float(rng.uniform(0.1, 0.6) * L)
    return {"s_start": a, "s_end": a + float(rng.uniform(150.0, 350.0))}


def build_cases(quick: bool, seed: int) -> list[dict]:
    from gprace.model import EFFECTS

    rng = np.random.default_rng(seed)
    cases = []
    mags = 1 if quick else 2
    for name in EFFECTS:
        for i, p in enumerate(MAGNITUDES[name][:mags] if not quick else MAGNITUDES[name][1:2]):
            cases.append({"kind": "single", "effects": [[name, dict(p)]], "track": CIRCUITS[rng.integers(len(CIRCUITS))],
                          "seed": int(rng.integers(1_000_000))})
    for _ in range(3 if quick else 8):
        cases.append({"kind": "null", "effects": [], "track": CIRCUITS[rng.integers(len(CIRCUITS))],
                      "seed": int(rng.integers(1_000_000))})
    for a, b in PAIRS[: 2 if quick else 4]:
        cases.append({"kind": "pair", "effects": [[a, dict(MAGNITUDES[a][1])], [b, dict(MAGNITUDES[b][1])]],
                      "track": CIRCUITS[rng.integers(len(CIRCUITS))], "seed": int(rng.integers(1_000_000))})
    for _ in range(1 if quick else 2):
        cases.append({"kind": "commonroad", "effects": [], "track": CIRCUITS[rng.integers(len(CIRCUITS))],
                      "seed": int(rng.integers(1_000_000))})
    return cases


def run_case(case: dict, laps: float) -> dict:
    from gprace.config import EffectConfig, load_vehicle
    from gprace.diagnose.diagnose import diagnose
    from gprace.diagnose.synth import record
    from gprace.model import EFFECTS
    from gprace.tracks.loaders import load_track

    track = load_track(TRACKS / f"{case['track']}.csv")
    rng = np.random.default_rng(case["seed"])
    effects = []
    for name, p in case["effects"]:
        if EFFECTS[name].window:
            p.update(_window(rng, track.length))
        effects.append(EffectConfig(name=name, params=p))
    case["effects"] = [[e.name, dict(e.params)] for e in effects]
    t0 = time.perf_counter()
    try:
        if case["kind"] == "commonroad":
            vehicle = load_vehicle("bmw_320i")
            run = record(vehicle, track, laps=laps, seed=case["seed"], plant="commonroad-std")
        else:
            vehicle = load_vehicle("audi_tt_cup")
            run = record(vehicle, track, effects, laps=laps, seed=case["seed"], substeps=10)
    except Exception as exc:
        return {**case, "error": f"recording: {type(exc).__name__}: {exc}"}
    t_rec = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        rep = diagnose([run], vehicle, seed=case["seed"]).report
    except Exception as exc:  # a benchmark row, not a crash
        return {**case, "error": f"{type(exc).__name__}: {exc}"}
    t_diag = time.perf_counter() - t0
    truth = {n for n, _ in case["effects"]}
    named = [e["name"] for e in rep["effects"]]
    amb = {e["name"]: e["ambiguous_with"] for e in rep["effects"]}
    row = {**case, "samples": run.n, "verdict": rep["verdict"], "named": named, "ambiguous": amb,
           "unexplained": rep["unexplained"], "t_record": round(t_rec, 1), "t_diagnose": round(t_diag, 1),
           "exact": set(named) == truth,
           "exact_or_ambiguous": len(named) == len(truth) and all(
               n in truth or any(t in amb[n] for t in truth) for n in named) and truth <= (
               set(named) | {a for v in amb.values() for a in v})}
    errs, ious = [], []
    for name, p in case["effects"]:
        fit = next((e for e in rep["effects"] if e["name"] == name), None)
        if fit is None:
            continue
        for k, v in p.items():
            if k in ("s_start", "s_end", "ramp"):
                continue
            neutral = 1.0 if k in NEUTRAL_ONE else 0.0
            if abs(v - neutral) < 1e-12 or k not in fit["parameters"]:
                continue
            errs.append(abs(fit["parameters"][k]["value"] - v) / abs(v - neutral))
        if "s_start" in p:
            a, b = fit["parameters"]["s_start"]["value"], fit["parameters"]["s_end"]["value"]
            inter = max(0.0, min(b, p["s_end"]) - max(a, p["s_start"]))
            ious.append(inter / (max(b, p["s_end"]) - min(a, p["s_start"])))
    row["param_errors"] = [round(e, 4) for e in errs]
    row["iou"] = [round(x, 3) for x in ious]
    return row


def summarise(rows: list[dict]) -> dict:
    ok = [r for r in rows if "error" not in r]
    single = [r for r in ok if r["kind"] == "single"]
    nulls = [r for r in ok if r["kind"] == "null"]
    pairs = [r for r in ok if r["kind"] == "pair"]
    synth = single + pairs
    tp = sum(len(set(r["named"]) & {n for n, _ in r["effects"]}) for r in synth)
    n_named = sum(len(r["named"]) for r in synth)
    n_true = sum(len(r["effects"]) for r in synth)
    errs = [e for r in synth for e in r["param_errors"]]
    ious = [x for r in synth for x in r["iou"]]
    confusion: dict[str, dict[str, int]] = {}
    for r in single:
        t = r["effects"][0][0]
        key = "+".join(sorted(r["named"])) or ("(unexplained)" if r["unexplained"] else "(none)")
        confusion.setdefault(t, {}).setdefault(key, 0)
        confusion[t][key] += 1
    cr = [r for r in ok if r["kind"] == "commonroad"]
    return {
        "cases": len(rows), "errors": [r["error"] for r in rows if "error" in r],
        "single_exact_recovery": round(np.mean([r["exact"] for r in single]), 3) if single else None,
        "single_recovery_incl_ambiguous": round(np.mean([r["exact_or_ambiguous"] for r in single]), 3) if single else None,
        "pair_exact_recovery": round(np.mean([r["exact"] for r in pairs]), 3) if pairs else None,
        "precision": round(tp / n_named, 3) if n_named else None,
        "recall": round(tp / n_true, 3) if n_true else None,
        "false_alarm_rate_nulls": round(np.mean([r["verdict"] != "no_significant_mismatch" or bool(r["named"])
                                                 for r in nulls]), 3) if nulls else None,
        "median_parameter_error": round(float(np.median(errs)), 4) if errs else None,
        "mean_window_iou": round(float(np.mean(ious)), 3) if ious else None,
        "min_window_iou": round(float(np.min(ious)), 3) if ious else None,
        "confusion": confusion,
        "commonroad": [{"verdict": r["verdict"], "named": r["named"], "unexplained": r["unexplained"]} for r in cr],
        "median_runtime_s": round(float(np.median([r["t_diagnose"] for r in ok])), 1) if ok else None,
        "median_samples": int(np.median([r["samples"] for r in ok])) if ok else None,
    }


def timing(workers_unused: int = 1) -> dict:
    """Runtime of a five-minute 20 Hz recording (6,000 samples) with a hidden effect."""
    from gprace.config import EffectConfig, load_vehicle
    from gprace.diagnose.diagnose import diagnose
    from gprace.diagnose.synth import record
    from gprace.tracks.loaders import load_track

    v = load_vehicle("audi_tt_cup")
    tr = load_track(TRACKS / "Norisring.csv")
    run = record(v, tr, [EffectConfig(name="downforce", params={"c_l": 2.0})], laps=4.2, seed=99, substeps=10)
    t0 = time.perf_counter()
    rep = diagnose([run], v).report
    return {"samples": run.n, "seconds": round(time.perf_counter() - t0, 1),
            "named": [e["name"] for e in rep["effects"]]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one magnitude per effect, fewer nulls and pairs")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--laps", type=float, default=2.0)
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args()
    cases = build_cases(args.quick, args.seed)
    t0 = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(max_workers=args.workers) as ex:
        for row in ex.map(run_case, cases, [args.laps] * len(cases)):
            rows.append(row)
            print(json.dumps(row, default=str), file=sys.stderr, flush=True)  # progress, one row a line
    out = {"summary": summarise(rows), "wall_s": round(time.perf_counter() - t0, 1)}
    if not args.no_timing:
        out["timing_6000_samples"] = timing()
    out["rows"] = rows
    json.dump(out, sys.stdout, indent=1, default=lambda o: o.item() if hasattr(o, "item") else str(o))
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
