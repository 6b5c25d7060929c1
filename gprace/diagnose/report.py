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
    return out


UNITS = {"v_x": "m/s", "v_y": "m/s", "yaw_rate": "rad/s"}


def plot_residuals(res, path: str | Path) -> Path:
    """Mean multi-step error along the track per dynamic channel: nominal vs augmented, with the
    noise twin's +-1 sigma band (matplotlib, Agg backend). ``res`` is a
    :class:`~gprace.diagnose.diagnose.Diagnosis` or its result; the figure is drawn from the
    stored residual profile, nothing is simulated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = getattr(res, "result", res)
    prof = r.residual_profile
    if prof is None:
        raise InputError("the diagnosis result has no stored residual profile (it predates it); "
                         "rerun `gprace diagnose ... --json`")
    effects = [e.name for e in r.effects]
    fig, axes = plt.subplots(len(prof.before), 1, figsize=(11, 8), sharex=True, squeeze=False)
    for ax, ch in zip(axes[:, 0], prof.before):
        band = prof.noise[ch]
        ax.axhspan(-band, band, color="0.85", label="noise twin (1 sigma)")
        ax.plot(prof.s, prof.before[ch], color="tab:red", lw=1.0, label="nominal")
        ax.plot(prof.s, prof.after[ch], color="tab:blue", lw=1.0, label="augmented" if effects else "augmented (= nominal)")
        ax.set_ylabel(f"{ch} error [{UNITS.get(ch, '-')}]")
        ax.grid(alpha=0.3)
    for g in r.regions:
        for ax in axes[:, 0]:
            ax.axvspan(g.s_start, g.s_end, color="gold", alpha=0.15)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[0, 0].set_title(f"multi-step ({r.horizon} steps) prediction error along the track; effects: "
                         f"{', '.join(effects) or 'none'}")
    axes[-1, 0].set_xlabel("s [m]")
    fig.tight_layout()
    return _save(fig, Path(path))


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise InputError(f"{path}: cannot write the plot ({exc.strerror})") from None
    finally:
        plt.close(fig)
    return path
