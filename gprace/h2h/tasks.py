"""The tasks of the head-to-head protocol, one frozen model per kind (issue 40).

A task holds everything that decides a run's result. The executor pickles it to a worker (local
processes and Dask alike), and everything random in a run derives from its ``seed``.

* :class:`RaceTask`: one race (collection, exploration episode, calibration or evaluation race: the
  four share one shape and differ in which entries they set);
* :class:`ErrorTask`: the offline prediction errors of every offline predictor on one stored race;
* :class:`BuildTask`: build one car's NMPC of a race configuration (compiles its NLP once).

:meth:`Task.as_dict` is the dict that records store as ``task`` and that earlier versions passed
around; :meth:`Task.hash` hashes it, with the race version, leaving out the id and the file
locations (whose contents enter as ``*_hash`` entries). Both are exactly what they were when tasks
were plain dicts, so an ``--out`` folder written then is still reused. Workers accept a task or its
dict (:meth:`Task.of`), as benchmarks and tests write them.
"""

from __future__ import annotations

from typing import Any

from gprace.config import Frozen, config_hash
from gprace.h2h.geometry import TrackSpec

# 2: the constant-velocity prediction advances every step; 3: the NMPC stops at its first acceptable
# iterate, and a race ends on the one stop rule (gprace.sim.stop); 4: a failed solve's fallback
# keeps v_x at the NLP's bound and holds the heading after two failures in a row (gprace.h2h.nmpc);
# 5: the NLP's prediction model turns kinematic at a crawl (gprace.h2h.nmpc.blended_rk4); 6: the
# border margin covers the footprint at any heading (gprace.h2h.nmpc.border_margin). Records of an
# older version are rerun.
RACE_VERSION = 6

PATH_KEYS = ("model", "explore_data", "record", "models")
"""Task entries that are file locations: their contents enter the task as ``*_hash`` entries."""


def task_hash(task: Task | dict) -> str:
    """Hash of what decides a run's result, with :data:`RACE_VERSION`; file locations are left
    out, so a copied or moved ``--out`` directory is still reused."""
    d = task.as_dict() if isinstance(task, Task) else task
    return config_hash({"race_version": RACE_VERSION, **{k: v for k, v in d.items() if k not in ("id", *PATH_KEYS)}})


class Task(Frozen):
    """Common behaviour of the protocol's tasks (see the module's docstring)."""

    @classmethod
    def of(cls, task: Task | dict):
        return task if isinstance(task, cls) else cls.model_validate(task)

    def as_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json", exclude_none=True)

    def hash(self) -> str:
        return task_hash(self)


class RaceTask(Task):
    """One race: ``track`` and ``seed`` (start grid, noise, GP samples), the ego's ``predictor``
    (``gp`` | ``cv`` | ``oracle``; ``model``: the GP's file for ``gp``, ``label``: the name the
    table uses when it differs), ``config`` (:class:`~gprace.h2h.config.H2HConfig` entries),
    a ``calibration`` of the predictor's spread, and for an exploration episode ``alpha`` (> 0
    needs ``explore_data``) and ``duration`` (the race then does not stop at the overtake)."""

    id: str = ""
    track: TrackSpec
    seed: int
    predictor: str = "gp"
    label: str | None = None
    config: dict[str, Any] = {}
    model: str | None = None
    model_hash: str | None = None
    calibration: dict[str, Any] | None = None
    alpha: float | None = None
    explore_data: str | None = None
    data_hash: str | None = None
    duration: float | None = None


class ErrorTask(Task):
    """Offline errors of the predictors ``models`` (name -> GP file, None for ``cv``) on the race
    stored at ``record`` (whose task hash is ``record_hash``)."""

    id: str = ""
    record: str
    record_hash: str
    track: TrackSpec
    seed: int
    config: dict[str, Any] = {}
    models: dict[str, str | None]
    model_hashes: dict[str, str] = {}
    version: int

    def as_dict(self) -> dict[str, Any]:
        d = super().as_dict()
        d["models"] = dict(self.models)  # a cv entry (None) is part of the task
        return d


class BuildTask(Task):
    """Build the NMPC of ``car`` (ego | opponent) of a race ``config``."""

    config: dict[str, Any] = {}
    car: str
