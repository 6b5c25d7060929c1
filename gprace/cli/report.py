"""``gprace show`` (one result file) and ``gprace report`` (a whole folder as one HTML page)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("show")
    def show_cmd(
        file: Path = typer.Argument(..., help="An artifact (.h5 of any kind), a CSV run, or a result JSON."),
        plot: Path | None = typer.Option(None, "--plot", help="Write a figure of it to this PNG (more than one: _2, _3 ...)."),
        features: str | None = typer.Option(None, "--features", help="Two input names (or indices) for dataset/GP plots, e.g. v_y,delta."),
        against: str = typer.Option("t", "--against", help="Runs: draw against time 't' or arc length 's'."),
        as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
    ) -> None:
        """Summarise FILE: kind, schema, provenance, attributes, arrays and its key results."""
        from gprace.console import console
        from gprace.report.inspect import describe, summary_lines

        info = describe(file)
        if plot is not None:
            from gprace.report.single import figures_for, save_figures

            info["plots"] = [str(p) for p in save_figures(figures_for(file, _two_features(features), against), plot)]
        if as_json:
            console.json(info)
            return
        for line in summary_lines(info):
            console.result(line)
        for p in info.get("plots", []):
            console.result(f"plot            {p}")

    @app.command("report")
    def report_cmd(
        folder: Path = typer.Argument(..., help="Folder to scan (recursively) for gprace results."),
        out: Path = typer.Option(Path("report.html"), "-o", "--out", help="The HTML page to write."),
        png: Path | None = typer.Option(None, "--png", help="Also write every figure as a PNG into this folder."),
        track: str | None = typer.Option(None, "--track", help="Track (name or file) for maps when the results do not name one."),
        features: str | None = typer.Option(None, "--features", help="Two GP input names (or indices) for the posterior plots."),
    ) -> None:
        """Build one self-contained HTML page (figures embedded) from every result under FOLDER."""
        from gprace.console import console
        from gprace.report.html import build_report

        rep = build_report(folder, out, png_dir=png, track=track, features=_two_features(features))
        console.result(f"report      {rep.path}")
        console.result(f"sections    {', '.join(s.title for s in rep.sections) or 'none'}")
        console.result(f"figures     {rep.n_figures}")
        if png is not None:
            console.result(f"png         {png} ({rep.n_figures} files)")
        for note in rep.missing:
            console.warn(note)


def _two_features(text: str | None) -> tuple[str, str] | None:
    """``--features a,b``: the two GP inputs of the posterior plots (None: the default pair)."""
    if not text:
        return None
    from gprace.errors import InputError

    parts = [p.strip() for p in text.split(",") if p.strip()]
    if len(parts) != 2:
        raise InputError(f"--features: give two names separated by a comma, got {text!r}")
    return parts[0], parts[1]
