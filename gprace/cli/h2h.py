"""CLI: ``gprace eval head2head`` (the whole protocol) and ``gprace h2h collect|train|explore``.

Heavy imports (casadi, dask, the GP layer) happen inside the commands.
"""

from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path
from typing import Optional

import typer

from gprace.cli.groups import RUN_PANEL, eval_group, h2h_group
from gprace.console import console
from gprace.options import EXECUTOR, SCHEDULER

OUT = typer.Option(Path("h2h_out"), "--out", help="Folder of cached artifacts and per-run HDF5 records.")
WORKERS = typer.Option(os.cpu_count() or 1, "--workers", help="Local worker processes (default: one per core).")
RESUME = typer.Option(False, "--resume", help="Keep finished runs; rerun only missing or failed ones.")
JSON = typer.Option(False, "--json", help="Print the result as JSON.")
EXPLORE_WIDTH = typer.Option(
    None, "--explore-width", help="Width of the exploration loop in metres (default: --width, the racing width; the loop's own is 1.5 m).")
RUNS = typer.Option(500, "--runs", help="Baseline collection runs (oracle predictor), one random track each.")
INIT_RUNS = typer.Option(20, "--init-runs", help="Collection runs on evaluation-style tracks behind the exploration's "
                         "initial GP.")
BASELINE_TRACKS = typer.Option(
    "training", "--baseline-tracks", help="Tracks of the baseline's collection: training (the short curve and chicane "
    "tracks of Zhu et al. 2022, as in the paper) or eval (random evaluation-style tracks).")
POINTS_PER_RUN = typer.Option(10, "--points-per-run", help="Evenly spaced steps kept per collection run.")
WIDTH = typer.Option(0.75, "--width", help="Width of the random tracks in metres (more than the car's 0.26 m footprint).")
STRETCHES = typer.Option(5, "--stretches", help="Stretches (curve, chicane, straight) per random track.")
MAX_TIME = typer.Option(60.0, "--max-time", help="Longest race in seconds (safety stop).")
GP_BACKEND = typer.Option("auto", "--gp-backend", help="exact | sparse | auto (sparse above --exact-max points).")
EXACT_MAX = typer.Option(1500, "--exact-max", help="Most points the exact GP takes with --gp-backend auto.")
INDUCING = typer.Option(200, "--inducing", help="Inducing points of the sparse GP.")


def _settings(out: Path, **kw):
    """Checked settings of a command writing to ``out``: every check before any file is written."""
    from gprace.executor import check_execution
    from gprace.h2h.protocol import Settings
    from gprace.io.artifacts import check_folder

    raced = kw.pop("predictors", None)
    if raced:
        kw["raced"] = tuple(p.strip() for p in raced.split(",") if p.strip())
    st = Settings(**kw)
    check_execution(st.executor, st.workers, st.scheduler)
    check_folder(out)
    return st


def _cell(row, fmt: str) -> str:
    """``mean ±seed std [bootstrap interval over tracks]`` of one figure over seeds (a
    :class:`~gprace.h2h.table.Figure`)."""
    if row is None or row.mean is None:
        return "-"
    txt = format(row.mean, fmt)
    if row.seed_std is not None:
        txt += f" ±{format(row.seed_std, fmt)}"
    lo, hi = row.ci
    return txt if lo is None else f"{txt} [{format(lo, fmt)}, {format(hi, fmt)}]"


def print_fits(fits: dict) -> None:
    """The fit quality of every model of every seed (held-out error per output against the exact
    GP on a subsample)."""
    from gprace.gp.quality import FitQuality

    rows = []
    for seed, models in fits.items():
        for name, q in models.items():
            q = FitQuality(**q)
            rows.append([seed, name, *(f"{h:.3f}/{r:.3f}" for h, r in zip(q.heldout, q.reference)),
                         f"{max(q.noise):.2g}", str(q.attempts)])
            outputs = q.outputs
    if rows:
        console.table("Fit quality: held-out error / exact GP on a subsample (RMSE / spread of the held-out "
                      "outputs; 1 = learned nothing)", ["seed", "model", *outputs, "noise max", "attempts"], rows)


