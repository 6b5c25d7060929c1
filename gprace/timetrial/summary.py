"""``summary.json`` of ``gprace iterate``: every finished record of a folder, aggregated by iteration and
by trial (the :class:`~gprace.timetrial.record.IterateSummary` layout), and the text of the failed laps
the tables print. Derived from the records alone, so any folder (finished, interrupted, old) is summarised
the same way.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gprace.errors import InputError
from gprace.timetrial.record import IterateSummary, read_record


def build_summary(out: str | Path) -> dict:
    """All finished records of a folder, by iteration and trial (what ``evaluate iterate`` prints),
    as a dict of the :class:`~gprace.timetrial.record.IterateSummary` layout."""
    out = Path(out)
    if not (out / "settings.json").exists():
        raise InputError(f"{out}: not a gprace iterate folder (no settings.json)")
    rows = []
    for p in sorted(out.glob("trial_*/iter_*/record.json")):
        rows.append(read_record(p))
    rows.sort(key=lambda r: (r["iteration"], r["trial"]))
    oracle = json.loads((out / "oracle.json").read_text()) if (out / "oracle.json").exists() else None
    base = {r["trial"]: r["driven"] for r in rows if r["iteration"] == 0}
    o_lap = None
    if oracle and oracle.get("known"):
        o_lap = oracle.get("driven") if oracle.get("completed") else oracle.get("planned")
        o_lap = o_lap if o_lap is not None and np.isfinite(o_lap) else None
    by_iter = {}
    for r in rows:
        # share of the gap between the trial's iteration-0 lap and the oracle lap that this lap closed
        b = base.get(r["trial"], float("nan"))
        r["gap_closed"] = float((b - r["driven"]) / (b - o_lap)) if o_lap is not None and b - o_lap > 0 else float("nan")
        by_iter.setdefault(r["iteration"], []).append(r)
    agg = []
    for i, rs in sorted(by_iter.items()):
        d = np.array([r["driven"] for r in rs], float)
        pl = np.array([r["planned"] for r in rs], float)
        g = rs if i else []  # the laps driven with GPs (none at iteration 0)
        agg.append({
            "iteration": i, "alpha": rs[0]["alpha"], "trials": len(rs),
            "planned_mean": _finite(np.mean, pl), "planned_std": _finite(np.std, pl),
            "driven_mean": _finite(np.mean, d), "driven_std": _finite(np.std, d), "gap_mean": _finite(np.mean, d - pl),
            **{f"err_{k}": _finite(np.mean, [r[f"err_{k}"] for r in g]) for k in ("tracking", "planning")},
            **{f"cov_{k}": _finite(np.min, [r[f"cov_{k}"] for r in g]) for k in ("tracking", "planning")},
            "gap_closed_min": _finite(np.min, [r["gap_closed"] for r in g]),
            "completed": int(sum(r["completed"] for r in rs)),
            "interventions": int(sum(r.get("interventions", 0) for r in rs)),
            "failed": [{"trial": r["trial"], "reason": r.get("reason") or "lap not completed"}
                       for r in rs if not r["completed"]],
        })
    # per trial: its iteration-0 lap, its best driven alpha-0 lap (the racing laps after the
    # exploration) and the share of the gap to the oracle that lap closed
    per_trial = []
    for j, b in sorted(base.items()):
        racing = [r for r in rows if r["trial"] == j and r["iteration"] > 0 and r["alpha"] == 0.0 and r["completed"]]
        best = min(racing, key=lambda r: r["driven"]) if racing else None
        per_trial.append({"trial": j, "iteration0": b, "best_alpha0": best["driven"] if best else float("nan"),
                          "best_iteration": best["iteration"] if best else None,
                          "gap_closed_best": best["gap_closed"] if best else float("nan")})
    summary = {"settings": json.loads((out / "settings.json").read_text()), "oracle": oracle, "rows": rows,
               "by_iteration": agg, "per_trial": per_trial}
    return IterateSummary.model_validate(summary).model_dump()


def _finite(stat, values) -> float:
    """``stat`` over the finite values, NaN if there is none (an iteration of failed laps)."""
    a = np.asarray(values, float)
    a = a[np.isfinite(a)]
    return float(stat(a)) if a.size else float("nan")


def failed_laps_text(by_iteration: list[dict]) -> list[str]:
    """One line per iteration with failed laps: how many of how many, and where each failed
    (the tables of ``eval iterate``, ``eval timetrial`` and ``show summary.json`` use it)."""
    return [f"iteration {a['iteration']}: {len(a['failed'])} of {a['trials']} laps failed: "
            + "; ".join(f"trial {f['trial']}: {f['reason']}" for f in a["failed"])
            for a in by_iteration if a.get("failed")]


SUMMARY_COLUMNS = ["iteration", "trial", "alpha", "planned", "driven", "gap", "err_tracking", "err_planning",
                   "dict_tracking", "dict_planning", "solve_median_ms", "solve_p99_ms", "border_hits", "fallbacks"]
