"""Time-trial learning pieces: feature sets, GP gradient, variance calibration and coverage,
spin samples left out, grip limits, the QP's grip rows, and iteration 0 on every shipped plant."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.errors import ConfigError, InputError

pytest.importorskip("gprace.gp")


def _run(X, U, t, completed=True):
    from gprace.io.runs import Run

    data = {"t": t, "s": X[:, 5], "e_y": X[:, 4], "e_psi": X[:, 3], "v_x": X[:, 0], "v_y": X[:, 1],
            "yaw_rate": X[:, 2], "delta": U[:, 0], "a_x": U[:, 1], "kappa": np.zeros(len(t))}
    return Run(data, {"completed": completed, "dt": float(t[1] - t[0])})


def test_feature_sets_produce_documented_columns():
    from gprace.gp.features import DYN_FEATURE_SETS, dyn_feature_set, dyn_inputs, dyn_set_of

    X = np.arange(12.0).reshape(2, 6)
    U = np.array([[0.1, -3.0], [0.2, 4.0]])
    assert DYN_FEATURE_SETS["paper"] == ("v_y", "yaw_rate", "delta")
    np.testing.assert_array_equal(dyn_inputs(X, U, dyn_feature_set("paper")), [[1, 2, 0.1], [7, 8, 0.2]])
    np.testing.assert_array_equal(dyn_inputs(X, U, dyn_feature_set("full")), [[0, 1, 2, 0.1, -3], [6, 7, 8, 0.2, 4]])
    assert dyn_set_of(["v_x", "v_y", "yaw_rate", "delta", "a_x"]) == "full"
    with pytest.raises(ConfigError, match="available: paper, full"):
        dyn_feature_set("magic")
    with pytest.raises(InputError, match="no known feature set"):
        dyn_set_of(["v_y"])


def test_mean_gradient_matches_finite_differences():
    from gprace.gp import make_gp

    rng = np.random.default_rng(1)
    Z = rng.normal(size=(150, 4)) * [1, 3, 0.1, 10]
    Y = np.column_stack([np.sin(Z[:, 0]) + Z[:, 2] * 5, Z[:, 1] * Z[:, 3] / 30])
    gp = make_gp("exact", optimize=False, length_scale=1.2, noise=1e-2, shared_kernel=True).fit(Z, Y)
    Q = rng.normal(size=(6, 4)) * [1, 3, 0.1, 10]
    mean, grad = gp.mean_gradient(Q)
    np.testing.assert_allclose(mean, gp.predict(Q)[0], atol=1e-12)
    h = 1e-5 * np.array([1, 3, 0.1, 10])
    fd = np.stack([(gp.predict(Q + h[j] * np.eye(4)[j])[0] - gp.predict(Q - h[j] * np.eye(4)[j])[0]) / (2 * h[j])
                   for j in range(4)], axis=-1)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-7)


def test_spectral_variance_bounds_the_exact_one():
    """The MPC's real-time variance never falls below the exact posterior variance, exceeds it by
    less than 1e-3 of the prior at the data (the bound of ExactGP._spectral), and a rough kernel
    (most eigenpairs needed) takes the exact path."""
    from gprace.gp import make_gp

    rng = np.random.default_rng(4)
    Z = rng.uniform(-3, 3, (400, 3))
    Y = np.column_stack([np.sin(Z[:, 0]) * np.cos(Z[:, 1]), 0.3 * Z[:, 2] ** 2]) + rng.normal(0, 0.05, (400, 2))
    Q = np.vstack([Z[:50], rng.uniform(-4, 4, (50, 3))])
    smooth = make_gp("exact", optimize=False, length_scale=2.5, noise=1e-2, shared_kernel=True).fit(Z, Y)
    ex = smooth.predict_with_gradient(Q, variance="exact")
    sp = smooth.predict_with_gradient(Q, variance="spectral")
    assert smooth._spectral(0).shape[1] < 100  # a smooth kernel: few eigenpairs
    np.testing.assert_allclose(sp[0], ex[0], atol=1e-12)  # same mean and gradient
    np.testing.assert_allclose(sp[2], ex[2], atol=1e-12)
    np.testing.assert_allclose(ex[1], smooth.predict(Q)[1], rtol=1e-9, atol=1e-14)
    prior = np.exp(smooth.hyper_.log_sf2) * smooth.hyper_.y_scale**2
    assert np.all(sp[1] >= ex[1] - 1e-12 * prior)
    assert np.all(sp[1][:50] - ex[1][:50] <= 1e-3 * prior)
    rough = make_gp("exact", optimize=False, length_scale=0.05, noise=1e-2, shared_kernel=True).fit(Z, Y)
    assert rough._spectral(0) is None
    np.testing.assert_allclose(rough.predict_with_gradient(Q)[1], rough.predict(Q)[1], rtol=1e-9, atol=1e-14)


def test_coverage_and_calibration_on_known_noise():
    """A GP with the right noise covers ~95 %; one told a tenth of the noise is recalibrated to it."""
    from gprace.gp import make_gp
    from gprace.timetrial.learning import GPPredictor, calibrate, coverage

    rng = np.random.default_rng(2)
    Z = rng.uniform(-2, 2, (600, 2))
    f = np.column_stack([np.sin(Z[:, 0]), np.cos(Z[:, 1])])
    sd = np.array([0.1, 0.05])
    Y = f + rng.normal(0, sd, f.shape)
    Zt = rng.uniform(-2, 2, (3000, 2))
    Yt = np.column_stack([np.sin(Zt[:, 0]), np.cos(Zt[:, 1])]) + rng.normal(0, sd, (3000, 2))
    honest = make_gp("exact", optimize=True, max_fit_points=300, seed=0).fit(Z, Y)
    cov = coverage(GPPredictor(honest, "tracking", inputs=("v_y", "yaw_rate")), Zt, Yt)
    assert np.all(np.abs(cov - 0.95) < 0.02), cov
    # overconfident: noise fixed at 1/100 of the true variance (in normalised units)
    tight = make_gp("exact", optimize=False, length_scale=1.0, noise=1e-4, signal_variance=1.0).fit(Z, Y)
    bad = coverage(GPPredictor(tight, "tracking", inputs=("v_y", "yaw_rate")), Zt, Yt)
    scale = calibrate(tight)
    fixed = coverage(GPPredictor(tight, "tracking", inputs=("v_y", "yaw_rate"), var_scale=scale), Zt, Yt)
    assert np.all(bad < 0.6) and np.all(scale > 10) and np.all(fixed > 0.9), (bad, scale, fixed)
    assert np.all(calibrate(honest) < 1.5)


def test_calibration_run_reveals_a_shift_the_own_data_cannot():
    """Fitted where the error is small, tested where it is three times larger: the leave-one-out
    scale stays near 1, a calibration run from the shifted region gives the variance ratio (~9
    on the noise, analytic) and restores the coverage of fresh shifted errors; a run of fewer than
    MIN_CALIB samples is ignored and the scale never falls below the leave-one-out one."""
    from gprace.gp import make_gp
    from gprace.timetrial.learning import MIN_CALIB, GPPredictor, calibrate, coverage

    rng = np.random.default_rng(5)
    f = lambda Z: np.column_stack([np.sin(Z[:, 0]), 0.5 * Z[:, 1]])  # noqa: E731
    Z = rng.uniform(-2, 2, (500, 2))
    gp = make_gp("exact", optimize=True, max_fit_points=300, seed=0).fit(Z, f(Z) + rng.normal(0, 0.05, (500, 2)))
    shifted = lambda n: (lambda Zs: (Zs, f(Zs) + rng.normal(0, 0.15, (n, 2))))(rng.uniform(-2, 2, (n, 2)))  # noqa: E731
    loo = calibrate(gp)
    cal = calibrate(gp, calib=shifted(800))
    inputs = ("v_y", "yaw_rate")
    test = shifted(4000)
    before = coverage(GPPredictor(gp, "tracking", inputs=inputs, var_scale=loo), *test)
    after = coverage(GPPredictor(gp, "tracking", inputs=inputs, var_scale=cal), *test)
    assert np.all(loo < 1.5) and np.all(np.abs(cal / 9.0 - 1) < 0.25), (loo, cal)
    assert np.all(before < 0.6) and np.all(np.abs(after - 0.95) < 0.02), (before, after)
    np.testing.assert_array_equal(calibrate(gp, calib=shifted(MIN_CALIB - 1)), loo)
    Zq = rng.uniform(-2, 2, (200, 2))
    np.testing.assert_array_equal(calibrate(gp, calib=(Zq, gp.predict(Zq)[0])), loo)  # errors of zero: the LOO scale stays


def test_spin_samples_and_the_loss_of_control_are_left_out():
    from gprace.config import load_vehicle
    from gprace.model import NominalModel
    from gprace.timetrial.learning import SPIN_HORIZON, features
    from gprace.tracks import load_track

    n, dt = 200, 0.05
    t = dt * np.arange(n)
    X = np.zeros((n, 6))
    X[:, 0] = 30.0
    X[:, 5] = 30.0 * t
    X[120:140, 1] = 15.0     # a spin in the middle: v_y half of v_x
    X[120:140, 2] = 2.0
    U = np.zeros((n, 2))
    m, tr = NominalModel(load_vehicle("audi_tt_cup")), load_track("circle_100")
    Z, _ = features(_run(X, U, t), m, tr, "tracking", "full")
    assert not np.any(np.abs(Z[:, 1]) > 5) and len(Z) == n - 1 - 20
    Zf, _ = features(_run(X, U, t, completed=False), m, tr, "tracking", "full")
    assert len(Zf) == len(Z) - int(round(SPIN_HORIZON / dt))  # the last second of a failed lap too


def test_grip_limits_widen_hold_and_back_off():
    from gprace.timetrial.grip import next_limits

    prev, cap = np.array([10.0, 4.0, 9.0]), np.array([14.0, 6.0, 14.0])
    np.testing.assert_allclose(next_limits(prev, [10.2, 4.0, 8.8], True, 0.4, cap, 0.05), [10.5, 4.2, 9.24])
    np.testing.assert_allclose(next_limits(prev, [10.0, 4.0, 9.0], True, 0.9, cap, 0.05), prev)       # near the peak slip: hold
    np.testing.assert_allclose(next_limits(prev, [10.0, 4.0, 9.0], True, 0.4, cap, 0.05, border_hits=1), prev)  # a border touched: hold
    np.testing.assert_allclose(next_limits(prev, [10.0, 1.0, 9.0], True, 0.4, cap, 0.05), [10.5, 4.2, 9.45])  # unused axis
    np.testing.assert_allclose(next_limits(prev, [np.nan] * 3, False, np.nan, cap, 0.05), 0.9 * prev)   # failed lap
    np.testing.assert_allclose(next_limits(prev * 2, prev * 2, True, 0.1, cap, 0.05), cap)
    # a level that lost the car earlier is not tried again: stay 5 % below it
    np.testing.assert_allclose(next_limits(prev, prev, True, 0.4, cap, 0.05, failed=[1.04 * prev]), 1.04 * 0.95 * prev)


def test_a_racing_lap_the_envelope_eased_holds_the_limits_it_was_driven_at():
    """``driven_limits``: a plan time-scaled by ``q`` asks ``q^2`` of its accelerations (checked on
    a curvature plan on a real circuit), so a racing lap that needed the envelope holds
    ``limits q^2``, not the plan's limits, and so does an exploration lap from ``EDGE_EVENTS``
    events on; exploration laps with fewer, laps without interventions and laps at full speed keep
    the plan's (issue 37, stops 56 and 60)."""
    from gprace.config import load_vehicle
    from gprace.model import NominalModel
    from gprace.plan import curvature_plan
    from gprace.timetrial.grip import EDGE_EVENTS, driven_limits, next_limits
    from gprace.timetrial.guard import time_scaled
    from gprace.tracks import load_track

    model = NominalModel(load_vehicle("bmw_320i"))
    plan = curvature_plan(load_track("gprace_ring"), model, ds=6.0, limits=(9.55, 3.0, 8.0))
    q = 0.97
    lat = lambda p: np.abs(p.v_x * p.yaw_rate).max()  # noqa: E731
    assert lat(time_scaled(plan, q)) == pytest.approx(q * q * lat(plan), rel=1e-12)
    assert np.abs(time_scaled(plan, q).a_x).max() == pytest.approx(q * q * np.abs(plan.a_x).max(), rel=1e-12)
    limits = np.array([9.55, 3.0, 8.0])
    for alpha, eased in ((0.0, 5), (0.0, 1), (0.857, EDGE_EVENTS)):
        np.testing.assert_allclose(driven_limits(limits, q, alpha, eased), q * q * limits)
    for step, alpha, eased in ((q, 0.857, EDGE_EVENTS - 1), (q, 0.0, 0), (1.0, 0.0, 5), (1.0, 0.857, 5)):
        np.testing.assert_allclose(driven_limits(limits, step, alpha, eased), limits)
    # held (the envelope intervened): the next limits are what the eased lap asked, below the plan's
    cap = np.full(3, 99.0)
    held = next_limits(driven_limits(limits, q, 0.0, 5), [9.78, 3.2, 8.1], True, 0.54, cap, interventions=5)
    np.testing.assert_allclose(held, q * q * limits)
    assert held[0] < limits[0]


