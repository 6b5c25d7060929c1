"""``gprace diagnose``: locate the sim-to-real mismatch, name the missing physics, model it."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from gprace.console import console


def register(app: typer.Typer) -> None:
    @app.command("diagnose")
    def diagnose_cmd(
        recordings: List[Path] = typer.Argument(..., help="Recordings (HDF5 run artifacts or CSV), same track and period."),
        vehicle: str = typer.Option(..., "--vehicle", help="Nominal vehicle TOML (path or shipped name)."),
        json_out: bool = typer.Option(False, "--json", help="Machine-readable report on stdout."),
        output: Optional[Path] = typer.Option(None, "-o", "--output", help="Write the augmented vehicle TOML here."),
        plot: Optional[Path] = typer.Option(None, "--plot", help="Residual-along-track plot (PNG), before and after."),
        horizon: int = typer.Option(15, "--horizon", min=3, max=60, help="Multi-step prediction horizon in steps."),
        seed: int = typer.Option(0, "--seed", help="Seed of the noise twin."),
    ) -> None:
        """Compare recordings with the nominal model; name, fit and write the effects it leaves out."""
        from gprace.model import load_vehicle
        from gprace.diagnose.diagnose import diagnose
        from gprace.diagnose.report import summary_lines, write_augmented
        from gprace.ingest.dispatch import read_any

        from gprace.io.artifacts import check_output

        check_output(output)
        check_output(plot, "--plot")
        veh = load_vehicle(vehicle)
        runs = [read_any(p) for p in recordings]
        res = diagnose(runs, veh, horizon=horizon, seed=seed, augmented_name=str(output) if output else None,
                       log=console.info)
        if output is not None:
            write_augmented(res.vehicle, output, res.result)
        if plot is not None:
            from gprace.report.sections.diagnosis import plot_residuals

            plot_residuals(res, plot)
        if json_out:
            console.json(res.report)
        else:
            for line in summary_lines(res.report):
                console.result(line)
