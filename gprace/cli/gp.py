"""GP commands: ``gprace select-data``, ``gprace retrain``, ``gprace eval gp``.

Heavy imports (scikit-learn, the model) happen inside the commands; the work is in
:mod:`gprace.gp.stages`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from gprace.cli.groups import SCORE_PANEL, eval_group
from gprace.console import console

JSON = typer.Option(False, "--json", help="Print the result as JSON.")


def select_data_cmd(
    inputs: list[Path] = typer.Argument(..., help="Runs (HDF5 or CSV) and optionally one dataset (data.h5) to continue."),
    output: Path = typer.Option(..., "--output", "-o", help="Dataset to write (HDF5, kind 'dataset')."),
    gp: str = typer.Option("tracking", "--gp", help="Feature map: tracking | planning (opponent data come from `gprace h2h collect`)."),
    max_points: int = typer.Option(2000, "--max-points", help="Dictionary size M."),
    selection: str = typer.Option("diverse", "--selection", help="diverse (paper) | random (baseline)."),
    vehicle: Optional[str] = typer.Option(None, "--vehicle", help="Nominal vehicle (name or TOML) for runs that carry none."),
    model: Optional[Path] = typer.Option(None, "--model", help="gp_model whose hyperparameters the diverse selection uses."),
    kernel: str = typer.Option("se", "--kernel", help="Kernel of the quick fit when no model is given: se | matern15."),
    step: str = typer.Option("euler", "--step", help="Nominal step the errors refer to: euler (paper) | rk4."),
    outlier_kappa: float = typer.Option(4.0, "--outlier-kappa", help="Outlier gate in standard deviations (0 disables)."),
    seed: int = typer.Option(0, "--seed", help="Seed of subsampling."),
    features: str = typer.Option("paper", "--features", help="GP inputs of tracking/planning: paper [v_y, yaw_rate, delta] | full (adds v_x, a_x)."),
    json_out: bool = JSON,
) -> None:
    """Build or extend a GP dataset: features of RUNs, diverse (or random) selection of M points."""
    from gprace.errors import ConfigError
    from gprace.gp.stages import select_data
    from gprace.ingest.dispatch import read_any

    from gprace.io.artifacts import check_output

    check_output(output)
    if not outlier_kappa >= 0:
        raise ConfigError(f"--outlier-kappa must be >= 0 (standard deviations; 0 disables the gate), got {outlier_kappa}")
    res = select_data(inputs, output, gp, max_points, selection, vehicle, model, kernel, step,
                      outlier_kappa if outlier_kappa > 0 else None, seed, features, read=read_any)
    for note in res["notes"]:
        console.warn(note)
    if json_out:
        console.json(res)
        return
    st = res["stats"]
    extra = ""
    if selection == "diverse":
        extra = (f"; replaced {st['replaced']}, inserted {st['inserted']}, rejected {st['rejected_variance']} "
                 f"(variance) + {st['rejected_outlier']} (outliers); hyperparameters from {st['hyperparameters_from']}")
    console.result(f"wrote {res['output']}: {res['points']} of at most {res['max_points']} points "
                   f"({res['feature_map']}, {selection}) from {res['new_samples']} new samples{extra}")


def retrain_cmd(
    data: Path = typer.Argument(..., help="Dataset from select-data."),
    output: Path = typer.Option(..., "--output", "-o", help="Model file to write (kind 'gp_model')."),
    backend: str = typer.Option("exact", "--backend", help="GP backend: exact | sparse | a plugin."),
    kernel: str = typer.Option("se", "--kernel", help="se | matern15."),
    seed: int = typer.Option(0, "--seed", help="Seed (subsampling, inducing points)."),
    opt: list[str] = typer.Option([], "--opt", help="Backend setting key=value, repeatable (e.g. max_fit_points=800)."),
    json_out: bool = JSON,
) -> None:
    """Fit GP hyperparameters and posterior on a dataset; write the model."""
    from gprace.gp.stages import parse_opts, retrain
    from gprace.io.artifacts import check_output

    check_output(output)
    res = retrain(data, output, backend, kernel, seed, parse_opts(opt))
    if json_out:
        console.json(res)
        return
    rows = []
    for name, o in res["outputs"].items():
        ls = ", ".join(f"{k} {v:.3g}" for k, v in o["length_scales"].items())
        rows.append([name, ls, o["signal_std"], o["noise_std"]])
    console.table(f"{res['backend']} GP ({res['kernel']}) on {res['points']} points, {res['seconds']:.1f} s",
                  ["output", "length scales", "signal std", "noise std"], rows)
    console.result(f"wrote {res['output']}")


def evaluate_gp_cmd(
    model: Path = typer.Argument(..., help="GP model (tracking or planning)."),
    run: Path = typer.Argument(..., help="Recording to evaluate on (HDF5 or CSV)."),
    vehicle: Optional[str] = typer.Option(None, "--vehicle", help="Nominal vehicle for a recording that carries none."),
    json_out: bool = JSON,
) -> None:
    """GP error on a recording: RMSE, MAE and 95% calibration per output, next to the nominal model's RMSE."""
    from gprace.gp.stages import evaluate_gp
    from gprace.ingest.dispatch import read_any

    res = evaluate_gp(model, run, vehicle, read=read_any)
    for note in res["notes"]:
        console.warn(note)
    if json_out:
        console.json(res)
        return
    rows = [[name, m["nominal_rmse"], m["rmse"], m["mae"], f"{100 * m['inside_95']:.1f} %"]
            for name, m in res["outputs"].items()]
    console.table(f"{res['feature_map']} GP on {res['run']} ({res['samples']} samples)",
                  ["output", "nominal RMSE", "GP RMSE", "GP MAE", "inside 95%"], rows)


def register(app: typer.Typer) -> None:
    app.command("select-data")(select_data_cmd)
    app.command("retrain")(retrain_cmd)
    eval_group(app).command("gp", rich_help_panel=SCORE_PANEL)(evaluate_gp_cmd)