def test_the_widening_asks_the_rear_tire_for_no_more_than_the_force_it_has_left():
    """``force_headroom``: at ``util`` of the peak slip angle a tire ``sin(C atan(B alpha))`` gives
    ``1 / (1 + headroom)`` of its peak force (analytic), none left at the peak, more far below it;
    ``next_limits`` with the tire's shape widens by at most that (issue 37, stop 51)."""
    from gprace.model.dynamics import peak_slip
    from gprace.timetrial.grip import force_headroom, next_limits

    B, C = 10.0, 1.35
    for util in (0.2, 0.5, 0.7, 0.95):
        force = np.sin(C * np.arctan(B * util * peak_slip(B, C)))
        assert force * (1.0 + force_headroom(util, C)) == pytest.approx(1.0)
    h = [force_headroom(u, C) for u in (0.3, 0.5, 0.7, 0.9)]
    assert all(np.diff(h) < 0) and force_headroom(1.0, C) == 0.0 and force_headroom(1.2, C) == 0.0
    assert force_headroom(0.7, C) < 0.02 < 0.05 < force_headroom(0.4, C)
    prev, cap = np.array([10.0, 4.0, 9.0]), np.full(3, 99.0)
    np.testing.assert_allclose(next_limits(prev, prev, True, 0.4, cap, 0.05, shape=C), 1.05 * prev)  # room left
    np.testing.assert_allclose(next_limits(prev, prev, True, 0.7, cap, 0.05, shape=C),
                               (1.0 + force_headroom(0.7, C)) * prev)


