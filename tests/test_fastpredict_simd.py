"""The 4-lane prediction kernel (issue 36, stop 48): its derivative is emitted from the CasADi
function's instructions and its transcendentals come from libmvec (a few ulp from libm), so it
must give the scalar kernel's predictions to rounding, and the numpy reference's, for every kind
of model the diagnosis builds; where it cannot run, or is switched off, the scalar kernel runs."""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from shared_data import TUM_TRACKS

from gprace.diagnose import core, fastpredict as fp
from gprace.diagnose.synth import record
from gprace.io.runs import Run
from gprace.model import EFFECTS


@pytest.fixture(scope="module")
def setup(audi):
    """The Audi on 0.6 laps of Norisring, where the 4-lane kernel and a compiler exist."""
    from gprace.compiled import compiler
    from gprace.tracks.loaders import load_track

    if not TUM_TRACKS.exists() or compiler() is None or not fp.simd_available():
        pytest.skip("needs the TUM circuits, a C compiler and an AVX2/FMA x86-64 Linux (libmvec)")
    track = load_track(TUM_TRACKS / "Norisring.csv")
    return audi, track, record(audi, track, [], laps=0.6, seed=4, substeps=5)


def _data(run: Run, mode: str, laps: bool = True):
    d = {k: v.copy() for k, v in run.data.items()}
    d["v_cmd"] = d["v_x"] + 0.5 * d["a_x"]
    kinds = {"force": {}, "kinematic": {"a_x": "measured"}, "speed": {"a_x": "derived", "v_cmd": "commanded"}}[mode]
    meta = {**run.meta, "inputs": {"delta": "commanded", **kinds}}
    if not laps:  # a recording without lap structure: s runs on, the curvature is not wrapped
        L = meta.pop("track_length")
        d["s"] = d["s"] + L * np.concatenate([[0], np.cumsum(np.diff(d["s"]) < -0.5 * L)])
    data = core.build_dataset([Run(d, meta, "x")])
    assert np.isfinite(data.L).all() == laps
    return data


def _states(model, data, starts, X0, kind: str, sub: int = 2):
    """The kernel's states with the 4-lane kernel (``simd``) or the scalar one."""
    orig = fp._simd_kernel
    if kind == "scalar":
        fp._simd_kernel = lambda *a: None
    try:
        return fp.predict_states(model, data, starts, 15, sub, X0, core._OFFSET)
    finally:
        fp._simd_kernel = orig


def _random_cases(m: int, L: float, rng):
    """Every kind of model the diagnosis builds, with random parameters (per window where the
    fits batch them): longitudinal kinds, lags in both orders, every stateless effect of the
    catalogue, catalogue profiles (periodic and open) and the fitting device's batched profile."""
    from gprace.diagnose import profiles as pf

    u = lambda lo, hi: rng.uniform(lo, hi)  # noqa: E731
    kn = np.linspace(0.0, L, 40, endpoint=False)
    basis = pf.Basis(L, 48, 6)
    stateless = [
        EFFECTS["aero_drag"](c_d=u(0.1, 0.6)), EFFECTS["rolling_resistance"](c_rr=u(0.005, 0.03)),
        EFFECTS["road_grade"](angle=u(-0.05, 0.05), s_start=u(0, 200), s_end=u(300, 600)),
        EFFECTS["downforce"](c_l=rng.uniform(0.0, 3.0, m)), EFFECTS["load_transfer"](cog_height=u(0.2, 0.6)),
        EFFECTS["tire_load_sensitivity"](k=u(0.0, 0.3)), EFFECTS["tire_friction"](front=u(0.8, 1.2), rear=u(0.8, 1.2)),
        EFFECTS["cornering_stiffness"](front=u(0.7, 1.3), rear=u(0.7, 1.3)),
        EFFECTS["friction_patch"](factor=u(0.6, 1.0), s_start=u(0, 200), s_end=u(300, 600)),
        EFFECTS["combined_slip"](k=rng.uniform(0.1, 1.0, m)),
        EFFECTS["road_bank"](angle=u(-0.1, 0.1), s_start=u(0, 200), s_end=u(300, 600)),
        EFFECTS["steering_offset"](offset=u(-0.01, 0.01)), EFFECTS["yaw_inertia"](factor=u(0.7, 1.4)),
    ]
    return [
        ("force", []),
        ("kinematic", []),
        ("speed", []),
        ("force", stateless),
        ("kinematic", [EFFECTS["steering_lag"](tau=u(0.02, 0.2)), *stateless[3:8]]),
        ("speed", [EFFECTS["drivetrain_lag"](tau=u(0.1, 0.4)), EFFECTS["steering_lag"](tau=u(0.02, 0.2)),
                   *stateless[8:], EFFECTS["gyro_bias"](bias=u(-0.02, 0.02))]),
        ("force", [EFFECTS["road_bank_profile"](knots=list(kn), values=list(0.08 * np.sin(kn / 150.0)), lap_length=L),
                   EFFECTS["friction_profile"](knots=[100.0, 400.0, 700.0], values=[0.9, 1.2, 0.7], lap_length=0.0),
                   EFFECTS["steering_lag"](tau=u(0.02, 0.2)), EFFECTS["downforce"](c_l=u(0, 3))]),
        ("kinematic", [pf.batched_effect("road_grade_profile", basis, 0.02 * rng.standard_normal((3, basis.K)),
                                         np.arange(m) % 3),
                       pf.batched_effect("road_bank_profile", basis, 0.03 * rng.standard_normal((2, basis.K)),
                                         np.arange(m) % 2)]),
    ]


