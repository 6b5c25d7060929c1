"""The ``gprace`` command: a thin typer app.

Each stage contributes its commands through ``gprace/<stage>/commands.py`` with a function
``register(app)``; this module only assembles them and is the one exit door for errors: a
:class:`~gprace.errors.GpraceError` becomes a one-line message on stderr and its exit code (2 for
bad input, 1 for a failed run), never a traceback unless ``GPRACE_DEBUG=1``; Ctrl-C and SIGTERM
become exit 130 and one line. The stages are imported (``app``, :func:`registered`) once the
signals are handled, so an early Ctrl-C also ends in that line.
"""

from __future__ import annotations

import functools
import importlib
import os
import re
import shlex
import sys
from pathlib import Path

import typer

from gprace import __version__, interrupt
from gprace.console import console
from gprace.errors import GpraceError

_app = typer.Typer(
    name="gprace",
    help="Learning-based autonomous racing: GP-compensated MPC, active exploration, head-to-head, diagnosis.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# stages that contribute commands, in the order --help lists them
COMMAND_MODULES = (
    "gprace.cli.tracks",
    "gprace.cli.sim",
    "gprace.cli.gp",
    "gprace.cli.report",
    "gprace.cli.h2h",
    "gprace.cli.timetrial",
    "gprace.cli.diagnose",
    "gprace.cli.ingest",
    "gprace.cli.learn",
)


def _version(value: bool) -> None:
    if value:
        console.result(f"gprace {__version__}")
        raise typer.Exit()


@_app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars or informational messages."),
) -> None:
    console.quiet = quiet


def _evaluate_renamed() -> None:
    console.warn("`gprace evaluate` is now `gprace eval` (same subcommands); the old name will be removed")


@functools.cache
def registered() -> typer.Typer:
    """The app with every stage's commands (imported on first use)."""
    for mod in COMMAND_MODULES:
        importlib.import_module(mod).register(_app)
    # the old name of `eval`'s scoring commands (`evaluate iterate`, `evaluate gp`) keeps working, hidden
    _app.add_typer(next(g.typer_instance for g in _app.registered_groups if g.name == "eval"), name="evaluate",
                   hidden=True, callback=_evaluate_renamed, help="Old name of `gprace eval` (deprecated).")
    return _app


def __getattr__(name: str):
    if name == "app":  # ``from gprace.cli import app``: the registered app
        return registered()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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


# Where every command writes (the typer parameter -> what it is): checked before the command starts,
# run folders locked while it runs (gprace.io.outputs). A test checks that every path parameter of
# every command is here or in INPUTS.
FILE, FOLDER, RUN = "file", "folder", "run"
OUTPUTS: dict[str, dict[str, str]] = {
    "simulate": {"output": FILE, "csv": FILE},
    "plan": {"output": FILE},
    "run": {"output": FILE, "mcap": FILE},
    "iterate": {"out": RUN, "mcap": FILE},
    "eval timetrial": {"out": RUN},
    "eval head2head": {"out": RUN},
    "h2h collect": {"out": RUN},
    "h2h explore": {"out": RUN},
    "h2h train": {"model": FILE},
    "select-data": {"output": FILE},
    "retrain": {"output": FILE},
    "diagnose": {"output": FILE, "plot": FILE},
    "import": {"output": FILE},
    "learn": {"out": RUN, "mcap": FILE},
    "show": {"plot": FILE},
    "report": {"out": FILE, "png": FOLDER},
    "track show": {"plot": FILE},
}
INPUTS: dict[str, tuple[str, ...]] = {
    "plan": ("model", "warm_start"), "run": ("plan", "model", "candidates"), "select-data": ("inputs", "model"),
    "retrain": ("data",), "eval gp": ("model", "run"), "eval iterate": ("folder",), "h2h train":
    ("dataset", "hyper_model", "initial", "validation"), "h2h explore": ("init_model", "init_data"),
    "diagnose": ("recordings",), "import": ("recording", "map_file"), "show": ("file",), "report": ("folder",),
    "learn": ("recordings", "map_file", "driven"), "eval learn": ("folder", "log", "map_file"),
}


def _resume_hint(path: str, kw: dict) -> str:
    """How to go on after an interrupt (the h2h commands keep finished races only with --resume)."""
    if path in ("eval head2head", "h2h collect", "h2h explore") and not kw.get("resume"):
        return "rerun the same command with --resume to continue where it stopped"
    return "rerun the same command to resume"


_RUN: dict = {"line": "gprace", "outputs": None}


def _option_name(param) -> str:
    """A parameter as the CLI spells it (``--output``, ``MODEL``)."""
    longs = [o for o in getattr(param, "opts", ()) if o.startswith("--")]
    if getattr(param, "param_type_name", "") == "argument":
        return param.name.upper()
    return longs[0] if longs else param.opts[0]


