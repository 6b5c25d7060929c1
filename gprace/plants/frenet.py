"""``frenet`` plant: the nominal model's structure plus hidden effects and sensor noise.

The true dynamics are :class:`~gprace.model.NominalModel` of the plant's vehicle with the
plant's ``effects`` added (the nominal model used by controllers does not know them), integrated
with fixed-step RK4 and ``substeps`` per control period, curvature re-evaluated at every stage.
"""

from __future__ import annotations

import numpy as np

from gprace.model import NominalModel
from gprace.plants.base import Plant


class FrenetPlant(Plant):
    NAME = "frenet"

    def __init__(self, config, track, dt):
        super().__init__(config, track, dt)
        self.model = NominalModel(config.vehicle, config.effects)
        self._x = np.zeros(self.model.nx)

    def reset(self, x0, u0=None):
        u0 = np.zeros(2) if u0 is None else np.asarray(u0, dtype=float)
        self._x = self.model.initial_state(np.asarray(x0, dtype=float), u0)
        self.lap = 0
        return self.measurement()

    def step(self, u):
        x = self.model.rk4(self._x, np.asarray(u, dtype=float), self.track.kappa, self.dt, self.config.substeps)
        self._x = self._wrap(x)
        return self.measurement()

    @property
    def state(self):
        return self._x[:6].copy()

    def measurement(self) -> np.ndarray:
        return self._noisy(self.model.measure(self._x)[0])
