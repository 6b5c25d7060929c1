"""A raceline back into a plan on a track (the reference a controller tracks, or a planner's warm
start): projected on the track (:func:`gprace.tracks.raceline.project_raceline`), its speed kept,
and the lateral velocity, yaw rate and steering of the steady corner of the nominal model, or of
the nominal model plus the tracking GP the car drives with (the states a raceline file does not
carry), as for the first, curvature-optimal plan. The raceline formats themselves are in
:mod:`gprace.tracks.raceline`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gprace.errors import InputError
from gprace.tracks.raceline import (
    Raceline,
    is_raceline,
    project_raceline,
    read_raceline,
    wrap_angle,
)


def plan_of_raceline(rl: Raceline, track, model, ds: float | None = None, gp=None, dt: float = 0.05):
    """The raceline as a :class:`~gprace.plan.Plan` on ``track`` (or on the track reversed, when
    the raceline runs the other way: ``plan.track_hash`` says which).

    At the plan's nodes (every ``ds`` of centre line; default the raceline's own point spacing
    scaled to the centre line) the offset ``e_y``, the path's heading and curvature and the speed
    are interpolated from the raceline; the lateral velocity, yaw rate and steering are those of
    the nominal model's steady corner at that speed and path curvature (the raceline files do not
    carry them), the body heading is the path heading minus the sideslip, and ``a_x`` the command
    that gives the raceline's change of speed in the nominal model.

    With ``gp``, the tracking GP the car drives with (``dt``: its step), the lateral velocity and
    the steering are those of the steady corner of the nominal model *plus the GP's mean*
    (:func:`compensated_corner`), where that corner is found; the references then ask for the
    sideslip the compensated MPC predicts, not the nominal tire's (issue 39, docs/decisions.md).
    """
    from gprace.plan.plan import Plan, track_hash
    from gprace.plan.steady import steady_state_inputs

    on = project_raceline(rl, track)
    trk = on.track
    L = trk.length
    h = float(ds) if ds is not None else float(np.median(np.diff(rl.s))) * L / rl.length
    smp = trk.sample(max(h, L / 20000))
    sn = smp.s
    # periodic interpolation over the unwrapped centre-line arc length of the points
    s0 = on.s
    sx = np.append(s0, s0[0] + L)

    def at(vals, angle=False):
        # the closing point repeats the first; an angle keeps its turn round the loop there
        v = np.unwrap(np.append(vals, vals[0])) if angle else np.append(vals, vals[0])
        return np.interp(np.mod(sn - s0[0], L) + s0[0], sx, v)

    e = at(on.e)
    heading = at(rl.heading, angle=True)
    kappa_p = at(rl.kappa)
    v = at(rl.vx)
    lim = model.vehicle.limits
    vy, r, delta = steady_state_inputs(model, v, kappa_p)
    beta = np.arctan2(vy, v)
    vx, vy = v * np.cos(beta), v * np.sin(beta)
    if gp is not None:
        X = np.column_stack([vx, vy, r, np.zeros_like(sn), e, sn])
        vy, delta = compensated_corner(model, gp, X, delta, smp.kappa, dt)
        beta = np.arctan2(vy, vx)
    epsi = wrap_angle(heading - trk.heading(sn)) - beta
    sdot = (vx * np.cos(epsi) - vy * np.sin(epsi)) / (1.0 - smp.kappa * e)
    hn = L / len(sn)
    dt = hn * 0.5 * (1 / sdot + 1 / np.roll(sdot, -1))
    t = np.concatenate([[0.0], np.cumsum(dt)])
    # the drive command that gives the raceline's change of speed in the model itself (drag,
    # rolling resistance and the longitudinal part of the front tire force in a corner: at constant
    # speed through the 1 m hairpin of the 1:10 loop that part alone is 0.25 m/s^2, and a car given
    # a_x = 0 there stalled)
    X = np.column_stack([vx, vy, r, epsi, e, sn])
    U0 = np.column_stack([delta, np.zeros_like(sn)])
    f0 = model.f(X, U0, smp.kappa)[:, 0]
    gain = model.f(X, U0 + [0.0, 1.0], smp.kappa)[:, 0] - f0
    a_x = (np.gradient(np.append(vx, vx[0]), t)[:-1] - f0) / np.where(np.abs(gain) > 1e-6, gain, 1.0)
    return Plan(s=sn, e_y=e, e_psi=epsi, v_x=vx, v_y=vy, yaw_rate=r, delta=np.clip(delta, -lim.steering_max, lim.steering_max),
                a_x=np.clip(a_x, lim.accel_min, lim.accel_max), t=t[:-1], lap_time=float(t[-1]), track=trk.name,
                track_length=L, track_hash=track_hash(trk), vehicle=model.vehicle.name, method="raceline",
                meta={"raceline": rl.source, "format": rl.fmt, "reversed": on.reversed, "ds": hn})

def compensated_corner(model, gp, X: np.ndarray, delta: np.ndarray, kappa: np.ndarray, dt: float,
                       iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """``(v_y, delta)`` per node of the steady corner of the model's RK4 step plus the tracking
    GP's mean: ``v_y`` and the yaw rate held over one step ``dt`` at the nodes' ``v_x`` and yaw rate
    (``X`` (n, 6)), with no drive command. Newton on both residuals of every node at once
    (finite-difference Jacobian, capped steps), started from zero rear slip and the kinematic
    steering: the stable corner is the one with the least slip, and a start on the nominal tire's
    flat top would stay there, far from the GP's data, where its mean is zero. A node whose solve
    does not settle keeps the nominal ``X[:, 1]`` and ``delta``.

    Measured (issue 39, Norisring, a plan learned from files): against the learned plan's own
    states the v_y references differ by 0.58 m/s rms (2.9 m/s at most) instead of 0.96 (5.8) with
    the nominal corner; the same solve with the GP's mean left out gives 0.95 (5.7)."""
    p = model.params
    X = np.array(X, dtype=float)
    lim = model.vehicle.limits.steering_max

    def residual(vy, dl):
        Xc = X.copy()
        Xc[:, 1] = vy
        U = np.column_stack([dl, np.zeros_like(dl)])
        mean, _ = gp.at(Xc, U)
        return (model.rk4(Xc, U, kappa, dt)[:, 1:3] + mean - Xc[:, 1:3]) / dt

    vy, d = p.lr * X[:, 2], np.clip((p.lf + p.lr) * np.asarray(kappa, dtype=float), -lim, lim)
    res = residual(vy, d)
    h = (1e-4, 1e-5)
    for _ in range(iterations):
        J = np.stack([(residual(vy + h[0], d) - res) / h[0], (residual(vy, d + h[1]) - res) / h[1]], axis=2)
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        ok = np.abs(det) > 1e-12
        det = np.where(ok, det, 1.0)
        step_vy = ok * (J[:, 1, 1] * res[:, 0] - J[:, 0, 1] * res[:, 1]) / det
        step_d = ok * (J[:, 0, 0] * res[:, 1] - J[:, 1, 0] * res[:, 0]) / det
        vy = vy - np.clip(step_vy, -0.3, 0.3)
        d = np.clip(d - np.clip(step_d, -0.01, 0.01), -lim, lim)
        res = residual(vy, d)
    settled = np.all(np.isfinite(res), axis=1) & (np.max(np.abs(res), axis=1) < 1e-2)
    return np.where(settled, vy, X[:, 1]), np.where(settled, d, np.asarray(delta, dtype=float))

