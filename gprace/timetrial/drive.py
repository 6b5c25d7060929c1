"""Drive a plan on a plant with the tracking MPC and record the run (``gprace run``).

The car starts on the plan at ``s = 0`` with the plan's state (a flying lap), the MPC runs at
``dt`` and the plant integrates each period. Recorded per period: the measured Frenet state, the
applied input, curvature, lap counter, ``border_hit`` (footprint over an edge), ``solve_time``
of the QP, ``fallback`` (the QP failed, the shifted previous solution was applied) and
``explore`` (Algorithm 1 changed the reference), and the stability envelope's
(:mod:`gprace.mpc.stability`) ``e_r``, ``e_beta``, ``d_r``, ``d_beta``, ``envelope`` (its score, > 1 outside the band)
and ``speed_factor``; the meta counts its ``interventions`` and the ``weaves`` it damped. A car
that leaves the track, spins or stalls (:func:`gprace.sim.stop.run_end`) ends the run early
(``meta.completed = False``); the run is still returned, and marked as gprace's own (no user-file
unit check: a spun lap is data, never an input error).

A ``supervisor`` (the shakedown of :mod:`gprace.timetrial.shakedown`) is called after every
period with the loop's state and may swap the MPC's plan or its delay.
"""

from __future__ import annotations

import math
import time
import numpy as np
from pydantic import Field

from gprace.config import CommandSettings
from gprace.errors import InputError
from gprace.io.runs import OWN_RUN, Run
from gprace.model.dynamics import Input, State
from gprace.mpc.stability import SIGNALS, Envelope, EnvelopeSettings, braking_needed, corners, lagging_in_corner, signals
from gprace.mpc.tracking import MPCSettings, TrackingMPC
from gprace.sim.stop import run_end, step_plant
from gprace.timetrial.grip import rear_use


class DriveSettings(CommandSettings):
    """One run of a plan with the tracking MPC."""

    laps: float = Field(1.0, gt=0, description="laps to drive")
    mpc: MPCSettings = Field(default_factory=MPCSettings, description="the tracking MPC")
    envelope: EnvelopeSettings = Field(default_factory=EnvelopeSettings, description="the run-time stability envelope")


def start_state(plan, track, vehicle) -> tuple[np.ndarray, np.ndarray]:
    """Plan state and input at ``s = 0``; InputError if the car would start off the track."""
    X, U = plan.at_time(np.array([0.0]))
    x0, u0 = X[0], U[0]
    vx, epsi, ey, s = (x0[i] for i in (State.V_X, State.E_PSI, State.E_Y, State.S))
    wl, wr = float(track.width_left(s)), float(track.width_right(s))
    half = 0.5 * vehicle.width
    if not (-wr + half <= ey <= wl - half) or vx <= 0 or abs(epsi) > 1.0:
        raise InputError(
            f"plan: infeasible start state at s = {s:.1f} m (e_y = {ey:.2f} m with track [-{wr:.2f}, {wl:.2f}] m, "
            f"v_x = {vx:.2f} m/s, e_psi = {epsi:.2f} rad)"
        )
    return x0, u0


