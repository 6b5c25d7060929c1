"""The model's envelope: which samples of a recording a dynamic bicycle model can describe.

ONE rule, shared by every stage that reads a recording (diagnose today; select-data and
``evaluate gp`` can call the same function). A test-day log holds spins, standstills, pit stops,
reversing and gaps in the logger's time stamps. Those samples are not errors of the file: they
are outside what the model (and the GPs learned on its residuals) is meant to describe, so they
are cut out and *reported* (how many samples and seconds, where in ``s`` and ``t``, why), never
silently used and never a reason to refuse the whole file.

:func:`envelope` is a pure function of the columns (vectorised, no loop over samples). It returns
a keep-mask and a small typed :class:`EnvelopeReport`.

Rules (all on the recorded channels, SI units), each on quantities that do not depend on the car's
size, so that a 1:10 car at 3 m/s and a 790 kg car at 30 m/s are judged alike (issue 36):

- **spin**: body slip ``|atan2(v_y, |v_x|)|`` above :data:`SPIN_SLIP` (20 deg); or a yaw rate in
  excess of the larger of the kinematic ones (``v_x tan(delta) / L`` of the steering, ``v_x kappa``
  of the road) by more than :data:`SPIN_EXCESS_G` g of lateral acceleration
  (``(|r| - r_kin) |v_x| > 1 g``: rotation no tire force sustains; only where the steering angle
  and the wheelbase are known, the road's curvature alone is no reference for a weaving car); or the car pointing more than
  :data:`WRONG_WAY` (100 deg) away from the track direction, i.e. going the wrong way. Each must
  hold over :data:`SUSTAIN_S` (a running majority), so one spike of a noisy ``v_y`` estimate is
  not a spin. A large slide of a few degrees is inside the envelope (it is where tire effects
  show). Moving slower than the standstill speed is never a spin (slip angles are undefined there).
- **standstill**: ``|v_x|`` below :func:`standstill_speed`: a fraction of the recording's typical
  moving speed and, when the wheelbase ``L`` is known, of the Froude speed ``sqrt(g L)`` (the
  speed at which a car of that size starts to need its tires), never below :data:`STANDSTILL_FLOOR`.
- **reversing**: ``v_x`` below minus half the standstill speed.
- **gap**: a time step longer than :data:`GAP_FACTOR` times the median step. No sample is
  dropped for a gap (none was recorded), but it is reported, and any stage predicting over time
  must not cross it.

Every excluded stretch is widened by :data:`MARGIN_S` seconds on both sides (the approach to a
spin and the recovery after it are transients too), and kept islands shorter than
:data:`MIN_KEEP_S` between exclusions are dropped as well. With the wheelbase these times are in
the car's own time scale ``sqrt(L / g)`` (0.5 s for a 2.5 m wheelbase, 0.18 s at 1:10): a
Froude-scaled copy of a drive (lengths x lambda, times and speeds x sqrt(lambda)) loses exactly
the same samples.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SPIN_SLIP = 0.35
"""Body slip [rad] above which a sample counts as a spin (20 deg; race-car slides stay below ~10)."""
SPIN_EXCESS_G = 1.0
"""Yaw rate beyond the kinematic one, as lateral acceleration ``(|r| - r_kin) |v_x|`` in g, above
which the car rotates faster than any tire force explains (a spin starting)."""
WRONG_WAY = 1.75
"""|e_psi| [rad] above which the car points against the track direction (100 deg)."""
SUSTAIN_S = 0.2
"""A spin condition must hold for the majority of this many seconds around a sample."""
STANDSTILL_TYPICAL = 0.15
"""Standstill below this share of the recording's typical (median moving) speed ..."""
STANDSTILL_FROUDE = 0.3
"""... and below this share of the Froude speed ``sqrt(g L)`` of the car (L the wheelbase)."""
STANDSTILL_FROUDE_FLOOR = 0.1
"""Standstill at least below this share of the Froude speed (a car creeping through the pits is
standing for a model of driving: 0.5 m/s for a 2.5 m wheelbase, 0.17 m/s at 1:10) ..."""
STANDSTILL_FLOOR = 0.2
"""... or, without the wheelbase, below this speed [m/s]."""
G = 9.81
GAP_FACTOR = 1.5
"""A time step longer than this multiple of the median step is a gap."""
MARGIN_S = 0.5
"""Seconds excluded on each side of a spin / standstill / reversing stretch (reference car)."""
MIN_KEEP_S = 1.0
"""Kept stretches shorter than this between two exclusions are excluded too (reference car)."""
REFERENCE_WHEELBASE = 2.5
"""The car whose time scale the times above are given in [m of wheelbase] (sqrt(L/g) = 0.5 s)."""

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
    samples_moving: int = -1  # samples driving forward faster than the standstill speed (-1: not computed)
    moving_kept: int = -1  # of those, the samples kept
    standstill_speed: float = float("nan")  # the speed [m/s] below which the car stands

    @property
    def moving_kept_share(self) -> float:
        """Share of the moving samples kept (NaN when not computed or none moving)."""
        if self.samples_moving <= 0:
            return float("nan")
        return self.moving_kept / self.samples_moving

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
                "samples_moving": self.samples_moving, "moving_kept": self.moving_kept,
                "standstill_speed": round(self.standstill_speed, 3),
                "excluded": [e.to_dict() for e in self.excluded]}


