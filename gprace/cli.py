"""The ``gprace`` command: a thin typer app.

Each stage contributes its commands through ``gprace/<stage>/commands.py`` with a function
``register(app)``; this module only assembles them and is the one exit door for errors: a
:class:`~gprace.errors.GpraceError` becomes a one-line message on stderr and its exit code (2 for
bad input, 1 for a failed run), never a traceback unless ``GPRACE_DEBUG=1``.
"""

from __future__ import annotations

import importlib
import os
import sys

import typer

from gprace import __version__
from gprace.console import console
from gprace.errors import GpraceError

app = typer.Typer(
    name="gprace",
    help="Learning-based autonomous racing: GP-compensated MPC, active exploration, head-to-head, diagnosis.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# stages that contribute commands, in the order --help lists them
COMMAND_MODULES = (
    "gprace.tracks.commands",
    "gprace.sim.commands",
    "gprace.gp.commands",
    "gprace.report.commands",
    "gprace.h2h.commands",
    "gprace.timetrial.commands",
    "gprace.diagnose.commands",
    "gprace.ingest.commands",
    "gprace.learn.commands",
)


def _version(value: bool) -> None:
    if value:
        console.result(f"gprace {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars or informational messages."),
) -> None:
    console.quiet = quiet


for _mod in COMMAND_MODULES:
    importlib.import_module(_mod).register(app)


def _evaluate_renamed() -> None:
    console.warn("`gprace evaluate` is now `gprace eval` (same subcommands); the old name will be removed")


# the old name of `eval`'s scoring commands (`evaluate iterate`, `evaluate gp`) keeps working, hidden
app.add_typer(next(g.typer_instance for g in app.registered_groups if g.name == "eval"), name="evaluate",
              hidden=True, callback=_evaluate_renamed, help="Old name of `gprace eval` (deprecated).")


def _click_exceptions() -> tuple[type, ...]:
    """Usage errors: click's, and those of the click copy that typer >= 0.20 vendors."""
    import click

    out: list[type] = [click.exceptions.ClickException]
    try:
        from typer._click.exceptions import ClickException as _Vendored

        out.append(_Vendored)
    except ImportError:  # older typer uses click itself
        pass
    return tuple(out)


def _flags_without_type(cmd) -> None:
    """A flag takes no value: no ``<bool>`` beside ``--json``, ``--resume`` or ``--help`` in the help.

    Typer renders an option's value type from its metavar; an empty one leaves the column blank.
    The help option is made on first use, so it is made here (and cached by the command) too.
    """
    help_opt = cmd.get_help_option(cmd.context_class(cmd, **cmd.context_settings))
    for p in [*getattr(cmd, "params", ()), *([help_opt] if help_opt is not None else [])]:
        if getattr(p, "is_flag", False) and p.metavar is None:
            p.metavar = ""
    for sub in getattr(cmd, "commands", {}).values():
        _flags_without_type(sub)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (also used by tests)."""
    debug = os.environ.get("GPRACE_DEBUG") == "1"
    try:
        cmd = typer.main.get_command(app)
        _flags_without_type(cmd)
        cmd(args=argv, standalone_mode=False)
    except GpraceError as exc:
        if debug:
            raise
        console.error(str(exc))
        return exc.exit_code
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        console.error("aborted")
        return 130
    except KeyboardInterrupt:
        console.error("interrupted; finished artifacts are kept, rerun the same command to resume")
        return 130
    except Exception as exc:  # click usage errors and anything unexpected
        if isinstance(exc, _click_exceptions()):  # usage: one line too, with where to look
            ctx = getattr(exc, "ctx", None)
            console.error(exc.format_message() + (f" (see `{ctx.command_path} --help`)" if ctx is not None else ""))
            return 2
        if debug:
            raise
        console.error(f"internal error: {type(exc).__name__}: {exc} (rerun with GPRACE_DEBUG=1 for a traceback)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
