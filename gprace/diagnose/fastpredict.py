"""Multi-step predictions in one compiled call: the diagnosis's hot path in C.

Every fit of the diagnosis integrates a batch of windows ``H`` steps ahead with RK4, and in numpy
each derivative is some sixty array operations: about 0.6 us per window and derivative (measured
0.5 to 0.75 us per element for 2,000 to 32,000 windows, plus 0.15 ms per call), which made a
diagnosis 13 to 48 s per 6,000 samples. Here the derivative is the SAME symbolic definition
(:func:`gprace.model.dynamics.dynamics`, CasADi's face of the model) turned into C by CasADi's
code generator, and a small hand-written driver runs RK4 with the curvature looked up at every
stage (``numpy.interp``'s rule, the lap wrapped with numpy's floor modulo), over all windows and
steps in one call.

Every parameter of the vehicle and of the effects is an input (one row per window, or one row
for all), so the batched fits (parameters per window) use the same function. A variant is
compiled per longitudinal input kind, set of actuator lags and set of stateless effects present
(only what the model has: the universal variant with every effect at its neutral values was
1.6 times slower for the nominal model), each once per machine and cached like the other
compiled kernels (about 0.5 s of gcc per variant; a diagnosis meets a few dozen the first time).
Stateless effects of one stage commute (sums and products of different quantities), so their
order in the model does not matter. A model with an effect outside the catalogue, two effects of
one kind, lags in another order or a steering offset before a steering lag falls back to the
numpy path, which stays the reference (tests check both give the same predictions to rounding).

**The 4-lane kernel** (issue 36, stop 48; ``gprace_predict4``, used wherever it builds): most of
a window-step's time was the derivative's transcendentals (4 atan, 4 sin/cos per call) and the
curvature look-ups. Here 8 windows advance in lockstep as two AVX2 vectors of 4 lanes (same H,
substeps and dt; each lane its own start, inputs, parameter row, lap and offset; the last group
repeats the last window in its unused lanes). The derivative is emitted by :func:`emit_vector`
from the SAME CasADi function, one vector statement per instruction of its algorithm
(GCC vector extensions; comparisons and if_else as masks with CasADi's and C99's NaN rules;
atan, sin, cos, tanh... from glibc's libmvec, ``-lmvec``). The look-ups stay scalar per lane,
and every kernel starts its interval search from the previous stage's interval (same interval,
so the same value as a plain binary search). libmvec is within a few ulp of libm, not bit
identical: on the real logs the 4-lane predictions of v_x, v_y and the yaw rate agree with the
scalar kernel's to 2e-14 of each channel's size (the Frenet channels of a few windows of the
25 m F1TENTH track to 3e-7); tests check 1e-12 on random windows of every model kind. Where it cannot
run (not x86-64 Linux, no AVX2/FMA, no libmvec or one without the functions, an operation the
emitter does not know) or ``GPRACE_DIAGNOSE_SIMD=0``, the scalar kernel runs; the numpy path stays
the reference.
"""

from __future__ import annotations

import ctypes
import functools
import os
import platform
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields

import numpy as np

from gprace.model import EFFECTS, Effect, NominalModel, Params
from gprace.model.dynamics import LONGITUDINAL, NX, dynamics

LAGS = ("steering_lag", "drivetrain_lag")
PARAM_FIELDS = tuple(f.name for f in fields(Params) if f.name != "longitudinal")
NEUTRAL = {
    "aero_drag": {"c_d": 0.0}, "rolling_resistance": {"c_rr": 0.0},
    "road_grade": {"angle": 0.0, "s_start": 0.0, "s_end": 1.0},
    "downforce": {"c_l": 0.0}, "load_transfer": {"cog_height": 0.0}, "tire_load_sensitivity": {"k": 0.0},
    "tire_friction": {"front": 1.0, "rear": 1.0}, "cornering_stiffness": {"front": 1.0, "rear": 1.0},
    "friction_patch": {"factor": 1.0, "s_start": 0.0, "s_end": 1.0}, "combined_slip": {"k": 0.0},
    "road_bank": {"angle": 0.0, "s_start": 0.0, "s_end": 1.0}, "steering_offset": {"offset": 0.0},
    "yaw_inertia": {"factor": 1.0},
}
"""Values at which each effect without states changes nothing (the universal function's default)."""
SENSOR_ONLY = ("gyro_bias", "velocity_misalignment")  # act on the measurement only (applied in numpy)
KERNEL_FLAGS = ("-O3", "-march=native", "-fno-math-errno", "-fno-trapping-math")
"""Compiler flags of the kernel (cached per machine, so tuned to its processor); no -ffast-math:
the driver relies on infinities (a recording without laps) and NaN passing through."""
SIMD_FLAGS = (*KERNEL_FLAGS, "-mavx2", "-mfma")
"""The 4-lane kernel's flags: AVX2 vectors whatever -march=native says (libmvec's ``_ZGVdN4*``
functions take and return them in ymm registers); used only where the processor has AVX2 and FMA."""
GROUPS = 2
"""Vectors of 4 windows the 4-lane kernel advances together (8 windows)."""
SIMD_ENV = "GPRACE_DIAGNOSE_SIMD"
"""Environment variable: ``0`` keeps the scalar kernel even where the 4-lane one could run."""
PROFILES = tuple(n for n, c in EFFECTS.items() if getattr(c, "profile", False))
"""Effects given along the lap by knots (:class:`~gprace.model.effects.ProfileEffect`): their value
at the car's position is interpolated by the driver (numpy's rule, periodic over the lap) from a
table per window and passed to the derivative beside the curvature, so the knot values never
enter the compiled code (one variant serves every knot count and every batch of profiles)."""

