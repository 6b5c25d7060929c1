"""The minimum-lap-time planner (paper appendix, problem "planning_problem") in CasADi/IPOPT.

Spatial domain: the independent variable is the centre-line arc length; ``n`` nodes
``s_k = k L / n`` on the closed lap, with the state ``[v_x, v_y, yaw_rate, e_psi, e_y]`` and the
inputs ``[delta, a_x]`` at every node. Node ``n`` is node 0 again, which is the closed-path
constraint ``xi_N = xi_0`` of the paper.

Dynamics: ``d xi / ds = (f(xi, u, kappa) + mu_plan) / s_dot`` with ``s_dot`` the centre-line
progress rate, discretised with the trapezoidal rule. **Decision:** the paper writes a forward
Euler step; at 5 to 8 m per node (0.1 to 0.3 s at racing speed) explicit Euler is unstable on the
fast lateral modes of a stiff race tire, the trapezoidal rule is A-stable and second order at the
same cost in variables. The objective is the lap time ``sum_k h (1/s_dot_k + 1/s_dot_{k+1}) / 2``
(the paper's eq. "cost_function_planning"), plus small penalties on input changes between nodes
(the paper's planner has none; without them the trapezoidal scheme admits node-to-node input
chatter; their weight is chosen to change the lap time by well under 0.1 %).

GP compensation: ``mu_plan`` (n, 2) is the planning GP's mean of the errors of ``d v_y/dt`` and
``d yaw_rate/dt`` evaluated on the PREVIOUS solution (the warm start); it enters the NLP as constant
data (a parameter), never as a function of the decision variables (paper appendix).

Bounds: ``-w_r + b/2 + margin <= e_y <= w_l - b/2 - margin`` (b the car width), steering and
acceleration limits, optionally a friction ellipse at a share ``grip`` of the model's limits, ``v_x >= v_low`` and the speed over ground ``|(v_x, v_y)| <= speed_max``, ``|e_psi| <= 1`` rad.
The steering changes between nodes within ``steer_rate`` (0.8) of the vehicle's
``steering_rate_max``, the bound the tracking MPC holds (beyond the paper, issue 37 stop 52).
Solved with IPOPT, exact Hessian, MUMPS.

The ellipse's three limits are NLP parameters, not constants, so one built solver serves every
plan of a model on the same nodes (the time trial widens the limits each iteration): building it
(expansion, derivatives, the Hessian's structure) took 1.6 to 2 s of the 5 to 7 s of a re-plan.
Solvers are kept per model object (:func:`_solver`). Measured on the README job's 7 re-plans of
a trial: the same IPOPT iterations but for one (191 -> 179), plans equal to 1e-7 (issue 37).
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np
from pydantic import Field

from gprace.config import CommandSettings
from gprace.errors import ConfigError, SolverError
from gprace.model.dynamics import peak_slip
from gprace.plan.plan import Plan, track_hash
from gprace.solvers import ipopt_status


class PlanSettings(CommandSettings):
    """The minimum-lap-time NLP (paper appendix)."""

    ds: float = Field(6.0, gt=0, description="node spacing [m]")
    margin: float = Field(0.3, ge=0, description="extra distance kept from the borders [m]")
    w_steer: float = Field(0.5, ge=0, description="penalty on (delta_{k+1} - delta_k)^2 [s/rad^2]")
    w_accel: float = Field(1e-4, ge=0, description="penalty on (a_{k+1} - a_k)^2 [s^5/m^2]")
    v_low: float = Field(3.0, gt=0, description="lower speed bound [m/s]")
    grip: float | None = Field(None, gt=0, description="if set: friction ellipse (a_x/a_lim)^2 + (v_x r/a_lat)^2 <= 1 "
                               "at this share of the model's own limits (a margin for a car the model does not know)")
    grip_brake: float | None = Field(None, gt=0, description="share of the braking limit inside the ellipse (default: grip)")
    limits: tuple[float, float, float] | None = Field(None, description="friction ellipse in m/s^2: (lateral, drive, "
                                                      "brake > 0); overrides grip/grip_brake (the time trial widens it "
                                                      "from measured laps)")
    slip_max: tuple[float, float] | None = Field(None, description="if set: (front, rear) largest slip angles as "
                                                 "shares of the nominal tire's peak slip angle (the time trial's GP "
                                                 "plans: the bounds its safety check holds them to)")
    steer_rate: float | None = Field(0.8, gt=0, le=1, description="if set: the steering changes between nodes no "
                                     "faster than this share of the vehicle's steering_rate_max (the tracking MPC's "
                                     "actuator bound; the rest is its room to correct)")
    barrier: Literal["monotone", "adaptive"] = Field(
        "monotone", description="IPOPT barrier strategy tried first (the other is the second try); 'adaptive' for "
        "re-plans warm-started from a nearby plan (docs/decisions.md, issue 37 stop 48)")
    max_iter: int = Field(1500, ge=1, description="IPOPT iteration limit")
    tol: float = Field(1e-6, gt=0, description="IPOPT tolerance")
    print_level: int = Field(0, ge=0, le=12, description="IPOPT print level")


# one node's decision variables: the five states the planner keeps (s is the independent variable)
# and the two inputs
VX, VY, R, EPSI, EY, DELTA, AX = range(7)
NODE = 7


def plan_min_time(track, model, settings: PlanSettings = PlanSettings(), warm: Plan | None = None,
                  mu_plan=None) -> Plan:
    """Solve the minimum-time lap; ``warm`` is the initial guess (default: the curvature plan).

    ``mu_plan`` is a callable ``(X (n, 6), U (n, 2)) -> (n, 2)`` mean derivative errors (the
    planning GP, which builds its own inputs from them), evaluated once on the initial guess;
    ``None`` plans with the nominal model.
    """
    from gprace.plan.curvature import curvature_plan

    if not track.closed:
        raise ConfigError(f"plan: track {track.name!r} is open; the minimum-lap-time planner needs a closed lap")
    if model.nx != 6:
        raise ConfigError("plan: the planning vehicle has effects with internal states (lags); the planner supports stateless effects only")
    t0 = time.perf_counter()
    smp = track.sample(settings.ds)
    n = len(smp.s)
    h = track.length / n
    if warm is None:
        warm = curvature_plan(track, model, ds=settings.ds, speed_scale=1.0, margin=settings.margin)
    else:
        warm.check_track(track, "warm start")
    X0, U0 = _resample(warm, smp.s)
    comp = np.zeros((n, 2))
    if mu_plan is not None:
        comp = np.asarray(mu_plan(X0, U0), dtype=float).reshape(n, 2)
        if not np.all(np.isfinite(comp)):
            raise SolverError("plan: the planning GP returned non-finite compensation")
    half = 0.5 * model.vehicle.width + settings.margin
    lo_ey, hi_ey = frenet_bounds(smp.kappa, -smp.wr + half, smp.wl - half)
    if np.any(lo_ey >= hi_ey):
        k = int(np.argmax(lo_ey >= hi_ey))
        raise ConfigError(f"plan: track {track.name!r} is narrower than the car plus margin at s = {smp.s[k]:.1f} m")

    ellipse = ellipse_limits(model, settings)
    LB, UB, guess = _bounds_and_guess(model, settings, X0, U0, lo_ey, hi_ey)
    args = dict(x0=guess.ravel(), lbx=LB.ravel(), ubx=UB.ravel(),
                p=np.concatenate([np.column_stack([smp.kappa, comp]).ravel(), ellipse or ()]))
    z, stats = _solve(model, settings, n, h, ellipse is not None, args, track)
    vx, vy, r, epsi, ey, delta, ax = z.reshape(n, NODE).T
    sd = (vx * np.cos(epsi) - vy * np.sin(epsi)) / (1 - smp.kappa * ey)
    dt = 0.5 * h * (1 / sd + 1 / np.roll(sd, -1))
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return Plan(
        s=smp.s, e_y=ey, e_psi=epsi, v_x=vx, v_y=vy, yaw_rate=r, delta=delta, a_x=ax, t=t[:-1], lap_time=float(t[-1]),
        track=track.name, track_length=track.length, track_hash=track_hash(track), vehicle=model.vehicle.name,
        method="min_time",
        meta={"ds": h, "iterations": int(stats["iter_count"]), "solve_time": time.perf_counter() - t0,
              "gp": mu_plan is not None, "warm": warm.method, "max_abs_mu_plan": float(np.max(np.abs(comp))) if n else 0.0},
    )


def _nlp(model, settings: PlanSettings, n: int, h: float, ellipse: bool) -> tuple[dict, np.ndarray, np.ndarray]:
    """The NLP over ``n`` nodes ``h`` apart in ``s`` (trapezoidal collocation on the closed lap),
    parameters ``(kappa, mu_vy, mu_r)`` per node, then (``ellipse``) the friction ellipse's
    ``(a_lat, a_drive, a_brake)``; its constraint bounds."""
    import casadi as ca

    lim = model.vehicle.limits
    # stage functions: time derivatives of the five states over ds/dt, and dt/ds
    x = ca.SX.sym("x", 5)
    u = ca.SX.sym("u", 2)
    pk = ca.SX.sym("p", 3)  # kappa, mu_vy, mu_r
    f = model.symbolic(ca.vertcat(x, 0.0), u, pk[0])
    sdot = (x[VX] * ca.cos(x[EPSI]) - x[VY] * ca.sin(x[EPSI])) / (1 - pk[0] * x[EY])
    fx = ca.vertcat(f[0], f[1] + pk[1], f[2] + pk[2], f[3], f[4])
    gmap = ca.Function("g", [x, u, pk], [fx / sdot, 1.0 / sdot]).map(n)

    w = ca.MX.sym("w", NODE * n)
    WU = ca.reshape(w, NODE, n)
    X, U = WU[:5, :], WU[5:, :]
    pv = ca.MX.sym("p", 3 * n + (3 if ellipse else 0))
    G, W = gmap(X, U, ca.reshape(pv[:3 * n], 3, n))
    Xn = ca.horzcat(X[:, 1:], X[:, :1])
    Gn = ca.horzcat(G[:, 1:], G[:, :1])
    defect = Xn - X - 0.5 * h * (G + Gn)
    lap = h * ca.sum2(W)
    dU = ca.horzcat(U[:, 1:], U[:, :1]) - U
    reg = settings.w_steer * ca.sumsqr(dU[0, :]) + settings.w_accel * ca.sumsqr(dU[1, :])
    g_all = [ca.vec(defect)]
    lbg, ubg = [np.zeros(5 * n)], [np.zeros(5 * n)]
    # top speed bounds the speed over ground, not v_x alone: with v_x at its bound a slide
    # (v_y != 0, e_psi against it) still adds progress, and GP-compensated plans of Budapest
    # slalomed at 70 m/s down the main straight (|v_y| up to 5.6 m/s) to gain it
    g_all.append(ca.vec(X[VX, :] ** 2 + X[VY, :] ** 2))
    lbg.append(np.zeros(n))
    ubg.append(np.full(n, lim.speed_max**2))
    if settings.slip_max is not None:
        # slip angles of the nominal kinematics (v_x >= v_low > 0 at every node): a compensation
        # evaluated on the warm start and held fixed is no licence to steer past the tire's peak
        # (measured, README job trial 2: a yaw compensation of -2.7 rad/s^2 read on the warm
        # plan answered with 20 times its steering, front slip 1.4 to 1.7 of the peak, and every
        # such plan refused by the safety check)
        p = model.params
        front = U[0, :] - ca.atan((X[VY, :] + p.lf * X[R, :]) / X[VX, :])
        rear = -ca.atan((X[VY, :] - p.lr * X[R, :]) / X[VX, :])
        for share, b, c, alpha in zip(settings.slip_max, (p.bf, p.br), (p.cf, p.cr), (front, rear)):
            g_all.append(ca.vec(alpha))
            lbg.append(np.full(n, -share * peak_slip(b, c)))
            ubg.append(np.full(n, share * peak_slip(b, c)))
    if settings.steer_rate is not None:
        # the steering between nodes within the actuator's rate over the time between them: the
        # tracking MPC holds |d delta / dt| to steering_rate_max, so a faster plan cannot be
        # followed, and the share left is its room to correct (docs/decisions.md, issue 37, stop
        # 52). The time between nodes is taken as h over the mean v_x: with the exact
        # h (1/s_dot_k + 1/s_dot_k+1) / 2 IPOPT stopped at a point of local infeasibility on the
        # circle tests; on the inside of a tight corner the plan's own rate is then up to
        # 1 / (1 - kappa e_y) higher (0.126 against 0.12 rad/s in the test)
        step = settings.steer_rate * lim.steering_rate_max * h
        g_all.append(ca.vec(dU[0, :] * 0.5 * (X[VX, :] + Xn[VX, :])))
        lbg.append(np.full(n, -step))
        ubg.append(np.full(n, step))
    if ellipse:
        a_lat, a_drive, a_brake = pv[3 * n], pv[3 * n + 1], pv[3 * n + 2]
        a_lon = ca.if_else(U[1, :] >= 0, U[1, :] / a_drive, -U[1, :] / a_brake)
        g_all.append(ca.vec(a_lon**2 + (X[VX, :] * X[R, :] / a_lat) ** 2))
        lbg.append(np.full(n, -np.inf))
        ubg.append(np.ones(n))
    nlp = {"x": w, "p": pv, "f": lap + reg, "g": ca.vertcat(*g_all)}
    return nlp, np.concatenate(lbg), np.concatenate(ubg)


def _bounds_and_guess(model, settings: PlanSettings, X0: np.ndarray, U0: np.ndarray, lo_ey: np.ndarray,
                      hi_ey: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 7) lower and upper bounds per node, and the initial guess clipped into them."""
    lim = model.vehicle.limits
    lbx = np.array([settings.v_low, -np.inf, -np.inf, -1.0, 0.0, -lim.steering_max, lim.accel_min])
    ubx = np.array([lim.speed_max, np.inf, np.inf, 1.0, 0.0, lim.steering_max, lim.accel_max])
    LB = np.tile(lbx, (len(X0), 1))
    UB = np.tile(ubx, (len(X0), 1))
    LB[:, EY], UB[:, EY] = lo_ey, hi_ey
    guess = np.column_stack([X0[:, :5], U0])
    guess[:, EY] = np.clip(guess[:, EY], lo_ey, hi_ey)
    guess[:, VX] = np.clip(guess[:, VX], settings.v_low, lim.speed_max)
    guess[:, DELTA] = np.clip(guess[:, DELTA], -lim.steering_max, lim.steering_max)
    guess[:, AX] = np.clip(guess[:, AX], lim.accel_min, lim.accel_max)
    return LB, UB, guess


