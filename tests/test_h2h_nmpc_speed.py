"""Speed settings of the head-to-head NMPC keep its solution: warm-start shift, IPOPT/MUMPS options."""

from __future__ import annotations

import numpy as np
import pytest

import gprace.h2h.nmpc as nmpc
from gprace.h2h.config import H2HConfig
from gprace.h2h.geometry import make_track
from gprace.h2h.nmpc import NMPC, NS, NU, NX, StageData, shift_plan
from gprace.h2h.race import _model, ellipse_data, usable_widths

CFG = H2HConfig()
# the reference: IPOPT's own MUMPS scaling, a tight tolerance and no early "acceptable" exit
REFERENCE = {k: v for k, v in nmpc.IPOPT_OPTIONS.items() if not k.startswith("mumps_")}
REFERENCE.update(tol=1e-10, acceptable_iter=0)


def _plan(N: int, v: float = 1.2, dt: float = 0.1) -> np.ndarray:
    """Stage-wise decision vector of a straight run at constant speed (inputs and slacks per stage)."""
    w = np.zeros((N, NU + NX + NS))
    k = np.arange(1, N + 1)
    w[:, :NU] = np.column_stack([0.01 * k, -0.02 * k])
    w[:, NU:NU + NX] = np.array([v, 0.0, 0.0, 0.0, 0.1, 0.0])
    w[:, NU + 5] = 2.0 + v * dt * k
    w[:, NU + 4] = 0.1 + 0.01 * k  # drifting left at a constant rate
    w[:, NU + NX:] = 0.001 * k[:, None]
    return w


def test_shift_plan_extrapolates_the_last_states():
    N, width = 10, NU + NX + NS
    w = _plan(N + 1)  # one stage longer: its last row is the exact next state of the motion
    got = shift_plan(w[:N].ravel(), width).reshape(N, width)
    np.testing.assert_allclose(got[:, NU:NU + NX], w[1:, NU:NU + NX], atol=1e-12)
    np.testing.assert_array_equal(got[:-1], w[1:N])  # the shifted part is a plain shift
    np.testing.assert_array_equal(got[-1, :NU], w[N - 1, :NU])  # inputs and slacks repeated
    np.testing.assert_array_equal(got[-1, NU + NX:], w[N - 1, NU + NX:])
    # too short to extrapolate: the last stage is repeated
    two = shift_plan(w[:2].ravel(), width).reshape(2, width)
    np.testing.assert_array_equal(two, w[[1, 1]])


def _problem(mpc: NMPC, track, x0, opp):
    N = CFG.horizon
    G = mpc.guess_states(x0)
    sig = G[1:, 5]
    cx, cy = track.to_global(sig, np.zeros(N))
    mean = np.tile(opp, (N, 1))
    mean[:, 5] = opp[5] + CFG.dt * opp[0] * np.arange(1, N + 1)
    wl, wr = usable_widths(track, sig)
    return StageData(kappa=track.kappa(G[:-1, 5]), wl=wl, wr=wr,
                     lin=np.column_stack([cx, cy, track.heading(sig), sig, track.kappa(sig)]),
                     opp=ellipse_data(track, CFG, mean, np.full((N, 2), 0.02)))


def _solves(mpc: NMPC, track, states=None, steps: int = 4):
    """Ego closing on a slower opponent: a cold start, then warm starts at the states the first
    plans reach (``states``: the (x, u) of each solve, taken from another run)."""
    mpc.reset()
    x, u = np.array([1.3, 0.0, 0.0, 0.0, 0.05, 0.5]), np.zeros(2)
    opp = np.array([0.6, 0.0, 0.0, 0.0, -0.05, 1.3])
    out, used = [], []
    for k in range(steps):
        if states is not None:
            x, u = states[k]
        used.append((x, u))
        sol = mpc.solve(x, u, 0.0, _problem(mpc, track, x, opp))
        assert sol.ok
        out.append(sol)
        x, u = sol.X[1], sol.U[0]
        opp = opp + np.array([0, 0, 0, 0, 0, CFG.dt * opp[0]])
    return out, used