def print_conditions(cond: dict) -> None:
    """The conditions of the comparison (noise, baseline tracks, blocking weight, exploration)."""
    if not cond:
        return
    std = lambda v: " ".join(f"{x:g}" for x in v)  # noqa: E731
    console.table("Conditions", ["sensor noise std", "process noise std", "baseline tracks", "blocking weight",
                                 "exploration min"],
                  [[std(cond["sensor_std"]), std(cond["process_std"]), cond["baseline_tracks"],
                    f"{cond['blocking_weight']:g}", f"{cond['explore_minutes']:g}"]])


def print_coverage(cov: dict) -> None:
    """Share of the evaluation errors inside the predicted 2-sigma band, calibrated (raw)."""
    if not cov:
        return
    import numpy as np

    def cell(c, out: str, k: int) -> str:
        v, r = getattr(c, out)[k], getattr(c, f"{out}_raw")[k]
        return "-" if not np.isfinite(v) else f"{100 * v:.0f} % ({100 * r:.0f} %)"

    K = max((len(c.ey) for c in cov.values()), default=0)
    rows = [[p, cell(c, "ey", K - 1), cell(c, "s", K - 1), cell(c, "ey", 0), cell(c, "s", 0), c.points]
            for p, c in cov.items() if len(c.ey) == K]
    console.table("Coverage of the errors by the predicted 2-sigma band on the evaluation races, calibrated (raw)",
                  ["predictor", f"e_y {K} steps", f"s {K} steps", "e_y 1 step", "s 1 step", "start times"], rows)


def print_table(tab: dict, as_json: bool) -> None:
    """The table of :func:`gprace.h2h.protocol.head2head` (its dump), as JSON or as text tables."""
    from gprace.h2h.table import failed_races_text, parse_table

    if as_json:
        console.json(tab)
        return
    t = parse_table(tab, "table")
    print_conditions(t.conditions)
    seeds = t.seeds
    how = (f"mean ±std over {len(seeds)} seeds" if len(seeds) > 1 else f"seed {seeds[0]}") + \
        " [95% bootstrap interval over tracks]"
    print_fits(t.fits)
    rows = []
    for p, r in t.racing.items():
        ot = "-" if r.overtake_time_mean is None else f"{r.overtake_time_mean:.2f}±{r.overtake_time_std:.2f}"
        ms = "-" if r.ego_solve_ms_median is None else f"{r.ego_solve_ms_median:.1f}"
        fig = {name: _cell(t.spread.get(f"{p}.{name}"), ".2f" if name == "overtake_time" else ".3g")
               for name in ("border_hits", "collisions", "overtakes", "overtake_time")}
        rows.append([p, f"{r.runs}/{r.failed}", *fig.values(), ot, r.overtake_scenarios, r.fallbacks_ego, ms])
    console.table(f"Head-to-head racing, {how}; first seed: {t.common_inside} scenarios with every predictor "
                  "inside, overtake time mean±std over them", ["predictor", "runs/failed", "border", "collide",
                  "overtakes", "overtake s", "first seed s", "n", "fallbacks", "solve ms"], rows)
    for p, r in t.racing.items():
        if r.failed:
            console.result(f"{p}: failed races {failed_races_text(r)}")
    errs = {p: e for p, e in t.ey_error.items() if e.mean}
    K = max((len(e.mean) for e in errs.values()), default=0)
    erows = [[f"{k + 1}"] + [_cell(t.spread.get(f"{p}.ey_error_{k + 1}"), ".4f") for p in errs] for k in range(K)]
    points = ", ".join(f"{p} {e.points}" for p, e in errs.items())
    console.table(f"Opponent e_y prediction error in metres, {how}, offline on all closed-loop opponent "
                  f"trajectories (start times in the first seed: {points})", ["steps ahead", *errs], erows)
    print_coverage(t.coverage)
    if t.claims:
        from gprace.verdict import MIN_SAMPLES

        crows = []
        for name, c in t.claims.items():
            fmt = ".4f" if name.startswith("ey_error") else ".3g"
            crows.append([name, _cell(c, fmt), " ".join("-" if lo is None else f"[{lo:{fmt}}, {hi:{fmt}}]"
                                                        for lo, hi in c.seed_ci),
                          "-" if c.tracks is None else c.tracks, c.shown_verdict(t.settings.get("tracks"))])
        console.table("Claims: exploration - baseline (the paper: lower, except more overtakes); a claim holds only "
                      "where every seed's 95% interval over tracks is on its side, and no verdict from fewer than "
                      f"{MIN_SAMPLES} tracks", ["figure", "difference", "interval per seed", "tracks", "verdict"], crows)