_LOOKUP_C = r"""
/* numpy's floating remainder: the sign of the divisor */
static inline double pymod(double a, double b) {
    if (a > 0 && a < b) return a;  /* inside the lap already: what fmod gives, without its cost */
    double r = fmod(a, b);
    if (r != 0.0) { if ((b < 0) != (r < 0)) r += b; } else r = copysign(0.0, b);
    return r;
}

/* numpy.interp(x, xp, fp) on a sorted table of n points, searching from the interval *hint of the
   previous call (galloping to a bracket, then bisecting): a window advancing along s finds its
   interval in a few comparisons, even where the table holds several laps' samples. The interval
   holding x is unique (xp[lo] <= x < xp[lo + 1]), so the value is that of a plain binary search. */
static inline double interp1h(double x, const double *xp, const double *fp, long n, long *hint) {
    if (!(x > xp[0])) return x < xp[0] || x == xp[0] ? fp[0] : x;  /* NaN passes through */
    if (x >= xp[n - 1]) return fp[n - 1];
    long lo = *hint < n - 1 ? *hint : 0, hi, step = 1;  /* wanted: xp[lo] <= x < xp[lo + 1] */
    if (xp[lo] <= x) {  /* gallop forward from the hint to a bracket xp[lo] <= x < xp[hi] */
        hi = lo + 1;
        while (xp[hi] <= x) { lo = hi; hi = lo + step < n - 1 ? lo + step : n - 1; step *= 2; }
    } else {  /* or backward */
        hi = lo; lo = hi - 1;
        while (xp[lo] > x) { hi = lo; lo = hi - step > 0 ? hi - step : 0; step *= 2; }
    }
    while (hi - lo > 1) { long mid = (lo + hi) / 2; if (xp[mid] <= x) lo = mid; else hi = mid; }
    *hint = lo;
    double slope = (fp[lo + 1] - fp[lo]) / (xp[lo + 1] - xp[lo]);
    return slope * (x - xp[lo]) + fp[lo];
}


/* curvature kap[0] and the NPROF profile values kap[1..] at s for window i (of m): profile q has
   pn[q] knots at pk + pko[q] (extended by one on each side when periodic, pL[q] > 0) and its values
   in row prow[q * m + i] of the table at pv + pvo[q] */
static inline void stage_inputs(double s, long i, long m, double L, double off, const double *ks, const double *kv,
                                long nk, const double *pk, const long *pko, const long *pn, const double *pL,
                                const double *pv, const long *pvo, const long *prow, long *hint, double *kap) {
    kap[0] = interp1h((isfinite(L) ? pymod(s, L) : s) + off, ks, kv, nk, &hint[0]);
    for (long q = 0; q < NPROF; q++) {
        double x = pL[q] > 0 ? pymod(s, pL[q]) : s;
        kap[1 + q] = interp1h(x, pk + pko[q], pv + pvo[q] + prow[q * m + i] * pn[q], pn[q], &hint[1 + q]);
    }
}

"""

