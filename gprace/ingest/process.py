"""From raw signals (:class:`~gprace.ingest.readers.Raw`) to a Frenet :class:`~gprace.io.runs.Run`.

Pipeline (all vectorised over samples; see docs/decisions.md, "Import (issue 15)"):

1. **Time base.** One uniform grid of period ``dt`` over the span every used source covers.
   Each quantity is resampled on its own: linearly (angles unwrapped first), or by zero-order hold
   for commands (``hold`` in the map: a command holds until the next one).
2. **Gaps stay gaps.** A grid point is *valid* for a source when the source has samples on both
   sides no further apart than ``max_gap`` (or a sample within 1 us of it). Rows where any used
   source is invalid are left out: the ``t`` column jumps over the gap and a ``segment`` column
   counts the contiguous pieces. Derivatives (speed from positions, yaw rate from heading, a_x from
   speed) never reach across a gap (one-sided differences at segment ends).
3. **Global state.** Position from ``x, y`` or ``lat, lon`` (local tangent plane at the first
   fix, WGS84); heading from ``yaw`` (else the velocity heading, then the path heading); body
   velocities from ``v_x, v_y``, or speed + course, or world-frame velocities, or positions.
4. **Unit checks** (robust medians over the moving samples): the speed the velocity columns give vs
   the speed from successive positions, the heading change vs the path's, the yaw rate vs the
   heading change, a_x vs the change of speed, the steering range. A ratio off by a known unit
   factor (3.6, 2.237, 57.3, 9.81) names the column and the probable unit.
5. **Projection** onto the centre line (``Track.to_frenet``: nearest point, then a second pass with
   the continued ``s`` as hint so self-crossing tracks follow the driven branch): ``s, e_y``,
   ``e_psi = yaw - heading(s)``, ``kappa(s)``; laps counted from the continued ``s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gprace.errors import InputError
from gprace.ingest.mapping import UNITS, RecordingMap
from gprace.ingest.readers import Raw, Signal

ANGLES = ("yaw", "course", "lat", "lon")
TOL = 1e-6
"""Time tolerance [s] for a sample to count as exactly on a grid point."""


@dataclass
class Grid:
    t: np.ndarray  # (n,) grid times [s], recording epoch
    valid: np.ndarray  # (n,) bool: every used source is valid
    dt: float


# ----------------------------------------------------------------------------------------------
# resampling


def _dedupe(sig: Signal) -> tuple[np.ndarray, np.ndarray]:
    t, v = sig.t, sig.v
    if len(t) > 1:
        keep = np.concatenate([np.diff(t) > 0, [True]])  # equal stamps: keep the last
        t, v = t[keep], v[keep]
    return t, v


def default_max_gap(t: np.ndarray, dt: float) -> float:
    per = float(np.median(np.diff(t))) if len(t) > 1 else dt
    return max(5.0 * per, 2.0 * dt)


def resample(sig: Signal, tg: np.ndarray, dt: float, max_gap: float | None, hold: bool, angle: bool):
    """Values of ``sig`` at grid times ``tg`` and a validity mask (gaps, outside the span)."""
    t, v = _dedupe(sig)
    if len(t) == 0:
        return np.zeros(len(tg)), np.zeros(len(tg), dtype=bool)
    gap = default_max_gap(t, dt) if max_gap is None else max_gap
    if angle:
        v = np.unwrap(v)
    i0 = np.searchsorted(t, tg + TOL, side="right") - 1  # last sample at or before tg
    i0c = np.clip(i0, 0, len(t) - 1)
    i1c = np.clip(i0 + 1, 0, len(t) - 1)
    exact = (i0 >= 0) & (np.abs(tg - t[i0c]) <= TOL)
    inside = (i0 >= 0) & (i0 + 1 < len(t))
    if hold:
        val = v[i0c]
        ok = exact | ((i0 >= 0) & (tg - t[i0c] <= gap) & ((t[i1c] - t[i0c] <= gap) | (i0 + 1 >= len(t))))
        ok &= tg <= t[-1] + gap
    else:
        val = np.interp(tg, t, v)
        ok = exact | (inside & (t[i1c] - t[i0c] <= gap))
    return val, ok


def _measured_or_rate(vals: dict, name: str, of: np.ndarray, valid: np.ndarray, dt: float, notes: list[str],
                      what: str) -> tuple[np.ndarray, np.ndarray]:
    """The recorded channel ``name``, or the rate of change of ``of`` (noted; valid where defined)."""
    if name in vals:
        return vals[name], valid
    rate, ok = seg_gradient(of, valid, dt)
    notes.append(f"no {name}: from {what}")
    return rate, valid & ok


def seg_gradient(v: np.ndarray, valid: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """d v / dt on a uniform grid by central differences inside valid runs, one-sided at their
    ends; never across an invalid sample. Returns the derivative and where it is defined."""
    n = len(v)
    fwd = np.full(n, np.nan)
    bwd = np.full(n, np.nan)
    pair = valid[:-1] & valid[1:]
    d = np.diff(v) / dt
    fwd[:-1] = np.where(pair, d, np.nan)
    bwd[1:] = np.where(pair, d, np.nan)
    both = np.isfinite(fwd) & np.isfinite(bwd)
    out = np.where(both, 0.5 * (fwd + bwd), np.where(np.isfinite(fwd), fwd, bwd))
    ok = np.isfinite(out) & valid
    return np.where(ok, out, 0.0), ok


def wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


# ----------------------------------------------------------------------------------------------
# geodesy


def enu_from_latlon(lat_rad: np.ndarray, lon_rad: np.ndarray, lat0: float, lon0: float):
    """East/north [m] of WGS84 points in the local tangent plane at ``(lat0, lon0)`` (height 0)."""
    a, f = 6378137.0, 1.0 / 298.257223563
    e2 = f * (2.0 - f)

    def ecef(la, lo):
        n = a / np.sqrt(1.0 - e2 * np.sin(la) ** 2)
        return n * np.cos(la) * np.cos(lo), n * np.cos(la) * np.sin(lo), n * (1.0 - e2) * np.sin(la)

    x, y, z = ecef(lat_rad, lon_rad)
    x0, y0, z0 = ecef(np.array(lat0), np.array(lon0))
    dx, dy, dz = x - x0, y - y0, z - z0
    sl, cl, so, co = math.sin(lat0), math.cos(lat0), math.sin(lon0), math.cos(lon0)
    east = -so * dx + co * dy
    north = -sl * co * dx - sl * so * dy + cl * dz
    return east, north


# ----------------------------------------------------------------------------------------------
# global state on the grid


@dataclass
class GlobalState:
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray  # unwrapped
    v_x: np.ndarray
    v_y: np.ndarray
    yaw_rate: np.ndarray
    delta: np.ndarray
    a_x: np.ndarray
    valid: np.ndarray
    notes: list[str]
    origin: dict[str, str]
    v_cmd: np.ndarray | None = None  # speed command [m/s] when the recording has one
    a_x_source: str = "column"  # "column" or "derived" (from the change of v_x)


def global_state(raw: Raw, rmap: RecordingMap, dt: float) -> GlobalState:
    """Resample every quantity onto one grid and derive the full global state (module docstring)."""
    S = raw.signals
    notes: list[str] = []
    pos, used = _used_signals(raw)
    start = max(float(S[q].t[0]) for q in used)
    end = min(float(S[q].t[-1]) for q in used)
    if not end > start + 2 * dt:
        spans = ", ".join(f"{S[q].origin} {S[q].t[0]:.3f}..{S[q].t[-1]:.3f} s" for q in used)
        raise InputError(f"{raw.source}: the sources do not overlap in time for more than 2 periods ({spans})")
    check_clock(raw, used, start, end, dt)
    n = int(math.floor((end - start) / dt + 1e-9)) + 1
    tg = start + dt * np.arange(n)
    vals, valid = {}, np.ones(n, dtype=bool)
    held = rmap.held()
    for q in used:
        v, ok = resample(S[q], tg, dt, rmap.max_gap, q in held, q in ANGLES)
        vals[q] = v
        valid &= ok
    _constant_channels(raw, vals, valid, notes)
    if pos == ("lat", "lon"):
        if rmap.origin is not None:
            lat0, lon0 = math.radians(rmap.origin[0]), math.radians(rmap.origin[1])
        else:
            lat0, lon0 = float(S["lat"].v[0]), float(S["lon"].v[0])
        x, y = enu_from_latlon(vals["lat"], vals["lon"], lat0, lon0)
        notes.append(f"lat/lon projected on the tangent plane at ({math.degrees(lat0):.6f}, {math.degrees(lon0):.6f})")
    else:
        x, y = vals["x"], vals["y"]
    valid = _position_jumps(raw, tg, x, y, vals, valid, dt, notes)
    yaw, v_x, v_y, valid = _heading_and_velocity(vals, x, y, valid, dt, notes)
    yaw_rate, valid = _measured_or_rate(vals, "yaw_rate", yaw, valid, dt, notes, "the heading")
    delta = vals["delta"] if "delta" in vals else vals["steering_wheel"] / rmap.steering_ratio
    a_x_source = "column" if "a_x" in vals else "derived"
    a_x, valid = _measured_or_rate(vals, "a_x", v_x, valid, dt, notes, "the change of v_x")
    if a_x_source == "derived":
        # the longitudinal acceleration of the body, as an accelerometer along x measures it: in
        # the rotating body frame dv_x/dt = a_x + r v_y (the model's kinematic v_x equation, which
        # reads a derived a_x); dv_x/dt itself would count r v_y twice (INI F1TENTH: 15-step v_x
        # errors 0.64 m/s learned against 0.45 nominal)
        a_x = a_x - yaw_rate * v_y
        notes[-1] = "no a_x: from the change of v_x less r v_y (the body's longitudinal acceleration)"
    origin = {q: S[q].origin for q in S}
    gs = GlobalState(tg, x, y, yaw, v_x, v_y, yaw_rate, delta, a_x, valid, notes, origin,
                     vals.get("v_cmd"), a_x_source)
    if rmap.check_units:
        check_units(raw, gs, vals, dt)
    return gs


def _used_signals(raw: Raw) -> tuple[tuple[str, str], list[str]]:
    """The position pair (``x, y`` or ``lat, lon``) and every quantity the global state is made
    from: position, heading, the first complete velocity group, steering, what else is there."""
    S = raw.signals
    if S.get("x") is not None and S.get("y") is not None:
        pos = ("x", "y")
    elif S.get("lat") is not None and S.get("lon") is not None:
        pos = ("lat", "lon")
    else:
        raise raw.missing("position", ("x", "y"))
    if "delta" not in S and "steering_wheel" not in S:
        raise raw.missing("steering angle", ("delta", "steering_wheel"))
    used = list(pos) + [q for q in ("yaw", "yaw_rate", "a_x", "v_cmd") if q in S]
    if "yaw" not in S and "course" in S:
        used.append("course")
    for group in (("v_x", "v_y"), ("speed", "course"), ("v_east", "v_north"), ("speed",)):
        if group[0] in S and (len(group) == 1 or group[1] in S or group[0] == "v_x"):
            used += [q for q in group if q in S and q not in used]
            break
    used.append("delta" if "delta" in S else "steering_wheel")
    return pos, used


def _heading_and_velocity(vals: dict[str, np.ndarray], x: np.ndarray, y: np.ndarray, valid: np.ndarray, dt: float,
                          notes: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Yaw and body-frame velocities ``(yaw, v_x, v_y, valid)`` from what the recording has, in
    this order: yaw, course, the path's heading; v_x (and v_y), speed and course, east/north
    velocities, speed along the path, successive positions. Derived quantities narrow ``valid``
    to where the positions' differences exist."""
    vxw, okx = seg_gradient(x, valid, dt)
    vyw, oky = seg_gradient(y, valid, dt)
    path_heading = np.unwrap(np.arctan2(vyw, vxw))
    if "yaw" in vals:
        yaw = vals["yaw"]
    elif "course" in vals:
        yaw = vals["course"]
        notes.append("no yaw: heading of the velocity used (v_y = 0)")
    else:
        yaw = path_heading
        valid = valid & okx & oky
        notes.append("no yaw: heading of the path used (v_y = 0)")
    if "v_x" in vals:
        v_x = vals["v_x"]
        if "v_y" in vals:
            v_y = vals["v_y"]
        else:
            v_y = -np.sin(yaw) * vxw + np.cos(yaw) * vyw
            valid = valid & okx & oky
            notes.append("no v_y: from successive positions")
    elif "speed" in vals and "course" in vals:
        v_x, v_y = vals["speed"] * np.cos(vals["course"] - yaw), vals["speed"] * np.sin(vals["course"] - yaw)
    elif "v_east" in vals and "v_north" in vals:
        c, s_ = np.cos(yaw), np.sin(yaw)
        v_x, v_y = c * vals["v_east"] + s_ * vals["v_north"], -s_ * vals["v_east"] + c * vals["v_north"]
    elif "speed" in vals:
        v_x, v_y = vals["speed"] * np.cos(path_heading - yaw), vals["speed"] * np.sin(path_heading - yaw)
    else:
        c, s_ = np.cos(yaw), np.sin(yaw)
        v_x, v_y = c * vxw + s_ * vyw, -s_ * vxw + c * vyw
        valid = valid & okx & oky
        notes.append("no velocities: from successive positions")
    return yaw, v_x, v_y, valid


