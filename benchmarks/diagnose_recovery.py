"""Blind recovery benchmark of ``gprace diagnose`` (issues 6 and 14), per recording SOURCE.

Sources (``--sources``, default all three):

- ``gprace``: concealed-effect recordings from gprace's own ``frenet`` plant and tracking driver on
  random real circuits from the TUM database (every catalogue effect, several magnitudes), nulls
  and pairs;
- ``independent``: :mod:`indep_source` (beside this file), a generator written apart from gprace's
  plant/driver/track code: its own random track generator, Frenet single track, tire fit, a harder
  driver with slides, full-drive corner exits and provoked spins, coloured sensor noise and
  time-stamp jitter; its nominal vehicle describes the car exactly except the concealed effect;
- ``commonroad``: the ``commonroad-std`` plant (``bmw_commonroad``) against the nominal
  ``bmw_320i``; its own physics differ from the bicycle, so its nulls show what the diagnosis says
  about that gap, and a sensor bias / steering offset concealed on top (applied to the logged
  channels, exactly equivalent to the catalogue effect) must be named among what is found.

Each recording is diagnosed blind; the script prints one JSON object with, per source: single
effects named exactly, pairs named exactly, false alarms on nulls, window IoU of bank/grade (and
friction patch), profile recovery (bank, grade, friction varying along the lap: error relative to
the profile's size, share of knots whose truth lies in the 95 % band), time per recording, the
confusion between effects, plus the per-case rows and the runtime of a 6,000-sample recording per
source.

Variants (``--variants``): ``wrapped`` (s wrapped per lap, as the sources write it) and
``continuous`` (the same case with ``s`` running on over the laps, no lap column and no lap
length: the diagnosis must find the laps itself). ``continuous_agreement`` compares each
continuous case with its wrapped twin (same names; window IoU of both).

    python benchmarks/diagnose_recovery.py [--quick | --quick-gprace] [--workers 2] [--seed 0]
        [--sources gprace,independent,commonroad] [--only steering_lag,null] [--kinds single,null,pair]
        [--variants wrapped,continuous]

Parameter error: ``|fitted - true| / |true - neutral|`` for each parameter that the truth moves
away from its neutral value (0, or 1 for factors), i.e. relative to the size of the effect.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

TRACKS = Path("/work/shared/data/tumftm-racetrack-database/tracks")
FIXTURES = Path(__file__).resolve().parent.parent / "tests" / "data"
"""TUM's banked oval (3d-road-geometry-coupling example tracks: geometry and 30-degree corner bank,
written from its facts into tests/data): the bank-profile case on real banked geometry."""
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
    "velocity_misalignment": [{"angle": 0.005}, {"angle": 0.012}],

    # profiles: the largest |value - neutral| along the lap; the shape is drawn per case (_profile)
    "road_bank_profile": [{"amplitude": 0.05}, {"amplitude": 0.09}],
    "road_grade_profile": [{"amplitude": 0.03}, {"amplitude": 0.05}],
    "friction_profile": [{"amplitude": 0.2}, {"amplitude": 0.3}],
}
PAIRS = [("aero_drag", "steering_lag"), ("downforce", "gyro_bias"), ("road_grade", "steering_offset"),
         ("rolling_resistance", "yaw_inertia")]
NEUTRAL_ONE = {"front", "rear", "factor"}


def _window(rng, L):
    a = float(rng.uniform(0.1, 0.6) * L)
    return {"s_start": a, "s_end": a + float(rng.uniform(150.0, 350.0))}


def _profile(rng, L: float, name: str, amplitude: float) -> dict:
    """A smooth profile along the lap (knots every 5 m): two or three bumps of 60-180 m (1 sigma) at
    random places; bank with both signs, grade with zero mean (a closed lap), friction as dips."""
    s = np.arange(0.0, L, 5.0)
    v = np.zeros_like(s)
    for i in range(int(rng.integers(2, 4))):
        c, w = rng.uniform(0.0, L), rng.uniform(60.0, 180.0)
        d = (s - c + 0.5 * L) % L - 0.5 * L
        sign = 1.0 if name == "friction_profile" else (1.0 if i % 2 == 0 else -1.0)
        v += sign * rng.uniform(0.6, 1.0) * np.exp(-0.5 * (d / w) ** 2)
    if name == "road_grade_profile":
        v -= v.mean()
    v *= amplitude / max(np.max(np.abs(v)), 1e-12)
    if name == "friction_profile":
        v = 1.0 - v
    return {"knots": s.tolist(), "values": v.tolist(), "lap_length": float(L)}


def build_cases(quick: bool, seed: int) -> list[dict]:
    """Cases of the ``gprace`` source (frenet plant), as before issue 14."""
    from gprace.model import EFFECTS

    rng = np.random.default_rng(seed)
    cases = []
    mags = 1 if quick else 2
    for name in (n for n in EFFECTS if not getattr(EFFECTS[n], "profile", False)):
        for i, p in enumerate(MAGNITUDES[name][:mags] if not quick else MAGNITUDES[name][1:2]):
            cases.append({"kind": "single", "effects": [[name, dict(p)]], "track": CIRCUITS[rng.integers(len(CIRCUITS))],
                          "seed": int(rng.integers(1_000_000))})
    for _ in range(3 if quick else 8):
        cases.append({"kind": "null", "effects": [], "track": CIRCUITS[rng.integers(len(CIRCUITS))],
                      "seed": int(rng.integers(1_000_000))})
    for a, b in PAIRS[: 2 if quick else 4]:
        cases.append({"kind": "pair", "effects": [[a, dict(MAGNITUDES[a][1])], [b, dict(MAGNITUDES[b][1])]],
                      "track": CIRCUITS[rng.integers(len(CIRCUITS))], "seed": int(rng.integers(1_000_000))})
    rng = np.random.default_rng(seed + 36)  # profiles (issue 36): drawn apart, the cases above unchanged
    for name in (n for n in EFFECTS if getattr(EFFECTS[n], "profile", False)):
        for p in (MAGNITUDES[name][:mags] if not quick else MAGNITUDES[name][1:2]):
            cases.append({"kind": "single", "effects": [[name, dict(p)]], "track": CIRCUITS[rng.integers(len(CIRCUITS))],
                          "seed": int(rng.integers(1_000_000))})
    if getattr(EFFECTS.get("road_bank_profile"), "profile", False) and (FIXTURES / "tum_banked_oval.toml").exists():
        cases.append({"kind": "single", "effects": [["road_bank_profile", {"fixture": "tum_banked_oval_bank.csv"}]],
                      "track": "tum_banked_oval", "seed": int(rng.integers(1_000_000))})
    for c in cases:
        c["source"] = "gprace"
    return cases


# independent source: one realistic magnitude per effect; short local effects over ~1/10 of the lap
INDEP_SINGLES = [
    ("aero_drag", {"c_d": 0.3}), ("rolling_resistance", {"c_rr": 0.03}), ("road_grade", {"angle": 0.05}),
    ("road_bank", {"angle": 0.08}), ("drivetrain_lag", {"tau": 0.25}), ("downforce", {"c_l": 2.0}),
    ("load_transfer", {"cog_height": 0.48}), ("tire_load_sensitivity", {"k": 0.2}),
    ("tire_friction", {"front": 0.85}), ("cornering_stiffness", {"rear": 1.3}),
    ("friction_patch", {"factor": 0.7}), ("combined_slip", {"k": 0.6}), ("steering_lag", {"tau": 0.04}),
    ("steering_lag", {"tau": 0.12}), ("steering_offset", {"offset": 0.004}), ("yaw_inertia", {"factor": 1.3}),
    ("gyro_bias", {"bias": 0.02}),
]
# along the whole lap, coded by the source as cosine harmonics (drawn per case in _indep_run)
INDEP_PROFILES = [("road_bank_profile", {"amplitude": 0.08}), ("road_grade_profile", {"amplitude": 0.04}),
                  ("friction_profile", {"amplitude": 0.25})]
INDEP_PAIRS = [(("downforce", {"c_l": 2.0}), ("steering_lag", {"tau": 0.1})),
               (("aero_drag", {"c_d": 0.3}), ("gyro_bias", {"bias": 0.02}))]
INDEP_WINDOW_M = 200.0  # bank, grade: a tenth of the 2 km lap; friction patch 250 m


def build_indep_cases(quick: bool, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed + 14)
    cases = []
    singles = INDEP_SINGLES[::2] if quick else INDEP_SINGLES
    for i, (n, p) in enumerate(singles):
        cases.append({"source": "independent", "kind": "single", "effects": [[n, dict(p)]],
                      "seed": int(rng.integers(1_000_000)), "spin": i % 4 == 3})
    for a, b in INDEP_PAIRS[: 1 if quick else 2]:
        cases.append({"source": "independent", "kind": "pair", "effects": [[a[0], dict(a[1])], [b[0], dict(b[1])]],
                      "seed": int(rng.integers(1_000_000)), "spin": False})
    for i in range(2 if quick else 4):
        cases.append({"source": "independent", "kind": "null", "effects": [], "seed": int(rng.integers(1_000_000)),
                      "spin": i % 2 == 1})
    rng = np.random.default_rng(seed + 36)  # profiles (issue 36): drawn apart, the cases above unchanged
    for n, p in INDEP_PROFILES:
        cases.append({"source": "independent", "kind": "single", "effects": [[n, dict(p)]],
                      "seed": int(rng.integers(1_000_000)), "spin": False})
    return cases


def build_commonroad_cases(quick: bool, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed + 77)
    cases = []
    for _ in range(1 if quick else 2):
        cases.append({"source": "commonroad", "kind": "null", "effects": [], "track": CIRCUITS[rng.integers(len(CIRCUITS))],
                      "seed": int(rng.integers(1_000_000))})
    for n, p in ([("gyro_bias", {"bias": 0.02})] if quick else [("gyro_bias", {"bias": 0.02}),
                                                              ("steering_offset", {"offset": 0.004})]):
        cases.append({"source": "commonroad", "kind": "single", "effects": [[n, dict(p)]],
                      "track": CIRCUITS[rng.integers(len(CIRCUITS))], "seed": int(rng.integers(1_000_000))})
    return cases


def _indep_run(case: dict, duration_s: float):
    """Recording of the independent source (window effects placed at random on the lap, profiles
    as random cosine harmonics of the lap position)."""
    import indep_source as ind
    from gprace.io.runs import Run

    rng = np.random.default_rng(case["seed"] + 5)
    hidden = {}
    for name, p in case["effects"]:
        p = dict(p)
        if name in ("road_grade", "road_bank", "friction_patch"):
            L = ind.Loop(case["seed"]).length
            a = float(rng.uniform(0.05, 0.8) * L)
            p.update({"s_start": a, "s_end": a + (250.0 if name == "friction_patch" else INDEP_WINDOW_M)})
        elif name.endswith("_profile"):
            amp = p.pop("amplitude")
            a = rng.uniform(0.3, 1.0, 4) / np.arange(1, 5)
            p = {"amplitudes": (amp * a / a.sum()).tolist(), "phases": rng.uniform(0, 2 * np.pi, 4).tolist()}
            if name == "friction_profile":
                p["amplitudes"] = [-x for x in p["amplitudes"]]
        hidden[name] = p
    case["effects"] = [[n, dict(p)] for n, p in hidden.items()]
    data, meta = ind.record(hidden, case["seed"], duration_s, spin=case.get("spin", False),
                            s_runs_on=case.get("variant") == "continuous")
    case["lap_length"] = ind.Loop(case["seed"]).length
    return ind.vehicle_config(), Run(data, meta, f"independent(seed {case['seed']})")


def _runs_on(run):
    """The recording with ``s`` running on over the laps: no lap column, no lap length."""
    from gprace.io.runs import Run

    L = float(run.meta["track_length"])
    data = {k: v for k, v in run.data.items() if k != "lap"}
    s = run["s"]
    lap = np.concatenate([[0], np.cumsum(np.diff(s) < -0.5 * L)])
    data["s"] = s + lap * L
    meta = {k: v for k, v in run.meta.items() if k != "track_length"}
    return Run(data, meta, run.source)


def _true_profile(name: str, p: dict, s: np.ndarray, L: float) -> np.ndarray:
    """The concealed profile at positions ``s``: catalogue knots/values (gprace source) or the
    independent source's harmonics."""
    if "knots" in p:
        return np.interp(np.mod(s, p["lap_length"]), p["knots"], p["values"], period=p["lap_length"])
    x = 2 * np.pi * np.asarray(s) / L
    v = sum(a * np.cos((k + 1) * x + ph) for k, (a, ph) in enumerate(zip(p["amplitudes"], p["phases"])))
    return (1.0 + v) if name == "friction_profile" else v + p.get("mean", 0.0)


