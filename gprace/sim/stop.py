"""The one stop rule of a driven car: off the track, spun, or stalled (simulate, the time-trial
drive, the head-to-head race).

A run ends early when the car's centre is more than two car widths outside a border, when it has
spun (``|e_psi| > SPIN_EPSI`` or ``|v_y| > SPIN_SLIP |v_x| + SPIN_SLIP_OFFSET``) or when ``v_x``
falls below the caller's stall speed (which depends on what is driven: a speed profile or a plan).
The spin limits are the time-trial drive's: the MPC may catch a slide that is still inside them.
:func:`run_end` adds the goal and the step budget: the end-of-step check of a driving loop.
:func:`step_plant` steps the plant: a plant whose model breaks down (an arithmetic error, its own
``SolverError``, or a state that is not finite) has lost the car, and the run ends like any other
lost lap.
"""

from __future__ import annotations

import numpy as np

from gprace.errors import SolverError
from gprace.model.dynamics import State

SPIN_EPSI = 1.2  # rad
SPIN_SLIP = 0.6  # |v_y| / |v_x|
SPIN_SLIP_OFFSET = 2.0  # m/s


def stop_kind(x: np.ndarray, width_left: float, width_right: float, car_width: float,
              v_stall: float = -np.inf) -> str:
    """Why a car in state ``x`` (6,) must stop: "" (it may go on), "off_track", "spun" or "stalled"."""
    vx, vy, epsi, ey = (x[i] for i in (State.V_X, State.V_Y, State.E_PSI, State.E_Y))
    if ey > width_left + 2 * car_width or ey < -width_right - 2 * car_width:
        return "off_track"
    if abs(epsi) > SPIN_EPSI or abs(vy) > SPIN_SLIP * abs(vx) + SPIN_SLIP_OFFSET:
        return "spun"
    if vx < v_stall:
        return "stalled"
    return ""


def stop_reason(x: np.ndarray, width_left: float, width_right: float, car_width: float, v_stall: float) -> str:
    """:func:`stop_kind` in words naming where ("" if the car may go on)."""
    kind = stop_kind(x, width_left, width_right, car_width, v_stall)
    vx, vy, epsi, ey, s = (x[i] for i in (State.V_X, State.V_Y, State.E_PSI, State.E_Y, State.S))
    return {
        "": "",
        "off_track": f"the car left the track at s = {s:.1f} m (e_y = {ey:.2f} m)",
        "spun": f"the car spun at s = {s:.1f} m (e_psi = {epsi:.2f} rad, v_y = {vy:.1f} m/s)",
        "stalled": f"the car stalled at s = {s:.1f} m (v_x = {vx:.2f} m/s)",
    }[kind]


def run_end(track, plant, car_width: float, v_stall: float, goal: float, steps: int, max_steps: int,
            too_long: str) -> str | None:
    """After ``steps`` steps of a run: None while it goes on, "" once the plant's progress
    (laps on a closed track) reaches ``goal`` metres, otherwise why it stops (:func:`stop_reason`,
    or ``too_long`` after more than ``max_steps`` steps)."""
    x = plant.state
    s = x[State.S]
    progress = plant.lap * track.length + s if track.closed else s
    if progress >= goal:
        return ""
    reason = stop_reason(x, float(track.width_left(s)), float(track.width_right(s)), car_width, v_stall)
    if not reason and steps > max_steps:
        reason = f"{too_long} after {max_steps} steps"
    return reason or None


def step_plant(plant, u: np.ndarray) -> tuple[np.ndarray | None, str]:
    """``(measurement, "")`` after one plant step, or ``(None, why)`` when the plant's model broke down.

    Third-party models are not written for a car in a spin: commonroad's multi-body model divides by
    a wheel's longitudinal speed, which is zero when the car slides sideways (measured on
    commonroad_mb, a lost lap of the unseen-plants benchmark, issue 37). Such a step is the car
    lost at that point, counted with the other lost laps, never a traceback that ends the experiment.
    What counts: an arithmetic error, a plant's own :class:`~gprace.errors.SolverError` (its
    integration failed: the built-in plants raise it on a state that is not finite) and a
    measurement or state that is not finite. Any other exception is a defect and is raised.
    """
    s = float(plant.state[State.S])
    try:
        y = plant.step(u)
    except (ArithmeticError, SolverError) as exc:
        return None, f"the plant's model broke down at s = {s:.1f} m ({type(exc).__name__}: {exc})"
    y = np.asarray(y, dtype=float)
    if not np.all(np.isfinite(y)) or not np.all(np.isfinite(plant.state)):
        return None, f"the plant's model broke down at s = {s:.1f} m (a state that is not finite)"
    return y, ""
