"""Plants: "the real car" behind the registry ``gprace.plant`` (``frenet``, ``commonroad-std``,
``commonroad-mb``, ``randomized``)."""

from gprace.plants.base import Approximation, Plant, approximate, make_plant

__all__ = ["Approximation", "Plant", "approximate", "make_plant"]
