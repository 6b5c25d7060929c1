"""What every versioned record schema shares (the time trial's records, the head-to-head records,
the diagnosis result): NaN that JSON stores as ``null``, the version check, and one-line errors.

A record's schema is a :class:`gprace.config.Frozen` model with a ``version`` field. Its reader:

* reads the file (:func:`read_json` for JSON records; HDF5 records through :mod:`gprace.io.artifacts`),
* checks the version and validates (:func:`parse_record`): a newer version is refused, a missing
  one is the layout of before the schema, read with the defaults of the fields it lacks and one
  warning; a field the schema refuses is one line naming file and field.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import BaseModel, BeforeValidator

from gprace.errors import ConfigError, InputError

NAN = float("nan")
M = TypeVar("M", bound=BaseModel)


def _nan_for_null(v: Any) -> Any:
    return NAN if v is None else v


Num = Annotated[float, BeforeValidator(_nan_for_null)]
"""A float that JSON stores as ``null`` when it is not a number (:func:`gprace.console.jsonable`)."""


def read_json(path: str | Path, what: str) -> Any:
    """The parsed JSON at ``path``; an unreadable file is one line naming it and ``what`` it should be."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable {what} ({exc})") from None


def _check_version(data: Any, current: int, where: str, what: str) -> bool:
    """True if ``data`` (a record's dict) has no version: the layout of before the schema. A version
    newer than ``current`` is an :class:`InputError` (a newer gprace wrote it)."""
    if not isinstance(data, dict):
        raise InputError(f"{where}: not a {what} (a JSON object)")
    version = data.get("version")
    if isinstance(version, int) and version > current:
        raise InputError(f"{where}: {what} version {version} is newer than this gprace reads ({current}); update gprace")
    return version is None


def validated(model: type[M], data: dict[str, Any], where: str, error: type[InputError] = InputError) -> M:
    """``data`` as ``model``; what the schema refuses is one line (``error``) naming ``where`` and
    the field. A record is data, not configuration: no vehicle-TOML conventions apply."""
    from gprace.config import validate

    try:
        return validate(model, data, where, toml=False)
    except ConfigError as exc:
        raise error(str(exc)) from None


def parse_record(model: type[M], data: Any, where: str, what: str, note: str = "missing fields set to their defaults",
                 warn: bool = True, error: type[InputError] = InputError) -> tuple[M, bool]:
    """``data`` as ``model`` (whose ``version`` field's default is the current layout) and whether
    it was of the layout of before the schema (no version: read as the current one, ``note`` in
    its warning; ``warn`` False leaves the warning to a caller reading a batch)."""
    current = model.model_fields["version"].default
    old = _check_version(data, current, where, what)
    record = validated(model, {"version": current, **data}, where, error)
    if old and warn:
        from gprace.console import console

        console.warn(f"{where}: {what} of the layout before version {current}; {note}")
    return record, old
