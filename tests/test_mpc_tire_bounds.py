"""The tracking MPC's input bounds from the tires (issue 37, stop 44): the steering near the front
tire's peak, drive and braking inside the plan's friction ellipse.

The nominal bicycle has neither a tire past its peak (where more steering gives no more force) nor
combined slip (where drive and braking take lateral grip). These tests show what the nominal QP
asks for in the states where the randomized cars were lost, and that the bounds stop it.
"""

from __future__ import annotations

import numpy as np
import pytest

from gprace.config import load_vehicle
from gprace.model import NominalModel
from gprace.model.dynamics import Input, State
from gprace.model.dynamics import peak_slip
from gprace.mpc.tracking import MPCSettings, TrackingMPC
from gprace.plan import curvature_plan
from gprace.tracks import load_track


@pytest.fixture(scope="module")
def circle():
    track = load_track("circle_100")
    model = NominalModel(load_vehicle("bmw_320i"))
    plan = curvature_plan(track, model, speed_scale=0.95)  # 9.85 m/s^2 of a 9.88 m/s^2 lateral limit
    X, U = plan.at_time(plan.time_at(np.array([50.0])))
    return track, model, plan, X[0], U[0]


def _commands(circle, state, settings, periods=1, delta_prev=None, a_prev=None):
    """The commands of ``periods`` MPC steps from the same measured ``state``."""
    track, model, plan, _, u_ref = circle
    mpc = TrackingMPC(model, track, plan, settings)
    mpc.reset(u_ref[Input.DELTA] if delta_prev is None else delta_prev, u_ref[Input.A_X] if a_prev is None else a_prev)
    return np.array([mpc.step(state)[0] for _ in range(periods)]), mpc


def _front_slip(model, state, delta):
    p = model.params
    return delta - np.arctan((state[State.V_Y] + p.lf * state[State.YAW_RATE]) / state[State.V_X])


def test_steering_stays_near_the_front_tires_peak(circle):
    """A car heading for the outer border: the nominal QP steers past the front tire's peak (1.6 of
    it), the bounded one stays within ``front_share`` of it. From full lock the wheel unwinds at
    the actuator's rate (the QP stays feasible)."""
    _, model, plan, x_ref, _ = circle
    p = model.params
    peak = peak_slip(p.bf, p.cf)
    x = x_ref.copy()
    x[[State.V_X, State.V_Y, State.YAW_RATE, State.E_PSI, State.E_Y]] = [20.0, 0.0, 0.0, -0.3, -4.0]
    free, _ = _commands(circle, x, MPCSettings(front_share=None, ellipse=None), periods=30)
    bounded, mpc = _commands(circle, x, MPCSettings(front_share=1.25, ellipse=None), periods=30)
    assert abs(_front_slip(model, x, free[-1, Input.DELTA])) > 1.4 * peak
    assert np.all(np.abs(_front_slip(model, x, bounded[:, Input.DELTA])) <= 1.25 * peak + 1e-6)
    # from full lock: back towards the peak at the rate limit, never further out
    lock = model.vehicle.limits.steering_max
    back, _ = _commands(circle, x, MPCSettings(), periods=5, delta_prev=lock)
    assert np.allclose(np.diff(np.r_[lock, back[:, Input.DELTA]]), -mpc.steer_step, atol=1e-6)