def standstill_speed(vx: np.ndarray, wheelbase: float | None = None) -> float:
    """The speed [m/s] below which a car stands: :data:`STANDSTILL_TYPICAL` of the recording's
    typical moving speed (the median of ``|v_x|`` where it exceeds the floor) and, with the
    wheelbase, :data:`STANDSTILL_FROUDE` of ``sqrt(g L)``: whichever is smaller, at least the floor
    (:data:`STANDSTILL_FROUDE_FLOOR` of ``sqrt(g L)``, or :data:`STANDSTILL_FLOOR` without ``L``).
    A 1:10 car (L 0.31 m, 3 m/s): 0.45 m/s; a 3 m wheelbase car at 30 m/s: 1.6 m/s."""
    v = np.abs(np.asarray(vx, dtype=float))
    moving = v[v > STANDSTILL_FLOOR]
    typical = STANDSTILL_TYPICAL * float(np.median(moving)) if len(moving) else STANDSTILL_FLOOR
    floor = STANDSTILL_FLOOR
    if wheelbase is not None and wheelbase > 0:
        froude = float(np.sqrt(G * wheelbase))
        typical = min(typical, STANDSTILL_FROUDE * froude)
        floor = STANDSTILL_FROUDE_FLOOR * froude
    return max(typical, floor)


def time_scale(wheelbase: float | None) -> float:
    """Factor on the envelope's times: ``sqrt(L / g)`` over that of the 2.5 m reference car
    (1 without the wheelbase)."""
    if wheelbase is None or wheelbase <= 0:
        return 1.0
    return float(np.sqrt(wheelbase / REFERENCE_WHEELBASE))