@pytest.fixture(scope="module")
def curvy():
    return make_track({"kind": "random", "seed": 4, "width": 0.75, "stretches": 4})


def test_tuned_solve_agrees_with_a_tight_reference(curvy, monkeypatch):
    tuned, states = _solves(NMPC(_model(), CFG.ego, CFG, collision=True), curvy)
    monkeypatch.setattr(nmpc, "IPOPT_OPTIONS", REFERENCE)
    ref, _ = _solves(NMPC(_model(), CFG.ego, CFG, collision=True), curvy, states)
    # per state [v_x, v_y, yaw_rate, e_psi, e_y, s]: the planned path within 2 mm and 5 mrad of
    # the tight solution, speeds within 5 mm/s, the yaw rate (no cost weighs it) within 0.03 rad/s.
    # Measured with one acceptable iterate ending the solve: inputs 3.6e-3, yaw rate 0.016, e_y
    # 0.4 mm at most (with three acceptable iterates, ten times less)
    tol = np.array([5e-3, 5e-3, 0.03, 5e-3, 2e-3, 2e-3])
    for a, b in zip(tuned, ref):
        assert np.max(np.abs(a.U - b.U)) < 5e-3
        assert np.all(np.abs(a.X - b.X) < tol)


# ------------------------------------------------------------------------------------------------
# the fallback after a failed solve
def _failed_after(mpc: NMPC, last_U: np.ndarray, streak: int = 0) -> None:
    """Put ``mpc`` in the state after a successful solve with plan inputs ``last_U`` and ``streak``
    fallbacks since."""
    N = CFG.horizon
    x = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    last = nmpc.Solution(X=np.tile(x, (N + 1, 1)), U=last_U, slack=np.zeros((N, NS)), ok=True, status="", seconds=0.0)
    mpc._warm = {"x": mpc.initial_guess(x), "last": last, "streak": streak}


def test_an_isolated_fallback_at_speed_is_the_shifted_plan():
    mpc = NMPC(_model(), CFG.ego, CFG, collision=True)
    U = np.column_stack([np.linspace(-0.4, 0.4, CFG.horizon), np.linspace(-1.0, 0.5, CFG.horizon)])
    _failed_after(mpc, U)
    sol = mpc._fallback(np.array([1.0, 0.0, 0.3, 0.2, 0.1, 5.0]), "failed", 0.0, 0.5)
    np.testing.assert_array_equal(sol.U[:-1], U[1:])
    assert sol.fallback and mpc._warm["streak"] == 1


def test_a_fallback_never_brakes_below_the_nlp_speed_bound():
    """A repeated braking input drove cars into reverse (down to v_x = -0.8 m/s in a default run),
    where every NLP, bounded by v_x >= V_X_MIN, is infeasible: the fallback brakes at most down
    to the bound in one step, and accelerates back up to it from below."""
    mpc = NMPC(_model(), CFG.ego, CFG, collision=True)
    assert (CFG.dt, CFG.ego.accel, nmpc.V_X_MIN) == (0.1, (-1.0, 0.55), 0.05)  # the numbers below
    # v_x -> the plan's full braking (-1) replaced by: down to the bound, hold it, back up to it,
    # the most the car has from reverse; well above the bound the plan's braking stays
    for vx, accel in ((1.0, -1.0), (0.12, -0.7), (0.05, 0.0), (0.0, 0.5), (-0.3, 0.55)):
        _failed_after(mpc, np.tile([0.0, -1.0], (CFG.horizon, 1)))
        a = mpc._fallback(np.array([vx, 0.0, 0.0, 0.0, 0.0, 1.0]), "failed", 0.0, 0.0).U[0, 1]
        assert a == pytest.approx(accel)