def check_clock(raw: Raw, used: list[str], start: float, end: float, dt: float) -> None:
    """Refuse a grid far denser than the data before it is allocated: time stamps in ms, us or ns
    read as seconds (the hint names the unit), or a span no recording has."""
    S = raw.signals
    n_grid = (end - start) / dt
    n_data = max(len(S[q].t) for q in used)
    if n_grid <= 50.0 * n_data + 1e5:
        return
    declared = raw.units.get("t", "s")
    q = max(used, key=lambda k: len(S[k].t))
    per = float(np.median(np.diff(S[q].t))) / UNITS["time"][declared]  # in the declared unit
    for unit, f in sorted(UNITS["time"].items(), key=lambda kv: -kv[1]):
        if unit != declared and 1e-4 <= per * f <= 2.0:
            raise InputError(
                f"{raw.source}: the time stamps advance by {per:.4g} {declared} per sample ({S[q].origin}): "
                f"the time stamps look like {unit}, not {declared}: set [units] t = \"{unit}\" in the map")
    raise InputError(
        f"{raw.source}: {end - start:.4g} s of recording at --dt {dt:g} s would make {n_grid:.3g} rows from "
        f"{n_data} samples; check the time column's unit ([units] t) or the clock offsets ([clocks])")


def _position_jumps(raw: Raw, tg, x, y, vals: dict, valid: np.ndarray, dt: float, notes: list[str]) -> np.ndarray:
    """Leave out positions that jump further than the car can go (a GNSS glitch, a re-fix): a
    step longer than 10 times the distance the speed (else the typical step) allows. A single
    sample off and back is dropped; after a lasting jump the rows before it and after it are
    separate pieces (the projection checks the rest against the track)."""
    idx = np.flatnonzero(valid)
    if len(idx) < 4:
        return valid
    px, py = x[idx], y[idx]
    step = np.hypot(np.diff(px), np.diff(py))
    gap_dt = np.diff(tg[idx])
    speed = None
    for group in (("v_x", "v_y"), ("v_x",), ("speed",), ("v_east", "v_north")):
        if all(q in vals for q in group):
            speed = np.hypot(*[vals[q][idx] for q in group]) if len(group) > 1 else np.abs(vals[group[0]][idx])
            break
    typical = float(np.median(step))
    allow = np.maximum(typical, 0.5 * (speed[1:] + speed[:-1]) * gap_dt if speed is not None else typical * gap_dt / dt)
    jump = step > 10.0 * allow + 1e-3
    if not jump.any():
        return valid
    out = valid.copy()
    j = np.flatnonzero(jump)
    # a spike: a jump out and one back, with the points either side close together
    spike = np.zeros(len(idx), dtype=bool)
    inner = j[(j + 1 < len(step)) & np.isin(j + 1, j)]
    back = np.hypot(px[np.minimum(inner + 2, len(px) - 1)] - px[inner], py[np.minimum(inner + 2, len(px) - 1)] - py[inner])
    spike[inner[back <= 10.0 * 2 * allow[inner]] + 1] = True
    lasting = [k for k in j if not (spike[k + 1] or spike[k])]
    out[idx[spike]] = False
    for k in lasting:  # the row after a lasting jump starts a new piece: drop the row before it
        out[idx[k]] = False
    biggest = float(step[j].max())
    k0 = int(j[np.argmax(step[j])])
    notes.append(f"positions jump {len(j)} time(s) further than the speed allows (largest {biggest:.4g} m at "
                 f"t = {tg[idx[k0 + 1]] - tg[idx[0]]:.2f} s, {raw.signals['x'].origin if 'x' in raw.signals else 'position'}): "
                 f"{int(spike.sum())} glitch sample(s) left out, {len(lasting)} break(s) in the recording")
    return out


