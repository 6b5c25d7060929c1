"""The :class:`Track`: a centre line parametrised by arc length, with widths and curvature.

Geometry pipeline (done once, in the constructor)
-------------------------------------------------
1. The input points are checked (finite, at least 4, no repeated consecutive point, positive
   widths). For a closed track a last point that repeats the first is dropped.
2. An interpolating cubic spline (periodic for closed tracks) through the points, parametrised by
   chord length, gives a first smooth curve; it is resampled at uniform *arc length* (spacing
   ``spacing``, by default half the median input spacing).
3. Optional smoothing (``smoothing = l`` metres, 0 disables it): a third-order Whittaker-Henderson
   smoother on the uniform samples, i.e. ``argmin |z - x|^2 + (l/h)^6 |D^3 z|^2``. Its gain on a
   wave of wavenumber ``w`` [rad/m] is ``1 / (1 + (w l)^6)``: the kinks of OpenStreetMap-derived
   centre lines (curvature spikes at polyline vertices about 5 m apart) are removed, while a
   corner of radius ``R >> l`` keeps its radius (a Gaussian filter of the same cut-off would shrink
   it by ``exp(-l^2 / 2R^2)``). Closed tracks are smoothed as a periodic signal (FFT), open ones
   with a banded solve. Smoothing moves the *reference line*, not the track: the widths take up
   the normal component of the displacement, so the borders stay where the data put them (to
   first order; ``self.smoothing_shift`` is the largest displacement, up to 0.9 m on the TUM
   circuits with ``l = 5 m``).
4. The final spline (``scipy.interpolate.CubicSpline``, ``bc_type='periodic'`` when closed) is
   fitted through these samples and re-parametrised three times by its own arc length (Gauss-
   Legendre quadrature), so the spline parameter *is* the arc length ``s``: exactly at the
   knots, within 0.5 mm between them on the TUM circuits (much less on segment tracks). Curvature comes from the spline's first and second derivatives, so it is continuous.

Widths are linear interpolants over ``s`` (periodic when closed) of the input widths, corrected
for the smoothing displacement.

Conventions (docs/architecture.md): ``e_y`` positive to the LEFT of the centre line; widths are
positive distances; ``kappa > 0`` is a left turn; all methods are vectorised over arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.interpolate import CubicSpline, PPoly

from gprace.errors import InputError

_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)


@dataclass(frozen=True)
class TrackSamples:
    """A track sampled at (nearly) uniform arc length, for planners and plots.

    ``heading`` is unwrapped (continuous along ``s``); every array has shape ``(n,)``.
    For a closed track the samples cover ``[0, L)``; for an open one ``[0, L]``.
    """

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    kappa: np.ndarray
    wl: np.ndarray
    wr: np.ndarray

    def __iter__(self):
        return iter((self.s, self.x, self.y, self.heading, self.kappa, self.wl, self.wr))


class Track:
    """A race track: centre line ``r(s)``, widths, curvature, Frenet <-> global conversion.

    Parameters
    ----------
    x, y : (n,) centre-line points in order of travel [m].
    width_left, width_right : (n,) positive distances from the centre line to the left and right
        borders [m].
    closed : whether the centre line is a loop (the last point connects to the first).
    name : a label.
    smoothing : Whittaker smoothing length ``l`` [m] (module docstring); 0 keeps the curve through
        the points (use for exact geometry such as segment tracks).
    spacing : uniform arc-length spacing of the spline knots [m]; default half the median input
        spacing.
    source : where the points came from (used in error messages).
    """

    def __init__(
        self,
        x,
        y,
        width_left,
        width_right,
        *,
        closed: bool,
        name: str = "track",
        smoothing: float = 0.0,
        spacing: float | None = None,
        source: str | None = None,
    ) -> None:
        where = source or name
        x, y, wl, wr = (np.asarray(a, dtype=float).ravel() for a in (x, y, width_left, width_right))
        _check_points(x, y, wl, wr, closed, where)
        if closed and np.hypot(x[-1] - x[0], y[-1] - y[0]) <= 1e-9 * _scale(x, y):
            x, y, wl, wr = x[:-1], y[:-1], wl[:-1], wr[:-1]
            _check_points(x, y, wl, wr, closed, where)
        if smoothing < 0 or not np.isfinite(smoothing):
            raise InputError(f"{where}: smoothing must be a finite length >= 0, got {smoothing}")

        self.name = str(name)
        self.closed = bool(closed)
        self.is_reversed = False  # set by reversed(): driven against the file's direction
        self.source = source
        self.smoothing = float(smoothing)

        # 1. first interpolant through the raw points, chord-length parametrised
        pts = np.column_stack([x, y])
        chords = np.hypot(*np.diff(np.vstack([pts, pts[:1]]) if closed else pts, axis=0).T)
        t = np.concatenate([[0.0], np.cumsum(chords)])
        first = _fit(t, pts, closed)
        s_raw = _arc_at_knots(first, t)  # arc length of every raw point along the first curve
        length0 = s_raw[-1]

        # 2. uniform arc-length resampling
        h = float(spacing) if spacing is not None else 0.5 * float(np.median(chords))
        if not (np.isfinite(h) and h > 0):
            raise InputError(f"{where}: spacing must be positive, got {spacing}")
        n = max(int(np.ceil(length0 / h)), 16)
        su = np.linspace(0.0, length0, n + 1)
        if closed:
            su = su[:-1]
        tu = _invert_arc(first, t, su)
        uni = first(tu)

        # 3. smoothing
        raw_uni = uni
        if self.smoothing > 0:
            lam = (self.smoothing / (length0 / n)) ** 6
            uni = _whittaker3(uni, lam, closed)
        self.smoothing_shift = float(np.max(np.hypot(*(uni - raw_uni).T)))

        # 4. final spline, re-parametrised by its own arc length
        self._spl, u = _arc_length_spline(uni, closed)
        self._d1 = self._spl.derivative(1)
        self._d2 = self._spl.derivative(2)
        self._d12 = _stacked(self._d1, self._d2)
        self._knots = u
        self.length = float(u[-1])
        self._h = self.length / (len(u) - 1)

        self._ws, self._wl, self._wr = _border_widths(self._d1, u, raw_uni, uni, s_raw * (self.length / length0),
                                                      wl, wr, closed, self.smoothing, where)
        self.n_points = len(x)

    # ------------------------------------------------------------------------------------------
    # basic geometry

    def wrap(self, s):
        """``s`` into ``[0, L)`` for a closed track; unchanged for an open one."""
        s = np.asarray(s, dtype=float)
        return np.mod(s, self.length) if self.closed else s

    def _clip(self, s):
        s = np.asarray(s, dtype=float)
        return np.mod(s, self.length) if self.closed else np.clip(s, 0.0, self.length)

    def position(self, s):
        """Centre-line point ``(x, y)`` at ``s`` (open tracks: clamped to the ends)."""
        p = self._spl(self._clip(s))
        return p[..., 0], p[..., 1]

    def kappa(self, s):
        """Curvature [1/m] at ``s``; positive for a left turn."""
        d = self._d12(self._clip(s))  # x', y', x'', y'' in one evaluation (the rollouts' hot path)
        num = d[..., 0] * d[..., 3] - d[..., 1] * d[..., 2]
        return num / np.hypot(d[..., 0], d[..., 1]) ** 3

    def heading(self, s):
        """Direction of travel of the centre line [rad], in ``(-pi, pi]``."""
        d1 = self._d1(self._clip(s))
        return np.arctan2(d1[..., 1], d1[..., 0])

    @cached_property
    def _width_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Width nodes ``s (m,)`` and ``[w_left, w_right] (2, m)``; closed tracks wrap once around
        (``np.interp``'s ``period`` sorts the nodes on every call, and the MPC asks every period)."""
        w = np.vstack([self._wl, self._wr])
        if not self.closed:
            return self._ws, w
        s = np.concatenate([self._ws[-1:] - self.length, self._ws, self._ws[:1] + self.length])
        return s, np.hstack([w[:, -1:], w, w[:, :1]])

    def _interp_width(self, s, side: int):
        ws, w = self._width_table
        return np.interp(self._clip(s), ws, w[side])

    def width_left(self, s):
        """Distance from the centre line to the left border [m] at ``s``."""
        return self._interp_width(s, 0)

    def width_right(self, s):
        """Distance from the centre line to the right border [m] at ``s``."""
        return self._interp_width(s, 1)

    # ------------------------------------------------------------------------------------------
    # Frenet <-> global

    def _frame(self, s):
        """Point, unit tangent, unit left normal at ``s`` (after clipping), each ``(..., 2)``."""
        sc = self._clip(s)
        p, d1 = self._spl(sc), self._d1(sc)
        t = d1 / np.hypot(d1[..., 0], d1[..., 1])[..., None]
        nrm = np.stack([-t[..., 1], t[..., 0]], axis=-1)
        return sc, p, t, nrm

    def to_global(self, s, e_y):
        """Global ``(x, y)`` of the point at arc length ``s`` and lateral offset ``e_y`` (left +).

        On an open track an ``s`` beyond an end continues along the end tangent.
        """
        s = np.asarray(s, dtype=float)
        e_y = np.asarray(e_y, dtype=float)
        s, e_y = np.broadcast_arrays(s, e_y)
        sc, p, t, nrm = self._frame(s)
        along = (s - sc) if not self.closed else 0.0
        q = p + np.asarray(along)[..., None] * t + e_y[..., None] * nrm
        return q[..., 0], q[..., 1]

    def to_frenet(self, x, y, s_hint=None, window: float | None = None):
        """Project global points to ``(s, e_y)``, following the path order.

        Without ``s_hint`` the nearest point of the whole centre line is taken. With ``s_hint``
        (same shape as ``x``, e.g. the previous step's ``s``) only centre-line points within
        ``window`` metres of arc length of the hint are candidates (default ``0.1 L``), so a
        self-crossing centre line (Suzuka) resolves to the branch being driven. The coarse
        answer is refined by safeguarded Newton steps on the spline. On an open track a point
        beyond an end gets ``s < 0`` or ``s > L`` along the end tangent.
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        x, y = np.broadcast_arrays(x, y)
        shape = x.shape
        p = np.column_stack([x.ravel(), y.ravel()])
        n = len(p)
        if n == 0:
            return np.zeros(shape), np.zeros(shape)
        if not np.all(np.isfinite(p)):
            raise InputError("to_frenet: x and y must be finite")
        knots_s = self._knot_s
        k = min(8 if s_hint is not None else 2, len(knots_s))
        _, idx = self._tree.query(p, k=k)
        idx = idx.reshape(n, k)
        cand = knots_s[idx]  # (n, k), nearest first
        valid = np.ones((n, k), dtype=bool)
        if s_hint is not None:
            hint = np.broadcast_to(np.asarray(s_hint, dtype=float), shape).ravel()
            w = 0.1 * self.length if window is None else float(window)
            valid = np.abs(self._ds(cand, hint[:, None])) <= w
            lost = ~valid.any(axis=1)
            if lost.any():  # none of the nearest knots is inside the window: search the window
                cand[lost, 0] = self._window_search(p[lost], hint[lost], w)
                valid[lost, 0] = True
            # keep the two nearest admissible knots
            order = np.argsort(~valid, axis=1, kind="stable")[:, :2]
            rows = np.arange(n)[:, None]
            cand, valid = cand[rows, order], valid[rows, order]
            k = 2
        s_ref = self._newton(np.repeat(p, k, axis=0), cand.ravel()).reshape(n, k)
        q, _, _ = self._eval(s_ref)
        d2 = np.sum((q - p[:, None, :]) ** 2, axis=-1)
        d2 = np.where(valid, d2, np.inf)
        best = np.argmin(d2, axis=1)
        s = s_ref[np.arange(n), best]
        sc, q, t, nrm = self._frame(s)
        rel = p - q
        e_y = np.sum(rel * nrm, axis=-1)
        if not self.closed:  # beyond an end: continue along the end tangent
            along = np.sum(rel * t, axis=-1)
            at_end = ((sc <= 0.0) & (along < 0)) | ((sc >= self.length) & (along > 0))
            s = np.where(at_end, sc + along, sc)
        return s.reshape(shape), e_y.reshape(shape)

    def _ds(self, a, b):
        """Signed arc-length difference ``a - b`` (shortest way round when closed)."""
        d = a - b
        if self.closed:
            d = (d + 0.5 * self.length) % self.length - 0.5 * self.length
        return d

    def _window_search(self, p, hint, w):
        """Nearest knot within ``|s - hint| <= w`` for each point (chunked brute force)."""
        m = max(int(np.ceil(w / self._h)), 1)
        offs = np.arange(-m, m + 1) * self._h
        out = np.empty(len(p))
        chunk = max(1, 200_000 // len(offs))
        for i in range(0, len(p), chunk):
            ss = hint[i : i + chunk, None] + offs[None, :]
            if not self.closed:
                ss = np.clip(ss, 0.0, self.length)
            xy = self._spl(self._clip(ss))
            d2 = np.sum((xy - p[i : i + chunk, None, :]) ** 2, axis=-1)
            out[i : i + chunk] = ss[np.arange(len(ss)), np.argmin(d2, axis=1)]
        return out

    def _newton(self, p, s, iters: int = 8):
        """Minimise ``|r(s) - p|^2`` over ``s`` from the start values, vectorised."""
        s = self._clip(s).copy()
        for _ in range(iters):
            sc = self._clip(s)
            r, d1, d2 = self._eval(sc)
            diff = r - p
            g = np.sum(diff * d1, axis=-1)
            sp2 = np.sum(d1 * d1, axis=-1)
            hess = sp2 + np.sum(diff * d2, axis=-1)
            hess = np.where(hess > 0.1 * sp2, hess, sp2)  # beyond the centre of curvature: gradient step
            step = np.clip(-g / hess, -self._h, self._h)
            s = self._clip(sc + step)
            if np.max(np.abs(step)) < 1e-12 * max(self.length, 1.0):
                break
        return s

    def _eval(self, sc):
        """``r, r', r''`` at clipped ``sc`` (one interval search, Horner on the coefficients)."""
        c, xk = self._spl.c, self._spl.x
        i = np.clip(np.searchsorted(xk, sc, side="right") - 1, 0, len(xk) - 2)
        dx = (sc - xk[i])[..., None]
        c0, c1, c2, c3 = c[0][i], c[1][i], c[2][i], c[3][i]
        r = ((c0 * dx + c1) * dx + c2) * dx + c3
        d1 = (3.0 * c0 * dx + 2.0 * c1) * dx + c2
        d2 = 6.0 * c0 * dx + 2.0 * c1
        return r, d1, d2

    @cached_property
    def _knot_s(self):
        return self._knots[:-1] if self.closed else self._knots

    @cached_property
    def _tree(self):
        from scipy.spatial import cKDTree

        return cKDTree(self._spl(self._knot_s))

    # ------------------------------------------------------------------------------------------
    # tables for planners

    def sample(self, ds: float) -> TrackSamples:
        """Sample at spacing close to ``ds`` (exactly ``L / n``); heading unwrapped."""
        if not (np.isfinite(ds) and ds > 0):
            raise InputError(f"sample: ds must be positive, got {ds}")
        n = max(int(round(self.length / ds)), 2)
        s = np.linspace(0.0, self.length, n + 1)
        if self.closed:
            s = s[:-1]
        xy = self._spl(s)
        return TrackSamples(
            s=s,
            x=xy[:, 0],
            y=xy[:, 1],
            heading=np.unwrap(self.heading(s)),
            kappa=self.kappa(s),
            wl=self.width_left(s),
            wr=self.width_right(s),
        )

    def kappa_table(self, ds: float | None = None):
        """``(s, kappa)`` on a uniform grid covering ``[0, L]`` including both ends.

        Default spacing: the spline's knot spacing. For a closed track the last value equals
        the first, so a lookup with ``wrap(s)`` is periodic.
        """
        step = self._h if ds is None else float(ds)
        if not (np.isfinite(step) and step > 0):
            raise InputError(f"kappa_table: ds must be positive, got {ds}")
        n = max(int(np.ceil(self.length / step)), 2)
        s = np.linspace(0.0, self.length, n + 1)
        k = self.kappa(s)
        if self.closed:
            k[-1] = k[0]
        return s, k

    def casadi_kappa(self, ds: float | None = None, method: str = "bspline"):
        """``casadi.interpolant`` of ``kappa`` over ``s in [0, L]`` (``'bspline'`` or ``'linear'``).

        Periodicity is the caller's business: evaluate at ``wrap(s)`` (e.g. ``fmod``).
        """
        import casadi

        if method not in ("bspline", "linear"):
            raise InputError(f"casadi_kappa: method must be 'bspline' or 'linear', got {method!r}")
        s, k = self.kappa_table(ds)
        return casadi.interpolant("kappa", method, [s.tolist()], k.tolist())

    # ------------------------------------------------------------------------------------------
    # summaries

    @cached_property
    def _dense(self):
        return self.sample(min(self._h, self.length / 200) / 2)

    @property
    def max_abs_kappa(self) -> float:
        return float(np.max(np.abs(self._dense.kappa)))

    @property
    def min_radius(self) -> float:
        """``1 / max |kappa|`` [m] (inf for a straight)."""
        k = self.max_abs_kappa
        return float(np.inf) if k == 0 else 1.0 / k

    @property
    def width_range(self) -> tuple[float, float]:
        """Smallest and largest total width ``wl + wr`` over the input points [m]."""
        tot = self._wl + self._wr
        return float(tot.min()), float(tot.max())

    def borders(self, ds: float | None = None):
        """``(x_left, y_left), (x_right, y_right)`` border polylines."""
        smp = self._dense if ds is None else self.sample(ds)
        left = self.to_global(smp.s, smp.wl)
        right = self.to_global(smp.s, -smp.wr)
        return left, right

    def summary(self) -> dict:
        lo, hi = self.width_range
        return {
            "name": self.name,
            "closed": self.closed,
            "length_m": self.length,
            "min_radius_m": self.min_radius,
            "width_min_m": lo,
            "width_max_m": hi,
            "n_points": self.n_points,
            "smoothing_m": self.smoothing,
        }

    def reversed(self) -> "Track":
        """The same track driven the other way: ``s' = L - s`` (closed: the start stays where it
        is), left and right swapped, curvature negated. Rebuilt through the knots without further
        smoothing, so the geometry is the same spline to rounding."""
        s = self._knots[:-1] if self.closed else self._knots
        xy = self._spl(s)
        wl, wr = self.width_left(s), self.width_right(s)
        order = np.r_[0, np.arange(len(s) - 1, 0, -1)] if self.closed else np.arange(len(s) - 1, -1, -1)
        out = Track(xy[order, 0], xy[order, 1], wr[order], wl[order], closed=self.closed, name=self.name,
                    smoothing=0.0, spacing=self._h, source=self.source)
        # the widths on this track's own nodes (not only at the knots), mirrored
        ws = (self.length - self._ws) * (out.length / self.length)
        if self.closed:
            ws = np.mod(ws, out.length)
        order = np.argsort(ws, kind="stable")
        ws, keep = np.unique(ws[order], return_index=True)
        out._ws, out._wl, out._wr = ws, self._wr[order][keep], self._wl[order][keep]
        out.smoothing_shift = self.smoothing_shift
        out.smoothing = self.smoothing
        out.n_points = self.n_points
        out.is_reversed = not self.is_reversed
        return out

    def __repr__(self) -> str:
        kind = "closed" if self.closed else "open"
        return f"Track({self.name!r}, {kind}, L={self.length:.2f} m)"


