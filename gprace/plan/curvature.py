"""The GP-free first path: minimum curvature line plus a friction-limited speed profile.

Iteration 0 of the time trial tracks this path with the nominal MPC (paper, section "Time
Trial": "a curvature-optimal path"). The line minimises the summed squared curvature of the path,
linearised about the centre line (``kappa_p ~ kappa + kappa^2 e + e''``), inside the track minus
half the car width (a bounded linear least-squares problem). The speed profile is the classic
forward-backward pass: the lateral limit ``v^2 |kappa_p| <= a_lat`` (``a_lat`` is the model's own
steady-state limit, scaled by ``speed_scale``), acceleration and braking limits shared with the
lateral demand on a friction ellipse, drag on the drive side.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import sparse

from gprace.plan.plan import Plan, track_hash
from gprace.plan.steady import max_corner_speed, steady_state_inputs


def lateral_limit(model) -> float:
    """Steady lateral acceleration limit of the model on a 100 m-ish corner [m/s^2]."""
    scale = max(model.vehicle.wheelbase, 0.1)
    return max_corner_speed(model, radius=40.0 * scale)["a_lat"]


def min_curvature_offsets(kappa: np.ndarray, lo: np.ndarray, hi: np.ndarray, h: float) -> np.ndarray:
    """Lateral offsets ``e`` (n,) of the closed minimum-curvature line between bounds ``lo, hi``."""
    n = len(kappa)
    i = np.arange(n)
    D2 = sparse.csr_matrix(
        (np.concatenate([np.ones(n), -2 * np.ones(n), np.ones(n)]) / h**2,
         (np.concatenate([i, i, i]), np.concatenate([(i - 1) % n, i, (i + 1) % n]))),
        shape=(n, n),
    )
    A = (D2 + sparse.diags(kappa**2)).tocsc()
    lo = np.minimum(lo, hi - 1e-6)
    return _bounded_least_squares(A, -kappa, lo, hi)


def _bounded_least_squares(A, b, lo, hi) -> np.ndarray:
    """``argmin |A e - b|^2`` with ``lo <= e <= hi`` as a sparse QP (Clarabel)."""
    import clarabel

    n = A.shape[1]
    scale = 1.0 / max(float(np.max(np.abs(A.data))), 1e-12)  # conditioning: O(1) entries
    As, bs = A * scale, b * scale
    P = sparse.triu(2.0 * (As.T @ As)).tocsc()
    q = -2.0 * (As.T @ bs)
    eye = sparse.identity(n, format="csc")
    G = sparse.vstack([eye, -eye]).tocsc()
    h = np.concatenate([hi, -lo])
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    sol = clarabel.DefaultSolver(P, q, G, h, [clarabel.NonnegativeConeT(2 * n)], settings).solve()
    e = np.asarray(sol.x)
    if not np.all(np.isfinite(e)):
        return np.clip(np.zeros(n), lo, hi)
    return np.clip(e, lo, hi)


def speed_profile(kappa_p: np.ndarray, ds: np.ndarray, a_lat: float, a_acc: float, a_brake: float, v_max: float,
                  drag_per_mass: float = 0.0) -> np.ndarray:
    """Forward-backward speed profile on a closed path (node spacing ``ds`` (n,) to the next node).

    Sequential by nature (each node depends on its neighbour); it runs once per plan, three laps
    around so the periodic start settles.
    """
    n = len(kappa_p)
    v_lim = np.minimum(np.sqrt(a_lat / np.maximum(np.abs(kappa_p), 1e-9)), v_max)
    v = v_lim.copy()

    def ellipse(vk, k):
        lat = vk**2 * abs(kappa_p[k]) / a_lat
        return np.sqrt(max(0.0, 1.0 - min(lat, 1.0) ** 2))

    for _ in range(3):
        for j in range(n):  # forward: acceleration
            k, k1 = j, (j + 1) % n
            acc = a_acc * ellipse(v[k], k) - drag_per_mass * v[k] ** 2
            v[k1] = min(v[k1], np.sqrt(max(v[k] ** 2 + 2 * max(acc, 0.0) * ds[k], 0.0)))
        for j in range(n - 1, -1, -1):  # backward: braking
            k, k1 = j, (j + 1) % n
            dec = a_brake * ellipse(v[k1], k1) + drag_per_mass * v[k1] ** 2
            v[k] = min(v[k], np.sqrt(v[k1] ** 2 + 2 * dec * ds[k]))
    return v


@dataclass(frozen=True)
class Line:
    """The minimum-curvature line of a track: offsets, heading error and curvature of the path at
    ``n`` nodes ``h`` apart, and the path length per centre-line metre (``ds_p``)."""

    track: Any
    s: np.ndarray
    e: np.ndarray
    epsi: np.ndarray
    kappa_p: np.ndarray
    ds_p: np.ndarray
    scale: np.ndarray  # 1 - kappa e
    h: float


def racing_line(track, model, ds: float = 6.0, margin: float = 0.3) -> Line:
    """The minimum-curvature line, ``margin`` from the borders on top of half the car width."""
    smp = track.sample(ds)
    s, kappa = smp.s, smp.kappa
    n = len(s)
    h = track.length / n
    half = 0.5 * model.vehicle.width + margin
    lo, hi = -smp.wr + half, smp.wl - half
    e = min_curvature_offsets(kappa, lo, hi, h)
    # geometry of the offset line from its global points (periodic central differences)
    X, Y = track.to_global(s, e)
    dX, dY = (np.roll(X, -1) - np.roll(X, 1)) / 2, (np.roll(Y, -1) - np.roll(Y, 1)) / 2
    ddX, ddY = np.roll(X, -1) - 2 * X + np.roll(X, 1), np.roll(Y, -1) - 2 * Y + np.roll(Y, 1)
    kappa_p = (dX * ddY - dY * ddX) / np.maximum(np.hypot(dX, dY), 1e-12) ** 3
    epsi = np.angle(np.exp(1j * (np.arctan2(dY, dX) - track.heading(s))))
    ds_p = np.hypot(np.roll(X, -1) - X, np.roll(Y, -1) - Y) / h
    return Line(track, s, e, epsi, _smooth(kappa_p), ds_p, 1.0 - kappa * e, h)


def line_plan(line: Line, model, limits, meta: dict | None = None) -> Plan:
    """The line driven at the friction-limited speed profile of ``limits`` = (lateral, drive,
    brake) [m/s^2, all > 0], with the steady-state sideslip, yaw rate and steering of each node."""
    a_lat, a_drive, a_brake = (float(v) for v in limits)
    lim, p = model.vehicle.limits, model.params
    track, h = line.track, line.h
    v = speed_profile(line.kappa_p, line.ds_p * h, a_lat, a_drive, a_brake, lim.speed_max, p.cxw / p.m)
    vy, r, delta = steady_state_inputs(model, v, line.kappa_p)
    beta = np.arctan2(vy, v)  # sideslip: the body points off the path by -beta
    vx = v * np.cos(beta)
    vy = v * np.sin(beta)
    epsi = line.epsi - beta
    sdot = (vx * np.cos(epsi) - vy * np.sin(epsi)) / line.scale
    dt = h * 0.5 * (1 / sdot + 1 / np.roll(sdot, -1))
    t = np.concatenate([[0.0], np.cumsum(dt)])
    ax = np.gradient(np.append(vx, vx[0]), t)[:-1] + (p.cxw * vx**2) / p.m + p.crr * p.g
    ax = np.clip(ax, lim.accel_min, lim.accel_max)
    return Plan(
        s=line.s, e_y=line.e, e_psi=epsi, v_x=vx, v_y=vy, yaw_rate=r, delta=delta, a_x=ax, t=t[:-1],
        lap_time=float(t[-1]), track=track.name, track_length=track.length, track_hash=track_hash(track),
        vehicle=model.vehicle.name, method="min_curvature",
        meta={"ds": h, "limits": [a_lat, a_drive, a_brake], **(meta or {})},
    )


def curvature_plan(track, model, ds: float = 6.0, speed_scale: float = 0.85, margin: float = 0.3,
                   a_lat: float | None = None, limits=None) -> Plan:
    """The minimum-curvature line with its speed profile, as a :class:`Plan` (method ``min_curvature``).

    ``speed_scale`` scales the lateral and braking limits (the drive limit stays the vehicle's);
    ``limits`` = (lateral, drive, brake) [m/s^2] gives all three instead. ``margin`` is kept from
    the borders on top of half the car width.
    """
    if a_lat is None:
        a_lat = lateral_limit(model)
    lim = model.vehicle.limits
    if limits is None:
        limits = (speed_scale * a_lat, lim.accel_max, -speed_scale * lim.accel_min)
    return line_plan(racing_line(track, model, ds, margin), model, limits, {"speed_scale": speed_scale, "a_lat": a_lat})


def _smooth(a: np.ndarray, w: int = 2) -> np.ndarray:
    """Periodic moving average over ``2w+1`` nodes (curvature from second differences is noisy)."""
    k = np.ones(2 * w + 1) / (2 * w + 1)
    ext = np.concatenate([a[-w:], a, a[:w]])
    return np.convolve(ext, k, mode="valid")
