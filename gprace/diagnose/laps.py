"""Laps of a Frenet recording whose ``s`` runs on: wrapped per lap before the diagnosis.

A recording without a lap column whose ``s`` keeps growing over several laps (an import without
a track, a logger that never resets ``s``) would be one long lap to the diagnosis: a bank met
every lap would be a different place each time and never repeat. :func:`wrap_runs` finds the lap
length (the recording's ``track_length`` when it states one, else the period of the curvature
along ``s``: :func:`gprace.tracks.laps.wrap_frenet`),
wraps ``s`` into the lap and says so in a note. The lap index follows the running maximum of
``s``, so sensor noise near the start line does not count a lap twice.
"""

from __future__ import annotations

import numpy as np

from gprace.io.runs import Run
from gprace.tracks.laps import wrap_frenet


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
        # kappa alone: with e_y and v given, wrap_frenet doubles the period when they correlate
        # better at two laps, which a driver's weave of its own wavelength or a spin does by chance
        # (2 of 6 independent-source recordings wrapped at twice the lap; docs/decisions.md)
        found = wrap_frenet(s, run["kappa"])
        if found is None:
            return run, None
        L, how = float(found[2]), "the period of the curvature along s"
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