# ----------------------------------------------------------------------------------------------
# helpers


def _scale(x, y) -> float:
    return float(max(np.ptp(x), np.ptp(y), 1e-12))


def _check_points(x, y, wl, wr, closed, where) -> None:
    n = len(x)
    if not (len(y) == len(wl) == len(wr) == n):
        raise InputError(f"{where}: x, y and widths must have the same length")
    if n < 4:
        raise InputError(f"{where}: a track needs at least 4 points, got {n}")
    for name, a in (("x", x), ("y", y), ("width_left", wl), ("width_right", wr)):
        bad = ~np.isfinite(a)
        if bad.any():
            raise InputError(f"{where}: point {int(np.argmax(bad))}: {name} is not finite")
    for name, a in (("width_left", wl), ("width_right", wr)):
        if np.any(a <= 0):
            raise InputError(f"{where}: point {int(np.argmax(a <= 0))}: {name} must be positive")
    d = np.hypot(np.diff(x), np.diff(y))
    tiny = 1e-9 * _scale(x, y)
    if np.any(d <= tiny):
        i = int(np.argmax(d <= tiny))
        raise InputError(f"{where}: points {i} and {i + 1} coincide (degenerate track)")


def _fit(t, pts, closed: bool) -> CubicSpline:
    """Cubic spline ``t -> (x, y)``; periodic when closed (``pts`` without the repeated end)."""
    if closed:
        return CubicSpline(t, np.vstack([pts, pts[:1]]), bc_type="periodic")
    return CubicSpline(t, pts, bc_type="not-a-knot")


