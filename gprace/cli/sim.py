"""``gprace simulate``: drive a plant with the reference controller and record a run."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("simulate")
    def simulate_cmd(
        plant: str = typer.Option("audi_nominal", "--plant", help="Plant config: a TOML path or a shipped name."),
        track: str = typer.Option("gprace_ring", "--track", help="Track: a TUM CSV / segment TOML path or a shipped name."),
        laps: float = typer.Option(1.0, "--laps", help="Laps to drive (closed tracks; open tracks stop at the end)."),
        dt: float = typer.Option(0.05, "--dt", help="Control and recording period, seconds."),
        weave: float = typer.Option(0.0, "--weave", help="Weaving amplitude, share of the usable half width [0..1]."),
        wavelength: float = typer.Option(100.0, "--weave-wavelength", help="Weaving wavelength along the track, metres."),
        speed_scale: float = typer.Option(0.8, "--speed-scale", help="Fraction of the friction-limited speed."),
        seed: int = typer.Option(0, "--seed", help="Seed of the sensor noise (added to the plant's)."),
        output: Path = typer.Option(..., "--output", "-o", help="Run file to write (.h5, or .csv)."),
        csv: Path | None = typer.Option(None, "--csv", help="Also export the run as CSV."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
    ) -> None:
        """Drive PLANT around TRACK with a speed-profile + lateral-feedback controller; record a run."""
        import time

        import numpy as np

        from gprace.config import SimulateConfig, from_options
        from gprace.model import load_plant
        from gprace.console import console
        from gprace.io.artifacts import check_output
        from gprace.io.runs import write_run, write_run_csv

        check_output(output)
        check_output(csv, "--csv")
        from gprace.sim import lap_times, run_hash, simulate
        from gprace.sim.simulate import check_budget
        from gprace.tracks import load_track

        cfg = from_options(
            SimulateConfig,
            {"dt": dt, "laps": laps, "speed_scale": speed_scale, "weave_amplitude": weave,
             "weave_wavelength": wavelength, "seed": seed},
            {"weave_amplitude": "--weave"},
        )
        plant_cfg = load_plant(plant)
        trk = load_track(track)
        check_budget(plant_cfg, trk, cfg)
        console.info(f"simulate: driving {plant} on {trk.name} for {laps:g} lap(s)")
        t0 = time.perf_counter()
        run = simulate(plant_cfg, trk, cfg)
        elapsed = time.perf_counter() - t0
        write_run(run, output, config_hash=run_hash(run), seed=cfg.seed)
        if csv is not None:
            write_run_csv(run, csv)
        laps_t = ", ".join(f"{x:.2f}" for x in lap_times(run)) or "-"
        hits = int(np.sum(run.data["border_hit"] > 0))
        console.info(f"simulated {run.n} steps in {elapsed:.1f} s")
        if as_json:
            console.json({"output": str(output), "samples": run.n, "duration_s": float(run.data["t"][-1]),
                          "plant": plant, "plant_kind": plant_cfg.kind, "track": trk.name, "lap_times": list(lap_times(run)),
                          "border_hit_samples": hits})
            return
        console.result(
            f"wrote {output}: {run.n} samples, {run.data['t'][-1]:.1f} s, plant {plant} ({plant_cfg.kind}), "
            f"track {trk.name}, lap times [s]: {laps_t}, border-hit samples: {hits}"
        )