def load_plan(path, track: str | None, vehicle, ds: float | None = None, gp=None, dt: float = 0.05):
    """``(plan, track)``: a plan file (on ``track``, default the plan's own by name), or a raceline
    CSV read as a plan (:func:`plan_of_raceline`) on ``track``, which a raceline needs; the track
    is returned in the direction the plan drives it. ``vehicle``: a name, path or VehicleConfig;
    ``gp``, ``dt``: the tracking GP a raceline's references are compensated with (a plan file
    carries its own states)."""
    from gprace.model import load_vehicle
    from gprace.model import NominalModel
    from gprace.plan import read_plan
    from gprace.tracks import load_track

    path = Path(path)
    if path.suffix.lower() in (".csv", ".txt") and path.exists() and is_raceline(path):
        if track is None:
            raise InputError(f"{path}: a raceline holds no track; give the track it was planned on (--track)")
        veh = load_vehicle(vehicle) if isinstance(vehicle, (str, Path)) else vehicle
        plan = plan_of_raceline(read_raceline(path), load_track(track), NominalModel(veh), ds, gp=gp, dt=dt)
        trk = load_track(track)
        return plan, (trk.reversed() if plan.meta["reversed"] else trk)
    plan = read_plan(path)
    trk = load_track(track or plan.track)
    plan.check_track(trk, str(path))
    return plan, trk
