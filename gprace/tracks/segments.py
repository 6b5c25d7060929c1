"""Tracks described by segments: straights, arcs and chicanes, as in a TOML track file.

.. code-block:: toml

    name = "example"
    closed = true
    width = 10.0                      # total width, centred; or width_left / width_right
    start = { x = 0.0, y = 0.0, heading = 0.0 }   # optional, heading [rad]

    [[segments]]
    type = "straight"
    length = 300.0                    # [m]

    [[segments]]
    type = "arc"
    radius = 50.0                     # [m]
    angle_deg = 90.0                  # swept angle, > 0 turns left; or `angle` in radians

    [[segments]]
    type = "chicane"                  # two opposite arcs, `gap` metres of straight between them
    radius = 30.0
    angle_deg = -25.0                 # the first arc's angle (here a right flick first)
    gap = 10.0

Any segment may override the widths (``width`` or ``width_left``/``width_right``) for its own
length. The centre line is generated exactly (closed-form arcs) at a fine spacing and handed to
:class:`~gprace.tracks.track.Track` without smoothing, so the arcs keep their exact curvature
``+-1/R`` away from the joins (the cubic spline makes the curvature continuous across a join
within about one knot spacing).

Closing a closed track: the segments must return to the start within 0.1 % of the track length
and within 0.01 rad of the start heading, else :class:`~gprace.errors.InputError` says by how
much they miss. The remaining small position error is removed by a linear shear along the arc
length (point ``k`` moves by ``-(s_k / L) * gap``), so the loop closes exactly; the periodic spline
absorbs the residual heading mismatch.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

import numpy as np
from pydantic import Field, model_validator

from gprace.config import Frozen
from gprace.errors import InputError

CLOSE_POS_TOL = 1e-3
"""Largest allowed closure gap of a closed segment track, as a share of its length."""
CLOSE_HEADING_TOL = 1e-2
"""Largest allowed heading mismatch at the closure of a closed segment track [rad]."""


class _Widths(Frozen):
    width: float | None = Field(None, gt=0, allow_inf_nan=False, description="total width, centred [m]")
    width_left: float | None = Field(None, gt=0, allow_inf_nan=False, description="centre line to left border [m]")
    width_right: float | None = Field(None, gt=0, allow_inf_nan=False, description="centre line to right border [m]")

    @model_validator(mode="after")
    def _one_width_form(self):
        if self.width is not None and (self.width_left is not None or self.width_right is not None):
            raise ValueError("give either width or width_left/width_right, not both")
        if (self.width_left is None) != (self.width_right is None):
            raise ValueError("width_left and width_right go together")
        return self

    def sides(self) -> tuple[float, float] | None:
        if self.width is not None:
            return 0.5 * self.width, 0.5 * self.width
        if self.width_left is not None:
            return self.width_left, self.width_right
        return None


class _Angle(_Widths):
    angle: float | None = Field(None, allow_inf_nan=False, description="swept angle [rad], > 0 turns left")
    angle_deg: float | None = Field(None, allow_inf_nan=False, description="swept angle [deg], > 0 turns left")

    @model_validator(mode="after")
    def _one_angle(self):
        if (self.angle is None) == (self.angle_deg is None):
            raise ValueError("give exactly one of angle [rad] or angle_deg [deg]")
        if self.theta == 0 or not np.isfinite(self.theta):
            raise ValueError("the swept angle must be finite and non-zero")
        return self

    @property
    def theta(self) -> float:
        return float(self.angle) if self.angle is not None else float(np.deg2rad(self.angle_deg))


class Straight(_Widths):
    type: Literal["straight"]
    length: float = Field(gt=0, allow_inf_nan=False, description="length [m]")


class Arc(_Angle):
    type: Literal["arc"]
    radius: float = Field(gt=0, allow_inf_nan=False, description="centre-line radius [m]")


class Chicane(_Angle):
    type: Literal["chicane"]
    radius: float = Field(gt=0, allow_inf_nan=False, description="radius of both arcs [m]")
    gap: float = Field(ge=0, allow_inf_nan=False, description="straight between the two arcs [m]")


Segment = Annotated[Union[Straight, Arc, Chicane], Field(discriminator="type")]


class StartPose(Frozen):
    x: float = Field(0.0, allow_inf_nan=False, description="initial x [m]")
    y: float = Field(0.0, allow_inf_nan=False, description="initial y [m]")
    heading: float = Field(0.0, allow_inf_nan=False, description="initial heading [rad]")


class SegmentTrack(Frozen):
    """A track file made of segments (module docstring)."""

    name: str | None = Field(None, description="track name; default the file name")
    closed: bool = Field(description="whether the last segment joins the first")
    width: float | None = Field(None, gt=0, allow_inf_nan=False, description="total width, centred [m]")
    width_left: float | None = Field(None, gt=0, allow_inf_nan=False, description="centre line to left border [m]")
    width_right: float | None = Field(None, gt=0, allow_inf_nan=False, description="centre line to right border [m]")
    start: StartPose = Field(default_factory=StartPose)
    transition: float | None = Field(
        None, ge=0, description="curvature ramp length at joins [m]; default from the geometry"
    )
    segments: list[Segment] = Field(min_length=1)

    @model_validator(mode="after")
    def _widths(self):
        if self.width is not None and (self.width_left is not None or self.width_right is not None):
            raise ValueError("give either width or width_left/width_right, not both")
        if self.width is None and (self.width_left is None or self.width_right is None):
            raise ValueError("the track needs width, or both width_left and width_right")
        return self

    def sides(self) -> tuple[float, float]:
        if self.width is not None:
            return 0.5 * self.width, 0.5 * self.width
        return float(self.width_left), float(self.width_right)


# ----------------------------------------------------------------------------------------------
# geometry


def _primitives(segments) -> list[tuple[float, float, tuple | None]]:
    """``(length, curvature, sides)`` pieces: a chicane becomes arc, straight, opposite arc."""
    out = []
    for seg in segments:
        sides = seg.sides()
        if isinstance(seg, Straight):
            out.append((seg.length, 0.0, sides))
        elif isinstance(seg, Arc):
            out.append((seg.radius * abs(seg.theta), np.sign(seg.theta) / seg.radius, sides))
        else:
            k = np.sign(seg.theta) / seg.radius
            arc = seg.radius * abs(seg.theta)
            out.append((arc, k, sides))
            if seg.gap > 0:
                out.append((seg.gap, 0.0, sides))
            out.append((arc, -k, sides))
    return out


def default_transition(spec: SegmentTrack) -> float:
    """Curvature transition length [m]: half of the smaller of the smallest radius and the
    shortest curved piece, so every arc still reaches its full curvature ``1/R``."""
    curved = [(length, abs(k)) for length, k, _ in _primitives(spec.segments) if k != 0.0]
    if not curved:
        return 0.0
    return 0.5 * min(min(1.0 / k for _, k in curved), min(length for length, _ in curved))


def centre_line(spec: SegmentTrack, where: str, ds: float | None = None):
    """Centre-line points ``x, y, wl, wr`` and their spacing ``ds`` of a segment track.

    The curvature of the segments (piecewise constant) is averaged over a sliding window of
    ``spec.transition`` metres, which turns every join into a linear curvature ramp (a clothoid,
    as on real roads) and keeps the exact ``1/R`` elsewhere; the heading change of every piece is
    unchanged. Points are integrated exactly for constant curvature per step. Default spacing:
    the smallest of ``L / 2000``, a twentieth of the smallest radius and a quarter of the transition.
    For a closed track the segments must close (module docstring) and the small remaining gap
    is sheared out.
    """
    prims = _primitives(spec.segments)
    lengths = np.array([p[0] for p in prims])
    kap = np.array([p[1] for p in prims])
    total = float(lengths.sum())
    trans = default_transition(spec) if spec.transition is None else float(spec.transition)
    if ds is None:
        rmin = min((1.0 / abs(k) for k in kap if k != 0.0), default=np.inf)
        ds = min(total / 2000.0, 0.05 * rmin, 0.25 * trans if trans > 0 else np.inf)
    th_start = spec.start.heading

    if spec.closed:
        ex, ey, eth = end_pose(spec)
        gap0 = np.hypot(ex - spec.start.x, ey - spec.start.y)
        dth = (eth - th_start + np.pi) % (2 * np.pi) - np.pi
        if gap0 > CLOSE_POS_TOL * total or abs(dth) > CLOSE_HEADING_TOL:
            raise InputError(
                f"{where}: closed = true but the segments do not close: the end is "
                f"{gap0:.3f} m (dx {ex - spec.start.x:.3f}, dy {ey - spec.start.y:.3f}) and "
                f"{np.rad2deg(dth):.2f} deg from the start (allowed {CLOSE_POS_TOL * total:.3f} m, "
                f"{np.rad2deg(CLOSE_HEADING_TOL):.2f} deg); adjust segment lengths or angles"
            )

    bounds = np.concatenate([[0.0], np.cumsum(lengths)])
    theta_b = np.concatenate([[0.0], np.cumsum(lengths * kap)])  # heading change at piece starts
    turn = theta_b[-1]

    def big_theta(q):
        """Exact heading change from s = 0 (piecewise linear), extended beyond the ends."""
        if spec.closed:
            lap = np.floor(q / total)
            r = q - lap * total
            return lap * turn + np.interp(r, bounds, theta_b)
        inside = np.interp(q, bounds, theta_b)
        inside = np.where(q < 0, q * kap[0], inside)
        return np.where(q > total, turn + (q - total) * kap[-1], inside)

    m = max(int(np.ceil(total / ds)), 4)
    s = np.linspace(0.0, total, m + 1)
    h = total / m
    mid = s[:-1] + 0.5 * h
    if trans > 0:
        k_mid = (big_theta(mid + 0.5 * trans) - big_theta(mid - 0.5 * trans)) / trans
    else:
        k_mid = (big_theta(s[1:]) - big_theta(s[:-1])) / h
    theta = th_start + np.concatenate([[0.0], np.cumsum(k_mid * h)])
    chord = h * np.sinc(k_mid * h / (2 * np.pi))  # 2 sin(k h / 2) / k
    dirn = theta[:-1] + 0.5 * k_mid * h
    x = spec.start.x + np.concatenate([[0.0], np.cumsum(chord * np.cos(dirn))])
    y = spec.start.y + np.concatenate([[0.0], np.cumsum(chord * np.sin(dirn))])

    base = spec.sides()
    sides = np.array([p[2] if p[2] is not None else base for p in prims])
    piece = np.clip(np.searchsorted(bounds, s, side="right") - 1, 0, len(prims) - 1)
    wl, wr = sides[piece, 0], sides[piece, 1]

    if spec.closed:
        gap = np.array([x[-1] - x[0], y[-1] - y[0]])
        x = x - (s / total) * gap[0]
        y = y - (s / total) * gap[1]
        x, y, wl, wr = x[:-1], y[:-1], wl[:-1], wr[:-1]
    return x, y, wl, wr, float(h)


def end_pose(spec: SegmentTrack) -> tuple[float, float, float]:
    """End ``(x, y, heading)`` of the segments (before any closure correction)."""
    x, y, th = spec.start.x, spec.start.y, spec.start.heading
    for length, k, _ in _primitives(spec.segments):
        if k == 0.0:
            x, y = x + length * np.cos(th), y + length * np.sin(th)
        else:
            x, y = x + (np.sin(th + k * length) - np.sin(th)) / k, y - (np.cos(th + k * length) - np.cos(th)) / k
        th += k * length
    return float(x), float(y), float(th)


def build_track(spec: SegmentTrack, name: str, where: str, ds: float | None = None):
    """A :class:`Track` from a validated segment description."""
    from gprace.tracks.track import Track

    x, y, wl, wr, step = centre_line(spec, where, ds)
    return Track(x, y, wl, wr, closed=spec.closed, name=name, smoothing=0.0, spacing=step, source=where)
