"""Kernel-times-weights products of many queries, compiled: the hot path of the opponent rollouts.

``kernel_dot(name, b, pts, wT, sf2)`` returns ``K(b, a) @ w`` for queries ``b (m, d)`` and points
``a (M, d)``, both already divided by the length scales, without forming the ``(m, M)`` kernel
block: per query one pass over the points (distance, kernel value, products with the ``q``
weight columns) in a small C function, built once per machine and cached like the NLP solvers
(:mod:`gprace.compiled`). Without a C compiler, or if the build fails, the same product
runs in numpy (:func:`gprace.gp.kernels.scaled_block`), with a warning: slower, the same values to
rounding (the sums run in another order; checked to 1e-12 relative in the tests).

Why: a 50-sample, 9-step rollout of a 600-point exact GP evaluates 8 blocks of 50 x 600 kernel
values; in numpy each is a product, a square root, an exponential and five more passes over a
temporary (0.8 ms each on this machine class), fused here into one pass (docs/decisions.md).
Compiled with ``-O3 -ffast-math`` (vectorised square roots and exponentials, reassociated sums),
and ``-mavx2 -mfma`` only where this CPU has them: the flags are part of the library's name, so
a cache shared by different machines holds one library per instruction set.
"""

from __future__ import annotations

import ctypes
import functools
from dataclasses import dataclass, field

import numpy as np

from gprace.gp.kernels import scaled_block

KERNEL_C = r"""
#include <math.h>
#include <string.h>
typedef double v4 __attribute__((vector_size(32)));
static inline v4 load4(const double *p) { v4 v; memcpy(&v, p, sizeof v); return v; }

/* buf (M) = k(b, a_j): one query b (d) against aT (d, M), both divided by the length scales;
   matern: 1 for Matern 3/2, 0 for the squared exponential. */
static inline void kernel_row(int M, int d, const double *restrict b, const double *restrict aT, double sf2,
                              int matern, double *restrict buf) {
    for (int j = 0; j < M; j++) { double t = b[0] - aT[j]; buf[j] = t * t; }
    for (int k = 1; k < d; k++) {
        const double bk = b[k]; const double *ak = aT + (long)k * M;
        for (int j = 0; j < M; j++) { double t = bk - ak[j]; buf[j] += t * t; }
    }
    if (matern) {
        for (int j = 0; j < M; j++) { double r = 1.7320508075688772 * sqrt(buf[j]); buf[j] = sf2 * (1.0 + r) * exp(-r); }
    } else {
        for (int j = 0; j < M; j++) buf[j] = sf2 * exp(-0.5 * buf[j]);
    }
}

/* x . y over M: four independent accumulators (one would wait on its own sums). */
static inline double dot(int M, const double *restrict x, const double *restrict y) {
    v4 s0 = {0, 0, 0, 0}, s1 = s0, s2 = s0, s3 = s0;
    int j = 0;
    for (; j + 16 <= M; j += 16) {
        s0 += load4(x + j) * load4(y + j);
        s1 += load4(x + j + 4) * load4(y + j + 4);
        s2 += load4(x + j + 8) * load4(y + j + 8);
        s3 += load4(x + j + 12) * load4(y + j + 12);
    }
    v4 s4 = (s0 + s1) + (s2 + s3);
    double s = (s4[0] + s4[1]) + (s4[2] + s4[3]);
    for (; j < M; j++) s += x[j] * y[j];
    return s;
}

/* out (m, q) = K(b, a) w: b (m, d) and aT (d, M) divided by the length scales, wT (q, M);
   buf: M doubles of scratch. */
void kernel_dot(int m, int M, int d, int q, const double *restrict b, const double *restrict aT,
                const double *restrict wT, double sf2, int matern, double *restrict out, double *restrict buf) {
    for (int i = 0; i < m; i++) {
        kernel_row(M, d, b + (long)i * d, aT, sf2, matern, buf);
        for (int c = 0; c < q; c++) out[(long)i * q + c] = dot(M, buf, wT + (long)c * M);
    }
}
"""


@dataclass
class Points:
    """The points ``a (M, d)`` of a kernel product (already divided by the length scales) in the
    layouts both paths need: rows with their squared norms (numpy) and columns (compiled)."""

    a: np.ndarray
    a2: np.ndarray = field(init=False)
    aT: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.a = np.ascontiguousarray(self.a, dtype=float)
        self.a2 = np.einsum("ij,ij->i", self.a, self.a)
        self.aT = np.ascontiguousarray(self.a.T)


def kernel_dot(name: str, b: np.ndarray, pts: Points, wT: np.ndarray, sf2: float) -> np.ndarray:
    """``K(b, a) @ wT.T`` ``(m, q)`` of kernel ``name`` (``se`` or ``matern15``) for queries ``b
    (m, d)`` and the points ``pts`` (both divided by the length scales); ``wT (q, M)`` C-ordered."""
    fn = _library()
    if fn is None:
        return scaled_block(name, b, pts.a, pts.a2, sf2) @ wT.T
    b = np.ascontiguousarray(b, dtype=float)
    m, (M, d), q = b.shape[0], pts.a.shape, wT.shape[0]
    wT = np.ascontiguousarray(wT, dtype=float)
    out, buf = np.empty((m, q)), np.empty(M)  # held here: the C function gets bare addresses
    fn(m, M, d, q, b.ctypes.data, pts.aT.ctypes.data, wT.ctypes.data, float(sf2), int(name != "se"),
       out.ctypes.data, buf.ctypes.data)
    return out


@dataclass(frozen=True)
class KernelForm:
    """A one-kernel GP posterior as arrays, for compiled predictors (the opponent rollout): in
    normalised units, for a query ``b = (z - z_mean) / (z_scale * ls)`` and ``k = K(b, a)``,
    mean ``wT @ k`` and latent variance ``sf2 - |L^-1 k|^2`` (``"tri"``, ``V = L`` lower, the
    exact GP) or ``sf2 - k^T V k`` (``"quad"``, the sparse GP's ``Q``). See
    :meth:`gprace.gp.base.GPBackend.kernel_form`."""

    kernel: str
    pts: Points
    wT: np.ndarray  # (p, M) C-ordered
    sf2: float
    variance: str  # "tri" or "quad"
    V: np.ndarray  # (M, M) C-ordered
    z_mean: np.ndarray
    z_div: np.ndarray  # z_scale * ls
    y_mean: np.ndarray
    y_scale: np.ndarray


def fast_flags() -> tuple[str, ...]:
    """Compiler flags of the hot-path kernels (see the module doc)."""
    return ("-O3", "-ffast-math", "-Wno-psabi", *_cpu_flags())


def _cpu_flags() -> tuple[str, ...]:
    try:
        with open("/proc/cpuinfo") as fh:
            words = set(next((line for line in fh if line.startswith("flags")), "").split())
    except OSError:
        return ()
    return ("-mavx2", "-mfma") if {"avx2", "fma"} <= words else ()


@functools.cache
def _library():
    """The compiled ``kernel_dot`` (loaded once per process), or None: numpy then."""
    from gprace.compiled import compiled_source

    lib = compiled_source("gp_kernel_dot", KERNEL_C, fast_flags(),
                          "GP kernel product")
    if lib is None:
        return None
    fn = ctypes.CDLL(str(lib)).kernel_dot
    fn.argtypes = [ctypes.c_int] * 4 + [ctypes.c_void_p] * 3 + [ctypes.c_double, ctypes.c_int] + [ctypes.c_void_p] * 2
    fn.restype = None
    return fn