BARRIERS = {
    # a monotone barrier from a small mu with a tight bound push: fewer iterations from the
    # curvature guess and in the oracle's continuation over tire margins
    "monotone": {"ipopt.mu_strategy": "monotone", "ipopt.mu_init": 1e-2, "ipopt.bound_push": 1e-6, "ipopt.bound_frac": 1e-6},
    # IPOPT's adaptive barrier with its default bound push: on the time trial's re-plans, warm-started
    # from the last plan, 66 % fewer iterations, and no false "infeasible" after 540 to 787
    # iterations as the monotone barrier gave on three of 22 (docs/decisions.md, issue 37 stop 48)
    "adaptive": {"ipopt.mu_strategy": "adaptive", "ipopt.mu_init": 0.1, "ipopt.bound_push": 1e-2, "ipopt.bound_frac": 1e-2},
}
"""IPOPT's barrier settings by name (:attr:`PlanSettings.barrier` first, then the other)."""


def _solve(model, settings: PlanSettings, n: int, h: float, ellipse: bool, args: dict, track) -> tuple[np.ndarray, dict]:
    """IPOPT with the barrier of ``settings.barrier``, then with the other if it failed (:data:`BARRIERS`)."""
    from gprace.interrupt import check as check_interrupt

    base = {
        "ipopt.print_level": settings.print_level, "print_time": 0, "ipopt.sb": "yes",
        "ipopt.max_iter": settings.max_iter, "ipopt.tol": settings.tol, "ipopt.linear_solver": "mumps",
        "ipopt.hessian_approximation": "exact", "expand": True,
    }
    for name in sorted(BARRIERS, key=lambda b: b != settings.barrier):
        attempt = BARRIERS[name]
        solver, lbg, ubg = _solver(model, settings, n, h, ellipse, {**base, **attempt, **_extra_opts()})
        sol = solver(**args, lbg=lbg, ubg=ubg)
        check_interrupt()  # IPOPT stops at Ctrl-C as if it had failed: that is no reason for another try
        stats = solver.stats()
        if ipopt_status(stats).usable:
            return np.asarray(sol["x"]).ravel(), stats
    raise SolverError(f"plan: IPOPT did not converge on {track.name!r} ({stats['return_status']}, {stats['iter_count']} iterations)")


