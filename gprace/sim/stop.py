"""The one stop rule of a driven car: off the track, spun, or stalled (simulate, the time-trial drive).

A run ends early when the car's centre is more than two car widths outside a border, when it has
spun (``|e_psi| > SPIN_EPSI`` or ``|v_y| > SPIN_SLIP |v_x| + SPIN_SLIP_OFFSET``) or when ``v_x``
falls below the caller's stall speed (which depends on what is driven: a speed profile or a plan).
The spin limits are the time-trial drive's: the MPC may catch a slide that is still inside them.
:func:`run_end` adds the goal and the step budget: the end-of-step check of a driving loop.
"""

from __future__ import annotations

import numpy as np

SPIN_EPSI = 1.2  # rad
SPIN_SLIP = 0.6  # |v_y| / |v_x|
SPIN_SLIP_OFFSET = 2.0  # m/s


def stop_reason(x: np.ndarray, width_left: float, width_right: float, car_width: float, v_stall: float) -> str:
    """Why a car in state ``x`` (6,) must stop ("" if it may go on), in words naming where."""
    if x[4] > width_left + 2 * car_width or x[4] < -width_right - 2 * car_width:
        return f"the car left the track at s = {x[5]:.1f} m (e_y = {x[4]:.2f} m)"
    if abs(x[3]) > SPIN_EPSI or abs(x[1]) > SPIN_SLIP * abs(x[0]) + SPIN_SLIP_OFFSET:
        return f"the car spun at s = {x[5]:.1f} m (e_psi = {x[3]:.2f} rad, v_y = {x[1]:.1f} m/s)"
    if x[0] < v_stall:
        return f"the car stalled at s = {x[5]:.1f} m (v_x = {x[0]:.2f} m/s)"
    return ""


def run_end(track, plant, car_width: float, v_stall: float, goal: float, steps: int, max_steps: int,
            too_long: str) -> str | None:
    """After ``steps`` steps of a run: None while it goes on, "" once the plant's progress
    (laps on a closed track) reaches ``goal`` metres, otherwise why it stops (:func:`stop_reason`,
    or ``too_long`` after more than ``max_steps`` steps)."""
    x = plant.state
    progress = plant.lap * track.length + x[5] if track.closed else x[5]
    if progress >= goal:
        return ""
    reason = stop_reason(x, float(track.width_left(x[5])), float(track.width_right(x[5])), car_width, v_stall)
    if not reason and steps > max_steps:
        reason = f"{too_long} after {max_steps} steps"
    return reason or None