def test_grip_rows_agree_across_backends_and_bind():
    """An active rear-slip row: every backend returns the same solution, within its bound."""
    from gprace.backends import solvers
    from gprace.mpc.qp import LtvProblem, Weights

    N = 14
    rng = np.random.default_rng(3)
    A = np.tile(np.eye(6), (N, 1, 1)) + 0.01 * rng.normal(size=(N, 6, 6))
    B = np.zeros((N, 6, 2))
    B[:, 1, 0], B[:, 2, 0], B[:, 0, 1] = 30.0, 15.0, 0.05
    G = np.zeros((N, 6))
    G[:, 1], G[:, 2] = -1 / 30, 1.5 / 30
    x0 = np.array([30.0, -4.0, 0.5, 0, 0, 0])   # a car sliding at 0.16 rad of rear slip, and a
    xref = np.tile(x0, (N, 1))                 # reference that asks it to keep sliding
    A = np.tile(np.eye(6), (N, 1, 1)) + 0.001 * rng.normal(size=(N, 6, 6))
    pb = LtvProblem(A, B, np.zeros((N, 6)), x0, xref, np.zeros((N, 2)), np.full(N, -5.0), np.full(N, 5.0),
                    np.array([-0.35, -10.0]), np.array([0.35, 5.0]), 0.0, Weights(), G, np.full(N, -0.05), np.full(N, 0.05))
    res = {name: solvers.create(name, N, Weights()).solve(pb) for name in ("clarabel", "casadi", "cvxpy-clarabel")}
    free = solvers.create("clarabel", N, Weights()).solve(LtvProblem(*[getattr(pb, f) for f in (
        "A", "B", "c", "x0", "xref", "uref", "ey_lo", "ey_hi", "u_lo", "u_hi", "delta_prev")]))
    assert np.max(np.abs(np.einsum("ki,ki->k", G, free.x))) > 0.08        # without the row: past the bound
    held = np.abs(np.einsum("ki,ki->k", G, res["clarabel"].x))
    assert np.all(held[1:] < 0.0505) and held[0] < 0.08   # with it: within from the 2nd step (steering-rate cost)
    for k in ("casadi", "cvxpy-clarabel"):
        # the optimum and the steering agree; a_x is nearly free here (weight 0.02, small gain)
        assert abs(res[k].objective - res["clarabel"].objective) < 1e-5 * abs(res["clarabel"].objective)
        np.testing.assert_allclose(res[k].u[:, 0], res["clarabel"].u[:, 0], atol=1e-4)


