"""One tracking-MPC step (linearisation, GP mean, gradient and variance, tightening, grip rows,
QP), N = 20, with the paper's dictionary M = 2000 and the default M = 1000.

The GP is the one the loop would use: tracking-GP data of weaving laps of the hidden-effects Audi
(``simulate``, 0.8 of the friction-limited speed, every sample in control), hyperparameters fitted
by marginal likelihood on 800 of them, the posterior on M random samples, on the default feature
set (``full``: v_x, v_y, yaw_rate, delta, a_x) with the MPC's real-time (spectral) variance. The MPC
then drives the minimum-curvature plan of the default circuit on that plant for a few hundred
steps per backend, timing every full step and the QP alone. BLAS runs on one thread, as in the
loop's workers (a control loop owns its core; threaded BLAS on 2 busy cores is 10 to 60 times
slower on these small products). Prints a JSON table: median and p99 [ms] per backend and M.
Usage: ``mpc_bench.py [STEPS [M,M,...] [FEATURES]]``.
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np


def driving_gp(M: int, features: str, model, track):
    """A tracking GP of ``M`` points fitted on weaving laps of ``audi_hidden`` (see the docstring)."""
    from gprace.config import SimulateConfig, load_plant
    from gprace.gp.features import dyn_feature_set
    from gprace.sim import simulate
    from gprace.timetrial import learning as L

    laps = max(1.0, math.ceil(1.2 * M / 1100))  # about 1,100 in-control samples per lap at 0.8
    run = simulate(load_plant("audi_hidden"), track, SimulateConfig(laps=laps, speed_scale=0.8, weave_amplitude=0.7,
                                                                    weave_wavelength=120.0, seed=3))
    Z, Y = L.features(run, model, track, "tracking", features)
    if len(Z) < M:
        raise SystemExit(f"only {len(Z)} samples for M = {M}")
    hyper = L.fit_hyper(Z, Y, seed=0, max_fit_points=800)
    idx = np.random.default_rng(0).choice(len(Z), M, replace=False)
    gp = L.refit_fixed(hyper, Z[idx], Y[idx])
    gp.predict_with_gradient(Z[:20])  # builds the spectral factor (once per fit, as in the loop)
    W = gp._spectral(0)
    pred = L.GPPredictor(gp, "tracking", inputs=dyn_feature_set(features), var_scale=L.calibrate(gp))
    return pred, (None if W is None else int(W.shape[1]))


def main(steps: int = 300, sizes=(2000, 1000), features: str = "full") -> None:
    from gprace.config import load_plant, load_vehicle
    from gprace.model import NominalModel
    from gprace.mpc.tracking import MPCSettings, TrackingMPC
    from gprace.plan import curvature_plan
    from gprace.plants import make_plant
    from gprace.timetrial.drive import start_state
    from gprace.tracks import load_track

    tr = load_track("gprace_ring")
    m = NominalModel(load_vehicle("audi_tt_cup"))
    plan = curvature_plan(tr, m)
    out, spectral = {}, {}
    for M in sizes:
        pred, spectral[M] = driving_gp(M, features, m, tr)
        for name in ("clarabel", "casadi", "cvxpy-clarabel"):
            mpc = TrackingMPC(m, tr, plan, MPCSettings(solver=name), gp=pred)
            x0, u0 = start_state(plan, tr, m.vehicle)
            plant = make_plant(load_plant("audi_hidden"), tr, 0.05)
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
    print(json.dumps({"N": 20, "features": features, "spectral_rank": spectral, "backends": out}, indent=1))


if __name__ == "__main__":
    import scipy.linalg  # noqa: F401 -- SciPy's own BLAS is loaded before the limit
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        main(int(sys.argv[1]) if len(sys.argv) > 1 else 300,
             tuple(int(v) for v in sys.argv[2].split(",")) if len(sys.argv) > 2 else (2000, 1000),
             sys.argv[3] if len(sys.argv) > 3 else "full")
