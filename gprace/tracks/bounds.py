"""A track from its two boundary polylines (as IAC and F1TENTH stacks keep them).

Input: two files of points ``x, y`` (a third column, ``z``, is ignored), with or without a header
(:mod:`gprace.io.table`). The files may run in opposite directions, start at different
points and have different point counts; their names say nothing (IAC's "inner" file is the
outer loop). Steps, all vectorised:

1. **Resample** each polyline at uniform arc length (spacing ``h``: the finer median point
   spacing, at most a quarter of the track's width). A polyline is *closed* when its ends are
   closer than twice the track's width (the width ``w0`` is the median distance from one boundary
   to the other).
2. **Same direction, aligned start**: the second boundary is reversed when its points run
   backwards along the first (median step of their nearest-point phase on the first), and a
   closed one is rolled to start nearest the first's start.
3. **Crossings**: the boundaries may not cross where they face each other; where segments of the
   two intersect at nearly the same position along the track (phase within 5 %) the files are
   refused (wrong pair, or a pair of one side). Crossings between far-apart parts of the lap (a
   bridge, as at Suzuka) are allowed.
4. **Centre line**: points at equal phase on both boundaries are averaged, then moved to the
   point equidistant from both boundaries by the fixed-point iteration ``c <- (P_A(c) + P_B(c)) / 2``
   (``P`` the nearest point on a boundary; 4 iterations). Points whose step runs backwards (a fold
   inside a hairpin) are dropped. Widths are the distances from the centre line to each
   boundary; the travel direction is the first file's, left and right follow from it.
5. The :class:`~gprace.tracks.Track` is built with the loaders' automatic smoothing
   (:func:`gprace.tracks.smoothing.smoothed_track`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gprace.errors import InputError
from gprace.tracks.smoothing import smoothed_track


def read_polyline(path: str | Path) -> np.ndarray:
    """``(n, 2)`` points of a boundary file: columns ``x, y`` by name (any case, ``x_m``...) or
    the first two columns; consecutive repeated points dropped."""
    from gprace.io.table import numbers, sniff

    path = Path(path)
    tbl = sniff(path, "boundary file")
    names = [n.lower() for n in tbl.names]
    cols = []
    for axis in ("x", "y"):
        hit = [j for j, n in enumerate(names) if n in (axis, f"{axis}_m", f"{axis}(m)", f"{axis} [m]", f"{axis}[m]")]
        cols.append(hit[0] if hit else None)
    if None in cols:
        if tbl.has_header and len(names) > 3:
            raise InputError(f"{path}: no columns x and y in the header ({', '.join(tbl.names)})")
        cols = [0, 1]
    if len(tbl.names) < 2:
        raise InputError(f"{path}: one column; a boundary needs x and y")
    xy = numbers(tbl, [tbl.names[j] for j in cols])
    bad = ~np.all(np.isfinite(xy), axis=1)
    if bad.any():
        from gprace.errors import at_row

        r = int(np.argmax(bad))
        raise InputError(f"{path}: {at_row(r + 1, int(tbl.body_lines[r]))}: x or y is not a finite number")
    keep = np.concatenate([[True], np.hypot(*np.diff(xy, axis=0).T) > 1e-9 * max(np.ptp(xy), 1e-12)])
    xy = xy[keep]
    if len(xy) < 4:
        raise InputError(f"{path}: only {len(xy)} distinct points; a boundary needs at least 4")
    return xy


def _arc(p: np.ndarray, closed: bool) -> np.ndarray:
    q = np.vstack([p, p[:1]]) if closed else p
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(q, axis=0).T))])


def _resample(p: np.ndarray, closed: bool, h: float) -> np.ndarray:
    """Points every ``h`` metres of arc length (linear between the input points)."""
    q = np.vstack([p, p[:1]]) if closed else p
    s = _arc(p, closed)
    n = max(int(np.ceil(s[-1] / h)), 8)
    su = np.linspace(0.0, s[-1], n + (0 if closed else 1), endpoint=not closed)
    return np.column_stack([np.interp(su, s, q[:, 0]), np.interp(su, s, q[:, 1])])


class _Nearest:
    """Nearest point on a polyline (vertices every ``h``), vectorised; also its phase in [0, 1]."""

    def __init__(self, p: np.ndarray, closed: bool):
        from scipy.spatial import cKDTree

        self.p, self.closed = p, closed
        self.q = np.vstack([p, p[:1]]) if closed else p
        self.s = _arc(p, closed)
        self.tree = cKDTree(p)

    def __call__(self, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest points ``(m, 2)`` and their arc lengths ``(m,)``."""
        _, i = self.tree.query(c)
        n = len(self.p)
        best_pt, best_s, best_d = None, None, None
        for j0 in (i - 1, i):  # the two segments at the nearest vertex
            if self.closed:
                a = np.mod(j0, n)
                b = a + 1
            else:
                a = np.clip(j0, 0, n - 2)
                b = a + 1
            pa, pb = self.q[a], self.q[b]
            d = pb - pa
            u = np.clip(np.sum((c - pa) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0.0, 1.0)
            pt = pa + u[:, None] * d
            dist = np.hypot(*(pt - c).T)
            sv = self.s[a] + u * (self.s[b] - self.s[a])
            if best_pt is None:
                best_pt, best_s, best_d = pt, sv, dist
            else:
                take = dist < best_d
                best_pt = np.where(take[:, None], pt, best_pt)
                best_s = np.where(take, sv, best_s)
                best_d = np.where(take, dist, best_d)
        return best_pt, best_s


def _crossings(a: np.ndarray, b: np.ndarray, closed: bool, h: float):
    """Index pairs ``(i, j)`` of intersecting segments of polylines ``a`` and ``b``."""
    from scipy.spatial import cKDTree

    qa = np.vstack([a, a[:1]]) if closed else a
    qb = np.vstack([b, b[:1]]) if closed else b
    ma, mb = 0.5 * (qa[1:] + qa[:-1]), 0.5 * (qb[1:] + qb[:-1])
    la = np.hypot(*np.diff(qa, axis=0).T).max()
    lb = np.hypot(*np.diff(qb, axis=0).T).max()
    k = min(8, len(mb))
    dist, j = cKDTree(mb).query(ma, k=k, distance_upper_bound=0.5 * (la + lb) + 1e-9)
    i = np.repeat(np.arange(len(ma)), k)
    j = j.ravel()
    ok = np.isfinite(dist.ravel())
    i, j = i[ok], j[ok]
    p1, p2, p3, p4 = qa[i], qa[i + 1], qb[j], qb[j + 1]

    def orient(p, q, r):
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

    hit = (orient(p1, p2, p3) * orient(p1, p2, p4) <= 0) & (orient(p3, p4, p1) * orient(p3, p4, p2) <= 0)
    return i[hit], j[hit]


def centre_from_bounds(a: np.ndarray, b: np.ndarray, *, where: str = "boundaries"):
    """Centre line and widths from boundary polylines ``a`` (sets the direction) and ``b``.

    Returns ``x, y, width_left, width_right, closed`` (module docstring). Raises
    :class:`InputError` when the boundaries cross where they face each other.
    """
    from scipy.spatial import cKDTree

    a = np.asarray(a, dtype=float)[:, :2]
    b = np.asarray(b, dtype=float)[:, :2]
    w0 = float(np.median(cKDTree(b).query(a)[0]))  # the track's width, roughly
    if not w0 > 0:
        raise InputError(f"{where}: the two boundaries coincide")
    gaps = [float(np.hypot(*(p[-1] - p[0]))) for p in (a, b)]
    lengths = [float(_arc(p, False)[-1]) for p in (a, b)]
    closed = all(g < max(2.0 * w0, 3.0 * float(np.median(np.hypot(*np.diff(p, axis=0).T)))) for g, p in zip(gaps, (a, b)))
    closed &= min(lengths) > 6.0 * w0
    h = min(float(np.median(np.hypot(*np.diff(p, axis=0).T))) for p in (a, b))
    h = max(min(h, 0.25 * w0), max(lengths) / 50_000)
    A, B = _resample(a, closed, h), _resample(b, closed, h)
    near_a = _Nearest(A, closed)
    # 2. direction and start of B along A
    _, sb = near_a(B)
    La = near_a.s[-1]
    step = np.diff(sb)
    if closed:
        step = (step + 0.5 * La) % La - 0.5 * La
    if np.median(step) < 0:
        B = B[::-1].copy()
    if closed:
        B = np.roll(B, -int(np.argmin(np.hypot(*(B - A[0]).T))), axis=0)
    near_b = _Nearest(B, closed)
    _refuse_facing_crossings(A, B, near_a, near_b, closed, h, where)
    c = _centre_line(A, B, near_a, near_b, closed, h)
    pa, _ = near_a(c)
    pb, _ = near_b(c)
    # which side is A: the sign of the tangent x (A - c)
    q = np.vstack([c[-1:], c, c[:1]]) if closed else np.vstack([c[:1], c, c[-1:]])
    tang = q[2:] - q[:-2]
    side_a = np.sign(tang[:, 0] * (pa - c)[:, 1] - tang[:, 1] * (pa - c)[:, 0])
    da, db = np.hypot(*(pa - c).T), np.hypot(*(pb - c).T)
    if np.median(side_a) > 0:  # A on the left
        wl, wr = da, db
    else:
        wl, wr = db, da
    floor = 0.02 * w0
    return c[:, 0], c[:, 1], np.maximum(wl, floor), np.maximum(wr, floor), bool(closed)


def _refuse_facing_crossings(A, B, near_a, near_b, closed: bool, h: float, where: str) -> None:
    """Raise when the resampled boundaries cross where they face each other (at about the same
    share of the lap); crossings of parts far apart along the lap are left to the track's checks."""
    La = near_a.s[-1]
    i, j = _crossings(A, B, closed, h)
    if len(i):
        ua = near_a.s[i] / La
        ub = near_b.s[j] / near_b.s[-1]
        du = np.abs(ua - ub)
        if closed:
            du = np.minimum(du, 1.0 - du)
        facing = du < 0.05
        if facing.any():
            k = int(np.argmax(facing))
            x, y = 0.5 * (A[i[k]] + A[(i[k] + 1) % len(A)])
            raise InputError(
                f"{where}: the boundary files cross each other near ({x:.1f}, {y:.1f}) "
                f"(at {100 * ua[k]:.0f} % of the lap); they must bound one track, left and right")


def _centre_line(A, B, near_a, near_b, closed: bool, h: float) -> np.ndarray:
    """Centre points: the boundaries paired at equal phase, moved to be equidistant from both,
    with folds (steps against the direction of travel) and near-duplicates dropped."""
    n = max(len(A), len(B))
    u = np.linspace(0.0, 1.0, n, endpoint=not closed)
    qa, qb = (np.vstack([P, P[:1]]) if closed else P for P in (A, B))
    sa, sb_ = _arc(A, closed), _arc(B, closed)
    ca = np.column_stack([np.interp(u * sa[-1], sa, qa[:, k]) for k in range(2)])
    cb = np.column_stack([np.interp(u * sb_[-1], sb_, qb[:, k]) for k in range(2)])
    c = 0.5 * (ca + cb)
    for _ in range(4):
        pa, _ = near_a(c)
        pb, _ = near_b(c)
        c = 0.5 * (pa + pb)
    # drop folds (a step against the direction of travel) and near-duplicates
    for _ in range(3):
        q = np.vstack([c, c[:1]]) if closed else c
        d = np.diff(q, axis=0)
        ref = np.roll(ca, -1, axis=0) - ca if closed else np.diff(ca, axis=0)
        fwd = np.sum(d * ref[: len(d)], axis=1) > 0
        big = np.hypot(*d.T) > 0.05 * h
        keep = np.concatenate([[True], (fwd & big)[:-1]]) if closed else np.concatenate([[True], fwd & big])
        if keep.all():
            break
        c, ca = c[keep], ca[keep]
    return c


def track_from_bounds(path_a: str | Path, path_b: str | Path, *, smoothing: float | None = None, name: str | None = None):
    """A :class:`~gprace.tracks.Track` from two boundary files (module docstring)."""
    path_a, path_b = Path(path_a), Path(path_b)
    where = f"{path_a},{path_b}"
    a, b = read_polyline(path_a), read_polyline(path_b)
    x, y, wl, wr, closed = centre_from_bounds(a, b, where=where)
    return smoothed_track(x, y, wl, wr, closed=closed, name=name or f"{path_a.stem}+{path_b.stem}",
                          source=where, smoothing=smoothing)
