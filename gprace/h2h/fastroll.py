"""The opponent rollout in one compiled call: features, GP mean and variance, the sampled steps.

:func:`gprace.h2h.predictors.sample_paths` in C for a GP with one kernel (the protocol's models;
:meth:`gprace.gp.base.GPBackend.kernel_form`) on a track with a spline centre line: per step the
features of every sample (:func:`~gprace.h2h.predictors.features`: the curvature from the centre
line's piecewise polynomial of derivatives, the gap in ``s`` wrapped on closed tracks), each
sample's mean (one fused kernel row and product, :mod:`gprace.gp.fastkernel`), the latent
variance at the samples' mean input (a forward substitution against the exact GP's Cholesky
factor or the sparse GP's quadratic form) and the update ``mean + sqrt(var) * eps``. The numpy
path stays the reference: the same values to rounding (checked in the tests), and the fallback
for other backends, GPs with one kernel per output and machines without a C compiler.

Why: in numpy a 50-sample, 9-step rollout makes about 1100 Python calls, which cost more than the
arithmetic (5.4 ms for the 600-point exact GP, 3.7 ms for the sparse baseline; issue 17 asks
for 3 ms).
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from gprace.gp.fastkernel import KERNEL_C, KernelForm, fast_flags

_ROLLOUT_C = r"""
/* numpy's floating remainder: the sign of the divisor */
static inline double pymod(double a, double b) {
    double r = fmod(a, b);
    if (r != 0.0) { if ((b < 0) != (r < 0)) r += b; } else r = copysign(0.0, b);
    return r;
}

/* Curvature at s from the piecewise polynomial of (x', y', x'', y''): breaks brk (nb + 1),
   coefficients coef (order, nb, 4), powers of (s - brk[i]) summed from the lowest. */
static double kappa(double s, int closed, double length, int nb, int order, const double *brk, const double *coef) {
    s = closed ? pymod(s, length) : (s < 0.0 ? 0.0 : (s > length ? length : s));
    int lo = 0, hi = nb;  /* the last break with brk[i] <= s, within [0, nb - 1] */
    while (hi - lo > 1) { int mid = (lo + hi) / 2; if (brk[mid] <= s) lo = mid; else hi = mid; }
    double t = s - brk[lo], z = 1.0, d[4] = {0, 0, 0, 0};
    for (int p = order - 1; p >= 0; p--) {
        const double *c = coef + ((long)p * nb + lo) * 4;
        for (int j = 0; j < 4; j++) d[j] += c[j] * z;
        z *= t;
    }
    double sp = hypot(d[0], d[1]);
    return (d[0] * d[3] - d[1] * d[2]) / (sp * sp * sp);
}

/* The 11 features of features() (predictors.py) from an ego state e and an opponent state o
   (both [v_x, v_y, yaw_rate, e_psi, e_y, s]). */
static void features(const double *e, const double *o, int closed, double length, int nb, int order,
                     const double *brk, const double *coef, const double *look, double *z) {
    double gap = o[5] - e[5];
    if (closed) gap = pymod(gap + 0.5 * length, length) - 0.5 * length;
    z[0] = e[4] - o[4]; z[1] = e[3]; z[2] = e[0]; z[3] = gap;
    z[4] = o[4]; z[5] = o[3]; z[6] = o[0]; z[7] = o[2];
    for (int j = 0; j < 3; j++) z[8 + j] = kappa(o[5] + look[j], closed, length, nb, order, brk, coef);
}

/* Latent variance at a kernel row k (M) in normalised units: sf2 - |L^-1 k|^2 (tri, L lower,
   row-major) or sf2 - k^T V k (quad); v: M doubles of scratch. */
static double variance(int M, const double *k, double sf2, int tri, const double *V, double *v) {
    double q = 0.0;
    if (tri) {
        for (int i = 0; i < M; i++) {
            const double *row = V + (long)i * M;
            double x = (k[i] - dot(i, row, v)) / row[i];
            v[i] = x; q += x * x;
        }
    } else {
        for (int i = 0; i < M; i++) q += k[i] * dot(M, V + (long)i * M, k);
    }
    double var = sf2 - q;
    return var > 0.0 ? var : 0.0;
}

/* Paths out (G n, K, 6) of n samples from each of G opponent states opp (G, 6), the ego at step
   k of start g in ego (K, G, 6), draws eps (K, G n, p); outputs p = 5 into state indices idx.
   GP: points aT (11, M) divided by the length scales, weights wT (p, M), the normalisation
   z_mean, z_div (11), y_mean, y_scale (p). work: (n (11 + p) + 2 M + 11 + 6 n) doubles. */
