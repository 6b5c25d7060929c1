"""The report's diagnosis section: verdict, residual along the track, channels, parameters."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gprace.diagnose.report import profile_text
from gprace.diagnose.result import DiagnosisResult, Effect, parse_result
from gprace.errors import InputError
from gprace.report import figures as F
from gprace.report.collect import Found, Item, Section, table


def diagnosis_section(found: Found) -> Section | None:
    reports = found.of("diagnosis")
    if not reports:
        return None
    sec = Section("diagnosis", "Diagnosis")
    for rp in reports:
        _add_result(sec, rp, found.json[rp])
    return sec


def _add_result(sec: Section, rp: Path, data: Any) -> None:
    """One diagnosis JSON, read through its schema: the summary, the residual along the track (the
    profile the result stores; never recomputed), the channels and the fitted parameters. A JSON
    the schema refuses is one line in ``missing``."""
    try:
        r = parse_result(data, str(rp))
    except InputError as exc:
        sec.missing.append(f"{rp.name}: not read as a diagnosis result ({exc})")
        return
    d = r.model_dump()
    sec.items.append(Item(f"{rp.name}: verdict", html=_diag_summary(r)))
    prof = r.residual_profile
    if prof is not None:
        sec.add_figure(f"residual_{rp.stem}", "Residual along the track, nominal model and augmented model "
                       "(located windows shaded, noise twin's +-1 sigma band grey); below, the named effects "
                       "that act along the lap with their 95 % intervals",
                       lambda: F.fig_residual_track(prof.s, prof.before, prof.after, d["regions"], noise=prof.noise,
                                                    effects=d["effects"]))
    else:
        sec.missing.append(f"{rp.name}: residual-along-track plot not drawn (the result predates the stored "
                           "residual profile; rerun `gprace diagnose ... --json`)")
        if any(F.along_lap(e) for e in d["effects"]):  # the effects along the lap need only the effects
            sec.add_figure(f"along_lap_{rp.stem}", "Named effects along the lap with their 95 % intervals",
                           lambda: F.fig_effects_along_lap(d["effects"]))
    sec.add_figure(f"channels_{rp.stem}", "Channels with structured error and the windows where it sits",
                   lambda: F.fig_channels(d["channels"], d["regions"]))
    if d["effects"]:
        sec.add_figure(f"parameters_{rp.stem}", "Fitted parameters with 95 % intervals",
                       lambda: F.fig_parameters(d["effects"]))


def _diag_summary(r: DiagnosisResult) -> str:
    import html

    parts = [f"<p><b>verdict:</b> {html.escape(r.verdict)}",
             f"; share of the structured error explained: {100 * r.explained_share:.0f} %"]
    if r.augmented_vehicle:
        parts.append(f"; augmented vehicle: <code>{html.escape(r.augmented_vehicle)}</code>")
    parts.append("</p>")
    rows = [[c.name, "yes" if c.structured else "no", c.statistic, c.rmse_nominal, _or_dash(c.heldout_rmse_nominal),
             _or_dash(c.heldout_rmse_augmented)] for c in r.channels]
    parts.append(table(["channel", "structured", "statistic", "RMSE nominal", "held-out RMSE before",
                        "held-out RMSE after"], rows))
    erow = [[e.name, _parameters_text(e), ", ".join(e.channels), e.improvement, ", ".join(e.ambiguous_with) or "-"]
            for e in r.effects]
    if erow:
        parts.append(table(["effect", "parameters (95 % interval)", "channels", "improvement", "ambiguous with"], erow))
    if r.unexplained:
        parts.append("<p><b>unexplained:</b> " + html.escape(", ".join(f"{k}: {v:.3g}" for k, v in r.unexplained.items()))
                     + "</p>")
    if r.regions:
        parts.append(table(["channel", "s start [m]", "s end [m]", "description"],
                           [[g.channel, g.s_start, g.s_end, g.description] for g in r.regions]))
    parts += [f"<p class='note'>{html.escape(n)}</p>" for n in r.notes]
    return "".join(parts)


def _or_dash(v: float | None) -> Any:
    return "-" if v is None else v


def _parameters_text(e: Effect) -> str:
    text = "; ".join(f"{k} = {p.value:.4g} [{p.ci95[0]:.4g}, {p.ci95[1]:.4g}] {p.unit}" for k, p in e.parameters.items())
    if e.profile is not None:
        text = (text + "; " if text else "") + profile_text(e)
    return text


def plot_residuals(res, path: str | Path) -> Path:
    """The residual-along-track figure of the report (:func:`~gprace.report.figures.fig_residual_track`:
    nominal and augmented model, located windows, the noise twin's +-1 sigma band) as a PNG.
    ``res`` is a :class:`~gprace.diagnose.diagnose.Diagnosis` or its result; the figure is drawn
    from the stored residual profile, nothing is simulated."""
    r = getattr(res, "result", res)
    prof = r.residual_profile
    if prof is None:
        raise InputError("the diagnosis result has no stored residual profile (it predates it); "
                         "rerun `gprace diagnose ... --json`")
    effects = ", ".join(e.name for e in r.effects) or "none"
    fig = F.fig_residual_track(prof.s, prof.before, prof.after, [g.model_dump() for g in r.regions],
                               f"multi-step ({r.horizon} steps) prediction error along the track; effects: {effects}",
                               noise=prof.noise, effects=[e.model_dump() for e in r.effects])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)  # like -o: check_output vetted the folder at the start
    return F.write_png(fig, path, dpi=110)