def _stacked(d1: PPoly, d2: PPoly) -> PPoly:
    """One piecewise polynomial of the first and second derivatives (outputs x', y', x'', y''):
    the second's coefficients padded with a leading zero, which Horner's rule passes exactly, so
    its values equal the two separate evaluations to the bit."""
    c2 = np.concatenate([np.zeros((d1.c.shape[0] - d2.c.shape[0], *d2.c.shape[1:])), d2.c])
    return PPoly(np.concatenate([d1.c, c2], axis=-1), d1.x, extrapolate=d1.extrapolate)


def _arc_at_knots(spl: CubicSpline, t: np.ndarray) -> np.ndarray:
    """Arc length of the spline at every knot (5-point Gauss-Legendre per interval)."""
    a, b = t[:-1], t[1:]
    half = 0.5 * (b - a)
    tt = (0.5 * (a + b))[:, None] + half[:, None] * _GL_X[None, :]
    d = spl.derivative(1)(tt.ravel())
    speed = np.hypot(d[:, 0], d[:, 1]).reshape(tt.shape)
    seg = half * (speed @ _GL_W)
    return np.concatenate([[0.0], np.cumsum(seg)])


def _invert_arc(spl: CubicSpline, t: np.ndarray, s_query: np.ndarray) -> np.ndarray:
    """Parameter ``t`` at arc lengths ``s_query`` (a dense arc-length table, 16 per interval)."""
    tt = np.linspace(t[0], t[-1], (len(t) - 1) * 16 + 1)
    ss = _arc_at_knots(spl, tt)
    return np.interp(s_query, ss, tt)