_DRIVER_C = r"""
/* out (m, H, NXS): windows i start from X0[i] (m, NXS) and step with the inputs U[k0[i] + j]
   (rows clamped to nu - 1), RK4 with `sub` substeps of dt / sub, curvature per stage from the
   table (ks, kv) at s wrapped to the lap L[i] (infinite: no wrap) plus the offset off[i], and the
   profiles' values (stage_inputs); parameters P + i * pstride (NP values). Returns 0. */
int gprace_predict(long m, long H, long sub, double dt, const double *X0, const long *k0, const double *U,
                   long nu, const double *P, long pstride, const double *ks, const double *kv, long nk,
                   const double *L, const double *off, const double *pk, const long *pko, const long *pn,
                   const double *pL, const double *pv, const long *pvo, const long *prow, double *out) {
    double x[NXS], x2[NXS], k1[NXS], k2[NXS], k3[NXS], k4[NXS], kap[1 + NPROF], u[2];
    long hint[1 + NPROF];
    casadi_real w[SZW > 0 ? SZW : 1];
    casadi_int iw[SZIW > 0 ? SZIW : 1];
    const casadi_real *arg[4];
    casadi_real *res[1];
    double h = dt / (double)sub;
    for (long i = 0; i < m; i++) {
        const double *p = P + i * pstride;
        for (int q = 0; q < NXS; q++) x[q] = X0[i * NXS + q];
        for (int q = 0; q < 1 + NPROF; q++) hint[q] = 0;
        arg[1] = u; arg[2] = kap; arg[3] = p;
        for (long j = 0; j < H; j++) {
            long r = k0[i] + j; if (r > nu - 1) r = nu - 1;
            u[0] = U[2 * r]; u[1] = U[2 * r + 1];
            for (long t = 0; t < sub; t++) {
                stage_inputs(x[5], i, m, L[i], off[i], ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint, kap); arg[0] = x; res[0] = k1; DERIV(arg, res, iw, w, 0);
                for (int q = 0; q < NXS; q++) x2[q] = x[q] + 0.5 * h * k1[q];
                stage_inputs(x2[5], i, m, L[i], off[i], ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint, kap); arg[0] = x2; res[0] = k2; DERIV(arg, res, iw, w, 0);
                for (int q = 0; q < NXS; q++) x2[q] = x[q] + 0.5 * h * k2[q];
                stage_inputs(x2[5], i, m, L[i], off[i], ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint, kap); arg[0] = x2; res[0] = k3; DERIV(arg, res, iw, w, 0);
                for (int q = 0; q < NXS; q++) x2[q] = x[q] + h * k3[q];
                stage_inputs(x2[5], i, m, L[i], off[i], ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint, kap); arg[0] = x2; res[0] = k4; DERIV(arg, res, iw, w, 0);
                for (int q = 0; q < NXS; q++) x[q] = x[q] + (h / 6.0) * (k1[q] + 2 * k2[q] + 2 * k3[q] + k4[q]);
            }
            for (int q = 0; q < NXS; q++) out[(i * H + j) * NXS + q] = x[q];
        }
    }
    return 0;
}
"""


_DRIVER4_C = r"""
/* the curvature and profile values of the 4 G lanes at their own s (stage_inputs, lane by lane);
   entry q of vector group g sits at [q * G + g] */
static inline void stage_lanes(const v4d *x, const long *idx, long m, const double *L, const double *off,
                               const double *ks, const double *kv, long nk, const double *pk, const long *pko,
                               const long *pn, const double *pL, const double *pv, const long *pvo, const long *prow,
                               long hint[][1 + NPROF], v4d *kap) {
    double k[1 + NPROF];
    for (int c = 0; c < 4 * G; c++) {
        int g = c / 4, l = c % 4;
        long i = idx[c];
        stage_inputs(x[5 * G + g][l], i, m, L[i], off[i], ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint[c], k);
        for (int q = 0; q < 1 + NPROF; q++) kap[q * G + g][l] = k[q];
    }
}

/* gprace_predict on 4 G windows at a time (G groups of 4 lanes of AVX2 vectors, advanced together so
   that the processor overlaps their dependency chains; same H, sub and dt, each window its own start,
   inputs, parameters, lap and offset); the last group repeats the last window in its unused lanes
   and writes only its own. Returns 0. */
int gprace_predict4(long m, long H, long sub, double dt, const double *X0, const long *k0, const double *U,
                    long nu, const double *P, long pstride, const double *ks, const double *kv, long nk,
                    const double *L, const double *off, const double *pk, const long *pko, const long *pn,
                    const double *pL, const double *pv, const long *pvo, const long *prow, double *out) {
    v4d x[NXS * G], x2[NXS * G], k1[NXS * G], k2[NXS * G], k3[NXS * G], k4[NXS * G], kap[(1 + NPROF) * G],
        u[2 * G], p[(NP > 0 ? NP : 1) * G];
    double h = dt / (double)sub;
    for (long g0 = 0; g0 < m; g0 += 4 * G) {
        long idx[4 * G], hint[4 * G][1 + NPROF];
        for (int c = 0; c < 4 * G; c++) {
            int g = c / 4, l = c % 4;
            idx[c] = g0 + c < m ? g0 + c : m - 1;
            for (int q = 0; q < 1 + NPROF; q++) hint[c][q] = 0;
            for (int q = 0; q < NXS; q++) x[q * G + g][l] = X0[idx[c] * NXS + q];
            for (int q = 0; q < NP; q++) p[q * G + g][l] = P[idx[c] * pstride + q];
        }
        long nl = m - g0 < 4 * G ? m - g0 : 4 * G;
        for (long j = 0; j < H; j++) {
            for (int c = 0; c < 4 * G; c++) {
                long r = k0[idx[c]] + j; if (r > nu - 1) r = nu - 1;
                u[c / 4][c % 4] = U[2 * r]; u[G + c / 4][c % 4] = U[2 * r + 1];
            }
            for (long t = 0; t < sub; t++) {
                stage_lanes(x, idx, m, L, off, ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint, kap); gprace_deriv4(x, u, kap, p, k1);
                for (int q = 0; q < NXS * G; q++) x2[q] = x[q] + 0.5 * h * k1[q];
                stage_lanes(x2, idx, m, L, off, ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint, kap); gprace_deriv4(x2, u, kap, p, k2);
                for (int q = 0; q < NXS * G; q++) x2[q] = x[q] + 0.5 * h * k2[q];
                stage_lanes(x2, idx, m, L, off, ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint, kap); gprace_deriv4(x2, u, kap, p, k3);
                for (int q = 0; q < NXS * G; q++) x2[q] = x[q] + h * k3[q];
                stage_lanes(x2, idx, m, L, off, ks, kv, nk, pk, pko, pn, pL, pv, pvo, prow, hint, kap); gprace_deriv4(x2, u, kap, p, k4);
                for (int q = 0; q < NXS * G; q++) x[q] = x[q] + (h / 6.0) * (k1[q] + 2 * k2[q] + 2 * k3[q] + k4[q]);
            }
            for (long c = 0; c < nl; c++)
                for (int q = 0; q < NXS; q++) out[((g0 + c) * H + j) * NXS + q] = x[q * G + c / 4][c % 4];
        }
    }
    return 0;
}
"""

