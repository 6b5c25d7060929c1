"""The nominal model and the effect catalogue: discretisation order, derivatives, steady states,
and the physics of each effect (channels it touches and how it scales)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import fsolve

from gprace.config import G, EffectConfig
from gprace.model import EFFECTS, STATE, NominalModel, make_effect

X0 = np.array([25.0, 0.6, 0.3, 0.05, 0.4, 120.0])  # a generic cornering state with side slip
U0 = np.array([0.04, -2.0])
K0 = 0.01


def test_rk4_converges_at_fourth_order(audi):
    m = NominalModel(audi)
    kfun = lambda s: 0.01 + 0.004 * np.sin(s / 20.0)  # curvature varying along s
    T = 0.8
    ref = m.rk4(X0, U0, kfun, T, substeps=1024)
    errs = [np.max(np.abs(m.rk4(X0, U0, kfun, T, substeps=n) - ref)) for n in (8, 16, 32)]
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    assert all(12.0 < r < 20.0 for r in ratios), (errs, ratios)
    # Euler, for contrast, is first order
    e1 = [np.max(np.abs(_euler_n(m, kfun, T, n) - ref)) for n in (64, 128)]
    assert 1.7 < e1[0] / e1[1] < 2.3


@pytest.mark.parametrize("with_effects", [False, True])
def test_casadi_rk4_expression_agrees_with_numpy_rk4(audi, with_effects):
    """The symbolic RK4 (plants and NMPCs; built from the model's cached ``f``) and the numpy RK4
    are the same scheme: curvature re-evaluated at each stage's s, with effect states as well."""
    import casadi as ca

    extra = [EffectConfig(name="downforce", params={"c_l": 1.5}), EffectConfig(name="steering_lag", params={"tau": 0.05})] \
        if with_effects else []
    m = NominalModel(audi, extra)
    x = ca.SX.sym("x", m.nx)
    u = ca.SX.sym("u", 2)
    step = ca.Function("step", [x, u], [m.rk4_expression(x, u, lambda s: 0.01 + 0.004 * ca.sin(s / 20.0), 0.2, 3)])
    x0 = m.initial_state(X0, U0)
    want = m.rk4(x0, U0, lambda s: 0.01 + 0.004 * np.sin(s / 20.0), 0.2, substeps=3)
    got = np.asarray(step(x0, U0)).ravel()
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(got - x0)) > 0.1  # the step moved the car (the check is not vacuous)


def _euler_n(m, kfun, T, n):
    x = X0.copy()
    for _ in range(n):
        x = m.euler(x, U0, kfun(x[5]), T / n)
    return x


