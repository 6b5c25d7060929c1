"""Time-trial commands: ``gprace plan``, ``gprace run``, ``gprace iterate``, ``gprace eval timetrial``,
``gprace eval iterate``."""

from __future__ import annotations

import math
from pathlib import Path

import typer

from gprace.cli.groups import RUN_PANEL, SCORE_PANEL, eval_group
from gprace.options import EXECUTOR, SCHEDULER


def _floats(text: str, what: str) -> tuple[float, ...]:
    from gprace.errors import ConfigError

    try:
        vals = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ConfigError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    return vals


# options shared by iterate and eval timetrial
PLANT = typer.Option("audi_hidden", "--plant", help="Plant config.")
VEHICLE = typer.Option("audi_tt_cup", "--vehicle", help="Nominal vehicle of planner and MPC.")
DICTIONARY = typer.Option(1000, "--dictionary-size", help="GP dictionary size M per GP.")
FEATURES = typer.Option("full", "--features", help="GP inputs: full (v_x, v_y, yaw_rate, delta, a_x) or paper (v_y, yaw_rate, delta).")
SEED = typer.Option(0, "--seed", help="Base seed.")
WORKERS = typer.Option(None, "--workers", help="Local worker processes (default: one per trial and oracle lap, "
                       "at most 3 per core: the cores are shared evenly, and no core idles while an odd trial runs alone).")
MCAP = typer.Option(None, "--mcap", help="Also write the recorded and planned laps, the GP's band (where a GP drove) and "
                    "the track as MCAP (Foxglove schemas).")
DELAY = typer.Option(None, "--delay", help="Total steering and measurement delay [s] the MPC predicts over "
                     "(default: the vehicle's known delays, else estimated in the shakedown).")


MIN_NODES, MAX_NODES = 20, 20_000


def check_nodes(track, ds: float) -> None:
    """``--ds`` must give a lap of MIN_NODES..MAX_NODES nodes (a coarser lap skips the corners, a
    finer one makes an NLP too large to solve)."""
    from gprace.errors import ConfigError

    n = track.length / ds
    if not MIN_NODES <= n <= MAX_NODES:
        raise ConfigError(f"--ds {ds:g} gives {n:.3g} nodes on the {track.length:.0f} m track {track.name}; "
                          f"use {track.length / MAX_NODES:.3g} to {track.length / MIN_NODES:.3g} m")