def _commonroad_run(case: dict, laps: float):
    """commonroad-std recording with a sensor/actuator effect applied to the logged channels."""
    from gprace.config import load_vehicle
    from gprace.diagnose.synth import record
    from gprace.io.runs import Run
    from gprace.tracks.loaders import load_track

    vehicle = load_vehicle("bmw_320i")
    track = load_track(TRACKS / f"{case['track']}.csv")
    run = record(vehicle, track, laps=laps, seed=case["seed"], plant="commonroad-std")
    case["lap_length"] = track.length
    data = {k: v.copy() for k, v in run.data.items()}
    for name, p in case["effects"]:
        if name == "gyro_bias":  # the logger's yaw rate carries the offset
            data["yaw_rate"] = data["yaw_rate"] + p["bias"]
        elif name == "steering_offset":  # the car steers command + offset; the log holds the command
            data["delta"] = data["delta"] - p["offset"]
    run = Run(data, dict(run.meta), run.source)
    return vehicle, (_runs_on(run) if case.get("variant") == "continuous" else run)


def run_case(case: dict, laps: float) -> dict:
    import sys as _sys

    _sys.path.insert(0, str(Path(__file__).resolve().parent))
    from gprace.config import EffectConfig, load_vehicle
    from gprace.diagnose.diagnose import diagnose
    from gprace.diagnose.synth import record
    from gprace.model import EFFECTS
    from gprace.tracks.loaders import load_track

    case = dict(case)
    t0 = time.perf_counter()
    try:
        if case["source"] == "independent":
            vehicle, run = _indep_run(case, duration_s=60.0 * laps * 1.5)
        elif case["source"] == "commonroad":
            vehicle, run = _commonroad_run(case, laps)
        else:
            oval = case["track"] == "tum_banked_oval"
            track = load_track(FIXTURES / "tum_banked_oval.toml" if oval else TRACKS / f"{case['track']}.csv")
            rng = np.random.default_rng(case["seed"])
            effects = []
            for name, p in case["effects"]:
                p = dict(p)
                if "fixture" in p:  # a bank sampled at a few points (tests/data)
                    sb = np.loadtxt(FIXTURES / p["fixture"], delimiter=",")
                    p = {"knots": sb[:, 0].tolist(), "values": sb[:, 1].tolist(), "lap_length": float(track.length)}
                elif EFFECTS[name].window:
                    p.update(_window(rng, track.length))
                elif getattr(EFFECTS[name], "profile", False):
                    p = _profile(rng, track.length, name, p["amplitude"])
                effects.append(EffectConfig(name=name, params=p))
            case["effects"] = [[e.name, {k: list(v) if isinstance(v, tuple) else v for k, v in e.params.items()}]
                               for e in effects]
            case["lap_length"] = track.length
            vehicle = load_vehicle("audi_tt_cup")
            run = record(vehicle, track, effects, laps=max(laps, 4.0) if oval else laps, seed=case["seed"], substeps=10)
            if case.get("variant") == "continuous":
                run = _runs_on(run)
    except Exception as exc:
        return {**case, "error": f"recording: {type(exc).__name__}: {exc}"}
    t_rec = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        rep = diagnose([run], vehicle, seed=case["seed"]).report
    except Exception as exc:  # a benchmark row, not a crash
        return {**case, "error": f"{type(exc).__name__}: {exc}"}
    t_diag = time.perf_counter() - t0
    cpu_diag = time.process_time() - c0  # diagnose is single-threaded: ~ its time on an idle core
    truth = {n for n, _ in case["effects"]}
    # what was found in the catalogue's terms: the named effects and the effects that changed
    # calibrated nominal parameters stand for (issue 36: a mis-set stiffness, inertia, offset,
    # drag or rolling resistance is calibrated, not named)
    from gprace.diagnose.result import parse_result

    found = parse_result(rep, "benchmark").findings()
    named = list(found)
    amb = {e["name"]: e["ambiguous_with"] for e in rep["effects"]}
    amb.update({n: [] for n in named if n not in amb})
    cal = rep.get("calibration") or {}
    row = {**case, "samples": run.n, "verdict": rep["verdict"], "named": named, "ambiguous": amb,
           "calibrated": [p["name"] for p in cal.get("parameters", []) if p.get("changed")] if cal.get("applied") else [],
           "excluded_s": round(sum(e["seconds_excluded"] for e in rep["excluded"]), 1),
           "unexplained": rep["unexplained"], "t_record": round(t_rec, 1), "t_diagnose": round(t_diag, 1), "cpu_diagnose": round(cpu_diag, 1),
           "load_1min": round(os.getloadavg()[0], 2),
           # commonroad: its own physics differ from the nominal bicycle, so the concealed effect must
           # be among the names; elsewhere the named set must equal the truth
           "exact": truth <= set(named) if case["source"] == "commonroad" else set(named) == truth,
           "exact_or_ambiguous": len(named) == len(truth) and all(
               n in truth or any(t in amb[n] for t in truth) for n in named) and truth <= (
               set(named) | {a for v in amb.values() for a in v})}
    errs, ious, prof, iou_by = [], [], [], {}
    for name, p in case["effects"]:
        fit = found.get(name)
        if fit is None:
            continue
        profile = next((e.get("profile") for e in rep["effects"] if e["name"] == name), None)
        if profile:
            prof.append(_profile_score(name, p, profile, case["lap_length"]))
            continue
        for k, v in p.items():
            if k in ("s_start", "s_end", "ramp"):
                continue
            neutral = 1.0 if k in NEUTRAL_ONE else 0.0
            if abs(v - neutral) < 1e-12 or k not in fit:
                continue
            errs.append(abs(fit[k] - v) / abs(v - neutral))
        if "s_start" in p:
            a, b = fit["s_start"], fit["s_end"]
            inter = max(0.0, min(b, p["s_end"]) - max(a, p["s_start"]))
            ious.append(inter / (max(b, p["s_end"]) - min(a, p["s_start"])))
            iou_by[name] = round(ious[-1], 3)
    row["param_errors"] = [round(e, 4) for e in errs]
    row["iou"] = [round(x, 3) for x in ious]
    row["profiles"] = prof
    row["iou_by_effect"] = {n: iou_by.get(n, 0.0) for n, p in case["effects"] if "s_start" in p}  # 0: not named
    row["notes"] = rep["notes"]
    return row