def drive(plan, plant_config, track, model, settings: DriveSettings = DriveSettings(), gp=None, grid=None,
          alpha: float = 0.0, seed: int = 0, band: tuple[float, float] | None = None, supervisor=None,
          sensors=None) -> Run:
    """Drive ``settings.laps`` laps; ``gp`` is a callable ``Z -> (mean, var)`` (the tracking GP);
    ``band`` the stability envelope's band from earlier laps (None: learned inside this run);
    ``sensors`` a :class:`gprace.mpc.sensors.SensorCalibration` the measurements are corrected by
    before the controller sees them (and as recorded)."""
    from gprace.plants import make_plant
    from gprace.sim.record import border_hits, lap_times_of, run_columns
    from gprace.timetrial.learning import in_control

    plan.check_track(track, "plan")
    dt = settings.mpc.dt
    if seed:
        plant_config = plant_config.model_copy(update={"seed": plant_config.seed + 1_000_003 * seed})
    mpc = TrackingMPC(model, track, plan, settings.mpc, gp=gp, grid=grid, alpha=alpha)
    x0, u0 = start_state(plan, track, model.vehicle)
    plant = make_plant(plant_config, track, dt)
    correct = sensors.apply if sensors is not None else (lambda y: y)
    y = correct(plant.reset(x0, u0))
    mpc.reset(delta_prev=float(u0[Input.DELTA]), a_prev=float(u0[Input.A_X]))
    u_prev = np.asarray(u0, float)

    goal = settings.laps * track.length
    v_stall = min(1.0, 0.5 * float(plan.v_x.min()))  # 1 m/s, or half the plan's slowest corner (1:10 cars)
    n_max = int(math.ceil(settings.laps * plan.lap_time * 2.0 / dt)) + 40
    vehicle = model.vehicle
    Y, X, U = np.empty((n_max + 1, 6)), np.empty((n_max + 1, 6)), np.empty((n_max + 1, 2))  # X: true states
    cols = {k: np.zeros(n_max + 1) for k in COLUMNS}
    env = Envelope(settings.envelope, dt, band)
    before = None  # the state the last solution predicted for this period
    plan_brake = 0.0  # the hardest braking the plan asks for over the horizon (before easing)
    ahead = (None, None)  # (plan, its corners): found again only when the shakedown swaps the plan
    delay_bumped = False  # the MPC's delay is lengthened once, at the first weave
    k = 0
    wall = time.perf_counter()
    while True:
        mpc.speed_factor = env.rho
        mpc.steer_damping = env.steer_damping
        if env.weaves and not delay_bumped:  # a weave: the delay was read short (EnvelopeSettings.weave_delay)
            delay_bumped = True
            mpc.set_delay(min(mpc.delay + settings.envelope.weave_delay, mpc.N * mpc.dt))
        mpc.use_gp = not (settings.envelope.nominal_when_active and env.active and _novel(gp, y, u_prev))
        lateral = float(y[State.V_X] * y[State.YAW_RATE])
        rear = float(rear_use(y[None, :], model)[0])
        limits = mpc.plan_limits()  # (lateral, drive, brake) of the plan driven this period
        brake_limit = limits[2]
        needed = 0.0
        if env.active:  # the braking that makes the plan's corners from half a second to a gentle stop ahead
            v = float(y[State.V_X])
            reach = v * v / (2.0 * settings.envelope.gentle_brake * brake_limit)
            if ahead[0] is not mpc.plan:
                ahead = (mpc.plan, corners(mpc.plan.s, mpc.plan.v_x))
            needed = braking_needed(ahead[1], track.length, float(y[State.S]), v, reach, near=v * settings.envelope.hold)
        # the envelope's braking stays inside the plan's friction ellipse (lateral and braking limits)
        mpc.bounds = env.input_bounds(mpc.u_lo, mpc.u_hi, plan_brake, lateral, limits[0], rear, brake_limit, needed)
        u, info = mpc.step(y)
        u_prev = u
        plan_brake = float(info["uref"][:, Input.A_X].min()) / mpc.speed_factor**2
        x = plant.state
        Y[k], X[k], U[k] = y, x, u
        sig = signals(mpc.predicted, before, info["xref"][0])
        before = mpc.prev_x[0]
        _log(cols, k, plant.lap, info, mpc, sig, env.rho)
        lagging = lagging_in_corner(mpc.predicted, info["xref"][0], limits[0], settings.envelope.recover_corner)
        cols["envelope"][k] = env.update(sig, bool(in_control(y[None, :])[0]), lagging)
        k += 1
        if (reason := run_end(track, plant, vehicle.width, v_stall, goal, k, n_max, "no lap")) is not None:
            break
        if supervisor is not None:
            supervisor(k, Y[:k], U[:k], mpc, env)
        y, reason = step_plant(plant, u)
        if reason:
            break
        y = correct(y)
    data = {
        **run_columns(track, dt, Y[:k], U[:k]),
        **{c: v[:k] for c, v in cols.items()},
        "border_hit": border_hits(track, X[:k], vehicle.length, vehicle.width).astype(float),
    }
    lap_times = lap_times_of(data["t"], data["lap"])
    st = data["solve_time"]
    meta = {
        "vehicle_toml": vehicle.to_toml(), "track": track.name, "dt": dt, "plant": plant_config.kind,
        "plant_hash": plant_config.digest(), "completed": not reason, "reason": reason,
        "lap_times": lap_times, "lap_time": lap_times[0] if lap_times else float("nan"),
        "planned_lap_time": float(plan.lap_time), "alpha": float(alpha), "solver": settings.mpc.solver,
        "fallbacks": int(mpc.fallbacks), "steps": int(k), "border_hit_steps": int(data["border_hit"].sum()),
        "border_hit": bool(data["border_hit"].any()),
        "solve_time_median": float(np.median(st)) if k else float("nan"),
        "solve_time_p99": float(np.quantile(st, 0.99)) if k else float("nan"),
        "wall_time": time.perf_counter() - wall, "seed": int(seed), "gp": gp is not None, OWN_RUN: True,
        "interventions": int(env.interventions), "weaves": int(env.weaves), "eased_steps": int(env.eased),
        "band": [float(b) for b in env.band],
        "delay": float(mpc.delay),
        **({"sensors": sensors.as_dict()} if sensors is not None and not sensors.identity else {}),
    }
    return Run(data, meta, source=f"drive({plant_config.kind}, {track.name})")