def test_drive_stays_inside_the_plans_friction_ellipse(circle):
    """At the lateral limit and 2 m/s behind the reference, the nominal QP asks for most of the
    drive limit to catch up (it knows no combined slip); inside the ellipse of the plan's limits
    it gets what the lateral acceleration leaves (``sqrt(1 - (a_y / a_lat)^2)`` of the limit)."""
    _, model, plan, x_ref, _ = circle
    lat, drive, brake = plan.meta["limits"]
    x = x_ref.copy()
    x[State.V_X] -= 2.0
    free, _ = _commands(circle, x, MPCSettings(ellipse=None))
    bounded, mpc = _commands(circle, x, MPCSettings(ellipse=1.0))
    room = np.sqrt(1.0 - (x[State.V_X] * x[State.YAW_RATE] / lat) ** 2)
    assert free[0, Input.A_X] > 0.75 * drive
    assert 0.0 < bounded[0, Input.A_X] <= room * drive + 1e-6 and room < 0.5
    # the range itself: the full limits when running straight, the floor (or what the reference
    # asks) at the lateral limit, the reference's own braking always
    lo, hi = np.array([-1.0, -brake]), np.array([1.0, drive])
    straight = x.copy()
    straight[State.YAW_RATE] = 0.0
    uref = np.zeros((mpc.N, 2))
    assert np.allclose(mpc.ellipse_bounds(straight, uref, lo, hi), (lo, hi))
    at_limit = x.copy()
    at_limit[State.YAW_RATE] = lat / x[State.V_X]
    uref[0, Input.A_X] = -0.5 * brake
    b_lo, b_hi = mpc.ellipse_bounds(at_limit, uref, lo, hi)
    assert np.isclose(b_hi[Input.A_X], 0.2 * drive) and np.isclose(b_lo[Input.A_X], -0.5 * brake)


def test_no_drive_beyond_the_reference_while_the_car_is_faster(circle):
    """A car faster than its reference gets no more drive than the reference asks anywhere on the
    horizon (none if it only brakes or coasts), never less than its braking bound; a slower car
    keeps the full range (issue 37, stop 58)."""
    from gprace.mpc.tracking import fast_drive_cap

    lo, hi = np.array([-0.5, -6.0]), np.array([0.5, 4.0])
    a_ref = np.array([-2.9, -2.5, 1.2])
    assert np.allclose(fast_drive_cap(12.0, 11.5, a_ref, lo, hi), [0.5, 1.2])
    assert np.allclose(fast_drive_cap(12.0, 11.5, -np.abs(a_ref), lo, hi), [0.5, 0.0])
    assert np.allclose(fast_drive_cap(11.0, 11.5, a_ref, lo, hi), hi)
    assert np.allclose(fast_drive_cap(12.0, 11.5, a_ref, np.array([-0.5, 2.0]), hi), [0.5, 2.0])
    _, model, plan, x_ref, _ = circle
    track = circle[0]
    for dv, held in ((1.0, True), (-1.0, False)):
        x = x_ref.copy()
        x[State.V_X] += dv
        pb, info = TrackingMPC(model, track, plan, MPCSettings()).build(x)
        free, _ = TrackingMPC(model, track, plan, MPCSettings(hold_drive_when_fast=False)).build(x)
        cap = max(float(info["uref"][:, Input.A_X].max()), 0.0)
        assert (pb.u_hi[Input.A_X] <= cap + 1e-12) == held
        assert free.u_hi[Input.A_X] > cap + 0.5


def test_the_nominal_model_alone_while_the_envelope_is_active(circle):
    """``use_gp = False`` (the drive loop sets it while the stability envelope is active): the QP
    of the period is the nominal MPC's, whatever the GP says; with it the GP's mean enters."""
    track, model, plan, x, _ = circle

    def gp(Z):  # a GP that says the car turns much less than the model
        return np.tile([0.0, -0.05], (len(Z), 1)), np.full((len(Z), 2), 1e-6)

    nominal = TrackingMPC(model, track, plan, MPCSettings()).build(x)[0]
    mpc = TrackingMPC(model, track, plan, MPCSettings(), gp=gp)
    assert not np.allclose(mpc.build(x)[0].c, nominal.c)
    mpc.use_gp = False
    assert np.allclose(mpc.build(x)[0].c, nominal.c)
    from gprace.mpc.stability import EnvelopeSettings

    assert EnvelopeSettings().nominal_when_active