def _profile_score(name: str, truth: dict, fitted: dict, L: float) -> dict:
    """A recovered profile against the truth at its knots: RMS error relative to the profile's
    size (largest |truth - neutral|), and the share of knots whose truth lies in the 95 % band."""
    s = np.asarray(fitted["s"], float)
    v = np.asarray(fitted["value"], float)
    lo, hi = np.asarray(fitted["ci95_low"], float), np.asarray(fitted["ci95_high"], float)
    tv = _true_profile(name, truth, s, L)
    size = float(np.max(np.abs(tv - (1.0 if name == "friction_profile" else 0.0))))
    return {"name": name, "relative_rms_error": round(float(np.sqrt(np.mean((v - tv) ** 2)) / max(size, 1e-12)), 4),
            "rms_error": round(float(np.sqrt(np.mean((v - tv) ** 2))), 5),
            "coverage_95": round(float(np.mean((tv >= lo) & (tv <= hi))), 3),
            "median_halfwidth": round(float(np.median(hi - lo) / 2), 5), "knots": len(s), "edf": fitted.get("edf")}


def summarise(rows: list[dict]) -> dict:
    """Per source (and variant): the issue-14 table plus precision/recall, parameter errors, profile
    recovery and the confusion; with both variants, how the continuous cases agree with the wrapped."""
    out = {}
    for src in dict.fromkeys(r["source"] for r in rows):
        for var in dict.fromkeys(r.get("variant", "wrapped") for r in rows if r["source"] == src):
            key = src if var == "wrapped" else f"{src} ({var} s)"
            out[key] = _summary([r for r in rows if r["source"] == src and r.get("variant", "wrapped") == var])
    pairs = _agreement(rows)
    if pairs:
        out["continuous_agreement"] = pairs
    return out


