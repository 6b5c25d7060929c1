"""The built-in backends (GP, QP solvers, compiled code). The plugin registry they and third-party
plugins register in lives in the core layer, :mod:`gprace.registry`; its names stay importable
from here (``from gprace.backends import plants, gps, solvers``), as plugins have used them."""

from gprace.registry import Registry, gps, plants, solvers

__all__ = ["Registry", "gps", "plants", "solvers"]
