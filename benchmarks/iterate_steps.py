"""CPU seconds per step of the time-trial loop (issue 37: the README job's time).

Runs ``iterate`` in this process (``workers=1``, so one BLAS thread as in the trial processes)
with the README job's alphas, and prints a JSON table: CPU seconds and calls of each loop step
(iteration 0, select, retrain, re-plan, drive), of the pieces inside them (hyperparameter fit,
dictionary update, refit, calibration, candidate grid, building IPOPT solvers) and the total.
No profiler (cProfile overstates the Python-heavy steps several times over).

    python benchmarks/iterate_steps.py OUT [--iterations 3] [--oracle]
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import time

STEPS = ("_iteration_zero", "_select", "_retrain", "_replan", "_drive_iteration", "_oracle_task",
         "_reference_task")
PIECES = ("fit_hyper", "update_dictionary", "refit_fixed", "calibrate")


def _timed(module, name: str, acc: dict, calls: collections.Counter, label: str | None = None) -> None:
    fn = getattr(module, name)

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        t = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[label or name] += time.process_time() - t
            calls[label or name] += 1

    setattr(module, name, wrapper)


def main() -> None:
    import casadi

    import gprace.timetrial.iterate as I
    import gprace.timetrial.iterate.training as T
    from gprace.timetrial import learning as L

    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--oracle", action="store_true")
    a = ap.parse_args()
    acc: dict = collections.defaultdict(float)
    calls: collections.Counter = collections.Counter()
    for name in STEPS:
        _timed(I, name, acc, calls)
    _timed(T, "make_grid", acc, calls)  # called by the retrain step, so patched where that looks it up
    for name in PIECES:
        _timed(L, name, acc, calls)
    _timed(casadi, "nlpsol", acc, calls, "nlpsol (solver builds)")
    st = I.IterateSettings(alphas=(0.857, 0.714, 0.0), trials=1, iterations=a.iterations, oracle=a.oracle)
    t = time.process_time()
    I.iterate(st, a.out, workers=1)
    acc["total"] = time.process_time() - t
    print(json.dumps({k: {"cpu_s": round(v, 2), "calls": calls[k]} for k, v in sorted(acc.items())}, indent=1))


if __name__ == "__main__":
    main()
