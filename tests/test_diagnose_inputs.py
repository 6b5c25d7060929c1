"""Issue 36 (diagnose part): the envelope on the car's scale, inputs as the log has them,
calibration before naming, the compiled predictions and the linearised cross-validation.

Recordings come from the frenet plant (gprace.diagnose.synth) on a TUM circuit for the full-size
car and on the shipped 36 m loop for a 1:10 car; what the test changes in them (a spin, a
standstill, a measured acceleration, a speed command) is built from the plant's own states.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gprace.config import EffectConfig, NoiseConfig, load_vehicle
from gprace.diagnose import core
from gprace.diagnose.synth import DEFAULT_NOISE, record
from gprace.io.envelope import envelope
from gprace.io.runs import Run
from gprace.model import EFFECTS, NominalModel

TRACKS = Path("/work/shared/data/tumftm-racetrack-database/tracks")
pytestmark = pytest.mark.skipif(not TRACKS.exists(), reason="TUM racetrack database not available")
CLEAN = NoiseConfig()


@pytest.fixture(scope="module")
def audi():
    return load_vehicle("audi_tt_cup")


@pytest.fixture(scope="module")
def norisring():
    from gprace.tracks.loaders import load_track

    return load_track(TRACKS / "Norisring.csv")


_CACHE: dict = {}


def _rec(vehicle, track, effects=(), seed=3, laps=1.5, noise=DEFAULT_NOISE, **kw) -> Run:
    key = (vehicle.name, track.name, repr(effects), seed, laps, repr(noise), tuple(sorted(kw.items())))
    if key not in _CACHE:
        _CACHE[key] = record(vehicle, track, list(effects), laps=laps, seed=seed, noise=noise, substeps=5, **kw)
    return _CACHE[key]


# ------------------------------------------------------------------------------------------
# the envelope on the car's scale


def _with_events(r: Run) -> tuple[dict, dict]:
    """The recording with, in the car's own terms: the first 2 s standing (5 % of its speed),
    a spin (body slip 40 deg for 1 s) at 60 % of it, and one spike of the v_y estimate at 30 %."""
    d = {k: v.copy() for k, v in r.data.items()}
    n, dt = r.n, r.dt
    stand = int(2.0 / dt)
    d["v_x"][:stand] = 0.05 * np.median(r["v_x"])
    i = int(0.6 * n)
    spin = slice(i, i + int(1.0 / dt))
    d["v_y"][spin] = np.tan(0.7) * d["v_x"][spin]
    j = int(0.3 * n)
    d["v_y"][j] = 0.6 * d["v_x"][j]  # one sample: an estimator's spike, not a spin
    return d, {"stand": stand, "spin": spin, "spike": j}


def _froude(d: dict, lam: float) -> dict:
    """The drive at a scale ``lam``, dynamically similar (Froude): lengths x lam, times and speeds
    x sqrt(lam), rates and curvature / lam^(1/2) and / lam, angles and accelerations unchanged."""
    q = np.sqrt(lam)
    out = dict(d)
    for c in ("s", "e_y"):
        out[c] = d[c] * lam
    for c in ("t",):
        out[c] = d[c] * q
    for c in ("v_x", "v_y"):
        out[c] = d[c] * q
    out["yaw_rate"] = d["yaw_rate"] / q
    out["kappa"] = d["kappa"] / lam
    return out


def test_envelope_judges_a_1_10_and_a_full_size_car_alike(audi, norisring):
    """One drive with a standstill, a spin and a spike of the v_y estimate, at full size (2.5 m
    wheelbase, ~28 m/s) and Froude-scaled to 1:10 (0.3 m, like the INI F1TENTH car, ~10 m/s):
    the same samples are cut, for the same reasons, and the spike is no spin."""
    r = _rec(audi, norisring, laps=1.0)
    d, ev = _with_events(r)
    lam = 0.307 / audi.wheelbase
    small = _froude(d, lam)
    assert 5.0 < np.median(small["v_x"]) < 12.0 and np.median(d["v_x"]) > 15.0
    res = {}
    for label, data, wb in (("full size", d, audi.wheelbase), ("1:10", small, audi.wheelbase * lam)):
        keep, rep = envelope(data, label, wb)
        assert [e.reason for e in rep.excluded] == ["standstill", "spin"], rep.note()
        assert keep[ev["spike"]]  # one sample: an estimator's spike, not a spin
        stand, spin = rep.excluded
        assert stand.first == 0 and ev["stand"] <= stand.last + 1
        assert spin.first <= ev["spin"].start and spin.last >= ev["spin"].stop - 1
        assert 0.02 < rep.standstill_speed / np.median(data["v_x"]) < 0.3
        assert rep.moving_kept_share > 0.9
        res[label] = keep
        # ordinary driving is inside the envelope at either scale
        clean = _froude(r.data, lam) if label == "1:10" else r.data
        assert envelope(clean, label, wb)[0].all()
    np.testing.assert_array_equal(res["full size"], res["1:10"])
    # judged with full-size seconds and speeds, the small car would lose its drive
    keep_fixed, _ = envelope({**small, "v_x": small["v_x"]}, "fixed", None)
    assert keep_fixed.sum() <= res["1:10"].sum()


def test_no_moving_sample_is_one_line_and_exit_2(audi, norisring, tmp_path, capsys):
    from gprace.cli import main
    from gprace.io.runs import write_run

    r = _rec(audi, norisring, laps=0.4)
    d = {k: v.copy() for k, v in r.data.items()}
    rng = np.random.default_rng(0)
    d["v_x"] = 0.01 * rng.standard_normal(r.n)
    d["v_y"] = 0.01 * rng.standard_normal(r.n)
    d["yaw_rate"] = 0.001 * rng.standard_normal(r.n)
    d["s"] = np.full(r.n, 100.0) + 0.01 * rng.standard_normal(r.n)
    write_run(Run(d, dict(r.meta), "parked"), tmp_path / "parked.h5")
    assert main(["-q", "diagnose", str(tmp_path / "parked.h5"), "--vehicle", "audi_tt_cup"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no moving sample" in err


# ------------------------------------------------------------------------------------------
# inputs as the log has them


def _measured_ax(vehicle, r_clean: Run, hidden) -> np.ndarray:
    """What an accelerometer reads on the plant with the ``hidden`` effects: dv_x/dt - r v_y."""
    m = NominalModel(vehicle, hidden)
    X = r_clean.states()
    xdot = m.f(np.hstack([X, m.initial_state(X, r_clean.inputs())[:, 6:]]), r_clean.inputs(), r_clean["kappa"])
    return xdot[:, 0] - X[:, 2] * X[:, 1]


def _noisy(r: Run, noise: NoiseConfig, seed: int = 1) -> dict:
    rng = np.random.default_rng(seed)
    d = {k: v.copy() for k, v in r.data.items()}
    for c in ("v_x", "v_y", "yaw_rate", "e_psi", "e_y", "s"):
        d[c] = d[c] + getattr(noise, c) * rng.standard_normal(r.n)
    return d


def test_measured_a_x_explains_v_x_kinematically(audi, norisring):
    """The plant hides extra drag; its accelerometer's a_x already holds it, so the kinematic
    model predicts v_x to the noise and the diagnosis neither names nor calibrates a drag."""
    from gprace.diagnose.diagnose import diagnose

    hidden = [EffectConfig(name="aero_drag", params={"c_d": 0.3})]
    clean = _rec(audi, norisring, hidden, noise=CLEAN, laps=1.6)
    d = _noisy(clean, DEFAULT_NOISE)
    d["a_x"] = _measured_ax(audi, clean, hidden) + 0.05 * np.random.default_rng(2).standard_normal(clean.n)
    run = Run(d, {**clean.meta, "inputs": {"delta": "commanded", "a_x": "measured"}}, "imu")
    data = core.build_dataset([run])
    assert data.longitudinal == "kinematic"
    starts = data.windows(15)
    err = {}
    for mode in ("kinematic", "force"):
        m = NominalModel(audi, (), mode)
        if mode == "force":  # the same a_x read as a command: drag subtracted a second time
            data.longitudinal = "force"
        E = core.errors(data, starts, core.predict(m, data, starts, 15, 1))
        err[mode] = float(np.sqrt(np.mean(E[:, -1, 0] ** 2)))
    data.longitudinal = "kinematic"
    assert err["kinematic"] < 0.3 * err["force"]
    rep = diagnose([run], audi).report
    assert rep["inputs"]["longitudinal"] == "kinematic" and rep["inputs"]["a_x"] == "measured"
    assert {"aero_drag", "rolling_resistance", "drivetrain_lag"} <= {t["effect"] for t in rep["inputs"]["not_testable"]}
    assert "aero_drag" not in {e["name"] for e in rep["effects"]}
    params = {p["name"] for p in (rep["calibration"] or {}).get("parameters", [])}
    assert not params & {"drag_coefficient", "rolling_resistance"}
    vx = next(c for c in rep["channels"] if c["name"] == "v_x")
    assert not vx["structured"]


def test_speed_command_drives_a_first_order_loop_whose_tau_is_calibrated(audi, norisring):
    """A car whose own controller follows a speed command with tau 0.2 s (the nominal file says
    0.5 s): the calibration finds the loop (rate 5 /s, authority 5 /s, i.e. gain 1)."""
    from gprace.diagnose.diagnose import diagnose

    clean = _rec(audi, norisring, noise=CLEAN, laps=1.6, seed=5)
    tau = 0.2
    d = _noisy(clean, DEFAULT_NOISE, seed=3)
    d["v_cmd"] = clean["v_x"] + tau * clean["a_x"]  # exactly what makes (v_cmd - v_x)/tau the a_x
    d["a_x"] = np.gradient(d["v_x"], clean["t"])  # derived, as an importer would
    run = Run(d, {**clean.meta, "inputs": {"delta": "commanded", "a_x": "derived", "v_cmd": "commanded"}}, "vcmd")
    res = diagnose([run], audi)
    rep = res.report
    assert rep["inputs"]["longitudinal"] == "speed"
    assert next(c for c in rep["channels"] if c["name"] == "v_x")["structured"]  # nominal 0.5 s: too slow
    assert rep["calibration"]["applied"]
    # noisy initial speeds are pulled back to the truth faster by a slightly faster loop, which
    # the multi-step error rewards: tau within a fifth, the gain within a tenth
    assert abs(res.vehicle.speed_loop_tau - tau) < 0.2 * tau, res.vehicle.speed_loop_tau
    assert abs(res.vehicle.speed_loop_gain - 1.0) < 0.1, res.vehicle.speed_loop_gain


# ------------------------------------------------------------------------------------------
# calibration before naming


def test_calibration_recovers_a_hidden_cornering_stiffness_and_steering_offset(audi, norisring):
    """Near the linear range (a_y below 40 % of the grip): the rear cornering stiffness (x1.25)
    and the steering offset (4 mrad) are identified and recovered, the front stiffness stays; the
    peak friction, which the data barely see there, is not found changed."""
    from gprace.diagnose.diagnose import diagnose

    hidden = [EffectConfig(name="cornering_stiffness", params={"rear": 1.25}),
              EffectConfig(name="steering_offset", params={"offset": 0.004})]
    r = _rec(audi, norisring, hidden, laps=2.0, seed=7, speed_scale=0.3)
    ay = np.abs(r["v_x"] * r["yaw_rate"])
    assert np.quantile(ay, 0.99) < 0.4 * audi.mu * 9.81
    rep = diagnose([r], audi).report
    c = rep["calibration"]
    assert c["applied"] and rep["effects"] == []
    got = {q["name"]: q for q in c["parameters"]}
    rear, front = got["cornering_stiffness_rear"], got["cornering_stiffness_front"]
    assert rear["unit"] == "N/rad" and rear["changed"] and not front["changed"]
    assert abs(rear["value"] / rear["nominal"] - 1.25) < 0.03, rear
    assert abs(front["value"] / front["nominal"] - 1.0) < 0.03, front
    off = got["steering_offset"]
    assert abs(off["value"] - 0.004) < 0.0005 and off["changed"]
    assert not got.get("peak_friction", {}).get("changed", False)
    from gprace.diagnose.result import parse_result

    found = parse_result(rep, "t").findings()
    assert set(found) == {"cornering_stiffness", "steering_offset"}
    assert abs(found["cornering_stiffness"]["rear"] - 1.25) < 0.03


def test_calibration_leaves_a_null_alone(audi, norisring):
    """Nothing hidden: the nominal model leaves no structured error and nothing is calibrated."""
    from gprace.diagnose.diagnose import diagnose

    rep = diagnose([_rec(audi, norisring, laps=1.6, seed=11)], audi).report
    assert rep["verdict"] == "no_significant_mismatch"
    assert not rep["calibration"]["applied"] and rep["calibration"]["parameters"] == []


# ------------------------------------------------------------------------------------------
# compiled predictions and linearised cross-validation


def test_compiled_predictions_equal_the_numpy_model(audi, norisring):
    """The universal compiled function (all catalogue effects, lags, per-window parameters,
    sensor effects, the three longitudinal inputs) gives the numpy model's predictions."""
    from gprace.backends.compiled import compiler

    if compiler() is None:
        pytest.skip("no C compiler")
    from gprace.diagnose import profiles as pf

    r = _rec(audi, norisring, laps=0.6)
    starts = core.build_dataset([r]).windows(15)[::7]
    m = len(starts)
    L = float(norisring.length)
    kn = np.linspace(0.0, L, 40, endpoint=False)
    basis, rng = pf.Basis(L, 48, 6), np.random.default_rng(5)
    cases = [
        ("force", []),
        ("force", [EFFECTS["downforce"](c_l=2.0), EFFECTS["road_bank"](angle=0.05, s_start=200.0, s_end=400.0),
                   EFFECTS["gyro_bias"](bias=0.01)]),
        ("kinematic", [EFFECTS["steering_lag"](tau=0.08), EFFECTS["combined_slip"](k=np.linspace(0.1, 1.0, m))]),
        ("speed", [EFFECTS["drivetrain_lag"](tau=0.2), EFFECTS["steering_lag"](tau=0.05),
                   EFFECTS["yaw_inertia"](factor=1.2), EFFECTS["road_grade"](angle=0.03, s_start=50.0, s_end=300.0)]),
        # lags in the other order than the catalogue's (the naming adds them as found): states permuted
        ("speed", [EFFECTS["steering_lag"](tau=0.12), EFFECTS["drivetrain_lag"](tau=0.3)]),
        # profiles: periodic over the lap, open (end values held), and the fitting device of
        # gprace.diagnose.profiles with one row of knot values per window set
        ("force", [EFFECTS["road_bank_profile"](knots=list(kn), values=list(0.08 * np.sin(kn / 150.0)),
                                                lap_length=L),
                   EFFECTS["friction_profile"](knots=[100.0, 400.0, 700.0], values=[0.9, 1.2, 0.7], lap_length=0.0),
                   EFFECTS["steering_lag"](tau=0.06)]),
        ("kinematic", [pf.batched_effect("road_grade_profile", basis, 0.02 * rng.standard_normal((3, basis.K)),
                                         np.arange(m) % 3)]),
    ]
    for mode, effects in cases:
        d = {k: v.copy() for k, v in r.data.items()}
        d["v_cmd"] = d["v_x"] + 0.5 * d["a_x"]
        kinds = {"force": {}, "kinematic": {"a_x": "measured"}, "speed": {"a_x": "derived", "v_cmd": "commanded"}}[mode]
        data = core.build_dataset([Run(d, {**r.meta, "inputs": {"delta": "commanded", **kinds}}, "x")])
        model = core.model_for(audi, data, effects)
        try:
            core.COMPILED = False
            ref = core.predict(model, data, starts, 15, 2)
        finally:
            core.COMPILED = True
        from gprace.diagnose.fastpredict import plan

        assert plan(model) is not None
        got = core.predict(model, data, starts, 15, 2)
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)