_VEC_HEAD_C = r"""#include <math.h>
#include <immintrin.h>
typedef double v4d __attribute__((vector_size(32)));
typedef long long v4l __attribute__((vector_size(32)));
static inline v4d vsel(v4l c, v4d a, v4d b) { return (v4d)(((v4l)a & c) | ((v4l)b & ~c)); }
static inline v4d vbool(v4l c) { return vsel(c, (v4d){1, 1, 1, 1}, (v4d){0, 0, 0, 0}); }
static inline v4l vtrue(v4d a) { return a != (v4d){0, 0, 0, 0}; }  /* C truth: NaN is true */
"""

# operations of the emitter: CasADi op code name -> C of a 4-lane expression of its arguments
# (a, b); the comparisons and logic give 1.0 / 0.0 like CasADi's scalar code, fmin/fmax follow
# C99's fmin/fmax (a NaN argument gives the other one), if_else_zero gives exactly 0 where false
_VEC_OPS = {
    "OP_ASSIGN": "{a}", "OP_ADD": "{a} + {b}", "OP_SUB": "{a} - {b}", "OP_MUL": "{a} * {b}",
    "OP_DIV": "{a} / {b}", "OP_NEG": "-{a}", "OP_SQ": "{a} * {a}", "OP_TWICE": "{a} + {a}",
    "OP_INV": "1.0 / {a}", "OP_SQRT": "(v4d)_mm256_sqrt_pd((__m256d){a})",
    "OP_FABS": "(v4d)((v4l){a} & (v4l){{0x7fffffffffffffffLL, 0x7fffffffffffffffLL, 0x7fffffffffffffffLL, 0x7fffffffffffffffLL}})",
    "OP_FMIN": "vsel(({a} <= {b}) | ({b} != {b}), {a}, {b})", "OP_FMAX": "vsel(({a} >= {b}) | ({b} != {b}), {a}, {b})",
    "OP_LT": "vbool({a} < {b})", "OP_LE": "vbool({a} <= {b})", "OP_EQ": "vbool({a} == {b})",
    "OP_NE": "vbool({a} != {b})", "OP_NOT": "vbool(~vtrue({a}))", "OP_AND": "vbool(vtrue({a}) & vtrue({b}))",
    "OP_OR": "vbool(vtrue({a}) | vtrue({b}))", "OP_IF_ELSE_ZERO": "(v4d)(vtrue({a}) & (v4l){b})",
}
_VEC_MATH = {"OP_SIN": "sin", "OP_COS": "cos", "OP_TAN": "tan", "OP_ATAN": "atan", "OP_ASIN": "asin",
             "OP_ACOS": "acos", "OP_EXP": "exp", "OP_LOG": "log", "OP_TANH": "tanh", "OP_SINH": "sinh",
             "OP_COSH": "cosh"}
"""One-argument functions taken from glibc's libmvec, AVX2 4-lane variants (``_ZGVdN4v_<name>``)."""
_VEC_MATH2 = {"OP_ATAN2": "atan2", "OP_POW": "pow"}  # two arguments: _ZGVdN4vv_<name>


def _c_double(c: float) -> str:
    if c != c:
        return "NAN"
    if c in (float("inf"), float("-inf")):
        return "INFINITY" if c > 0 else "(-INFINITY)"
    return repr(float(c))


