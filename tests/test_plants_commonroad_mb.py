"""``commonroad-mb``: the multi-body BMW of commonroad-vehicle-models steps as the package does."""

from __future__ import annotations

import inspect
import math
import re

import numpy as np
import pytest

from conftest import make_circle
from gprace.config import EffectConfig, PlantConfig, SimulateConfig, load_plant
from gprace.errors import ConfigError, SolverError
from gprace.plants import make_plant
from gprace.plants.commonroad import mb_substep, rk4_step, wheels_held

mb = pytest.importorskip("vehiclemodels.vehicle_dynamics_mb")
WHEELS = slice(23, 27)


@pytest.fixture(scope="module")
def p():
    from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

    return parameters_vehicle2()


def _package_reference(module: str, name: str) -> list[float]:
    """A ground-truth list as the package's own unit tests write it (read from their source)."""
    import importlib

    src = inspect.getsource(importlib.import_module(f"vehiclemodels.unit_tests.{module}"))
    return eval(re.search(name + r"\s*=\s*(\[[^\]]*\])", src).group(1))  # noqa: S307 - numbers only


def test_the_plant_derivative_is_the_package_derivative(p):
    """The package's derivative reference (its test_derivatives.test_mb) through the plant's
    wrapper: the wheel rule changes nothing while the wheels turn."""
    x = _package_reference("test_derivatives", "x_mb")
    want = _package_reference("test_derivatives", "f_mb_gt")
    got = wheels_held(mb.vehicle_dynamics_mb, x, [0.15, 0.63 * 9.81], p, WHEELS)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-7)


def test_the_plant_integrator_reproduces_the_package_trajectory_from_rest(p):
    """The package's reference trajectory of an accelerating, steering car (1 s from rest; its
    test_zeroInitialVelocity). The package's own odeint no longer reproduces its references
    (docs/decisions.md); the plant's RK4 does: states within the package's 1e-2, wheel speeds
    (11 to 310 rad/s) within 0.2 %."""
    from vehiclemodels.init_mb import init_mb

    want = np.array(_package_reference("test_zeroInitialVelocity", "x_acc_gt"))
    z = init_mb([0, 0, 0, 0, 0, 0, 0], p)

    def deriv(z, a, b):
        return wheels_held(mb.vehicle_dynamics_mb, z, [a, b], p, WHEELS)

    for _ in range(100):
        n = max(int(math.ceil(0.01 / mb_substep(z[3]) - 1e-9)), 1)
        for _ in range(n):
            z = rk4_step(deriv, z, 0.15, 0.63 * 9.81, 0.01 / n, WHEELS)
    z = np.array(z)
    body = np.r_[0:23, 27:29]
    np.testing.assert_allclose(z[body], want[body], rtol=0, atol=1e-2)
    np.testing.assert_allclose(z[WHEELS], want[WHEELS], rtol=2e-3)


def _drive(plant, x0, inputs):
    plant.reset(x0, np.zeros(2))
    return np.array([plant.step(np.array(u)) for u in inputs])


