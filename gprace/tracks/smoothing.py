"""The smoothing of a centre line into a :class:`~gprace.tracks.track.Track`, shared by the loaders
of a centre line (:mod:`gprace.tracks.loaders`) and of two boundary files
(:mod:`gprace.tracks.bounds`): a Whittaker length equal to the median point spacing, at most
:data:`TUM_SMOOTHING` metres, halved (three times at most) while it moves the line past a border;
an error then names the option (:data:`SMOOTHING_OPTION`). The rule is described in the
:mod:`gprace.tracks.loaders` docstring ("Smoothing that scales").
"""

from __future__ import annotations

import numpy as np

from gprace.errors import InputError
from gprace.tracks.track import Track

TUM_SMOOTHING = 5.0
"""Largest Whittaker smoothing length [m] given to a CSV centre line (the TUM circuits' point
spacing); smaller tracks get their own median point spacing."""

SMOOTHING_OPTION = "--track-smoothing"
"""How the messages name the smoothing override (``track show`` calls it ``--smoothing``)."""


def auto_smoothing(x: np.ndarray, y: np.ndarray, closed: bool = True) -> float:
    """Default Whittaker length of a centre line: its median point spacing, at most
    :data:`TUM_SMOOTHING` (module docstring)."""
    p = np.column_stack([x, y])
    d = np.hypot(*np.diff(np.vstack([p, p[:1]]) if closed else p, axis=0).T)
    return float(min(TUM_SMOOTHING, np.median(d)))


def smoothed_track(x, y, wl, wr, *, closed: bool, name: str, source: str, smoothing: float | None) -> Track:
    """A :class:`Track` with the given or automatic smoothing; automatic smoothing that pushes the
    line past a border is halved (three times at most) before the error names the option."""
    if smoothing is not None:
        try:
            return Track(x, y, wl, wr, closed=closed, name=name, smoothing=smoothing, source=source)
        except InputError as exc:
            raise _with_option(exc) from None
    l = auto_smoothing(x, y, closed)
    for k in range(4):
        try:
            return Track(x, y, wl, wr, closed=closed, name=name, smoothing=l / 2**k, source=source)
        except InputError as exc:
            if "smoothing of" not in str(exc) or k == 3:
                raise _with_option(exc) from None
    raise AssertionError  # pragma: no cover


def _with_option(exc: InputError) -> InputError:
    msg = str(exc)
    if "use less smoothing" in msg:
        msg = msg.replace("use less smoothing", f"use less smoothing ({SMOOTHING_OPTION} L, in metres; 0 keeps the points)")
    return InputError(msg)
