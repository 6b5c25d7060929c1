"""Show: text summary, the augmented vehicle file and the residual-along-track plot."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gprace.config import VehicleConfig
from gprace.diagnose.result import Channel, DiagnosisResult, Effect, parse_result
from gprace.errors import InputError
from gprace.io.artifacts import write_text_atomic


def write_augmented(vehicle: VehicleConfig, path: str | Path) -> Path:
    """Write the augmented vehicle as TOML (atomic); loadable by ``gprace.config.load_vehicle``."""
    path = Path(path)
    text = "# written by gprace diagnose: the nominal vehicle plus the effects it found\n" + vehicle.to_toml()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, text)
    except OSError as exc:
        raise InputError(f"{path}: cannot write the augmented vehicle ({exc.strerror})") from None
    return path


def summary_lines(rep: DiagnosisResult | dict[str, Any]) -> list[str]:
    """The result in words, one line per finding (``gprace diagnose`` without ``--json``); ``rep``
    is the result or its dump (read through the schema)."""
    r = parse_result(rep, "diagnosis JSON")
    out = [f"verdict: {r.verdict}"]
    for c in r.channels:
        out += _channel_lines(c)
    for g in r.regions:
        out.append(f"  region {g.channel}: s {g.s_start:.0f}..{g.s_end:.0f} m ({g.description})")
    for e in r.effects:
        out += _effect_lines(e)
    if r.unexplained:
        out.append("  unexplained structured error (RMS): " + ", ".join(f"{k} {v:.3g}" for k, v in r.unexplained.items()))
    if r.verdict == "mismatch":
        out.append(f"  share of the structured error explained: {100 * r.explained_share:.0f}%")
    out += [f"  note: {n}" for n in r.notes]
    if r.augmented_vehicle:
        out.append(f"  augmented vehicle: {r.augmented_vehicle}")
    return out


def _channel_lines(c: Channel) -> list[str]:
    flag = "STRUCTURED" if c.structured else "noise"
    line = (f"  {c.name:9s} {flag:10s} statistic {c.statistic:8.2f}  multi-step RMSE nominal "
            f"{c.rmse_nominal:.4g} (noise floor {c.rmse_noise_floor:.4g})")
    if c.heldout_rmse_nominal is not None:
        after = c.heldout_rmse_augmented if c.heldout_rmse_augmented is not None else float("nan")
        line += f"  held-out {c.heldout_rmse_nominal:.4g} -> {after:.4g}"
    return [line] + ([f"            regime: {c.regime}"] if c.regime else [])


def _effect_lines(e: Effect) -> list[str]:
    amb = f" (ambiguous with {', '.join(e.ambiguous_with)})" if e.ambiguous_with else ""
    where = e.significant_where
    where = f" (significant where it acts: {where})" if where and where != "all windows" else ""
    out = [f"  effect {e.name}{amb}: improvement {100 * e.improvement:.0f}%{where}"]
    for k, p in e.parameters.items():
        lo, hi = p.ci95
        out.append(f"      {k} = {p.value:.4g} {p.unit}  (95% [{lo:.4g}, {hi:.4g}])")
    if e.profile is not None:
        from gprace.report.sections.diagnosis import profile_text

        out.append(f"      {profile_text(e)}")
    return out


def plot_residuals(res, path: str | Path) -> Path:
    """The residual-along-track figure of the report (:func:`gprace.report.figures.fig_residual_track`:
    nominal and augmented model, located windows, the noise twin's +-1 sigma band) as a PNG.
    ``res`` is a :class:`~gprace.diagnose.diagnose.Diagnosis` or its result; the figure is drawn
    from the stored residual profile, nothing is simulated."""
    from gprace.report.figures import fig_residual_track, write_png

    r = getattr(res, "result", res)
    prof = r.residual_profile
    if prof is None:
        raise InputError("the diagnosis result has no stored residual profile (it predates it); "
                         "rerun `gprace diagnose ... --json`")
    effects = ", ".join(e.name for e in r.effects) or "none"
    fig = fig_residual_track(prof.s, prof.before, prof.after, [g.model_dump() for g in r.regions],
                             f"multi-step ({r.horizon} steps) prediction error along the track; effects: {effects}",
                             noise=prof.noise, effects=[e.model_dump() for e in r.effects])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)  # like -o: check_output vetted the folder at the start
    return write_png(fig, path, dpi=110)