CONSTANT_FALLBACK = {"a_x": "the change of v_x", "yaw_rate": "the heading", "v_y": "successive positions"}


def _constant_channels(raw: Raw, vals: dict, valid: np.ndarray, notes: list[str]) -> None:
    """A channel that never changes (a placeholder: all zeros, a stuck sensor) is named in a note;
    ``a_x``, ``yaw_rate`` and ``v_y`` are then taken as absent and derived as when missing."""
    if valid.sum() < 3:
        return
    for q in ("v_x", "v_y", "yaw_rate", "delta", "steering_wheel", "a_x", "speed", "v_cmd"):
        if q not in vals:
            continue
        v = vals[q][valid]
        if np.ptp(v) > 1e-12 * max(1.0, abs(float(v[0]))):
            continue
        what = f"{raw.signals[q].origin} is constant ({float(v[0]):.6g})"
        if q in CONSTANT_FALLBACK:
            notes.append(f"{what}: left out, {q} from {CONSTANT_FALLBACK[q]}")
            del vals[q]
        else:
            notes.append(f"{what}: kept, but it carries no information")


# ----------------------------------------------------------------------------------------------
# unit checks


def _probable_unit(dimension: str, declared: str, ratio: float) -> str | None:
    """The unit whose factor explains a measured/expected ``ratio`` (within 12 %), if any."""
    if not ratio > 0:
        return None
    f_true = UNITS[dimension][declared] / ratio
    best = min(UNITS[dimension].items(), key=lambda kv: abs(math.log(kv[1] / f_true)))
    return best[0] if abs(math.log(best[1] / f_true)) < math.log(1.12) and best[0] != declared else None


