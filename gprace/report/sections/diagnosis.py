"""The report's diagnosis section: verdict, residual along the track, channels, parameters."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gprace.report import figures as F
from gprace.report.collect import Found, Item, Section, table
from gprace.report.inspect import COMPUTE_FAILED, UNREADABLE, artifact_kind, open_artifact


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
    parts.append(table(["channel", "structured", "statistic", "RMSE nominal", "held-out RMSE before",
                        "held-out RMSE after"], rows))
    erow = []
    for e in d.get("effects", []):
        ps = "; ".join(f"{k} = {float(v['value']):.4g} [{float(v['ci95'][0]):.4g}, {float(v['ci95'][1]):.4g}] {v.get('unit', '')}"
                       for k, v in (e.get("parameters") or {}).items() if isinstance(v, dict) and "ci95" in v)
        erow.append([e.get("name"), ps, ", ".join(e.get("channels", [])), e.get("improvement"),
                     ", ".join(e.get("ambiguous_with", [])) or "-"])
    if erow:
        parts.append(table(["effect", "parameters (95 % interval)", "channels", "improvement", "ambiguous with"], erow))
    if d.get("unexplained"):
        parts.append("<p><b>unexplained:</b> " + html.escape(", ".join(f"{k}: {v:.3g}" for k, v in d["unexplained"].items()))
                     + "</p>")
    rg = d.get("regions") or []
    if rg:
        parts.append(table(["channel", "s start [m]", "s end [m]", "description"],
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