def _agreement(rows: list[dict]) -> dict:
    """Per source: continuous cases named as their wrapped twin, and both variants' bank/grade IoU."""
    key = lambda r: (r["source"], r["kind"], r["seed"], json.dumps(r["effects"], sort_keys=True, default=str))
    wrapped = {key(r): r for r in rows if r.get("variant", "wrapped") == "wrapped" and "error" not in r}
    out: dict = {}
    for r in rows:
        if r.get("variant") != "continuous" or "error" in r or key(r) not in wrapped:
            continue
        w = wrapped[key(r)]
        d = out.setdefault(r["source"], {"same_names": 0, "cases": 0, "differ": [], "iou_bank_grade": []})
        d["cases"] += 1
        same = sorted(r["named"]) == sorted(w["named"])
        d["same_names"] += same
        if not same:
            d["differ"].append({"seed": r["seed"], "truth": [n for n, _ in r["effects"]], "wrapped": w["named"],
                                "continuous": r["named"]})
        for n, a in r.get("iou_by_effect", {}).items():
            if n in ("road_bank", "road_grade"):
                d["iou_bank_grade"].append({"effect": n, "continuous": a, "wrapped": w.get("iou_by_effect", {}).get(n)})
    return out


def _summary(rows: list[dict]) -> dict:
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
    local_ious = [x for r in synth for x, (n, _) in zip(r["iou"], [e for e in r["effects"] if "s_start" in e[1]])
                  if n in ("road_grade", "road_bank")]
    prof = [p for r in synth for p in r.get("profiles", [])]
    confusion: dict[str, dict[str, int]] = {}
    for r in single:
        t = r["effects"][0][0]
        key = "+".join(sorted(r["named"])) or ("(unexplained)" if r["unexplained"] else "(none)")
        confusion.setdefault(t, {}).setdefault(key, 0)
        confusion[t][key] += 1
    src = rows[0]["source"] if rows else ""
    out = {
        "cases": len(rows), "errors": [r["error"] for r in rows if "error" in r],
        "singles_named_exactly": f"{sum(r['exact'] for r in single)} of {len(single)}",
        "single_exact_recovery": round(float(np.mean([r["exact"] for r in single])), 3) if single else None,
        "single_recovery_incl_ambiguous": round(float(np.mean([r["exact_or_ambiguous"] for r in single])), 3) if single else None,
        "pairs_named_exactly": f"{sum(r['exact'] for r in pairs)} of {len(pairs)}",
        "precision": round(tp / n_named, 3) if n_named else None,
        "recall": round(tp / n_true, 3) if n_true else None,
        "median_parameter_error": round(float(np.median(errs)), 4) if errs else None,
        "window_iou_bank_grade": [round(x, 3) for x in local_ious],
        "mean_window_iou": round(float(np.mean(ious)), 3) if ious else None,
        "min_window_iou": round(float(np.min(ious)), 3) if ious else None,
        "profiles": [{k: p[k] for k in ("name", "relative_rms_error", "coverage_95", "edf")} for p in prof],
        "confusion": confusion,
        "misses": [{"truth": [n for n, _ in r["effects"]], "named": r["named"], "ambiguous": r["ambiguous"],
                "calibrated": r.get("calibrated", []),
                    "unexplained": r["unexplained"], "seed": r["seed"]} for r in synth if not r["exact"]],
        "median_runtime_s": round(float(np.median([r["t_diagnose"] for r in ok])), 1) if ok else None,
        "median_cpu_s": round(float(np.median([r["cpu_diagnose"] for r in ok])), 1) if ok else None,
        "median_load_1min": round(float(np.median([r["load_1min"] for r in ok])), 2) if ok else None,
        "max_runtime_s": round(float(np.max([r["t_diagnose"] for r in ok])), 1) if ok else None,
        "median_samples": int(np.median([r["samples"] for r in ok])) if ok else None,
        "seconds_excluded_by_envelope": [r["excluded_s"] for r in ok if r.get("excluded_s")],
    }
    if src == "commonroad":  # not a null: the bicycle is an approximation of that plant
        out["nulls"] = [{"verdict": r["verdict"], "named": r["named"], "unexplained": r["unexplained"]} for r in nulls]
    else:
        out["false_alarms_on_nulls"] = f"{sum(r['verdict'] != 'no_significant_mismatch' or bool(r['named']) for r in nulls)} of {len(nulls)}"
    return out


