"""Vehicle and plant configurations loaded for use: :mod:`gprace.config` reads and checks a file's
structure (keys, types, units, ranges); here its ``[[effects]]`` are checked against the effect
catalogue (:mod:`gprace.model.effects`), which the configuration layer does not know. Everything that
loads a configuration to build a model or a plant from it loads it through :func:`load_vehicle` and
:func:`load_plant`, so an unknown effect or parameter is still refused when the file is read, before
any work, as one line naming the file and the effect (``plant.toml: effects.1: unknown effect ...``).
"""

from __future__ import annotations

from pathlib import Path

from gprace import config
from gprace.config import PlantConfig, VehicleConfig
from gprace.errors import ConfigError
from gprace.model.effects import make_effect


def check_effects(cfg: VehicleConfig | PlantConfig, where: str) -> None:
    """Every effect of ``cfg`` (a plant's and its vehicle's) built from the catalogue; the first that
    fails is a :class:`ConfigError` ``"{where}: {field}.{i}: {why}"`` (the layout of
    :func:`gprace.config.validate`), with how many more fail."""
    groups = [("effects", cfg.effects)]
    if isinstance(cfg, PlantConfig):
        groups.append(("vehicle.effects", cfg.vehicle.effects))
    bad = []
    for field, effects in groups:
        for i, e in enumerate(effects):
            try:
                make_effect(e)
            except ConfigError as exc:
                bad.append(f"{field}.{i}: {exc}")
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise ConfigError(f"{where}: {bad[0]}{more}")


def load_vehicle(name_or_path: str | Path) -> VehicleConfig:
    """:func:`gprace.config.load_vehicle` with the effects checked against the catalogue."""
    return config.load_vehicle(name_or_path, check=check_effects)


def load_plant(name_or_path: str | Path) -> PlantConfig:
    """:func:`gprace.config.load_plant` with the effects checked against the catalogue."""
    return config.load_plant(name_or_path, check=check_effects)
