"""``gprace learn`` and ``gprace eval learn``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import typer

from gprace.cli.groups import SCORE_PANEL, eval_group


def learn_cmd(
    recordings: list[Path] = typer.Argument(..., help="Recorded laps: raw logs (CSV, MCAP, bag, MDF4; map beside them or --map) or gprace runs."),
    track: str = typer.Option(..., "--track", help="Track: a centre-line CSV, INNER.csv,OUTER.csv, an F1TENTH waypoint file or a shipped name."),
    vehicle: str = typer.Option(..., "--vehicle", help="Nominal vehicle: shipped name or TOML path."),
    out: Path = typer.Option(..., "--out", help="Folder of the iterations (rerun to resume; the next recordings make the next iteration)."),
    alpha: Optional[float] = typer.Option(None, "--alpha", help="Exploration weight in [0, 1]: also write Algorithm 1's candidates and reference."),
    map_file: Optional[Path] = typer.Option(None, "--map", help="Recording map of raw recordings (default: <name>.map.toml beside each)."),
    dt: float = typer.Option(0.05, "--dt", help="Controller step the recordings are resampled to [s]."),
    dictionary: int = typer.Option(1000, "--dictionary-size", help="GP dictionary size M per GP."),
    features: str = typer.Option("full", "--features", help="GP inputs: full (v_x, v_y, yaw_rate, delta, a_x) or paper (v_y, yaw_rate, delta)."),
    selection: str = typer.Option("diverse", "--selection", help="Data selection: diverse (paper) or random (baseline)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the hyperparameter fit and the selection."),
    mcap: Optional[Path] = typer.Option(None, "--mcap", help="Also write the recorded and planned laps, the GP's band and the track as MCAP (Foxglove schemas)."),
    as_json: bool = typer.Option(False, "--json", help="Print the iteration's record as JSON."),
    driven: Optional[Path] = typer.Option(None, "--driven", help="First iteration: the plan or raceline (gprace plan, TUM or F1TENTH CSV) the recordings drove; the widening starts from its limits (default: the measured envelope, not widened)."),
    widen: float = typer.Option(0.05, "--widen", help="Widening of the limits per clean iteration (as iterate)."),
    widen_max: float = typer.Option(0.15, "--widen-max", help="Widening per clean iteration that used little of the tires' slip (as iterate)."),
    never_worse: bool = typer.Option(True, "--never-worse/--no-never-worse", help="As iterate: after a lost or slower lap back to the last good limits; an unsafe new plan is replaced by the last good one."),
) -> None:
    """Learn from recorded laps: retrain both GPs, re-plan the lap, write the next raceline (TUM and F1TENTH CSV) and the portable tracking GP."""
    from gprace.console import console
    from gprace.io.artifacts import check_output
    from gprace.learn.workflow import STAGES, LearnSettings, learn

    check_output(mcap, "--mcap")
    st = LearnSettings(track=track, vehicle=vehicle, map_file=str(map_file) if map_file else None, dt=dt, alpha=alpha,
                       dictionary_size=dictionary, features=features, selection=selection, seed=seed,
                       driven=str(driven) if driven else None, widen=widen, widen_max=widen_max, never_worse=never_worse)
    from gprace.learn.workflow import check_inputs

    checked = check_inputs(recordings, st, out)  # before the start line: a refusal is one line
    with console.progress(f"learn: {len(recordings)} recording(s) -> {out}", total=len(STAGES), unit="stages") as bar:

        def stage_done(name: str) -> None:  # the bar names the stage being worked on
            i = STAGES.index(name) + 1
            bar.update(completed=i, description=f"learn: {STAGE_TEXT[STAGES[i]]}" if i < len(STAGES) else "learn: done")

        bar.update(description=f"learn: {STAGE_TEXT[STAGES[0]]}")  # the start line says what and where
        rec = learn(recordings, st, out, progress=stage_done, checked=checked)
    if mcap is not None:
        from gprace.learn.workflow import write_mcap

        write_mcap(Path(out), rec["iteration"], mcap)
    if as_json:
        console.json(rec)
        return
    console.result("\n".join(summary_lines(rec, mcap)))


# what learn's bar says while a stage runs
STAGE_TEXT = {"import": "importing the recordings", "select": "selecting the GPs' data", "retrain": "retraining the GPs",
              "plan": "re-planning the lap (IPOPT)", "export": "writing the racelines and the portable GP",
              "predict": "predicting the band along the lap"}


def cut_text(recordings: list[dict]) -> str:
    """What the envelope left out of learning, by reason over the recordings (a spin of a lost lap
    is counted here, the rest of its lap is learned from)."""
    cut: dict[str, int] = {}
    for r in recordings:
        for why, n in r.get("cut", {}).items():
            cut[why] = cut.get(why, 0) + int(n)
    return f" (left out: {', '.join(f'{why} {n}' for why, n in sorted(cut.items()))})" if any(cut.values()) else ""


def summary_lines(rec: dict, mcap: Path | None = None) -> list[str]:
    """The learn result as an engineer reads it."""
    k, d = rec["iteration"], Path(rec["out"]) / f"iter_{rec['iteration']:02d}"
    laps = [t for r in rec["recordings"] for t in r["laps"]]
    best = f", best {min(laps):.3f} s" if laps else ""
    lines = [f"iteration {k} in {rec['out']}" + (" (already learned from these recordings)" if rec.get("already_done") else ""),
             f"recordings: {len(rec['recordings'])}, {len(laps)} whole lap(s){best}; usable samples "
             f"{sum(r['usable'] for r in rec['recordings'])} of {sum(r['samples'] for r in rec['recordings'])}"
             + cut_text(rec["recordings"])]
    g = rec["retrain"]
    lines.append("GP dictionaries: " + ", ".join(f"{kk} {v['dictionary']} points ({v['new']} new samples, variance x"
                                                 f"{max(v['var_scale']):.2f})" for kk, v in g.items()))
    lim, p = rec["grip"], rec["plan"]
    lines.append(f"predicted lap time: {p['planned_lap_time']:.3f} s"
                 + (f" (re-plan FAILED, previous plan kept: {p['replan_failed']})" if p["replan_failed"] else "")
                 + (f" (the new plan was not predicted safe: {p['unsafe']}; {p['warm_start']} kept)" if p.get("unsafe") else ""))
    if lim.get("source", "replan") != "replan":
        lines.append(f"limits: {lim['source']} (the last lap was {lim['status'][-1]})")
    lines.append("friction ellipse [m/s^2] lateral/drive/brake: " + " / ".join(f"{v:.2f}" for v in lim["limits"])
                 + " (measured " + " / ".join(f"{v:.2f}" for v in lim["measured"]) + ")")
    lines.append("where the plan uses most of the learned grip:")
    for gp in rec["prediction"]["grip_places"]:
        lines.append(f"  s {gp['s_start']:.1f}..{gp['s_end']:.1f} m: {100 * gp['use']:.0f} % of the ellipse at "
                     f"{gp['v_x']:.1f} m/s (a_lat {gp['a_lat']:.2f}, a_x {gp['a_x']:.2f} m/s^2)")
    pr = rec["prediction"]
    lines.append(f"GP band along the lap (95 %, lateral): median {pr['band_median_m']:.3f} m, widest "
                 f"{pr['band_max_m']:.3f} m at s = {pr['band_max_at_s']:.1f} m")
    lines.append("wrote: " + ", ".join(str(d / f) for f in rec["exports"]) + (f", {mcap}" if mcap else ""))
    return lines


def eval_learn_cmd(
    folder: Path = typer.Argument(..., help="A learn --out folder."),
    log: Path = typer.Argument(..., help="The next recorded log (driven on the iteration's raceline)."),
    iteration: Optional[int] = typer.Option(None, "--iteration", help="The iteration whose prediction is checked (default: the last)."),
    map_file: Optional[Path] = typer.Option(None, "--map", help="Recording map of a raw log."),
    as_json: bool = typer.Option(False, "--json", help="Print the comparison as JSON."),
) -> None:
    """Compare an iteration's prediction with the next recorded lap: lap time, speed along s, where the car left the GP's band."""
    from gprace.console import console
    from gprace.learn.workflow import evaluate_learn

    res = evaluate_learn(folder, log, iteration=iteration, map_file=map_file)
    if as_json:
        console.json(res)
        return
    lines = [f"{log} against iteration {res['iteration']} of {folder}: predicted lap {res['predicted_lap_s']:.3f} s"]
    if not res["laps"]:
        lines.append("no whole lap in the log")
    for lp in res["laps"]:
        lines.append(f"lap {lp['lap']}: {lp['time_s']:.3f} s ({lp['time_error_s']:+.3f} s), speed along s: mean "
                     f"{lp['speed_mean_mps']:+.2f}, rms {lp['speed_rms_mps']:.2f} m/s, largest {lp['speed_max_mps']:+.2f} m/s at "
                     f"s = {lp['speed_max_at_s']:.1f} m; {100 * lp['inside_band']:.1f} % inside the band")
        for b in lp["left_band"]:
            lines.append(f"  left the band at s {b['s_start']:.1f}..{b['s_end']:.1f} m: {b['deviation_m']:+.3f} m from the line "
                         f"(band {b['band_m']:.3f} m, {b['max_excess_m']:.3f} m beyond) at s = {b['at_s']:.1f} m")
    lines.append(f"{res['left_band']} stretch(es) outside the band" if math.isfinite(res["left_band"]) else "")
    console.result("\n".join(x for x in lines if x))


def register(app: typer.Typer) -> None:
    app.command("learn")(learn_cmd)
    eval_group(app).command("learn", rich_help_panel=SCORE_PANEL)(eval_learn_cmd)
