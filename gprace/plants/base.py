"""The plant protocol: a car driven with inputs held over one control period.

A plant lives on a :class:`~gprace.tracks.Track` and is observed in Frenet coordinates
``[v_x, v_y, yaw_rate, e_psi, e_y, s]`` (``s`` wrapped into ``[0, L)`` on closed tracks), with
the sensor noise of its configuration. Plants integrate accurately (RK4 with substeps or
better) at the period the caller chooses.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from gprace.config import PlantConfig
from gprace.model.dynamics import State


class Plant(ABC):
    NAME: ClassVar[str]

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
