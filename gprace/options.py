"""Command-line options that several commands share, declared once (typer ``Option`` objects)."""

from __future__ import annotations

import typer

EXECUTOR = typer.Option("local", "--executor", help="Where runs go: local (processes on this machine) or dask.")
SCHEDULER = typer.Option(None, "--scheduler", help="Dask scheduler address tcp://HOST:PORT (with --executor dask).")