def emit_vector(F, groups: int = 1) -> str:
    """C of ``static void gprace_deriv4(x, u, kappa, p, out)``: the CasADi SX function ``F``
    (four inputs, one output) evaluated on 4 lanes at once, one statement per instruction of its
    algorithm (``instruction_id/input/output/constant``), in AVX2 vectors of GCC's vector
    extension, the transcendental functions from libmvec. NotImplementedError for an operation
    it does not know (the caller keeps the scalar kernel)."""
    import casadi as ca

    name = {getattr(ca, n): n for n in dir(ca) if n.startswith("OP_")}
    body, used, G = [], set(), groups
    for k in range(F.n_instructions()):
        op = name.get(F.instruction_id(k), str(F.instruction_id(k)))
        i, o = F.instruction_input(k), F.instruction_output(k)
        for g in range(G):  # the groups' statements side by side: independent chains to overlap
            if op == "OP_INPUT":
                body.append(f"w{o[0]}_{g} = a{i[0]}[{i[1] * G + g}];")
                continue
            if op == "OP_OUTPUT":
                body.append(f"r[{o[1] * G + g}] = w{i[0]}_{g};")
                continue
            if op == "OP_CONST":
                c = _c_double(F.instruction_constant(k))
                body.append(f"w{o[0]}_{g} = (v4d){{{c}, {c}, {c}, {c}}};")
                continue
            args = {"a": f"w{i[0]}_{g}", "b": f"w{i[1]}_{g}" if len(i) > 1 else ""}
            if op in _VEC_OPS:
                expr = _VEC_OPS[op].format(**args)
            elif op in _VEC_MATH:
                fn = f"_ZGVdN4v_{_VEC_MATH[op]}"
                used.add(f"v4d {fn}(v4d);")
                expr = f"{fn}({args['a']})"
            elif op in _VEC_MATH2:
                fn = f"_ZGVdN4vv_{_VEC_MATH2[op]}"
                used.add(f"v4d {fn}(v4d, v4d);")
                expr = f"{fn}({args['a']}, {args['b']})"
            else:
                raise NotImplementedError(f"the 4-lane emitter has no {op}")
            body.append(f"w{o[0]}_{g} = {expr};")
    work = ", ".join(f"w{j}_{g}" for j in range(max(F.sz_w(), 1)) for g in range(G))
    decl = "".join(f"extern {d}\n" for d in sorted(used))
    return (decl + "static void gprace_deriv4(const v4d *a0, const v4d *a1, "
            "const v4d *a2, const v4d *a3, v4d *r) {\n"
            f"    v4d {work};\n    " + "\n    ".join(body) + "\n}\n")


def vector_source(F, lay: Layout, nprof: int, groups: int = None) -> str:
    """C of the 4-lane kernel (``gprace_predict4``): the emitted derivative and the 4-lane driver,
    ``groups`` (default :data:`GROUPS`) vectors of 4 windows advanced together."""
    G = GROUPS if groups is None else groups
    return (_VEC_HEAD_C + f"#define NXS {lay.nx}\n#define NPROF {nprof}\n#define NP {lay.np}\n#define G {G}\n"
            + emit_vector(F, G) + _LOOKUP_C + _DRIVER4_C)


@dataclass(frozen=True)
class Layout:
    """Where each parameter sits in the universal function's parameter row."""

    longitudinal: str
    lags: tuple[str, ...]
    effects: tuple[str, ...]  # catalogue effects in the function, in catalogue order
    index: dict  # ("params", field) or (effect, parameter) -> column
    nx: int

    @property
    def np(self) -> int:
        return len(self.index)


def _layout(longitudinal: str, lags: tuple[str, ...], only: tuple[str, ...] | None = None) -> Layout:
    names = tuple(n for n in EFFECTS if (n in NEUTRAL and (only is None or n in only)) or n in lags)
    index = {("params", f): i for i, f in enumerate(PARAM_FIELDS)}
    for n in names:
        for k in EFFECTS[n].params:
            index[(n, k)] = len(index)
    return Layout(longitudinal, lags, names, index, NX + len(lags))


def _deriv_function(longitudinal: str, lags: tuple[str, ...], only: tuple[str, ...] | None, profiles: tuple[str, ...]):
    """(CasADi SX function ``gprace_deriv(x, u, kappa, p) -> xdot``, Layout) of a variant: the
    model's own :func:`~gprace.model.dynamics.dynamics` with every parameter an input."""
    import casadi as ca

    from gprace.model.nominal import _casadi_ops

    lay = _layout(longitudinal, lags, only)
    x, u, k = ca.SX.sym("x", lay.nx), ca.SX.sym("u", 2), ca.SX.sym("kappa", 1 + len(profiles))
    P = ca.SX.sym("p", lay.np)
    p = Params(**{f: P[lay.index[("params", f)]] for f in PARAM_FIELDS}, longitudinal=longitudinal)
    effects, z0 = [], 0
    for n in lay.effects:
        e = EFFECTS[n](**{q: P[lay.index[(n, q)]] for q in EFFECTS[n].params})
        e.z0 = z0
        z0 += e.n_states
        effects.append(e)
    for q, n in enumerate(profiles):  # the profile's value at s is the input k[1 + q]
        e = _symbolic_profile(n, k[1 + q])
        e.z0 = z0
        effects.append(e)
    xdot = dynamics([x[i] for i in range(lay.nx)], [u[0], u[1]], k[0], p, effects, _casadi_ops())
    return ca.Function("gprace_deriv", [x, u, k, P], [ca.vertcat(*xdot)]), lay