def _whittaker3(z: np.ndarray, lam: float, closed: bool) -> np.ndarray:
    """Third-order Whittaker-Henderson smoother of the columns of ``z`` (shape ``(n, d)``).

    Solves ``(I + lam D3^T D3) z_s = z``: by FFT when periodic (the matrix is circulant), as a
    banded system otherwise.
    """
    n = len(z)
    if closed:
        k = np.arange(n)
        eig = (2.0 * np.sin(np.pi * k / n)) ** 6
        return np.real(np.fft.ifft(np.fft.fft(z, axis=0) / (1.0 + lam * eig)[:, None], axis=0))
    from scipy.linalg import solveh_banded
    from scipy.sparse import diags

    d3 = diags([-1.0, 3.0, -3.0, 1.0], [0, 1, 2, 3], shape=(n - 3, n))
    mat = (lam * (d3.T @ d3)).tocsr()
    ab = np.zeros((4, n))  # upper banded storage, bandwidth 3
    for off in range(4):
        ab[3 - off, off:] = mat.diagonal(off)
    ab[3] += 1.0
    return solveh_banded(ab, z)


def _arc_length_spline(uni: np.ndarray, closed: bool):
    """The spline through the resampled points, parametrised by its own arc length (three fixed-
    point passes): ``(spline, knots u)``."""
    nodes = np.vstack([uni, uni[:1]]) if closed else uni
    u = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(nodes, axis=0).T))])
    for _ in range(3):
        spl = _fit(u, uni, closed)
        u = _arc_at_knots(spl, u)
    return _fit(u, uni, closed), u


