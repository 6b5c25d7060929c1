"""Small synthetic result folders for the report tests (builders only; the checks live in
test_report.py and test_report_browser.py).

The artifacts use the real writers (write_artifact, write_run, save_model with a real GP fit) and
the layouts of the stages: an iterate folder per time-trial variant (summary.json, iter_<k>/
with plan and runs), a head-to-head folder (table.json, eval/<predictor>/run_*.h5, models/),
a diagnosis JSON with its stored residual profile.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gprace.io.artifacts import Artifact, write_artifact
from gprace.io.runs import Run, write_run

TRACK = "circle_100"  # shipped, 628.3 m circle, kappa = 0.01 1/m
L = 2 * np.pi * 100.0


def make_plan(path: Path, v: float = 20.0) -> Path:
    n = 200
    s = np.linspace(0, L, n, endpoint=False)
    e_y = 2.0 * np.sin(2 * np.pi * s / L)
    v_x = v + 1.5 * np.cos(4 * np.pi * s / L)
    t = np.concatenate([[0.0], np.cumsum(np.diff(s) / v_x[:-1])])
    lap = float(t[-1] + (L - s[-1]) / v_x[-1])
    arrays = {"s": s, "e_y": e_y, "e_psi": np.zeros(n), "v_x": v_x, "v_y": 0.05 * np.sin(6 * np.pi * s / L),
              "yaw_rate": v_x * 0.01, "delta": np.full(n, 0.025), "a_x": np.zeros(n), "t": t}
    return write_artifact(path, Artifact("plan", arrays=arrays, attrs={
        "track": TRACK, "track_length": L, "track_hash": "0" * 16, "lap_time": lap, "vehicle": "audi_tt_cup",
        "method": "min_time", "meta": {}}))


def make_run(path: Path, v: float, alpha: float = 0.0, seed: int = 0, planned: float | None = None,
             hits: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    dt = 0.05
    n = int(L / v / dt)
    t = dt * np.arange(n)
    s = np.mod(v * t, L)
    v_x = v + 0.5 * np.sin(2 * np.pi * t / t[-1]) + 0.02 * rng.standard_normal(n)
    wiggle = alpha * 0.3 * np.sin(2 * np.pi * s / 40.0)
    data = {"t": t, "s": s, "e_y": 1.5 * np.sin(2 * np.pi * s / L) + 3 * wiggle, "e_psi": 0.01 * np.sin(t),
            "v_x": v_x, "v_y": 0.05 * np.sin(6 * np.pi * s / L) + wiggle + 0.01 * rng.standard_normal(n),
            "yaw_rate": v_x * 0.01 + 0.5 * wiggle, "delta": np.full(n, 0.025), "a_x": np.gradient(v_x, dt),
            "kappa": np.full(n, 0.01), "lap": np.zeros(n), "border_hit": np.zeros(n)}
    if hits:
        data["border_hit"][n // 3: n // 3 + hits] = 1.0
    lap_time = float(L / v)
    meta = {"track": TRACK, "dt": dt, "lap_time": lap_time, "lap_times": [lap_time],
            "planned_lap_time": float(planned if planned is not None else lap_time - 0.8), "alpha": alpha,
            "completed": True, "reason": "", "seed": seed, "border_hit_steps": int(hits)}
    return write_run(Run(data, meta, str(path)), path, seed=seed)


def make_gp_model(path: Path, seed: int = 0) -> Path:
    from gprace.gp import make_gp, save_model

    rng = np.random.default_rng(seed)
    Z = np.column_stack([rng.uniform(-0.5, 0.5, 40), rng.uniform(-0.3, 0.3, 40), rng.uniform(-0.05, 0.05, 40)])
    Y = np.column_stack([np.sin(3 * Z[:, 0]) + 0.5 * Z[:, 1], Z[:, 1] ** 2])
    gp = make_gp("exact", kernel="se", optimize=False).fit(Z, Y)
    return save_model(path, gp, {"feature_map": "tracking", "input_names": ["v_y", "yaw_rate", "delta"],
                                 "output_names": ["dv_y", "dyaw_rate"]})


def make_dataset(path: Path, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    Z = rng.normal(size=(60, 3)) * [0.3, 0.2, 0.03]
    Y = np.column_stack([Z[:, 0] * 0.1, Z[:, 1] ** 2])
    return write_artifact(path, Artifact("dataset", arrays={"Z": Z, "Y": Y},
                                         attrs={"inputs": ["v_y", "yaw_rate", "delta"], "outputs": ["dv_y", "dyaw_rate"]}))


def make_iterate(root: Path, name: str, iterations: int = 3, trials: int = 2, explore: bool = True,
                 summary: bool = True, gain: float = 0.6) -> Path:
    """An iterate folder in the layout of ``gprace iterate``: settings.json, per trial and iteration
    a plan, a run and the iteration record, a tracking GP in the last iteration, summary.json."""
    from gprace.io.artifacts import read_artifact
    from gprace.timetrial.iterate import IterateSettings, build_summary
    from gprace.timetrial.record import IterationRecord, write_json, write_record

    d = root / name
    alphas = (0.857, 0.714, 0.0) if explore else (0.0,)
    st = IterateSettings(alphas=alphas, selection="diverse" if explore else "random", iterations=max(iterations - 1, 1),
                         trials=trials, track=TRACK)
    d.mkdir(parents=True, exist_ok=True)
    write_json(d / "settings.json", st.model_dump(mode="json"))
    for tr in range(trials):
        for it in range(iterations):
            folder = d / f"trial_{tr}" / f"iter_{it:02d}"
            pl = float(read_artifact(make_plan(folder / "plan.h5", v=20.0 + gain * it), "plan").attrs["lap_time"])
            alpha = st.alpha(it) if it else 0.0
            v = 19.0 + gain * it + 0.2 * tr
            hits = 2 if (it == iterations - 1 and tr == 0) else 0
            make_run(folder / "run.h5", v, alpha=alpha, seed=tr, planned=pl, hits=hits)
            nan = float("nan")
            write_record(folder / "record.json", IterationRecord(
                iteration=it, trial=tr, alpha=alpha, planned=pl, driven=float(L / v), completed=True, border_hits=hits,
                err_planning=0.3 / (1 + it) if it else nan, err_tracking=0.05 / (1 + it + tr) if it else nan))
    if iterations > 1:
        make_gp_model(d / "trial_0" / f"iter_{iterations - 1:02d}" / "gp_tracking.h5")
    if summary:
        write_json(d / "summary.json", build_summary(d))
    return d


def make_h2h(root: Path, steps: int = 60) -> Path:
    """A head-to-head folder: one evaluation race with its offline-error record, and table.json."""
    from gprace.h2h.records import ErrorAttrs, RaceAttrs, record_of, write_record

    d = root / "h2h"
    t = 0.1 * np.arange(steps + 1)
    # two cars on the built-in loop, the ego catching up and passing on the left
    s_o = 1.0 + 1.0 * t
    s_e = 0.4 + 1.2 * t
    ego = np.column_stack([np.full_like(t, 1.2), np.zeros_like(t), np.zeros_like(t), np.zeros_like(t),
                           0.3 * np.sin(0.5 * t), s_e])
    opp = np.column_stack([np.full_like(t, 1.0), np.zeros_like(t), np.zeros_like(t), np.zeros_like(t),
                           -0.2 * np.sin(0.3 * t), s_o])
    task = {"id": "eval-explore-0", "track": {"kind": "loop"}, "seed": 0, "predictor": "gp", "label": "explore",
            "config": {"samples": 5}}
    attrs = {"track": "h2h_loop", "predictor": "explore", "end_reason": "overtaken", "overtake_time": 3.1,
             "border_hit": False, "collision": False, "steps": steps}
    race = d / "eval" / "explore" / "run_00000.h5"
    write_record(race, record_of(RaceAttrs, task, "race0", True, {"arrays": {
        "t": t, "ego": ego, "opp": opp, "border_ego": np.zeros(len(t), bool)}, "attrs": attrs}, ""))
    # the protocol's offline errors of that race: (K, start times) per predictor
    k = np.arange(1, 10)[:, None]
    starts = np.arange(steps - 8)[None, :]
    errors = {"cv": 0.01 * k * (1 + 0.1 * np.sin(starts)), "explore": 0.002 * k ** 1.2 * (1 + 0.1 * np.cos(starts))}
    write_record(d / "errors" / "explore" / "run_00000.h5", record_of(
        ErrorAttrs, {"id": "errors-explore-0", "record": str(race), "record_hash": "race0", "seed": 0}, "err0", True,
        {"arrays": errors, "attrs": {}}, ""))
    K = 9
    steps_k = np.arange(1, K + 1)
    table = {"settings": {"tracks": 1, "config": {"dt": 0.1}}, "common_inside": 1,
             "racing": {"baseline": {"runs": 1, "failed": 0, "border_hits": 0, "collisions": 0, "overtakes": 1,
                                     "overtake_time_mean": 3.4, "overtake_time_std": 0.0},
                        "explore": {"runs": 1, "failed": 0, "border_hits": 0, "collisions": 0, "overtakes": 1,
                                    "overtake_time_mean": 3.1, "overtake_time_std": 0.0}},
             "ey_error": {"baseline": {"mean": (0.003 * steps_k ** 1.3).tolist(), "std": (0.002 * steps_k).tolist(), "points": 50},
                          "explore": {"mean": (0.002 * steps_k ** 1.2).tolist(), "std": (0.001 * steps_k).tolist(), "points": 50},
                          "cv": {"mean": (0.01 * steps_k).tolist(), "std": (0.005 * steps_k).tolist(), "points": 50}}}
    (d / "table.json").write_text(json.dumps(table))
    return d


def make_diagnosis(root: Path) -> Path:
    """A diagnosis result as ``gprace diagnose --json`` writes it (version 1, residual profile stored)."""
    from gprace.diagnose.result import DiagnosisResult, residual_profile

    d = root / "diagnosis"
    d.mkdir(parents=True, exist_ok=True)
    rep = {"verdict": "mismatch",
           "channels": [{"name": "v_x", "structured": True, "statistic": 14.2, "rmse_nominal": 0.21},
                        {"name": "v_y", "structured": False, "statistic": 1.1, "rmse_nominal": 0.02},
                        {"name": "yaw_rate", "structured": False, "statistic": 0.9, "rmse_nominal": 0.01}],
           "regions": [{"channel": "v_x", "s_start": 120.0, "s_end": 220.0, "description": "braking into turn 1"}],
           "effects": [{"name": "road_grade", "parameters": {
               "angle": {"value": 0.031, "ci95": [0.028, 0.034], "unit": "rad"},
               "s_start": {"value": 118.0, "ci95": [115.0, 121.0], "unit": "m"},
               "s_end": {"value": 221.0, "ci95": [219.0, 224.0], "unit": "m"}},
               "channels": ["v_x"], "heldout_rmse_before": {"v_x": 0.21}, "heldout_rmse_after": {"v_x": 0.04},
               "improvement": 0.81, "ambiguous_with": []}],
           "unexplained": {}, "augmented_vehicle": "augmented.toml", "explained_share": 0.93}
    # the residual along the track as the diagnosis stores it: large in the window before, noise after
    s = np.arange(5.0, L, 10.0)
    win = ((s > 120) & (s < 220)).astype(float)
    rng = np.random.default_rng(3)
    n = len(s)
    rep["residual_profile"] = residual_profile(
        s, {"v_x": 0.3 * win + 0.02 * rng.standard_normal(n), "v_y": 0.01 * rng.standard_normal(n)},
        {"v_x": 0.02 * rng.standard_normal(n), "v_y": 0.01 * rng.standard_normal(n)}, {"v_x": 0.02, "v_y": 0.01}, 10.0)
    (d / "diagnosis.json").write_text(json.dumps(DiagnosisResult.model_validate(rep).to_json()))
    return d


def make_everything(root: Path) -> Path:
    make_iterate(root, "exploration", explore=True, gain=0.7)
    make_iterate(root, "baseline", explore=False, gain=0.4)
    make_h2h(root)
    make_diagnosis(root)
    make_dataset(root / "gp" / "dataset.h5")
    return root
