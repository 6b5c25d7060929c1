"""The report's head-to-head section: the results table, error curves, one race."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from gprace.report import figures as F
from gprace.report.collect import Found, Item, Section, table
from gprace.report.inspect import COMPUTE_FAILED, UNREADABLE, artifact_kind, open_artifact


def _first_race(paths: list[Path]):
    """(path, artifact) of the first readable race record that finished and holds the ego's states."""
    for p in paths:
        try:
            art = open_artifact(p, "h2h_run")
        except UNREADABLE:
            continue
        if art.attrs.get("ok", True) and "ego" in art.arrays:
            return p, art
    return None


def h2h_section(found: Found, max_error_samples: int = 20) -> Section | None:
    tables = found.of("h2h_table")
    records = found.of("h2h_run")
    if not tables and not records:
        return None
    sec = Section("h2h", "Head-to-head")
    if tables:
        tab = found.json[tables[0]]
        err = tab.get("ey_error") or {}
        err = {k: v for k, v in err.items() if v.get("mean")}
        if err:
            dt = (tab.get("settings") or {}).get("config", {}).get("dt", 0.1)
            sec.add_figure("opponent_pred_errors", "Opponent e_y prediction error against steps ahead: mean and "
                           "+-1 std over all closed-loop opponent trajectories", lambda: F.fig_pred_errors(err, dt))
        else:
            sec.missing.append(f"{tables[0]}: no offline prediction errors in the table")
        racing = tab.get("racing") or {}
        if racing:
            from gprace.h2h.protocol import failed_races_text

            rows = []
            for p, r in racing.items():
                e = (tab.get("ey_error") or {}).get(p, {})
                m = e.get("mean") or []
                rows.append([p, r.get("runs"), failed_races_text(r), r.get("border_hits"), r.get("collisions"), r.get("overtakes"),
                             _pm(r.get("overtake_time_mean"), r.get("overtake_time_std")),
                             m[0] if m else float("nan"), m[-1] if m else float("nan")])
            for p, e in (tab.get("ey_error") or {}).items():
                if p not in racing and e.get("mean"):
                    rows.append([p, "-", "-", "-", "-", "-", "-", e["mean"][0], e["mean"][-1]])
            sec.items.append(Item(f"Results table ({tables[0].name}; overtake time over the "
                                  f"{tab.get('common_inside', '?')} scenarios every raced predictor finished inside the track)",
                                  html=table(["predictor", "runs", "failed", "border hits", "collisions", "overtakes",
                                              "overtake time [s]", "e_y error 1-step [m]", "e_y error last step [m]"], rows)))
    else:
        sec.missing.append("no table.json (the evaluation did not finish): no results table or error curves")
    evals = [p for p in records if "eval" in p.relative_to(found.root).parts]
    # prefer a race of the exploring predictor, else the first evaluation race, else any race
    evals = sorted(evals, key=lambda q: ("explore" not in q.parent.name, str(q)))[:20]
    shown = _first_race(evals) or _first_race(records[:20])
    if shown:
        p, art = shown
        from gprace.report.single import h2h_track

        track = h2h_track(art.attrs)
        if track is not None:
            sec.add_figure("race", f"One race on its track ({p.parent.name}/{p.name}, predictor "
                           f"{art.attrs.get('predictor')}, end: {art.attrs.get('end_reason')})",
                           lambda: F.fig_race(track, art.arrays["ego"], art.arrays["opp"], art.arrays.get("border_ego"),
                                              title=f"{art.attrs.get('predictor')}"))
            errs = _errors_along(p, art, found, max_error_samples)
            if errs is not None:
                t, E = errs
                sec.add_figure("error_along_run", "1-step and 9-step opponent e_y error along that run",
                               lambda: F.fig_error_along_run(t, E, (1, min(9, min(e.shape[0] for e in E.values())))))
            else:
                sec.missing.append("error along one run: no opponent models found next to the run records")
        else:
            sec.missing.append(f"{p}: cannot rebuild the race's track from its task")
    else:
        sec.missing.append("no finished race record (eval/<predictor>/run_*.h5)")
    return sec


def _pm(m: Any, s: Any) -> str:
    try:
        m, s = float(m), float(s)
    except (TypeError, ValueError):
        return "-"
    return "-" if not np.isfinite(m) else f"{m:.3f} +- {s:.3f}"


def _task_of(attrs) -> dict:
    """A run record's task (stored as JSON text; the artifact reader may already have parsed it)."""
    task = attrs.get("task")
    return json.loads(task) if isinstance(task, str) else task if isinstance(task, dict) else {}


def _stored_errors(p: Path, art) -> dict[str, np.ndarray] | None:
    """The protocol's own error record of race ``p`` (``errors/<predictor>/``), if it is that race's."""
    q = p.parents[2] / "errors" / p.parent.name / p.name if len(p.parents) > 2 else None
    if q is None or not q.exists():
        return None
    try:
        rec = open_artifact(q, "h2h_run")
        if _task_of(rec.attrs).get("record_hash") != art.attrs.get("task_hash"):
            return None
    except (*UNREADABLE, ValueError, KeyError):  # unreadable or older record: recompute
        return None
    return dict(rec.arrays)


def _errors_along(p: Path, art, found: Found, samples: int) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """k-step e_y errors along one record for the constant-velocity predictor and every opponent
    GP model of the same experiment: the protocol's stored errors, else the head-to-head stage's
    offline evaluation run here with fewer samples."""
    out = _stored_errors(p, art)
    if out is not None:
        return _error_series(art, out)
    try:
        from gprace.h2h.protocol import offline_errors_task
    except ImportError:
        return None
    root = next((a for a in p.parents if (a / "models").is_dir()), None)
    models: dict[str, Any] = {"cv": None}
    if root is not None:
        for m in sorted((root / "models").glob("*.h5")):
            if m.stem in ("baseline", "explore", "select") and artifact_kind(m) in ("gp_model",):
                models[m.stem] = str(m)
    task = _task_of(art.attrs)
    if not task:
        return None
    cfg = dict(task.get("config", {}))
    cfg["samples"] = min(int(cfg.get("samples", samples)), samples)

    def errors(models: dict) -> dict:
        return offline_errors_task({"record": str(p), "track": task["track"], "seed": task.get("seed", 0),
                                    "config": cfg, "models": models})["arrays"]

    try:
        out = errors(models)
    except COMPUTE_FAILED:  # fall back to the model that needs no file
        try:
            out = errors({"cv": None})
        except COMPUTE_FAILED:
            return None
    return _error_series(art, out)


def _error_series(art, out: dict) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    E = {k: np.asarray(v) for k, v in out.items() if np.ndim(v) == 2 and np.shape(v)[1]}
    if not E:
        return None
    T = next(iter(E.values())).shape[1]
    t = np.asarray(art.arrays.get("t", np.arange(T + 10) * 0.1))[:T]
    return t, E
