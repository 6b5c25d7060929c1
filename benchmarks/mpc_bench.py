"""One tracking-MPC step (linearisation, GP mean, gradient and variance, tightening, grip rows,
QP), N = 20, with the paper's dictionary M = 2000 and the default M = 1000.

Drives a minimum-curvature plan of the default circuit on the nominal plant for a few hundred
steps per backend with an exact GP of M points on the default feature set (``full``: v_x, v_y,
yaw_rate, delta, a_x; synthetic targets, one kernel for both outputs as iterate fits it), timing
every full step and the QP alone. Prints a JSON table: median and p99 [ms] per backend and M.
Usage: ``mpc_bench.py [STEPS [M,M,...] [FEATURES]]``.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np


def main(steps: int = 300, sizes=(2000, 1000), features: str = "full") -> None:
    from gprace.config import load_plant, load_vehicle
    from gprace.gp import make_gp
    from gprace.gp.features import dyn_feature_set
    from gprace.model import NominalModel
    from gprace.mpc.tracking import MPCSettings, TrackingMPC
    from gprace.plan import curvature_plan
    from gprace.plants import make_plant
    from gprace.timetrial.drive import start_state
    from gprace.timetrial.learning import GPPredictor
    from gprace.tracks import load_track

    tr = load_track("gprace_ring")
    m = NominalModel(load_vehicle("audi_tt_cup"))
    plan = curvature_plan(tr, m)
    names = dyn_feature_set(features)
    center = {"v_x": (40.0, 15.0), "v_y": (0.0, 1.0), "yaw_rate": (0.1, 0.3), "delta": (0.02, 0.04), "a_x": (0.0, 5.0)}
    mu, sd = np.array([center[n] for n in names]).T
    out = {}
    for M in sizes:
        rng = np.random.default_rng(0)
        Z = rng.normal(mu, sd, (M, len(names)))
        Y = np.column_stack([0.01 * np.sin(Z[:, 1]), 0.005 * Z[:, 2]]) + rng.normal(0, 1e-3, (M, 2))
        gp = make_gp("exact", optimize=False, length_scale=1.0, noise=1e-2, shared_kernel=True).fit(Z, Y)
        pred = GPPredictor(gp, "tracking", inputs=names)
        for name in ("clarabel", "casadi", "cvxpy-clarabel"):
            mpc = TrackingMPC(m, tr, plan, MPCSettings(solver=name), gp=pred)
            x0, u0 = start_state(plan, tr, m.vehicle)
            plant = make_plant(load_plant("audi_nominal"), tr, 0.05)
            y = plant.reset(x0, u0)
            mpc.reset(u0[0])
            full, qp = [], []
            for _ in range(steps):
                t0 = time.perf_counter()
                u, info = mpc.step(y)
                full.append(time.perf_counter() - t0)
                qp.append(info["solve_time"])
                y = plant.step(u)
            full, qp = 1e3 * np.array(full[10:]), 1e3 * np.array(qp[10:])
            out[f"{name} M={M}"] = {"step_median_ms": float(np.median(full)), "step_p99_ms": float(np.quantile(full, 0.99)),
                                    "qp_median_ms": float(np.median(qp)), "qp_p99_ms": float(np.quantile(qp, 0.99)),
                                    "fallbacks": int(mpc.fallbacks), "steps": len(full)}
    print(json.dumps({"N": 20, "features": features, "backends": out}, indent=1))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 300,
         tuple(int(v) for v in sys.argv[2].split(",")) if len(sys.argv) > 2 else (2000, 1000),
         sys.argv[3] if len(sys.argv) > 3 else "full")
