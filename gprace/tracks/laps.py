"""Laps from the data: when a recording has no track and no lap column.

Two pure, vectorised entry points (docs/decisions.md, "Real logs as they come", issue 36):

* :func:`path_laps` ``(x, y) -> PathLaps | None``: the laps of a driven path in the plane, from
  the closure of the path. The lap length is the shift of driven distance ``tau`` that brings the
  path back onto itself (the minimum of the median closure ``C(tau) = median_d |p(d + tau) -
  p(d)|``, the smallest of its near-equal minima, so two laps are not taken for one); one closed
  reference line is built from all the laps (each lap's points binned by their position along a
  first single-lap line, averaged, smoothed, closed). Robust to a standing start (standstill adds
  no distance), pit or slow laps (medians; samples far off the laps do not enter the average),
  noise (averaging over laps, then smoothing) and a partial last lap. ``None`` when the path does
  not close (an open stage, or it overlaps itself by less than 1.5 % of its length).
* :func:`wrap_frenet` ``(s, kappa, e_y=None, v=None) -> (s_wrapped, lap, lap_length) | None``:
  a Frenet recording whose ``s`` runs on over several laps. The lap length is the period of
  ``kappa`` along ``s`` (normalised autocorrelation on a uniform ``s`` grid, refined by least
  squares between ``kappa(s)`` and ``kappa(s + L)``); ``e_y`` and ``v``, when given, check it (a
  track with two equal halves has a kappa period of half a lap; the driver's line and speed
  rarely repeat at half a lap). ``None`` when ``s`` is not running on or no period is found.

The importer (:mod:`gprace.ingest.importer`) uses :func:`path_laps` for recordings without a
track; diagnose calls :func:`wrap_frenet` on Frenet recordings without a lap column.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprace.tracks.track import Track

MIN_LAPS = 1.02
"""A path must run on for this many laps (driven distance) before its laps are recognised; the
overlap must also hold 1.5 % of the path (:func:`_closure`)."""


FRENET_MIN_LAPS = 1.2
"""``s`` must run on for this many periods before a kappa period is believed: at least a fifth
of a lap of overlap (over a shorter overlap, straights correlate by chance)."""


@dataclass(frozen=True)
class PathLaps:
    """Laps recognised in a driven path (:func:`path_laps`).

    ``lap_length``: length of the reference line [m] (the driven distance per lap is longer
    with position noise, which adds to every step); ``x, y``: the closed reference line
    (averaged laps, smoothed; its point 0 nearest the first moving sample); ``smoothing``: the
    Whittaker length given to it [m]; ``spread``: the 95th percentile of the laps' distance from
    the line [m]; ``closure``: the median closure distance at one lap [m]; ``laps``: completed
    laps in the recording (start-line crossings after the first moving sample).
    """

    lap_length: float
    x: np.ndarray
    y: np.ndarray
    smoothing: float
    spread: float
    closure: float
    laps: int

    def track(self, *, name: str = "path", source: str | None = None, half_width: float | None = None):
        """The reference line as a closed :class:`~gprace.tracks.Track` (already smoothed; the
        half width defaults to twice the laps' spread, at least 3 % of... see the docstring of
        :func:`reference_half_width`)."""
        w = reference_half_width(self) if half_width is None else float(half_width)
        ww = np.full(len(self.x), w)
        return Track(self.x, self.y, ww, ww, closed=True, name=name, smoothing=0.0, source=source or name)


def reference_half_width(laps: PathLaps) -> float:
    """Half width of a path-derived line: twice the spread of the laps around it, at least 1 %
    of a lap (only border checks use it: a path is not a track)."""
    return float(max(2.0 * laps.spread, 0.01 * laps.lap_length))


# ----------------------------------------------------------------------------------------------
# the driven path


def driven_distance(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Cumulative distance along the path, steps of a standing car not counted (a step below 5 %
    of the 90th-percentile step is jitter)."""
    step = np.hypot(np.diff(x), np.diff(y))
    if len(step) == 0:
        return np.zeros(len(x))
    scale = float(np.percentile(step, 90))
    step = np.where(step > 0.05 * scale, step, 0.0)
    return np.concatenate([[0.0], np.cumsum(step)])