def _unit_error(raw: Raw, q: str, dimension: str, declared: str, ratio: float, against: str, m: int,
                stat: str = "median") -> InputError:
    where = raw.signals[q].origin
    unit = _probable_unit(dimension, declared, ratio)
    if unit is not None:
        hint = f"it looks like {unit}, not {declared}: set [units] {q} = \"{unit}\" in the map"
    elif ratio < 0 and abs(abs(ratio) - 1.0) < 0.2:
        hint = f"its sign is flipped: set [signs] {q} = -1 in the map"
    else:
        hint = f"check its unit and sign (declared {declared})"
    return InputError(
        f"{raw.source}: {where} disagrees with {against} by a factor {ratio:.3g} "
        f"({stat} over {m} windows); {hint}"
    )


def _window(valid: np.ndarray, k: int) -> np.ndarray:
    """Start indices ``i`` whose window ``[i, i + k]`` holds only valid samples."""
    bad = np.concatenate([[0], np.cumsum(~valid)])
    i = np.arange(len(valid) - k)
    return i[(bad[i + k + 1] - bad[i]) == 0]


def _wmean(v: np.ndarray, i: np.ndarray, k: int) -> np.ndarray:
    """Trapezoidal mean of ``v`` over the windows ``[i, i + k]``."""
    c = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))])
    return (c[i + k] - c[i]) / k


