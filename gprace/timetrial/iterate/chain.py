"""What every step of a trial reads: the step markers (resuming), the task's settings and the
chain of one trial (folders, track, nominal model, plant, reference runs, cached GP features)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gprace.timetrial.iterate.settings import IterateSettings
from gprace.timetrial.record import IterationRecord, read_record


class Steps:
    def __init__(self, out: Path) -> None:
        self.dir = out / ".steps"
        self.dir.mkdir(parents=True, exist_ok=True)

    def done(self, name: str) -> bool:
        return (self.dir / f"{name}.done").exists()

    def mark(self, name: str) -> None:
        from gprace.io.artifacts import write_text_atomic

        write_text_atomic(self.dir / f"{name}.done", time.strftime("%Y-%m-%dT%H:%M:%S"))


def _task_settings(task: dict) -> IterateSettings:
    return IterateSettings(**{k: tuple(v) if isinstance(v, list) else v for k, v in task["settings"].items()})


@dataclass
class _Chain:
    """What every step of one trial's chain of iterations reads: settings, folders, the track, the
    nominal model, the plant, the reference runs (held-out and calibration)."""

    st: IterateSettings
    out: Path
    trial: int
    steps: Steps
    track: Any
    model: Any
    plant: Any
    mpc: Any
    seed: int
    runs: dict  # "heldout" / "calib" -> Run or None, as the corrected sensors read them
    cap: np.ndarray
    sensors: Any = None  # the SensorCalibration read from a reference run (gprace.mpc.sensors)
    _features: dict = field(default_factory=dict)

    @property
    def folder(self) -> Path:
        return self.out / f"trial_{self.trial}"

    def dir(self, i: int) -> Path:
        return self.folder / f"iter_{i:02d}"

    def tag(self, i: int, name: str) -> str:
        return f"t{self.trial}_i{i}_{name}"

    def record(self, i: int) -> IterationRecord:
        return read_record(self.dir(i) / "record.json")

    @property
    def delay(self) -> float:
        """The total delay the GP iterations predict over [s]: the experiment's, the vehicle's known
        delays, else the shakedown's estimate (0 before iteration 0 is recorded)."""
        d = self.delay_known
        if d is not None:
            return d
        if (self.dir(0) / "record.json").exists():
            est = self.record(0).delay
            return float(est) if np.isfinite(est) else 0.0
        return 0.0

    @property
    def delay_known(self) -> float | None:
        return self.st.delay if self.st.delay is not None else self.model.vehicle.known_delay

    def drive_settings(self, delay: float):
        from gprace.mpc.stability import EnvelopeSettings
        from gprace.timetrial.drive import DriveSettings

        return DriveSettings(laps=self.st.laps, mpc=self.mpc.model_copy(update={"delay": delay}),
                             envelope=EnvelopeSettings(enabled=self.st.envelope))

    def data(self, name: str, kind: str):
        """GP features ``(Z, Y)`` of a reference run (None without it), with the chain's delay."""
        from gprace.timetrial import learning as L

        key = (name, kind, self.delay)
        if key not in self._features:
            run = self.runs[name]
            self._features[key] = (None if run is None else
                                   L.features(run, self.model, self.track, kind, self.st.features, delay=self.delay))
        return self._features[key]

    @property
    def heldout(self) -> dict:
        return {k: self.data("heldout", k) for k in ("tracking", "planning")}

    @property
    def calib(self) -> dict:
        return {k: self.data("calib", k) for k in ("tracking", "planning")}


def _chain(task: dict) -> _Chain:
    from gprace.config import load_plant, load_vehicle
    from gprace.io.runs import read_run
    from gprace.model import NominalModel
    from gprace.mpc import sensors as S
    from gprace.mpc.tracking import MPCSettings
    from gprace.timetrial import grip as G
    from gprace.timetrial.learning import in_control
    from gprace.tracks import load_track

    st = _task_settings(task)
    out, j = Path(task["out"]), int(task["trial"])
    track, model = load_track(st.track), NominalModel(load_vehicle(st.vehicle))
    mpc = MPCSettings(solver=st.solver, beta=st.beta, grip=st.grip)
    runs = {"heldout": read_run(out / "heldout.h5"), "calib": read_run(out / "calib.h5") if st.calib_weave > 0 else None}
    sensors = S.of_run(_sensor_run(runs), track, in_control)
    runs = {k: None if r is None else S.corrected(r, sensors) for k, r in runs.items()}
    return _Chain(st=st, out=out, trial=j, steps=Steps(out), track=track, model=model, plant=load_plant(st.plant),
                  mpc=mpc, seed=st.seed * 1000 + j + 1, runs=runs, cap=G.nominal_cap(model, st.plan_grip), sensors=sensors)


def _sensor_run(runs: dict):
    """The reference run the car's sensors are read from (:mod:`gprace.mpc.sensors`): of the
    calibration and held-out runs (driven before the first lap) the one with the longest stretch in
    control: the reference controller spins some cars of the randomized family within
    20 s on one of them (docs/decisions.md, issue 37, stop 71)."""
    from gprace.mpc.sensors import held_seconds
    from gprace.timetrial.learning import in_control

    return max((r for r in (runs.get("calib"), runs.get("heldout")) if r is not None),
               key=lambda run: held_seconds(run["t"], in_control(run.states())))