def test_a_run_of_fallbacks_holds_the_heading_along_the_track():
    """After STALE_STEPS fallbacks in a row the plan is stale: its last input (here full left lock)
    is no longer repeated; the steering turns the car parallel to the track (kinematic steering of
    the curvature minus the heading error), a mirror image for a mirrored state."""
    mpc = NMPC(_model(), CFG.ego, CFG, collision=True)
    lock = np.tile([CFG.ego.steering_max, 0.0], (CFG.horizon, 1))
    x = np.array([0.8, 0.0, 0.0, 0.3, 0.2, 4.0])  # heading 0.3 rad to the left of the track
    _failed_after(mpc, lock, streak=nmpc.STALE_STEPS - 1)
    assert mpc._fallback(x, "failed", 0.0, 0.0).U[0, 0] == CFG.ego.steering_max  # still the plan
    steer = mpc._fallback(x, "failed", 0.0, 0.0).U[0, 0]  # one more: stale
    assert steer == pytest.approx(-nmpc.HOLD_GAIN * 0.3)
    L = _model().params.lf + _model().params.lr
    mirrored = x * np.array([1, -1, -1, -1, -1, 1])
    assert nmpc.heading_hold(mirrored, 0.0, L, CFG.ego.steering_max) == pytest.approx(-steer)
    # on an arc the hold steers with the curvature: kinematic steering atan(L kappa) at e_psi = 0
    on_arc = nmpc.heading_hold(np.zeros(6), 1.5, L, CFG.ego.steering_max)
    assert on_arc == pytest.approx(np.arctan(L * 1.5))


def _step_jacobians(v: float, delta: float):
    """Jacobians d x+/d x of the NLP's one-step map and of the dynamic model's own RK4 at speed ``v``."""
    import casadi as ca

    m, dt, sub = _model(), CFG.dt, CFG.ego.substeps
    x, u, k = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("k")
    x0, u0 = [v, 0.01, 0.05, 0.1, 0.05, 3.0], [delta, 0.3]
    out = []
    for F in (nmpc.blended_rk4(m, dt, sub), m.casadi_rk4(dt, sub)):
        out.append(np.array(ca.Function("J", [x, u, k], [ca.jacobian(F(x, u, k), x)])(x0, u0, 0.5)))
    return out


def test_the_prediction_model_is_stable_at_a_crawl_and_the_dynamic_model_at_speed():
    """The dynamic model's RK4 with the NLP's sub-step amplifies errors below about 0.4 m/s (its
    lateral eigenvalue is about -22/v_x); the blended model's one-step map never does, and above the
    blend it is the dynamic model's RK4 exactly."""
    worst_blend, worst_dyn = 0.0, 0.0
    for v in (0.05, 0.1, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45):
        for delta in (0.0, 0.2, 0.435):
            blend, dyn = _step_jacobians(v, delta)
            worst_blend = max(worst_blend, np.abs(np.linalg.eigvals(blend)).max())
            worst_dyn = max(worst_dyn, np.abs(np.linalg.eigvals(dyn)).max())
    # nothing grows beyond the geometry's own drift on a curve (1.0003 to 1.005 per step, in the
    # dynamic model at speed as well)
    assert worst_blend <= 1.01
    assert worst_dyn > 10.0  # the model it replaces at a crawl: errors grow tenfold per step
    m, F = _model(), nmpc.blended_rk4(_model(), CFG.dt, CFG.ego.substeps)
    rng = np.random.default_rng(3)
    for _ in range(20):  # above KIN_BLEND[1]: bit for bit the dynamic model
        x = np.array([rng.uniform(nmpc.KIN_BLEND[1] + 0.1, 1.6), *rng.normal(0, 0.05, 4), 5.0])
        u, kap = rng.uniform([-0.4, -1.0], [0.4, 0.5]), rng.uniform(-1.0, 1.0)
        np.testing.assert_array_equal(np.array(F(x, u, kap)), np.array(m.casadi_rk4(CFG.dt, CFG.ego.substeps)(x, u, kap)))