def timing(source: str) -> dict:
    """Runtime of a five-minute 20 Hz recording (6,000 samples) with a hidden effect."""
    case = {"source": source, "kind": "single", "effects": [["downforce", {"c_l": 2.0}]], "seed": 99,
            "track": "Norisring", "spin": False}
    if source == "commonroad":
        case["effects"] = [["gyro_bias", {"bias": 0.02}]]
    laps = {"gprace": 4.2, "independent": 300.0 / 90.0, "commonroad": 4.2}[source]
    row = run_case(case, laps)
    return {k: row.get(k) for k in ("samples", "t_diagnose", "cpu_diagnose", "load_1min", "t_record", "named", "error")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one magnitude per effect, fewer nulls and pairs")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--laps", type=float, default=2.0)
    ap.add_argument("--sources", default="gprace,independent,commonroad")
    ap.add_argument("--quick-gprace", action="store_true", help="--quick for the gprace source only")
    ap.add_argument("--only", default="", help="comma-separated effect names (subset of the cases)")
    ap.add_argument("--kinds", default="single,null,pair", help="comma-separated case kinds to run")
    ap.add_argument("--variants", default="wrapped", help="wrapped,continuous: s wrapped per lap and/or running on")
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args()
    sources = args.sources.split(",")
    cases = []
    if "gprace" in sources:
        cases += build_cases(args.quick or args.quick_gprace, args.seed)
    if "independent" in sources:
        cases += build_indep_cases(args.quick, args.seed)
    if "commonroad" in sources:
        cases += build_commonroad_cases(args.quick, args.seed)
    if args.only:
        keep = set(args.only.split(","))
        cases = [c for c in cases if {n for n, _ in c["effects"]} & keep or ("null" in keep and not c["effects"])]
    cases = [c for c in cases if c["kind"] in set(args.kinds.split(","))]
    cases = [{**c, "variant": v} for c in cases for v in args.variants.split(",")]
    if args.workers > 1:  # the diagnoses run side by side: one kernel thread each (fastpredict)
        os.environ.setdefault("GPRACE_DIAGNOSE_THREADS", "1")
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(max_workers=args.workers) as ex:
        for row in ex.map(run_case, cases, [args.laps] * len(cases)):
            rows.append(row)
            print(json.dumps(row, default=str), file=sys.stderr, flush=True)  # progress, one row a line
    out = {"summary": summarise(rows), "wall_s": round(time.perf_counter() - t0, 1)}
    if not args.no_timing:
        out["timing_6000_samples"] = {src: timing(src) for src in sources}
    # times mean little without the machine's load (1-minute averages at start and end)
    out["load_average"] = {"start": [round(x, 2) for x in load0], "end": [round(x, 2) for x in os.getloadavg()],
                           "cpus": os.cpu_count()}
    out["rows"] = rows
    json.dump(out, sys.stdout, indent=1, default=lambda o: o.item() if hasattr(o, "item") else str(o))
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