def _velocity_turns_with_path(gs: GlobalState, vals: dict, i: np.ndarray, k: int, d_path: np.ndarray,
                              turn: np.ndarray) -> bool:
    """Whether the heading of the velocity, ``yaw + atan2(v_y, v_x)``, turns with the path (median
    ratio 0.8..1.25 over the turning windows ``turn``), when the body velocities are columns.

    The yaw alone turns with the path only while the body slip holds still: in a slide or a spin
    (a lost lap's last seconds) the car rotates and the path does not, and on a short log those
    windows can be most of the turning ones (measured: a 6 s lap that fishtailed into a spin at
    Norisring gave 2.62). The velocity's heading follows the path in any motion, so a yaw whose
    sum with the recorded slip does is in its unit; a yaw in degrees (57 times) or of the other
    sign is not rescued. The heading is averaged over the two chords' windows as the chords average
    the path's (a fishtail of 1.2 s period through points would read 1.35). Only with measured ``v_x`` and ``v_y``: velocities derived from the
    positions or from a course turn with the path whatever the yaw's unit."""
    if not ("v_x" in vals and "v_y" in vals):
        return False
    head = np.unwrap(gs.yaw + np.arctan2(gs.v_y, gs.v_x))
    d_vel = _wmean(head, i + k, k) - _wmean(head, i, k)  # means over the chords' windows, as the chords
    ratio = float(np.median(d_vel[turn] / d_path[turn]))
    return bool(0.8 < ratio < 1.25)