def _uniform(d: np.ndarray, x: np.ndarray, y: np.ndarray, h: float):
    """Points every ``h`` metres of driven distance, and for each its sample position (float)."""
    keep = np.concatenate([[True], np.diff(d) > 0])
    dk, xk, yk, ik = d[keep], x[keep], y[keep], np.flatnonzero(keep).astype(float)
    du = np.arange(0.0, dk[-1], h)
    return np.column_stack([np.interp(du, dk, xk), np.interp(du, dk, yk)]), np.interp(du, dk, ik)


def _closure(P: np.ndarray, lags: np.ndarray, max_pairs: int = 3000) -> np.ndarray:
    """``median_k |P[k + m] - P[k]|`` for every lag ``m`` (pairs subsampled to ``max_pairs``)."""
    out = np.full(len(lags), np.inf)
    n = len(P)
    for j, m in enumerate(lags):  # a loop over candidate lags, each vectorised over the pairs
        if n - m < max(8, 0.015 * n):
            continue
        k = np.arange(0, n - m, max(1, (n - m) // max_pairs))
        out[j] = np.median(np.hypot(*(P[k + m] - P[k]).T))
    return out


def lap_period(P: np.ndarray, h: float, min_lag: int) -> tuple[int, float] | None:
    """Lap length (in points of ``P``, spaced ``h``) from the closure, and the closure there."""
    n = len(P)
    max_lag = int(n / MIN_LAPS)
    if max_lag <= min_lag + 4:
        return None
    step = max(1, (max_lag - min_lag) // 800)
    lags = np.arange(min_lag, max_lag + 1, step)
    c = _closure(P, lags, max_pairs=1500)
    best = float(np.min(c))
    extent = float(np.hypot(*np.ptp(P, axis=0)))
    if not best < 0.1 * extent:
        return None
    # the smallest lag whose closure is a deep local minimum: within 1.5x (+ h) of the best, or
    # below a quarter of the median closure (laps of unequal length drift apart, so the minima
    # at 2, 3 ... laps are shallower; a lag near the end of the recording has few pairs and may
    # look better than it is)
    deep = (c <= 1.5 * best + h) | (c <= 0.25 * float(np.median(c)))
    cand = np.flatnonzero(deep & (c <= np.minimum(np.roll(c, 1), np.roll(c, -1))))
    if len(cand) == 0:
        cand = np.array([int(np.argmin(c))])
    j = int(cand[0])
    # refine at unit step around it
    lo, hi = max(min_lag, lags[j] - 2 * step), min(max_lag, lags[j] + 2 * step)
    fine = np.arange(lo, hi + 1, max(1, (hi - lo) // 40))
    cf = _closure(P, fine, max_pairs=4000)
    k = int(np.argmin(cf))
    return int(fine[k]), float(cf[k])


def path_laps(x, y, *, min_lap: float | None = None) -> PathLaps | None:
    """Laps of the driven path ``x, y`` (time order, metres) from its closure (module docstring).

    ``min_lap``: the shortest lap to consider [m]; default 1.2 times the diagonal of the path's
    bounding box (a closed lap is at least that long).
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if len(x) < 16:
        return None
    d = driven_distance(x, y)
    total = float(d[-1])
    extent = float(np.hypot(np.ptp(x), np.ptp(y)))
    if not (total > 0 and extent > 0):
        return None
    min_lap = 1.2 * extent if min_lap is None else float(min_lap)
    h = max(extent / 300.0, total / 50_000.0)
    P, src = _uniform(d, x, y, h)
    found = lap_period(P, h, max(4, int(min_lap / h)))
    if found is None:
        return None
    m, closure = found
    L = m * h
    # the best single lap: the window whose points close best, averaged over a tenth of a lap
    n = len(P)
    e = np.hypot(*(P[m:] - P[:-m]).T)
    w = max(1, m // 10)
    avg = np.convolve(e, np.ones(w) / w, mode="valid")
    k0 = int(np.argmin(avg)) + w // 2
    k0 = min(k0, n - m - 1)
    lap = P[k0 : k0 + m + 1]
    gap = lap[-1] - lap[0]
    lap = lap[:-1] - np.outer(np.arange(m) / m, gap)  # close it: the gap spread along the lap
    # average every lap on that line, then smooth
    moving = np.flatnonzero(np.diff(d) > 0)
    pts = np.column_stack([x, y])[np.union1d(moving, moving + 1)]
    ref, spread, l_smooth = _average_laps(pts, lap, L)
    # point 0 nearest the first moving sample
    i0 = int(moving[0]) if len(moving) else 0
    j0 = int(np.argmin(np.hypot(ref[:, 0] - x[i0], ref[:, 1] - y[i0])))
    ref = np.roll(ref, -j0, axis=0)
    laps = _count_laps(P, ref, L)
    length = float(np.sum(np.hypot(*np.diff(np.vstack([ref, ref[:1]]), axis=0).T)))
    return PathLaps(length, ref[:, 0].copy(), ref[:, 1].copy(), l_smooth, spread, closure, laps)


def _average_laps(pts: np.ndarray, lap: np.ndarray, L: float):
    """The closed line through the mean of every lap's points ``pts`` (the moving samples),
    binned by their nearest point on the seed ``lap``; its spread and the smoothing used. Points
    far off the laps (a pit lane) are left out of the mean."""
    from gprace.tracks.track import _whittaker3
    from scipy.spatial import cKDTree

    step = np.hypot(*np.diff(pts, axis=0).T)
    hs = max(float(np.median(step[step > 0])) if np.any(step > 0) else L / 1000.0, L / 5000.0)
    # the seed densified to a fifth of the sample spacing, so the bin of a point is its phase
    nd = max(len(lap), int(np.ceil(5.0 * L / hs)))
    q = np.vstack([lap, lap[:1]])
    sq = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(q, axis=0).T))])
    su = np.linspace(0.0, sq[-1], nd, endpoint=False)
    dense = np.column_stack([np.interp(su, sq, q[:, 0]), np.interp(su, sq, q[:, 1])])
    dist, j = cKDTree(dense).query(pts)
    mad = float(np.median(dist))
    near = dist <= max(6.0 * mad, 3.0 * hs)
    nb = max(32, int(round(L / hs)))
    # each lap's line at the bin centres (every lap counts once per bin, however many samples it
    # has there), then the mean over the laps; a bin a lap skips (a pit detour) gets nothing
    phi = j / nd
    step = np.diff(phi)
    step = (step + 0.5) % 1.0 - 0.5
    cont = np.concatenate([[0.0], np.cumsum(step)]) + phi[0]
    centres = (np.arange(nb) + 0.5) / nb
    sx, sy, cnt = np.zeros(nb), np.zeros(nb), np.zeros(nb)
    keep = np.flatnonzero(near)
    pc, px, py = cont[keep], pts[keep, 0], pts[keep, 1]
    for lap_no in range(int(np.floor(pc.min())), int(np.floor(pc.max())) + 1):  # a loop over laps
        sel = (pc >= lap_no - 1.0 / nb) & (pc < lap_no + 1.0 + 1.0 / nb)
        if sel.sum() < 2:
            continue
        order = np.argsort(pc[sel], kind="stable")  # noise may put a sample behind its predecessor
        u = pc[sel][order] - lap_no
        q = np.searchsorted(u, centres)
        inside = (q > 0) & (q < len(u))
        qc = np.clip(q, 1, len(u) - 1)
        ok = inside & (u[qc] - u[qc - 1] < 6.0 / nb)  # no sample for 6 bins: this lap was elsewhere
        sx[ok] += np.interp(centres[ok], u, px[sel][order])
        sy[ok] += np.interp(centres[ok], u, py[sel][order])
        cnt[ok] += 1
    seed_b = dense[np.clip((centres * nd).astype(int), 0, nd - 1)]
    ref = np.where((cnt > 0)[:, None], np.column_stack([sx, sy]) / np.maximum(cnt, 1)[:, None], seed_b)
    # smoothing: three bins (at least 0.1 % of a lap), at most 30 % of the tightest radius
    hb = L / nb
    l0 = max(3.0 * hb, 0.001 * L)
    rough = _whittaker3(ref, (l0 / hb) ** 6, True)
    r99 = 1.0 / max(float(np.percentile(np.abs(_curvature(rough, hb)), 99)), 1e-9)
    l_smooth = float(min(l0, 0.3 * r99))
    ref = _whittaker3(ref, (l_smooth / hb) ** 6, True)
    d2, _ = cKDTree(ref).query(pts[near])
    spread = float(np.percentile(d2, 95)) if len(d2) else 0.0
    step = np.hypot(*np.diff(np.vstack([ref, ref[:1]]), axis=0).T)
    ref = ref[step > 1e-6 * L]  # drop repeated points
    return ref, spread, l_smooth


def _curvature(p: np.ndarray, h: float) -> np.ndarray:
    d1 = (np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)) / (2 * h)
    d2 = (np.roll(p, -1, axis=0) - 2 * p + np.roll(p, 1, axis=0)) / h**2
    return (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.maximum(np.hypot(*d1.T) ** 3, 1e-12)


def _count_laps(P: np.ndarray, ref: np.ndarray, L: float) -> int:
    """Completed laps of the uniform path ``P`` on the closed line ``ref``: the continued
    nearest-point phase, unwrapped, from the first point."""
    from scipy.spatial import cKDTree

    _, j = cKDTree(ref).query(P)
    n = len(ref)
    step = np.diff(j)
    step = (step + n // 2) % n - n // 2  # shortest way round
    cont = np.concatenate([[0], np.cumsum(step)])
    return int(max(0, np.floor((cont[-1] + 0.02 * n) / n)))


# ----------------------------------------------------------------------------------------------
# Frenet recordings whose s runs on


def _autocorr(z: np.ndarray) -> np.ndarray:
    """Normalised autocorrelation of ``z`` at every lag (unbiased: divided by the overlap)."""
    n = len(z)
    z = z - z.mean()
    f = np.fft.rfft(z, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac /= np.arange(n, 0, -1)
    return ac / max(ac[0], 1e-300)


def _lag_corr(z: np.ndarray, m: int) -> float:
    a, b = z[:-m], z[m:]
    if len(a) < 8 or np.std(a) == 0 or np.std(b) == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def wrap_frenet(s, kappa, *, e_y=None, v=None, min_length: float | None = None,
                min_corr: float = 0.7) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Wrap an ``s`` that runs on over several laps: ``(s_wrapped, lap, lap_length)`` or None.

    ``s`` [m] and ``kappa`` [1/m] per sample (time order); ``e_y`` [m] and ``v`` [m/s]
    optional checks (module docstring). ``s_wrapped = s mod L`` (the track's origin stays the
    origin), ``lap`` counts from 0 at the first sample. None when ``s`` does not run on (it
    already wraps, or goes back by more than 1 % of its span) or when kappa has no period with a
    normalised autocorrelation of at least ``min_corr`` in ``[min_length, span / 1.2]``.
    """
    s = np.asarray(s, dtype=float)
    kappa = np.asarray(kappa, dtype=float)
    if len(s) < 32 or not (np.all(np.isfinite(s)) and np.all(np.isfinite(kappa))):
        return None
    span = float(s[-1] - s[0])
    if not span > 0:
        return None
    back = np.maximum.accumulate(s) - s
    if back.max() > 0.01 * span:  # s goes back: it already wraps, or is not a lap coordinate
        return None
    sm = np.maximum.accumulate(s)
    keep = np.concatenate([[True], np.diff(sm) > 0])
    sk = sm[keep]
    pos = np.diff(sk)
    h = max(float(np.median(pos)) if len(pos) else span, span / 200_000.0)
    grid = np.arange(sk[0], sk[-1], h)
    if len(grid) < 32:
        return None

    def on_grid(q):
        return np.interp(grid, sk, np.asarray(q, dtype=float)[keep])

    kg = on_grid(kappa)
    if not np.std(kg) > 1e-9 * (np.max(np.abs(kg)) + 1e-9):  # constant curvature (a circle): no lap in it
        return None
    ac = _autocorr(kg)
    lo = max(4, int(np.ceil((min_length if min_length is not None else 8.0 * h) / h)))
    hi = int(len(grid) / FRENET_MIN_LAPS)
    if hi <= lo + 2:
        return None
    seg = ac[lo : hi + 1]
    peaks = np.flatnonzero((seg >= np.roll(seg, 1)) & (seg >= np.roll(seg, -1)))
    peaks = peaks[(peaks > 0) & (peaks < len(seg) - 1)]
    if len(peaks) == 0:
        return None
    # the FFT gives the peaks; their height is the Pearson correlation over the overlap (a short
    # overlap of busy corners would otherwise look better than the whole lap)
    peaks = lo + peaks[np.argsort(seg[peaks])[::-1][:40]]
    r = np.array([_lag_corr(kg, int(mm)) for mm in peaks])
    ok = np.isfinite(r)
    if not ok.any():
        return None
    peaks, r = peaks[ok], r[ok]
    best = float(r.max())
    if best < min_corr:
        return None
    good = r >= best - 0.05 * (1.0 - min_corr) - 0.02
    m = int(peaks[good].min())
    # e_y / v check: a period of half a lap (a track of two equal halves) shows in the driving
    checks = [q for q in (e_y, v) if q is not None]
    if checks and 2 * m <= hi:
        half = np.nanmean([_lag_corr(on_grid(q), m) for q in checks])
        full = np.nanmean([_lag_corr(on_grid(q), 2 * m) for q in checks])
        if np.isfinite(full) and full > 0.5 and (not np.isfinite(half) or half < full - 0.3):
            m = 2 * m
    L = _refine_period(grid, kg, m * h, h)
    lap = np.floor(s / L) - np.floor(s[0] / L)
    return s - L * np.floor(s / L), lap, L

def _refine_period(grid: np.ndarray, kg: np.ndarray, L_peak: float, h: float) -> float:
    """The lap length near the autocorrelation's peak ``L_peak`` [m] (curvature ``kg`` on the
    uniform ``grid`` of spacing ``h``)."""
    # least squares of kappa(s) - kappa(s + L) over the overlap (zero at the period),
    # within 2 % of the peak, then to a tenth of the grid
    def mismatch(cands):
        out = []
        for Lc in cands:  # a loop over candidate lengths, each vectorised over the grid
            sel = grid <= grid[-1] - Lc
            out.append(np.mean((np.interp(grid[sel] + Lc, grid, kg) - kg[sel]) ** 2) if sel.sum() > 8 else np.inf)
        return np.asarray(out)

    coarse = L_peak * (1.0 + np.linspace(-0.02, 0.02, 81))
    L0 = float(coarse[int(np.argmin(mismatch(coarse)))])
    dl = max(coarse[1] - coarse[0], h)
    fine = L0 + np.linspace(-dl, dl, 41)
    return float(fine[int(np.argmin(mismatch(fine)))])
