"""Shared fixtures (keep small): shipped vehicles and a small exact circle track."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.config import load_vehicle

from shared_data import TUM_TRACKS as _TUM

TUM_TRACKS = str(_TUM)


@pytest.fixture(scope="session")
def audi():
    return load_vehicle("audi_tt_cup")


@pytest.fixture(scope="session")
def bmw():
    return load_vehicle("bmw_320i")


def make_circle(radius: float = 100.0, width: float = 10.0, n: int = 400):
    """A closed circle (counter-clockwise, kappa = +1/radius), half-width ``width`` each side."""
    from gprace.tracks import Track

    th = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return Track(radius * np.cos(th), radius * np.sin(th), np.full(n, width), np.full(n, width),
                 closed=True, name=f"circle_{radius:g}")


@pytest.fixture(scope="session")
def circle_track():
    return make_circle()
