"""Racelines in the formats real racing stacks read, written from a plan and read back.

Two formats, both a closed loop in the track's global frame:

* ``tum``: the race trajectory of TUM's global_racetrajectory_optimization (its
  ``export_traj_race``): comment lines, then the header comment ``# s_m; x_m; y_m; psi_rad;
  kappa_radpm; vx_mps; ax_mps2`` and rows separated by ``"; "``.
* ``f1tenth``: the waypoint file of the INI F1TENTH stack (``IPZ20_wp.csv``): a plain header
  ``s_m,x_m,y_m,psi_rad,kappa_radpm,vx_mps,ax_mps2,d_right_iqp,d_left_iqp`` (the stack's reader
  asks for these names; ``d_right`` / ``d_left`` are read too) and comma-separated rows, no comments.

Conventions, the same in both (checked on TUM's writer and README and on the INI file):

* ``s_m``: arc length along the raceline from its first point [m];
* ``psi_rad``: heading of the raceline in ``[-pi, pi)`` with **zero pointing north** (along +y),
  counter-clockwise positive: ``psi = atan2(dy, dx) - pi/2``. (INI's reader adds ``pi/2`` back.)
* ``kappa_radpm``: curvature of the raceline, positive turning left;
* ``vx_mps``: target speed along the raceline; ``ax_mps2``: target acceleration, constant from a
  point to the next (``(v_{i+1}^2 - v_i^2) / (2 ds_i)``);
* ``d_right``, ``d_left``: distance from the point to the right and left border [m];
* closed loop: the last row repeats the first point with ``s_m`` = the loop length.

:func:`raceline_of_plan` turns a :class:`~gprace.plan.Plan` into a :class:`Raceline`;
:func:`gprace.plan.raceline.plan_of_raceline` turns a raceline back into a plan on a track.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gprace.errors import InputError

COMMON = ("s_m", "x_m", "y_m", "psi_rad", "kappa_radpm", "vx_mps", "ax_mps2")
FORMATS: dict[str, tuple[str, ...]] = {
    "tum": COMMON,
    "f1tenth": COMMON + ("d_right_iqp", "d_left_iqp"),
}
WIDTH_NAMES = {"d_right": ("d_right_iqp", "d_right"), "d_left": ("d_left_iqp", "d_left")}
SUFFIXES = {"tum": "raceline_tum.csv", "f1tenth": "raceline_f1tenth.csv"}


@dataclass(frozen=True, eq=False)
class Raceline:
    """A closed raceline: ``n`` distinct points in travel order (the closing row of a file is not
    repeated here) and the loop length ``length`` (from the last point back to the first).

    ``psi`` follows the files' convention (zero north); :attr:`heading` is the usual
    ``atan2(dy, dx)``. ``d_right`` / ``d_left`` are None for a format without widths.
    """

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    psi: np.ndarray
    kappa: np.ndarray
    vx: np.ndarray
    ax: np.ndarray
    length: float
    d_right: np.ndarray | None = None
    d_left: np.ndarray | None = None
    fmt: str = "tum"
    source: str = "<memory>"
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.s)

    @property
    def heading(self) -> np.ndarray:
        return wrap_angle(self.psi + 0.5 * np.pi)

    @property
    def lap_time(self) -> float:
        """Time of one loop at the target speeds (trapezoidal in ``1/v`` between the points)."""
        ds = np.diff(np.append(self.s, self.length))
        v = np.maximum(self.vx, 1e-6)
        return float(np.sum(ds * 0.5 * (1 / v + 1 / np.roll(v, -1))))


def wrap_angle(a):
    """Angles into ``[-pi, pi)``."""
    return (np.asarray(a, dtype=float) + np.pi) % (2 * np.pi) - np.pi


# ------------------------------------------------------------------------------------------------
# files


def write_raceline(path: str | Path, rl: Raceline, fmt: str, comments: tuple[str, ...] = ()) -> Path:
    """Write ``rl`` in format ``fmt`` (``tum`` or ``f1tenth``), atomically; ``comments`` go into
    the TUM file's comment lines (the F1TENTH file has none: its stack reads a plain header)."""
    from gprace.io.artifacts import write_text_atomic

    if fmt not in FORMATS:
        raise InputError(f"unknown raceline format {fmt!r}; available: {', '.join(FORMATS)}")
    cols = [np.append(a, a[:1]) for a in (rl.x, rl.y, rl.psi, rl.kappa, rl.vx, rl.ax)]
    table = [np.append(rl.s, rl.length), *cols]
    if fmt == "f1tenth":
        if rl.d_right is None or rl.d_left is None:
            raise InputError("f1tenth raceline: the distances to the borders are unknown (plan the raceline on a track)")
        table += [np.append(rl.d_right, rl.d_right[:1]), np.append(rl.d_left, rl.d_left[:1])]
    data = np.column_stack(table)
    if fmt == "tum":
        head = "".join(f"# {c}\n" for c in comments) + "# " + "; ".join(FORMATS["tum"]) + "\n"
        body = "\n".join("; ".join(f"{v:.7f}" for v in row) for row in data)
    else:
        head = ",".join(FORMATS["f1tenth"]) + "\n"
        body = "\n".join(",".join(f"{v:.6f}" for v in row) for row in data)
    return write_text_atomic(path, head + body + "\n")