def _border_widths(d1_of, u: np.ndarray, raw_uni: np.ndarray, uni: np.ndarray, s_in: np.ndarray, wl: np.ndarray,
                   wr: np.ndarray, closed: bool, smoothing: float, where: str):
    """Nodes and left/right widths along the final line (``d1_of``: its first derivative, ``u``: its
    knots, ``s_in``: the input points' arc length on it); refuses a smoothing that moved the line
    outside a border."""
    length = float(u[-1])
    # widths: linear in s between the input points; smoothing moves the reference line, not
    # the borders, so the widths take up the normal component of the displacement (first
    # order in the displacement). Nodes: the input points and the spline knots.
    ws = u[:-1] if closed else u
    d1 = d1_of(ws)
    nrm = np.column_stack([-d1[:, 1], d1[:, 0]]) / np.hypot(d1[:, 0], d1[:, 1])[:, None]
    shift = np.sum((raw_uni - uni) * nrm, axis=1)
    if closed:
        nodes = np.union1d(ws, s_in[:-1])
        wln = np.interp(nodes, s_in[:-1], wl, period=length)
        wrn = np.interp(nodes, s_in[:-1], wr, period=length)
        sh = np.interp(nodes, ws, shift, period=length)
    else:
        nodes = np.union1d(ws, s_in)
        wln, wrn = np.interp(nodes, s_in, wl), np.interp(nodes, s_in, wr)
        sh = np.interp(nodes, ws, shift)
    wln, wrn = wln + sh, wrn - sh
    for side, w in (("left", wln), ("right", wrn)):
        if np.any(w <= 0):
            i = int(np.argmin(w))
            raise InputError(
                f"{where}: smoothing of {smoothing:g} m moves the centre line outside the "
                f"{side} border near s = {nodes[i]:.1f} m; use less smoothing"
            )
    return nodes, wln, wrn