def test_mpc_step_follows_the_curvature_through_a_kink():
    """The MPC's prediction step lets the curvature change with s inside the step: entering the
    S-bend of gprace_ring at 43 m/s its heading error after one period is within 1e-3 rad of a
    50-substep integration on the exact curvature; held constant (the paper's step) it is off by
    more than 1e-2 rad (0.3 rad/s of yaw rate the QP would command to follow the plan)."""
    from gprace.config import load_vehicle
    from gprace.model import NominalModel
    from gprace.mpc.tracking import KAPPA_DS, MPCSettings, TrackingMPC
    from gprace.plan import curvature_plan
    from gprace.tracks import load_track

    tr = load_track("gprace_ring")
    m = NominalModel(load_vehicle("audi_tt_cup"))
    mpc = TrackingMPC(m, tr, curvature_plan(tr, m), MPCSettings())
    x, u = np.array([43.0, 0.0, 0.0, 0.0, -4.0, 1252.0]), np.array([0.0, -3.0])
    X, U = np.tile(x, (mpc.N, 1)), np.tile(u, (mpc.N, 1))
    s = X[:, 5]
    slope = (tr.kappa(s + KAPPA_DS) - tr.kappa(s - KAPPA_DS)) / (2 * KAPPA_DS)
    xn = mpc._lin(X, U, np.column_stack([tr.kappa(s), slope, s]))[0][0]
    fine = m.rk4(x, u, tr.kappa, mpc.dt, substeps=50)
    held = m.rk4(x, u, float(tr.kappa(x[5])), mpc.dt)
    assert abs(xn[3] - fine[3]) < 1e-3 and abs(xn[4] - fine[4]) < 1e-3
    assert abs(held[3] - fine[3]) > 1e-2


