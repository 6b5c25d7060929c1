"""Plants: "the real car" behind the registry ``gprace.plant`` (``frenet``, ``commonroad-std``)."""

from gprace.plants.base import Plant, make_plant

__all__ = ["Plant", "make_plant"]
