"""The report's time-trial section: lap times and GP errors per iteration, exploration, driven lines."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gprace.report import figures as F
from gprace.report.collect import ITER_RE, TRIAL_RE, Found, Item, Section, load_track, path_number, table
from gprace.report.inspect import UNREADABLE, open_artifact

if TYPE_CHECKING:
    from gprace.timetrial.record import IterateSummary, IterationRecord


def _iteration_of(path: Path) -> int | None:
    """The iteration of a file of an iterate folder, from its ``iter_<i>`` folder (the layout of
    ``gprace iterate``); None outside one."""
    return path_number(path, ITER_RE)


def _trial_of(path: Path) -> int:
    """The trial of a file of an iterate folder, from its ``trial_<j>`` folder (0 without one)."""
    n = path_number(path, TRIAL_RE)
    return 0 if n is None else n


def _variant_name(root: Path, settings: dict | None) -> str:
    """``baseline`` for random selection without exploration, ``exploration`` when alphas > 0,
    else the folder name (a folder named *baseline* or *explor* says it directly)."""
    name = root.name.lower()
    if "baseline" in name:
        return "baseline"
    if "explor" in name:
        return "exploration"
    if settings is not None:
        explores = any(float(x) > 0 for x in settings["alphas"])
        if settings["selection"] == "random" and not explores:
            return "baseline"
        if explores:
            return "exploration"
    return root.name or "time trial"


def _settings(root: Path, summary: IterateSummary | None) -> tuple[dict | None, str]:
    """The experiment of an iterate folder (settings.json, else the summary's copy), read through
    :class:`IterateSettings`; (None, why) if there is none or it is of another layout."""
    from pydantic import ValidationError

    from gprace.timetrial.iterate import IterateSettings

    p = root / "settings.json"
    try:
        data = json.loads(p.read_text()) if p.exists() else summary.settings if summary else None
        return (None, "") if data is None else (IterateSettings.model_validate(data).model_dump(), "")
    except (OSError, ValueError, ValidationError) as exc:  # a ValidationError is a ValueError; named for the reader
        return None, f"{p}: not readable as the settings of this gprace ({str(exc).splitlines()[0]})"


def _summary(root: Path) -> tuple[IterateSummary | None, str]:
    """summary.json through its schema; (None, why) if missing or of another layout."""
    from gprace.timetrial.record import read_summary

    p = root / "summary.json"
    if not p.exists():
        return None, ""
    try:
        return read_summary(p), ""
    except UNREADABLE as exc:
        return None, str(exc)


def _iteration_record(p: Path) -> IterationRecord | None:
    """A time-trial iteration record through its schema (None if it is not one; never rewritten)."""
    from gprace.timetrial.record import read_record

    try:
        return read_record(p, migrate=False)
    except UNREADABLE:
        return None


def _iterate_root(p: Path, top: Path) -> Path | None:
    """The iterate folder of an artifact: the nearest ancestor with settings.json or summary.json,
    else the folder above its ``iter_<i>`` (and ``trial_<j>``) folders; None outside any."""
    for a in p.parents:
        if (a / "settings.json").exists() or (a / "summary.json").exists():
            return a
        if a == top:
            break
    rel = p.relative_to(top).parts[:-1]
    for k in range(len(rel) - 1, -1, -1):
        if re.match(ITER_RE, rel[k]):
            up = k - 1 if k >= 1 and re.match(TRIAL_RE, rel[k - 1]) else k
            return top.joinpath(*rel[:up])
    return None


def timetrial_variants(found: Found) -> dict[Path, dict[str, Any]]:
    """Per iterate folder: ``{"name", "summary", "rows", "runs": [(path, art, it, trial)], "plans"}``.

    A folder is an iterate folder when it holds ``settings.json`` / ``summary.json`` (the layout
    of ``gprace iterate``) or run artifacts under ``iter_<i>`` folders. Rows (one per iteration and
    trial) come from summary.json, else from the per-iteration ``record.json`` files of an
    interrupted loop, else from the run artifacts' lap times.
    """
    roots: dict[Path, dict[str, Any]] = {}
    for p in found.of("timetrial_summary", "iterate_settings"):
        if p.name in ("summary.json", "settings.json") or (p.parent / "settings.json").exists():
            roots.setdefault(p.parent, {})
    for p in found.of("run") + found.of("plan"):
        r = _iterate_root(p, found.root)
        if r is not None and any(re.match(ITER_RE, x) for x in p.relative_to(r).parts[:-1]):
            roots.setdefault(r, {})
    for root, v in roots.items():
        v["root"] = root
        v["summary"], why_summary = _summary(root)
        v["settings"], why_settings = _settings(root, v["summary"])
        v["notes"] = [w for w in (why_summary, why_settings) if w]
        v["name"] = _variant_name(root, v["settings"])
        v["rows"] = list(v["summary"].rows) if v["summary"] is not None else []
        v["rows_from"] = "summary.json" if v["rows"] else ""
        if not v["rows"]:
            recs = [_iteration_record(q) for q in sorted(root.glob("**/record.json"))]
            v["rows"] = [r for r in recs if r is not None]
            v["rows_from"] = "record.json files" if v["rows"] else ""
        v["runs"], v["plans"] = [], []
        for p in found.of("run"):
            if root in p.parents and _iterate_root(p, found.root) == root:
                rel = p.relative_to(root)
                try:
                    art = open_artifact(p, "run")
                except UNREADABLE:
                    continue
                it = _iteration_of(rel)
                if it is not None:  # runs outside iter_<i> (the held-out test run) are no laps of the loop
                    v["runs"].append((p, art, it, _trial_of(rel)))
        v["plans"] = [p for p in found.of("plan") if root in p.parents]
    # exploration first (blue), baseline second (orange), then the rest by folder
    order = {"exploration": 0, "baseline": 1}
    roots = dict(sorted(roots.items(), key=lambda kv: (order.get(kv[1]["name"], 2), str(kv[0]))))
    seen: dict[str, int] = {}
    for v in roots.values():
        n = v["name"]
        seen[n] = seen.get(n, 0) + 1
        if seen[n] > 1:
            v["name"] = f"{n} {seen[n]}"
    return roots


def timetrial_section(found: Found, track_override: str | None = None) -> Section | None:
    variants = timetrial_variants(found)
    loose_runs = [p for p in found.of("run") if not any(r in p.parents for r in variants)]
    loose_plans = [p for p in found.of("plan") if not any(r in p.parents for r in variants)]
    if not variants and not loose_runs and not loose_plans:
        return None
    sec = Section("timetrial", "Time trial")
    lap, gperr, table_rows = _iteration_rows(sec, variants)
    _lap_and_error_figures(sec, variants, lap, gperr, table_rows)
    all_runs = [r for v in variants.values() for r in v["runs"]]
    _exploration_figure(sec, found, variants, all_runs)
    _driven_line_figure(sec, all_runs, loose_runs, track_override)
    if not variants:
        for p in loose_plans[:2]:
            art = open_artifact(p, "plan")
            track = load_track(art.attrs.get("track"), track_override)
            sec.add_figure(f"plan_{p.stem}", f"Plan {p.name}: lap time {float(art.attrs.get('lap_time', np.nan)):.2f} s",
                           lambda art=art, track=track, p=p: F.fig_plan(art.arrays, track, title=p.name))
    return sec


def _iteration_rows(sec: Section, variants: dict) -> tuple[dict, dict, list]:
    """Per variant: lap times and GP errors per iteration (from the records, else from the run
    files), the table's rows; what is missing goes to ``sec.missing``."""
    lap: dict[str, dict[str, list[float]]] = {}
    gperr: dict[str, dict[str, list[float]]] = {}
    table_rows = []
    for root, v in variants.items():
        name = v["name"]
        L = lap.setdefault(name, {"iteration": [], "planned": [], "driven": []})
        E = gperr.setdefault(name, {"iteration": []})
        for r in v["rows"]:  # IterationRecord (or SummaryRow) models: a failed lap has a NaN driven time
            it = r.iteration
            L["iteration"].append(float(it))
            L["planned"].append(r.planned)
            L["driven"].append(r.driven)
            table_rows.append([name, it, r.trial, r.alpha, r.planned, r.driven, r.gap,
                               r.border_hits, _lap_status(r.completed, r.reason)])
            if not r.completed:
                sec.missing.append(f"{name}, iteration {it}, trial {r.trial}: lap not completed"
                                   + (f" ({r.reason})" if r.reason else ""))
            if it > 0:  # iteration 0 is driven without GPs
                E["iteration"].append(float(it))
                E.setdefault("tracking", []).append(r.err_tracking)
                E.setdefault("planning", []).append(r.err_planning)
        if not L["iteration"]:  # no records: lap times from the run artifacts
            for p, art, it, trial in v["runs"]:
                pl, dr = art.attrs.get("planned_lap_time"), art.attrs.get("lap_time")
                if it is not None and isinstance(pl, (int, float)) and isinstance(dr, (int, float)):
                    L["iteration"].append(float(it))
                    L["planned"].append(float(pl))
                    L["driven"].append(float(dr))
                    table_rows.append([name, it, trial, art.attrs.get("alpha", "-"), float(pl), float(dr),
                                       float(dr) - float(pl), art.attrs.get("border_hit_steps", "-"),
                                       _lap_status(art.attrs.get("completed", True), art.attrs.get("reason"))])
            if L["iteration"]:
                v["rows_from"] = "run files"
        sec.missing += v["notes"]
        if v.get("summary") is None:
            sec.missing.append(f"{root}: no summary.json (loop interrupted?); lap times taken from the "
                               f"{v['rows_from'] or 'run files'}")
        if not L["iteration"]:
            sec.missing.append(f"{root}: no finished lap yet (no run with a lap time)")
        else:
            done = sorted({int(x) for x in L["iteration"]})
            want = _expected_iterations(v)
            if want is not None and len(done) < want:
                sec.missing.append(f"{root} ({name}): {len(done)} of {want} iterations finished")
    return lap, gperr, table_rows


def _lap_and_error_figures(sec: Section, variants: dict, lap: dict, gperr: dict, table_rows: list) -> None:
    """Lap times per iteration (figure and table) and the GPs' errors per iteration."""
    lap = {k: {a: np.asarray(b) for a, b in d.items()} for k, d in lap.items() if d["iteration"]}
    if lap:
        sec.add_figure("lap_times", "Lap time per iteration: planned, driven and their difference (mean and "
                       "+-1 std over trials)", lambda: F.fig_lap_times(lap))
        failed = "; ".join(
            f"{n} iteration {int(x)}: {int(np.sum((d['iteration'] == x) & ~np.isfinite(d['driven'])))}/"
            f"{int(np.sum(d['iteration'] == x))}"
            for n, d in lap.items() for x in np.unique(d["iteration"][~np.isfinite(d["driven"])]))
        sec.items.append(Item("Lap times per iteration and trial (failed laps per iteration: "
                              f"{failed or 'none'})", html=table(
            ["variant", "iteration", "trial", "alpha", "planned [s]", "driven [s]", "driven - planned [s]",
             "border-hit steps", "lap"],
            sorted(table_rows, key=lambda r: (r[0], r[1], r[2] if r[2] is not None else -1)))))
        if len(lap) == 1 and len(variants) == 1:
            sec.missing.append("only one iterate folder: exploration vs baseline comparison needs both "
                               "(run `gprace iterate` again with `--selection random --alpha 0` into a sibling folder)")
    gperr = {k: {a: np.asarray(b, float) for a, b in d.items()} for k, d in gperr.items()
             if any(np.isfinite(np.asarray(e, float)).any() for g, e in d.items() if g != "iteration")}
    if gperr:
        sec.add_figure("gp_errors", "GP prediction error per iteration on the diverse test run, both GPs "
                       "(mean and +-1 std over trials)", lambda: F.fig_gp_errors(gperr))
    elif variants:
        sec.missing.append("GP prediction errors per iteration: not in any summary.json yet")


def _exploration_figure(sec: Section, found: Found, variants: dict, all_runs: list) -> None:
    """The data collected in the first exploration iteration, against its plan."""
    expl = [r for r in all_runs if float(r[1].attrs.get("alpha", 0) or 0) > 0]
    if expl:
        p, art, it, _ = sorted(expl, key=lambda r: (r[2] if r[2] is not None else 0, r[3]))[0]
        plan_p = _nearest_plan(p, found)
        if plan_p is not None:
            plan = open_artifact(plan_p, "plan").arrays
            sec.add_figure("exploration_data", f"Data collected while exploring (iteration {it}, alpha "
                           f"{float(art.attrs.get('alpha')):.3g}): v_y and yaw rate against the plan",
                           lambda: F.fig_exploration_data(art.arrays, plan, title=f"{p.parent.name}/{p.name}"))
        else:
            sec.missing.append(f"{p}: exploration run found but no plan next to it")
    elif variants:
        sec.missing.append("no run driven with exploration (alpha > 0) found")


def _driven_line_figure(sec: Section, all_runs: list, loose_runs: list, track_override: str | None) -> None:
    """The latest run's line coloured by speed (a loose run if no iterate folder has one)."""
    cand = sorted(all_runs, key=lambda r: (r[2] if r[2] is not None else -1, -r[3]))
    pick = cand[-1] if cand else None
    if pick is None and loose_runs:
        try:
            pick = (loose_runs[0], open_artifact(loose_runs[0], "run"), None, 0)
        except UNREADABLE:
            pick = None
    if pick is not None:
        p, art, it, _ = pick
        track = load_track(art.attrs.get("track"), track_override)
        if track is not None:
            a = art.arrays
            sec.add_figure("driven_line", f"Driven line coloured by speed, border hits marked ({p.name}"
                           + (f", iteration {it}" if it is not None else "") + ")",
                           lambda: F.fig_track_speed(track, a["s"], a["e_y"], a["v_x"], a.get("border_hit"),
                                                     title=p.name))
        else:
            sec.missing.append(f"{p}: track {art.attrs.get('track')!r} cannot be loaded; pass --track for the map")


def _lap_status(completed, reason) -> str:
    """'completed', or 'failed' and where (the reason names the place: 'the car spun at s = ...');
    ``completed`` of a record or a run's attributes (only ``False`` is a failed lap)."""
    if completed is not False:
        return "completed"
    return f"failed: {reason}" if reason else "failed"


def _expected_iterations(v: dict) -> int | None:
    """Iterations the experiment asked for (iteration 0 included), from its settings."""
    return v["settings"]["iterations"] + 1 if v["settings"] is not None else None


def _nearest_plan(run_path: Path, found: Found) -> Path | None:
    plans = found.of("plan")
    for d in run_path.parents:
        here = [p for p in plans if p.parent == d]
        if here:
            return here[0]
        if d == found.root:
            break
    return None