def envelope(data: dict[str, np.ndarray], source: str = "<memory>",
             wheelbase: float | None = None) -> tuple[np.ndarray, EnvelopeReport]:
    """Keep-mask ``(n,)`` (True = inside the envelope) and the report of what was cut out.

    ``data`` holds at least the columns ``t, s, v_x, v_y, e_psi`` (a :class:`~gprace.io.runs.Run`'s
    ``data``); with ``yaw_rate``, ``delta`` and ``kappa`` the yaw-rate test runs too (``delta``
    only with the ``wheelbase`` [m]). Pure function, the arrays are not modified.
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
    v_stand = standstill_speed(vx, wheelbase)
    ts = time_scale(wheelbase)

    code = _reason_codes(data, vx, vy, epsi, v_stand, ts, dt, wheelbase)

    # widen every flagged stretch by the margin (in samples), keeping the strongest reason
    w = max(int(round(MARGIN_S * ts / max(dt, 1e-9))), 0)
    grown = code.copy()
    for k in range(1, w + 1):  # loop over the margin width (~10), not over samples
        grown[k:] = np.maximum(grown[k:], code[:-k])
        grown[:-k] = np.maximum(grown[:-k], code[k:])
    keep = grown == 0

    # drop short kept islands between exclusions (and at the ends next to one)
    min_keep = max(int(round(MIN_KEEP_S * ts / max(dt, 1e-9))), 1)
    starts, ends = true_runs(keep)
    if (~keep).any():
        short = (ends - starts + 1) < min_keep
        for a, b in zip(starts[short], ends[short]):  # a few stretches, not samples
            keep[a : b + 1] = False
            grown[a : b + 1] = np.maximum(grown[a : b + 1], 1)

    ex = _exclusions(keep, grown, t, s, w, dt)
    gaps = np.flatnonzero(np.diff(t) > GAP_FACTOR * dt)
    for g in gaps:
        ex.append(Exclusion("gap", int(g + 1), int(g + 1), float(t[g]), float(t[g + 1]), float(s[g]), float(s[g + 1]), 0))
    ex.sort(key=lambda e: e.t_start)
    moving = vx >= v_stand  # driving forward (reversing is not driving the lap)
    return keep, EnvelopeReport(source, n, tuple(ex), int(moving.sum()), int((keep & moving).sum()), v_stand)


def _reason_codes(data: dict[str, np.ndarray], vx: np.ndarray, vy: np.ndarray, epsi: np.ndarray, v_stand: float,
                  ts: float, dt: float, wheelbase: float | None) -> np.ndarray:
    """Per sample the index into :data:`REASONS` (0: inside): standing, reversing, or a sustained
    spin (slip angle, yaw rate beyond the steering's, heading the wrong way)."""
    n = len(vx)
    code = np.zeros(n, dtype=np.int8)  # index into REASONS
    stand = np.abs(vx) < v_stand
    code = np.where(stand, 1, code)
    code = np.where(vx < -0.5 * v_stand, 2, code)
    speed = np.maximum(np.abs(vx), 1e-9)
    spin = np.abs(np.arctan2(vy, speed)) > SPIN_SLIP
    if "yaw_rate" in data and "delta" in data and wheelbase:
        # only against the steering: the road's curvature alone is no reference (a car weaving on a
        # straight at 35 m/s turns at 0.3 rad/s on its tires, 1 g "in excess" of v_x kappa = 0)
        r_kin = np.abs(vx * np.tan(np.asarray(data["delta"], dtype=float)) / wheelbase)
        if "kappa" in data:
            r_kin = np.maximum(r_kin, np.abs(vx * np.asarray(data["kappa"], dtype=float)))
        excess = (np.abs(np.asarray(data["yaw_rate"], dtype=float)) - r_kin) * speed
        spin |= excess > SPIN_EXCESS_G * G
    spin |= np.abs(epsi) > WRONG_WAY
    spin = _sustained(spin, max(int(round(SUSTAIN_S * ts / max(dt, 1e-9))), 1)) & ~stand
    code = np.where(spin & (vx >= -0.5 * v_stand), 3, code).astype(np.int8)
    return code


def _exclusions(keep: np.ndarray, grown: np.ndarray, t: np.ndarray, s: np.ndarray, w: int, dt: float) -> list[Exclusion]:
    """One :class:`Exclusion` per excluded stretch of ``keep`` and reason (``grown``: the widened
    reason codes, merged in place where a piece shorter than the margin ``w`` joins its stronger
    neighbour)."""
    n = len(t)
    ex: list[Exclusion] = []
    xs, xe = true_runs(~keep)
    for a0, b0 in zip(xs, xe):  # one entry per excluded stretch and reason (a spin, then standing)
        g = np.maximum(grown[a0 : b0 + 1], 1)
        cut = np.flatnonzero(np.diff(g)) + 1
        pieces = [[a, b] for a, b in zip(np.r_[0, cut] + a0, np.r_[cut, len(g)] + a0 - 1)]
        while len(pieces) > 1:  # a piece shorter than the margin joins its stronger neighbour
            size = [b - a + 1 for a, b in pieces]
            i = int(np.argmin(size))
            if size[i] > w:
                break
            j = i - 1 if i == len(pieces) - 1 or (i > 0 and grown[pieces[i - 1][0]] >= grown[pieces[i + 1][0]]) else i + 1
            lo, hi = min(pieces[i][0], pieces[j][0]), max(pieces[i][1], pieces[j][1])
            grown[lo : hi + 1] = max(grown[pieces[i][0]], grown[pieces[j][0]])
            pieces[min(i, j)] = [lo, hi]
            del pieces[max(i, j)]
        merged: list[list[int]] = []
        for a, b in pieces:  # neighbours of one reason are one stretch
            if merged and grown[merged[-1][0]] == grown[a]:
                merged[-1][1] = b
            else:
                merged.append([a, b])
        for a, b in merged:
            reason = REASONS[int(grown[a : b + 1].max(initial=1))]
            t1 = t[b + 1] if b + 1 < n else t[b] + dt
            ex.append(Exclusion(reason, int(a), int(b), float(t[a]), float(t1), float(s[a]), float(s[b]), int(b - a + 1)))
    return ex


def _sustained(flag: np.ndarray, w: int) -> np.ndarray:
    """``flag`` where it holds for the majority of the ``w`` (odd, at least 1) samples centred on
    each sample: a centred running count, so isolated spikes drop out and long stretches keep
    their exact ends."""
    w = w + 1 - w % 2
    if w <= 1:
        return flag.copy()
    h = w // 2
    c = np.concatenate([[0], np.cumsum(flag.astype(np.int64))])
    i = np.arange(len(flag))
    lo, hi = np.maximum(i - h, 0), np.minimum(i + h + 1, len(flag))
    return (c[hi] - c[lo]) * 2 > (hi - lo)


def true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last index of every run of True in ``mask`` (vectorised)."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
