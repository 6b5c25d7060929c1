"""``gprace eval timetrial``: the paper's comparison in one command.

Two variants of ``gprace iterate`` with the same seeds, plant and track, their trials in one
batch of the executor (local processes or Dask):

- ``exploration``: ``--alpha 0.857,0.714,0`` with the diverse selection (the paper's method);
- ``double_gp``: alpha 0 throughout with a random selection of all data (Su et al. 2023).

Each variant lives in ``OUT/<variant>/`` (an ordinary iterate folder, resumable). The table holds
the data of the paper's two figures: per iteration the planned and driven lap times, their gap
(mean and std over trials), laps completed of laps driven, and both GPs' held-out errors and
coverage; plus the oracle lap.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

VARIANTS = {
    "exploration": {"alphas": (0.857, 0.714, 0.0), "selection": "diverse"},
    "double_gp": {"alphas": (0.0,), "selection": "random"},
}


def compare(base, out: str | Path, executor: str = "local", workers: int | None = 1, scheduler: str | None = None) -> dict:
    """Run (or resume) both variants of ``base`` (an IterateSettings) under ``out``; return the table."""
    from gprace.errors import RunFailedError
    from gprace.timetrial.iterate import build_summary, iterate_many

    from gprace.io.artifacts import check_folder

    out = check_folder(out)
    experiments = [(base.model_copy(update=kw), out / name) for name, kw in VARIANTS.items()]
    error = None
    try:
        iterate_many(experiments, executor, workers, scheduler)
    except RunFailedError as exc:  # report what finished, then fail
        error = str(exc)
    summaries = {name: build_summary(folder) for name, (_, folder) in zip(VARIANTS, experiments)}
    table = {name: figure_data(summary) for name, summary in summaries.items()}
    oracle = summaries["exploration"].get("oracle")
    per_trial = {name: summary["per_trial"] for name, summary in summaries.items()}
    return {"plant": base.plant, "track": base.track, "trials": base.trials, "iterations": base.iterations,
            "features": base.features, "oracle": oracle, "variants": table, "per_trial": per_trial,
            "claims": claims(per_trial), "error": error}


def claims(per_trial: dict) -> dict:
    """The paper's claim, exploration against Double GP on the same seeds: a faster best alpha-0
    lap. The difference per trial (both laps completed), its bootstrap interval over trials and
    the verdict of :mod:`gprace.verdict` (too few samples below its minimum of trials)."""
    from gprace.verdict import mean_interval, verdict

    best = {name: {t["trial"]: t["best_alpha0"] for t in rows} for name, rows in per_trial.items()}
    e, d = best.get("exploration", {}), best.get("double_gp", {})
    diff = [e[j] - d[j] for j in sorted(set(e) & set(d)) if np.isfinite(e[j]) and np.isfinite(d[j])]
    ci = mean_interval(diff)
    return {"best_alpha0_lap": {"difference": float(np.mean(diff)) if diff else None, "ci": ci, "trials": len(diff),
                                "verdict": verdict([ci], claimed=-1, n=len(diff))}}


def figure_data(summary: dict) -> list[dict]:
    """Per iteration: lap times (planned, driven, gap: mean and std over completed laps), laps
    completed of laps driven, GP errors and coverage (both GPs), and the share of the gap to the
    oracle lap closed (smallest over trials)."""
    rows = []
    for a in summary["by_iteration"]:
        rs = [r for r in summary["rows"] if r["iteration"] == a["iteration"]]
        gap = np.array([r["gap"] for r in rs if r["completed"]], float)
        rows.append({
            "iteration": a["iteration"], "alpha": a["alpha"], "laps": a["trials"], "completed": a["completed"],
            "planned_mean": a["planned_mean"], "planned_std": a["planned_std"],
            "driven_mean": a["driven_mean"], "driven_std": a["driven_std"],
            "gap_mean": float(gap.mean()) if len(gap) else float("nan"), "gap_std": float(gap.std()) if len(gap) else float("nan"),
            "err_tracking": a["err_tracking"], "err_planning": a["err_planning"],
            "cov_tracking": a["cov_tracking"], "cov_planning": a["cov_planning"], "gap_closed_min": a["gap_closed_min"],
            "failed": a.get("failed", []),
        })
    return rows


COLUMNS = (("iter", "iteration"), ("alpha", "alpha"), ("done", "done"), ("planned", "planned_mean"), ("+-", "planned_std"),
           ("driven", "driven_mean"), ("+-", "driven_std"), ("gap", "gap_mean"), ("+-", "gap_std"),
           ("errTrk", "err_tracking"), ("errPln", "err_planning"), ("covTrk", "cov_tracking"), ("covPln", "cov_planning"),
           ("closed", "gap_closed_min"))


def format_table(res: dict) -> str:
    """Plain fixed-width text (readable in pipes and logs)."""
    def cell(v) -> str:
        if isinstance(v, str):
            return f"{v:>7}"
        if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            return f"{v:>7d}"
        return f"{v:>7.3f}" if v is not None and np.isfinite(v) else f"{'-':>7}"

    lines = [f"time trial on {res['plant']} / {res['track']}: {res['trials']} trials, {res['iterations']} iterations, "
             f"GP features {res['features']} (lap times [s]; GP errors: held-out RMS / its std; cov: share of held-out "
             "errors inside the 95 % band, smallest output; closed: smallest share over trials of the gap between "
             "iteration 0 and the oracle lap)"]
    from gprace.timetrial.iterate import failed_laps_text

    for name, rows in res["variants"].items():
        lines += ["", name, " ".join(f"{h:>7}" for h, _ in COLUMNS)]
        for r in rows:
            r = {**r, "done": f"{r['completed']}/{r['laps']}"}
            lines.append(" ".join(cell(r[k]) for _, k in COLUMNS))
        lines += [f"  {ln}" for ln in failed_laps_text([{**r, "trials": r["laps"]} for r in rows])]
    for name, c in (res.get("claims") or {}).items():
        diff = "-" if c["difference"] is None else f"{c['difference']:+.3f} s"
        ci = "" if c["ci"][0] is None else f" [{c['ci'][0]:+.3f}, {c['ci'][1]:+.3f}]"
        lines += ["", f"claim: exploration's best alpha-0 lap faster than Double GP's (same seeds): {diff}{ci} "
                  f"over {c['trials']} trial(s): {c['verdict']}"]
    o = res.get("oracle") or {}
    lines.append("")
    if o.get("known"):
        lines.append(f"oracle lap: planned {cell(o['planned']).strip()} s, driven {cell(o['driven']).strip()} s"
                     + ("" if o.get("completed") else f" (not completed: {o.get('reason')})")
                     + f"; 'closed' measured against the {o.get('basis', 'driven')} lap")
    else:
        lines.append(f"oracle lap: unknown ({o.get('why', 'no oracle')})")
    return "\n".join(lines)
