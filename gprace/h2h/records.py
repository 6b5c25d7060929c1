"""The head-to-head protocol's per-task records: one schema per record kind, written and read only
through :func:`write_record` and :func:`read_record`.

Two kinds, both HDF5 artifacts of kind :data:`RUN_KIND` (``run_<i>.h5``) as before the schema:

* :class:`RaceAttrs`, a race: collection (``collect/runs``, ``init/runs``), exploration
  (``explore/runs``), calibration (``calib/.../runs``) and evaluation (``eval/<predictor>``);
* :class:`ErrorAttrs`, the offline errors of the predictors on one race (``errors/<predictor>``,
  ``calib/.../errors``); its task names the race by ``record_hash`` (the race's ``task_hash``).

The reader names the kind it expects (the folder says which it is). Attributes are the model's
fields, scalars, with the task stored as JSON text (a dict in memory) and ``seed`` also the
artifact's provenance seed; the arrays are what the task function returned (not validated: the
race's states and inputs, the errors' ``(K, start times)`` arrays).

Versions: ``version`` is :data:`RECORD_VERSION`. A newer one is refused with an
:class:`~gprace.errors.InputError` (``--resume`` does not overwrite what a newer gprace wrote). A
record without it is the layout of before the schema (2026-11-24): the same attributes, the
oldest without ``wall_s`` or ``task_hash``; they take the defaults below. The reader gives such a
record back with ``old`` set and warns, or leaves the warning to a caller reading a batch, which
warns once (:func:`warn_old`: 500 old records are one line); the protocol rewrites the records
it reuses (:func:`migrate`), the report only reads.

Unknown attributes are refused, as in the time trial's record: the layouts of before the schema
wrote no attribute outside these fields (the race's attributes are the set :func:`run_race` has
written since it was written; the protocol added ok, error, task_hash, task and wall_s; the first
protocol's ``seed`` is the artifact's seed, which the reader takes), so there is nothing an older
gprace wrote to tolerate, and a file with another key is not one of these records. A record that
does not validate is an :class:`~gprace.errors.ArtifactError` naming the file and the field: the
protocol reruns its task as it does for an unreadable file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np
from pydantic import Field, NonNegativeFloat, NonNegativeInt, model_validator

from gprace.config import Frozen
from gprace.errors import ArtifactError
from gprace.io.records import NAN, parse_record, validated

RUN_KIND = "h2h_run"
RECORD_VERSION = 1


OLD_NOTE = "missing fields set to their defaults; not migrated (`gprace eval head2head --resume` does)"


class RecordAttrs(Frozen):
    """What every record holds: the task, its hash, and whether it ran."""

    version: int = Field(RECORD_VERSION, description="layout version of the record")
    ok: bool = Field(description="the task ran to its end (False: ``error`` says why not)")
    error: str = Field("", description="the failed task's error and traceback (empty when ok)")
    task_hash: str = Field("", description="hash of what decides the result (gprace.h2h.tasks.task_hash); "
                           "a record whose hash differs from its task's is rerun")
    task: dict[str, Any] = Field(default_factory=dict, description="the task (JSON text in the file)")
    seed: int = Field(0, description="the task's seed (also the artifact's provenance seed)")

    @model_validator(mode="before")
    @classmethod
    def _task_from_text(cls, data: Any) -> Any:
        """The task is stored as JSON text; in memory it is the dict."""
        if isinstance(data, dict) and isinstance(data.get("task"), str):
            try:
                data = {**data, "task": json.loads(data["task"])}
            except ValueError:
                raise ValueError("task: not JSON text") from None
        return data

    def stored(self) -> dict[str, Any]:
        """The attributes as the file holds them (the task as JSON text)."""
        return {**self.model_dump(), "task": json.dumps(self.task)}


class RaceAttrs(RecordAttrs):
    """One race (:func:`gprace.h2h.race.run_race` and the protocol's additions); a failed race
    holds only the common fields, the others at their defaults."""

    track: str = Field("", description="name of the generated track")
    track_length: float = Field(NAN, description="length of the track [m]")
    predictor: str = Field("", description="the ego's predictor (its label in the evaluation)")
    alpha: NonNegativeFloat = Field(0.0, description="exploration weight of the ego")
    end_reason: str = Field("", description="why the race ended: time, overtaken, track_end, diverged, "
                            "or a stop kind of gprace.sim.stop (empty: it did not run)")
    overtake_time: float = Field(NAN, description="time of the overtake [s]; NaN without one")
    border_hit: bool = Field(False, description="the ego touched a border")
    border_hit_opp: bool = Field(False, description="the opponent touched a border")
    collision: bool = Field(False, description="the cars touched")
    steps: NonNegativeInt = Field(0, description="steps of 0.1 s raced")
    fallbacks_ego: NonNegativeInt = Field(0, description="steps the ego drove on its previous plan (a failed solve)")
    fallbacks_opp: NonNegativeInt = Field(0, description="the same for the opponent")
    stalemates: NonNegativeInt = Field(0, description="stalemates the exploring ego broke (0 without exploration)")
    wall_s: float = Field(NAN, description="wall-clock time of the race and its GP pairs [s]")


class ErrorAttrs(RecordAttrs):
    """The offline errors of the predictors on one race; its task names the race."""

    @model_validator(mode="after")
    def _names_its_race(self) -> ErrorAttrs:
        if not isinstance(self.task.get("record_hash"), str):
            raise ValueError("task.record_hash: required key missing (the race these errors are of)")
        return self

    @property
    def record_hash(self) -> str:
        """The ``task_hash`` of the race these errors are of."""
        return self.task["record_hash"]


A = TypeVar("A", bound=RecordAttrs)


@dataclass(frozen=True)
class Record(Generic[A]):
    """One record: its arrays and its validated attributes; ``old`` when it was read from the
    layout of before the schema and not yet migrated."""

    arrays: dict[str, np.ndarray]
    attrs: A
    old: bool = field(default=False, compare=False)


def record_of(schema: type[A], task: dict, task_hash: str, ok: bool, value: dict | None, error: str,
              where: str = "record") -> Record[A]:
    """The record of one task: its function's result ``value`` (``{"arrays", "attrs"}``) or, when
    it failed, ``error``; validated, so a task function that returns an unknown attribute fails
    here rather than in the file."""
    attrs = dict(value["attrs"]) if value else {}
    attrs.update(ok=bool(ok), error=error, task_hash=task_hash, task=task, seed=int(task.get("seed", 0)))
    return Record(dict(value["arrays"]) if value else {}, validated(schema, attrs, where, ArtifactError))


def write_record(path: str | Path, record: Record) -> Record:
    """Write ``record`` atomically in the current layout; returns it (no longer ``old``)."""
    from gprace.io.artifacts import Artifact, write_artifact

    write_artifact(path, Artifact(RUN_KIND, arrays=record.arrays, attrs=record.attrs.stored(), seed=record.attrs.seed))
    return Record(record.arrays, record.attrs)


def read_record(path: str | Path, schema: type[A], warn: bool = True) -> Record[A]:
    """The record at ``path`` as ``schema``. A record of the layout of before the schema comes back
    with ``old`` set, warned about here unless ``warn`` is False (a caller reading a batch warns
    once, :func:`warn_old`). Raises :class:`~gprace.errors.ArtifactError` for a file that is not
    such a record and :class:`~gprace.errors.InputError` for a newer version."""
    from gprace.io.artifacts import read_artifact

    art = read_artifact(path, RUN_KIND)
    attrs, old = parse_record(schema, {**art.attrs, "seed": art.seed}, str(path), "head-to-head record",
                              OLD_NOTE, warn=warn, error=ArtifactError)
    return Record(art.arrays, attrs, old=old)


def migrate(path: str | Path, record: Record) -> Record:
    """Rewrite an old record in the current layout (same arrays and values, with the version)."""
    return write_record(path, record) if record.old else record


def warn_old(paths: list[Path], migrated: bool) -> None:
    """One warning for the records of the layout of before the schema read in one batch."""
    if not paths:
        return
    from gprace.console import console

    where = f"{paths[0]}" if len(paths) == 1 else f"{len(paths)} records ({paths[0]}, ...)"
    console.warn(f"{where}: head-to-head record of the layout before version {RECORD_VERSION}; "
                 + ("missing fields set to their defaults; migrated" if migrated else OLD_NOTE))
