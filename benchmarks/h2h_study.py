"""Head-to-head sensitivity study (issue 17, item 2): the paper's table under changed conditions.

Usage::

    python benchmarks/h2h_study.py [--out benchmarks/out/h2h_study] [--tracks 100] [--seeds 1]
        [--conditions default,noiseless,...] [--workers 2] [--executor local|dask] [--scheduler ADDR]
        [-- extra options for every run, e.g. --runs 40 --init-runs 10 --explore-minutes 1]

Every condition is one ``gprace eval head2head`` run in its own folder ``OUT/<condition>`` with
``--resume``: an interrupted study continues where it stopped, and a finished condition costs only
reading its records. Before a condition starts, the run records of the conditions already in
``OUT`` are linked into its folder; the protocol keeps a record only if the hash of its task
matches (a condition that changes nothing about the collection races reuses them, any other
condition reruns them), so sharing is safe. Runs go through the protocol's executor (``--executor
dask --scheduler tcp://...`` spreads the races over a cluster).

Prints one JSON object: per condition its settings, the paper's table (border hits, collisions,
overtakes, overtake time, e_y error at 1, 2, 8 and 9 steps) with 95 % bootstrap intervals over
tracks (and the spread over seeds with ``--seeds``), a verdict per claim of the paper (exploration
against the baseline: lower 8/9-step error, earlier overtakes, no more border hits; "too few
samples for a verdict" below ``gprace.verdict.MIN_SAMPLES`` tracks), and the diagnostics behind a
verdict:

* ``data_coverage``: how close the evaluation interactions (the GP inputs of every step of the
  evaluation races) lie to each model's training inputs: median nearest-neighbour distance and the
  share within one standard deviation of the evaluation features (Euclidean, features scaled by
  their spread over the evaluation steps);
* ``spread_vs_error``: per predictor the share of the 9-step e_y and s errors inside the predicted
  2-sigma band, with the predictor's own spread and with the calibrated one (the ellipses').
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

CONDITIONS: dict[str, list[str]] = {
    # name: options of `gprace eval head2head` that define the condition (besides --tracks/--seeds)
    "default": [],  # realistic sensor and process noise of 1:10 cars, baseline on the training tracks (docs/decisions.md)
    "noiseless": ["--sensor-noise", "0", "--process-noise", "0"],
    "noise_x3": ["--sensor-noise", "3", "--process-noise", "3"],
    "baseline_eval_tracks": ["--baseline-tracks", "eval"],
    "no_blocking": ["--blocking-weight", "0"],
    "strong_blocking": ["--blocking-weight", "2000"],
    "explore_3min": ["--explore-minutes", "3"],
}
CLAIMS = {"ey_error_8": "lower 8-step error", "ey_error_9": "lower 9-step error",
          "overtake_time": "earlier overtakes", "border_hits": "no more border hits"}
RADIUS = 1.0  # data coverage: share of evaluation steps within this scaled distance of a training input


def link_records(src_root: Path, dst: Path) -> int:
    """Hard-link (copy across file systems) the run records (collection, exploration, evaluation,
    offline errors) of the other conditions into ``dst`` where ``dst`` has none yet; the protocol
    reuses a record only if its task hash matches, and replaces the others atomically (a new file,
    so the linked original stays as it was).

    One path takes the first source's record, so ``default`` comes first: a condition shares its
    stages with the default, not with another condition (docs/decisions.md, issue 17)."""
    import shutil

    n = 0
    sources = (p for p in src_root.iterdir() if p.is_dir() and p != dst)
    for src in sorted(sources, key=lambda p: (p.name != "default", p.name)):
        for rec in src.glob("**/run_*.h5"):
            target = dst / rec.relative_to(src)
            if target.exists():
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(rec, target)
            except OSError:
                shutil.copy2(rec, target)
            n += 1
    return n


def run_condition(name: str, args: list[str], out: Path, common: list[str]) -> dict:
    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    linked = link_records(out, folder)
    cmd = [sys.executable, "-m", "gprace.cli", "eval", "head2head", "--out", str(folder), "--resume", "--json",
           *common, *args]
    print(f"study: {name}: {' '.join(cmd[2:])} ({linked} records linked)", file=sys.stderr, flush=True)
    done = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    if done.returncode != 0:
        return {"error": f"exit {done.returncode}", "command": cmd[2:]}
    from gprace.h2h.table import read_table

    return read_table(folder / "table.json").model_dump()


def _training_inputs(model: Path, dataset: Path | None) -> np.ndarray | None:
    """The training inputs of a saved opponent GP: an exact GP's own points, otherwise its dataset."""
    from gprace.h2h.predictors import read_opponent_gp
    from gprace.h2h.protocol import read_dataset

    gp, _ = read_opponent_gp(model)
    Z = getattr(gp, "Z_", None)
    if Z is not None:
        return Z * gp.hyper_.z_scale + gp.hyper_.z_mean
    return read_dataset(dataset)[0] if dataset is not None and dataset.exists() else None


