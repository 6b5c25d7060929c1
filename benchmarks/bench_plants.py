"""Plants: cost per step, accuracy against a fine reference, the commonroad-mb integrator choice,
`simulate` laps, and commonroad-mb at the grip limit.

Prints JSON tables (one object per section). Usage (run with `nice`, 2 cores are shared)::

    python benchmarks/bench_plants.py                      # steps, accuracy, simulate laps
    python benchmarks/bench_plants.py --integrators        # commonroad-mb: RK4 vs scipy integrators
    python benchmarks/bench_plants.py --grip-limit 20      # 20 random runs at the grip limit (mb, std)
    python benchmarks/bench_plants.py --laps 1             # laps of the simulate rows
"""

from __future__ import annotations

import json
import math
import sys
import time
from contextlib import contextmanager

import numpy as np

PLANTS = ("audi_nominal", "audi_hidden", "audi_randomized", "bmw_randomized", "bmw_commonroad", "bmw_commonroad_mb")


def manoeuvre(k: int, dt: float = 0.05) -> tuple[float, float]:
    """A lively 3 s input sequence: turn in, brake in the corner, ease off, accelerate out."""
    t = k * dt
    delta = 0.03 * math.sin(1.3 * t) + (0.02 if t > 0.5 else 0.0)
    ax = -3.0 if 1.0 < t < 1.8 else (1.5 if t > 2.2 else 0.0)
    return delta, ax


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


@contextmanager
def finer(kind: str, factor: float):
    """The commonroad plants' substep bounds divided by ``factor`` (module constants) for a reference."""
    from gprace.plants import commonroad as cr

    names = {"commonroad-std": ("H_MAX", "_STIFF"), "commonroad-mb": ("H_MB_MAX", "_MB_STIFF")}.get(kind, ())
    old = {n: getattr(cr, n) for n in names}
    for n in names:
        setattr(cr, n, old[n] / factor)
    try:
        yield
    finally:
        for n, v in old.items():
            setattr(cr, n, v)


def accuracy(plant_name: str, track, factor: int = 20, n: int = 60) -> dict:
    """Largest deviation of the shipped plant from the same plant integrated ``factor`` times finer
    over :func:`manoeuvre` (true states, no noise)."""
    from gprace.config import NoiseConfig, load_plant
    from gprace.plants import make_plant

    pc = load_plant(plant_name).model_copy(update={"noise": NoiseConfig()})
    x0 = np.array([22.0, 0.0, 0.0, 0.0, 0.0, 0.0])

    def run(cfg, fine):
        with finer(cfg.kind, factor if fine else 1):
            plant = make_plant(cfg, track, 0.05)
            plant.reset(x0, np.zeros(2))
            t = time.perf_counter()
            X = [plant.step(np.array(manoeuvre(k))) for k in range(n)]
            return np.array(X), (time.perf_counter() - t) / n

    fine_cfg = pc.model_copy(update={"substeps": min(pc.substeps * factor, 1000)})
    A, ta = run(pc, False)
    B, tb = run(fine_cfg, True)
    err = np.abs(A - B).max(axis=0)
    return {"plant": plant_name, "manoeuvre_s": n * 0.05, "fine_factor": factor, "max_err_v_x": float(err[0]),
            "max_err_v_y": float(err[1]), "max_err_yaw_rate": float(err[2]), "max_err_e_y_m": float(err[4]),
            "ms_per_step": round(1e3 * ta, 2), "fine_ms_per_step": round(1e3 * tb, 2)}


def simulate_rows(laps: float) -> list[dict]:
    from gprace.config import SimulateConfig, load_plant
    from gprace.sim import lap_times, simulate
    from gprace.tracks import load_track

    ring = load_track("gprace_ring")
    rows = []
    for p in PLANTS:
        t = time.perf_counter()
        run = simulate(load_plant(p), ring, SimulateConfig(laps=laps, speed_scale=0.6 if "randomized" in p else 0.8))
        rows.append({"simulate": p, "track": "gprace_ring", "laps": laps, "speed_scale": run.meta["speed_scale"],
                     "steps": run.n, "seconds": round(time.perf_counter() - t, 2), "lap_times_s": lap_times(run),
                     "max_abs_e_y_m": round(float(np.abs(run["e_y"]).max()), 2),
                     "border_hit_samples": int(run["border_hit"].sum()), "completed": run.meta["completed"]})
    return rows


# ---------------------------------------------------------------------------------------------
# commonroad-mb: which integrator