COLUMNS = ("lap", "solve_time", "fallback", "explore", "gamma", *SIGNALS, "envelope", "speed_factor")
"""The columns a drive logs per period besides the state and input (module docstring)."""


def _log(cols: dict, k: int, lap: int, info: dict, mpc, sig, rho: float) -> None:
    """Period ``k``'s MPC and envelope columns (all of :data:`COLUMNS` but ``envelope``)."""
    cols["lap"][k] = lap
    cols["solve_time"][k] = info["solve_time"]
    cols["fallback"][k] = float(info["fallback"])
    cols["explore"][k] = float(mpc.last_target is not None and info.get("explored", False))
    cols["gamma"][k] = float(info["gamma"][0]) if len(info["gamma"]) else 0.0
    for name, v in zip(SIGNALS, sig):
        cols[name][k] = v
    cols["speed_factor"][k] = rho


EXTRAPOLATING = 0.5  # latent std over prior std above which the tracking GP counts as extrapolating


def _novel(gp, y: np.ndarray, u: np.ndarray) -> bool:
    """True where the tracking GP extrapolates at the measured state (its latent std above
    ``EXTRAPOLATING`` of its prior std; a backend without a prior variance: its predictive std above
    ``guard.NOVEL_STD`` times its noise std), or for a GP that cannot say: there the stability
    envelope's nominal model replaces it. Where the GP has data it stays on.

    Measured (re-drives of single laps, docs/decisions.md issue 37 stop 45): on audi_hidden, whose
    nominal model lacks its downforce, switching a well-fed GP off under the envelope left the track
    at s = 1480.2 m on a plan completed twice before (extrapolation along that lap at most 0.07);
    on randomized_09 the GP of iteration 1, fed by one slow lap, kept steering the sliding car into
    the hairpin (extrapolation median 0.78, up to 1.0) and spun it, and completes with the nominal
    model under the envelope. The noise-relative novelty could not tell: that GP's signal std is
    1.3 times its noise std, so its novelty never exceeds 1.65.
    """
    from gprace.timetrial.guard import NOVEL_STD

    if gp is None or not hasattr(gp, "extrapolation"):
        return True
    y, u = y[None, :], np.asarray(u, float)[None, :]
    share = float(gp.extrapolation(y, u)[0])
    return share > EXTRAPOLATING if np.isfinite(share) else bool(gp.novelty(y, u)[0] > NOVEL_STD)