def data_coverage(folder: Path, raced: list[str]) -> dict:
    """Nearest-neighbour distance of the evaluation interactions to each model's training inputs."""
    from scipy.spatial import cKDTree

    from gprace.io.artifacts import read_artifact

    Zs = []
    for p in raced:
        for rec in sorted((folder / "eval" / p).glob("run_*.h5")):
            a = read_artifact(rec, "h2h_run")
            if a.attrs.get("ok") and "Z" in a.arrays and len(a.arrays["Z"]):
                Zs.append(a.arrays["Z"])
    if not Zs:
        return {}
    E = np.vstack(Zs)
    scale = np.maximum(E.std(axis=0), 1e-9)
    out = {}
    for name, dataset in (("baseline", folder / "collect" / "dataset.h5"), ("explore", None), ("select", None)):
        path = folder / "models" / f"{name}.h5"
        if not path.exists():
            continue
        Z = _training_inputs(path, dataset)
        if Z is None:
            continue
        d, _ = cKDTree(Z / scale).query(E / scale)
        out[name] = {"training_points": int(len(Z)), "eval_steps": int(len(E)),
                     "median_nn_distance": float(np.median(d)), f"share_within_{RADIUS:g}": float(np.mean(d <= RADIUS))}
    return out


def summary(tab: dict, folder: Path) -> dict:
    """The condition's table with intervals, its verdicts and the diagnostics."""
    spread, claims = tab.get("spread", {}), tab.get("claims", {})
    rows = {}
    for p, r in tab.get("racing", {}).items():
        rows[p] = {f: {"value": r.get(k), "ci": spread.get(f"{p}.{f}", {}).get("ci")}
                   for f, k in (("border_hits", "border_hits"), ("collisions", "collisions"),
                                ("overtakes", "overtakes"), ("overtake_time", "overtake_time_mean"))}
    for p, e in tab.get("ey_error", {}).items():
        row = rows.setdefault(p, {})
        for k in (1, 2, 8, 9):
            if len(e.get("mean", [])) >= k:
                row[f"ey_error_{k}"] = {"value": e["mean"][k - 1], "ci": spread.get(f"{p}.ey_error_{k}", {}).get("ci")}
    from gprace.h2h.table import Claim

    def judged(key: str) -> str:  # the table's rule: no verdict from fewer tracks than gprace.verdict.MIN_SAMPLES
        return Claim(**claims[key]).shown_verdict(tab.get("settings", {}).get("tracks")) if key in claims else "not measured"

    verdicts = {text: {"verdict": judged(key), "tracks": claims.get(key, {}).get("tracks"),
                       "explore_minus_baseline": claims.get(key, {}).get("mean"),
                       "ci": claims.get(key, {}).get("ci")} for key, text in CLAIMS.items()}
    raced = list(tab.get("racing", {}))
    return {"settings": tab.get("settings", {}), "seeds": tab.get("seeds", [0]), "table": rows, "claims": verdicts,
            "data_coverage": data_coverage(folder, raced),
            "spread_vs_error": {p: {"ey_9_raw": c["ey_raw"][-1], "ey_9_calibrated": c["ey"][-1],
                                    "s_9_raw": c["s_raw"][-1], "s_9_calibrated": c["s"][-1]}
                                for p, c in tab.get("coverage", {}).items() if c.get("ey")}}


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="benchmarks/out/h2h_study")
    ap.add_argument("--tracks", type=int, default=100)
    ap.add_argument("--seeds", default="1")
    ap.add_argument("--conditions", default=",".join(CONDITIONS))
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--executor", default="local")
    ap.add_argument("--scheduler", default=None)
    a = ap.parse_args(argv)
    names = [c.strip() for c in a.conditions.split(",") if c.strip()]
    unknown = [c for c in names if c not in CONDITIONS]
    if unknown:
        sys.exit(f"error: unknown condition(s) {', '.join(unknown)}; available: {', '.join(CONDITIONS)}")
    common = ["--tracks", str(a.tracks), "--seeds", a.seeds, "--workers", str(a.workers), "--executor", a.executor,
              *(["--scheduler", a.scheduler] if a.scheduler else []), *extra]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    result = {}
    for name in names:
        tab = run_condition(name, CONDITIONS[name], out, common)
        result[name] = tab if "error" in tab else summary(tab, out / name)
    print(json.dumps(result, indent=2, default=lambda o: o.item() if hasattr(o, "item") else str(o)))


if __name__ == "__main__":
    main()
