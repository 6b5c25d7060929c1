"""The model's envelope: which samples of a recording a dynamic bicycle model can describe.

ONE rule, shared by every stage that reads a recording (diagnose today; select-data and
``evaluate gp`` can call the same function). A test-day log holds spins, standstills, pit stops,
reversing and gaps in the logger's time stamps. Those samples are not errors of the file: they
are outside what the model (and the GPs learned on its residuals) is meant to describe, so they
are cut out and *reported* (how many samples and seconds, where in ``s`` and ``t``, why), never
silently used and never a reason to refuse the whole file.

:func:`envelope` is a pure function of the columns (vectorised, no loop over samples). It returns
a keep-mask and a small typed :class:`EnvelopeReport`.

Rules (all on the recorded channels, SI units):

- **spin**: body slip ``|atan2(v_y, v_x)|`` above :data:`SPIN_SLIP` (20 deg), or the car pointing
  more than :data:`SPIN_HEADING` (60 deg) away from the track direction. A large slide of a few
  degrees is inside the envelope (it is where tire effects show).
- **reversing**: ``v_x`` below ``-`` :data:`REVERSE_SPEED`.
- **standstill**: ``v_x`` below :data:`STANDSTILL_SPEED` (pit stop, stop on track, launch): slip
  angles are undefined near zero speed.
- **gap**: a time step longer than :data:`GAP_FACTOR` times the median step. No sample is
  dropped for a gap (none was recorded), but it is reported, and any stage predicting over time
  must not cross it.

Every excluded stretch is widened by :data:`MARGIN_S` seconds on both sides (the approach to a
spin and the recovery after it are transients too), and kept islands shorter than
:data:`MIN_KEEP_S` between exclusions are dropped as well.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SPIN_SLIP = 0.35
"""Body slip [rad] above which a sample counts as a spin (20 deg; race-car slides stay below ~10)."""
SPIN_HEADING = 1.05
"""|e_psi| [rad] above which the car points too far from the track direction (60 deg)."""
STANDSTILL_SPEED = 2.0
"""v_x [m/s] below which a sample counts as standstill."""
REVERSE_SPEED = 0.3
"""-v_x [m/s] beyond which the car is reversing."""
GAP_FACTOR = 1.5
"""A time step longer than this multiple of the median step is a gap."""
MARGIN_S = 0.5
"""Seconds excluded on each side of a spin / standstill / reversing stretch."""
MIN_KEEP_S = 1.0
"""Kept stretches shorter than this between two exclusions are excluded too."""

REASONS = ("kept", "standstill", "reversing", "spin")  # priority order: later wins within a stretch


@dataclass(frozen=True)
class Exclusion:
    """One contiguous excluded stretch (or one time gap, with ``samples == 0``)."""

    reason: str  # "spin" | "standstill" | "reversing" | "gap"
    first: int  # first excluded row (0-based); for a gap: the first row after it
    last: int  # last excluded row (inclusive); for a gap: equal to ``first``
    t_start: float
    t_end: float
    s_start: float
    s_end: float
    samples: int

    @property
    def seconds(self) -> float:
        return float(self.t_end - self.t_start)

    def text(self) -> str:
        if self.reason == "gap":
            return f"gap of {self.seconds:.2f} s in t at t {self.t_start:.1f}..{self.t_end:.1f} s (s {self.s_start:.0f} m)"
        return (f"{self.reason}: {self.samples} samples ({self.seconds:.1f} s) at t {self.t_start:.1f}.."
                f"{self.t_end:.1f} s, s {self.s_start:.0f}..{self.s_end:.0f} m")

    def to_dict(self) -> dict:
        return {"reason": self.reason, "first_row": self.first, "last_row": self.last,
                "t_start": round(self.t_start, 3), "t_end": round(self.t_end, 3),
                "s_start": round(self.s_start, 1), "s_end": round(self.s_end, 1),
                "samples": self.samples, "seconds": round(self.seconds, 3)}


@dataclass(frozen=True)
class EnvelopeReport:
    """What :func:`envelope` cut out of one recording."""

    source: str
    samples: int  # samples in the recording
    excluded: tuple[Exclusion, ...] = field(default_factory=tuple)

    @property
    def samples_excluded(self) -> int:
        return int(sum(e.samples for e in self.excluded))

    @property
    def seconds_excluded(self) -> float:
        return float(sum(e.seconds for e in self.excluded if e.reason != "gap"))

    @property
    def gaps(self) -> tuple[Exclusion, ...]:
        return tuple(e for e in self.excluded if e.reason == "gap")

    def note(self) -> str:
        """One line for a report; empty when nothing was excluded."""
        if not self.excluded:
            return ""
        parts = "; ".join(e.text() for e in self.excluded[:6])
        more = f"; and {len(self.excluded) - 6} more" if len(self.excluded) > 6 else ""
        return (f"{self.source}: outside the model's envelope, excluded {self.samples_excluded} of {self.samples} "
                f"samples ({self.seconds_excluded:.1f} s): {parts}{more}")

    def to_dict(self) -> dict:
        return {"source": self.source, "samples": self.samples, "samples_excluded": self.samples_excluded,
                "seconds_excluded": round(self.seconds_excluded, 3),
                "excluded": [e.to_dict() for e in self.excluded]}


def envelope(data: dict[str, np.ndarray], source: str = "<memory>") -> tuple[np.ndarray, EnvelopeReport]:
    """Keep-mask ``(n,)`` (True = inside the envelope) and the report of what was cut out.

    ``data`` holds at least the columns ``t, s, v_x, v_y, e_psi`` (a :class:`~gprace.io.runs.Run`'s
    ``data``); pure function, the arrays are not modified.
    """
    t = np.asarray(data["t"], dtype=float)
    s = np.asarray(data["s"], dtype=float)
    vx = np.asarray(data["v_x"], dtype=float)
    vy = np.asarray(data["v_y"], dtype=float)
    epsi = np.asarray(data["e_psi"], dtype=float)
    n = len(t)
    if n < 2:
        return np.ones(n, dtype=bool), EnvelopeReport(source, n)
    dt = float(np.median(np.diff(t)))

    code = np.zeros(n, dtype=np.int8)  # index into REASONS
    code = np.where(vx < STANDSTILL_SPEED, 1, code)
    code = np.where(vx < -REVERSE_SPEED, 2, code)
    spin = (np.abs(np.arctan2(vy, np.maximum(np.abs(vx), 1e-9))) > SPIN_SLIP) | (np.abs(epsi) > SPIN_HEADING)
    code = np.where(spin & (vx >= -REVERSE_SPEED), 3, code).astype(np.int8)

    # widen every flagged stretch by the margin (in samples), keeping the strongest reason
    w = max(int(round(MARGIN_S / max(dt, 1e-9))), 0)
    grown = code.copy()
    for k in range(1, w + 1):  # loop over the margin width (~10), not over samples
        grown[k:] = np.maximum(grown[k:], code[:-k])
        grown[:-k] = np.maximum(grown[:-k], code[k:])
    keep = grown == 0

    # drop short kept islands between exclusions (and at the ends next to one)
    min_keep = max(int(round(MIN_KEEP_S / max(dt, 1e-9))), 1)
    starts, ends = _runs(keep)
    if (~keep).any():
        short = (ends - starts + 1) < min_keep
        for a, b in zip(starts[short], ends[short]):  # a few stretches, not samples
            keep[a : b + 1] = False
            grown[a : b + 1] = np.maximum(grown[a : b + 1], 1)

    ex: list[Exclusion] = []
    xs, xe = _runs(~keep)
    for a, b in zip(xs, xe):  # one entry per excluded stretch
        reason = REASONS[int(np.max(grown[a : b + 1]))] if np.max(grown[a : b + 1]) > 0 else "standstill"
        t1 = t[b + 1] if b + 1 < n else t[b] + dt
        ex.append(Exclusion(reason, int(a), int(b), float(t[a]), float(t1), float(s[a]), float(s[b]), int(b - a + 1)))
    gaps = np.flatnonzero(np.diff(t) > GAP_FACTOR * dt)
    for g in gaps:
        ex.append(Exclusion("gap", int(g + 1), int(g + 1), float(t[g]), float(t[g + 1]), float(s[g]), float(s[g + 1]), 0))
    ex.sort(key=lambda e: e.t_start)
    return keep, EnvelopeReport(source, n, tuple(ex))


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last index of every run of True in ``mask``."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