_SOLVERS: dict = {}  # id(model) -> (weak reference to the model, {key: (solver, lbg, ubg)})
_SOLVERS_PER_MODEL = 4  # built solvers kept per model (node counts and options), the oldest dropped first


def _solver(model, settings: PlanSettings, n: int, h: float, ellipse: bool, opts: dict):
    """The IPOPT solver of :func:`_nlp` with ``opts`` and its constraint bounds, built once per
    model object, node layout, objective weights and options (a process keeps a few per model;
    a model that is gone takes its solvers with it)."""
    import weakref

    import casadi as ca

    # the model's numbers are in the key too: a model changed in place gets a new solver
    physics = (repr(getattr(model, "params", None)), repr(model.vehicle.limits),
               tuple(repr(vars(e)) for e in getattr(model, "effects", ())))
    key = (n, float(h), ellipse, float(settings.w_steer), float(settings.w_accel), settings.slip_max,
           settings.steer_rate, repr(sorted(opts.items())), physics)
    ref, kept = _SOLVERS.get(id(model), (None, None))
    if ref is None or ref() is not model:
        kept = {}
        try:
            ref = weakref.ref(model, lambda _, k=id(model): _SOLVERS.pop(k, None))
        except TypeError:  # no weak references: build every time
            ref = None
        if ref is not None:
            _SOLVERS[id(model)] = (ref, kept)
    if key not in kept:
        nlp, lbg, ubg = _nlp(model, settings, n, h, ellipse)
        kept[key] = (ca.nlpsol("plan", "ipopt", nlp, opts), lbg, ubg)
        while len(kept) > _SOLVERS_PER_MODEL:
            kept.pop(next(iter(kept)))
    return kept[key]