def raceline_format(names) -> str | None:
    """``tum`` / ``f1tenth`` when the column names are those of a raceline, None when they are not
    a raceline at all (a track, a recording); InputError when they look like one but do not match."""
    names = [str(c).strip() for c in names]
    have = set(names)
    if not {"s_m", "x_m", "y_m"} <= have or not have & {"psi_rad", "kappa_radpm", "vx_mps", "ax_mps2"}:
        return None
    widths = {k: next((c for c in alts if c in have), None) for k, alts in WIDTH_NAMES.items()}
    fmt = "f1tenth" if any(widths.values()) else "tum"
    want = list(COMMON) + ([widths["d_right"] or "d_right_iqp", widths["d_left"] or "d_left_iqp"] if fmt == "f1tenth" else [])
    missing = [c for c in want if c not in have]
    extra = [c for c in names if c not in want]
    if missing or extra:
        detail = "; ".join(p for p in (f"missing {', '.join(missing)}" if missing else "",
                                       f"unexpected {', '.join(extra)}" if extra else "") if p)
        raise InputError(f"columns do not match the {fmt} raceline format ({detail}); expected "
                         + ("; ".join(FORMATS["tum"]) if fmt == "tum" else ",".join(FORMATS["f1tenth"])))
    return fmt


def is_raceline(path: str | Path) -> bool:
    """Whether ``path`` is a raceline file (by its header; cheap)."""
    from gprace.io.table import peek_names

    try:
        return raceline_format(peek_names(path)) is not None
    except InputError:
        return True  # a raceline with wrong columns: read_raceline says what is wrong


def read_raceline(path: str | Path) -> Raceline:
    """A raceline file of either format (recognised by its columns, in any order; separators,
    comments and BOM as :mod:`gprace.io.table` reads them). One-line InputError when the
    columns do not match a format, a value is not finite, the speeds are not positive or the
    points do not form a loop."""
    from gprace.io.table import numbers, sniff

    path = Path(path)
    tbl = sniff(path, "raceline")
    if not tbl.has_header:
        raise InputError(f"{path}: no header; a raceline names its columns ({'; '.join(FORMATS['tum'])})")
    try:
        fmt = raceline_format(tbl.names)
    except InputError as exc:
        raise InputError(f"{path}: line {tbl.header_line}: {exc}") from None
    if fmt is None:
        raise InputError(f"{path}: not a raceline (columns {', '.join(tbl.names)}); expected "
                         f"{'; '.join(FORMATS['tum'])} (TUM) or {','.join(FORMATS['f1tenth'])} (F1TENTH)")
    names = [c.strip() for c in tbl.names]
    tbl.names = names
    want = list(COMMON)
    if fmt == "f1tenth":
        want += [next(c for c in WIDTH_NAMES[k] if c in names) for k in ("d_right", "d_left")]
    a = numbers(tbl, want)
    lines = tbl.body_lines
    bad = ~np.isfinite(a)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(f"{path}: column {want[c]!r} row {r + 1} (line {int(lines[r])}): not a finite number")
    if len(a) < 4:
        raise InputError(f"{path}: {len(a)} rows; a raceline needs at least 4 points")
    if np.any(a[:, 5] <= 0):
        r = int(np.argmax(a[:, 5] <= 0))
        raise InputError(f"{path}: column 'vx_mps' row {r + 1} (line {int(lines[r])}): speed {a[r, 5]:g} m/s; a raceline's speeds are positive")
    if np.any(np.diff(a[:, 0]) <= 0):
        r = int(np.argmax(np.diff(a[:, 0]) <= 0)) + 1
        raise InputError(f"{path}: column 's_m' row {r + 1} (line {int(lines[r])}): s does not increase")
    x, y = a[:, 1], a[:, 2]
    extent = max(float(np.ptp(x)), float(np.ptp(y)), 1e-9)
    step = np.hypot(np.diff(x), np.diff(y))
    closing = float(np.hypot(x[-1] - x[0], y[-1] - y[0]))
    if closing <= 1e-6 * extent:  # the closing row repeats the first point
        length = float(a[-1, 0])
        a = a[:-1]
    else:
        if closing > 5 * float(np.median(step)) + 1e-9:
            raise InputError(f"{path}: the raceline does not close: its last point is {closing:.3g} m from its first "
                             f"(points {float(np.median(step)):.3g} m apart); a raceline is a closed loop")
        length = float(a[-1, 0] + closing)
    if not length > a[-1, 0]:
        raise InputError(f"{path}: column 's_m': the loop length {length:g} m is not beyond the last point's s")
    d_right = d_left = None
    if fmt == "f1tenth":
        d_right, d_left = a[:, 7], a[:, 8]
        if np.any(d_right <= 0) or np.any(d_left <= 0):
            r = int(np.argmax((d_right <= 0) | (d_left <= 0)))
            raise InputError(f"{path}: row {r + 1} (line {int(lines[r])}): distances to the borders must be positive")
    return Raceline(s=a[:, 0] - a[0, 0], x=a[:, 1], y=a[:, 2], psi=a[:, 3], kappa=a[:, 4], vx=a[:, 5], ax=a[:, 6],
                    length=length - a[0, 0], d_right=d_right, d_left=d_left, fmt=fmt, source=str(path))


