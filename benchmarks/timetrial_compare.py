"""The paper's comparison on two plants: ``gprace eval timetrial`` on audi_hidden and bmw_commonroad.

For each plant runs both variants (exploration: alpha 0.857,0.714,0 with diverse selection;
Double GP: alpha 0 with random selection) with the same seeds into
``benchmarks/out/timetrial_<plant>/`` (resumable), and prints one JSON table: per plant and
variant, laps completed of laps driven, driven and planned lap time per iteration (mean, std),
the oracle lap, both GPs' held-out errors and coverage, and the acceptance checks of issue 13
(no failed GP lap; alpha-0 laps close >= 60 % of the gap to the oracle on audi_hidden, beat
iteration 0 on bmw_commonroad). Long: about 10 minutes per plant and 3 trials on 2 cores.

Usage: ``timetrial_compare.py [TRIALS [ITERATIONS [PLANT,PLANT]]]`` (defaults 5, 7, both).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

PLANTS = {"audi_hidden": "audi_tt_cup", "bmw_commonroad": "bmw_320i"}  # plant -> nominal vehicle


def _nanmin(values) -> float:
    """Smallest finite value, NaN when there is none (no oracle: commonroad)."""
    v = np.asarray([np.nan if x is None else x for x in values], float)
    return float(np.nanmin(v)) if np.isfinite(v).any() else float("nan")


def checks(res: dict) -> dict:
    """Acceptance figures per variant: failed GP laps, and the alpha-0 laps against the targets."""
    out = {}
    for name, rows in res["variants"].items():
        gp_rows = [r for r in rows if r["iteration"] > 0]
        failed = sum(r["laps"] - r["completed"] for r in gp_rows)
        racing = [r for r in gp_rows if r["alpha"] == 0.0]
        base = rows[0]["driven_mean"] if rows else float("nan")
        trials = res["per_trial"][name]
        out[name] = {
            "failed_gp_laps": int(failed), "gp_laps": int(sum(r["laps"] for r in gp_rows)),
            "gap_closed_last_iteration_worst_trial": _nanmin([racing[-1]["gap_closed_min"]]) if racing else float("nan"),
            "gap_closed_best_alpha0_lap_worst_trial": _nanmin([t["gap_closed_best"] for t in trials]),
            "trials_faster_than_iteration0": int(sum(t["best_alpha0"] < t["iteration0"] for t in trials)),
            "trials": len(trials),
            "best_driven_alpha0": float(np.nanmin([r["driven_mean"] for r in racing])) if racing else float("nan"),
            "iteration0_driven": base,
        }
    return out


def main(trials: int = 5, iterations: int = 7, plants=tuple(PLANTS)) -> None:
    from gprace.errors import GpraceError
    from gprace.timetrial.compare import compare
    from gprace.console import jsonable
    from gprace.timetrial.iterate import IterateSettings

    table = {}
    for plant in plants:
        st = IterateSettings(trials=trials, iterations=iterations, plant=plant, vehicle=PLANTS[plant])
        folder = Path(__file__).parent / "out" / f"timetrial_{plant}"
        try:
            res = compare(st, folder, workers=2)
        except GpraceError as exc:
            print(f"{plant}: {exc}", file=sys.stderr)
            continue
        res["checks"] = checks(res)
        table[plant] = res
    print(json.dumps(jsonable(table), indent=1))


if __name__ == "__main__":
    a = sys.argv[1:]
    main(int(a[0]) if a else 5, int(a[1]) if len(a) > 1 else 7, tuple(a[2].split(",")) if len(a) > 2 else tuple(PLANTS))
