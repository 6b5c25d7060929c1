"""A reference line made from the driven path itself, for recordings without a track file.

The path (valid samples, in time order) is resampled every ``spacing`` metres of driven distance.
If it returns to its start (within ``max(5 m, 3 spacing)``, heading within 60 degrees, after going
at least 4 times that far away) the first lap becomes a *closed* line (``s = 0`` where the
recording starts); otherwise the whole path is an *open* line. Either way it is smoothed with the
track's Whittaker smoother (``smoothing`` metres, which removes GNSS noise and weave while keeping
corner radii) and given a constant half width (only border checks use it).
"""

from __future__ import annotations

import numpy as np

from gprace.errors import InputError


def path_reference(x: np.ndarray, y: np.ndarray, *, smoothing: float = 10.0, half_width: float = 6.0,
                   spacing: float = 2.0, name: str = "path", source: str | None = None):
    from gprace.tracks import Track

    d = np.hypot(np.diff(x), np.diff(y))
    cum = np.concatenate([[0.0], np.cumsum(d)])
    total = float(cum[-1])
    if total < 20.0 * spacing:
        raise InputError(f"{source or name}: the car drives only {total:.1f} m; too short to make a reference line from the path; give a track (`gprace import --track`, or `track = ...` in the recording's .map.toml)")
    idx = np.unique(np.searchsorted(cum, np.arange(0.0, total, spacing)))
    px, py, pc = x[idx], y[idx], cum[idx]
    tol = max(5.0, 3.0 * spacing)
    dist0 = np.hypot(px - px[0], py - py[0])
    left = np.flatnonzero(dist0 > 4.0 * tol)
    closed = False
    if len(left):
        after = np.arange(len(px)) > left[0]
        back = np.flatnonzero(after & (dist0 < tol))
        if len(back):
            # the nearest approach to the start on the first return
            j0 = back[0]
            stop = np.flatnonzero(after & (np.arange(len(px)) > j0) & (dist0 >= tol))
            j1 = stop[0] if len(stop) else len(px)
            j = j0 + int(np.argmin(dist0[j0:j1]))
            h0 = np.arctan2(py[1] - py[0], px[1] - px[0])
            hj = np.arctan2(py[min(j + 1, len(px) - 1)] - py[j - 1], px[min(j + 1, len(px) - 1)] - px[j - 1])
            if np.cos(hj - h0) > 0.5 and pc[j] > 8.0 * tol:
                closed = True
                px, py = px[:j], py[:j]
    w = np.full(len(px), float(half_width))
    return Track(px, py, w, w, closed=closed, name=name, smoothing=smoothing, source=source or name)
