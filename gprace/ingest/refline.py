"""A reference line made from the driven path itself, for recordings without a track file.

When the path closes (:func:`gprace.tracks.laps.path_laps`: the lap length from the closure of
the path, one line averaged over all laps, smoothed and closed), the line is closed and the
import wraps ``s`` per lap and counts the laps on it. Otherwise (an open stage, less than about
1.02 laps) the whole path is an *open* line: resampled every ``spacing`` metres of driven
distance (standstill adds none) and smoothed over three spacings. Either way the half width is
only for border checks (a path is not a track): twice the spread of the laps around the line,
or the map's ``reference_width``; ``reference_smoothing`` overrides the smoothing length.
"""

from __future__ import annotations

import numpy as np

from gprace.errors import InputError


def path_reference(x: np.ndarray, y: np.ndarray, *, smoothing: float | None = None, half_width: float | None = None,
                   name: str = "path", source: str | None = None):
    from gprace.tracks import Track
    from gprace.tracks.laps import driven_distance, path_laps, reference_half_width

    d = driven_distance(x, y)
    total = float(d[-1])
    extent = float(np.hypot(np.ptp(x), np.ptp(y))) if len(x) else 0.0
    if not total > 0 or len(x) < 16 or total < 2.0 * max(extent, 1e-9) and total < 1.0:
        raise InputError(f"{source or name}: the car drives only {total:.2f} m; too short to make a reference line from the path; "
                         "give a track (`gprace import --track`, or `track = ...` in the recording's map)")
    laps = path_laps(x, y)
    if laps is not None:
        w = reference_half_width(laps) if half_width is None else float(half_width)
        if smoothing is None:
            return laps.track(name=name, source=source or name, half_width=w)
        ww = np.full(len(laps.x), w)
        return Track(laps.x, laps.y, ww, ww, closed=True, name=name, smoothing=smoothing, source=source or name)
    step = np.hypot(np.diff(x), np.diff(y))
    spacing = max(float(np.median(step[step > 0])) if np.any(step > 0) else total / 100, total / 20_000)
    idx = np.unique(np.searchsorted(d, np.arange(0.0, total, spacing)))
    px, py = x[idx], y[idx]
    if len(px) < 8:
        raise InputError(f"{source or name}: the car drives only {total:.2f} m; too short to make a reference line from the path; "
                         "give a track (`gprace import --track`, or `track = ...` in the recording's map)")
    w = np.full(len(px), float(half_width) if half_width is not None else max(0.05 * extent, 0.5))
    return Track(px, py, w, w, closed=False, name=name, smoothing=3.0 * spacing if smoothing is None else smoothing,
                 source=source or name)
