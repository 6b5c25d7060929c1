"""Find gprace results under a folder and turn them into figure inputs, per domain.

Scanning is by content, not by file name: HDF5 files by their ``kind`` attribute, JSON files by
their keys (:func:`gprace.report.inspect.json_kind`). Each domain collector returns a
:class:`Section` with its figures and tables and, for anything it expected but did not find or
could not read, a one-line note; nothing here raises on a partial or odd folder.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from gprace.report import figures as F
from gprace.errors import GpraceError
from gprace.report.inspect import COMPUTE_FAILED, UNREADABLE, artifact_kind, json_kind, key_results, open_artifact


@dataclass
class Item:
    caption: str
    figure: Any = None  # matplotlib Figure
    html: str = ""  # a table or text block (already escaped)
    name: str = ""  # file stem for --png


@dataclass
class Section:
    key: str
    title: str
    items: list[Item] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)

    def add_figure(self, name: str, caption: str, make: Callable[[], Any]) -> None:
        """Add ``make()``; a figure that fails becomes a note naming the error, never a crash."""
        try:
            self.items.append(Item(caption, figure=make(), name=name))
        except COMPUTE_FAILED as exc:  # a report shows what it can
            self.missing.append(f"{caption}: could not be drawn ({type(exc).__name__}: {exc})")


@dataclass
class Found:
    """Result files under a folder, by kind (``kind -> [paths]``) and parsed JSON (path -> obj)."""

    root: Path
    files: dict[str, list[Path]] = field(default_factory=dict)
    json: dict[Path, Any] = field(default_factory=dict)

    def of(self, *kinds: str) -> list[Path]:
        out: list[Path] = []
        for k in kinds:
            out += self.files.get(k, [])
        return sorted(set(out))

    def kinds_like(self, part: str) -> list[Path]:
        return sorted({p for k, ps in self.files.items() if part in k for p in ps})


def scan(root: str | Path) -> Found:
    """Every artifact (``*.h5``, ``*.hdf5``) and result JSON below ``root``, skipping hidden and
    temporary files (an interrupted atomic write leaves ``.name.tmp``)."""
    root = Path(root)
    found = Found(root)
    for p in sorted(root.rglob("*")):
        if not p.is_file() or any(part.startswith(".") for part in p.relative_to(root).parts):
            continue
        suf = p.suffix.lower()
        if suf in (".h5", ".hdf5"):
            k = artifact_kind(p)
            if k is not None:
                found.files.setdefault(k, []).append(p)
        elif suf == ".json":
            try:
                obj = json.loads(p.read_text())
            except (OSError, UnicodeDecodeError, ValueError):
                continue
            found.json[p] = obj
            found.files.setdefault(json_kind(obj), []).append(p)
    return found


# ----------------------------------------------------------------------------------------------
# helpers
ITER_RE = r"^it(?:er(?:ation)?)?[_-]?(\d+)$"  # iter_03, iteration-3, it3
TRIAL_RE = r"^trial[_-]?(\d+)$"


def _num(path: Path, pattern: str) -> int | None:
    """The number in the last path component matching ``pattern`` (e.g. ``iter_03`` -> 3)."""
    for part in reversed(path.parts):
        m = re.search(pattern, part)
        if m:
            return int(m.group(1))
    return None


def _iteration_of(path: Path, meta: dict) -> int | None:
    for k in ("iteration", "iter"):
        if k in meta and isinstance(meta[k], (int, float)):
            return int(meta[k])
    return _num(path, ITER_RE)


def _trial_of(path: Path, meta: dict) -> int:
    for k in ("trial",):
        if k in meta and isinstance(meta[k], (int, float)):
            return int(meta[k])
    n = _num(path, TRIAL_RE)
    if n is not None:
        return n
    return int(meta.get("seed", 0) or 0)


def _table(headers: list[str], rows: list[list[Any]]) -> str:
    import html

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "-" if not np.isfinite(v) else f"{v:.4g}"
        if isinstance(v, (list, tuple)):
            return ", ".join(cell(x) for x in v)
        return html.escape(str(v))

    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _load_track(name: Any, override: str | None):
    from gprace.report.single import try_track

    return try_track(override) if override else try_track(name)


# ----------------------------------------------------------------------------------------------
# time trial
def _variant_name(root: Path, settings: Any, summary: Any) -> str:
    """``baseline`` for random selection without exploration, ``exploration`` when alphas > 0,
    else the folder name (a folder named *baseline* or *explor* says it directly)."""
    name = root.name.lower()
    if "baseline" in name:
        return "baseline"
    if "explor" in name:
        return "exploration"
    st = settings if isinstance(settings, dict) else (summary or {}).get("settings") if isinstance(summary, dict) else None
    if isinstance(st, dict):
        alphas = st.get("alphas", st.get("alpha"))
        alphas = alphas if isinstance(alphas, (list, tuple)) else [alphas] if isinstance(alphas, (int, float)) else []
        if st.get("selection") == "random" and not any(float(x) > 0 for x in alphas):
            return "baseline"
        if any(float(x) > 0 for x in alphas):
            return "exploration"
    return root.name or "time trial"


_KEYS = {
    "iteration": ("iteration", "iter", "it"),
    "trial": ("trial", "seed"),
    "planned": ("planned", "planned_lap_time", "lap_time_planned", "plan_lap_time"),
    "driven": ("driven", "driven_lap_time", "lap_time_driven", "lap_time"),
}


def _rows_in(obj: Any) -> list[dict]:
    """The longest list of dicts inside a summary JSON that carries an iteration field."""
    best: list[dict] = []

    def visit(o: Any) -> None:
        nonlocal best
        if isinstance(o, list) and o and all(isinstance(x, dict) for x in o):
            if any(any(k in x for k in _KEYS["iteration"]) for x in o) and len(o) > len(best):
                best = o
            for x in o:
                visit(x)
        elif isinstance(o, dict):
            for v in o.values():
                visit(v)

    visit(obj)
    return best


def _get(row: dict, what: str) -> Any:
    for k in _KEYS[what]:
        if k in row:
            return row[k]
    return None


def _gp_errors(row: dict) -> dict[str, float]:
    """``{"planning": e, "tracking": e}`` from a summary row's GP-error fields (``err_tracking``,
    or nested ``{"gp_error": {"tracking": e}}``)."""
    out: dict[str, float] = {}
    for k, v in row.items():
        kl = k.lower()
        if isinstance(v, dict) and ("err" in kl or "rmse" in kl):
            for g, e in v.items():
                if isinstance(e, (int, float)):
                    out[str(g)] = float(e)
                elif isinstance(e, dict):  # per output: average
                    vals = [float(x) for x in e.values() if isinstance(x, (int, float))]
                    if vals:
                        out[str(g)] = float(np.mean(vals))
        elif isinstance(v, (int, float)) and ("err" in kl or "rmse" in kl):
            for g in ("planning", "tracking"):
                if g in kl:
                    out[g] = float(v)
    return out


def _read_json(p: Path) -> Any:
    try:
        return json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return None


def _iteration_record(p: Path) -> dict | None:
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
    for p in found.of("timetrial_summary"):
        if p.name == "summary.json" or (p.parent / "settings.json").exists():
            roots.setdefault(p.parent, {})
    for p in found.of("run") + found.of("plan"):
        r = _iterate_root(p, found.root)
        if r is not None and any(re.match(ITER_RE, x) for x in p.relative_to(r).parts[:-1]):
            roots.setdefault(r, {})
    for root, v in roots.items():
        v["root"] = root
        v["summary"] = _read_json(root / "summary.json") if (root / "summary.json").exists() else None
        settings = _read_json(root / "settings.json") if (root / "settings.json").exists() else None
        v["name"] = _variant_name(root, settings, v["summary"])
        v["rows"] = _rows_in(v["summary"]) if v["summary"] is not None else []
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
                it = _iteration_of(rel, art.attrs)
                if it is not None:  # runs outside iter_<i> (the held-out test run) are no laps of the loop
                    v["runs"].append((p, art, it, _trial_of(rel, art.attrs)))
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
            track = _load_track(art.attrs.get("track"), track_override)
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
        for r in v["rows"]:
            it, pl, dr = _get(r, "iteration"), _get(r, "planned"), _get(r, "driven")
            if dr is None and r.get("completed") is False:
                dr = float("nan")  # a failed lap stays in the figure's counts (null in summary.json)
            if isinstance(it, (int, float)) and isinstance(pl, (int, float)) and isinstance(dr, (int, float)):
                L["iteration"].append(float(it))
                L["planned"].append(float(pl))
                L["driven"].append(float(dr))
                table_rows.append([name, int(it), _get(r, "trial"), r.get("alpha", "-"), float(pl), float(dr),
                                   float(dr) - float(pl), r.get("border_hits", "-"), _lap_status(r)])
            if r.get("completed") is False:
                sec.missing.append(f"{name}, iteration {it}, trial {_get(r, 'trial')}: lap not completed"
                                   + (f" ({r['reason']})" if r.get("reason") else ""))
            errs = _gp_errors(r)
            if errs and isinstance(it, (int, float)):
                n = len(E["iteration"])
                E["iteration"].append(float(it))
                for g, e in errs.items():
                    E.setdefault(g, [np.nan] * n).append(e)
                for g in E:
                    if g != "iteration" and len(E[g]) < n + 1:
                        E[g].append(np.nan)
        if not L["iteration"]:  # no records: lap times from the run artifacts
            for p, art, it, trial in v["runs"]:
                pl, dr = art.attrs.get("planned_lap_time"), art.attrs.get("lap_time")
                if it is not None and isinstance(pl, (int, float)) and isinstance(dr, (int, float)):
                    L["iteration"].append(float(it))
                    L["planned"].append(float(pl))
                    L["driven"].append(float(dr))
                    table_rows.append([name, it, trial, art.attrs.get("alpha", "-"), float(pl), float(dr),
                                       float(dr) - float(pl), art.attrs.get("border_hit_steps", "-"), _lap_status(art.attrs)])
            if L["iteration"]:
                v["rows_from"] = "run files"
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
                              f"{failed or 'none'})", html=_table(
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
        track = _load_track(art.attrs.get("track"), track_override)
        if track is not None:
            a = art.arrays
            sec.add_figure("driven_line", f"Driven line coloured by speed, border hits marked ({p.name}"
                           + (f", iteration {it}" if it is not None else "") + ")",
                           lambda: F.fig_track_speed(track, a["s"], a["e_y"], a["v_x"], a.get("border_hit"),
                                                     title=p.name))
        else:
            sec.missing.append(f"{p}: track {art.attrs.get('track')!r} cannot be loaded; pass --track for the map")


def _lap_status(r: dict) -> str:
    """'completed', or 'failed' and where (the reason names the place: 'the car spun at s = ...')."""
    if r.get("completed", True) is not False:
        return "completed"
    return f"failed: {r['reason']}" if r.get("reason") else "failed"


def _expected_iterations(v: dict) -> int | None:
    """Iterations the experiment asked for (iteration 0 included), from its settings."""
    st = (v.get("summary") or {}).get("settings") if isinstance(v.get("summary"), dict) else None
    if st is None and (v["root"] / "settings.json").exists():
        st = _read_json(v["root"] / "settings.json")
    if isinstance(st, dict) and isinstance(st.get("iterations"), int):
        return int(st["iterations"]) + 1
    return None


def _nearest_plan(run_path: Path, found: Found) -> Path | None:
    plans = found.of("plan")
    for d in run_path.parents:
        here = [p for p in plans if p.parent == d]
        if here:
            return here[0]
        if d == found.root:
            break
    return None


# ----------------------------------------------------------------------------------------------
# head-to-head

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
                                  html=_table(["predictor", "runs", "failed", "border hits", "collisions", "overtakes",
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


# ----------------------------------------------------------------------------------------------
# diagnosis
def diagnosis_section(found: Found) -> Section | None:
    reports = found.of("diagnosis")
    residuals = found.kinds_like("diagnos") + found.kinds_like("residual")
    if not reports and not residuals:
        return None
    sec = Section("diagnosis", "Diagnosis")
    for rp in reports:
        d = found.json[rp]
        eff = d.get("effects") or []
        sec.items.append(Item(f"{rp.name}: verdict", html=_diag_summary(d)))
        res = _residual_data(rp, residuals)
        why = ""
        if res is None:
            res, why = _recompute_residuals(rp, d)
        if res is not None:
            s, before, after, length = res
            sec.add_figure(f"residual_{rp.stem}", "Residual along the track, nominal model and augmented model "
                           "(located windows shaded)", lambda: F.fig_residual_track(s, before, after, d.get("regions", [])))
        else:
            sec.missing.append(f"{rp.name}: residual-along-track plot not drawn ({why or 'no residual data'})")
        sec.add_figure(f"channels_{rp.stem}", "Channels with structured error and the windows where it sits",
                       lambda d=d: F.fig_channels(d.get("channels", []), d.get("regions", [])))
        if eff:
            sec.add_figure(f"parameters_{rp.stem}", "Fitted parameters with 95 % intervals",
                           lambda eff=eff: F.fig_parameters(eff))
    if not reports:
        sec.missing.append("no diagnosis JSON (`gprace diagnose --json > diagnosis.json`)")
    return sec


def _diag_summary(d: dict) -> str:
    import html

    parts = [f"<p><b>verdict:</b> {html.escape(str(d.get('verdict')))}"]
    if "explained_share" in d:
        parts.append(f"; share of the structured error explained: {100 * float(d['explained_share']):.0f} %")
    if d.get("augmented_vehicle"):
        parts.append(f"; augmented vehicle: <code>{html.escape(str(d['augmented_vehicle']))}</code>")
    parts.append("</p>")
    rows = [[c.get("name"), "yes" if c.get("structured") else "no", c.get("statistic"), c.get("rmse_nominal"),
             c.get("heldout_rmse_nominal", "-"), c.get("heldout_rmse_augmented", "-")] for c in d.get("channels", [])]
    parts.append(_table(["channel", "structured", "statistic", "RMSE nominal", "held-out RMSE before",
                         "held-out RMSE after"], rows))
    erow = []
    for e in d.get("effects", []):
        ps = "; ".join(f"{k} = {float(v['value']):.4g} [{float(v['ci95'][0]):.4g}, {float(v['ci95'][1]):.4g}] {v.get('unit', '')}"
                       for k, v in (e.get("parameters") or {}).items() if isinstance(v, dict) and "ci95" in v)
        erow.append([e.get("name"), ps, ", ".join(e.get("channels", [])), e.get("improvement"),
                     ", ".join(e.get("ambiguous_with", [])) or "-"])
    if erow:
        parts.append(_table(["effect", "parameters (95 % interval)", "channels", "improvement", "ambiguous with"], erow))
    if d.get("unexplained"):
        parts.append("<p><b>unexplained:</b> " + html.escape(", ".join(f"{k}: {v:.3g}" for k, v in d["unexplained"].items()))
                     + "</p>")
    rg = d.get("regions") or []
    if rg:
        parts.append(_table(["channel", "s start [m]", "s end [m]", "description"],
                            [[r.get("channel"), r.get("s_start"), r.get("s_end"), r.get("description", "")] for r in rg]))
    for n in d.get("notes", []) or []:
        parts.append(f"<p class='note'>{html.escape(str(n))}</p>")
    return "".join(parts)


def _recompute_residuals(report_path: Path, d: dict) -> tuple[Any, str]:
    """Mean multi-step prediction error along the track, nominal and augmented model, from the
    recordings next to the diagnosis JSON (run artifacts or CSV runs in the same folder).

    The nominal vehicle is the one the recordings embed (else the augmented file without the
    named effects); the augmented one is the JSON's ``augmented_vehicle`` file (looked up next
    to the JSON, then from the working folder). Returns ``((s, before, after, None), "")`` or
    ``(None, reason)``.
    """
    try:
        from gprace.config import load_vehicle
        from gprace.diagnose import core
        from gprace.diagnose.locate import track_profile
        from gprace.io.runs import read_run
        from gprace.model import NominalModel
    except ImportError as exc:
        return None, f"diagnosis code unavailable: {exc}"
    folder = report_path.parent
    recs = sorted(p for p in folder.iterdir() if p.is_file() and (
        (p.suffix.lower() in (".h5", ".hdf5") and artifact_kind(p) == "run") or p.suffix.lower() == ".csv"))
    runs = []
    for p in recs:
        try:
            runs.append(read_run(p))
        except UNREADABLE:  # a CSV that is not a run
            continue
    if not runs:
        return None, f"no recordings next to {report_path.name}"
    aug = None
    name = d.get("augmented_vehicle")
    if name:
        for cand in (Path(name), folder / Path(name).name, folder / name):
            if cand.exists():
                try:
                    aug = load_vehicle(str(cand))
                except UNREADABLE:
                    aug = None
                break
    try:
        nom = runs[0].vehicle()
    except UNREADABLE:
        nom = None
    if nom is None and aug is not None:
        k = len(d.get("effects") or [])
        nom = aug.model_copy(update={"effects": tuple(aug.effects)[: len(aug.effects) - k]})
    if nom is None:
        return None, "the recordings embed no vehicle and no augmented vehicle file was found"
    try:
        H = int(d.get("horizon", 15))
        data = core.build_dataset(runs, min_samples=max(2 * H, 10))
        starts = data.windows(H)
        starts = starts[:: max(1, len(starts) // 4000)]
        out = {}
        for key, veh in (("before", nom), ("after", aug)):
            if veh is None:
                continue
            E = core.errors(data, starts, core.predict(NominalModel(veh), data, starts, H, 2))
            out[key] = {}
            for c, ch in enumerate(("v_x", "v_y", "yaw_rate")):
                sb, e = track_profile(data, starts, H, E, c)
                out[key][ch] = e
        return (sb, out["before"], out.get("after"), None), ""
    except COMPUTE_FAILED as exc:
        return None, f"recomputing the residuals failed: {type(exc).__name__}: {exc}"


def _residual_data(report_path: Path, residuals: list[Path]):
    """``(s, before, after, length)`` from a residual artifact in the report's folder (arrays
    ``s`` and ``before/<channel>``, ``after/<channel>``, or ``residual_before``/``residual_after``
    of shape (n, channels) with attribute ``channels``)."""
    for p in sorted(residuals, key=lambda q: (q.parent != report_path.parent, str(q))):
        try:
            art = open_artifact(p)
        except UNREADABLE:
            continue
        a = dict(art.arrays)
        for g in art.groups.values():
            a.update(g)
        if "s" not in a:
            continue
        before = {k.split("/", 1)[1]: v for k, v in a.items() if k.startswith("before/")}
        after = {k.split("/", 1)[1]: v for k, v in a.items() if k.startswith("after/")}
        if not before and "residual_before" in a:
            ch = art.attrs.get("channels") or [f"c{i}" for i in range(np.shape(a["residual_before"])[1])]
            before = {c: a["residual_before"][:, i] for i, c in enumerate(ch)}
            if "residual_after" in a:
                after = {c: a["residual_after"][:, i] for i, c in enumerate(ch)}
        if before:
            return a["s"], before, after or None, art.attrs.get("track_length")
    return None


# ----------------------------------------------------------------------------------------------
# GP models and datasets
def gp_section(found: Found, features: tuple[str, str] | None = None, max_models: int = 4) -> Section | None:
    models = found.of("gp_model")
    datasets = found.kinds_like("dataset")
    if not models and not datasets:
        return None
    sec = Section("gp", "Gaussian processes")
    from gprace.report.single import load_gp, pick_features

    rows = []
    for p in models:
        try:
            info = key_results(open_artifact(p, "gp_model"))
        except UNREADABLE as exc:
            sec.missing.append(f"{p}: unreadable model ({exc})")
            continue
        rows.append([str(p.relative_to(found.root)), info.get("backend"), info.get("kernel"), info.get("dictionary_size"),
                     ", ".join(map(str, info.get("input_names", []))), ", ".join(map(str, info.get("output_names", [])))])
    if rows:
        sec.items.append(Item("Models", html=_table(["model", "backend", "kernel", "dictionary", "inputs", "outputs"], rows)))
    if len(models) > max_models:
        sec.missing.append(f"{len(models)} models found; posterior plots drawn for {max_models} of the latest "
                           "iteration (first trial)")

    def latest(p: Path) -> tuple:
        rel = p.relative_to(found.root)
        it = _num(rel.parent, ITER_RE)
        return (-(it if it is not None else -1), _num(rel.parent, TRIAL_RE) or 0, str(rel))

    for p in sorted(models, key=latest)[:max_models]:
        def make(p=p):
            gp, names_in, names_out, Zd = load_gp(p)
            if Zd is None:
                raise ValueError("the model stores no dictionary points")
            try:
                i, j = pick_features(names_in, features)
            except GpraceError:  # features of another GP
                i, j = pick_features(names_in)
            return F.fig_gp_posterior(gp.predict, Zd, names_in, names_out, i, j, title=str(p.relative_to(found.root)))

        sec.add_figure(f"gp_{'_'.join(p.relative_to(found.root).with_suffix('').parts)}",
                       f"{p.relative_to(found.root)}: posterior mean and standard deviation over two features "
                       "(others at the dictionary median), dictionary points in black", make)
    for p in datasets[:2]:
        def make_d(p=p):
            art = open_artifact(p)
            names_in = [str(x) for x in art.attrs.get("inputs", art.attrs.get("input_names", []))]
            names_out = [str(x) for x in art.attrs.get("outputs", art.attrs.get("output_names", []))]
            return F.fig_dataset(art.arrays["Z"], art.arrays["Y"], names_in, names_out, title=str(p.relative_to(found.root)))

        sec.add_figure(f"data_{'_'.join(p.relative_to(found.root).with_suffix('').parts)}",
                       f"{p.relative_to(found.root)}: inputs of the dataset coloured by output", make_d)
    return sec