void rollout(int K, int G, int n, const double *ego, const double *opp, const double *eps,
             int closed, double length, int nb, int order, const double *brk, const double *coef, const double *look,
             int M, int p, const int *idx, const double *aT, const double *wT, double sf2, int matern,
             int tri, const double *V, const double *z_mean, const double *z_div, const double *y_mean,
             const double *y_scale, double *out, double *work) {
    const int d = 11;
    double *Zs = work, *mu = Zs + (long)n * d, *row = mu + (long)n * p, *v = row + M, *zbar = v + M, *S = zbar + d;
    double z[11], sd[8];
    for (int g = 0; g < G; g++) {
        for (int i = 0; i < n; i++) memcpy(S + 6 * i, opp + 6 * g, 6 * sizeof(double));
        for (int k = 0; k < K; k++) {
            const double *e = ego + ((long)k * G + g) * 6;
            const int m = k == 0 ? 1 : n;  /* at step 0 the samples share their state: one query */
            for (int j = 0; j < d; j++) zbar[j] = 0.0;
            for (int i = 0; i < m; i++) {
                features(e, S + 6 * i, closed, length, nb, order, brk, coef, look, z);
                double *b = Zs + (long)i * d;
                for (int j = 0; j < d; j++) { zbar[j] += z[j]; b[j] = (z[j] - z_mean[j]) / z_div[j]; }
                kernel_row(M, d, b, aT, sf2, matern, row);
                for (int c = 0; c < p; c++) mu[(long)i * p + c] = dot(M, row, wT + (long)c * M) * y_scale[c] + y_mean[c];
            }
            if (m > 1) {
                for (int j = 0; j < d; j++) z[j] = (zbar[j] / m - z_mean[j]) / z_div[j];
                kernel_row(M, d, z, aT, sf2, matern, row);
            }
            double sv = sqrt(variance(M, row, sf2, tri, V, v));
            for (int c = 0; c < p; c++) sd[c] = sv * fabs(y_scale[c]);
            for (int i = 0; i < n; i++) {
                const double *mi = mu + (long)(m > 1 ? i : 0) * p;
                const double *ei = eps + ((long)k * G * n + (long)g * n + i) * p;
                double *si = S + 6 * i;
                for (int c = 0; c < p; c++) si[idx[c]] += mi[c] + sd[c] * ei[c];
                memcpy(out + (((long)g * n + i) * K + k) * 6, si, 6 * sizeof(double));
            }
        }
    }
}
"""


def rollout(form: KernelForm | None, track, ego: np.ndarray, opp: np.ndarray, n: int, eps: np.ndarray,
            look: np.ndarray, idx: tuple[int, ...]) -> np.ndarray | None:
    """:func:`~gprace.h2h.predictors.sample_paths` compiled (same arguments, ``form`` for the GP,
    ``look`` the curvature look-ahead, ``idx`` the state index of each output), or None where
    it does not apply: no form, a track without the spline centre line, no C compiler."""
    if not applies(form, track):
        return None
    fn, poly = _library(), track._d12
    K, G = ego.shape[0], opp.shape[0]
    p, M = form.wT.shape
    ego = np.ascontiguousarray(ego, dtype=float)
    opp = np.ascontiguousarray(opp, dtype=float)
    eps = np.ascontiguousarray(eps, dtype=float)
    brk, coef = np.ascontiguousarray(poly.x, dtype=float), np.ascontiguousarray(poly.c, dtype=float)
    look = np.ascontiguousarray(look, dtype=float)
    idx_c = np.ascontiguousarray(idx, dtype=np.intc)
    out = np.empty((G * n, K, 6))
    work = np.empty(n * (11 + p) + 2 * M + 11 + 6 * n)
    fn(K, G, n, ego.ctypes.data, opp.ctypes.data, eps.ctypes.data,
       int(bool(track.closed)), float(track.length), coef.shape[1], coef.shape[0], brk.ctypes.data, coef.ctypes.data,
       look.ctypes.data, M, p, idx_c.ctypes.data, form.pts.aT.ctypes.data, form.wT.ctypes.data, form.sf2,
       int(form.kernel != "se"), int(form.variance == "tri"), form.V.ctypes.data, form.z_mean.ctypes.data,
       form.z_div.ctypes.data, form.y_mean.ctypes.data, form.y_scale.ctypes.data, out.ctypes.data, work.ctypes.data)
    return out


def applies(form: KernelForm | None, track) -> bool:
    """Whether :func:`rollout` runs compiled for this GP form and track (else the numpy loop)."""
    poly = getattr(track, "_d12", None)
    return (form is not None and poly is not None and form.pts.a.shape[1] == 11 and poly.c.shape[-1] == 4
            and _library() is not None)


@functools.cache
def _library():
    """The compiled ``rollout`` (loaded once per process), or None: numpy then."""
    from gprace.backends.compiled import compiled_source

    lib = compiled_source("h2h_rollout", KERNEL_C + _ROLLOUT_C, fast_flags(), "opponent rollout")
    if lib is None:
        return None
    fn = ctypes.CDLL(str(lib)).rollout
    I, P, D = ctypes.c_int, ctypes.c_void_p, ctypes.c_double
    fn.argtypes = [I, I, I, P, P, P, I, D, I, I, P, P, P, I, I, P, P, P, D, I, I, P, P, P, P, P, P, P]
    fn.restype = None
    return fn