@pytest.mark.parametrize("laps", [True, False])
def test_four_lanes_give_the_scalar_kernel_and_numpy(setup, laps):
    """Random windows (their count not a multiple of 4: the last group is padded), random and
    per-window parameters, every model kind: the 4-lane states equal the scalar kernel's to 1e-12
    of each channel's size, and both the numpy reference's to 1e-10; a window starting from NaN
    stays NaN in every kernel and leaves its neighbours in the same vector untouched."""
    audi, track, run = setup
    rng = np.random.default_rng(11 if laps else 12)
    base = _data(run, "force", laps)
    starts = np.sort(rng.choice(base.windows(15), 37, replace=False))
    m = len(starts)
    for mode, effects in _random_cases(m, float(track.length), rng):
        data = _data(run, mode, laps)
        model = core.model_for(audi, data, effects)
        assert fp.plan(model) is not None, (mode, [e.name for e in effects])
        Z = core.lag_states(model, data) if model.nx > 6 else np.zeros((data.n, 0))
        X0 = core.initial_states(model, data.Y[starts], Z[starts])
        X0[5, 1] = np.nan  # one window of the second 4-lane group
        scalar = _states(model, data, starts, X0, "scalar")
        simd = _states(model, data, starts, X0, "simd")
        ok = np.arange(m) != 5
        assert np.isnan(scalar[5]).any() and np.array_equal(np.isnan(scalar), np.isnan(simd)), mode
        size = np.abs(scalar[ok]).max(axis=(0, 1))
        np.testing.assert_allclose(simd[ok] / size, scalar[ok] / size, rtol=0, atol=1e-12, err_msg=mode)
        try:
            core.COMPILED = False
            ref = core.predict(model, data, starts, 15, 2)
        finally:
            core.COMPILED = True
        got = core.predict(model, data, starts, 15, 2)  # measured channels, the 4-lane kernel
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12, err_msg=mode)


def test_switched_off_the_scalar_kernel_runs(setup, monkeypatch):
    """``GPRACE_DIAGNOSE_SIMD=0``: the predictions are the scalar kernel's bit for bit (the 4-lane
    kernel is not built); a value other than 0 or 1 is a one-line configuration error."""
    from gprace.errors import ConfigError

    audi, track, run = setup
    data = _data(run, "force")
    starts = data.windows(15)[::5]
    model = core.model_for(audi, data, [EFFECTS["steering_lag"](tau=0.08)])
    Z0 = core.lag_states(model, data)[starts]
    scalar = _states(model, data, starts, core.initial_states(model, data.Y[starts], Z0), "scalar")
    fp.simd_available.cache_clear(), fp._simd_kernel.cache_clear()
    try:
        monkeypatch.setenv(fp.SIMD_ENV, "0")
        assert not fp.simd_available()
        off = fp.predict_states(model, data, starts, 15, 2, core.initial_states(model, data.Y[starts], Z0),
                                core._OFFSET)
        assert np.array_equal(off, scalar)
        fp.simd_available.cache_clear()
        monkeypatch.setenv(fp.SIMD_ENV, "yes")
        with pytest.raises(ConfigError, match=fp.SIMD_ENV):
            fp.simd_available()
    finally:
        fp.simd_available.cache_clear(), fp._simd_kernel.cache_clear()


