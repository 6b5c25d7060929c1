"""The car model of the ``randomized`` plant: per-wheel loads, load-sensitive tires, relaxation.

A physics model the nominal bicycle (:mod:`gprace.model.dynamics`) and its effect catalogue do not
contain, written once for numpy (vectorised over states) and CasADi (compiled control periods):

* **state** ``x``: the nominal ``[v_x, v_y, yaw_rate, e_psi, e_y, s]`` (``State``; Frenet, SI),
  then (:class:`Extra`) the tires' lagged slip angles ``alpha_f, alpha_r`` [rad] and the accelerations the chassis
  has settled to, ``a_x, a_y`` [m/s^2] (they set the load transfer).
* **inputs**: the actual road-wheel angle ``delta`` [rad] (the steering actuator is solved in
  closed form outside, :func:`gprace.plants.randomized.steering_path`) and the commanded
  acceleration ``a_x`` [m/s^2]; the track curvature ``kappa`` at ``s``.

Physics per period of integration (``p`` a :class:`CarParams`):

* **loads** per wheel: static axle load, plus the downforce ``c_l v_x^2`` (front share
  ``aero_front``), minus/plus the longitudinal transfer ``m h a_x / L``; each axle's two wheels
  then differ by the lateral transfer ``roll_front m h a_y / t_f`` (rear: ``1 - roll_front``,
  ``t_r``). ``a_x, a_y`` follow the chassis' real accelerations with the lag ``load_lag`` (roll
  and pitch do not settle at once, and this keeps the loads explicit: no algebraic loop).
  A wheel load never goes below zero (wheel lift).
* **tires**: the nominal simplified Magic Formula per wheel with a load-sensitive friction
  ``mu_w = mu_axle (1 - k_load (F_z,w - F_z0)/F_z0)``; ``F_z0 = m g / 4`` is the tire's rated
  load (the same tire on every corner, so a heavier axle has a little less friction per newton:
  a mild understeer, as on real cars), ``mu_axle`` the nominal mu times the axle's grip factor.
  Lateral load transfer and downforce so cost grip as on a real tire. The axle's ``B`` is the
  nominal one over the grip factor: grip moves the peak force, not the cornering stiffness
  ``B C mu F_z`` (wear and temperature change the peak far more than the initial slope).
* **relaxation**: with ``sigma > 0`` the slip angle a tire acts on lags the kinematic one,
  ``sigma / v_x * alpha' + alpha = alpha_kin`` (time constant ``sigma / v_x``).
* **combined slip** (``combined = 1``): the longitudinal force of each wheel (drive shared by
  ``drive_rear``, braking by the current axle loads, half per wheel) is capped at
  ``0.98 mu_w F_z,w`` and the lateral force shrinks on the friction ellipse,
  ``F_y = F_y0 sqrt(1 - (F_x / (mu_w F_z,w))^2)``; a left/right difference of the capped forces
  turns the car. Without it the command ``m a_x`` acts whole, as in the nominal model.
* **body**: the nominal equations with the summed axle forces, wind drag ``c_xw v_x^2`` and
  rolling resistance, ``I_zz`` of the drawn car.

With every effect off (``h = 0``, ``c_l = 0``, ``k_load = 0``, ``sigma = 0``, ``combined = 0``,
grip factors 1, nominal ``I_zz`` and drag) this is exactly the nominal bicycle. ``sigma`` and
``combined`` switch terms on or off and must be scalars; the other fields may be arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum
from typing import Any, Sequence

from gprace.config import G

SIGMA_MIN = 0.05
"""Relaxation lengths below this [m, full-size car] are taken as none (a lag under 1 ms at 50 m/s)."""

SATURATION = 0.98
"""Share of ``mu_w F_z,w`` a wheel's longitudinal force is capped at under combined slip."""


class Extra(IntEnum):
    """States after the nominal six (:class:`gprace.model.State`), units in the module docstring."""

    ALPHA_F = 6
    ALPHA_R = 7
    A_X = 8
    A_Y = 9


NX = 6 + len(Extra)


@dataclass(frozen=True)
class CarParams:
    """Physical parameters of one drawn car (SI); floats, or arrays broadcasting over states."""

    m: float
    iz: float
    lf: float
    lr: float
    track_f: float  # wheel track (left-right wheel distance) [m]
    track_r: float
    h: float  # CoG height for load transfer [m]
    mu_f: float  # peak friction of the axle's tires at their rated load m g / 4
    mu_r: float
    bf: float  # Magic Formula B of the axle (nominal B / grip factor)
    cf: float
    br: float
    cr: float
    cxw: float  # wind drag [kg/m]
    crr: float
    c_l: float  # downforce coefficient [N s^2/m^2]
    aero_front: float  # share of the downforce on the front axle
    roll_front: float  # share of the lateral load transfer taken by the front axle
    k_load: float  # tire load sensitivity
    sigma: float  # relaxation length [m]; 0: none
    combined: float  # 1: friction ellipse; 0: the command acts whole
    drive_rear: float  # share of the drive force on the rear axle
    load_lag: float  # time constant of the load transfer [s]
    vmin: float
    g: float = G

    def replace(self, **kw: Any) -> "CarParams":
        return CarParams(**{**{f.name: getattr(self, f.name) for f in fields(self)}, **kw})

    @property
    def relaxed(self) -> bool:
        return bool(self.sigma > 0)


