"""Show: text summary, the augmented vehicle file and the residual-along-track plot."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gprace.config import VehicleConfig
from gprace.diagnose.result import Calibration, Channel, DiagnosisResult, Effect, Inputs, parse_result
from gprace.errors import InputError
from gprace.io.artifacts import write_text_atomic


def write_augmented(vehicle: VehicleConfig, path: str | Path, result: DiagnosisResult | None = None) -> Path:
    """Write the augmented vehicle as TOML (atomic); loadable by ``gprace.config.load_vehicle``.

    The calibrated parameters are in the vehicle's own fields; a comment block above them lists
    each with its nominal value and 95 % interval, and the named effects (``result`` given)."""
    path = Path(path)
    text = "# written by gprace diagnose: the nominal vehicle, calibrated, plus the effects it found\n"
    if result is not None:
        text += "".join(f"# {line}\n" for line in _toml_notes(result))
    text += vehicle.to_toml()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, text)
    except OSError as exc:
        raise InputError(f"{path}: cannot write the augmented vehicle ({exc.strerror})") from None
    return path


def _toml_notes(r: DiagnosisResult) -> list[str]:
    out = []
    c = r.calibration
    if c is not None and c.applied and c.parameters:
        out.append(f"calibrated parameters (held-out gain {100 * c.heldout_gain:.0f}%, by lap):")
        out += [f"  {p.name} ({p.field}) = {p.value:.5g} {p.unit}, nominal {p.nominal:.5g}, "
                f"95% [{p.ci95[0]:.4g}, {p.ci95[1]:.4g}]" + (", at its bound" if p.at_bound else "")
                for p in c.parameters]
    if r.effects:
        out.append("missing physics named: " + ", ".join(e.name for e in r.effects))
    if r.partial_effects:
        out.append("partial fits (improve held-out prediction, leave structure; not named): "
                   + ", ".join(e.name for e in r.partial_effects))
    return out


def summary_lines(rep: DiagnosisResult | dict[str, Any]) -> list[str]:
    """The result in words, one line per finding (``gprace diagnose`` without ``--json``); ``rep``
    is the result or its dump (read through the schema)."""
    r = parse_result(rep, "diagnosis JSON")
    out = [f"verdict: {r.verdict}"]
    if r.inputs is not None:
        out += _input_lines(r.inputs)
    for c in r.channels:
        out += _channel_lines(c)
    for g in r.regions:
        out.append(f"  region {g.channel}: s {g.s_start:.0f}..{g.s_end:.0f} m ({g.description})")
    if r.calibration is not None:
        out += _calibration_lines(r.calibration)
    if r.effects:
        out.append("  missing physics:")
    for e in r.effects:
        out += _effect_lines(e)
    if r.partial_effects:
        out.append("  partial fits (improve held-out prediction, leave their channels structured; in the augmented"
                   " vehicle, not named):")
    for e in r.partial_effects:
        out += _effect_lines(e)
    if r.unexplained:
        out.append("  unexplained structured error (RMS): " + ", ".join(f"{k} {v:.3g}" for k, v in r.unexplained.items()))
    if r.verdict == "mismatch":
        out.append(f"  share of the structured error explained: {100 * r.explained_share:.0f}%")
    out += [f"  note: {n}" for n in r.notes]
    if r.augmented_vehicle:
        out.append(f"  augmented vehicle: {r.augmented_vehicle}")
    return out


def _input_lines(i: Inputs) -> list[str]:
    how = {"force": "v_x by the commanded a_x through the forces",
           "speed": "v_x by the speed command through the car's speed loop",
           "kinematic": "v_x by the measured a_x, kinematically"}.get(i.longitudinal, i.longitudinal)
    given = ", ".join(f"{k} {v}" for k, v in (("steering", i.delta), ("a_x", i.a_x)) if v)
    given += ", a speed command" if i.v_cmd else ""
    out = [f"  inputs: {given}; {how}"]
    out += [f"    {ch} tests {what}" for ch, what in i.tests.items()]
    if i.not_testable:
        out.append("    not testable with these inputs: " + "; ".join(f"{t.effect} ({t.reason})" for t in i.not_testable))
    return out


def _calibration_lines(c: Calibration) -> list[str]:
    if not c.parameters and not c.not_identified:
        return []
    state = "applied" if c.applied else ("not applied: its held-out gain is not significant" if c.tested
                                         else "not needed: the named effects explain the structured error")
    out = [f"  calibrated parameters (held-out gain {100 * c.heldout_gain:.0f}%, t = {c.t:.1f}; {state}):"]
    for p in c.parameters:
        lo, hi = p.ci95
        out.append(f"      {p.name} = {p.value:.4g} {p.unit}  (nominal {p.nominal:.4g}; 95% [{lo:.4g}, {hi:.4g}])"
                   + ("  at its bound" if p.at_bound else ""))
    for n in c.not_identified:
        out.append(f"      {n.name}: not identified, kept nominal ({n.reason})")
    return out


def _channel_lines(c: Channel) -> list[str]:
    flag = "STRUCTURED" if c.structured else "noise"
    line = (f"  {c.name:9s} {flag:10s} statistic {c.statistic:8.2f}  multi-step RMSE nominal "
            f"{c.rmse_nominal:.4g} (noise floor {c.rmse_noise_floor:.4g})")
    if c.heldout_rmse_nominal is not None:
        after = c.heldout_rmse_augmented if c.heldout_rmse_augmented is not None else float("nan")
        mid = f" -> calibrated {c.heldout_rmse_calibrated:.4g}" if c.heldout_rmse_calibrated is not None else ""
        line += f"  held-out {c.heldout_rmse_nominal:.4g}{mid} -> {after:.4g}"
    return [line] + ([f"            regime: {c.regime}"] if c.regime else [])


def _effect_lines(e: Effect) -> list[str]:
    amb = f" (ambiguous with {', '.join(e.ambiguous_with)})" if e.ambiguous_with else ""
    where = e.significant_where
    where = f" (significant where it acts: {where})" if where and where != "all windows" else ""
    out = [f"  effect {e.name}{amb}: improvement {100 * e.improvement:.0f}%{where}"]
    for k, p in e.parameters.items():
        lo, hi = p.ci95
        out.append(f"      {k} = {p.value:.4g} {p.unit}  (95% [{lo:.4g}, {hi:.4g}])"
                   + ("  at its physical bound" if p.at_bound else ""))
    if e.profile is not None:
        out.append(f"      {profile_text(e)}" + ("  (at its physical bound somewhere)" if e.profile.at_bound else ""))
    return out


def profile_text(e: Effect) -> str:
    """A profile in words: its extreme value, where, with the interval there."""
    import numpy as np

    p = e.profile
    v = np.asarray(p.value, float)
    neutral = 1.0 if p.unit == "-" else 0.0
    i = int(np.nanargmax(np.abs(v - neutral)))
    return (f"profile along the lap ({len(v)} knots, {p.edf if p.edf is not None else float('nan'):.1f} "
            f"effective parameters): extreme {v[i]:.4g} {p.unit} at s = {p.s[i]:.0f} m "
            f"[{p.ci95_low[i]:.4g}, {p.ci95_high[i]:.4g}]")