def test_braking_headroom_sheds_a_speed_excess():
    """A car 2 m/s faster than its reference at the start of a braking zone planned at the limit
    (the nominal model as the plant, so the only error is the excess): held to the plan's own
    braking limit the MPC can never shed it (it grows as the car slows), with ``brake_headroom``
    beyond it the car gets back towards the reference (issue 37, stop 50)."""
    track = load_track("gprace_ring")
    model = NominalModel(load_vehicle("bmw_320i"))
    plan = curvature_plan(track, model, limits=(8.0, 3.5, 3.5))
    i = int(np.argmin(plan.a_x))
    while plan.a_x[i - 1] < -2.0:  # back to where the braking starts
        i -= 1
    X, U = plan.at_time(plan.time_at(np.array([plan.s[i]])))
    excess = {}
    for headroom in (0.0, 0.15):
        x = X[0].copy()
        x[State.V_X] += 2.0
        mpc = TrackingMPC(model, track, plan, MPCSettings(brake_headroom=headroom))
        mpc.reset(U[0][Input.DELTA], U[0][Input.A_X])
        for _ in range(50):
            x = model.rk4(x, mpc.step(x)[0], track.kappa, mpc.dt, 4)
        excess[headroom] = x[State.V_X] - np.interp(x[State.S], plan.s, plan.v_x)
    assert excess[0.0] > 1.9 and excess[0.15] < 1.2


def test_an_uncertain_gp_never_tightens_the_rear_slip_bound_below_the_reference(circle):
    """A tracking GP far from its data (a large variance) tightens the rear-slip rows; they are
    never tightened below the reference's own rear slip. Below it the rows break the reference
    and the QP turns the car off the line to meet them (issue 37, stop 51: a randomized BMW left
    the track on the inside of a 40 m/s corner). On the nominal plant with such a GP the car
    holds the circle at 0.95 of its lateral limit within 0.15 m."""
    from gprace.mpc.tracking import rear_slip_rows

    track, model, plan, x, u = circle

    def unsure(Z):  # no correction, and unsure of it
        return np.zeros((len(Z), 2)), np.full((len(Z), 2), 0.05)

    mpc = TrackingMPC(model, track, plan, MPCSettings(), gp=unsure)
    pb, info = mpc.build(x)
    G, lo, hi = pb.grip()
    at_ref = np.einsum("ki,ki->k", G, info["xref"])
    assert np.all(at_ref >= lo - 1e-9) and np.all(at_ref <= hi + 1e-9)
    a_ref = np.abs(rear_slip_rows(info["xref"], model.params.lr, model.params.vmin)[0])
    assert np.isclose(0.5 * (hi - lo).min(), a_ref.min(), rtol=0.05)  # tightened right down to the reference
    mpc.reset(u[Input.DELTA], u[Input.A_X])
    dev = []
    for _ in range(60):
        x = model.rk4(x, mpc.step(x)[0], track.kappa, mpc.dt, 4)
        dev.append(abs(x[State.E_Y] - np.interp(x[State.S] % track.length, plan.s, plan.e_y)))
    assert max(dev) < 0.15  # 0.32 m with the rows tightened to 0.3 of the bound, below the reference's 0.68


def test_the_linearisation_keeps_the_steering_gain_positive_past_the_front_peak(circle):
    """Along a warm start that steers past the nominal front tire's peak, the tangent of the tire
    says that more steering turns the car less (``B[r, delta] < 0``) and the QP then steers in to
    stop an over-rotation. The linearisation point's steering is held within ``LINEARISE_FRONT``
    of the peak slip, where the gain is positive (issue 37, stop 51: randomized_07's lap, with
    ``B[r, delta]`` from +0.62 to -0.08 along its warm start)."""
    from gprace.mpc.tracking import _at_s, front_heading

    track, model, plan, x, u = circle
    p = model.params
    mpc = TrackingMPC(model, track, plan, MPCSettings())
    pb, info = mpc.build(x)
    assert np.all(pb.B[:, State.YAW_RATE, Input.DELTA] > 0)
    kin = front_heading(info["xref"], p.lf, p.vmin)
    mpc.prev_x = np.vstack([x, _at_s(info["xref"][:-1], x[State.S])])
    mpc.prev_u = np.column_stack([kin + 2.0 * peak_slip(p.bf, p.cf), np.zeros(mpc.N)])
    pb, _ = mpc.build(x)
    assert np.all(pb.B[:, State.YAW_RATE, Input.DELTA] > 0)
    # the tangent there: the nominal model linearised at that steering turns the other way
    k0 = float(front_heading(x, p.lf, p.vmin)[0])
    B = model.jacobians(x, np.array([k0 + 2.0 * peak_slip(p.bf, p.cf), 0.0]), float(track.kappa(x[State.S])), mpc.dt)[1]
    assert B[State.YAW_RATE, Input.DELTA] < 0