def derivative(x: Sequence[Any], delta: Any, ax_cmd: Any, kappa: Any, p: CarParams, ops) -> list[Any]:
    """``dx/dt`` as a list of :data:`NX` components (numpy arrays or CasADi expressions)."""
    vx, vy, r, epsi, ey, s, alf, alr, axl, ayl = (x[i] for i in range(NX))
    L = p.lf + p.lr
    vxs = ops.fmax(vx, p.vmin)
    cd, sd = ops.cos(delta), ops.sin(delta)

    # slip angles: kinematic, or lagged by the relaxation length
    kin_f = delta - ops.atan((vy + p.lf * r) / vxs)
    kin_r = -ops.atan((vy - p.lr * r) / vxs)
    if p.relaxed:
        a_f, a_r = alf, alr
        dalf, dalr = vxs / p.sigma * (kin_f - alf), vxs / p.sigma * (kin_r - alr)
    else:
        a_f, a_r = kin_f, kin_r
        dalf = dalr = 0.0 * vx

    # wheel loads
    fz0_f, fz0_r = p.m * p.g * p.lr / L, p.m * p.g * p.lf / L  # static axle loads
    fz0w = 0.25 * p.m * p.g  # rated load of the tires
    aero = p.c_l * vx * vx
    dlong = p.m * p.h * axl / L
    fz_f = fz0_f + p.aero_front * aero - dlong
    fz_r = fz0_r + (1.0 - p.aero_front) * aero + dlong
    dlat_f = p.roll_front * p.m * p.h * ayl / p.track_f
    dlat_r = (1.0 - p.roll_front) * p.m * p.h * ayl / p.track_r
    wheels = (  # (axle, side): side +1 right (outer in a left turn), -1 left
        (fz_f, dlat_f, p.mu_f, p.bf, p.cf, a_f),
        (fz_r, dlat_r, p.mu_r, p.br, p.cr, a_r),
    )

    # longitudinal demand per axle: drive shared by drive_rear, braking by the axle loads
    fx = p.m * ax_cmd
    drive, brake = ops.fmax(fx, 0.0), ops.fmin(fx, 0.0)
    share_f = fz_f / (fz_f + fz_r)
    fx_axle = (drive * (1.0 - p.drive_rear) + brake * share_f, drive * p.drive_rear + brake * (1.0 - share_f))

    fy_axle, fx_sum, yaw_fx = [], 0.0, 0.0
    for (fz, dlat, mu, b, c, alpha), fxa, half_track in zip(wheels, fx_axle, (0.5 * p.track_f, 0.5 * p.track_r)):
        fy_a = 0.0
        for side in (-1.0, 1.0):
            fzw = ops.fmax(0.5 * fz + side * dlat, 0.0)
            muw = mu * (1.0 - p.k_load * (fzw - fz0w) / fz0w)
            fy0 = muw * fzw * ops.sin(c * ops.atan(b * alpha))
            dem = 0.5 * fxa
            if p.combined:
                cap = SATURATION * muw * fzw
                fxw = ops.fmax(ops.fmin(dem, cap), -cap)
                ratio = fxw / ops.fmax(muw * fzw, 1e-9)
                fyw = fy0 * ops.sqrt(ops.fmax(1.0 - ratio * ratio, 0.0))
            else:
                fxw, fyw = dem, fy0
            fy_a = fy_a + fyw
            fx_sum = fx_sum + fxw
            yaw_fx = yaw_fx + side * half_track * fxw
        fy_axle.append(fy_a)
    fy_f, fy_r = fy_axle

    rx = p.crr * p.m * p.g
    fxw_drag = p.cxw * vx * vx
    ax_body = (fx_sum - fy_f * sd - rx - fxw_drag) / p.m  # acceleration along the car's axis
    ay_body = (fy_f * cd + fy_r) / p.m
    vx_dot = ax_body + r * vy
    vy_dot = ay_body - r * vx
    r_dot = (p.lf * fy_f * cd - p.lr * fy_r + yaw_fx) / p.iz
    s_dot = (vx * ops.cos(epsi) - vy * ops.sin(epsi)) / (1.0 - kappa * ey)
    epsi_dot = r - kappa * s_dot
    ey_dot = vx * ops.sin(epsi) + vy * ops.cos(epsi)
    return [vx_dot, vy_dot, r_dot, epsi_dot, ey_dot, s_dot, dalf, dalr,
            (ax_body - axl) / p.load_lag, (ay_body - ayl) / p.load_lag]


def initial_state(x6: Sequence[float], delta: float, ax: float, p: CarParams) -> list[float]:
    """The full state of a car placed at Frenet state ``x6`` with the road-wheel angle ``delta``
    and acceleration ``ax``: slip angles at their kinematic values, chassis settled to ``a_x`` and
    the steady lateral acceleration ``v_x r``."""
    import math

    vx, vy, r = float(x6[0]), float(x6[1]), float(x6[2])
    vxs = max(vx, p.vmin)
    return [*map(float, x6[:6]), delta - math.atan((vy + p.lf * r) / vxs), -math.atan((vy - p.lr * r) / vxs),
            float(ax), vx * r]