def test_the_plant_period_agrees_with_a_fine_integration_at_the_limit(bmw, monkeypatch):
    """1.5 s at the grip limit (0.06 rad at 22 m/s, braking in the corner: the inner wheels lift
    and lock) against the same plant with 10 times smaller substeps."""
    from gprace.plants import commonroad as cr

    track = make_circle(100.0, 10.0)
    cfg = PlantConfig(kind="commonroad-mb", vehicle=bmw)
    x0 = np.array([22.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    inputs = [(0.06, -3.0 if k >= 15 else 0.0) for k in range(30)]
    plant = make_plant(cfg, track, 0.05)
    A = _drive(plant, x0, inputs)
    locked = min(plant.global_state[WHEELS])
    monkeypatch.setattr(cr, "H_MB_MAX", cr.H_MB_MAX / 10)
    monkeypatch.setattr(cr, "_MB_STIFF", cr._MB_STIFF / 10)
    B = _drive(make_plant(cfg, track, 0.05), x0, inputs)
    assert locked < 1.0  # a wheel locked: the stiff, non-smooth case
    assert np.abs(A - B)[:, [0, 1, 2]].max() < 1e-3 and np.abs(A - B)[:, 4].max() < 1e-3


def test_multi_body_and_single_track_agree_in_the_linear_range(bmw):
    """At a_y = 1 m/s^2 the two BMWs of the package (same parameters, different models) hold the
    same circle; near the limit they do not (roll, per-wheel loads, camber)."""
    def hold(kind, v):
        track = make_circle(100.0, 30.0)
        plant = make_plant(PlantConfig(kind=kind, vehicle=bmw), track, 0.05)
        u = (2.6 / 100.0 + 0.0 * v, 0.0)
        X = _drive(plant, np.array([v, 0.0, v / 100.0, 0.0, 0.0, 0.0]), [u] * 40)
        return X

    S, M = hold("commonroad-std", 10.0), hold("commonroad-mb", 10.0)
    assert np.abs(S[:, 2] - M[:, 2]).max() < 0.03 * 0.1 and np.abs(S[:, 4] - M[:, 4]).max() < 0.05
    S, M = hold("commonroad-std", 28.0), hold("commonroad-mb", 28.0)
    assert np.abs(S[:, 4] - M[:, 4]).max() > 0.3


def test_simulate_drives_the_multi_body_plant(bmw):
    run = _sim(load_plant("bmw_commonroad_mb"), make_circle(100.0, 6.0), SimulateConfig(laps=0.3, dt=0.05))
    assert run.meta["completed"] and run.meta["plant"] == "commonroad-mb"
    assert np.abs(run["e_y"]).max() < 1.0 and run.vehicle().name == "bmw_320i"


def _sim(pc, track, cfg):
    from gprace.sim import simulate

    return simulate(pc, track, cfg)


def test_multi_body_plant_places_the_car_and_rejects_effects(bmw, circle_track):
    plant = make_plant(PlantConfig(kind="commonroad-mb", vehicle=bmw), circle_track, 0.05)
    x0 = np.array([15.0, 0.4, 0.1, 0.05, -1.2, 30.0])
    np.testing.assert_allclose(plant.reset(x0), x0, atol=1e-7)
    z = plant.global_state
    assert z.shape == (29,) and z[3] == pytest.approx(15.0) and z[10] == pytest.approx(0.4)
    np.testing.assert_allclose(z[WHEELS], 15.0 / 0.344, rtol=1e-3)  # rolling
    assert plant.describe()["model"] == "vehiclemodels.vehicle_dynamics_mb"
    bad = PlantConfig(kind="commonroad-mb", vehicle=bmw, effects=(EffectConfig(name="downforce", params={"c_l": 1.0}),))
    with pytest.raises(ConfigError, match=r"'commonroad-mb' has its own physics"):
        make_plant(bad, circle_track, 0.05)


def test_a_car_spinning_on_the_multi_body_plant_is_a_lost_lap_not_a_traceback(bmw, circle_track):
    """The package divides by a wheel's longitudinal speed, clipped at zero: a car yawing fast at
    walking pace (a spin) runs its inner front wheel backwards, and the step fails (a division by
    zero, or a state that is no longer finite). The drive loops' step
    (:func:`gprace.sim.stop.step_plant`) turns that into the car lost there."""
    from gprace.sim.stop import step_plant

    plant = make_plant(PlantConfig(kind="commonroad-mb", vehicle=bmw), circle_track, 0.05)
    plant.reset(np.array([15.0, 0.0, 0.0, 0.0, 0.0, 30.0]))
    spin = plant.global_state.copy()
    spin[3], spin[5] = 1.0, 5.0  # v_x 1 m/s, yaw rate 5 rad/s: the inner front wheel runs backwards
    plant._z = list(spin)
    with pytest.raises((ZeroDivisionError, SolverError)):
        plant.step(np.zeros(2))
    plant._z = list(spin)
    y, why = step_plant(plant, np.zeros(2))
    assert y is None and why.startswith("the plant's model broke down at s = 30.0 m")
    plant.reset(np.array([15.0, 0.0, 0.0, 0.0, 0.0, 30.0]))
    y, why = step_plant(plant, np.zeros(2))
    assert why == "" and np.all(np.isfinite(y)) and y[0] > 14.0