def test_rear_within_clips_only_the_lateral_speed_of_states_past_the_bound():
    from gprace.mpc.tracking import rear_within

    p = NominalModel(load_vehicle("audi_tt_cup")).params
    rng = np.random.default_rng(5)
    X = np.column_stack([rng.uniform(0.5, 60, 400), rng.normal(0, 3, 400), rng.normal(0, 1, 400),
                         rng.normal(0, 0.2, (400, 3))])
    bound = 0.9 * peak_slip(p.br, p.cr)
    Y = rear_within(X, p, bound)

    def rear(Z):
        return -np.arctan((Z[:, State.V_Y] - p.lr * Z[:, State.YAW_RATE]) / np.maximum(Z[:, State.V_X], p.vmin))

    inside = np.abs(rear(X)) <= bound
    assert 0 < inside.sum() < len(X)
    assert np.all(np.abs(rear(Y)) <= bound + 1e-12)
    np.testing.assert_array_equal(Y[inside], X[inside])
    np.testing.assert_allclose(np.abs(rear(Y[~inside])), bound, rtol=1e-9)  # moved to the bound, not beyond
    assert np.all(np.sign(rear(Y[~inside])) == np.sign(rear(X[~inside])))
    np.testing.assert_array_equal(np.delete(Y, State.V_Y, axis=1), np.delete(X, State.V_Y, axis=1))
    # one bound per state (a sliding car's way back): each state within its own
    bounds = rng.uniform(0.5, 3.0, len(X)) * bound
    assert np.all(np.abs(rear(rear_within(X, p, bounds))) <= bounds + 1e-12)


def test_the_linearisation_does_not_follow_a_prediction_past_the_rear_peak(circle):
    """The linearisation point after its first step is the previous solution. Where that
    prediction carries the rear past the grip rows' bound, it is linearised at the bound: a warm
    start at 1.5, 3 or 6 times the rear peak gives the QP the dynamics of one at the bound (issue
    37, stop 62: predictions at up to 8 times the peak, linearised where they were, fed the next
    prediction and the car stalled in a hairpin); with ``grip = False`` (the paper's QP) it is
    linearised where the prediction is. A car sliding now keeps its slip on the way back that the
    grip rows allow (``RECOVER_STEPS``): without that, a shakedown that slid at a hairpin entry
    was lost on 4 of 7 noise draws."""
    from gprace.mpc.tracking import RECOVER_STEPS, _at_s

    track, model, plan, x, u = circle
    p = model.params
    bound = MPCSettings().grip_share * peak_slip(p.br, p.cr)

    def sliding(X, share):
        X = X.copy()
        X[..., State.V_Y] = p.lr * X[..., State.YAW_RATE] - np.tan(share * peak_slip(p.br, p.cr)) * X[..., State.V_X]
        return X

    def dynamics(share, grip=True, now=x):
        mpc = TrackingMPC(model, track, plan, MPCSettings(grip=grip))
        _, info = mpc.build(now)
        mpc.prev_x = np.vstack([now, sliding(_at_s(info["xref"][:-1], now[State.S]), share)])
        mpc.prev_u = np.tile(u, (mpc.N, 1))
        pb, _ = mpc.build(now)
        return pb.A, pb.B, pb.c

    at_bound = dynamics(MPCSettings().grip_share)
    for share in (1.5, 3.0, 6.0):
        for got, want in zip(dynamics(share), at_bound):
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
        assert not np.allclose(dynamics(share, grip=False)[0], dynamics(0.9, grip=False)[0])
    # sliding now at twice the peak: the steps on the way back keep the prediction's slip, the later ones do not
    now = sliding(x, 2.0)
    back = int(np.ceil(RECOVER_STEPS * (1.0 - bound / (2.0 * peak_slip(p.br, p.cr)))))
    A2, A1 = dynamics(2.0, now=now)[0], dynamics(MPCSettings().grip_share, now=now)[0]
    assert all(not np.allclose(A2[k], A1[k]) for k in range(1, back))
    np.testing.assert_allclose(A2[back:], A1[back:], rtol=1e-12, atol=1e-12)
