"""Figures of gprace results: small pure functions ``fig_*(data) -> matplotlib Figure``.

Every function takes plain arrays / dicts (or a :class:`~gprace.tracks.Track`), builds a
:class:`matplotlib.figure.Figure` on the Agg canvas (no display, no pyplot state, safe in
workers) and returns it; :func:`png_bytes` renders one. Axis labels always carry SI units in
brackets. Colours: exploration (or the first variant) blue, baseline orange, plan grey.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

UNITS = {
    "t": "s", "s": "m", "e_y": "m", "e_psi": "rad", "v_x": "m/s", "v_y": "m/s", "yaw_rate": "rad/s",
    "delta": "rad", "a_x": "m/s^2", "kappa": "1/m",
}
LABELS = {
    "t": "time", "s": "arc length s", "e_y": "lateral offset e_y", "e_psi": "heading error e_psi",
    "v_x": "speed v_x", "v_y": "lateral speed v_y", "yaw_rate": "yaw rate", "delta": "steering delta",
    "a_x": "acceleration a_x", "kappa": "curvature",
}
PALETTE = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:cyan")


def label(col: str) -> str:
    """``'lateral speed v_y [m/s]'`` for a run column (the column name alone if unknown)."""
    unit = UNITS.get(col)
    return f"{LABELS.get(col, col)} [{unit}]" if unit else col


def _figure(nrows: int = 1, ncols: int = 1, size: tuple[float, float] = (7.0, 4.0), **kw):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False, **kw)
    return fig, axes


def write_png(fig, path: str | Path, dpi: int = 100) -> Path:
    """Write ``fig`` as a PNG to ``path`` (its folder exists); a file system refusal is one line."""
    from gprace.errors import InputError

    path = Path(path)
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise InputError(f"{path}: cannot write the plot ({exc.strerror or exc})") from None
    return path


def png_bytes(fig, dpi: int = 90) -> bytes:
    """The figure as PNG bytes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _map_size(track, width: float = 7.0) -> tuple[float, float]:
    """Figure size that fits the track's aspect ratio (plus room for title and labels)."""
    (xl, yl), (xr, yr) = track.borders()
    dx = max(np.ptp(np.concatenate([xl, xr])), 1e-9)
    dy = max(np.ptp(np.concatenate([yl, yr])), 1e-9)
    return width, float(np.clip(width * dy / dx * 0.85 + 1.2, 2.8, 7.0))