def integrators(n: int = 60, fev_cap: int = 20000) -> list[dict]:
    """commonroad-mb over two 3 s manoeuvres from 22 m/s, with each integrator restarted every
    period (inputs are held per period), against RK4 at 0.1 ms. ``moderate``: the manoeuvre at half
    the steering and braking (no wheel locks); ``limit``: as :func:`manoeuvre` with 0.06 rad of
    steering, at the grip limit (the unloaded inner wheels lift and lock). An adaptive integrator
    that needs more than ``fev_cap`` derivative calls in one period is counted as stalled."""
    from scipy.integrate import solve_ivp

    from gprace.config import load_plant
    from gprace.plants import make_plant
    from gprace.plants.commonroad import mb_substep, rk4_step
    from gprace.tracks import load_track

    plant = make_plant(load_plant("bmw_commonroad_mb"), load_track("circle_100"), 0.05)
    W = plant.WHEELS

    def inputs(kind, k):
        d, a = manoeuvre(k)
        return (0.5 * d, 0.5 * a) if kind == "moderate" else (0.06 if k * 0.05 > 0.2 else 0.0, a)

    def rk4(kind, h_of_v):
        z = list(plant._init([0.0, 0.0, 0.0, 22.0, 0.0, 0.0, 0.0], plant.p))
        calls, t0 = 0, time.perf_counter()
        for k in range(n):
            d, a = inputs(kind, k)
            m = max(int(math.ceil(0.05 / h_of_v(z[3]) - 1e-9)), 1)
            for _ in range(m):
                z = rk4_step(plant._deriv, z, d, a, 0.05 / m, W)
            calls += 4 * m
        return np.array(z), (time.perf_counter() - t0) / n, calls / n, 0

    class Stall(Exception):
        pass

    def ivp(kind, method, rtol, atol):
        z = np.array(plant._init([0.0, 0.0, 0.0, 22.0, 0.0, 0.0, 0.0], plant.p))
        calls, stalls, t0 = [0], 0, time.perf_counter()
        for k in range(n):
            d, a = inputs(kind, k)
            start = calls[0]

            def f(t, y):
                calls[0] += 1
                if calls[0] - start > fev_cap:
                    raise Stall
                return plant._deriv(y, d, a)

            try:
                sol = solve_ivp(f, (0.0, 0.05), z, method=method, rtol=rtol, atol=atol)
                z = sol.y[:, -1].copy() if sol.success else z
                stalls += not sol.success
            except Stall:
                stalls += 1
                return None, (time.perf_counter() - t0) / (k + 1), calls[0] / (k + 1), stalls
            z[W] = np.maximum(z[W], 0.0)
        return z, (time.perf_counter() - t0) / n, calls[0] / n, stalls

    rows = []
    for kind in ("moderate", "limit"):
        ref, tref, _, _ = rk4(kind, lambda v: 1e-4)
        cands = [("RK4 (plant: mb_substep)", lambda: rk4(kind, mb_substep))]
        cands += [(f"RK4 fixed {h * 1e3:g} ms", lambda h=h: rk4(kind, lambda v: h)) for h in (0.01, 0.0025, 0.001)]
        cands += [(f"{m} rtol {rt:g}", lambda m=m, rt=rt: ivp(kind, m, rt, rt * 1e-2))
                  for m, rt in (("LSODA", 1e-5), ("LSODA", 1e-7), ("BDF", 1e-5), ("Radau", 1e-5), ("RK45", 1e-5))]
        for name, fn in cands:
            z, tm, calls, stalls = fn()
            row = {"manoeuvre": kind, "integrator": name, "ms_per_period": round(1e3 * tm, 1),
                   "derivative_calls_per_period": round(calls, 1), "stalled_periods": stalls}
            if z is not None:
                row.update(err_position_m=float(np.abs(z[:2] - ref[:2]).max()), err_yaw_rad=float(abs(z[4] - ref[4])),
                           err_v_x=float(abs(z[3] - ref[3])), err_v_y=float(abs(z[10] - ref[10])))
            else:
                row["result"] = "stalled"
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


# ---------------------------------------------------------------------------------------------
# commonroad-mb at the grip limit


def grip_limit(n_runs: int, seed: int = 2024) -> list[dict]:
    """``n_runs`` random runs of `simulate` (one lap each) at the grip limit: a random TUM circuit,
    speed_scale U(0.9, 1.0), a random noise seed; for commonroad-mb and commonroad-std on the same
    draws. A numerical failure (non-finite state, an exception) is counted apart from a lost car."""
    from pathlib import Path

    from gprace.config import SimulateConfig, load_plant
    from gprace.sim import lap_times, simulate
    from gprace.tracks import load_track

    tracks = sorted(Path("/work/shared/data/tumftm-racetrack-database/tracks").glob("*.csv"))
    rng = np.random.default_rng(seed)
    draws = [(tracks[rng.integers(len(tracks))], float(rng.uniform(0.9, 1.0)), int(rng.integers(1, 10_000)))
             for _ in range(n_runs)]
    rows = []
    for plant_name in ("bmw_commonroad_mb", "bmw_commonroad"):
        for path, scale, noise_seed in draws:
            t = time.perf_counter()
            row = {"plant": plant_name, "track": path.stem, "speed_scale": round(scale, 3), "seed": noise_seed}
            try:
                run = simulate(load_plant(plant_name), load_track(str(path)), SimulateConfig(laps=1, speed_scale=scale, seed=noise_seed))
                row.update(outcome="completed" if run.meta["completed"] else "car lost", lap_times_s=lap_times(run),
                           s_end_m=round(float(run["s"][-1]), 1))
            except Exception as exc:  # a numerical failure is the point of the count
                row.update(outcome="numerical failure", error=f"{type(exc).__name__}: {exc}")
            row["seconds"] = round(time.perf_counter() - t, 1)
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    summary = []
    for plant_name in ("bmw_commonroad_mb", "bmw_commonroad"):
        mine = [r for r in rows if r["plant"] == plant_name]
        summary.append({"summary": plant_name, "runs": len(mine), **{o: sum(r["outcome"] == o for r in mine)
                        for o in ("completed", "car lost", "numerical failure")}})
    return rows + summary


def main() -> None:
    from gprace.tracks import load_track

    args = sys.argv[1:]
    if "--integrators" in args:
        print(json.dumps(integrators(), indent=1))
        return
    if "--grip-limit" in args:
        print(json.dumps(grip_limit(int(args[args.index("--grip-limit") + 1])), indent=1))
        return
    laps = float(args[args.index("--laps") + 1]) if "--laps" in args else 1.0
    circle = load_track("circle_100")
    rows = [per_step(p, circle) for p in PLANTS]
    rows += [accuracy(p, circle) for p in PLANTS if p != "audi_nominal"]
    rows += simulate_rows(laps)
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
