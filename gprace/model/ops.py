"""Math namespaces so the model is written once and evaluated by numpy or built in CasADi.

Model code uses only ``ops.<fn>`` and arithmetic, so the same source gives a vectorised numpy
evaluation over many samples and a symbolic CasADi graph (for AD, linearisation and NLPs).
"""

from __future__ import annotations

import numpy as np


class NumpyOps:
    name = "numpy"
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    tan = staticmethod(np.tan)
    atan = staticmethod(np.arctan)
    atan2 = staticmethod(np.arctan2)
    sqrt = staticmethod(np.sqrt)
    exp = staticmethod(np.exp)
    tanh = staticmethod(np.tanh)
    fmax = staticmethod(np.maximum)
    fmin = staticmethod(np.minimum)
    fabs = staticmethod(np.abs)

    @staticmethod
    def sigmoid(x):
        return 0.5 * (1.0 + np.tanh(0.5 * x))


class CasadiOps:
    name = "casadi"

    def __init__(self) -> None:
        import casadi as ca

        self.sin, self.cos, self.tan = ca.sin, ca.cos, ca.tan
        self.atan, self.atan2, self.sqrt = ca.atan, ca.atan2, ca.sqrt
        self.exp, self.tanh = ca.exp, ca.tanh
        self.fmax, self.fmin, self.fabs = ca.fmax, ca.fmin, ca.fabs

    def sigmoid(self, x):
        return 0.5 * (1.0 + self.tanh(0.5 * x))


NP = NumpyOps()