def _guard(cmd, path: str, quiet) -> None:
    """Wrap the command's callback: ``-q`` after the subcommand, then its outputs checked and locked."""
    outs = OUTPUTS.get(path, {})
    names = {p.name: _option_name(p) for p in cmd.params}
    callback = cmd.callback

    @functools.wraps(callback)
    def run(**kw):
        from gprace.io.outputs import Output, Outputs  # h5py: not for --help

        if kw.pop("quiet", False):
            console.quiet = True
        items = [Output(names[n], Path(kw[n]), kind) for n, kind in outs.items() if kw.get(n) is not None]
        with Outputs(items, command=_RUN["line"], resume=_resume_hint(path, kw)) as o:
            _RUN["outputs"] = o
            return callback(**kw)

    cmd.callback = run
    if quiet is not None and not any(p.name == "quiet" for p in cmd.params):
        cmd.params.append(quiet)


_UNIT = re.compile(r"(?<!\\)\[")
"""An opening bracket in a help text: a unit (``[m]``, ``[s]``) or a list (``[v_y, yaw_rate,
delta]``). The help is rendered as rich markup, which takes such a bracket for a style and drops
it with its content; no help text uses markup, so every bracket is escaped."""


def _prepare(cmd, path: str = "", quiet=None) -> None:
    """Every command of the tree: flags shown without a value type, then the guard of :func:`_guard`.

    A flag takes no value: no ``<bool>`` beside ``--json``, ``--resume`` or ``--help`` in the help.
    Typer renders an option's value type from its metavar; an empty one leaves the column blank.
    The help option is made on first use, so it is made here (and cached by the command) too.
    """
    help_opt = cmd.get_help_option(cmd.context_class(cmd, **cmd.context_settings))
    for p in [*getattr(cmd, "params", ()), *([help_opt] if help_opt is not None else [])]:
        if getattr(p, "is_flag", False) and p.metavar is None:
            p.metavar = ""
        if getattr(p, "help", None):  # brackets ("[m]", "[v_y, yaw_rate, delta]") are text, not rich markup
            p.help = _UNIT.sub(r"\\[", p.help)
    subs = getattr(cmd, "commands", None)
    if not path:  # the root's -q, also accepted after any subcommand (the same option object)
        quiet = next((p for p in cmd.params if p.name == "quiet"), None)
    elif subs is None and cmd.callback is not None:
        _guard(cmd, path, quiet)
    for name, sub in (subs or {}).items():
        _prepare(sub, f"{path} {'eval' if name == 'evaluate' else name}".strip(), quiet)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (also used by tests).

    Ctrl-C and SIGTERM end the command with exit 130 and one line saying what was kept and how to
    go on (:mod:`gprace.interrupt`, :meth:`gprace.io.outputs.Outputs.interrupted_line`).
    """
    if argv is not None:  # a caller's own process (tests, scripts): return the code
        return _main([str(a) for a in argv], process=False)
    # the command is the process (the `gprace` script): end it as soon as the command has ended
    code = _main(sys.argv[1:], process=True)
    interrupt.exit_process(code, lambda: console.error(
        "interrupted; the command had finished before the signal: everything it wrote is complete"))
    return code  # not reached


def _main(argv: list[str], process: bool) -> int:
    debug = os.environ.get("GPRACE_DEBUG") == "1"
    _RUN.update(line=shlex.join(["gprace", *argv]), outputs=None)
    with interrupt.handled(process):
        try:
            cmd = typer.main.get_command(registered())
            _prepare(cmd)
            with cmd.make_context("gprace", list(argv)) as ctx:
                cmd.invoke(ctx)
        except KeyboardInterrupt:
            interrupt.restore_stderr()
            o = _RUN["outputs"]
            console.error(o.interrupted_line() if o is not None else "interrupted; nothing was written")
            return 130
        except GpraceError as exc:
            if debug:
                raise
            console.error(str(exc))
            return exc.exit_code
        except typer.Exit as exc:
            return exc.exit_code
        except MemoryError:  # a size no check foresaw: still one line, with what the machine has
            if debug:
                raise
            from gprace.resources import available_memory, human

            console.error(f"out of memory: the settings ask for more than the {human(available_memory())} this machine "
                          "has available; rerun with smaller sizes")
            return 2
        except OverflowError as exc:
            if debug:
                raise
            console.error(f"a number is too large to compute with ({exc}); rerun with smaller settings")
            return 2
        except typer.Abort:
            console.error("aborted")
            return 130
        except BrokenPipeError:  # the reader went away (`gprace ... --help | head`): end quietly, as shell tools do
            if process:
                _drop_stdout()
            return 141  # 128 + SIGPIPE, what a shell reports for a tool its pipe's reader closed
        except Exception as exc:  # click usage errors and anything unexpected
            if isinstance(exc, _click_exceptions()):  # usage: one line too, with where to look
                ctx = getattr(exc, "ctx", None)
                console.error(exc.format_message() + (f" (see `{ctx.command_path} --help`)" if ctx is not None else ""))
                return 2
            if debug:
                raise
            console.error(f"internal error: {type(exc).__name__}: {exc} (rerun with GPRACE_DEBUG=1 for a traceback)")
            return 1
        finally:
            _RUN["outputs"] = None
    return 0


def _drop_stdout() -> None:
    """Point the process's stdout at the null device: the flush at exit would hit the closed pipe again."""
    import contextlib

    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())


if __name__ == "__main__":
    sys.exit(main())
