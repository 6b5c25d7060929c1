"""GP layer benchmark (issue 3, "Performance" and "How we will know"): prints one JSON table.

    python benchmarks/gp_bench.py [--quick] [--threads N] [--no-quality] [--seeds 3]

Speed, with M = 2000, 3 inputs, 2 outputs (synthetic smooth functions, timing only):

- ``predict_20_ms``: posterior mean and variance of both outputs at 20 points (median of 200),
  exact backend with per-output kernels and with one shared kernel, and the sparse backend;
- ``grid_10k_s``: variance on a 10,000-point candidate grid (exact, sparse);
- ``selection_stream_s``: 10,000 points of a smooth "run" streamed into a full M = 2000 dictionary,
  with the number of replacements and the deviation of the maintained inverse from a fresh one;
- ``retrain_s``: exact backend, hyperparameters (scikit-learn, on its default 800-point subsample)
  and posterior on all 2000 points;
- ``sparse_fit_50k_s`` and ``sparse_predict_10k_s``.

Quality (``gprace simulate`` is available): recordings of the ``audi_hidden`` plant (hidden
downforce, load transfer, combined slip, rear friction and stiffness, steering lag) on the
shipped ring: three racing-line laps at different speeds plus two short weaving stretches (the
little exploration data among much routine data that the paper's selection is meant to keep).
Per seed (sensor noise), a tracking dataset of M = 250 points (of about 4,700 samples) is chosen
by the diverse selection and by a random subsample; a GP with the SAME fixed hyperparameters
(fitted once on 400 pooled points) is conditioned on each, and both predict a held-out,
noise-free run that weaves across the track (also printed: the GP on all samples, and the
nominal model alone).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

if __name__ == "__main__" and "--threads" in sys.argv:  # BLAS reads this when it loads
    _n = sys.argv[sys.argv.index("--threads") + 1]
    for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_v] = _n

import numpy as np  # noqa: E402


def _f(Z: np.ndarray) -> np.ndarray:
    return np.column_stack([np.sin(2.0 * Z[:, 0]) * np.cos(Z[:, 2]) + 0.3 * Z[:, 1],
                            0.5 * Z[:, 1] ** 2 - Z[:, 2] + 0.2 * np.sin(3.0 * Z[:, 0])])


def _data(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    Z = rng.normal(size=(n, 3)) * np.array([1.0, 0.7, 1.3])
    return Z, _f(Z) + 0.05 * rng.standard_normal((n, 2))


def _median_ms(fn, reps: int) -> float:
    fn()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def speed(M: int, n_grid: int, n_stream: int, n_sparse: int, out: dict) -> None:
    from gprace.gp import make_gp
    from gprace.gp.selection import DiverseSelector

    Z, Y = _data(M, 0)
    Zq = _data(20, 1)[0]
    Zg = _data(n_grid, 2)[0]

    t0 = time.perf_counter()
    exact = make_gp("exact").fit(Z, Y)
    out["retrain_s"] = time.perf_counter() - t0
    out["retrain_hyperparameters"] = {"length_scales": np.exp(exact.hyper_.log_ls).round(3).tolist(),
                                      "noise": np.exp(exact.hyper_.log_sn2).tolist()}
    shared = make_gp("exact", shared_kernel=True).fit(Z, Y)
    out["predict_20_ms"] = {"exact": _median_ms(lambda: exact.predict(Zq), 200),
                            "exact_shared_kernel": _median_ms(lambda: shared.predict(Zq), 200)}
    t0 = time.perf_counter()
    exact.predict(Zg)
    out["grid_10k_s"] = {"exact": time.perf_counter() - t0}

    # selection: a full dictionary, then a smooth run that partly leaves the covered region
    sel = DiverseSelector(exact.hyper_, M)
    sel.initialize(Z, Y)
    t = np.linspace(0.0, 200.0, n_stream)
    Zs = np.column_stack([1.6 * np.sin(0.31 * t) * np.cos(0.05 * t), 1.1 * np.sin(0.53 * t + 1.0), 1.8 * np.cos(0.17 * t)])
    Zs += 0.05 * np.random.default_rng(3).standard_normal(Zs.shape)
    Ys = _f(Zs) + 0.05 * np.random.default_rng(4).standard_normal((n_stream, 2))
    t0 = time.perf_counter()
    sel.update(Zs, Ys)
    out["selection_stream_s"] = time.perf_counter() - t0
    out["selection_stats"] = sel.stats.as_dict()
    out["selection_factor_error"] = sel.factor_error()

    Zb, Yb = _data(n_sparse, 5)
    t0 = time.perf_counter()
    sparse = make_gp("sparse").fit(Zb, Yb)
    out["sparse_fit_50k_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sparse.predict(Zg)
    out["sparse_predict_10k_s"] = time.perf_counter() - t0
    out["grid_10k_s"]["sparse"] = out["sparse_predict_10k_s"]
    out["predict_20_ms"]["sparse"] = _median_ms(lambda: sparse.predict(Zq), 200)
    mean, _ = sparse.predict(Zg)
    out["sparse_rmse_vs_truth"] = np.sqrt(np.mean((mean - _f(Zg)) ** 2, axis=0)).tolist()


def quality(seeds: int, M: int, out: dict, laps: float) -> None:
    """Diverse vs random selection on recordings of a plant with hidden effects."""
    from gprace.config import NoiseConfig, SimulateConfig, load_plant, load_vehicle, validate
    from gprace.gp import make_gp
    from gprace.gp.features import run_features
    from gprace.gp.selection import random_subsample, select_diverse
    from gprace.sim import simulate
    from gprace.tracks import load_track

    plant = load_plant("audi_hidden")
    track = load_track("gprace_ring")
    vehicle = load_vehicle("audi_tt_cup")
    # (speed scale, weave amplitude, weave wavelength, laps): mostly racing-line laps, as in a time
    # trial, and a little exploration (short weaving stretches) -- the data a dictionary must keep
    train_set = [
        (0.75, 0.0, 100.0, laps), (0.85, 0.0, 100.0, laps), (0.9, 0.0, 100.0, laps),
        (0.8, 0.3, 150.0, 0.2 * laps), (0.9, 0.5, 90.0, 0.2 * laps),
    ]
    clean = plant.model_copy(update={"noise": NoiseConfig()})  # held-out run without sensor noise
    rows = []
    for seed in range(seeds):
        Zs, Ys = [], []
        for i, (sp, wv, wl, nl) in enumerate(train_set):
            cfg = validate(SimulateConfig, {"dt": 0.05, "laps": nl, "speed_scale": sp, "weave_amplitude": wv,
                                            "weave_wavelength": wl, "seed": 100 * seed + i}, "bench")
            Z, Y = run_features(simulate(plant, track, cfg), "tracking", vehicle)
            Zs.append(Z)
            Ys.append(Y)
        Z, Y = np.concatenate(Zs), np.concatenate(Ys)
        test_cfg = validate(SimulateConfig, {"dt": 0.05, "laps": laps, "speed_scale": 0.85, "weave_amplitude": 0.8,
                                             "weave_wavelength": 60.0, "seed": 100 * seed + 99}, "bench")
        Zt, Yt = run_features(simulate(clean, track, test_cfg), "tracking", vehicle)
        rng = np.random.default_rng(seed)
        sub = rng.choice(len(Z), min(len(Z), 400), replace=False)
        hyper_gp = make_gp("exact", max_fit_points=400, seed=seed).fit(Z[sub], Y[sub])
        h = hyper_gp.hyper_

        def fixed_fit(Zd, Yd):
            # the same hyperparameters in physical units for both datasets
            from gprace.gp.base import fit_scalers

            _, zs, _, ys = fit_scalers(Zd, Yd)
            return make_gp("exact", optimize=False,
                           length_scale=np.exp(h.log_ls) * h.z_scale / zs,
                           signal_variance=np.exp(h.log_sf2) * h.y_scale**2 / ys**2,
                           noise=np.exp(h.log_sn2) * h.y_scale**2 / ys**2).fit(Zd, Yd)

        t0 = time.perf_counter()
        Zd, Yd, st = select_diverse(h, Z, Y, M)
        t_sel = time.perf_counter() - t0
        Zr, Yr = random_subsample(Z, Y, M, seed)
        res = {"seed": seed, "samples": int(len(Z)), "test_samples": int(len(Zt)), "selection_s": t_sel,
               "replaced": st.replaced, "outliers": st.rejected_outlier}
        for name, (Za, Ya) in (("diverse", (Zd, Yd)), ("random", (Zr, Yr))):
            mean, _ = fixed_fit(Za, Ya).predict(Zt)
            res[f"rmse_{name}"] = np.sqrt(np.mean((mean - Yt) ** 2, axis=0)).tolist()
        res["rmse_nominal"] = np.sqrt(np.mean(Yt**2, axis=0)).tolist()
        mean, _ = fixed_fit(Z, Y).predict(Zt)
        res["rmse_all_data"] = np.sqrt(np.mean((mean - Yt) ** 2, axis=0)).tolist()
        res["diverse_better"] = bool(np.mean(np.array(res["rmse_diverse"]) / np.array(res["rmse_random"])) < 1.0)
        rows.append(res)
        print(json.dumps(res), file=sys.stderr)
    out["quality"] = {"plant": "audi_hidden", "track": "gprace_ring", "feature_map": "tracking", "M": M,
                      "outputs": ["v_y", "yaw_rate"], "runs": rows,
                      "diverse_better_in": f"{sum(r['diverse_better'] for r in rows)}/{len(rows)} seeds"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smaller sizes (a smoke run, not the targets)")
    ap.add_argument("--threads", type=int, default=0, help="BLAS threads (set before numpy loads; 0: library default)")
    ap.add_argument("--no-quality", action="store_true", help="skip the selection-quality experiment")
    ap.add_argument("--no-speed", action="store_true", help="skip the speed measurements")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--quality-m", type=int, default=250, help="dictionary size of the quality experiment")
    ap.add_argument("--laps", type=float, default=1.0, help="laps per simulated run in the quality experiment")
    args = ap.parse_args()
    M, n_grid, n_stream, n_sparse = (500, 2000, 2000, 5000) if args.quick else (2000, 10000, 10000, 50000)
    out: dict = {"M": M, "inputs": 3, "outputs": 2, "threads": args.threads or "default",
                 "load_average_start": os.getloadavg()[0], "cpus": os.cpu_count()}
    if not args.no_speed:
        speed(M, n_grid, n_stream, n_sparse, out)
    if not args.no_quality:
        quality(args.seeds, 200 if args.quick else args.quality_m, out, 0.3 if args.quick else args.laps)
    out["load_average_end"] = os.getloadavg()[0]
    out["targets"] = {"predict_20_ms": 3.0, "grid_10k_s_exact": 2.5, "grid_10k_s_sparse": 0.1,
                      "selection_stream_s": 10.0, "retrain_s": 60.0, "sparse_fit_50k_s": 120.0,
                      "sparse_predict_10k_s": 0.1}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
