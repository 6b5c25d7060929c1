"""Reference driving: a speed-profile + Frenet-feedback controller and ``simulate`` (records a Run).

>>> from gprace.sim import simulate
>>> run = simulate(load_plant("audi_nominal"), load_track("gprace_ring"), SimulateConfig(laps=1))
"""

from gprace.sim.controller import ReferenceController, build_profile, speed_profile
from gprace.sim.simulate import lap_times, run_hash, simulate

__all__ = ["ReferenceController", "build_profile", "speed_profile", "lap_times", "run_hash", "simulate"]
