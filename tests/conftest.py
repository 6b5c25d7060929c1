"""Shared fixtures (keep small): shipped vehicles and a small exact circle track."""

from __future__ import annotations

import os

# one BLAS thread per test process, pytest-xdist running one process per core, as gprace's batch
# tasks run (gprace.executor.single_thread_blas), set before any BLAS is loaded (no plugin loads
# numpy before this file) so that it also holds for the libraries loaded later, which a limit set
# at run time does not reach (CasADi loads its own OpenBLAS with IPOPT). With threaded
# BLAS the rounding depends on the machine's load: on a busy machine (issue 37, stop 55) IPOPT
# called the bounded circle plan of test_slip_bounds_hold_the_plan_below_the_tire_peak infeasible;
# idle or single-threaded it solves.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from gprace.config import load_vehicle  # noqa: E402

from shared_data import TUM_TRACKS as _TUM  # noqa: E402

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
