"""The one plugin registry (core layer; :mod:`gprace.backends` re-exports it).

A :class:`Registry` maps names to classes for one entry-point group (``gprace.gp``,
``gprace.solver``, ``gprace.plant``). Built-ins register through the same entry points as
third-party plugins (see ``pyproject.toml``) and, so that a source checkout works without an
install, also through :meth:`Registry.builtin`. A duplicate name is an error naming both classes;
an unknown name is an error listing the valid ones; a plugin that fails to import is a warning.
"""

from __future__ import annotations

import importlib
import warnings
from importlib.metadata import entry_points
from typing import Any

from gprace.errors import ConfigError, UnknownBackendError


class Registry:
    def __init__(self, group: str, kind: str) -> None:
        self.group = group
        self.kind = kind
        self._builtin: dict[str, str] = {}
        self._classes: dict[str, type] = {}
        self._loaded = False

    def builtin(self, name: str, target: str) -> None:
        """Declare a built-in ``name -> "module:Class"`` (imported lazily)."""
        self._builtin[name] = target

    def register(self, name: str, cls: type) -> type:
        old = self._classes.get(name)
        if old is not None and old is not cls:
            raise ConfigError(
                f"{self.kind} name {name!r} registered twice: "
                f"{old.__module__}.{old.__qualname__} and {cls.__module__}.{cls.__qualname__}"
            )
        self._classes[name] = cls
        return cls

    def _load(self) -> None:
        if self._loaded:
            return
        self._loaded = True
        targets: dict[str, str] = dict(self._builtin)
        for ep in entry_points(group=self.group):
            if ep.name in targets and targets[ep.name] != ep.value:
                raise ConfigError(
                    f"{self.kind} name {ep.name!r} registered twice: {targets[ep.name]} and {ep.value}"
                )
            targets[ep.name] = ep.value
        for name, target in targets.items():
            try:
                cls = _import(target)
            except Exception as exc:  # a broken plugin must not take the tool down
                warnings.warn(f"{self.kind} plugin {name!r} ({target}) failed to import: {exc}")
                continue
            self.register(name, cls)

    def names(self) -> list[str]:
        self._load()
        return sorted(self._classes)

    def get(self, name: str) -> type:
        self._load()
        try:
            return self._classes[name]
        except KeyError:
            raise UnknownBackendError(
                f"unknown {self.kind} {name!r}; available: {', '.join(self.names()) or 'none'}"
            ) from None

    def create(self, name: str, *args: Any, **kwargs: Any) -> Any:
        return self.get(name)(*args, **kwargs)


def _import(target: str) -> type:
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


plants = Registry("gprace.plant", "plant")
plants.builtin("frenet", "gprace.plants.frenet:FrenetPlant")
plants.builtin("commonroad-std", "gprace.plants.commonroad:CommonRoadSTDPlant")
plants.builtin("commonroad-mb", "gprace.plants.commonroad:CommonRoadMBPlant")
plants.builtin("randomized", "gprace.plants.randomized:RandomizedPlant")

gps = Registry("gprace.gp", "GP backend")
gps.builtin("exact", "gprace.backends.gp_exact:ExactGP")
gps.builtin("sparse", "gprace.backends.gp_sparse:SparseGP")
solvers = Registry("gprace.solver", "QP solver")
solvers.builtin("cvxpy-clarabel", "gprace.backends.qp_cvxpy:CvxpyClarabelQP")
solvers.builtin("clarabel", "gprace.backends.qp_clarabel:ClarabelQP")
solvers.builtin("casadi", "gprace.backends.qp_casadi:CasadiQP")