def plan_cmd(
    track: str = typer.Option("gprace_ring", "--track", help="Track: shipped name or a CSV/TOML path."),
    vehicle: str = typer.Option("audi_tt_cup", "--vehicle", help="Nominal vehicle: shipped name or TOML path."),
    model: Path | None = typer.Option(None, "--model", help="Planning GP (gp_model, feature map 'planning')."),
    warm_start: Path | None = typer.Option(None, "--warm-start", help="Previous plan of the same track, or a raceline CSV (TUM or F1TENTH) on it (initial guess)."),
    curvature: bool = typer.Option(False, "--curvature", help="Write the GP-free minimum-curvature path instead."),
    ds: float = typer.Option(6.0, "--ds", help="Node spacing in metres."),
    grip: float | None = typer.Option(None, "--grip", help="Friction-ellipse margin: share of the model's limits (e.g. 0.9)."),
    output: Path = typer.Option(..., "--output", "-o", help="Plan file to write (.h5)."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
) -> None:
    """Plan a minimum-lap-time lap (CasADi/IPOPT), optionally compensated by a planning GP."""
    from gprace.console import console
    from gprace.errors import ConfigError
    from gprace.model import NominalModel, load_vehicle
    from gprace.plan import PlanSettings, curvature_plan, plan_min_time
    from gprace.io.artifacts import check_output
    from gprace.tracks import load_track

    check_output(output)
    if ds <= 0:
        raise ConfigError(f"--ds must be positive, got {ds}")
    if grip is not None and not 0.0 < grip <= 1.0:
        raise ConfigError(f"--grip must be in (0, 1] (a share of the model's limits), got {grip}")
    tr = load_track(track)
    check_nodes(tr, ds)
    m = NominalModel(load_vehicle(vehicle))
    nodes = f"{tr.length / ds:.0f} nodes of {tr.name}"
    if curvature:
        console.info(f"plan: minimum-curvature path on {nodes}")
        plan = curvature_plan(tr, m, ds=ds)
    else:
        warm = None
        if warm_start:  # a plan file, or a raceline CSV: then the lap is planned in its direction
            from gprace.plan.raceline import load_plan

            warm, tr = load_plan(warm_start, track, m.vehicle, ds)
        mu = None
        if model is not None:
            from gprace.timetrial.learning import load_predictor

            gp = load_predictor(model, "planning")
            mu = lambda X, U: gp.at(X, U)[0]  # noqa: E731
        console.info(f"plan: minimum-time NLP (IPOPT) on {nodes}" + (" with the planning GP" if mu else ""))
        plan = plan_min_time(tr, m, PlanSettings(ds=ds, grip=grip), warm=warm, mu_plan=mu)
    plan.write(output)
    if as_json:
        console.json({"output": str(output), "method": plan.method, "track": tr.name, "lap_time": plan.lap_time, "nodes": plan.n})
    else:
        console.result(f"{output}: {plan.method} plan of {tr.name}, lap time {plan.lap_time:.3f} s, {plan.n} nodes")


def run_cmd(
    plan: Path = typer.Option(..., "--plan", help="Plan file (from gprace plan), or a raceline CSV (TUM or F1TENTH) with --track."),
    plant: str = typer.Option("audi_hidden", "--plant", help="Plant config: shipped name or TOML path."),
    track: str | None = typer.Option(None, "--track", help="Track (default: the plan's track by name)."),
    vehicle: str = typer.Option("audi_tt_cup", "--vehicle", help="The controller's nominal vehicle."),
    model: Path | None = typer.Option(None, "--model", help="Tracking GP (gp_model, feature map 'tracking')."),
    candidates: Path | None = typer.Option(None, "--candidates", help="Exploration candidates (from iterate); default: built from the GP's data."),
    alpha: float = typer.Option(0.0, "--alpha", help="Exploration trade-off in [0, 1] (0: plain tracking)."),
    laps: float = typer.Option(1.0, "--laps", help="Laps to drive."),
    solver: str = typer.Option("clarabel", "--solver", help="QP backend: clarabel, cvxpy-clarabel, casadi or a plugin."),
    beta: float = typer.Option(0.6, "--beta", help="Risk parameter of the lateral chance constraints."),
    radius: float = typer.Option(0.5, "--explore-radius", help="Exploration trust region (scaled feature distance)."),
    delay: float | None = DELAY,
    seed: int = typer.Option(0, "--seed", help="Seed of the plant's sensor noise."),
    output: Path = typer.Option(..., "--output", "-o", help="Run file to write (.h5)."),
    mcap: Path | None = MCAP,
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
) -> None:
    """Drive a plan on a plant with the (GP-compensated, exploring) tracking MPC; record a run."""
    from gprace.backends import solvers
    from gprace.console import console
    from gprace.errors import ConfigError, RunFailedError
    from gprace.io.runs import write_run
    from gprace.model import NominalModel, load_plant, load_vehicle
    from gprace.mpc.tracking import MPCSettings
    from gprace.timetrial.drive import DriveSettings, drive
    from gprace.io.artifacts import check_output
    from gprace.plan.raceline import load_plan

    check_output(output)
    check_output(mcap, "--mcap")
    if not 0.0 <= alpha <= 1.0:
        raise ConfigError(f"--alpha must be in [0, 1], got {alpha}")
    if laps <= 0:
        raise ConfigError(f"--laps must be positive, got {laps}")
    m = NominalModel(load_vehicle(vehicle))
    known = m.vehicle.known_delay if delay is None else delay
    if delay is None and known is not None:  # the vehicle's delays: named as the vehicle's, not as --delay
        from gprace.mpc.delay import check

        check(known, MPCSettings().N, MPCSettings().dt, f"--vehicle {vehicle}: actuator_delay + measurement_delay")
    # checks radius, beta and the delay (at most the horizon)
    mpc = MPCSettings(solver=solver, beta=beta, explore_radius=radius, delay=known or 0.0)
    solvers.get(solver)  # an unknown name lists the registered ones
    gp = grid = None
    if model is not None:
        from gprace.timetrial.learning import load_predictor

        gp = load_predictor(model, "tracking")
    p0, tr = load_plan(plan, track, m.vehicle, gp=gp, dt=mpc.dt)  # a plan file, or a raceline CSV on --track
    if alpha > 0:
        grid = _exploration_grid(gp, candidates, mpc)
    settings = DriveSettings(laps=laps, mpc=mpc)
    plant_cfg = load_plant(plant)
    console.info(f"run: driving {plan} on {plant} for {laps:g} lap(s) with the tracking MPC"
                 + (" and the tracking GP" if gp is not None else "") + (f", exploring (alpha {alpha:g})" if alpha > 0 else ""))
    run = drive(p0, plant_cfg, tr, m, settings, gp=gp, grid=grid, alpha=alpha, seed=seed)
    write_run(run, output)
    if mcap is not None:  # also for a lost lap: where it went is what an engineer looks at
        from gprace.report.mcap import write_plan_run

        write_plan_run(mcap, tr, p0, run, m, gp, mpc.dt, mpc.N, [f"gprace run {plan} on {plant}: {run.meta['reason'] or 'completed'}"])
    mt = run.meta
    _print_run(output, mt, as_json)
    if not mt["completed"]:  # a failed run (the record is kept for inspection): exit 1
        raise RunFailedError(f"run: {mt['reason']}; the partial run is in {output}")


def _exploration_grid(gp, candidates: Path | None, mpc):
    """Algorithm 1's candidates for ``run --alpha``: the ``--candidates`` file, else built from the
    tracking GP's training inputs in data units (the MPC's features)."""
    from gprace.errors import ConfigError
    from gprace.explore.algorithm import CandidateGrid
    from gprace.io.artifacts import read_artifact

    if gp is None:
        raise ConfigError("--alpha > 0 needs --model (exploration ranks candidates by the tracking GP's variance)")
    if candidates is not None:
        c = read_artifact(candidates, "candidates")
        return CandidateGrid(c.arrays["Z"], c.arrays["v"], c.arrays["scale"])
    from gprace.gp import train_inputs
    from gprace.timetrial.iterate import make_grid

    return make_grid(gp.gp, train_inputs(gp.gp), mpc, 7)


def _print_run(output: Path, mt: dict, as_json: bool) -> None:
    """The result of ``gprace run``: JSON, or one line."""
    from gprace.console import console

    if as_json:
        console.json({"output": str(output), **{k: mt[k] for k in ("lap_time", "planned_lap_time", "completed", "reason",
                                                                  "border_hit_steps", "fallbacks")},
                      "solve_time_median_ms": 1e3 * mt["solve_time_median"]})
        return
    lap = (f"lap {mt['lap_time']:.2f} s" if math.isfinite(mt["lap_time"])
           else "no full lap" if mt["completed"] else "lap not completed")
    console.result(
        f"{output}: {lap} (planned {mt['planned_lap_time']:.2f} s), completed {mt['completed']}, "
        f"border-hit steps {mt['border_hit_steps']}, fallbacks {mt['fallbacks']}, QP median {1e3 * mt['solve_time_median']:.2f} ms"
    )


def iterate_cmd(
    alpha: str = typer.Option("0.857,0.714,0", "--alpha", help="Exploration alphas per iteration; the last repeats."),
    iterations: int = typer.Option(7, "--iterations", help="GP iterations after the nominal iteration 0."),
    trials: int = typer.Option(3, "--trials", help="Independent repetitions (seeds)."),
    selection: str = typer.Option("diverse", "--selection", help="Data selection: diverse (paper) or random (baseline)."),
    plant: str = PLANT,
    track: str = typer.Option("gprace_ring", "--track", help="Track."),
    vehicle: str = VEHICLE,
    dictionary: int = DICTIONARY,
    features: str = FEATURES,
    grip: bool = typer.Option(True, "--grip/--no-grip", help="Rear-slip (grip) constraint in the tracking MPC; --no-grip is the paper's QP."),
    solver: str = typer.Option("clarabel", "--solver", help="QP backend."),
    delay: float | None = DELAY,
    seed: int = SEED,
    workers: int | None = WORKERS, executor: str = EXECUTOR, scheduler: str | None = SCHEDULER,
    out: Path = typer.Option(Path("iterate_out"), "--out", help="Folder for every artifact (rerun to resume)."),
    mcap: Path | None = MCAP,
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """The iterative double-GP time trial with active exploration (resumable)."""
    from gprace.timetrial.iterate import IterateSettings, iterate

    st = IterateSettings(alphas=_floats(alpha, "--alpha"), iterations=iterations, trials=trials, selection=selection,
                         plant=plant, track=track, vehicle=vehicle, dictionary_size=dictionary, solver=solver, seed=seed,
                         features=features, grip=grip, delay=delay)
    from gprace.executor import check_execution

    check_execution(executor, 1 if workers is None else workers, scheduler)
    from gprace.io.artifacts import check_output

    check_output(mcap, "--mcap")
    from gprace.errors import RunFailedError

    failed = None
    try:
        summary = iterate(st, out, executor=executor, workers=workers, scheduler=scheduler)
    except RunFailedError as exc:  # a failed trial: the MCAP still shows the finished laps
        failed = exc
    if mcap is not None:
        from gprace.report.mcap import write_iterate

        write_iterate(out, mcap)
    if failed is not None:
        raise failed
    _print_summary(summary, as_json)


def eval_timetrial(
    plant: str = PLANT,
    track: str = typer.Option("gprace_ring", "--track", help="Track: shipped name or a TUM CSV/TOML path."),
    vehicle: str = VEHICLE,
    trials: int = typer.Option(3, "--trials", help="Independent repetitions (the same seeds in both variants)."),
    iterations: int = typer.Option(7, "--iterations", help="GP iterations after the nominal iteration 0."),
    features: str = FEATURES,
    dictionary: int = DICTIONARY,
    seed: int = SEED,
    workers: int | None = WORKERS, executor: str = EXECUTOR, scheduler: str | None = SCHEDULER,
    out: Path = typer.Option(Path("timetrial_out"), "--out", help="Folder of both variants (rerun to resume)."),
    as_json: bool = typer.Option(False, "--json", help="Print the table as JSON."),
) -> None:
    """The paper's comparison: exploration (alpha 0.857,0.714,0, diverse) vs Double GP (alpha 0, random)."""
    from gprace.console import console
    from gprace.errors import RunFailedError
    from gprace.timetrial.compare import compare, format_table
    from gprace.timetrial.iterate import IterateSettings

    st = IterateSettings(iterations=iterations, trials=trials, plant=plant, track=track, vehicle=vehicle,
                         dictionary_size=dictionary, seed=seed, features=features)
    from gprace.executor import check_execution

    check_execution(executor, 1 if workers is None else workers, scheduler)
    res = compare(st, out, executor=executor, workers=workers, scheduler=scheduler)
    if as_json:
        console.json(res)
    else:
        console.result(format_table(res))
    if res["error"]:
        raise RunFailedError(res["error"])


def evaluate_iterate(
    folder: Path = typer.Argument(..., help="An iterate --out folder."),
    as_json: bool = typer.Option(False, "--json", help="Print as JSON."),
) -> None:
    """Print the summary table of an iterate folder (finished steps only)."""
    from gprace.timetrial.iterate import build_summary

    _print_summary(build_summary(folder), as_json)


def register(app: typer.Typer) -> None:
    app.command("plan")(plan_cmd)
    app.command("run")(run_cmd)
    app.command("iterate")(iterate_cmd)
    ev = eval_group(app)
    ev.command("timetrial", rich_help_panel=RUN_PANEL)(eval_timetrial)
    ev.command("iterate", rich_help_panel=SCORE_PANEL)(evaluate_iterate)


def _print_summary(summary: dict, as_json: bool) -> None:
    """Plain fixed-width tables (readable in pipes and logs at any terminal width)."""
    from gprace.console import console

    if as_json:
        console.json(summary)
        return
    head = ("iter", "trial", "alpha", "planned", "driven", "gap", "errTrk", "errPln", "Mtrk", "Mpln", "qp50ms", "qp99ms",
            "hits", "fallb", "interv")
    keys = ("iteration", "trial", "alpha", "planned", "driven", "gap", "err_tracking", "err_planning", "dict_tracking",
            "dict_planning", "solve_median_ms", "solve_p99_ms", "border_hits", "fallbacks", "interventions")
    lines = ["per iteration and trial (lap times [s]; GP errors: RMS on the held-out weaving run, per output / its std)",
             " ".join(f"{h:>7}" for h in head)]
    for r in summary["rows"]:
        note = "" if r.get("completed", True) else f"  ({r.get('reason')})"
        if r.get("plan_source", "").startswith(("back", "last good")):
            note += f"  [{r['plan_source']}]"
        lines.append(" ".join(_cell(r.get(k)) for k in keys) + note)
    lines.append("")
    lines.append("per iteration, mean +- std over the completed laps; done = laps completed of laps driven;")
    lines.append("cov = smallest share of held-out errors inside the GP's 95 % band; closed = smallest share of the")
    lines.append("gap between iteration 0 and the oracle lap closed by a trial; interv = stability-envelope interventions")
    head2 = ("iter", "alpha", "done", "planned", "+-", "driven", "+-", "gap", "errTrk", "errPln", "covTrk", "covPln", "closed",
             "interv")
    keys2 = ("iteration", "alpha", "done", "planned_mean", "planned_std", "driven_mean", "driven_std", "gap_mean",
             "err_tracking", "err_planning", "cov_tracking", "cov_planning", "gap_closed_min", "interventions")
    lines.append(" ".join(f"{h:>7}" for h in head2))
    for a in summary["by_iteration"]:
        a = {**a, "done": f"{a['completed']}/{a['trials']}"}
        lines.append(" ".join(_cell(a.get(k)) for k in keys2))
    from gprace.timetrial.iterate import failed_laps_text

    lines += failed_laps_text(summary["by_iteration"])
    o = summary.get("oracle")
    if o is not None:
        lines.append("")
        if o.get("known"):
            planned, driven = (float("nan") if o.get(k) is None else o[k] for k in ("planned", "driven"))
            lines.append(f"oracle lap (true physics: {', '.join(o.get('effects', []))}): planned {_cell(planned).strip()} s, "
                         f"driven {_cell(driven).strip()} s" + ("" if o.get("completed") else f" ({o.get('reason')})")
                         + f"; 'closed' measured against the {o.get('basis', 'driven')} lap")
        else:
            lines.append(f"oracle lap: unknown ({o.get('why', 'plant physics not known')})")
    best = [t for t in summary.get("per_trial", []) if math.isfinite(t["best_alpha0"])]
    if best:
        lines.append("best alpha-0 lap per trial (iteration 0 -> best, share of the gap to the oracle closed): " + "; ".join(
            f"trial {t['trial']}: {t['iteration0']:.2f} -> {t['best_alpha0']:.2f} s (it {t['best_iteration']}, {_cell(t['gap_closed_best']).strip()})"
            for t in best))
    console.result("\n".join(lines))


def _cell(v) -> str:
    if isinstance(v, bool):
        return f"{str(v):>7}"
    if isinstance(v, int):
        return f"{v:>7d}"
    if isinstance(v, float):
        return f"{v:>7.3f}" if abs(v) < 1000 else f"{v:>7.0f}"
    return f"{str(v):>7}"
