"""Per-step cost of the plants and the runtime of `simulate` on one lap of the default track.

Prints a JSON table. Usage: python benchmarks/bench_plants.py [--laps 1]
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np


def per_step(plant_name: str, track, n: int = 400) -> dict:
    from gprace.config import load_plant
    from gprace.plants import make_plant

    pc = load_plant(plant_name)
    plant = make_plant(pc, track, 0.05)
    v = 25.0
    kappa = float(track.kappa(0.0))
    plant.reset(np.array([v, 0.0, v * kappa, 0.0, 0.0, 0.0]), np.array([2.6 * kappa, 0.0]))
    u = np.array([2.6 * kappa, 0.3])
    t = time.perf_counter()
    for _ in range(n):
        plant.step(u)
    dt = (time.perf_counter() - t) / n
    return {"plant": plant_name, "kind": pc.kind, "dt_s": 0.05, "ms_per_step": round(1e3 * dt, 3),
            "realtime_factor": round(0.05 / dt, 1)}


def main() -> None:
    from gprace.config import SimulateConfig, load_plant
    from gprace.sim import lap_times, simulate
    from gprace.tracks import load_track

    laps = float(sys.argv[sys.argv.index("--laps") + 1]) if "--laps" in sys.argv else 1.0
    circle = load_track("circle_100")
    rows = [per_step(p, circle) for p in ("audi_nominal", "audi_hidden", "bmw_commonroad")]
    ring = load_track("gprace_ring")
    for p in ("audi_nominal", "audi_hidden", "bmw_commonroad"):
        t = time.perf_counter()
        run = simulate(load_plant(p), ring, SimulateConfig(laps=laps))
        rows.append({"simulate": p, "track": "gprace_ring", "laps": laps, "steps": run.n,
                     "seconds": round(time.perf_counter() - t, 2), "lap_times_s": lap_times(run),
                     "max_abs_e_y_m": round(float(np.abs(run["e_y"]).max()), 2),
                     "border_hit_samples": int(run["border_hit"].sum()), "completed": run.meta["completed"]})
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