@pytest.mark.parametrize("with_effects", [False, True])
def test_casadi_jacobian_matches_finite_differences(audi, with_effects):
    extra = [EffectConfig(name="downforce", params={"c_l": 1.5}), EffectConfig(name="load_transfer", params={"cog_height": 0.5}),
             EffectConfig(name="combined_slip"), EffectConfig(name="steering_lag", params={"tau": 0.05})] if with_effects else []
    m = NominalModel(audi, extra)
    x = m.initial_state(X0, U0) + (0.01 if with_effects else 0.0) * np.r_[np.zeros(6), np.ones(m.nx - 6)]
    dt = 0.05
    A, B = m.jacobians(x, U0, K0, dt)
    assert A.shape == (m.nx, m.nx) and B.shape == (m.nx, 2)
    Afd = np.empty_like(A)
    Bfd = np.empty_like(B)
    for j in range(m.nx):
        h = 1e-6 * max(1.0, abs(x[j]))
        e = np.zeros(m.nx)
        e[j] = h
        Afd[:, j] = (m.euler(x + e, U0, K0, dt) - m.euler(x - e, U0, K0, dt)) / (2 * h)
    for j in range(2):
        h = 1e-6 * max(1.0, abs(U0[j]))
        e = np.zeros(2)
        e[j] = h
        Bfd[:, j] = (m.euler(x, U0 + e, K0, dt) - m.euler(x, U0 - e, K0, dt)) / (2 * h)
    np.testing.assert_allclose(A, Afd, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(B, Bfd, rtol=1e-6, atol=1e-7)


def test_numpy_and_casadi_faces_are_one_model(audi):
    m = NominalModel(audi, [EffectConfig(name="road_grade", params={"angle": 0.05, "s_start": 100.0, "s_end": 200.0})])
    rng = np.random.default_rng(0)
    X = X0 + rng.normal(0, [3, 0.3, 0.1, 0.03, 1.0, 40.0], size=(50, 6))
    U = U0 + rng.normal(0, [0.02, 2.0], size=(50, 2))
    k = rng.normal(0, 0.01, size=50)
    F = m.f(X, U, k)
    f = m.casadi_f()
    Fc = np.array([np.asarray(f(X[i], U[i], k[i])).ravel() for i in range(50)])
    np.testing.assert_allclose(F, Fc, rtol=1e-12, atol=1e-12)
    # the CasADi RK4 step equals the numpy one when curvature is constant
    np.testing.assert_allclose(np.asarray(m.casadi_rk4(0.05, 4)(X0, U0, K0)).ravel(), m.rk4(X0, U0, K0, 0.05, 4), rtol=1e-12)


def test_centre_line_of_an_arc_at_constant_speed_stays_at_zero_offset(audi):
    """Steady cornering on an arc (a_y = 6 m/s^2, tires in their non-linear range).

    On the centre line the velocity must be tangent, so the heading error is the side-slip angle
    ``e_psi = -atan(v_y / v_x)``; at path speed ``V`` the yaw rate is ``V kappa``. Solve the force
    balance ``f[:3] = 0`` for ``(v_x, v_y, delta, a_x)`` with ``|v| = V``, then drive 10 s.
    """
    m = NominalModel(audi)
    R, V = 80.0, 22.0
    kappa = 1.0 / R

    def state(vx, vy):
        return np.array([vx, vy, V * kappa, -np.arctan2(vy, vx), 0.0, 0.0])

    def res(z):
        vx, vy, delta, ax = z
        f = m.f(state(vx, vy), np.array([delta, ax]), kappa)
        return [f[0], f[1], f[2], np.hypot(vx, vy) - V]

    vx, vy, delta, ax = fsolve(res, [V, 0.0, 2.5 * kappa, 0.0], xtol=1e-14)
    assert np.max(np.abs(res([vx, vy, delta, ax]))) < 1e-9
    assert abs(vy) > 0.05  # a real side slip, not a trivial case
    x = state(vx, vy)
    T = 10.0
    xT = m.rk4(x, np.array([delta, ax]), kappa, T, substeps=400)
    assert abs(xT[4]) < 1e-6  # e_y stays 0
    np.testing.assert_allclose(xT[:4], x[:4], atol=1e-8)
    assert xT[5] == pytest.approx(V * T, rel=1e-9)  # s advances at the path speed


# --------------------------------------------------------------------------------------------
# effects: channels and physics

CHANNELS = {
    "aero_drag": ("v_x",), "rolling_resistance": ("v_x",), "downforce": ("v_y", "yaw_rate"),
    "road_grade": ("v_x",), "road_bank": ("v_y",), "load_transfer": ("v_y", "yaw_rate"),
    "tire_load_sensitivity": ("v_y", "yaw_rate"), "combined_slip": ("v_y", "yaw_rate"),
    "tire_friction": ("v_y", "yaw_rate"), "cornering_stiffness": ("v_y", "yaw_rate"),
    "steering_lag": ("v_y", "yaw_rate"), "steering_offset": ("v_y", "yaw_rate"),
    "drivetrain_lag": ("v_x",), "yaw_inertia": ("yaw_rate",), "friction_patch": ("v_y", "yaw_rate"),
    "gyro_bias": ("yaw_rate",), "velocity_misalignment": ("v_y",),
    # issue 36: the same physics as the windows, varying along the lap
    "road_bank_profile": ("v_y",), "road_grade_profile": ("v_x",), "friction_profile": ("v_y", "yaw_rate"),
}  # DESIGN.md section 3

PARAMS = {
    "aero_drag": {"c_d": 0.3}, "rolling_resistance": {"c_rr": 0.02}, "downforce": {"c_l": 2.0},
    "road_grade": {"angle": 0.05, "s_start": 100.0, "s_end": 140.0},
    "road_bank": {"angle": 0.05, "s_start": 100.0, "s_end": 140.0}, "load_transfer": {"cog_height": 0.5},
    "tire_load_sensitivity": {"k": 0.2}, "combined_slip": {"k": 1.0}, "tire_friction": {"front": 0.9, "rear": 0.85},
    "cornering_stiffness": {"front": 1.2, "rear": 0.8}, "steering_lag": {"tau": 0.05},
    "steering_offset": {"offset": 0.01}, "drivetrain_lag": {"tau": 0.2}, "yaw_inertia": {"factor": 1.5},
    "friction_patch": {"factor": 0.7, "s_start": 100.0, "s_end": 140.0}, "gyro_bias": {"bias": 0.02},
    "velocity_misalignment": {"angle": 0.01},
    "road_bank_profile": {"knots": [0.0, 100.0, 150.0], "values": [0.0, 0.05, 0.02], "lap_length": 200.0},
    "road_grade_profile": {"knots": [0.0, 100.0, 150.0], "values": [0.0, 0.05, -0.05], "lap_length": 200.0},
    "friction_profile": {"knots": [0.0, 100.0, 150.0], "values": [1.0, 0.7, 0.9], "lap_length": 200.0},
}

# near-zero steering so that lateral forces leak into v_x only through F_yf sin(delta) ~ 1 %
XC = np.array([25.0, 0.6, 0.3, 0.05, 0.4, 120.0])
UC = np.array([0.005, -3.0])


def test_catalogue_is_the_designed_one():
    assert set(EFFECTS) == set(CHANNELS)


@pytest.mark.parametrize("name", sorted(CHANNELS))
def test_each_effect_changes_exactly_its_channels(audi, name):
    nom = NominalModel(audi)
    eff = NominalModel(audi, [EffectConfig(name=name, params=PARAMS[name])])
    x = eff.initial_state(XC, UC)
    if eff.nx > 6:  # actuator lags: the actuator has not reached the command yet
        x[6:] += {"steering_lag": 0.01, "drivetrain_lag": 1.5}[name]
    d = eff.f(x, UC, K0)[:6] - nom.f(XC, UC, K0)
    ym = eff.measure(x)[0] - nom.measure(XC)[0]
    listed = [STATE.index(c) for c in CHANNELS[name]]
    others = [i for i in range(6) if i not in listed]
    if name == "gyro_bias":  # a sensor effect: dynamics untouched, only the measured yaw rate
        np.testing.assert_array_equal(d, 0.0)
        assert ym[2] == pytest.approx(0.02) and np.all(ym[[0, 1, 3, 4, 5]] == 0.0)
        return
    if name == "velocity_misalignment":  # the velocities turned by 0.01 rad; v_x barely moves
        np.testing.assert_array_equal(d, 0.0)
        assert ym[1] == pytest.approx(XC[0] * np.sin(0.01) + XC[1] * (np.cos(0.01) - 1.0))
        assert abs(ym[0]) < 0.05 * abs(ym[1]) and np.all(ym[[2, 3, 4, 5]] == 0.0)
        return
    np.testing.assert_array_equal(ym, 0.0)  # only sensor effects touch the measurement
    big = np.max(np.abs(d[listed]))
    for i in listed:
        assert abs(d[i]) > 1e-4 * max(big, 1e-12) and abs(d[i]) > 1e-6, (name, STATE[i], d)
    for i in others:
        tol = 0.0 if STATE[i] in ("e_psi", "e_y", "s") else 0.02 * big
        assert abs(d[i]) <= tol, (name, STATE[i], d)


def test_aero_drag_force_quadruples_when_speed_doubles(audi):
    nom = NominalModel(audi)
    eff = NominalModel(audi, [EffectConfig(name="aero_drag", params={"c_d": 0.3})])
    u = np.array([0.0, 0.0])
    drag = []
    for v in (20.0, 40.0):
        x = np.array([v, 0.0, 0.0, 0.0, 0.0, 0.0])
        drag.append(-(eff.f(x, u, 0.0)[0] - nom.f(x, u, 0.0)[0]) * audi.mass)
    assert drag[0] == pytest.approx(0.3 * 20.0**2, rel=1e-12)
    assert drag[1] / drag[0] == pytest.approx(4.0, rel=1e-12)


def _axle_forces(m, x, u, kappa):
    """Solve the (delta = 0) force balance for F_yf, F_yr from v_y' and r'."""
    f = m.f(x, u, kappa)
    p = m.params
    lat = p.m * (f[1] + x[2] * x[0])
    yaw = f[2] * p.iz
    A = np.array([[1.0, 1.0], [p.lf, -p.lr]])
    return np.linalg.solve(A, [lat, yaw])


def test_downforce_raises_lateral_force_in_proportion_to_axle_load(audi):
    c_l, bal = 2.0, 0.4
    nom = NominalModel(audi)
    eff = NominalModel(audi, [EffectConfig(name="downforce", params={"c_l": c_l, "balance": bal})])
    x = np.array([40.0, 0.8, 0.2, 0.0, 0.0, 0.0])
    u = np.array([0.0, 0.0])
    f0, r0 = _axle_forces(nom, x, u, 0.0)
    f1, r1 = _axle_forces(eff, x, u, 0.0)
    p = nom.params
    assert abs(f1) > abs(f0) and abs(r1) > abs(r0)
    assert f1 / f0 == pytest.approx(1 + bal * c_l * 40.0**2 / p.fz_front, rel=1e-9)
    assert r1 / r0 == pytest.approx(1 + (1 - bal) * c_l * 40.0**2 / p.fz_rear, rel=1e-9)


def test_road_grade_acts_only_inside_its_window(audi):
    angle = 0.05
    nom = NominalModel(audi)
    eff = NominalModel(audi, [EffectConfig(name="road_grade", params={"angle": angle, "s_start": 100.0, "s_end": 300.0})])
    u = np.array([0.0, 1.0])
    s = np.array([0.0, 50.0, 200.0, 350.0, 1000.0])
    X = np.column_stack([np.full(5, 20.0), np.zeros((5, 4)), s])
    dvx = eff.f(X, u, 0.0)[:, 0] - nom.f(X, u, 0.0)[:, 0]
    np.testing.assert_allclose(dvx[[0, 1, 3, 4]], 0.0, atol=1e-12)
    assert dvx[2] == pytest.approx(-G * np.sin(angle), rel=1e-9)


def test_steering_lag_with_vanishing_time_constant_is_the_nominal_model(audi):
    nom = NominalModel(audi)
    u = np.array([0.03, 0.5])
    x0 = np.array([20.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    ref = nom.rk4(x0, u, 0.0, 1.0, substeps=2000)
    dev = {}
    for tau in (1e-3, 0.1):
        m = NominalModel(audi, [EffectConfig(name="steering_lag", params={"tau": tau})])
        x = m.initial_state(x0, np.array([0.0, 0.5]))  # actuator starts at 0, command is a step
        xT = m.rk4(x, u, 0.0, 1.0, substeps=2000)
        dev[tau] = np.max(np.abs(xT[:6] - ref)[[1, 2, 3, 4]])
    # the gap is O(tau): 100 times smaller tau, about 100 times smaller gap
    assert 50.0 < dev[0.1] / dev[1e-3] < 200.0
    assert dev[1e-3] < 1e-2


def test_yaw_inertia_factor_two_halves_yaw_acceleration(audi):
    nom = NominalModel(audi)
    eff = NominalModel(audi, [EffectConfig(name="yaw_inertia", params={"factor": 2.0})])
    r0 = nom.f(XC, UC, K0)
    r1 = eff.f(XC, UC, K0)
    assert r1[2] == pytest.approx(0.5 * r0[2], rel=1e-12)
    np.testing.assert_array_equal(np.delete(r1, 2), np.delete(r0, 2))


def test_effect_parameters_are_checked():
    from gprace.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown effect 'dwnforce'"):
        make_effect("dwnforce")
    with pytest.raises(ConfigError, match="c_x"):
        make_effect("downforce", c_l=1.0, c_x=2.0)
    with pytest.raises(ConfigError, match="required"):
        make_effect("aero_drag")
    with pytest.raises(ConfigError, match="outside"):
        make_effect("yaw_inertia", factor=50.0)


def test_named_state_indices_pick_the_kinematic_equations(audi):
    """``State``/``Input`` name the entries of :data:`STATE`/:data:`INPUT`, and indexing the model's
    derivative by them gives the Frenet kinematics: ``s' = (v_x cos e_psi - v_y sin e_psi) /
    (1 - kappa e_y)``, ``e_y' = v_x sin e_psi + v_y cos e_psi``, ``e_psi' = r - kappa s'``."""
    from gprace.model import INPUT, Input, State

    assert [m.name.lower() for m in State] == list(STATE) and [m.name.lower() for m in Input] == list(INPUT)
    f = NominalModel(audi).f(X0, U0, K0)
    vx, vy, r, epsi, ey = (X0[i] for i in (State.V_X, State.V_Y, State.YAW_RATE, State.E_PSI, State.E_Y))
    sdot = (vx * np.cos(epsi) - vy * np.sin(epsi)) / (1 - K0 * ey)
    assert f[State.S] == pytest.approx(sdot, rel=1e-12)
    assert f[State.E_Y] == pytest.approx(vx * np.sin(epsi) + vy * np.cos(epsi), rel=1e-12)
    assert f[State.E_PSI] == pytest.approx(r - K0 * sdot, rel=1e-12)
