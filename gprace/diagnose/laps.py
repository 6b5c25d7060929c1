"""Laps of a Frenet recording whose ``s`` runs on: wrapped per lap before the diagnosis.

A recording without a lap column whose ``s`` keeps growing over several laps (an import without
a track, a logger that never resets ``s``) would be one long lap to the diagnosis: a bank met
every lap would be a different place each time and never repeat. :func:`wrap_runs` finds the lap
length (the recording's ``track_length`` when it states one, else the period of the curvature
along ``s``), wraps ``s`` into the lap and says so in a note. The lap index follows the running
maximum of ``s``, so sensor noise near the start line does not count a lap twice.
"""

from __future__ import annotations

import numpy as np

from gprace.io.runs import Run

MIN_LAPS = 1.2
"""Distance recorded, in laps, before a period of the curvature is trusted (20 % of a lap overlaps)."""
MATCH = 0.05
"""Largest mean squared curvature difference between ``s`` and ``s + L``, relative to twice the
curvature's variance, accepted as "the same place one lap later"."""


def wrap_runs(runs: list[Run]) -> tuple[list[Run], list[str]]:
    """Every recording with ``s`` wrapped per lap where it runs on; notes for those wrapped."""
    out, notes = [], []
    for r in runs:
        w, note = wrap_run(r)
        out.append(w)
        if note:
            notes.append(note)
    return out, notes


def wrap_run(run: Run) -> tuple[Run, str | None]:
    """``run`` with ``s`` wrapped into ``[0, L)`` and ``track_length`` in its meta when ``s`` runs on
    over more than a lap; unchanged (and no note) otherwise."""
    s = np.asarray(run["s"], dtype=float)
    span = float(np.ptp(s)) if len(s) else 0.0
    if len(s) < 3 or np.any(np.diff(s) < -0.5 * max(span, 1e-9)):  # already wrapped per lap
        return run, None
    meta = run.meta if isinstance(run.meta, dict) else {}
    L = float(meta.get("track_length") or 0.0)
    how = "the recording's track length"
    if not (L > 0 and span > L * 1.02):
        if L > 0:  # within one lap of a known track: nothing to wrap
            return run, None
        L = lap_length_from_curvature(s, np.asarray(run["kappa"], dtype=float)) or 0.0
        how = "the period of the curvature along s"
        if not L:
            return run, None
    s_wrapped, lap = wrap(s, L)
    data = dict(run.data)
    data["s"] = s_wrapped
    laps = int(lap.max() - lap.min() + 1)
    note = (f"{run.source}: s runs on over {span / L:.2f} laps without a lap column; wrapped at the "
            f"lap length {L:.1f} m ({how}): {laps} lap(s)")
    return Run(data, {**meta, "track_length": L}, run.source), note


def wrap(s: np.ndarray, L: float) -> tuple[np.ndarray, np.ndarray]:
    """``s`` wrapped by ``L`` and the lap index; laps counted on the running maximum of ``s``
    (monotone), so a noisy ``s`` near the start line wraps once."""
    top = np.maximum.accumulate(s)
    k = np.floor(top / L)
    return s - k * L, (k - k[0]).astype(int)


def lap_length_from_curvature(s: np.ndarray, kappa: np.ndarray, min_laps: float = MIN_LAPS) -> float | None:
    """The lap length as the period of ``kappa`` along ``s``, or None when the recording covers
    less than ``min_laps`` or no period matches.

    ``kappa`` is resampled on a uniform grid; the mean squared difference ``kappa(s) - kappa(s +
    lag)`` over the overlap is computed for every lag at once (FFT correlation, prefix sums);
    lags shorter than the curvature's own correlation length are skipped, the best match must be
    within :data:`MATCH`, the shortest lag matching nearly as well is taken (a multiple of the lap
    matches too) and refined to a fraction of the grid step by a parabola.
    """
    o = np.argsort(s, kind="stable")
    ss, kk = s[o], kappa[o]
    span = float(ss[-1] - ss[0])
    if span <= 0:
        return None
    n = int(min(2**17, max(1024, len(s) * 4)))
    grid = np.linspace(ss[0], ss[-1], n)
    a = np.interp(grid, ss, kk)
    a = a - a.mean()
    var = float(np.mean(a * a))
    if var <= 0:
        return None
    ds = grid[1] - grid[0]
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    fa = np.fft.rfft(a, nfft)
    cross = np.fft.irfft(fa * np.conj(fa), nfft)[:n]  # sum_i a_i a_{i+lag}
    pre = np.concatenate([[0.0], np.cumsum(a * a)])
    lag = np.arange(n)
    cnt = n - lag
    msd = (pre[n - lag] + (pre[n] - pre[lag]) - 2.0 * cross) / np.maximum(cnt, 1) / (2.0 * var)
    max_lag = int(span / min_laps / ds)
    above = np.flatnonzero(msd[: max_lag + 1] > 0.5)
    if len(above) == 0:
        return None
    lo = int(above[0])
    if max_lag <= lo + 2:
        return None
    seg = msd[lo: max_lag + 1]
    best = float(seg.min())
    if best > MATCH:
        return None
    # local minima matching nearly as well as the best; the shortest is the lap
    interior = (seg[1:-1] <= seg[:-2]) & (seg[1:-1] <= seg[2:])
    cand = np.flatnonzero(interior & (seg[1:-1] <= max(2.0 * best, best + 0.01))) + 1
    i = int(cand[0]) if len(cand) else int(np.argmin(seg))
    k = lo + i
    y0, y1, y2 = msd[k - 1], msd[k], msd[min(k + 1, n - 1)]
    den = y0 - 2.0 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if den > 0 else 0.0
    return float((k + np.clip(frac, -0.5, 0.5)) * ds)