def test_linearised_fold_refit_is_exact_for_a_linear_parameter(audi, norisring):
    """A gyro bias enters the measured yaw rate linearly: one Gauss-Newton step from the full
    fit IS the refit without the fold, so the linearised cross-validation equals refitting by
    iterations to convergence."""
    from gprace.diagnose import crossval, diagnose as dg, name as nm

    r = _rec(audi, norisring, [EffectConfig(name="gyro_bias", params={"bias": 0.02})], laps=1.6, seed=13)
    p = dg.prepare([r], 15, audi.wheelbase)
    s = dg.screen(p, audi, 0)
    ctx = dg._context(p, audi, s)
    f = nm.fit_effect(ctx.prob, "gyro_bias", ctx.fit_w, [{"bias": 0.0}], max_nfev=30)
    assert abs(f.x[0] - 0.02) < 0.002
    lin = crossval.cv_losses(ctx.prob, [crossval.effect_block(f, p.data)], ctx.eval_w, ctx.fold)
    ref = np.empty_like(lin)
    for fo in np.unique(ctx.fold):
        te = ctx.fold == fo
        sub = ctx.eval_w[::max(1, len(ctx.eval_w) // crossval.FIT_WINDOWS)]
        g = nm.refit(ctx.prob, f, sub[ctx.fold[::max(1, len(ctx.eval_w) // crossval.FIT_WINDOWS)] != fo], max_nfev=50)
        ref[te] = np.mean(ctx.prob.residuals(ctx.prob.model([g.effect()]), ctx.eval_w[te]) ** 2, axis=1)
    np.testing.assert_allclose(lin.mean(axis=0), ref.mean(axis=0), rtol=1e-4)


def test_calibration_bounds_stay_inside_what_a_car_can_have(audi):
    """The stated ranges (inertia x0.2..5, mu x0.5..2) meet what VehicleConfig refuses: a radius of
    gyration beyond half the car's diagonal, a mu above 3. The bounds stop there, so a calibrated
    vehicle at any bound still loads (before, a heavy-ended car's inertia x5 or slicks' mu x2
    made the augmented vehicle itself invalid)."""
    from gprace.diagnose import calibrate as cal

    k_max = 0.5 * np.hypot(audi.length, audi.width)
    veh = audi.model_copy(update={"yaw_inertia": audi.mass * (0.9 * k_max) ** 2, "mu": 1.7})
    params = [cal.BY_NAME["yaw_inertia"], cal.BY_NAME["peak_friction"]]
    lo, hi = cal.bounds(veh, params, 30.0)
    for z in (lo, hi):
        v = cal.values(veh, params, z)
        assert audi.mass * (0.1 * audi.wheelbase) ** 2 <= v["yaw_inertia"] <= audi.mass * k_max**2
        assert 0.05 <= v["peak_friction"] <= 3.0
        cal.with_values(veh, v)  # validates: no ValueError
    v_hi = cal.values(veh, params, hi)
    assert v_hi["yaw_inertia"] == pytest.approx(audi.mass * k_max**2, rel=1e-6)  # x1.23 here, not x5
    assert v_hi["peak_friction"] == pytest.approx(3.0, rel=1e-6)  # not 3.4
    # a car far from the limits keeps its stated ranges
    lo0, hi0 = cal.bounds(audi, [cal.BY_NAME["steering_offset"]], 30.0)
    assert (lo0[0], hi0[0]) == (-0.1, 0.1)


def test_calibration_intervals_never_collapse(audi, norisring):
    """Two ways an interval used to be of zero width: (a) a few windows whose open-loop prediction
    diverges (a 1e-8 change of a stiffness moves it by noise floors) dominate the fit's Jacobian;
    they are left out of the covariance, and the intervals stay those of the smooth windows; (b) a
    parameter pressed against a bound gets a one-sided interval from the bound inwards, not
    [bound, bound]."""
    from dataclasses import replace as dc_replace

    from gprace.diagnose import calibrate as cal, diagnose as dg

    hidden = [EffectConfig(name="cornering_stiffness", params={"rear": 1.25})]
    r = _rec(audi, norisring, hidden, laps=1.6, seed=7, speed_scale=0.3)
    p = dg.prepare([r], 15, audi.wheelbase)
    s = dg.screen(p, audi, 0)
    ctx = dg._context(p, audi, s)
    params = [cal.BY_NAME[n] for n in ("cornering_stiffness_front", "cornering_stiffness_rear", "steering_offset")]
    lo, hi = cal.bounds(audi, params, cal.v_top(p.data))
    x0 = cal.start(audi, params)
    f = cal.covariance(ctx.prob, cal.fit(ctx.prob, params, x0, lo, hi, ctx.fit_w), lo, hi)
    assert f.windows_used > 0.98 and not f.at_bound.any()
    sd = f.sd()
    assert np.all(sd > 0) and abs(np.exp(f.x[1]) - 1.25) < 0.05
    # (a) five windows whose finite-difference response exploded
    per = ctx.prob.H * 3
    bad = np.zeros(len(f.win), bool)
    bad[[3, 50, 120, 200, 333]] = True
    jac = f.jac.copy()
    jac[np.repeat(bad, per)] *= 1e8
    g = cal.covariance(ctx.prob, dc_replace(f, jac=jac), lo, hi)
    assert g.windows_used < f.windows_used and not cal.smooth_windows(ctx.prob, dc_replace(f, jac=jac), lo, hi)[bad].any()
    assert np.all(np.abs(g.sd() / sd - 1.0) < 0.3), (g.sd(), sd)
    # (b) the rear stiffness capped below its true factor: at the bound, one-sided interval
    hi_b = hi.copy()
    hi_b[1] = np.log(1.1)
    fb = cal.covariance(ctx.prob, cal.fit(ctx.prob, params, x0, lo, hi_b, ctx.fit_w), lo, hi_b)
    assert fb.at_bound[1]
    rep = {q["name"]: q for q in fb.report(audi)}["cornering_stiffness_rear"]
    lo95, hi95 = rep["ci95"]
    assert rep["at_bound"] and hi95 == pytest.approx(1.1 * rep["nominal"], rel=1e-6) and lo95 < hi95 - 1e-6 * hi95