def _tag(longitudinal: str, lags: tuple[str, ...], only: tuple[str, ...] | None, profiles: tuple[str, ...]) -> str:
    fx = "all" if only is None else ("-".join("".join(w[0] for w in n.split("_")) for n in only) or "none")
    if profiles:
        fx += "_p" + "-".join("".join(w[0] for w in n.split("_")) for n in profiles)
    return f"diagnose_predict_{longitudinal}_{'_'.join(lags) or 'nolag'}_{fx}"


def _bind(lib, symbol: str):
    fn = getattr(ctypes.CDLL(str(lib)), symbol)
    dp, lp, L_ = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_long), ctypes.c_long
    fn.argtypes = [L_, L_, L_, ctypes.c_double, dp, lp, dp, L_, dp, L_, dp, dp, L_, dp, dp,
                   dp, lp, lp, dp, dp, lp, lp, dp]
    fn.restype = ctypes.c_int
    return fn


def scalar_source(F, lay: Layout, nprof: int) -> str:
    """C of the scalar kernel: CasADi's generated derivative and the driver (``gprace_predict``)."""
    import casadi as ca

    gen = ca.CodeGenerator("gprace_deriv.c", {"with_header": False, "with_mem": False})
    gen.add(F)
    return gen.dump() + f"\n#define NXS {lay.nx}\n#define SZW {F.sz_w()}\n#define SZIW {F.sz_iw()}\n" \
        f"#define NPROF {nprof}\n#define DERIV gprace_deriv\n" + _LOOKUP_C + _DRIVER_C


@functools.cache
def _kernel(longitudinal: str, lags: tuple[str, ...], only: tuple[str, ...] | None = None,
            profiles: tuple[str, ...] = ()):
    """(ctypes function, Layout) of a compiled variant, or None (no compiler, or a failed build).
    ``profiles``: the profile effects present, whose values come in beside the curvature."""
    from gprace.compiled import compiled_source

    F, lay = _deriv_function(longitudinal, lags, only, profiles)
    lib = compiled_source(_tag(longitudinal, lags, only, profiles), scalar_source(F, lay, len(profiles)),
                          KERNEL_FLAGS, "diagnosis prediction kernel")
    return None if lib is None else (_bind(lib, "gprace_predict"), lay)


@functools.cache
def _simd_kernel(longitudinal: str, lags: tuple[str, ...], only: tuple[str, ...] | None = None,
                 profiles: tuple[str, ...] = ()):
    """(ctypes function, Layout) of the 4-lane variant (same arguments and outputs as the scalar
    one), or None: SIMD switched off, no AVX2/FMA on this processor, not x86-64 Linux, an operation
    the emitter does not know, no libmvec (or one without the functions), or a failed build."""
    if not simd_available() or _SIMD_FAILED:
        return None
    from gprace.compiled import compiled_source

    F, lay = _deriv_function(longitudinal, lags, only, profiles)
    try:
        src = vector_source(F, lay, len(profiles))
    except NotImplementedError:
        return None
    lib = compiled_source(_tag(longitudinal, lags, only, profiles) + "_simd4", src, SIMD_FLAGS,
                          "4-lane diagnosis prediction kernel", libs=("-lmvec",), fallback="the scalar kernel runs")
    if lib is None:  # no libmvec, or a compiler without AVX2: the other variants would fail too
        _SIMD_FAILED.append(_tag(longitudinal, lags, only, profiles))
        return None
    try:
        return _bind(lib, "gprace_predict4"), lay
    except OSError:  # a libmvec without the functions at load time
        _SIMD_FAILED.append(_tag(longitudinal, lags, only, profiles))
        return None


_SIMD_FAILED: list[str] = []
"""Variants whose 4-lane build failed in this process: no other is tried (one warning, not one
per variant; the scalar kernel runs)."""


@functools.cache
def simd_available() -> bool:
    """The 4-lane kernel may run here: not switched off (``GPRACE_DIAGNOSE_SIMD=0``), x86-64 Linux
    (glibc's libmvec) and a processor with AVX2 and FMA (its flags in /proc/cpuinfo). Whether
    libmvec has the functions is found when the kernel is linked (``-lmvec``, no undefined symbol)."""
    raw = os.environ.get(SIMD_ENV, "").strip()
    if raw not in ("", "0", "1"):
        from gprace.errors import ConfigError

        raise ConfigError(f"{SIMD_ENV}={raw!r}: expected 0 (scalar kernel) or 1 (4-lane kernel where it runs)")
    if raw == "0" or not sys.platform.startswith("linux") or platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return {"avx2", "fma"} <= flags
    except OSError:
        pass
    return False


