"""The tracking GP's gradient at the yaw-stability edge (issue 37, stop 49): the rules of
``TrackingMPC._compensate`` on constructed GPs."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.config import load_vehicle
from gprace.model import NominalModel
from gprace.model.dynamics import Input, State
from gprace.mpc.tracking import (GP_STATES, MPCSettings, TrackingMPC, spectral_radius2, stable_share, steer_share,
                                trust_share)
from gprace.plan import curvature_plan
from gprace.tracks import load_track


@pytest.fixture(scope="module")
def circle():
    tr = load_track("circle_100")
    m = NominalModel(load_vehicle("audi_tt_cup"))
    return tr, m, curvature_plan(tr, m)


class _GradientGP:
    """A tracking GP with a fixed mean and gradient (feature set "full")."""

    inputs = ("v_x", "v_y", "yaw_rate", "delta", "a_x")

    def __init__(self, J: np.ndarray, mean=(0.01, -0.02)) -> None:
        self.J, self.mean = np.asarray(J, float), np.asarray(mean, float)

    def at_with_gradient(self, X, U):
        n = len(X)
        return np.tile(self.mean, (n, 1)), np.full((n, 2), 1e-6), np.tile(self.J, (n, 1, 1))


def test_spectral_radius_of_2x2_matches_eigenvalues():
    rng = np.random.default_rng(3)
    M = rng.normal(0, 1, (500, 2, 2))
    assert np.allclose(spectral_radius2(M), np.abs(np.linalg.eigvals(M)).max(axis=1), atol=1e-12)


def test_stable_share_cuts_only_what_adds_to_a_nominal_instability():
    stable = np.array([[0.9, -0.3], [0.1, 0.8]])     # rho 0.85
    unstable = np.array([[1.05, -0.3], [0.1, 1.0]])  # rho above 1 (a tire past its peak)
    A0 = np.array([stable, stable, unstable, unstable])
    J = np.array([[[0.0, 0.0], [0.0, -0.1]],   # more yaw damping
                  [[0.0, 0.0], [0.0, 0.6]],    # yaw rate feeding itself: unstable with all of it
                  [[0.0, 0.0], [0.0, -0.1]],
                  [[0.0, 0.0], [0.0, 0.2]]])
    t = stable_share(A0, J)
    r0 = spectral_radius2(A0)
    assert r0[0] < 1.0 < r0[2]
    # a stable nominal block keeps the whole gradient, even one that makes it unstable
    assert t[0] == 1.0 and t[1] == 1.0 and spectral_radius2(A0[1:2] + J[1:2])[0] > 1.0
    # an unstable one keeps what damps it and loses what adds to its instability
    assert t[2] == 1.0
    assert 0.0 <= t[3] < 1.0
    assert spectral_radius2(A0[3:] + J[3:])[0] > r0[3]
    assert spectral_radius2(A0[3:] + t[3] * J[3:])[0] <= r0[3] + 1e-9


def _sliding(plan):
    """The plan's first state at half its speed with the rear sliding (v_y = -3 m/s): the nominal
    model's lateral block of the first step is unstable there (rho about 1.01), later steps (the
    reference's states) are stable."""
    x = plan.at_time(np.array([0.0]))[0][0].copy()
    x[State.V_X] *= 0.5
    x[State.YAW_RATE] *= 0.5
    x[State.V_Y] = -3.0
    return x


def _build(circle, J, **kw):
    tr, m, plan = circle
    x0 = _sliding(plan)
    mpc = TrackingMPC(m, tr, plan, MPCSettings(**kw), gp=_GradientGP(J))
    pb, _ = mpc.build(x0)
    pb0, _ = TrackingMPC(m, tr, plan, MPCSettings(**kw)).build(x0)
    return pb, pb0, mpc


def test_a_gradient_that_adds_to_the_nominal_instability_is_shrunk(circle):
    """A GP whose yaw-error gradient in the yaw rate is +0.3 per period: where the nominal lateral
    block is unstable (the first step, at a sliding state) it makes it more unstable; without the
    rule the QP predicts with it, with the rule it is shrunk there and kept whole where the nominal
    block is stable. The mean still enters."""
    J = np.zeros((2, 5))
    J[1, 2] = 0.3  # d(yaw-rate error)/d(yaw rate)
    pb, pb0, _ = _build(circle, J, gp_stable=False)
    r0 = spectral_radius2(pb0.A[:, GP_STATES, GP_STATES])
    assert r0[0] > 1.0 and np.all(r0[1:] < 1.0)
    assert spectral_radius2(pb.A[:1, GP_STATES, GP_STATES])[0] > r0[0]  # fails without the rule
    pb, pb0, mpc = _build(circle, J, gp_stable=True)
    r = spectral_radius2(pb.A[:, GP_STATES, GP_STATES])
    assert r[0] <= r0[0] + 1e-9 and mpc.gp_share[0] < 1.0
    assert np.all(mpc.gp_share[1:] == 1.0)
    assert np.allclose(pb.A[1:, State.YAW_RATE, State.YAW_RATE] - pb0.A[1:, State.YAW_RATE, State.YAW_RATE], 0.3)
    # the mean enters the affine term whatever the gradient's share
    assert not np.allclose(pb.c[:, GP_STATES], pb0.c[:, GP_STATES])


def test_a_damping_gradient_is_kept_whole(circle):
    J = np.zeros((2, 5))
    J[1, 2] = -0.05  # more yaw damping
    J[1, 3] = 0.5    # and more steering authority
    pb, pb0, mpc = _build(circle, J, gp_stable=True)
    assert np.all(mpc.gp_share == 1.0)
    assert np.allclose(pb.A[:, State.YAW_RATE, State.YAW_RATE] - pb0.A[:, State.YAW_RATE, State.YAW_RATE], -0.05)
    assert np.allclose(pb.B[:, State.YAW_RATE, Input.DELTA] - pb0.B[:, State.YAW_RATE, Input.DELTA], 0.5)