def _track_outline(ax, track) -> None:
    (xl, yl), (xr, yr) = track.borders()
    if track.closed:
        xl, yl, xr, yr = (np.append(a, a[0]) for a in (xl, yl, xr, yr))
    ax.plot(xl, yl, color="0.35", lw=0.8)
    ax.plot(xr, yr, color="0.35", lw=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def _colored_line(ax, x, y, c, cmap: str = "viridis", lw: float = 2.0):
    from matplotlib.collections import LineCollection

    pts = np.column_stack([x, y]).reshape(-1, 1, 2)
    seg = np.concatenate([pts[:-1], pts[1:]], axis=1)
    lc = LineCollection(seg, cmap=cmap, linewidths=lw)
    lc.set_array(0.5 * (np.asarray(c[:-1], float) + np.asarray(c[1:], float)))
    ax.add_collection(lc)
    return lc


def _mean_std_by(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unique ``x`` with mean, standard deviation and count of finite ``y`` per value."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    u, inv = np.unique(x, return_inverse=True)
    n = np.bincount(inv, minlength=len(u)).astype(float)
    m = np.bincount(inv, weights=y, minlength=len(u)) / np.maximum(n, 1)
    v = np.bincount(inv, weights=(y - m[inv]) ** 2, minlength=len(u)) / np.maximum(n, 1)
    return u, m, np.sqrt(v), n


def _band(ax, x, y, color, name, marker="o"):
    """Mean line with markers and a +-1 std band (over trials) of ``y`` grouped by ``x``."""
    u, m, sd, _ = _mean_std_by(x, y)
    if len(u) == 0:
        return
    ax.plot(u, m, marker=marker, color=color, label=name)
    ax.fill_between(u, m - sd, m + sd, color=color, alpha=0.2, lw=0)


# ----------------------------------------------------------------------------------------------
# single artifacts (gprace show --plot)
def fig_run(data: Mapping[str, np.ndarray], x: str = "t", plan: Mapping[str, np.ndarray] | None = None,
            title: str = "run"):
    """States and inputs of a run against time (``x='t'``) or arc length (``x='s'``), with the
    plan overlaid when given (against ``s`` only)."""
    cols = [c for c in ("v_x", "v_y", "yaw_rate", "e_y", "delta", "a_x") if c in data]
    cols = cols or [c for c in data if c not in ("t", "s", x)][:6]
    fig, axes = _figure((len(cols) + 1) // 2, 2, size=(9.0, 1.9 * ((len(cols) + 1) // 2) + 0.6), sharex=True)
    xs = np.asarray(data[x], float)
    # against s: one line per lap (no stroke back across the start line)
    cut = np.flatnonzero(np.diff(xs) < -0.5 * max(np.ptp(xs), 1e-12)) + 1 if x == "s" else np.zeros(0, int)
    for ax, c in zip(axes.flat, cols):
        ax.plot(np.insert(xs, cut, np.nan), np.insert(np.asarray(data[c], float), cut, np.nan), lw=0.9,
                color=PALETTE[0], label="driven")
        if plan is not None and x == "s" and c in plan:
            o = np.argsort(plan["s"])
            ax.plot(np.asarray(plan["s"])[o], np.asarray(plan[c])[o], lw=0.9, color="0.4", ls="--", label="plan")
        ax.set_ylabel(label(c))
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(cols):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel(label(x))
    if plan is not None and x == "s":
        axes.flat[0].legend(fontsize="small")
    fig.suptitle(title)
    return fig


def fig_track_speed(track, s: np.ndarray, e_y: np.ndarray, v_x: np.ndarray, border_hit: np.ndarray | None = None,
                    title: str = "driven line"):
    """The line ``(s, e_y)`` on the track map coloured by speed; border hits marked with red crosses."""
    fig, axes = _figure(1, 1, size=_map_size(track, 7.5))
    ax = axes[0, 0]
    _track_outline(ax, track)
    x, y = track.to_global(np.asarray(s, float), np.asarray(e_y, float))
    x, y = np.asarray(x), np.asarray(y)
    # no segment across the start line of a closed track
    jump = np.flatnonzero(np.abs(np.diff(np.asarray(s, float))) > 0.5 * track.length) + 1
    lc = None
    for part in np.split(np.arange(len(x)), jump):
        if len(part) >= 2:
            lc = _colored_line(ax, x[part], y[part], np.asarray(v_x, float)[part])
            lc.set_clim(float(np.min(v_x)), float(np.max(v_x)) + 1e-9)
    if lc is not None:
        fig.colorbar(lc, ax=ax, label=label("v_x"), shrink=0.8)
    nh = 0
    if border_hit is not None:
        hit = np.asarray(border_hit, float) > 0
        nh = int(hit.sum())
        if nh:
            ax.plot(x[hit], y[hit], "x", color="tab:red", ms=6, label=f"border hit ({nh} steps)")
            ax.legend(loc="best", fontsize="small")
    ax.plot(x[:1], y[:1], "o", color="k", ms=4)
    ax.autoscale_view()
    ax.set_title(f"{title}: {track.name}" + (f", {nh} border-hit steps" if border_hit is not None else ""))
    return fig


def fig_plan(plan: Mapping[str, np.ndarray], track=None, title: str = "plan"):
    """A plan: on the track map coloured by speed when the track is known, else speed, e_y and
    steering against arc length."""
    if track is not None:
        return fig_track_speed(track, plan["s"], plan["e_y"], plan["v_x"], None, title=title)
    fig, axes = _figure(3, 1, size=(7.0, 6.0), sharex=True)
    o = np.argsort(plan["s"])
    for ax, c in zip(axes[:, 0], ("v_x", "e_y", "delta")):
        ax.plot(np.asarray(plan["s"])[o], np.asarray(plan[c])[o], color=PALETTE[0])
        ax.set_ylabel(label(c))
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel(label("s"))
    fig.suptitle(title)
    return fig


def fig_dataset(Z: np.ndarray, Y: np.ndarray, input_names: Sequence[str], output_names: Sequence[str],
                i: int = 0, j: int = 1, title: str = "dataset"):
    """Scatter of two inputs, coloured by each of the first two outputs (one panel per output)."""
    Z = np.asarray(Z, float).reshape(len(Z), -1)
    Y = np.asarray(Y, float).reshape(len(Y), -1)
    j = min(j, Z.shape[1] - 1)
    no = min(Y.shape[1], 2)
    fig, axes = _figure(1, no, size=(5.0 * no, 4.2))
    for o in range(no):
        ax = axes[0, o]
        yj = Z[:, j] if j != i else np.zeros(len(Z))
        sc = ax.scatter(Z[:, i], yj, c=Y[:, o], s=8, cmap="coolwarm")
        fig.colorbar(sc, ax=ax, label=_name(output_names, o, "y"))
        ax.set_xlabel(_name(input_names, i, "z"))
        ax.set_ylabel(_name(input_names, j, "z") if j != i else "-")
        ax.set_title(f"{len(Z)} points")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    return fig


def _name(names: Sequence[str], k: int, prefix: str) -> str:
    n = names[k] if k < len(names) else f"{prefix}{k}"
    unit = UNITS.get(n)
    return f"{n} [{unit}]" if unit else n


def fig_gp_posterior(predict: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], Zd: np.ndarray,
                     input_names: Sequence[str], output_names: Sequence[str], i: int = 0, j: int = 1,
                     output: int = 0, n_grid: int = 40, title: str = "GP posterior"):
    """Posterior mean and standard deviation of one output over features ``i`` and ``j``.

    The other features are held at the median of the dictionary points ``Zd`` (n, d); the grid
    spans the dictionary's range plus 10 % each side; the dictionary points are drawn on top.
    ``predict(Z) -> (mean (m, p), var (m, p))`` is the GP contract of :mod:`gprace.gp`.
    """
    Zd = np.asarray(Zd, float)
    lo, hi = Zd.min(axis=0), Zd.max(axis=0)
    pad = 0.1 * np.maximum(hi - lo, 1e-9)
    gi = np.linspace(lo[i] - pad[i], hi[i] + pad[i], n_grid)
    gj = np.linspace(lo[j] - pad[j], hi[j] + pad[j], n_grid)
    A, B = np.meshgrid(gi, gj)
    Zq = np.tile(np.median(Zd, axis=0), (A.size, 1))
    Zq[:, i], Zq[:, j] = A.ravel(), B.ravel()
    mean, var = predict(Zq)
    mean = np.asarray(mean, float).reshape(A.size, -1)[:, output].reshape(A.shape)
    std = np.sqrt(np.maximum(np.asarray(var, float).reshape(A.size, -1)[:, output], 0.0)).reshape(A.shape)
    fig, axes = _figure(1, 2, size=(10.0, 4.2))
    oname = _name(output_names, output, "y")
    for ax, F, what, cmap in ((axes[0, 0], mean, "mean", "coolwarm"), (axes[0, 1], std, "std", "viridis")):
        cs = ax.contourf(A, B, F, levels=14, cmap=cmap)
        fig.colorbar(cs, ax=ax, label=f"posterior {what} of {oname}")
        ax.plot(Zd[:, i], Zd[:, j], ".", color="k", ms=3, alpha=0.6, label=f"dictionary ({len(Zd)})")
        ax.set_xlabel(_name(input_names, i, "z"))
        ax.set_ylabel(_name(input_names, j, "z"))
        ax.set_title(f"{what}")
    axes[0, 0].legend(loc="upper right", fontsize="small")
    fig.suptitle(title)
    return fig


# ----------------------------------------------------------------------------------------------
# time trial
def fig_lap_times(variants: Mapping[str, Mapping[str, np.ndarray]], title: str = "lap times"):
    """Planned, driven and driven - planned lap time per iteration, mean and +-1 std over trials.

    ``variants``: name (``exploration``, ``baseline``) -> ``{"iteration", "planned", "driven"}``,
    one entry per (iteration, trial); a lap that was not completed has ``driven`` NaN. The means
    are over the completed laps only, so every iteration with failed laps is marked on the driven
    panels (a cross at the bottom) and labelled "k/n failed": no mean hides its failures.
    """
    fig, axes = _figure(1, 3, size=(12.0, 3.8))
    for k, (name, d) in enumerate(variants.items()):
        c = PALETTE[k % len(PALETTE)]
        it = np.asarray(d["iteration"], float)
        pl, dr = np.asarray(d["planned"], float), np.asarray(d["driven"], float)
        _band(axes[0, 0], it, pl, c, name)
        _band(axes[0, 1], it, dr, c, name)
        _band(axes[0, 2], it, dr - pl, c, name)
        for ax in axes[0, 1:]:
            _mark_failed(ax, it, np.isfinite(dr), c, name)
    for ax, what in zip(axes[0], ("planned", "driven", "driven - planned")):
        ax.set_xlabel("iteration [-]")
        ax.set_ylabel(f"{what} lap time [s]")
        ax.grid(alpha=0.3)
        ax.xaxis.get_major_locator().set_params(integer=True)
    axes[0, 2].axhline(0.0, color="0.5", lw=0.8)
    axes[0, 0].legend(fontsize="small")
    fig.suptitle(title)
    return fig


def _mark_failed(ax, it: np.ndarray, ok: np.ndarray, color, name: str) -> None:
    """A cross at the bottom of ``ax`` and "k/n failed" at every iteration with failed laps."""
    u = np.unique(it[np.isfinite(it)])
    n = np.array([np.sum(it == x) for x in u])
    bad = np.array([np.sum((it == x) & ~ok) for x in u])
    if not bad.any():
        return
    m = bad > 0
    tr = ax.get_xaxis_transform()  # x in data, y in axes fraction
    ax.plot(u[m], np.full(m.sum(), 0.04), "x", color=color, ms=8, mew=2, transform=tr, clip_on=False,
            label=f"{name}: failed laps ({int(bad.sum())} of {int(n.sum())})")
    for x, b, t in zip(u[m], bad[m], n[m]):
        ax.annotate(f"{b}/{t} failed", (x, 0.04), xycoords=tr, xytext=(0, 6), textcoords="offset points",
                    ha="center", fontsize="x-small", color=color)
    ax.legend(fontsize="x-small", loc="upper right")


def fig_exploration_data(run: Mapping[str, np.ndarray], plan: Mapping[str, np.ndarray],
                         title: str = "data collected while exploring"):
    """v_y and yaw rate driven in an exploration iteration against the plan: both along the
    lap and in the (v_y, yaw rate) feature plane."""
    fig, axes = _figure(1, 3, size=(13.0, 3.8))
    ps = np.argsort(plan["s"])
    for ax, c in zip(axes[0, :2], ("v_y", "yaw_rate")):
        ax.plot(np.asarray(run["s"]), np.asarray(run[c]), ".", ms=2, color=PALETTE[0], label="driven (exploring)")
        ax.plot(np.asarray(plan["s"])[ps], np.asarray(plan[c])[ps], color="0.3", lw=1.0, label="plan")
        ax.set_xlabel(label("s"))
        ax.set_ylabel(label(c))
        ax.grid(alpha=0.3)
    ax = axes[0, 2]
    ax.plot(run["v_y"], run["yaw_rate"], ".", ms=2, color=PALETTE[0], label="driven (exploring)")
    ax.plot(plan["v_y"], plan["yaw_rate"], ".", ms=2, color="0.3", label="plan")
    ax.set_xlabel(label("v_y"))
    ax.set_ylabel(label("yaw_rate"))
    ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize="small", markerscale=4)
    fig.suptitle(title)
    return fig


def fig_gp_errors(variants: Mapping[str, Mapping[str, np.ndarray]], units: Mapping[str, str] | None = None,
                  title: str = "GP prediction error on the diverse test run"):
    """GP prediction error per iteration for each GP (one panel each), mean +-1 std over trials.

    ``variants``: name -> ``{"iteration": (n,), "<gp name>": (n,), ...}`` (e.g. ``planning``,
    ``tracking``); ``units`` maps a GP name to the unit of its error.
    """
    gps: list[str] = []
    for d in variants.values():
        gps += [k for k in d if k != "iteration" and k not in gps]
    gps = gps or ["tracking"]
    fig, axes = _figure(1, len(gps), size=(5.5 * len(gps), 3.8))
    for g, ax in zip(gps, axes[0]):
        for k, (name, d) in enumerate(variants.items()):
            if g in d:
                _band(ax, d["iteration"], d[g], PALETTE[k % len(PALETTE)], name)
        ax.set_xlabel("iteration [-]")
        u = (units or {}).get(g, "")
        ax.set_ylabel(f"{g} GP error" + (f" [{u}]" if u else " (RMSE)"))
        ax.set_title(f"{g} GP")
        ax.grid(alpha=0.3)
        ax.xaxis.get_major_locator().set_params(integer=True)
    axes[0, 0].legend(fontsize="small")
    fig.suptitle(title)
    return fig


# ----------------------------------------------------------------------------------------------
# head-to-head
def fig_pred_errors(ey_error: Mapping[str, Mapping[str, Sequence[float]]], dt: float | None = None,
                    title: str = "opponent e_y prediction error"):
    """Mean and +-1 std of the opponent e_y prediction error against the number of steps ahead,
    one line per predictor (``{name: {"mean": [K], "std": [K]}}``)."""
    fig, axes = _figure(1, 1, size=(7.0, 4.2))
    ax = axes[0, 0]
    for k, (name, e) in enumerate(ey_error.items()):
        m = np.asarray(e.get("mean", []), float)
        if not len(m):
            continue
        sd = np.asarray(e.get("std", np.zeros_like(m)), float)
        steps = np.arange(1, len(m) + 1)
        c = PALETTE[k % len(PALETTE)]
        ax.plot(steps, m, marker="o", color=c, label=name)
        ax.fill_between(steps, np.maximum(m - sd, 0), m + sd, color=c, alpha=0.15, lw=0)
    ax.set_xlabel("steps ahead [-]" + (f" ({dt:g} s each)" if dt else ""))
    ax.set_ylabel("|e_y error| [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(title)
    return fig


def fig_error_along_run(t: np.ndarray, errors: Mapping[str, np.ndarray], steps: Sequence[int] = (1, 9),
                        title: str = "prediction error along one run"):
    """The k-step-ahead e_y error at every start time of one run, one panel per k in ``steps``.

    ``errors``: predictor -> ``(K, T)`` absolute errors (row k-1 = k steps ahead), ``t`` (T,).
    """
    fig, axes = _figure(len(steps), 1, size=(8.0, 2.4 * len(steps) + 0.5), sharex=True)
    for ax, k in zip(axes[:, 0], steps):
        for c, (name, E) in enumerate(errors.items()):
            E = np.asarray(E, float)
            if E.ndim == 2 and E.shape[0] >= k and E.shape[1]:
                ax.plot(np.asarray(t)[: E.shape[1]], E[k - 1], lw=1.0, color=PALETTE[c % len(PALETTE)], label=name)
        ax.set_ylabel(f"{k}-step |e_y error| [m]")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("prediction start time [s]")
    axes[0, 0].legend(fontsize="small")
    fig.suptitle(title)
    return fig


def fig_race(track, ego: np.ndarray, opp: np.ndarray, border_ego: np.ndarray | None = None,
             title: str = "race"):
    """Both cars' paths on the track (states ``(T, 6)``, ``e_y`` column 4, ``s`` column 5),
    dots every second of 0.1-s steps, start marked, ego border hits as red crosses."""
    fig, axes = _figure(1, 1, size=_map_size(track))
    ax = axes[0, 0]
    _track_outline(ax, track)
    for X, name, c in ((ego, "ego", PALETTE[0]), (opp, "opponent", PALETTE[1])):
        X = np.asarray(X, float)
        x, y = track.to_global(track.wrap(X[:, 5]) if track.closed else X[:, 5], X[:, 4])
        x, y = np.asarray(x), np.asarray(y)
        ax.plot(x, y, color=c, lw=1.5, label=name)
        ax.plot(x[::10], y[::10], ".", color=c, ms=5)
        ax.plot(x[:1], y[:1], "o", color=c, ms=7, mfc="none")
        if name == "ego" and border_ego is not None and np.any(border_ego):
            h = np.asarray(border_ego, bool)[: len(x)]
            ax.plot(x[: len(h)][h], y[: len(h)][h], "x", color="tab:red", label="ego border hit")
    ax.legend(fontsize="small")
    ax.set_title(f"{title}: {track.name}")
    return fig


# ----------------------------------------------------------------------------------------------
# diagnosis
def fig_residual_track(s: np.ndarray, before: Mapping[str, np.ndarray], after: Mapping[str, np.ndarray] | None = None,
                       regions: Sequence[Mapping[str, Any]] = (), title: str = "residual along the track",
                       noise: Mapping[str, float] | None = None, effects: Sequence[Mapping[str, Any]] = ()):
    """Residual (measured - model) per channel against arc length, nominal model and augmented
    model, with the located windows shaded and, with ``noise``, the noise twin's +-1 sigma band.
    Named effects that act along the lap (``effects`` as in the diagnosis JSON: windows and
    profiles) are drawn below on the same axis (:func:`draw_along_lap`)."""
    chans = list(before)
    along = [e for e in effects if along_lap(e)]
    n = len(chans) + len(along)
    fig, axes = _figure(n, 1, size=(9.0, 2.3 * n + 0.6), sharex=True)
    for ax, e in zip(axes[len(chans):, 0], along):
        draw_along_lap(ax, e)
    s = np.asarray(s, float)
    o = np.argsort(s, kind="stable")
    # binned profiles (a few hundred points) as lines, raw residuals as dots
    style = {"ls": "-", "lw": 1.0, "marker": ".", "ms": 3} if len(s) <= 600 else {"ls": "none", "marker": ".", "ms": 2}
    for ax, c in zip(axes[:, 0], chans):
        if noise is not None and c in noise:
            ax.axhspan(-noise[c], noise[c], color="0.85", label="noise twin (1 sigma)")
        ax.plot(s[o], np.asarray(before[c], float)[o], color=PALETTE[1], label="nominal model", **style)
        if after is not None and c in after:
            ax.plot(s[o], np.asarray(after[c], float)[o], color=PALETTE[0], label="augmented model", **style)
        for r in regions:
            if r.get("channel") in (c, None):
                ax.axvspan(float(r["s_start"]), float(r["s_end"]), color="tab:red", alpha=0.12)
        u = UNITS.get(c)
        ax.set_ylabel(f"{c} residual" + (f" [{u}]" if u else ""))
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel(label("s"))
    axes[0, 0].legend(fontsize="small", markerscale=4)
    fig.suptitle(title)
    return fig


def along_lap(e: Mapping[str, Any]) -> bool:
    """Does the named effect (diagnosis JSON) act along the lap: a profile, or a window?"""
    p = e.get("parameters") or {}
    return bool(e.get("profile")) or ("s_start" in p and "s_end" in p)


_NEUTRAL_ONE = ("factor",)


def draw_along_lap(ax, e: Mapping[str, Any]) -> None:
    """One named effect against the lap position: a profile's values at its knots with the
    pointwise 95 % band, or a window's amplitude over [s_start, s_end] (its interval shaded)."""
    name = str(e.get("name"))
    prof = e.get("profile")
    if prof:
        s = np.asarray(prof["s"], float)
        L = float(prof.get("lap_length") or (s[-1] + (s[1] - s[0]) if len(s) > 1 else 1.0))
        close = lambda a: np.append(np.asarray(a, float), np.asarray(a, float)[:1])  # noqa: E731 (periodic)
        x = np.append(s, L)
        lo, hi = close(prof["ci95_low"]), close(prof["ci95_high"])
        if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
            ax.fill_between(x, lo, hi, color=PALETTE[0], alpha=0.25, lw=0, label="95 % interval (pointwise)")
        ax.plot(x, close(prof["value"]), color=PALETTE[0], lw=1.5, label=name)
        unit = prof.get("unit", "")
        neutral = 1.0 if unit == "-" else 0.0
    else:
        p = e["parameters"]
        key = next((k for k in p if k not in ("s_start", "s_end", "ramp")), None)
        a, b = float(p["s_start"]["value"]), float(p["s_end"]["value"])
        amp = p[key] if key else {"value": 1.0, "ci95": [np.nan, np.nan], "unit": ""}
        neutral = 1.0 if key in _NEUTRAL_ONE else 0.0
        v = float(amp["value"])
        ax.step([a - 1e-9, a, b, b + 1e-9], [neutral, v, v, neutral], where="post", color=PALETTE[0], lw=1.5,
                label=f"{name} (window)")
        ax.plot([min(0.0, a), a], [neutral, neutral], color=PALETTE[0], lw=1.5)
        ci = np.asarray(amp.get("ci95", [np.nan, np.nan]), float)
        if np.all(np.isfinite(ci)):
            ax.fill_between([a, b], [ci[0]] * 2, [ci[1]] * 2, color=PALETTE[0], alpha=0.25, lw=0,
                            label="95 % interval")
        unit = amp.get("unit", "")
    ax.axhline(neutral, color="0.5", lw=0.8)
    ax.set_ylabel(f"{name}" + (f" [{unit}]" if unit else ""))
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")


def fig_effects_along_lap(effects: Sequence[Mapping[str, Any]], title: str = "named effects along the lap"):
    """The named effects that act along the lap (profiles and windows), one row each, with their
    95 % intervals; an empty figure says there are none."""
    along = [e for e in effects if along_lap(e)]
    fig, axes = _figure(max(len(along), 1), 1, size=(9.0, 2.2 * max(len(along), 1) + 0.6), sharex=True)
    for ax, e in zip(axes[:, 0], along):
        draw_along_lap(ax, e)
    if not along:
        axes[0, 0].text(0.5, 0.5, "no effect along the lap", ha="center", va="center", transform=axes[0, 0].transAxes)
    axes[-1, 0].set_xlabel(label("s"))
    fig.suptitle(title)
    return fig


def fig_channels(channels: Sequence[Mapping[str, Any]], regions: Sequence[Mapping[str, Any]] = (),
                 length: float | None = None, title: str = "where the mismatch sits"):
    """Left: structure statistic per channel (red = structured, grey = noise). Right: the located
    windows along the track per channel."""
    fig, axes = _figure(1, 2, size=(11.0, 3.6))
    ax = axes[0, 0]
    names = [str(c.get("name")) for c in channels]
    stat = np.array([float(c.get("statistic", np.nan)) for c in channels])
    col = ["tab:red" if c.get("structured") else "0.6" for c in channels]
    ax.bar(np.arange(len(names)), np.nan_to_num(stat), color=col)
    ax.set_xticks(np.arange(len(names)), names)
    ax.set_ylabel("structure statistic [-]")
    ax.set_xlabel("channel")
    ax.set_title("red: structured error, grey: noise level")
    ax.grid(alpha=0.3, axis="y")
    ax = axes[0, 1]
    chans = sorted({str(r.get("channel")) for r in regions} | {n for n, c in zip(names, channels) if c.get("structured")})
    for k, ch in enumerate(chans):
        spans = [(float(r["s_start"]), float(r["s_end"]) - float(r["s_start"])) for r in regions if str(r.get("channel")) == ch]
        if spans:
            ax.broken_barh(spans, (k - 0.35, 0.7), color="tab:red", alpha=0.7)
    ax.set_yticks(np.arange(len(chans)), chans)
    ax.set_ylim(-0.6, max(len(chans), 1) - 0.4)
    ax.set_xlabel(label("s"))
    ax.set_title(f"{len(regions)} window(s) that repeat lap after lap")
    if length:
        ax.set_xlim(0, float(length))
    ax.grid(alpha=0.3, axis="x")
    fig.suptitle(title)
    return fig


def fig_parameters(effects: Sequence[Mapping[str, Any]], title: str = "fitted parameters (95 % intervals)"):
    """Each fitted parameter with its 95 % interval, one row per parameter, units in the labels."""
    rows = []
    for e in effects:
        for p, v in (e.get("parameters") or {}).items():
            val = float(v.get("value", np.nan)) if isinstance(v, Mapping) else float(v)
            ci = v.get("ci95") if isinstance(v, Mapping) else None
            unit = v.get("unit", "") if isinstance(v, Mapping) else ""
            rows.append((f"{e.get('name')}.{p}" + (f" [{unit}]" if unit else ""), val, ci))
    n = max(len(rows), 1)
    fig, axes = _figure(n, 1, size=(7.0, 0.9 * n + 0.9))
    for ax, (name, val, ci) in zip(axes[:, 0], rows):
        if ci is not None and len(ci) == 2 and np.all(np.isfinite(np.asarray(ci, float))):
            lo, hi = float(ci[0]), float(ci[1])
            ax.errorbar([val], [0], xerr=[[val - lo], [hi - val]], fmt="o", color=PALETTE[0], capsize=5)
            ax.set_xlim(lo - 0.6 * (hi - lo + 1e-12) - 1e-12, hi + 0.6 * (hi - lo + 1e-12) + 1e-12)
        else:
            ax.plot([val], [0], "o", color=PALETTE[0])
        ax.set_yticks([0], [name])
        ax.grid(alpha=0.3, axis="x")
    if not rows:
        axes[0, 0].text(0.5, 0.5, "no fitted effects", ha="center", va="center", transform=axes[0, 0].transAxes)
        axes[0, 0].set_yticks([])
    axes[-1, 0].set_xlabel("value (unit in each row's label)")
    fig.suptitle(title)
    return fig
