"""The plant protocol: a car driven with inputs held over one control period.

A plant lives on a :class:`~gprace.tracks.Track` and is observed in Frenet coordinates
``[v_x, v_y, yaw_rate, e_psi, e_y, s]`` (``s`` wrapped into ``[0, L)`` on closed tracks), with
the sensor noise of its configuration. Plants integrate accurately (RK4 with substeps or
better) at the period the caller chooses.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from gprace.config import EffectConfig, PlantConfig, VehicleConfig
from gprace.model.dynamics import State


@dataclass(frozen=True)
class Approximation:
    """A plant's physics in the nominal model's terms, for an oracle lap.

    ``known``: whether gprace knows them at all; then ``vehicle`` (effects empty) with the
    catalogue ``effects`` is the nominal-model car closest to the plant, ``exact`` when it *is* the
    plant, and ``missing`` names what the nominal model cannot hold (``delay_periods``: the
    measurement delay among them). ``why`` says why not known.
    """

    known: bool
    vehicle: VehicleConfig | None = None
    effects: tuple[EffectConfig, ...] = ()
    exact: bool = False
    missing: tuple[str, ...] = ()
    why: str = ""
    delay_periods: float = 0.0
    """Age of the plant's measurements [control periods] (a controller that knows the plant
    predicts over it, as over a steering lag)."""


class Plant(ABC):
    NAME: ClassVar[str]
    Options: ClassVar[type | None] = None
    """Pydantic model of the kind's ``options`` (extra keys forbidden); None: the kind takes none."""

    def __init__(self, config: PlantConfig, track, dt: float) -> None:
        self.config = config
        self.track = track
        self.dt = float(dt)
        self.rng = np.random.default_rng(config.seed)
        self.lap = 0

    @abstractmethod
    def reset(self, x0: np.ndarray, u0: np.ndarray | None = None) -> np.ndarray:
        """Place the car at Frenet state ``x0`` (6,); return the first measurement (6,)."""

    @abstractmethod
    def step(self, u: np.ndarray) -> np.ndarray:
        """Hold ``u = [delta, a_x]`` for one period; return the new measurement (6,)."""

    @property
    @abstractmethod
    def state(self) -> np.ndarray:
        """True (noise-free) Frenet state (6,)."""

    def describe(self) -> dict[str, Any]:
        """What this plant is, for run metadata (a randomized plant adds the car it drew)."""
        return {"kind": self.NAME}

    @classmethod
    def approximate(cls, config: PlantConfig) -> Approximation:
        """The plant's physics in the nominal model's terms (:class:`Approximation`); unknown by default."""
        return Approximation(known=False, why=f"the physics of plant kind {config.kind!r} are not known to gprace")

    def _noisy(self, y: np.ndarray) -> np.ndarray:
        n = self.config.noise
        sd = np.array([n.v_x, n.v_y, n.yaw_rate, n.e_psi, n.e_y, n.s])
        return y + sd * self.rng.standard_normal(6)

    def _wrap(self, x: np.ndarray) -> np.ndarray:
        """Keep s inside the lap on closed tracks and count laps."""
        if self.track.closed:
            L, S = self.track.length, State.S
            while x[S] >= L:
                x[S] -= L
                self.lap += 1
            while x[S] < 0:
                x[S] += L
                self.lap -= 1
        return x


def make_plant(config: PlantConfig, track, dt: float) -> Plant:
    from gprace.backends import plants

    return plants.create(config.kind, config, track, dt)


def approximate(config: PlantConfig) -> Approximation:
    """:meth:`Plant.approximate` of the configured kind (no track needed): the oracle's model."""
    from gprace.backends import plants

    cls = plants.get(config.kind)
    fn = getattr(cls, "approximate", None)
    return fn(config) if fn is not None else Plant.approximate.__func__(cls, config)