def head2head_cmd(
    tracks: int = typer.Option(100, "--tracks", help="Random evaluation scenarios."),
    out: Path = OUT,
    runs: int = RUNS,
    init_runs: int = INIT_RUNS,
    explore_minutes: float = typer.Option(10.0, "--explore-minutes", help="Simulated exploration time."),
    episode_seconds: float = typer.Option(60.0, "--episode-seconds", help="Length of one exploration episode."),
    explore_width: Optional[float] = EXPLORE_WIDTH,
    alpha: float = typer.Option(0.9, "--alpha", help="Exploration weight during exploration."),
    dict_size: int = typer.Option(600, "--dict-size", help="Dictionary size of the exploration GP."),
    points_per_run: int = POINTS_PER_RUN,
    width: float = WIDTH,
    stretches: int = STRETCHES,
    predictors: str = typer.Option("baseline,explore", "--predictors", help="Predictors raced (baseline, explore, select, init, cv, oracle)."),
    backend: str = GP_BACKEND,
    exact_max: int = EXACT_MAX,
    inducing: int = INDUCING,
    samples: int = typer.Option(50, "--samples", help="GP rollout samples."),
    max_time: float = MAX_TIME,
    sensor_noise: float = typer.Option(
        1.0, "--sensor-noise", help="Scale of the measurement noise of both cars' states (1: realistic for 1:10 "
        "cars, std v_x 0.01 m/s, v_y 0.01 m/s, yaw rate 0.02 rad/s, e_psi 0.005 rad, e_y and s 5 mm; 0: none)."),
    process_noise: float = typer.Option(
        1.0, "--process-noise", help="Scale of the process noise per 0.1 s plant step (1: std v_x 0.01 m/s, "
        "v_y 0.005 m/s, yaw rate 0.02 rad/s; 0: none)."),
    baseline_tracks: str = BASELINE_TRACKS,
    blocking_weight: float = typer.Option(500.0, "--blocking-weight", help="The opponent's blocking weight."),
    calib_runs: int = typer.Option(20, "--calib-runs", help="Held-out races per calibration pass of every "
                                   "predictor's spread."),
    calib_passes: int = typer.Option(3, "--calib-passes", help="At most this many calibration passes driven by "
                                     "the raced predictors (they stop when the races confirm the calibration)."),
    seeds: str = typer.Option("1", "--seeds", help="Seeds of the whole chain (collection, training, exploration, "
                              "evaluation): a count N (seeds 0..N-1) or a list such as 0,4,7. Seed 0 writes to "
                              "--out, seed s to --out/seed_<s>; the evaluation scenarios are shared."),
    workers: int = WORKERS, executor: str = EXECUTOR, scheduler: Optional[str] = SCHEDULER,
    resume: bool = RESUME, as_json: bool = JSON,
) -> None:
    """The paper's head-to-head comparison: collect, train, explore, race all predictors, tabulate."""
    from gprace.h2h.protocol import head2head as run, parse_seeds

    st = _settings(out, tracks=tracks, runs=runs, init_runs=init_runs, explore_minutes=explore_minutes,
                   episode_seconds=episode_seconds, explore_width=explore_width, alpha=alpha, dict_size=dict_size,
                   points_per_run=points_per_run, width=width,
                   stretches=stretches, predictors=predictors, backend=backend, exact_max=exact_max,
                   inducing=inducing, samples=samples, max_time=max_time, sensor_noise=sensor_noise,
                   process_noise=process_noise, baseline_tracks=baseline_tracks, blocking_weight=blocking_weight,
                   calib_runs=calib_runs, calib_passes=calib_passes, workers=workers, executor=executor,
                   scheduler=scheduler, resume=resume, seeds=parse_seeds(seeds))
    print_table(run(st, out), as_json)


def collect_cmd(
    out: Path = OUT,
    runs: int = RUNS, init_runs: int = INIT_RUNS, points_per_run: int = POINTS_PER_RUN,
    baseline_tracks: str = BASELINE_TRACKS, width: float = WIDTH, stretches: int = STRETCHES, max_time: float = MAX_TIME,
    workers: int = WORKERS, executor: str = EXECUTOR, scheduler: Optional[str] = SCHEDULER,
    resume: bool = RESUME, as_json: bool = JSON,
) -> None:
    """Race the collection tracks with the oracle predictor; write the (Z, Y) datasets."""
    from gprace.h2h.protocol import collect as run, read_dataset

    st = _settings(out, runs=runs, init_runs=init_runs, points_per_run=points_per_run, baseline_tracks=baseline_tracks,
                   width=width, stretches=stretches, max_time=max_time,
                   workers=workers, executor=executor, scheduler=scheduler, resume=resume)
    paths = run(st, out)
    res = {k: {"path": str(v), "points": len(read_dataset(v)[0])} for k, v in paths.items()}
    console.json(res) if as_json else [console.result(f"{k}: {v['path']} ({v['points']} points)") for k, v in res.items()]


