"""The paper's Frenet dynamic bicycle model (eq. "dynamic_bicycle_model"), written once.

State ``x = [v_x, v_y, yaw_rate, e_psi, e_y, s]`` (then any effect states), input
``u = [delta, a_x]``, track curvature ``kappa`` at the car's ``s``::

    v_x'  = a_x - (F_yf sin(delta) + R_x + F_xw)/m - g sin(phi) + yaw_rate v_y
    v_y'  = (F_yf cos(delta) + F_yr)/m - yaw_rate v_x
    r'    = (l_f F_yf cos(delta) - l_r F_yr)/I_zz
    e_psi'= r - kappa s'
    e_y'  = v_x sin(e_psi) + v_y cos(e_psi)
    s'    = (v_x cos(e_psi) - v_y sin(e_psi)) / (1 - kappa e_y)

with ``R_x = c_rr m g``, ``F_xw = C_xw v_x^2``, flat road (``phi = 0``) and the simplified Magic
Formula ``F_y = mu F_z sin(C atan(B alpha))`` on static axle loads. Slip angles
``alpha_f = delta - atan((v_y + l_f r)/v_x)``, ``alpha_r = -atan((v_y - l_r r)/v_x)`` with ``v_x``
floored at ``v_min``.

Inputs as a recording has them (issue 36): the road-wheel angle is ``delta = k_delta u_0 +
delta_0`` (steering gain and offset of the vehicle, 1 and 0 unless calibrated), and ``u_1`` drives
``v_x`` in one of three ways (:data:`LONGITUDINAL`, ``Params.longitudinal``):

- ``"force"``: ``u_1`` is the commanded powertrain acceleration ``a_x`` (the paper's model above);
- ``"kinematic"``: ``u_1`` is a measured (IMU) or derived acceleration, which already holds every
  longitudinal force: ``v_x' = a_x + r v_y - g sin(phi)`` (drag and rolling resistance are not
  subtracted again; an accelerometer does not feel the grade, hence its term);
- ``"speed"``: ``u_1`` is a speed command ``v_cmd`` followed by the car's first-order speed loop,
  ``a_x = (k_v v_cmd - v_x) / tau_v``, which then drives the force model.

The computation runs as a pipeline of named stages (inputs -> loads -> tire -> forces); each effect
of :mod:`gprace.model.effects` hooks into the stages it changes. The same function builds the
numpy evaluation and the CasADi graph (``ops``), which is the "one symbolic definition".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from types import SimpleNamespace
from typing import Any, Sequence

from gprace.config import G, VehicleConfig

STATE = ("v_x", "v_y", "yaw_rate", "e_psi", "e_y", "s")
INPUT = ("delta", "a_x")
NX, NU = 6, 2
LONGITUDINAL = ("force", "kinematic", "speed")
"""How the second input drives v_x: commanded a_x, measured/derived a_x, or a speed command."""


class State(IntEnum):
    """Index of each entry of the car state (named in :data:`STATE`): ``x[State.E_Y]``, ``X[:, State.S]``."""

    V_X = 0
    V_Y = 1
    YAW_RATE = 2
    E_PSI = 3
    E_Y = 4
    S = 5


class Input(IntEnum):
    """Index of each input (named in :data:`INPUT`)."""

    DELTA = 0
    A_X = 1


@dataclass(frozen=True)
class Params:
    """Numeric nominal parameters (SI), one frozen object instead of many floats."""

    m: float
    iz: float
    lf: float
    lr: float
    h: float
    mu: float
    cxw: float
    crr: float
    bf: float
    cf: float
    br: float
    cr: float
    vmin: float
    g: float = G
    steer_gain: float = 1.0  # road-wheel angle per unit of the steering input
    steer_offset: float = 0.0  # [rad] added to the road-wheel angle
    longitudinal: str = "force"  # one of LONGITUDINAL
    speed_tau: float = 0.5  # [s] time constant of the speed loop ("speed" only)
    speed_gain: float = 1.0  # speed the loop aims at per unit of the command ("speed" only)

    @classmethod
    def from_vehicle(cls, v: VehicleConfig, longitudinal: str = "force") -> "Params":
        if longitudinal not in LONGITUDINAL:
            raise ValueError(f"longitudinal input {longitudinal!r}; expected one of {', '.join(LONGITUDINAL)}")
        return cls(
            m=v.mass, iz=v.yaw_inertia, lf=v.l_f, lr=v.l_r, h=v.cog_height, mu=v.mu,
            cxw=v.drag_coefficient, crr=v.rolling_resistance,
            bf=v.tire.b_front, cf=v.tire.c_front, br=v.tire.b_rear, cr=v.tire.c_rear, vmin=v.v_min,
            steer_gain=v.steering_gain, steer_offset=v.steering_offset, longitudinal=longitudinal,
            speed_tau=v.speed_loop_tau, speed_gain=v.speed_loop_gain,
        )

    @property
    def fz_front(self) -> float:
        return self.m * self.g * self.lr / (self.lf + self.lr)

    @property
    def fz_rear(self) -> float:
        return self.m * self.g * self.lf / (self.lf + self.lr)


def peak_slip(b: float, c: float) -> float:
    """Slip angle [rad] of the peak of ``sin(C atan(B alpha))``: ``tan(pi / (2 C)) / B``."""
    return math.tan(math.pi / (2.0 * c)) / b if c > 1.0 else math.pi / 2


def dynamics(x: Sequence[Any], u: Sequence[Any], kappa: Any, p: Params, effects: Sequence[Any], ops) -> list[Any]:
    """Continuous-time derivative as a list of components (numpy arrays or CasADi expressions).

    ``x`` and ``u`` are sequences of components (each an (n,) array or a scalar symbol).
    """
    c = SimpleNamespace(ops=ops, p=p, kappa=kappa)
    c.vx, c.vy, c.r, c.epsi, c.ey, c.s = x[:NX]
    c.z = list(x[NX:])
    c.delta_cmd, c.ax_cmd = u
    if not (_is(p.steer_gain, 1.0) and _is(p.steer_offset, 0.0)):  # the road-wheel angle commanded
        c.delta_cmd = p.steer_gain * c.delta_cmd + p.steer_offset
    if p.longitudinal == "speed":  # the car's speed loop turns the speed command into a_x
        c.ax_cmd = (p.speed_gain * c.ax_cmd - c.vx) / p.speed_tau
    c.delta, c.ax = c.delta_cmd, c.ax_cmd
    _run(effects, "inputs", c)

    c.fz_f, c.fz_r = p.fz_front, p.fz_rear
    _run(effects, "loads", c)

    c.mu_f = c.mu_r = p.mu
    c.b_f, c.c_f, c.b_r, c.c_r = p.bf, p.cf, p.br, p.cr
    _run(effects, "tire", c)

    vxs = ops.fmax(c.vx, p.vmin)
    c.alpha_f = c.delta - ops.atan((c.vy + p.lf * c.r) / vxs)
    c.alpha_r = -ops.atan((c.vy - p.lr * c.r) / vxs)
    c.fy_f = c.mu_f * c.fz_f * ops.sin(c.c_f * ops.atan(c.b_f * c.alpha_f))
    c.fy_r = c.mu_r * c.fz_r * ops.sin(c.c_r * ops.atan(c.b_r * c.alpha_r))

    c.rx = p.crr * p.m * p.g
    c.fxw = p.cxw * c.vx * c.vx
    c.grade = 0.0  # road inclination phi [rad]
    c.f_lat = 0.0  # extra lateral force (road bank) [N]
    c.iz = p.iz
    _run(effects, "forces", c)

    cd, sd = ops.cos(c.delta), ops.sin(c.delta)
    if p.longitudinal == "kinematic":  # a_x measured: every longitudinal force is inside it
        vx_dot = c.ax - p.g * ops.sin(c.grade) + c.r * c.vy
    else:
        vx_dot = c.ax - (c.fy_f * sd + c.rx + c.fxw) / p.m - p.g * ops.sin(c.grade) + c.r * c.vy
    vy_dot = (c.fy_f * cd + c.fy_r + c.f_lat) / p.m - c.r * c.vx
    r_dot = (p.lf * c.fy_f * cd - p.lr * c.fy_r) / c.iz
    s_dot = (c.vx * ops.cos(c.epsi) - c.vy * ops.sin(c.epsi)) / (1.0 - c.kappa * c.ey)
    epsi_dot = c.r - c.kappa * s_dot
    ey_dot = c.vx * ops.sin(c.epsi) + c.vy * ops.cos(c.epsi)
    out = [vx_dot, vy_dot, r_dot, epsi_dot, ey_dot, s_dot]
    for e in effects:
        if e.n_states:
            out.extend(e.derivative(c))
    return out


def _run(effects: Sequence[Any], stage: str, c: SimpleNamespace) -> None:
    for e in effects:
        getattr(e, stage)(c)


def _is(x: Any, value: float) -> bool:
    """``x`` is the plain number ``value`` (arrays of per-window parameters are never skipped)."""
    return isinstance(x, (int, float)) and x == value
