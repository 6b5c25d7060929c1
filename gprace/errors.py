"""The one error hierarchy of gprace.

Library code raises these; the CLI turns every :class:`GpraceError` into a one-line message and
exit code 2 (bad input) or 1 (a failed run). Each subclasses the matching builtin so callers that
catch ``ValueError`` or ``KeyError`` keep working.
"""

from __future__ import annotations


class GpraceError(Exception):
    """Base class. ``exit_code`` is what the CLI returns for it."""

    exit_code = 2


class ConfigError(GpraceError, ValueError):
    """A configuration file or value is wrong (unknown key, bad type, out of range)."""


class InputError(GpraceError, ValueError):
    """A data file is missing or malformed (missing column, NaN, truncated, wrong units)."""


class ArtifactError(InputError):
    """An HDF5 artifact is of the wrong kind, schema or content."""


class UnknownBackendError(GpraceError, KeyError):
    """A plugin name that is not registered; the message lists the valid names."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class FitError(GpraceError, ValueError):
    """A model fit degenerated (an output learned nothing) and was refused rather than used."""


class SolverError(GpraceError, RuntimeError):
    """A numerical solver failed in a way the caller cannot recover from."""

    exit_code = 1


class RunFailedError(GpraceError, RuntimeError):
    """A command ran but its result is a failure the user asked to be told about."""

    exit_code = 1


def at_row(row: int, line: int | None = None) -> str:
    """Where a sample sits in a data file, said the same way by every reader.

    Rows count samples from 1 (the first data row after a header is row 1; the header and blank
    or comment lines are not rows); a reader that knows the file line adds it: ``row 2 (line 3)``.
    """
    return f"row {row}" if line is None else f"row {row} (line {line})"