# ------------------------------------------------------------------------------------------------
# plan -> raceline


def raceline_spacing(length: float) -> float:
    """Point spacing of a written raceline: 1 m on a circuit, at most 1/250 of a small loop (0.1 m
    on a 25 m F1TENTH track, as IPZ20_wp.csv)."""
    return float(min(1.0, length / 250.0))


def raceline_of_plan(plan, track, spacing: float | None = None) -> Raceline:
    """The plan's path in the global frame at uniform arc length along the path.

    The path is the periodic cubic spline through the plan's nodes ``to_global(s_k, e_y_k)``
    (over the centre-line arc length); heading and curvature are the path's own (what the two
    formats mean by them); the speed is the speed over ground ``hypot(v_x, v_y)`` interpolated
    along the lap; ``ax`` is constant between points. The distances to the borders are measured
    along the track's normal at the point's centre-line position.
    """
    from scipy.interpolate import CubicSpline

    plan.check_track(track, "raceline")
    L = float(track.length)
    s = np.append(plan.s, L)
    X, Y = track.to_global(plan.s, plan.e_y)
    spl = CubicSpline(s, np.column_stack([np.append(X, X[0]), np.append(Y, Y[0])]), bc_type="periodic")
    # dense samples over the centre line's s, then uniform in the path's own arc length
    u = np.linspace(0.0, L, 20 * max(len(plan.s), 100) + 1)
    P = spl(u)
    sp = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(P, axis=0).T))])
    Lp = float(sp[-1])
    h = raceline_spacing(Lp) if spacing is None else float(spacing)
    m = max(int(round(Lp / h)), 8)
    s_out = np.linspace(0.0, Lp, m + 1)[:-1]
    u_out = np.interp(s_out, sp, u)
    p, d1 = spl(u_out), spl(u_out, 1)
    heading = np.arctan2(d1[:, 1], d1[:, 0])
    # curvature from the plan's own heading of travel (centre-line heading + heading error +
    # sideslip: smooth states of the plan) differentiated along the path; the spline's second
    # derivative wiggles between the nodes (1/260 m on a straight of Norisring at 6 m nodes)
    hc = np.unwrap(np.append(track.heading(plan.s), track.heading(plan.s[:1])))
    turn = hc[-1] - hc[0]  # +-2 pi: the heading's turn round the loop
    th = hc[:-1] + plan.e_psi + np.arctan2(plan.v_y, plan.v_x)
    spn = np.interp(plan.s, u, sp)  # path arc length of the nodes
    nxt_th, prv_th = np.roll(th, -1), np.roll(th, 1)
    nxt_th[-1] += turn
    prv_th[0] -= turn
    nxt_s, prv_s = np.roll(spn, -1), np.roll(spn, 1)
    nxt_s[-1] += Lp
    prv_s[0] -= Lp
    k_nodes = (nxt_th - prv_th) / (nxt_s - prv_s)
    k_nodes = np.append(k_nodes, k_nodes[0])
    kappa = np.interp(u_out, s, k_nodes)
    speed = np.hypot(plan.v_x, plan.v_y)
    v = np.interp(u_out, s, np.append(speed, speed[0]))
    e = np.interp(u_out, s, np.append(plan.e_y, plan.e_y[0]))
    ds = np.diff(np.append(s_out, Lp))
    ax = (np.roll(v, -1) ** 2 - v**2) / (2 * ds)
    return Raceline(s=s_out, x=p[:, 0], y=p[:, 1], psi=wrap_angle(heading - 0.5 * np.pi), kappa=kappa, vx=v, ax=ax,
                    length=Lp, d_right=track.width_right(u_out) + e, d_left=track.width_left(u_out) - e,
                    source=f"plan of {plan.track}", meta={"lap_time": float(plan.lap_time)})