def train_cmd(
    dataset: Path = typer.Argument(..., help="An opponent GP dataset (from h2h collect or h2h explore)."),
    model: Path = typer.Argument(..., help="Output GP model file."),
    size: Optional[int] = typer.Option(None, "--select", help="Diverse selection of this many points first."),
    hyper_model: Optional[Path] = typer.Option(None, "--hyper-model", help="GP whose hyperparameters drive the selection."),
    initial: Optional[Path] = typer.Option(None, "--initial", help="Dataset that starts the dictionary."),
    validation: Optional[Path] = typer.Option(
        None, "--validation", help="Held-out dataset of the fit quality report (default: training points "
        "outside the reference's subsample)."),
    backend: str = GP_BACKEND, exact_max: int = EXACT_MAX, inducing: int = INDUCING, as_json: bool = JSON,
) -> None:
    """Fit the opponent GP (Matern 1.5) on a dataset; print its fit quality (a degenerate fit is refused)."""
    from gprace.gp.quality import COLUMNS
    from gprace.h2h.predictors import read_opponent_gp
    from gprace.h2h.protocol import Settings, fit_report, train as run

    st = Settings(backend=backend, exact_max=exact_max, inducing=inducing)
    path = run(dataset, model, st, size=size, hyper_model=hyper_model, initial=initial, validation=validation)
    _, attrs = read_opponent_gp(path)
    q = fit_report(attrs)
    res = {"model": str(path), "backend": attrs["backend"], "points": int(attrs.get("n_points", 0)),
           "quality": None if q is None else asdict(q)}
    if as_json:
        console.json(res)
        return
    if q is not None:
        console.table(f"Fit quality (held-out: {q.heldout_points} points, {q.heldout_source}; exact GP on "
                      f"{q.reference_points} points; attempts {q.attempts})", COLUMNS, q.rows())
    console.result(f"{res['model']}: {res['backend']} GP on {res['points']} points")


def explore_cmd(
    out: Path = OUT,
    init_model: Path = typer.Option(..., "--init-model", help="The initial GP model."),
    init_data: Path = typer.Option(..., "--init-data", help="Its dataset (candidate grid, first dictionary)."),
    explore_minutes: float = typer.Option(10.0, "--explore-minutes", help="Simulated exploration time."),
    episode_seconds: float = typer.Option(60.0, "--episode-seconds", help="Length of one exploration episode."),
    explore_width: Optional[float] = typer.Option(
        None, "--explore-width", help="Width of the exploration loop in metres (default 0.75 m, the racing width of "
        "eval head2head; the loop's own is 1.5 m)."),
    alpha: float = typer.Option(0.9, "--alpha", help="Exploration weight in [0, 1]."),
    workers: int = WORKERS, executor: str = EXECUTOR, scheduler: Optional[str] = SCHEDULER,
    resume: bool = RESUME, as_json: bool = JSON,
) -> None:
    """Exploration episodes on the closed loop (Algorithm 1, stalemate breaking)."""
    from gprace.h2h.protocol import explore as run, read_dataset

    st = _settings(out, explore_minutes=explore_minutes, episode_seconds=episode_seconds, explore_width=explore_width,
                   alpha=alpha, workers=workers,
                   executor=executor, scheduler=scheduler, resume=resume)
    path = run(st, out, init_model, init_data)
    res = {"dataset": str(path), "points": len(read_dataset(path)[0])}
    console.json(res) if as_json else console.result(f"{res['dataset']}: {res['points']} exploration points")


def register(app: typer.Typer) -> None:
    ev = eval_group(app)
    h2h = h2h_group(app)
    ev.command("head2head", rich_help_panel=RUN_PANEL)(head2head_cmd)
    h2h.command("collect")(collect_cmd)
    h2h.command("train")(train_cmd)
    h2h.command("explore")(explore_cmd)
