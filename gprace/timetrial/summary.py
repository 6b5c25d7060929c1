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
from gprace.timetrial.record import FailedLap, IterateSummary, IterationSummary, SummaryRow, TrialSummary, read_record


def build_summary(out: str | Path) -> dict:
    """All finished records of a folder, by iteration and trial (what ``evaluate iterate`` prints),
    as a dict of the :class:`~gprace.timetrial.record.IterateSummary` layout (what ``summary.json``
    and ``gprace iterate --json`` hold)."""
    return summarise(out).model_dump()


def summarise(out: str | Path) -> IterateSummary:
    """:func:`build_summary` as the frozen :class:`~gprace.timetrial.record.IterateSummary`."""
    out = Path(out)
    if not (out / "settings.json").exists():
        raise InputError(f"{out}: not a gprace iterate folder (no settings.json)")
    records = sorted((read_record(p) for p in out.glob("trial_*/iter_*/record.json")), key=lambda r: (r.iteration, r.trial))
    oracle = json.loads((out / "oracle.json").read_text()) if (out / "oracle.json").exists() else None
    base = {r.trial: r.driven for r in records if r.iteration == 0}
    o_lap = None
    if oracle and oracle.get("known"):
        o_lap = oracle.get("driven") if oracle.get("completed") else oracle.get("planned")
        o_lap = o_lap if o_lap is not None and np.isfinite(o_lap) else None
    rows, by_iter = [], {}
    for r in records:
        # share of the gap between the trial's iteration-0 lap and the oracle lap that this lap closed
        b = base.get(r.trial, float("nan"))
        closed = float((b - r.driven) / (b - o_lap)) if o_lap is not None and b - o_lap > 0 else float("nan")
        rows.append(SummaryRow(**r.model_dump(), gap_closed=closed))
        by_iter.setdefault(r.iteration, []).append(rows[-1])
    return IterateSummary(settings=json.loads((out / "settings.json").read_text()), oracle=oracle, rows=rows,
                          by_iteration=[_iteration(i, rs) for i, rs in sorted(by_iter.items())],
                          per_trial=[_trial(j, b, rows) for j, b in sorted(base.items())])


def _iteration(i: int, rs: list[SummaryRow]) -> IterationSummary:
    """One iteration's laps over the trials: means, spreads, the GPs' worst coverage, the failed laps."""
    d = np.array([r.driven for r in rs], float)
    pl = np.array([r.planned for r in rs], float)
    g = rs if i else []  # the laps driven with GPs (none at iteration 0)
    return IterationSummary(
        iteration=i, alpha=rs[0].alpha, trials=len(rs),
        planned_mean=_finite(np.mean, pl), planned_std=_finite(np.std, pl),
        driven_mean=_finite(np.mean, d), driven_std=_finite(np.std, d), gap_mean=_finite(np.mean, d - pl),
        err_tracking=_finite(np.mean, [r.err_tracking for r in g]), err_planning=_finite(np.mean, [r.err_planning for r in g]),
        cov_tracking=_finite(np.min, [r.cov_tracking for r in g]), cov_planning=_finite(np.min, [r.cov_planning for r in g]),
        gap_closed_min=_finite(np.min, [r.gap_closed for r in g]),
        completed=int(sum(r.completed for r in rs)),
        interventions=int(sum(r.interventions for r in rs)),
        failed=[FailedLap(trial=r.trial, reason=r.reason or "lap not completed") for r in rs if not r.completed])


def _trial(j: int, b: float, rows: list[SummaryRow]) -> TrialSummary:
    """Trial ``j``: its iteration-0 lap ``b``, its best driven alpha-0 lap (the racing laps after the
    exploration) and the share of the gap to the oracle that lap closed."""
    racing = [r for r in rows if r.trial == j and r.iteration > 0 and r.alpha == 0.0 and r.completed]
    best = min(racing, key=lambda r: r.driven) if racing else None
    return TrialSummary(trial=j, iteration0=b, best_alpha0=best.driven if best else float("nan"),
                        best_iteration=best.iteration if best else None,
                        gap_closed_best=best.gap_closed if best else float("nan"))


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
