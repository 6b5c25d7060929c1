"""The command groups several stages share: ``gprace eval`` (with its two help panels) and
``gprace h2h``. One module owns them; the stage modules of :mod:`gprace.cli` add their commands."""

from __future__ import annotations

import typer

EVAL_HELP = ("Evaluate: run the paper's protocols (timetrial, head2head) or score finished results (iterate: "
             "the table of an iterate folder; gp: a GP model on a recording).")
H2H_HELP = "Head-to-head racing steps: collect, train, explore."
RUN_PANEL, SCORE_PANEL = "Run a protocol", "Score finished results"


def group(app: typer.Typer, name: str, help: str) -> typer.Typer:
    """The sub-app ``name`` of ``app``, created by the first stage that asks for it."""
    for info in app.registered_groups:
        if info.name == name and info.typer_instance is not None:
            return info.typer_instance
    sub = typer.Typer(help=help, no_args_is_help=True)
    app.add_typer(sub, name=name)
    return sub


def eval_group(app: typer.Typer) -> typer.Typer:
    """``gprace eval``: the stages add their subcommands with ``eval_group(app).command(name,
    rich_help_panel=RUN_PANEL or SCORE_PANEL)``. ``gprace evaluate``, its old name for scoring
    finished results, is an alias made in :mod:`gprace.cli`."""
    return group(app, "eval", EVAL_HELP)


def h2h_group(app: typer.Typer) -> typer.Typer:
    return group(app, "h2h", H2H_HELP)
