"""Drive a plant around a track with the reference controller and record a :class:`Run`.

The controller sees only the measured (noisy) Frenet state, as on a real car. Each recorded row
``k`` holds the measurement at ``t_k = k dt``, the command applied over ``[t_k, t_k + dt)``, the
curvature at the measured ``s``, the lap counter and ``border_hit`` (1 when the car's footprint,
from the *true* state, crosses a track edge: :func:`gprace.sim.record.border_hits`).

Stops after ``laps`` laps (closed tracks) or at the track end (open tracks). A car that leaves the
track, spins or stalls (:func:`gprace.sim.stop.run_end`) ends the run early with a warning;
the recording up to one second before that is kept (``meta["completed"]`` False).
"""

from __future__ import annotations

import math

import numpy as np

from gprace.config import PlantConfig, SimulateConfig, config_hash
from gprace.console import console
from gprace.errors import RunFailedError
from gprace.io.runs import OWN_RUN, Run
from gprace.plants import make_plant
from gprace.resources import check_size
from gprace.sim.controller import ReferenceController
from gprace.sim.record import border_hits, lap_times_of, run_columns
from gprace.sim.stop import run_end, step_plant


STEP_NUMBERS = 48
"""Numbers kept per recorded step (the buffers here and the run's columns), for the memory check."""


def _budget(ctrl: ReferenceController, track, sim_config: SimulateConfig) -> tuple[float, int]:
    """The distance to drive and the step budget (the slowest progress allowed: 0.3 of the mean
    speed of the controller's profile); a budget that cannot be held in memory is refused."""
    dt = sim_config.dt
    goal = sim_config.laps * track.length if track.closed else track.length
    n_max = int(math.ceil(goal / max(0.3 * float(np.mean(ctrl.profile.v)), 1e-3) / dt)) + 10
    per_lap = (n_max - 10) / (sim_config.laps if track.closed else 1.0)
    check_size(f"--laps {sim_config.laps:g} at --dt {dt:g} s ({n_max:,} steps at most)", n_max,
               lambda n: 8.0 * STEP_NUMBERS * n, say=lambda n: f"{max(n - 10, 0) / per_lap:.4g} laps")
    return goal, n_max


def check_budget(plant_config: PlantConfig, track, sim_config: SimulateConfig) -> None:
    """What :func:`simulate` checks before it drives, for a command to check before it starts."""
    _budget(ReferenceController(plant_config.vehicle, track, sim_config.dt, sim_config.speed_scale,
                                sim_config.weave_amplitude, sim_config.weave_wavelength), track, sim_config)


def simulate(plant_config: PlantConfig, track, sim_config: SimulateConfig) -> Run:
    """Record ``sim_config.laps`` laps of ``plant_config`` on ``track`` (see module docstring)."""
    dt = sim_config.dt
    if sim_config.seed:
        plant_config = plant_config.model_copy(update={"seed": plant_config.seed + 1_000_003 * sim_config.seed})
    vehicle = plant_config.vehicle
    ctrl = ReferenceController(vehicle, track, dt, sim_config.speed_scale, sim_config.weave_amplitude,
                               sim_config.weave_wavelength)
    plant = make_plant(plant_config, track, dt)
    x0, u0 = ctrl.initial_state(0.0)
    y = plant.reset(x0, u0)

    goal, n_max = _budget(ctrl, track, sim_config)
    v_mean = float(np.mean(ctrl.profile.v))
    v_stall = 0.2 * min(v_mean, float(ctrl.profile.v.min()) + 1e-9)

    Y = np.empty((n_max + 1, 6))
    X = np.empty((n_max + 1, 6))  # true states, for the footprint check
    U = np.empty((n_max + 1, 2))
    lap = np.empty(n_max + 1)
    k = 0
    while True:
        u = ctrl(y)
        x = plant.state
        Y[k], X[k], U[k], lap[k] = y, x, u, plant.lap
        k += 1
        if (reason := run_end(track, plant, vehicle.width, v_stall, goal, k, n_max, "no progress to the goal")) is not None:
            break
        y, reason = step_plant(plant, u)
        if reason:
            break

    if reason:
        if k < 2:
            raise RunFailedError(f"simulate: {reason} at the first step")
        k = max(k - int(round(1.0 / dt)), 2)  # drop the last second: the slide, not driving data
        console.warn(f"simulate: {reason}; the recording keeps the {k} samples up to 1 s before")
    data = {
        **run_columns(track, dt, Y[:k], U[:k]),
        "lap": lap[:k],
        "border_hit": border_hits(track, X[:k], vehicle.length, vehicle.width).astype(float),
    }
    meta = {
        "vehicle_toml": vehicle.to_toml(),
        "track": str(getattr(track, "source", None) or track.name),
        "dt": dt,
        "plant": plant_config.kind,
        "plant_hash": plant_config.digest(),
        "simulate_hash": sim_config.digest(),
        "laps": sim_config.laps,
        "speed_scale": sim_config.speed_scale,
        "weave_amplitude": sim_config.weave_amplitude,
        "weave_wavelength": sim_config.weave_wavelength,
        "completed": not reason,
        OWN_RUN: True,  # a recording of gprace's own loop: no user-file unit check (gprace.io.runs)
    }
    return Run(data, meta, source=f"simulate({plant_config.kind}, {track.name})")


def run_hash(run: Run) -> str:
    """Config hash stored with a simulated run: plant, simulation settings and track."""
    return config_hash([run.meta.get("plant_hash"), run.meta.get("simulate_hash"), run.meta.get("track")])


def lap_times(run: Run) -> list[float]:
    """Times of the completed laps [s] (from the lap counter)."""
    return lap_times_of(run.data["t"], np.asarray(run.data["lap"]))
