"""``gprace track show``: summary and optional picture of a track."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    track_app = typer.Typer(help="Inspect race tracks (TUM CSV, two boundary files, segment TOML, shipped names).", no_args_is_help=True)

    @track_app.command("show")
    def show_cmd(
        files: list[str] = typer.Argument(..., help="Track: a centre-line .csv (TUM, with or without header), two boundary files (INNER OUTER, or INNER,OUTER), a .toml (segments) path, or a shipped name."),
        plot: Path | None = typer.Option(None, "--plot", help="Write a PNG of centre line and borders."),
        smoothing: float | None = typer.Option(None, "--smoothing", help="Whittaker smoothing length of a CSV centre line [m]; default its point spacing, at most 5 m."),
        on_track: str | None = typer.Option(None, "--track", help="For a raceline file: the track it was planned on (where the line lies on it)."),
        as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
    ) -> None:
        """Print length, min radius, width range and point count of a track, or a raceline's (TUM or F1TENTH CSV); optionally plot it."""
        from gprace.errors import InputError
        from gprace.tracks import load_track

        if len(files) > 2:
            raise InputError(f"track show: one track file, or two boundary files; got {len(files)}")
        if len(files) == 1 and files[0].lower().endswith((".csv", ".txt")):
            from gprace.tracks.raceline import is_raceline

            if is_raceline(files[0]):
                show_raceline(files[0], on_track, plot, as_json)
                return
        if on_track is not None:
            raise InputError("track show: --track is for a raceline file (it names the track the line lies on)")
        try:
            track = load_track(files if len(files) == 2 else files[0], smoothing=smoothing)
        except InputError as exc:
            raise InputError(str(exc).replace("--track-smoothing", "--smoothing")) from None
        info = track.summary()
        if plot is not None:
            plot_track(track, plot)
        _print_summary(info, [
            f"track       {info['name']} ({'closed' if info['closed'] else 'open'})",
            f"length      {info['length_m']:.2f} m",
            f"min radius  {info['min_radius_m']:.2f} m",
            f"width       {info['width_min_m']:.2f} .. {info['width_max_m']:.2f} m",
            f"points      {info['n_points']}",
            f"smoothing   {info['smoothing_m']:.3g} m"], plot, as_json)

    app.add_typer(track_app, name="track")


def show_raceline(path: str, on_track: str | None, plot: Path | None, as_json: bool) -> None:
    """``track show RACELINE [--track T]``: the raceline's summary, and where it lies on a track."""
    from gprace.tracks import load_track
    from gprace.tracks.raceline import raceline_summary, raceline_track, read_raceline

    rl = read_raceline(path)
    track = load_track(on_track) if on_track else None
    info = raceline_summary(rl, track)
    if plot is not None:
        plot_track(track or raceline_track(rl), plot, line=(rl.x, rl.y))
    lines = [f"raceline    {path} ({info['format']} format, closed loop)",
             f"length      {info['length_m']:.2f} m, {info['points']} points",
             f"lap time    {info['lap_time_s']:.3f} s at its speeds ({info['speed_min_mps']:.2f} .. {info['speed_max_mps']:.2f} m/s)",
             f"ax          {info['ax_min_mps2']:.2f} .. {info['ax_max_mps2']:.2f} m/s^2",
             f"min radius  {info['min_radius_m']:.2f} m"]
    if "track" in info:
        where = "inside" if info["inside"] else "OUTSIDE"
        lines += [f"on track    {info['track']} ({info['track_length_m']:.2f} m"
                  + (", driven against its file's direction" if info["against_track_direction"] else "") + ")",
                  f"e_y         {info['e_y_min_m']:.3f} .. {info['e_y_max_m']:.3f} m; {where} the borders, "
                  f"closest {info['margin_min_m']:.3f} m"]
    elif "margin_min_m" in info:
        lines.append(f"borders     closest {info['margin_min_m']:.3f} m (its own d_right / d_left)")
    _print_summary(info, lines, plot, as_json)


def _print_summary(info: dict, lines: list[str], plot: Path | None, as_json: bool) -> None:
    """A summary as JSON, or as fixed-width lines with the plot's path last."""
    from gprace.console import console

    if plot is not None:
        info["plot"] = str(plot)
        lines = [*lines, f"plot        {plot}"]
    if as_json:
        console.json(info)
        return
    for line in lines:
        console.result(line)


def plot_track(track, path: Path, line=None) -> None:
    """Centre line, borders and start marker of ``track`` as a PNG (headless)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gprace.errors import InputError
    from gprace.report.figures import write_png

    path = Path(path)
    if path.parent and not path.parent.exists():
        raise InputError(f"{path}: folder {path.parent} does not exist")
    (xl, yl), (xr, yr) = track.borders()
    smp = track.sample(min(track.length / 2000, 1.0))
    fig, ax = plt.subplots(figsize=(7, 7))
    try:
        if track.closed:
            xl, yl, xr, yr = (list(a) + [a[0]] for a in (xl, yl, xr, yr))
            cx, cy = list(smp.x) + [smp.x[0]], list(smp.y) + [smp.y[0]]
        else:
            cx, cy = smp.x, smp.y
        ax.plot(xl, yl, color="0.2", lw=1.0, label="borders")
        ax.plot(xr, yr, color="0.2", lw=1.0)
        ax.plot(cx, cy, color="tab:blue", lw=0.8, ls="--", label="centre line")
        if line is not None:
            ax.plot(list(line[0]) + [line[0][0]], list(line[1]) + [line[1][0]], color="tab:orange", lw=1.0, label="raceline")
        ax.plot(smp.x[0], smp.y[0], "o", color="tab:red", label="start")
        hx, hy = smp.x[1] - smp.x[0], smp.y[1] - smp.y[0]
        scale = 0.03 * max(float(max(smp.x) - min(smp.x)), float(max(smp.y) - min(smp.y)), 1e-9)
        norm = (hx * hx + hy * hy) ** 0.5
        ax.annotate(
            "",
            xy=(smp.x[0] + scale * hx / norm * 2, smp.y[0] + scale * hy / norm * 2),
            xytext=(smp.x[0], smp.y[0]),
            arrowprops={"arrowstyle": "->", "color": "tab:red"},
        )
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"{track.name}: {track.length:.1f} m, min radius {track.min_radius:.1f} m")
        ax.legend(loc="best", fontsize="small")
        fig.tight_layout()
        write_png(fig, path, dpi=110)
    finally:
        plt.close(fig)
