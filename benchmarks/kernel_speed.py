"""Speed of the diagnosis's prediction kernel (issue 36, stop 48), one JSON row per recording and
model variant: nanoseconds per window-step (one RK4 step of one window: 4 derivatives and 4
curvature/profile look-ups) of the scalar kernel and of the 4-lane kernel, one thread, and the
largest relative difference of their predictions. Timed as the difference of calls on 48 and on 8
windows (the least of ``--repeat`` runs each, at 40 places): short runs escape the preemption of a
loaded machine, and the difference removes the per-call overhead (~90 us, ~5 ns per window-step
in a diagnosis's calls).

With ``--parts``, the scalar kernel's time split into the derivative, the curvature/profile
look-ups and the rest (RK4 bookkeeping, input rows, stores), by timing variants of its driver with
the look-ups replaced by a constant and/or the derivative by a linear stand-in (benchmark-only
builds; the split is approximate: the parts overlap in the processor).

Recordings: the two real logs as ``benchmarks/real_logs.py`` imports them (or ``--runs DIR``
with ``ini_01-45-24.h5`` and ``iac.h5``), all their windows of ``--horizon`` steps, 1 substep
(the diagnosis's setting), with the vehicle's nominal parameters.

With ``--diagnose``: the whole-log diagnosis of each log instead, CPU and wall seconds of its
second run in the process (kernel cache warm), the kernel's calls, window-steps and wall time.

    python benchmarks/kernel_speed.py [--runs DIR] [--only ini,iac] [--repeat 5] [--parts] [--diagnose]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

_USER_ENV = set(os.environ)
os.environ.setdefault("GPRACE_DIAGNOSE_THREADS", "1")  # the kernel timings: one thread


def variants(lap_length: float):
    """(label, effects) of the model kinds a diagnosis meets."""
    from gprace.model import EFFECTS

    knots = np.linspace(0.0, lap_length, 48, endpoint=False)
    return [
        ("nominal", []),
        ("lags", [EFFECTS["steering_lag"](tau=0.05), EFFECTS["drivetrain_lag"](tau=0.1)]),
        ("effects", [EFFECTS["downforce"](c_l=1.0), EFFECTS["load_transfer"](cog_height=0.3),
                     EFFECTS["combined_slip"](k=0.5), EFFECTS["tire_friction"](front=0.9, rear=1.1)]),
        ("profile", [EFFECTS["road_bank_profile"](knots=knots.tolist(), values=(0.02 * np.sin(knots)).tolist(),
                                                  lap_length=lap_length)]),
    ]


def _timed(call, m: int, repeat: int, big: int = 48, small: int = 8) -> float:
    """Seconds per window: ``call(a, b)`` on ``big`` and on ``small`` windows from the same start,
    the least of ``repeat`` runs of each, their difference per window averaged over the starts.
    Short runs escape the preemption of a loaded machine, and the difference removes the per-call
    overhead (about 90 us of Python and ctypes)."""
    diff, n = 0.0, 0
    for a in range(0, m - big, max(big, (m - big) // 40)):
        best = {}
        for size in (big, small):
            best[size] = np.inf
            for _ in range(repeat):
                t = time.perf_counter()
                call(a, a + size)
                best[size] = min(best[size], time.perf_counter() - t)
        diff += (best[big] - best[small]) / (big - small)
        n += 1
    return diff / n


def _part_kernels(key):
    """Scalar driver variants: full, no look-ups, no derivative, neither (benchmark-only builds)."""
    from gprace.compiled import compiled_source
    from gprace.diagnose import fastpredict as fp

    F, lay = fp._deriv_function(*key)
    src = fp.scalar_source(F, lay, len(key[3]))
    stub_stage = ("static inline void stage_const(double s, long i, long m, double L, double off, const double *ks, "
                  "const double *kv, long nk, const double *pk, const long *pko, const long *pn, const double *pL, "
                  "const double *pv, const long *pvo, const long *prow, long *hint, double *kap) { for (int q = 0; q <= NPROF; q++) "
                  "kap[q] = 1e-3; }\n")
    stub_deriv = ("static int deriv_lin(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, "
                  "int mem) { for (int q = 0; q < NXS; q++) res[0][q] = 1e-3 * arg[0][(q + 1) % NXS] + arg[2][0] "
                  "+ arg[1][q % 2]; return 0; }\n")
    out = {}
    for label, stage, deriv in (("full", False, False), ("no_lookup", True, False), ("no_deriv", False, True),
                                ("neither", True, True)):
        s = src
        head, drv = s.split("/* out (m, H, NXS)", 1)
        if stage:
            drv = drv.replace("stage_inputs(", "stage_const(")
        if deriv:
            drv = drv.replace("DERIV(", "deriv_lin(")
        s = head + stub_stage + stub_deriv + "/* out (m, H, NXS)" + drv
        lib = compiled_source(fp._tag(*key) + "_bench_" + label, s, fp.KERNEL_FLAGS, "benchmark kernel")
        out[label] = fp._bind(lib, "gprace_predict")
    return out, lay


def rows_for(key_name: str, run, vehicle, H: int, repeat: int, parts: bool) -> list[dict]:
    from gprace.diagnose import core, fastpredict as fp

    data = core.build_dataset([run])
    starts = data.windows(H)
    rows = []
    L = float(data.L[0]) if np.isfinite(data.L[0]) else float(np.ptp(data.Y[:, 5]))
    for label, effects in variants(L):
        model = core.model_for(vehicle, data, effects)
        Z = core.lag_states(model, data) if model.nx > 6 else np.zeros((data.n, 0))
        X0 = core.initial_states(model, data.Y[starts], Z[starts])
        pl = fp.plan(model)
        profs = [e.name for e in pl[2] if e.name in fp.PROFILES]
        key = (pl[0], pl[1], tuple(e.name for e in pl[2] if e.name in fp.NEUTRAL), tuple(profs))
        steps = len(starts) * H
        res = {}
        for kind, kern in (("scalar", fp._kernel(*key)), ("simd4", fp._simd_kernel(*key))):
            if kern is None:
                continue
            orig = fp._simd_kernel
            fp._simd_kernel = (lambda *a, k=kern: k) if kind == "simd4" else (lambda *a: None)
            try:
                call = lambda a, b: fp.predict_states(model, data, starts[a:b], H, 1, X0[a:b], core._OFFSET)  # noqa: E731
                res[kind] = (_timed(call, len(starts), repeat) * len(starts), call(0, len(starts)))
            finally:
                fp._simd_kernel = orig
        row = {"recording": key_name, "variant": label, "kernel": fp._tag(*key), "windows": int(len(starts)), "H": H,
               "ns_per_window_step": {k: round(v[0] / steps * 1e9, 1) for k, v in res.items()}}
        if len(res) == 2:
            a, b = res["scalar"][1], res["simd4"][1]
            row["speedup"] = round(res["scalar"][0] / res["simd4"][0], 2)
            row["max_rel_diff"] = float(np.nanmax(np.abs(a - b) / np.maximum(np.abs(a), 1e-6 * np.abs(a).max(axis=(0, 1)))))
        if parts:
            kerns, lay = _part_kernels(key)
            t = {}
            for lab, fn in kerns.items():
                orig_k, orig_s = fp._kernel, fp._simd_kernel
                fp._kernel, fp._simd_kernel = (lambda *a, f=fn: (f, lay)), (lambda *a: None)
                try:
                    t[lab] = _timed(lambda a, b: fp.predict_states(model, data, starts[a:b], H, 1, X0[a:b], core._OFFSET),
                                    len(starts), repeat) * len(starts)
                finally:
                    fp._kernel, fp._simd_kernel = orig_k, orig_s
            ns = {k: v / steps * 1e9 for k, v in t.items()}
            row["scalar_parts_ns"] = {"derivative": round(ns["full"] - ns["no_deriv"], 1),
                                      "lookups": round(ns["full"] - ns["no_lookup"], 1),
                                      "rest": round(ns["neither"], 1), "full": round(ns["full"], 1)}
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


def diagnosis_row(key: str, run, vehicle) -> dict:
    """The whole-log diagnosis as ``real_logs.py`` runs it, timed on its second run in the process
    (the kernel cache warm), with the kernel's calls, window-steps and wall time counted."""
    from gprace.diagnose import core, fastpredict as fp
    from gprace.diagnose.diagnose import diagnose

    diagnose([run], vehicle)  # builds what the kernel cache lacks
    count = [0.0, 0, 0]
    inner = core._compiled_states

    def counted(model, data, starts, H, substeps, X0):
        t = time.perf_counter()
        out = inner(model, data, starts, H, substeps, X0)
        count[0] += time.perf_counter() - t
        count[1] += 1
        count[2] += len(starts) * H * substeps
        return out

    core._compiled_states = counted
    load = os.getloadavg()[0]
    c0, w0 = time.process_time(), time.perf_counter()
    try:
        rep = diagnose([run], vehicle).report
    finally:
        core._compiled_states = inner
    cpu, wall, n = time.process_time() - c0, time.perf_counter() - w0, rep["samples"]
    row = {"recording": key, "diagnosed_samples": n, "cpu_s": round(cpu, 2), "wall_s": round(wall, 2),
           "cpu_s_per_10k": round(cpu / n * 1e4, 2), "wall_s_per_10k": round(wall / n * 1e4, 2),
           "kernel_wall_s": round(count[0], 2), "kernel_calls": count[1], "window_steps_M": round(count[2] / 1e6, 2),
           "kernel_threads": fp._threads(),
           "load_1min": [round(load, 2), round(os.getloadavg()[0], 2)], "named": [e["name"] for e in rep["effects"]]}
    print(json.dumps(row), file=sys.stderr, flush=True)
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=None)
    ap.add_argument("--only", default="ini,iac")
    ap.add_argument("--horizon", type=int, default=15)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--parts", action="store_true")
    ap.add_argument("--diagnose", action="store_true",
                    help="time the whole-log diagnosis instead (kernel threads as GPRACE_DIAGNOSE_THREADS, default 2)")
    args = ap.parse_args()
    if args.diagnose and os.environ.get("GPRACE_DIAGNOSE_THREADS") == "1" and "GPRACE_DIAGNOSE_THREADS" not in _USER_ENV:
        del os.environ["GPRACE_DIAGNOSE_THREADS"]  # the diagnosis's own default
    import real_logs

    from gprace.config import load_vehicle

    rows = []
    for key in args.only.split(","):
        run, _ = real_logs.load(key, args.runs)
        vehicle = load_vehicle(real_logs.RECORDINGS[key]["vehicle"])
        if args.diagnose:
            rows.append(diagnosis_row(key, run, vehicle))
        else:
            rows += rows_for(key, run, vehicle, args.horizon, args.repeat, args.parts)
    json.dump({"rows": rows, "load_average": [round(x, 2) for x in os.getloadavg()]}, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
