"""What a lap's record holds besides the lap: the GPs' errors and coverage on the held-out run,
the measured envelope, and the record itself with its status."""

from __future__ import annotations

import numpy as np

from gprace.timetrial.iterate.chain import _Chain
from gprace.timetrial.record import IterationRecord


def _lap_extra(run, model) -> dict:
    """What the next plan's limits are made from: the measured envelope and the rear-slip use."""
    from gprace.timetrial import grip as G
    from gprace.timetrial.learning import in_control

    return {"envelope": G.envelope(run, in_control).tolist(), "utilisation": G.utilisation(run, model, in_control)}


def _gp_error(pred, data) -> float:
    """RMS prediction error on the held-out run, each output normalised by its spread, averaged."""
    Z, Y = data
    if pred is None or len(Z) == 0:
        return float("nan")
    mean, _ = pred(Z)
    sd = np.maximum(Y.std(axis=0), 1e-12)
    return float(np.mean(np.sqrt(np.mean(((mean - Y) / sd) ** 2, axis=0))))


def _coverage(pred, data) -> float:
    """Smallest share over the outputs of held-out errors inside the predicted 95 % band."""
    from gprace.timetrial.learning import coverage

    Z, Y = data
    if pred is None or len(Z) == 0:
        return float("nan")
    return float(np.min(coverage(pred, Z, Y)))


def _record(i, alpha, c: _Chain, plan, run, gps, sizes, extra) -> IterationRecord:
    from gprace.timetrial.guard import lap_status

    m, H, trial = run.meta, c.heldout, c.trial
    rec = {
        "iteration": i, "trial": trial, "alpha": alpha, "planned": float(plan.lap_time),
        "driven": float(m["lap_time"]), "completed": bool(m["completed"]), "reason": m.get("reason", ""),
        "gap": float(m["lap_time"] - plan.lap_time), "solve_median_ms": 1e3 * m["solve_time_median"],
        "solve_p99_ms": 1e3 * m["solve_time_p99"], "border_hits": int(m["border_hit_steps"]), "fallbacks": int(m["fallbacks"]),
        "samples": int(run.n), "replan_failed": bool(plan.meta.get("replan_failed")),
    }
    for k in ("tracking", "planning"):
        rec[f"err_{k}"] = _gp_error(gps[k] if gps else None, H[k])
        rec[f"dict_{k}"] = int(sizes[k]) if sizes else 0
        rec[f"cov_{k}"] = _coverage(gps[k] if gps else None, H[k])
    rec["limits"] = [float(v) for v in plan.meta.get("limits", [])]
    rec["interventions"] = int(m.get("interventions", 0))
    rec["eased_steps"] = int(m.get("eased_steps", 0))
    rec["weaves"] = int(m.get("weaves", 0))
    rec["band"] = [float(v) for v in m.get("band", [])]
    draft = IterationRecord(**rec, **extra)
    return draft.model_copy(update={"status": lap_status(draft, [c.record(k) for k in range(i)], c.st.slower_tolerance)})