def ellipse_limits(model, settings: PlanSettings) -> tuple[float, float, float] | None:
    """``(a_lat, a_drive, a_brake)`` [m/s^2, all > 0] of the planner's friction ellipse, or None."""
    if settings.limits is not None:
        lat, drive, brake = (float(v) for v in settings.limits)
        if min(lat, drive, brake) <= 0:
            raise ConfigError(f"plan: friction-ellipse limits must be positive, got {settings.limits}")
        return lat, drive, brake
    if settings.grip is None:
        return None
    from gprace.plan.curvature import lateral_limit

    lim = model.vehicle.limits
    return (settings.grip * lateral_limit(model), settings.grip * lim.accel_max,
            -(settings.grip_brake or settings.grip) * lim.accel_min)


FRENET_REACH = 0.75
"""Share of the radius of the centre line's bend that ``e_y`` may reach on its inside."""


def frenet_bounds(kappa: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lateral bounds kept inside the region where the Frenet frame is regular (``1 - kappa e_y
    >= 1 - FRENET_REACH``). The frame is singular at the centre of curvature: on a track wider than
    the radius of its bends (the INI F1TENTH hairpin: radius 0.47 m, 0.9 m to each border) a
    minimum-time plan went through it (``1 - kappa e_y = -0.66``, progress counted backwards) and
    claimed a lap of 6.9 s."""
    reach = FRENET_REACH / np.maximum(np.abs(kappa), 1e-12)
    return (np.where(kappa < 0, np.maximum(lo, -reach), lo), np.where(kappa > 0, np.minimum(hi, reach), hi))


def _extra_opts() -> dict:
    """IPOPT options from ``GPRACE_IPOPT`` (JSON), for experiments."""
    import json
    import os

    text = os.environ.get("GPRACE_IPOPT")
    return {f"ipopt.{k}": v for k, v in json.loads(text).items()} if text else {}


def _resample(plan: Plan, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plan states (n, 6) and inputs (n, 2) at arc lengths ``s`` (periodic linear interpolation)."""
    L = plan.track_length
    sp = np.append(plan.s, L)
    cols = [np.interp(s, sp, np.append(a, a[0])) for a in (plan.v_x, plan.v_y, plan.yaw_rate, plan.e_psi, plan.e_y)]
    X = np.column_stack(cols + [s])
    U = np.column_stack([np.interp(s, sp, np.append(a, a[0])) for a in (plan.delta, plan.a_x)])
    return X, U