def _symbolic_profile(name: str, value):
    """An instance of the catalogue's profile ``name`` whose value at the car's position is the
    symbol ``value`` (same hooks, so the same physics as the numpy model's)."""
    cls = EFFECTS[name]
    sym = type(f"Symbolic{cls.__name__}", (cls,), {"value": lambda self, c: value})
    neutral = 1.0 if cls.params["values"].unit == "-" else 0.0
    return sym(knots=[0.0, 1.0], values=[neutral, neutral], lap_length=0.0)


def profile_table(e, m: int) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """(knots, period, values (rows, K), row of each of the ``m`` windows) of a profile effect:
    a catalogue one (one row), or a fitting device of :mod:`gprace.diagnose.profiles` carrying
    one row of knot values per window set (``table()``)."""
    if hasattr(e, "table"):
        return e.table()
    return (np.asarray(e._knots, float), float(e._period), np.atleast_2d(np.asarray(e._vals, float)),
            np.zeros(m, dtype=np.int64))


def _profile_inputs(profs: list, m: int):
    """The driver's profile arguments (stage_inputs in the C): knots extended by one on each side
    of a periodic profile (numpy.interp's ``period`` rule), tables and per-window rows."""
    pk, pko, pn, pL, pv, pvo, prow = [], [], [], [], [], [], []
    ok, ov = 0, 0
    for e in profs:
        kn, L, V, row = profile_table(e, m)
        if L > 0:
            kn = np.concatenate([[kn[-1] - L], kn, [kn[0] + L]])
            V = np.hstack([V[:, -1:], V, V[:, :1]])
        pk.append(kn), pko.append(ok), pn.append(len(kn)), pL.append(L)
        pv.append(V.ravel()), pvo.append(ov), prow.append(np.broadcast_to(np.asarray(row, np.int64), (m,)))
        ok += len(kn)
        ov += V.size
    if not profs:
        z, zi = np.zeros(1), np.zeros(1, dtype=np.int64)
        return z, zi, zi, z, z, zi, zi
    c = np.ascontiguousarray
    return (c(np.concatenate(pk)), c(pko, dtype=np.int64), c(pn, dtype=np.int64), c(pL, dtype=float),
            c(np.concatenate(pv)), c(pvo, dtype=np.int64), c(np.concatenate(prow), dtype=np.int64))


def plan(model: NominalModel) -> tuple[str, tuple[str, ...], list[Effect]] | None:
    """(longitudinal, lags, catalogue effects) when the universal function can run ``model``,
    else None (an effect outside the catalogue or of a subclass, one kind twice, lags or a steering
    offset in an order whose arithmetic the universal (catalogue) order would change). Lags in
    another order than the catalogue's run too: they act on different inputs, so only the layout
    of their states differs, which :func:`predict_states` permutes."""
    names = [e.name for e in model.effects]
    if len(set(names)) != len(names):
        return None
    for e in model.effects:
        if e.name in PROFILES:  # the catalogue's profile, or a fitting device derived from it
            if not isinstance(e, EFFECTS[e.name]) or not (hasattr(e, "table") or type(e) is EFFECTS[e.name]):
                return None
            continue
        if EFFECTS.get(e.name) is not type(e) or not (e.name in NEUTRAL or e.name in LAGS or e.name in SENSOR_ONLY):
            return None
    cat = [n for n in EFFECTS if n in names]
    # stateless effects of one stage add to or scale different quantities, or the same one by
    # sums and products: any order gives the same numbers (to rounding). What order changes: the
    # layout of the lag states, and a steering offset added before a steering lag replaces the
    # angle (the lag's state then holds no offset).
    if "steering_offset" in names and "steering_lag" in names \
            and names.index("steering_offset") < names.index("steering_lag"):
        return None
    if model.params.longitudinal not in LONGITUDINAL:
        return None
    return model.params.longitudinal, tuple(n for n in cat if n in LAGS), list(model.effects)


def parameter_rows(model: NominalModel, lay: Layout, m: int) -> np.ndarray:
    """(1, np) or (m, np) parameter rows of ``model`` (per-window arrays of length ``m`` allowed)."""
    cols: dict[int, object] = {}
    p = model.params
    for f in PARAM_FIELDS:
        cols[lay.index[("params", f)]] = getattr(p, f)
    present = {e.name: e for e in model.effects}
    for n in lay.effects:
        e = present.get(n)
        for q, spec in EFFECTS[n].params.items():
            if e is not None:
                v = e.values[q]
            else:
                v = NEUTRAL.get(n, {}).get(q, spec.default if spec.default is not None else 0.0)
            cols[lay.index[(n, q)]] = v
    per_window = any(isinstance(v, np.ndarray) and v.ndim == 1 and len(v) == m and m > 1 for v in cols.values())
    P = np.empty((m if per_window else 1, lay.np))
    for j, v in cols.items():
        P[:, j] = v
    return P


