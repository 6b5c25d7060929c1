"""Head-to-head benchmark: ego NMPC step, GP rollout, and a reduced-size paper comparison.

Usage::

    python benchmarks/h2h_bench.py [--out DIR] [--tracks 100] [--runs 500] [--init-runs 20]
        [--explore-minutes 10] [--explore-width W] [--dict-size 600] [--workers 2] [--skip-protocol]
    python benchmarks/h2h_bench.py --models DIR     # rollout times of the GP models DIR/*.h5 only

Defaults are the paper's protocol (14 to 38 minutes on 2 cores, depending on the machine's hour);
smaller numbers give a quick look.

Prints one JSON object:

* ``nmpc``: ego NMPC step times (median, p99 [ms]) over a closed-loop race (oracle predictor, so
  the times are the solver's alone), IPOPT (MUMPS) through ``nlpsol``, warm-started; targets
  10 / 30 ms;
* ``rollout``: one 50-sample x 9-step GP rollout [ms], median and p99 over repetitions (compiled,
  and the numpy loop it replaces as ``numpy_*``), for each
  GP model of the protocol (the exact and the sparse backend), with one BLAS thread and with
  every core, target 3 ms;
* ``protocol``: the table next to the paper's numbers (docs/reference.md#head-to-head) and the wall time per stage.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

PAPER = {
    "baseline": {"border_hits": 2, "overtake_time": [12.772, 4.353],
                 "ey_error": {"1": [0.003, 0.003], "2": [0.009, 0.009], "8": [0.100, 0.100], "9": [0.119, 0.119]}},
    "explore": {"border_hits": 5, "overtake_time": [12.442, 5.041],
                "ey_error": {"1": [0.004, 0.004], "2": [0.007, 0.007], "8": [0.046, 0.046], "9": [0.055, 0.055]}},
    "select": {"ey_error": {"1": [0.005, 0.005], "2": [0.011, 0.011], "8": [0.108, 0.105], "9": [0.131, 0.127]}},
    "tracks": 100, "common_inside": 93,
}


def bench_nmpc(seconds: float = 20.0) -> dict:
    from gprace.h2h.race import run_race

    out = run_race({"track": {"kind": "random", "seed": 3, "width": 0.75, "stretches": 4}, "seed": 1,
                    "predictor": "oracle", "duration": seconds, "config": {"max_time": seconds}})
    ms = out["arrays"]["ego_solve_ms"]
    return {"steps": int(len(ms)), "median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99)),
            "max_ms": float(ms.max()), "fallbacks": int(out["attrs"]["fallbacks_ego"]),
            "target_median_ms": 10, "target_p99_ms": 30}


def bench_rollout(models: dict[str, Path], reps: int = 200) -> dict:
    """Rollout times with one BLAS thread (as in the race workers, one race per core) and with
    every core (one controller on its own computer, as on the car)."""
    import os

    from threadpoolctl import threadpool_limits

    from gprace.executor import single_thread_blas

    res = {"one_thread": single_thread_blas(_bench_rollout)(models, reps)}  # this also loads SciPy's BLAS
    with threadpool_limits(limits=os.cpu_count()):
        res["all_cores"] = _bench_rollout(models, reps)
    return res


def _bench_rollout(models: dict[str, Path], reps: int = 200) -> dict:
    """Per model the compiled rollout (``median_ms``, ``p99_ms``; :mod:`gprace.h2h.fastroll`) and
    the numpy loop it replaces (``numpy_*``), on the same draws."""
    from gprace.h2h.fastroll import applies
    from gprace.h2h.geometry import make_track
    from gprace.h2h.predictors import OUTPUTS, read_opponent_gp, sample_paths

    track = make_track({"kind": "random", "seed": 3, "width": 0.75})
    ego = np.tile([1.2, 0, 0, 0, 0.1, 1.0], (9, 1, 1))
    ego[:, 0, 5] += 0.12 * np.arange(9)
    opp = np.array([[1.0, 0, 0, 0.0, -0.05, 1.8]])
    eps = np.random.default_rng(0).standard_normal((9, 50, len(OUTPUTS)))

    def times(gp, compiled: bool) -> np.ndarray:
        sample_paths(gp, track, ego, opp, 50, eps, compiled)
        t = np.empty(reps)
        for i in range(reps):
            t0 = time.perf_counter()
            sample_paths(gp, track, ego, opp, 50, eps, compiled)
            t[i] = time.perf_counter() - t0
        return 1e3 * t

    res = {}
    for name, path in models.items():
        gp, attrs = read_opponent_gp(path)
        fast, slow = times(gp, True), times(gp, False)
        res[name] = {"backend": attrs["backend"], "points": int(attrs.get("n_points", 0)),
                     "path": "compiled" if applies(gp.kernel_form(), track) else "numpy",
                     "median_ms": float(np.median(fast)), "p99_ms": float(np.percentile(fast, 99)),
                     "numpy_median_ms": float(np.median(slow)), "numpy_p99_ms": float(np.percentile(slow, 99)),
                     "target_ms": 3}
    return res


def compare(tab: dict) -> dict:
    """Measured next to the paper, per predictor: border hits, overtake time, e_y error at 1, 2, 8, 9."""
    rows = {}
    for p in ("baseline", "explore", "select", "cv"):
        row: dict = {}
        r = tab["racing"].get(p)
        if r:
            row["border_hits"] = f"{r['border_hits']}/{r['runs']} (paper {PAPER.get(p, {}).get('border_hits', '-')}/100)"
            row["collisions"] = r["collisions"]
            row["overtakes"] = f"{r['overtakes']}/{r['runs']}"
            pt = PAPER.get(p, {}).get("overtake_time")
            mine = "-" if r["overtake_time_mean"] is None else f"{r['overtake_time_mean']:.2f} +- {r['overtake_time_std']:.2f}"
            row["overtake_time"] = f"{mine} over {r['overtake_scenarios']}" + (f" (paper {pt[0]} +- {pt[1]})" if pt else "")
        e = tab["ey_error"].get(p)
        if e and e["mean"]:
            for k in (1, 2, 8, 9):
                pe = PAPER.get(p, {}).get("ey_error", {}).get(str(k))
                row[f"ey_err_{k}"] = f"{e['mean'][k - 1]:.3f} +- {e['std'][k - 1]:.3f}" + (f" (paper {pe[0]} +- {pe[1]})" if pe else "")
        if row:
            rows[p] = row
    return rows


def main() -> None:
    from gprace.h2h import protocol as P

    d = P.Settings()
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="h2h_bench_out", help="protocol folder (cached artifacts are reused)")
    ap.add_argument("--tracks", type=int, default=d.tracks)
    ap.add_argument("--runs", type=int, default=d.runs)
    ap.add_argument("--init-runs", type=int, default=d.init_runs)
    ap.add_argument("--explore-minutes", type=float, default=d.explore_minutes)
    ap.add_argument("--episode-seconds", type=float, default=d.episode_seconds)
    ap.add_argument("--explore-width", type=float, default=None)
    ap.add_argument("--dict-size", type=int, default=d.dict_size)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-protocol", action="store_true")
    ap.add_argument("--models", default=None,
                    help="only time the rollouts of the GP models DIR/*.h5 (no NMPC, no protocol)")
    ap.add_argument("--nmpc-seconds", type=float, default=20.0)
    a = ap.parse_args()
    if a.models is not None:
        models = {p.stem: p for p in sorted(Path(a.models).glob("*.h5"))}
        print(json.dumps({"rollout": bench_rollout(models)}, indent=2))
        return
    result: dict = {"nmpc": bench_nmpc(a.nmpc_seconds)}
    if not a.skip_protocol:
        out = Path(a.out)
        st = P.Settings(tracks=a.tracks, runs=a.runs, init_runs=a.init_runs, explore_minutes=a.explore_minutes,
                        episode_seconds=a.episode_seconds, explore_width=a.explore_width, dict_size=a.dict_size,
                        workers=a.workers, resume=True)
        stages = {}
        t0 = time.perf_counter()
        paths = P.models(st, out)
        stages["collect_train_explore_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        raced = P.race_predictors(st, out, paths)
        stages["race_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        errors = P.offline_errors(st, out, raced, paths)
        stages["offline_errors_s"] = time.perf_counter() - t0
        stages["total_min"] = sum(stages.values()) / 60.0
        tab = P.table(st, raced, errors)
        result["rollout"] = bench_rollout({k: v for k, v in paths.items() if k != "init"})
        result["protocol"] = {"settings": tab["settings"], "stages_wall_s": stages, "table": tab, "paper": PAPER,
                              "note": "stage times include only work not found in --out (reused artifacts cost ~0)"}
        result["comparison"] = compare(tab)
    print(json.dumps(result, indent=2, default=lambda o: o.item() if hasattr(o, "item") else str(o)))


if __name__ == "__main__":
    main()