def test_emitter_follows_casadi_on_every_operation_it_knows(setup):
    """Each operation of the emitter's table, evaluated on 4 lanes by the emitted C, against
    CasADi's own evaluation of the same function, on random arguments with NaN, infinities, zeros
    and ties (comparisons, fmin/fmax and if_else where C's and CasADi's NaN rules matter)."""
    import casadi as ca

    from gprace.compiled import compiled_source

    a, b = ca.SX.sym("a", 2), ca.SX.sym("b", 2)
    x, y = a[0], b[0]
    pos = ca.fabs(x) + 0.5
    outs = [x + y, x - y, x * y, x / y, -x, x ** 2, 2 * x, 1 / y, ca.sqrt(pos), ca.fabs(x), ca.fmin(x, y),
            ca.fmax(x, y), x < y, x <= y, x == y, x != y, ca.logic_not(x), ca.logic_and(x, y), ca.logic_or(x, y),
            ca.if_else(x < y, ca.sin(x), ca.cos(y)), ca.tan(x / 4), ca.atan(x), ca.asin(x / 4),
            ca.acos(y / 4), ca.exp(x / 4), ca.log(pos), ca.tanh(x), ca.sinh(x / 4), ca.cosh(y / 4),
            ca.atan2(x, y), ca.power(pos, y / 4), a[1] * 1e300 * b[1], ca.if_else(y > 0, a[1], b[1]), 3.5 + 0 * x]
    F = ca.Function("f", [a, b, ca.SX.sym("c", 1), ca.SX.sym("d", 1)], [ca.vertcat(*outs)])
    n = len(outs)
    src = fp._VEC_HEAD_C + fp.emit_vector(F) + (
        "int eval4(const double *A, const double *B, double *R) {\n"
        "    v4d a[2], b[2], c[1] = {{0}}, d[1] = {{0}}, r[%d];\n"
        "    for (int l = 0; l < 4; l++) for (int q = 0; q < 2; q++) { a[q][l] = A[2 * l + q]; b[q][l] = B[2 * l + q]; }\n"
        "    gprace_deriv4(a, b, c, d, r);\n"
        "    for (int l = 0; l < 4; l++) for (int q = 0; q < %d; q++) R[%d * l + q] = r[q][l];\n"
        "    return 0;\n}\n") % (n, n, n)
    lib = compiled_source("test_emitter_ops", src, fp.SIMD_FLAGS, "emitter test", libs=("-lmvec",))
    assert lib is not None
    fn = ctypes.CDLL(str(lib)).eval4
    dp = ctypes.POINTER(ctypes.c_double)
    fn.argtypes, fn.restype = [dp, dp, dp], ctypes.c_int
    rng = np.random.default_rng(3)
    special = [np.nan, np.inf, -np.inf, 0.0, -0.0, 1.0, 2.0]
    vals = np.concatenate([rng.uniform(-3, 3, 200), special])
    A = np.column_stack([rng.choice(vals, 400), rng.choice(vals, 400)])
    B = np.column_stack([rng.choice(vals, 400), rng.choice(vals, 400)])
    A[:20, 0] = B[:20, 0]  # ties
    for g in range(0, 400, 4):
        a4, b4 = np.ascontiguousarray(A[g:g + 4]), np.ascontiguousarray(B[g:g + 4])
        R = np.empty((4, n))
        fn(a4.ctypes.data_as(dp), b4.ctypes.data_as(dp), R.ctypes.data_as(dp))
        for lane in range(4):
            ref = np.asarray(F(a4[lane], b4[lane], 0.0, 0.0)).ravel()
            np.testing.assert_allclose(R[lane], ref, rtol=1e-14, atol=0, equal_nan=True,
                                       err_msg=f"{a4[lane]}, {b4[lane]}")


def test_a_failed_four_lane_build_falls_back_to_the_scalar_kernel(setup, monkeypatch):
    """A 4-lane build that fails (here: a compiler that cannot link libmvec) leaves the scalar
    kernel running with the same predictions, and no other variant is tried in the process."""
    from gprace import compiled

    audi, track, run = setup
    data = _data(run, "kinematic")
    starts = data.windows(15)[::9]
    model = core.model_for(audi, data, [EFFECTS["yaw_inertia"](factor=1.1)])
    X0 = core.initial_states(model, data.Y[starts], np.zeros((len(starts), 0)))
    scalar = _states(model, data, starts, X0, "scalar")
    real = compiled.compiled_source
    tried = []

    def broken(name, source, flags, what, libs=(), fallback=""):
        if libs:
            tried.append(name)
            return None  # what _compiled returns when the build fails (after its warning)
        return real(name, source, flags, what, libs, fallback)

    monkeypatch.setattr(compiled, "compiled_source", broken)
    fp._simd_kernel.cache_clear()
    monkeypatch.setattr(fp, "_SIMD_FAILED", [])
    try:
        got = fp.predict_states(model, data, starts, 15, 2, X0, core._OFFSET)
        assert np.array_equal(got, scalar) and len(tried) == 1
        other = core.model_for(audi, data, [EFFECTS["downforce"](c_l=1.0)])
        assert fp.predict_states(other, data, starts, 15, 2, X0, core._OFFSET) is not None
        assert len(tried) == 1  # not tried again
    finally:
        fp._simd_kernel.cache_clear()