def predict_states(model: NominalModel, data, starts: np.ndarray, H: int, substeps: int, X0: np.ndarray,
                   offset: float) -> np.ndarray | None:
    """Model states ``(m, H, nx)`` of the windows at ``starts`` from ``X0`` (m, nx), or None when the
    compiled path cannot run this model (the caller integrates in numpy). Inputs of rows past the
    data's end repeat its last row; ``offset`` separates recordings in the curvature table."""
    pl = plan(model)
    if pl is None:
        return None
    profs = sorted((e for e in pl[2] if e.name in PROFILES), key=lambda e: PROFILES.index(e.name))
    key = (pl[0], pl[1], tuple(e.name for e in pl[2] if e.name in NEUTRAL), tuple(e.name for e in profs))
    kern = _simd_kernel(*key) or _kernel(*key)
    if kern is None:
        return None
    fn, lay = kern
    m = len(starts)
    # the model's lag states in its own order -> the kernel's (catalogue) order, and back
    own = [n for n in (e.name for e in model.effects) if n in LAGS]
    perm = None
    if own != list(pl[1]):
        pos, j = {}, NX
        for e in model.effects:
            pos[e.name] = j
            j += e.n_states
        perm = np.r_[np.arange(NX), [pos[n] + i for n in pl[1] for i in range(EFFECTS[n].n_states)]].astype(int)
        X0 = X0[:, perm]
    prof_args = _profile_inputs(profs, m)
    P = np.ascontiguousarray(parameter_rows(model, lay, m))
    X0 = np.ascontiguousarray(X0, dtype=float)
    k0 = np.ascontiguousarray(starts, dtype=np.int64)
    U = np.ascontiguousarray(data.U, dtype=float)
    rec = data.rec[starts]
    L = np.ascontiguousarray(data.L[rec], dtype=float)
    off = np.ascontiguousarray(rec * offset, dtype=float)
    out = np.empty((m, H, lay.nx))
    _run_chunks(fn, lay, m, H, int(substeps), float(data.dt), X0, k0, U, P, data, L, off, prof_args, out)
    if perm is not None:
        back = np.empty_like(out)
        back[..., perm] = out
        return back
    return out


THREADS_ENV = "GPRACE_DIAGNOSE_THREADS"
"""Environment variable: threads of the kernel's calls (default: the cores this process may use,
at most 2; 1 turns the threading off, as a benchmark running several diagnoses at once does)."""
MIN_CHUNK_STEPS = 20_000
"""Window-steps (windows x horizon x substeps) below which a call is not split: a thread's start
and hand-over cost about what 20,000 steps of the kernel do (~20 us)."""


@functools.cache
def _threads() -> int:
    raw = os.environ.get(THREADS_ENV, "")
    if raw.strip():
        try:
            return max(1, int(raw))
        except ValueError:
            from gprace.errors import ConfigError

            raise ConfigError(f"{THREADS_ENV}={raw!r}: expected a whole number of threads") from None
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(2, cores))


@functools.cache
def _pool(n: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=n, thread_name_prefix="gprace-kernel")


def _run_chunks(fn, lay, m, H, sub, dt, X0, k0, U, P, data, L, off, prof_args, out) -> None:
    """The kernel over the windows, split into contiguous chunks run on threads (ctypes releases
    the GIL; the driver keeps its work arrays on the stack, and every window is integrated on its
    own, so the result is bit for bit that of one call). Per-window arrays are cut by row; the
    profiles' per-window table rows (``prow``, profile-major: ``q * m + i``) are cut per profile."""
    dp, lp = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_long)
    pstride = 0 if len(P) == 1 else lay.np
    n = min(_threads(), max(1, (m * H * sub) // MIN_CHUNK_STEPS), m)
    *shared, prow = prof_args
    nprof = len(prow) // m if len(prow) >= m else 0

    def ptr(a, t=dp):
        return a.ctypes.data_as(t)

    def call(a: int, b: int) -> None:
        rows = np.ascontiguousarray(prow.reshape(nprof, m)[:, a:b]) if nprof else prow
        fn(b - a, H, sub, dt, ptr(X0[a:b]), ptr(k0[a:b], lp), ptr(U), len(U), ptr(P[a:b] if pstride else P),
           pstride, ptr(data.ks), ptr(data.kv), len(data.ks), ptr(L[a:b]), ptr(off[a:b]),
           *(ptr(x) if x.dtype == float else ptr(x, lp) for x in shared), ptr(rows, lp), ptr(out[a:b]))

    if n <= 1:
        call(0, m)
        return
    w = 4 * GROUPS  # chunks of whole 4-lane groups (the scalar kernel does not mind)
    edges = np.minimum(w * np.round(np.linspace(0, m, n + 1) / w).astype(int), m)
    edges[-1] = m
    list(_pool(n).map(lambda ab: call(*ab), zip(edges[:-1], edges[1:])))