def check_units(raw: Raw, gs: GlobalState, vals: dict, dt: float, window: float = 0.5) -> None:
    """Cross-check channels against the positions with robust statistics (module docstring).

    Everything is compared over windows of ``window`` seconds (so position noise does not
    dominate the differences): chord speed of the positions vs the mean measured speed, change of
    the chord heading vs the change of yaw, change of yaw vs the integral of the yaw rate, change
    of v_x vs the integral of a_x. A ratio is the median over the windows where the car moves
    (and turns, or accelerates); a ratio near -1 is named as a flipped sign.
    """
    k = max(1, int(round(window / dt)))
    i = _window(gs.valid, 2 * k)
    if len(i) < 20:
        return
    units = raw.units
    T = k * dt
    chord_v = np.hypot(gs.x[i + k] - gs.x[i], gs.y[i + k] - gs.y[i]) / T
    moving = (chord_v > 2.0) | (_wmean(np.hypot(gs.v_x, gs.v_y), i, k) > 2.0)  # either says it moves
    moving &= chord_v > 1e-3 * np.median(chord_v[moving]) if moving.any() else moving
    if moving.sum() < 20:
        return
    i, chord_v = i[moving], chord_v[moving]
    # 1. speed columns vs the speed from successive positions
    for q in ("v_x", "speed", "v_east"):
        if q in vals:
            meas = _wmean(np.hypot(gs.v_x, gs.v_y), i, k)
            ratio = float(np.median(meas / chord_v))
            t_unit = units.get("t", "s")
            for unit, f in UNITS["time"].items():  # every speed off by 1000^k: the clock's unit
                if unit != t_unit and abs(math.log(ratio * f / UNITS["time"][t_unit])) < math.log(1.12):
                    raise InputError(
                        f"{raw.source}: {raw.signals[q].origin} disagrees with the speed from successive "
                        f"positions by a factor {ratio:.3g}: the time stamps look like {unit}, not {t_unit}: "
                        f"set [units] t = \"{unit}\" in the map"
                    )
            if not (1 / 1.2 < ratio < 1.2):
                raise _unit_error(raw, q, "speed", units[q], ratio, "the speed from successive positions", len(i))
            break
    # 2. heading change vs the change of the chord heading (a yaw in degrees turns 57 times too fast)
    i2 = i  # windows of 2k valid samples
    if "yaw" in vals:
        h_a = np.arctan2(gs.y[i2 + k] - gs.y[i2], gs.x[i2 + k] - gs.x[i2])
        h_b = np.arctan2(gs.y[i2 + 2 * k] - gs.y[i2 + k], gs.x[i2 + 2 * k] - gs.x[i2 + k])
        d_path = wrap(h_b - h_a)
        d_yaw = gs.yaw[i2 + k + k // 2] - gs.yaw[i2 + k // 2]
        turn = np.abs(d_path) > 0.05 * T
        if turn.sum() >= 20:
            ratio = float(np.median(d_yaw[turn] / d_path[turn]))
            if not (0.6 < ratio < 1.6) and not _velocity_turns_with_path(gs, vals, i2, k, d_path, turn):
                raise _unit_error(raw, "yaw", "angle", units["yaw"], ratio, "the heading change of the path", int(turn.sum()))
    # 3. yaw rate vs the change of yaw
    if "yaw_rate" in vals:
        d_yaw = gs.yaw[i + k] - gs.yaw[i]
        turn = np.abs(d_yaw) > 0.05 * T
        if turn.sum() >= 20:
            ratio = float(np.median(_wmean(gs.yaw_rate, i, k)[turn] * T / d_yaw[turn]))
            if not (0.7 < ratio < 1.4):
                raise _unit_error(raw, "yaw_rate", "rate", units["yaw_rate"], ratio, "the heading change", int(turn.sum()))
    # 4. a_x vs the change of speed: least-squares slope over windows with clear acceleration
    if "a_x" in vals:
        dv = (gs.v_x[i + k] - gs.v_x[i]) / T
        a = _wmean(gs.a_x, i, k)
        acc = np.abs(a) > 0.5
        if acc.sum() >= 20:
            ratio = float(np.sum(a[acc] ** 2) / np.sum(a[acc] * dv[acc]))  # measured / expected
            if _probable_unit("accel", units["a_x"], ratio) is not None and not (0.4 < ratio < 2.5):
                raise _unit_error(raw, "a_x", "accel", units["a_x"], ratio, "the change of speed", int(acc.sum()),
                                  "least squares")
    # 5. steering: a road-wheel angle above ~70 deg is an angle in degrees or a steering-wheel angle
    q = "delta" if "delta" in vals else "steering_wheel"
    p99 = float(np.percentile(np.abs(gs.delta[gs.valid]), 99)) if gs.valid.any() else 0.0
    if p99 > 1.2:
        what = raw.signals[q].origin
        probable = "deg" if units[q] == "rad" else "a steering-wheel angle"
        raise InputError(
            f"{raw.source}: {what} reaches {p99:.3g} rad (99th percentile), no road-wheel angle does; "
            f"it looks like {probable}: set [units] {q} = \"deg\" or give it as steering_wheel with a steering_ratio"
        )


# ----------------------------------------------------------------------------------------------
# projection


def project(gs: GlobalState, track, source: str, origin_at_start: bool = False) -> dict[str, np.ndarray]:
    """Frenet coordinates of the valid grid rows on ``track``; laps from the continued ``s``.

    ``origin_at_start`` (path-derived reference lines): ``s`` and the laps count from the first
    sample's projection, so the recording starts at ``s = 0``, lap 0.
    """
    m = gs.valid
    x, y = gs.x[m], gs.y[m]
    s, e_y = track.to_frenet(x, y)
    L = track.length
    speed = np.hypot(gs.v_x[m], gs.v_y[m])
    if track.closed and len(s) > 1:
        # continue s through time; a jump that the speed cannot explain is a wrong branch
        ds = track._ds(s[1:], s[:-1])
        dt_rows = np.diff(gs.t[m])
        expect = 0.5 * (speed[1:] + speed[:-1]) * dt_rows
        tol = min(5.0, 0.02 * L)  # a step off by more than this is a jump (scales with the track)
        excursion = branch_excursions(ds, expect, tol)
        if excursion.any():
            ds = np.where(excursion, expect, ds)
            s_hint = track.wrap(s[0] + np.concatenate([[0.0], np.cumsum(ds)]))
            s, e_y = track.to_frenet(x, y, s_hint=s_hint, window=max(4.0 * tol, 0.05 * L))
            ds = track._ds(s[1:], s[:-1])
        s_cont = s[0] + np.concatenate([[0.0], np.cumsum(ds)])
        s_track = track.wrap(s_cont)
        if origin_at_start:  # the lowest s before the car has gone 2 % of a lap: a standing start's jitter stays in lap 0
            away = np.flatnonzero(s_cont - s_cont[0] > 0.02 * L)
            s_cont = s_cont - float(np.min(s_cont[: (away[0] if len(away) else len(s_cont)) + 1]))
        s_cont = s_cont - L * np.floor((s_cont[0] + 1e-3) / L)  # lap 0 at the start, even on the line
        lap = np.floor((s_cont + 1e-3) / L)  # within 1 mm before the line is on it
        s = np.maximum(s_cont - lap * L, 0.0)
    else:
        lap = np.zeros(len(s))
        s_track = s
    wl, wr = track.width_left(s_track), track.width_right(s_track)
    outside = np.maximum(e_y - wl, -e_y - wr)
    if np.all(outside > 0.5):
        i = int(np.argmin(outside))
        raise InputError(
            f"{source}: the recording never comes within track {track.name!r}: its closest point is "
            f"{abs(e_y[i]):.1f} m from the centre line ({outside[i]:.1f} m outside the border, at s = {s[i]:.0f} m); "
            "wrong track, or positions in another frame (lat/lon, offset origin)?"
        )
    e_psi = wrap(gs.yaw[m] - track.heading(s_track))
    return {"s": s, "e_y": e_y, "e_psi": e_psi, "kappa": track.kappa(s_track), "lap": lap}


def branch_excursions(ds: np.ndarray, expect: np.ndarray, tol: float) -> np.ndarray:
    """Steps of the projected ``s`` that jump to another branch of the line and back.

    A step is a jump when it differs from the distance driven by more than ``max(tol, 50 %)``.
    Two successive jumps that cancel (within the same tolerance) bound an *excursion*: the
    nearest point sat on another part of the line (a crossing, an adjacent straight) and came
    back; both steps are marked. A jump that is not undone is kept: the nearest point skipped
    ahead (inside a hairpin tighter than the car's offset), and ``s`` really is further on.
    Loops over the jumps only (a handful), never over samples.
    """
    d = ds - expect
    jumps = np.flatnonzero(np.abs(d) > np.maximum(tol, 0.5 * expect))
    out = np.zeros(len(ds), dtype=bool)
    k = 0
    while k < len(jumps) - 1:
        a, b = jumps[k], jumps[k + 1]
        if abs(d[a] + d[b]) < max(tol, 0.5 * (expect[a] + expect[b])):
            out[a] = out[b] = True
            k += 2
        else:
            k += 1
    return out


def segments(t: np.ndarray, dt: float) -> np.ndarray:
    """Contiguous-piece counter: increments where the time step exceeds 1.5 dt."""
    return np.concatenate([[0], np.cumsum(np.diff(t) > 1.5 * dt)]).astype(float)