# ------------------------------------------------------------------------------------------------
# raceline -> track position, plan


@dataclass(frozen=True, eq=False)
class OnTrack:
    """A raceline projected on a track: the track in the raceline's direction (reversed when the
    raceline runs against the file's direction), and per point the centre-line arc length
    ``s`` (unwrapped, increasing, starting in ``[0, L)``) and lateral offset ``e``."""

    track: object
    s: np.ndarray
    e: np.ndarray
    reversed: bool

    def margins(self, half_width: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Distance left (m,) of each point to the left and right border, minus ``half_width``."""
        sw = self.track.wrap(self.s)
        return self.track.width_left(sw) - self.e - half_width, self.track.width_right(sw) + self.e - half_width


def project_raceline(rl: Raceline, track) -> OnTrack:
    """Project the raceline's points on ``track`` following the loop (InputError when the
    raceline does not lie along this track: it goes round another loop, or back and forth)."""
    if not track.closed:
        raise InputError(f"raceline {rl.source}: track {track.name!r} is open; a raceline is a closed loop")
    s, e = track.to_frenet(rl.x, rl.y)
    ds = track._ds(np.roll(s, -1), s)
    rev = bool(np.median(ds) < 0)
    if rev:
        track = track.reversed()
        s, e = track.to_frenet(rl.x, rl.y)
        ds = track._ds(np.roll(s, -1), s)
    step = np.diff(np.append(rl.s, rl.length))
    # a point whose nearest centre-line point jumps (inside a hairpin tighter than the offset):
    # projected again within a window around where the path's own arc length puts it
    expect = step * (track.length / rl.length)
    jump = np.abs(ds - expect) > np.maximum(0.5 * expect, 0.02 * track.length)
    if jump.any():
        hint = s[0] + np.concatenate([[0.0], np.cumsum(expect)[:-1]])
        s, e = track.to_frenet(rl.x, rl.y, s_hint=track.wrap(hint), window=0.05 * track.length)
        ds = track._ds(np.roll(s, -1), s)
    total = float(np.sum(ds))
    if abs(total - track.length) > 0.05 * track.length or np.mean(ds <= 0) > 0.02:
        raise InputError(f"raceline {rl.source}: it does not go once round track {track.name!r} "
                         f"({total:.4g} m of the track's {track.length:.4g} m covered, "
                         f"{100 * np.mean(ds <= 0):.0f} % of the steps backwards): a raceline of another track?")
    s_un = s[0] + np.concatenate([[0.0], np.cumsum(np.maximum(ds[:-1], 0.0))])
    return OnTrack(track=track, s=s_un, e=e, reversed=rev)


def raceline_track(rl: Raceline, name: str | None = None):
    """The track an F1TENTH waypoint file describes: the raceline as reference line with its
    distances to the borders as widths (InputError for a format without widths)."""
    from gprace.tracks.track import Track

    if rl.d_left is None or rl.d_right is None:
        raise InputError(f"{rl.source}: a {rl.fmt} raceline has no distances to the borders, so no track; "
                         "give the track it was planned on (--track)")
    return Track(rl.x, rl.y, rl.d_left, rl.d_right, closed=True, name=name or Path(rl.source).stem, smoothing=0.0,
                 source=rl.source)


def raceline_summary(rl: Raceline, track=None, half_width: float = 0.0) -> dict:
    """What ``gprace track show RACELINE`` prints: format, length, lap time, speeds, curvature;
    with a track, where the line lies on it (offsets and the smallest margin to a border)."""
    out = {
        "format": rl.fmt, "points": rl.n, "length_m": rl.length, "lap_time_s": rl.lap_time,
        "speed_min_mps": float(rl.vx.min()), "speed_max_mps": float(rl.vx.max()),
        "ax_min_mps2": float(rl.ax.min()), "ax_max_mps2": float(rl.ax.max()),
        "min_radius_m": float(1.0 / max(np.max(np.abs(rl.kappa)), 1e-12)),
    }
    if rl.d_left is not None:
        out["margin_min_m"] = float(min(rl.d_left.min(), rl.d_right.min()))
    if track is not None:
        on = project_raceline(rl, track)
        ml, mr = on.margins(half_width)
        out.update({"track": track.name, "track_length_m": track.length, "against_track_direction": on.reversed,
                    "e_y_min_m": float(on.e.min()), "e_y_max_m": float(on.e.max()),
                    "margin_min_m": float(min(ml.min(), mr.min())), "inside": bool(min(ml.min(), mr.min()) >= 0)})
    return out
