"""The time trial's iteration record (``trial_J/iter_II/record.json``): one schema, written and read
only through :func:`write_record` and :func:`read_record`.

The file is JSON with ``null`` for a number that is not one (a lap not completed has no driven
time); :func:`read_record` gives it back as NaN. ``version`` is :data:`RECORD_VERSION`. A record
without it is the layout of before the schema (2026-11-24): the same fields, any of them but the
lap's (iteration, trial, alpha, planned, driven, completed) missing in older folders; it is
migrated once (rewritten with the defaults below and the version) with a warning, so an old
folder resumes and reports.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from pydantic import Field, model_validator

from gprace.config import Frozen, validate
from gprace.console import console, jsonable
from gprace.errors import ConfigError, InputError

RECORD_VERSION = 1
NAN = float("nan")


class IterationRecord(Frozen):
    """One driven lap of one iteration of one trial, and the GPs it was driven with."""

    version: int = Field(RECORD_VERSION, description="layout version of the record")
    iteration: int = Field(ge=0, description="0: the nominal model's lap; i >= 1: after i GP updates")
    trial: int = Field(ge=0, description="independent repetition")
    alpha: float = Field(description="exploration weight the lap was driven with")
    planned: float = Field(description="the plan's lap time [s]")
    driven: float = Field(description="the driven lap time [s]; NaN if the lap was not completed")
    completed: bool = Field(description="the lap was completed")
    reason: str = Field("", description="why the run stopped early (empty if it did not)")
    gap: float = Field(NAN, description="driven minus planned [s] (an old record without it: computed)")
    solve_median_ms: float = Field(NAN, description="median QP solve time of the tracking MPC [ms]")
    solve_p99_ms: float = Field(NAN, description="99th percentile of the QP solve time [ms]")
    border_hits: int = Field(0, ge=0, description="steps with a wheel outside a border")
    fallbacks: int = Field(0, ge=0, description="steps driven on the previous solution (a QP failed)")
    samples: int = Field(0, ge=0, description="samples of the run")
    replan_failed: bool = Field(False, description="the re-plan failed and an earlier plan was driven")
    err_tracking: float = Field(NAN, description="tracking GP: normalised RMS error on the held-out run")
    dict_tracking: int = Field(0, ge=0, description="tracking GP: dictionary size")
    cov_tracking: float = Field(NAN, description="tracking GP: share of held-out errors in its 95 % band")
    err_planning: float = Field(NAN, description="planning GP: normalised RMS error on the held-out run")
    dict_planning: int = Field(0, ge=0, description="planning GP: dictionary size")
    cov_planning: float = Field(NAN, description="planning GP: share of held-out errors in its 95 % band")
    limits: list[float] = Field(default_factory=list, description="friction ellipse the plan used: lateral, "
                                "drive, brake [m/s^2]")
    envelope: list[float] = Field(default_factory=list, description="measured lateral, drive and brake "
                                  "accelerations of the in-control samples [m/s^2]")
    utilisation: float = Field(NAN, description="robust peak rear slip over the nominal tire's peak slip")

    @model_validator(mode="before")
    @classmethod
    def _null_is_nan(cls, data: Any) -> Any:
        """JSON ``null`` in a number field is NaN (as :func:`gprace.console.jsonable` writes it)."""
        if isinstance(data, dict):
            data = {k: NAN if v is None and k in _FLOATS else v for k, v in data.items()}
            if "gap" not in data and all(isinstance(data.get(k), (int, float)) for k in ("driven", "planned")):
                data["gap"] = data["driven"] - data["planned"]
        return data


_FLOATS = frozenset(k for k, f in IterationRecord.model_fields.items() if f.annotation is float)


def write_json(path: Path, obj) -> None:
    """``obj`` as JSON (NaN as ``null``), atomically: a killed run leaves the old file or the new
    one, never half of one. Every JSON file of an iterate folder is written by it."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(jsonable(obj), indent=1, allow_nan=False))
    os.replace(tmp, path)


def write_record(path: Path, record: IterationRecord) -> None:
    write_json(path, record.model_dump())


def read_record(path: Path, migrate: bool = True) -> dict:
    """The record at ``path`` as a dict (NaN for ``null``), validated by :class:`IterationRecord`.
    A record of the layout before the schema is read with a warning and, with ``migrate``,
    rewritten in the current layout (a reader that only looks, like the report, passes False)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable iteration record ({exc})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: not an iteration record (a JSON object)")
    old = "version" not in data
    if isinstance(data.get("version"), int) and data["version"] > RECORD_VERSION:
        raise InputError(f"{path}: record version {data['version']} is newer than this gprace reads "
                         f"({RECORD_VERSION}); update gprace")
    try:
        rec = validate(IterationRecord, {**data, "version": RECORD_VERSION}, str(path))
    except ConfigError as exc:  # a record is input data, not configuration
        raise InputError(str(exc)) from None
    if old:
        console.warn(f"{path}: record of the layout before version {RECORD_VERSION}; missing fields set to "
                     "their defaults" + ("; migrated" if migrate else ""))
        if migrate:
            write_record(path, rec)
    return rec.model_dump()
