"""Show: text summary, the augmented vehicle file and the residual-along-track plot."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from gprace.config import VehicleConfig
from gprace.errors import InputError


def write_augmented(vehicle: VehicleConfig, path: str | Path) -> Path:
    """Write the augmented vehicle as TOML (atomic); loadable by ``gprace.config.load_vehicle``."""
    path = Path(path)
    text = "# written by gprace diagnose: the nominal vehicle plus the effects it found\n" + vehicle.to_toml()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError as exc:
        raise InputError(f"{path}: cannot write the augmented vehicle ({exc.strerror})") from None
    return path


def summary_lines(rep: dict[str, Any]) -> list[str]:
    out = [f"verdict: {rep['verdict']}"]
    for c in rep["channels"]:
        flag = "STRUCTURED" if c["structured"] else "noise"
        line = (f"  {c['name']:9s} {flag:10s} statistic {c['statistic']:8.2f}  multi-step RMSE nominal "
                f"{c['rmse_nominal']:.4g} (noise floor {c['rmse_noise_floor']:.4g})")
        if "heldout_rmse_nominal" in c:
            line += f"  held-out {c['heldout_rmse_nominal']:.4g} -> {c['heldout_rmse_augmented']:.4g}"
        out.append(line)
        if c.get("regime"):
            out.append(f"            regime: {c['regime']}")
    for r in rep["regions"]:
        out.append(f"  region {r['channel']}: s {r['s_start']:.0f}..{r['s_end']:.0f} m ({r['description']})")
    for e in rep["effects"]:
        amb = f" (ambiguous with {', '.join(e['ambiguous_with'])})" if e["ambiguous_with"] else ""
        where = e.get("significant_where", "all windows")
        where = f" (significant where it acts: {where})" if where and where != "all windows" else ""
        out.append(f"  effect {e['name']}{amb}: improvement {100 * e['improvement']:.0f}%{where}")
        for k, p in e["parameters"].items():
            lo, hi = p["ci95"]
            out.append(f"      {k} = {p['value']:.4g} {p['unit']}  (95% [{lo:.4g}, {hi:.4g}])")
    if rep["unexplained"]:
        out.append("  unexplained structured error (RMS): " + ", ".join(f"{k} {v:.3g}" for k, v in rep["unexplained"].items()))
    if rep["verdict"] == "mismatch":
        out.append(f"  share of the structured error explained: {100 * rep['explained_share']:.0f}%")
    for n in rep.get("notes", []):
        out.append(f"  note: {n}")
    if rep["augmented_vehicle"]:
        out.append(f"  augmented vehicle: {rep['augmented_vehicle']}")
    return out


def plot_residuals(res, path: str | Path) -> Path:
    """Mean multi-step error along the track per dynamic channel: nominal vs augmented, with the
    noise twin's +-1 sigma band (matplotlib, Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gprace.diagnose.locate import track_profile

    pd = res.plot_data
    data, starts, H = pd["data"], pd["starts"], pd["H"]
    names = ("v_x", "v_y", "yaw_rate")
    units = ("m/s", "m/s", "rad/s")
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    for c, ax in enumerate(axes):
        s, e0 = track_profile(data, starts, H, pd["Ed0"], c)
        _, e1 = track_profile(data, starts, H, pd["Ed1"], c)
        band = float(np.sqrt(np.mean(pd["Et0"][..., c] ** 2)))
        ax.axhspan(-band, band, color="0.85", label="noise twin (1 sigma)")
        ax.plot(s, e0, color="tab:red", lw=1.0, label="nominal")
        ax.plot(s, e1, color="tab:blue", lw=1.0, label="augmented" if pd["effects"] else "augmented (= nominal)")
        ax.set_ylabel(f"{names[c]} error [{units[c]}]")
        ax.grid(alpha=0.3)
    for r in res.report["regions"]:
        for ax in axes:
            ax.axvspan(r["s_start"], r["s_end"], color="gold", alpha=0.15)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(f"multi-step ({H} steps) prediction error along the track; effects: "
                      f"{', '.join(pd['effects']) or 'none'}")
    axes[-1].set_xlabel("s [m]")
    fig.tight_layout()
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise InputError(f"{path}: cannot write the plot ({exc.strerror})") from None
    finally:
        plt.close(fig)
    return path
