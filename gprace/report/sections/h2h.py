"""The report's head-to-head section: the results table, error curves, one race.

It reads what the protocol stored (the table, the race records, their offline error records,
through :mod:`gprace.h2h.records`) and simulates nothing: a race without its stored errors gets a
note instead of the error figure. Records of an older layout are read as they are (one warning).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gprace.h2h.records import ErrorAttrs, RaceAttrs, Record, read_record, warn_old
from gprace.report import figures as F
from gprace.report.collect import Found, Item, Section, table
from gprace.report.inspect import UNREADABLE


def _first_race(paths: list[Path], old: list[Path]) -> tuple[Path, Record[RaceAttrs]] | None:
    """(path, record) of the first readable race record that finished and holds the ego's states;
    the paths of records of an older layout read on the way go to ``old``."""
    for p in paths:
        try:
            rec = read_record(p, RaceAttrs, warn=False)
        except UNREADABLE:
            continue
        old += [p] if rec.old else []
        if rec.attrs.ok and "ego" in rec.arrays:
            return p, rec
    return None


def h2h_section(found: Found) -> Section | None:
    tables = found.of("h2h_table")
    records = found.of("h2h_run")
    if not tables and not records:
        return None
    sec = Section("h2h", "Head-to-head")
    if tables:
        _table_items(sec, tables[0], found.json[tables[0]])
    else:
        sec.missing.append("no table.json (the evaluation did not finish): no results table or error curves")
    evals = [p for p in records if "eval" in p.relative_to(found.root).parts]
    # prefer a race of the exploring predictor, else the first evaluation race, else any race
    evals = sorted(evals, key=lambda q: ("explore" not in q.parent.name, str(q)))[:20]
    old: list[Path] = []
    shown = _first_race(evals, old) or _first_race(records[:20], old)
    if shown:
        _race_figures(sec, *shown, old)
    else:
        sec.missing.append("no finished race record (eval/<predictor>/run_*.h5)")
    warn_old(old, migrated=False)
    return sec


def _race_figures(sec: Section, p: Path, rec: Record[RaceAttrs], old: list[Path]) -> None:
    """One race on its track and the stored offline errors along it (or notes saying what is missing)."""
    from gprace.report.single import h2h_track

    track = h2h_track(rec.attrs)
    if track is None:
        sec.missing.append(f"{p}: cannot rebuild the race's track from its task")
        return
    a = rec.attrs
    sec.add_figure("race", f"One race on its track ({p.parent.name}/{p.name}, predictor {a.predictor}, end: {a.end_reason})",
                   lambda: F.fig_race(track, rec.arrays["ego"], rec.arrays["opp"], rec.arrays.get("border_ego"),
                                      title=a.predictor))
    errs, why = _errors_along(p, rec, old)
    if errs is not None:
        t, E = errs
        sec.add_figure("error_along_run", "1-step and 9-step opponent e_y error along that run",
                       lambda: F.fig_error_along_run(t, E, (1, min(9, min(e.shape[0] for e in E.values())))))
    else:
        sec.missing.append(f"error along {p.parent.name}/{p.name}: the folder holds no stored offline errors for this "
                           f"race ({why}); `gprace eval head2head` writes them")


def _table_items(sec: Section, path: Path, data: Any) -> None:
    """The error curves and the results table of ``table.json``, read through its schema."""
    from gprace.h2h.table import failed_races_text, parse_table

    try:
        tab = parse_table(data, str(path))
    except UNREADABLE as exc:
        sec.missing.append(str(exc))
        return
    err = {p: e.model_dump() for p, e in tab.ey_error.items() if e.mean}
    if err:
        dt = tab.settings.get("config", {}).get("dt", 0.1)  # the race's period (H2HConfig.dt unless set)
        sec.add_figure("opponent_pred_errors", "Opponent e_y prediction error against steps ahead: mean and "
                       "+-1 std over all closed-loop opponent trajectories", lambda: F.fig_pred_errors(err, dt))
    else:
        sec.missing.append(f"{path}: no offline prediction errors in the table")
    if not tab.racing:
        return
    rows = []
    for p, r in tab.racing.items():
        m = tab.ey_error[p].mean if p in tab.ey_error else []
        rows.append([p, r.runs, failed_races_text(r), r.border_hits, r.collisions, r.overtakes,
                     _pm(r.overtake_time_mean, r.overtake_time_std), m[0] if m else np.nan, m[-1] if m else np.nan])
    rows += [[p, "-", "-", "-", "-", "-", "-", e.mean[0], e.mean[-1]]
             for p, e in tab.ey_error.items() if p not in tab.racing and e.mean]
    sec.items.append(Item(f"Results table ({path.name}; overtake time over the {tab.common_inside} scenarios every "
                          "raced predictor finished inside the track)",
                          html=table(["predictor", "runs", "failed", "border hits", "collisions", "overtakes",
                                      "overtake time [s]", "e_y error 1-step [m]", "e_y error last step [m]"], rows)))


def _pm(m: Any, s: Any) -> str:
    try:
        m, s = float(m), float(s)
    except (TypeError, ValueError):
        return "-"
    return "-" if not np.isfinite(m) else f"{m:.3f} +- {s:.3f}"


def _error_path(p: Path) -> Path | None:
    """Where the protocol stores the offline errors of the evaluation race ``p``
    (``eval/<predictor>/run_i.h5`` -> ``errors/<predictor>/run_i.h5``)."""
    return p.parents[2] / "errors" / p.parent.name / p.name if len(p.parents) > 2 else None


def _errors_along(p: Path, rec: Record[RaceAttrs], old: list[Path]) -> tuple[tuple | None, str]:
    """k-step e_y errors along race ``p`` from the protocol's stored error record of that race:
    ``((t, {predictor: (K, start times)}), "")``, or ``(None, why there are none)``. Computes
    nothing (the report never simulates)."""
    q = _error_path(p)
    if q is None or not q.exists():
        return None, f"no {q.relative_to(p.parents[2]) if q else 'errors/ folder'}"
    try:
        err = read_record(q, ErrorAttrs, warn=False)
    except UNREADABLE as exc:
        return None, f"unreadable: {exc}"
    old += [q] if err.old else []
    if not err.attrs.ok:
        return None, f"{q.name}: the error computation failed"
    if err.attrs.record_hash != rec.attrs.task_hash:
        return None, f"{q.name} is of another race"
    series = _error_series(rec, err.arrays)
    return (series, "") if series is not None else (None, f"{q.name} holds no error arrays")


def _error_series(rec: Record, out: dict) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    E = {k: np.asarray(v) for k, v in out.items() if np.ndim(v) == 2 and np.shape(v)[1]}
    if not E:
        return None
    T = next(iter(E.values())).shape[1]
    t = np.asarray(rec.arrays.get("t", np.arange(T + 10) * 0.1))[:T]
    return t, E