def test_at_a_crawl_the_prediction_turns_like_a_kinematic_bicycle():
    """Below the blend, yaw rate and lateral speed settle at v_x tan(delta) / L and l_r times that,
    and v_x follows the commanded acceleration (no tyre forces)."""
    m = _model()
    p = m.params
    F = nmpc.blended_rk4(m, CFG.dt, CFG.ego.substeps)
    v, delta = 0.12, 0.3
    x = np.array([v, 0.0, 0.0, 0.0, 0.0, 0.0])
    for _ in range(10):
        x = np.array(F(x, [delta, p.crr * p.g + p.cxw * v * v / p.m], 0.0)).ravel()  # holds the speed
    yaw = v * np.tan(delta) / (p.lf + p.lr)
    assert x[0] == pytest.approx(v, abs=1e-6)
    assert x[2] == pytest.approx(yaw, rel=1e-3) and x[1] == pytest.approx(p.lr * yaw, rel=1e-3)


# ------------------------------------------------------------------------------------------------
# the border margin at a large heading error
def test_the_border_margin_is_the_configured_one_until_the_footprint_needs_more():
    import casadi as ca

    L, W, c = CFG.car_length, CFG.car_width, CFG.ego.border_margin
    e = ca.SX.sym("e")
    m = ca.Function("m", [e], [nmpc.border_margin(e, c, L, W)])
    dm = ca.Function("dm", [e], [ca.jacobian(nmpc.border_margin(e, c, L, W), e)])
    psi = np.linspace(-1.5, 1.5, 3001)
    got = np.array(m(psi.reshape(1, -1))).ravel()
    ext = 0.5 * L * np.abs(np.sin(psi)) + 0.5 * W * np.cos(psi) + nmpc.MARGIN_BUFFER
    below = ext <= c
    assert below[np.abs(psi) < 0.28].all() and not below[np.abs(psi) > 0.3].any()
    np.testing.assert_array_equal(got[below], c)  # the NLP of a small heading error is unchanged
    d = nmpc.MARGIN_SMOOTH
    assert np.all(got >= np.maximum(c, ext - d / 2) - 1e-6) and np.all(got <= np.maximum(c, ext) + 1e-6)
    far = ext > c + d
    np.testing.assert_allclose(got[far], ext[far] - d / 2, atol=1e-6)  # the footprint plus the buffer
    slope = np.array(dm(psi.reshape(1, -1))).ravel()
    assert np.max(np.abs(np.diff(slope))) < 0.01  # once differentiable: no jump in the slope


def _corners_of_plan(mpc: NMPC) -> np.ndarray:
    """A slow car 0.15 m left of the centre of a straight 0.75 m track, heading 0.9 rad into the
    left border: the plan's footprint corners' largest lateral position per stage."""
    from gprace.h2h.geometry import corner_offsets

    N = CFG.horizon
    x = np.array([0.3, 0.0, 0.0, 0.9, 0.15, 1.0])
    sol = mpc.solve(x, np.zeros(2), 0.0, StageData(kappa=np.zeros(N), wl=np.full(N, 0.375), wr=np.full(N, 0.375)))
    assert sol.ok
    c = corner_offsets(CFG.car_length, CFG.car_width)
    epsi, ey = sol.X[1:, 3, None], sol.X[1:, 4, None]
    return (ey + c[:, 0] * np.sin(epsi) + c[:, 1] * np.cos(epsi)).max(axis=1)


def test_the_plan_keeps_the_footprint_inside_at_a_large_heading_error(monkeypatch):
    corners = _corners_of_plan(NMPC(_model(), CFG.ego, CFG, collision=True))
    assert corners.max() <= 0.375 - (nmpc.MARGIN_BUFFER - nmpc.MARGIN_SMOOTH / 2) + 1e-4  # the far branch
    # with half the length as the only margin, the same plan's corners leave the track
    monkeypatch.setattr(nmpc, "MARGIN_BUFFER", -1.0)
    free = CFG.ego.model_copy(update={"compiled": False})
    assert _corners_of_plan(NMPC(_model(), free, CFG, collision=True)).max() > 0.375
