"""``gprace import``: a real recording (CSV, ROS bag / MCAP, MDF4) -> a Frenet run file."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer) -> None:
    @app.command("import")
    def import_cmd(
        recording: Optional[list[Path]] = typer.Argument(None, help="Recording: .csv (global frame), .mcap, .db3, .bag, a rosbag2 folder, .mf4/.mdf; several files of one drive (pose, IMU, commands) are merged on one time base."),
        track: Optional[str] = typer.Option(None, "--track", help="Track: a centre-line CSV (TUM, header optional), two boundary files INNER.csv,OUTER.csv, a segment TOML or a shipped name; default the map's track, else a reference line from the laps of the driven path."),
        track_smoothing: Optional[float] = typer.Option(None, "--track-smoothing", help="Whittaker smoothing length of a CSV track [m]; default its point spacing, at most 5 m."),
        output: Optional[Path] = typer.Option(None, "--output", "-o", help="Run file to write (.h5, or .csv with provenance in <name>.meta.json)."),
        map_file: Optional[Path] = typer.Option(None, "--map", help="Recording map (TOML): columns, topics, channels, units, signs."),
        dt: float = typer.Option(0.05, "--dt", help="Period of the written run, seconds."),
        print_map: bool = typer.Option(False, "--print-map", help="Print the default map (TOML) and exit."),
        json_out: bool = typer.Option(False, "--json", help="Summary as JSON on stdout."),
    ) -> None:
        """Resample RECORDING on one period, project it onto TRACK, write a run with its provenance."""
        from gprace.console import console
        from gprace.errors import InputError

        if print_map:
            from gprace.ingest.mapping import default_map_toml

            console.result(default_map_toml().rstrip("\n"))
            return
        if not recording:
            raise InputError("import: give a RECORDING (or --print-map)")
        if output is None:
            raise InputError("import: give the run file to write with -o/--output (.h5 or .csv)")
        if output.suffix.lower() not in (".h5", ".hdf5", ".csv"):
            raise InputError(f"{output}: the output must be .h5 or .csv")
        from gprace.io.artifacts import check_output

        check_output(output)
        import time

        from gprace.ingest.importer import import_hash, import_recording
        from gprace.ingest.mapping import load_map
        from gprace.io.runs import write_run

        t0 = time.perf_counter()
        rmap = load_map(map_file)
        run, trk = import_recording(recording, track=track, rmap=rmap, map_path=map_file, dt=dt, log=console.info,
                                    track_smoothing=track_smoothing)
        if map_file is not None:
            run.meta["map_file"] = str(map_file)
        write_run(run, output, config_hash=import_hash(run))  # a CSV gets its meta in <name>.meta.json
        elapsed = time.perf_counter() - t0
        d = run.data
        summary = {
            "output": str(output), "source": " + ".join(map(str, recording)), "samples": run.n, "duration_s": float(d["t"][-1]),
            "dt": dt, "track": trk.name, "reference": run.meta["reference"], "laps": int(d["lap"].max() - d["lap"].min()),
            "gaps": run.meta["gaps"], "rows_dropped": run.meta["rows_dropped"],
            "e_y_abs_max_m": float(abs(d["e_y"]).max()), "s_min_m": float(d["s"].min()), "s_max_m": float(d["s"].max()),
            "track_length_m": run.meta["track_length"], "inputs": run.meta["inputs"], "notes": run.meta["notes"],
            "seconds": elapsed,
        }
        if json_out:
            console.json(summary)
        else:
            console.result(
                f"wrote {output}: {run.n} samples, {summary['duration_s']:.1f} s at {dt:g} s, "
                f"{'track' if summary['reference'] == 'track' else 'reference line'} {trk.name}, "
                f"{summary['laps']} lap crossing(s), {summary['gaps']} gap(s), max |e_y| {summary['e_y_abs_max_m']:.2f} m"
            )