def test_steer_share_keeps_the_sign_and_a_share_of_the_steering_gain():
    b0 = np.array([1.0, 1.0, 1.0, -0.5, 0.4])
    jb = np.array([-0.5, -0.9, 0.3, -1.0, -2.0])
    t = steer_share(b0, jb, 0.25)
    assert np.allclose(t, [1.0, 0.75 / 0.9, 1.0, 1.0, 0.75 * 0.4 / 2.0])
    gain = b0 + t * jb
    assert np.all(gain[b0 > 0] >= 0.25 * b0[b0 > 0] - 1e-12)
    assert np.isclose(gain[4], 0.1) and np.isclose(gain[1], 0.25)
    assert np.all(steer_share(b0, jb, 0.0) <= 1.0) and np.isclose(steer_share(b0, jb, 0.0)[4], 0.2)


def test_a_gradient_that_reverses_the_steering_is_shrunk(circle):
    """A GP whose yaw-error gradient in the steering is -3 per period (as one fitted on laps with
    the front past its peak): without the rule the QP's steering turns the car the other way, with
    it the steering keeps a quarter of its nominal gain and the rest of the gradient its share."""
    J = np.zeros((2, 5))
    J[1, 3] = -3.0  # d(yaw-rate error)/d(delta)
    pb, pb0, _ = _build(circle, J, gp_steer_keep=0.0, gp_stable=False)
    b0 = pb0.B[:, State.YAW_RATE, Input.DELTA]
    assert np.all(b0 > 0) and np.any(pb.B[:, State.YAW_RATE, Input.DELTA] < 0)  # reversed without the rule
    pb, pb0, mpc = _build(circle, J, gp_stable=False)
    b = pb.B[:, State.YAW_RATE, Input.DELTA]
    assert np.all(b >= 0.25 * b0 - 1e-9)
    assert np.allclose(b[mpc.gp_share < 1], 0.25 * b0[mpc.gp_share < 1])


class _EdgeGP(_GradientGP):
    """A constructed GP whose extrapolation runs from its data (0) past its prior (1.2) along the horizon."""

    def extrapolation_of(self, var):
        return np.linspace(0.0, 1.2, len(var))


def test_the_gradient_fades_as_the_gp_nears_its_prior(circle):
    """With ``gp_trust`` each step keeps ``1 - extrapolation`` of the gradient (none at or past the
    prior); without it, the whole gradient. The mean enters either way."""
    tr, m, plan = circle
    x0 = plan.at_time(np.array([0.0]))[0][0]
    J = np.zeros((2, 5))
    J[1, 3] = 0.4  # d(yaw-rate error)/d(delta)
    kw = dict(gp_stable=False, gp_steer_keep=0.0)
    pb0, _ = TrackingMPC(m, tr, plan, MPCSettings(**kw)).build(x0)
    mpc = TrackingMPC(m, tr, plan, MPCSettings(**kw), gp=_EdgeGP(J))
    pb, _ = mpc.build(x0)
    e = np.linspace(0.0, 1.2, len(pb.A))
    assert np.allclose(mpc.gp_share, np.clip(1.0 - e, 0.0, 1.0)) and np.allclose(trust_share([np.nan, 0.3]), [1.0, 0.7])
    gain = pb.B[:, State.YAW_RATE, Input.DELTA] - pb0.B[:, State.YAW_RATE, Input.DELTA]
    assert np.allclose(gain, 0.4 * mpc.gp_share) and gain[0] == pytest.approx(0.4) and np.all(gain[e >= 1.0] == 0.0)
    whole = TrackingMPC(m, tr, plan, MPCSettings(gp_trust=False, **kw), gp=_EdgeGP(J))
    pbw, _ = whole.build(x0)
    assert np.allclose(pbw.B[:, State.YAW_RATE, Input.DELTA] - pb0.B[:, State.YAW_RATE, Input.DELTA], 0.4)
    # where no gradient is left the GP's mean alone moves the affine term
    assert np.allclose((pb.c - pb0.c)[e >= 1.0][:, GP_STATES], [0.01, -0.02])


def test_extrapolation_from_the_real_time_variance_matches_the_exact_one():
    """``GPPredictor.extrapolation_of`` on the variance of the MPC's real-time path (spectral, with
    a calibration) reads what ``extrapolation`` reads from an exact prediction, never below it."""
    from gprace.gp import make_gp
    from gprace.timetrial.learning import GPPredictor

    rng = np.random.default_rng(5)
    Z = rng.uniform(-2, 2, (600, 2))
    Y = np.column_stack([np.sin(Z[:, 0]), np.cos(Z[:, 1])]) + rng.normal(0, 0.1, (600, 2))
    gp = GPPredictor(make_gp("exact", optimize=True, max_fit_points=500, seed=0).fit(Z, Y), "tracking",
                     inputs=("v_y", "yaw_rate"), var_scale=[2.0, 0.5])
    X = np.zeros((60, 6))
    X[:, State.V_X] = 20.0
    X[:, State.V_Y] = np.linspace(0.0, 6.0, 60)  # from the middle of the data to far outside it
    X[:, State.YAW_RATE] = 0.5
    U = np.zeros((60, 2))
    exact = gp.extrapolation(X, U)
    fast = gp.extrapolation_of(gp.at_with_gradient(X, U)[1])
    assert exact[0] < 0.3 and exact[-1] > 0.99 and np.all(np.diff(exact[X[:, State.V_Y] > 2.5]) >= -1e-9)
    assert np.all(fast >= exact - 1e-9) and np.all(fast <= 1.1 * exact + 0.01)