def test_mpc_brings_a_sliding_car_back_within_the_slip_bound_gradually():
    """The tracking MPC's grip rows: a car past the bound gets RECOVER_STEPS periods to come back."""
    from gprace.config import load_vehicle
    from gprace.model import NominalModel
    from gprace.mpc.tracking import RECOVER_STEPS, MPCSettings, TrackingMPC, rear_slip_rows
    from gprace.plan import curvature_plan
    from gprace.tracks import load_track

    tr, m = load_track("circle_100"), NominalModel(load_vehicle("audi_tt_cup"))
    plan = curvature_plan(tr, m, speed_scale=0.7)
    mpc = TrackingMPC(m, tr, plan, MPCSettings())
    x = plan.states()[0].copy()
    x[1] -= 4.0                                   # a slide: rear slip far past 0.9 of the peak
    a0 = abs(rear_slip_rows(x[None], m.params.lr, m.params.vmin)[0][0])
    assert a0 > mpc.slip_max
    pb, _ = mpc.build(x)
    G, lo, hi = pb.grip()
    k = np.arange(1, mpc.N + 1)
    width = 0.5 * (hi - lo)                       # the bound's half width per step
    # no GP, so no tightening: the bound is the peak share, widened to a line back from the slide
    np.testing.assert_allclose(width, np.maximum(mpc.slip_max, a0 * (1 - k / RECOVER_STEPS)), rtol=1e-9)


@pytest.mark.parametrize("plant,vehicle,track,ds", [("audi_hidden", "audi_tt_cup", "gprace_ring", 6.0),
                                                    ("audi_nominal", "audi_tt_cup", "gprace_ring", 6.0),
                                                    ("bmw_commonroad", "bmw_320i", "gprace_ring", 6.0),
                                                    ("barc_nominal", "barc_1_10", "h2h_loop", 0.5)])
def test_iteration0_completes_on_every_shipped_plant(plant, vehicle, track, ds):
    """Iteration 0's conservative curvature plan, driven by the nominal MPC, completes a lap."""
    from gprace.config import load_plant, load_vehicle
    from gprace.model import NominalModel
    from gprace.plan import curvature_plan
    from gprace.timetrial.drive import drive
    from gprace.timetrial.iterate import IterateSettings
    from gprace.tracks import load_track

    tr, m = load_track(track), NominalModel(load_vehicle(vehicle))
    plan = curvature_plan(tr, m, ds=ds, speed_scale=IterateSettings().first_speed_scale)
    run = drive(plan, load_plant(plant), tr, m, seed=100)
    assert run.meta["completed"], run.meta["reason"]
    assert run.meta["lap_time"] < 1.1 * plan.lap_time


def test_bad_input_exits_2_before_anything_is_written(capsys, tmp_path):
    """Unknown feature set; a track the car cannot start on (narrower than the car): one line, exit 2."""
    from gprace.cli import main

    out = tmp_path / "it"
    assert main(["iterate", "--features", "magic", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "magic" in err[0] and "paper, full" in err[0]
    assert main(["eval", "timetrial", "--features", "magic", "--out", str(out)]) == 2
    capsys.readouterr()
    narrow = tmp_path / "narrow.toml"
    narrow.write_text('name = "narrow"\nclosed = true\nwidth = 1.0\n\n[[segments]]\ntype = "arc"\nradius = 100.0\nangle_deg = 360.0\n')
    assert main(["iterate", "--track", str(narrow), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("narrower" in err[0] or "start" in err[0]), err
    assert not out.exists()


def test_eval_timetrial_runs_both_variants_and_resumes(capsys, tmp_path):
    """A tiny comparison: both variants' folders, the table, a resumed rerun that redoes nothing."""
    import json

    from gprace.cli import main

    out = tmp_path / "tt"
    args = ["eval", "timetrial", "--plant", "audi_nominal", "--track", "circle_100", "--trials", "1", "--iterations", "1",
            "--dictionary-size", "100", "--workers", "1", "--out", str(out), "--json"]
    assert main(args) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res["variants"]) == {"exploration", "double_gp"}
    for name, rows in res["variants"].items():
        assert [r["iteration"] for r in rows] == [0, 1]
        assert json.loads((out / name / "settings.json").read_text())["selection"] == ("diverse" if name == "exploration" else "random")
    # the same seeds: iteration 0 is the same lap in both variants
    assert res["variants"]["exploration"][0]["driven_mean"] == res["variants"]["double_gp"][0]["driven_mean"]
    assert res["oracle"]["known"] and (out / "double_gp" / "oracle.json").exists()
    stamp = (out / "double_gp" / "trial_0" / "iter_01" / "run.h5").stat().st_mtime_ns
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["variants"] == res["variants"]
    assert (out / "double_gp" / "trial_0" / "iter_01" / "run.h5").stat().st_mtime_ns == stamp
    # the report draws both variants side by side (Double GP shows as the random-selection baseline)
    from gprace.report.collect import scan
    from gprace.report.sections.timetrial import timetrial_variants

    names = {v["name"] for v in timetrial_variants(scan(out)).values()}
    assert names == {"exploration", "baseline"}
    page = tmp_path / "report.html"
    assert main(["report", str(out), "--out", str(page)]) == 0
    html = page.read_text()
    assert 'data-section="timetrial"' in html and "only one iterate folder" not in html


def test_oracle_is_unknown_for_commonroad():
    from gprace.timetrial.iterate import IterateSettings, oracle_lap

    res = oracle_lap(IterateSettings(plant="bmw_commonroad", vehicle="bmw_320i"))
    assert res["known"] is False and "commonroad" in res["why"] and "driven" not in res


def test_trial_modules_are_preloaded_only_for_forked_workers(monkeypatch):
    """Issue 37: the parent imports what every trial process would import, when the workers are
    forked (they inherit it); with spawned workers it would be work for nothing and is skipped."""
    import importlib
    import importlib.util
    import multiprocessing

    from gprace.timetrial import learning as L

    assert all(importlib.util.find_spec(name) is not None for name in L.TRIAL_MODULES)
    imported = []
    monkeypatch.setattr(importlib, "import_module", imported.append)
    monkeypatch.setattr(multiprocessing, "get_start_method", lambda allow_none=False: "spawn")
    assert L.preload_trial_modules() is False and imported == []
    monkeypatch.setattr(multiprocessing, "get_start_method", lambda allow_none=False: "fork")
    assert L.preload_trial_modules() is True and imported == list(L.TRIAL_MODULES)


def test_novelty_is_small_on_the_data_and_large_off_it():
    """The tracking GP's novelty (predictive std over noise std) is near 1 where it was trained and
    beyond the guard's threshold far from it; under the stability envelope only there does the
    nominal model replace it."""
    from gprace.gp import make_gp
    from gprace.model.dynamics import State
    from gprace.timetrial.drive import _novel
    from gprace.timetrial.guard import NOVEL_STD
    from gprace.timetrial.learning import GPPredictor

    rng = np.random.default_rng(3)
    Z = rng.uniform(-2, 2, (400, 2))
    Y = np.column_stack([np.sin(Z[:, 0]), np.cos(Z[:, 1])]) + rng.normal(0, 0.1, (400, 2))
    gp = GPPredictor(make_gp("exact", optimize=True, max_fit_points=300, seed=0).fit(Z, Y), "tracking",
                     inputs=("v_y", "yaw_rate"))
    X = np.zeros((2, 6))
    X[:, State.V_X] = 20.0
    X[0, [State.V_Y, State.YAW_RATE]] = [0.5, -0.3]  # inside the data
    X[1, [State.V_Y, State.YAW_RATE]] = [9.0, 9.0]   # far outside
    z, e = gp.novelty(X, np.zeros((2, 2))), gp.extrapolation(X, np.zeros((2, 2)))
    assert z[0] < 1.5 and z[1] > NOVEL_STD and e[0] < 0.3 and e[1] > 0.99, (z, e)
    assert not _novel(gp, X[0], np.zeros(2)) and _novel(gp, X[1], np.zeros(2)) and _novel(None, X[0], np.zeros(2))
    # a GP whose signal is hardly above its noise: its novelty stays below the threshold even far
    # from the data, its extrapolation still reaches 1 there (the randomized_09 spin, issue 37)
    weak = GPPredictor(make_gp("exact", optimize=False, length_scale=1.0, noise=0.5, signal_variance=0.7).fit(Z, Y),
                       "tracking", inputs=("v_y", "yaw_rate"))
    assert weak.novelty(X, np.zeros((2, 2)))[1] < NOVEL_STD and weak.extrapolation(X, np.zeros((2, 2)))[1] > 0.99
    assert _novel(weak, X[1], np.zeros(2)) and not _novel(weak, X[0], np.zeros(2))
