"""Feature maps: errors against the nominal model, gaps, opponent inputs and lap wrap."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.config import EffectConfig, load_vehicle
from gprace.errors import InputError
from gprace.gp.features import FEATURE_MAPS, dynamics_features, opponent_features, run_features, wrap_ds
from gprace.io.runs import Run
from gprace.model import NominalModel

DT = 0.05


def drive(model, n=300, dt=DT, seed=0):
    """A recording of ``model`` stepped with Euler: lane keeping plus a steering and throttle dither."""
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0, 2 * np.pi, 3)
    t = dt * np.arange(n)
    kappa = 0.004 * np.sin(0.2 * t)
    wheelbase = model.vehicle.l_f + model.vehicle.l_r
    x = model.initial_state(np.array([30.0, 0.0, 0.0, 0.0, 0.0, 0.0]), np.zeros(2))
    X, U = np.empty((n, 6)), np.empty((n, 2))
    for k in range(n):
        X[k] = x[:6]
        dither = 0.02 * np.sin(0.9 * t[k] + ph[0]) + 0.01 * np.sin(2.3 * t[k] + ph[1])
        U[k] = [wheelbase * kappa[k] - 0.05 * x[4] - 0.8 * x[3] + dither, 1.5 * np.sin(0.4 * t[k] + ph[2])]
        x = model.euler(x, U[k], kappa[k], dt)
    data = {"t": t, "s": X[:, 5], "e_y": X[:, 4], "e_psi": X[:, 3], "v_x": X[:, 0], "v_y": X[:, 1],
            "yaw_rate": X[:, 2], "delta": U[:, 0], "a_x": U[:, 1], "kappa": kappa}
    return Run(data, {"dt": dt, "vehicle_toml": model.vehicle.to_toml()}, "synthetic")


@pytest.fixture(scope="module")
def audi_model():
    return NominalModel(load_vehicle("audi_tt_cup"))


@pytest.fixture(scope="module")
def true_model():
    return NominalModel(load_vehicle("audi_tt_cup"), [EffectConfig(name="downforce", params={"c_l": 1.5, "balance": 0.45})])


def test_nominal_recording_has_zero_error(audi_model):
    run = drive(audi_model)
    for kind in ("tracking", "planning"):
        Z, Y = dynamics_features(run, audi_model, kind)
        assert Z.shape == (299, 3) and Y.shape == (299, 2)
        assert np.max(np.abs(Y)) < 1e-9
    np.testing.assert_array_equal(Z[:, 0], run["v_y"][:-1])
    np.testing.assert_array_equal(Z[:, 2], run["delta"][:-1])


def test_hidden_effect_error_is_the_model_difference(audi_model, true_model):
    run = drive(true_model)
    Z, Y = dynamics_features(run, audi_model, "tracking")
    X, U = run.states(), run.inputs()
    expected = true_model.euler(X[:-1], U[:-1], run["kappa"][:-1], DT) - audi_model.euler(X[:-1], U[:-1], run["kappa"][:-1], DT)
    np.testing.assert_allclose(Y, expected[:, 1:3], rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(Y)) > 1e-3  # downforce is visible in v_y and yaw rate
    _, Yp = dynamics_features(run, audi_model, "planning")
    np.testing.assert_allclose(Yp, Y / DT, rtol=1e-12)


def test_rk4_step_and_run_vehicle(audi_model):
    run = drive(audi_model)
    Z, Y = run_features(run, "tracking", step="rk4")  # vehicle from the run
    assert Y.shape == (299, 2) and np.max(np.abs(Y)) > 0  # Euler data, RK4 reference: not zero
    with pytest.raises(Exception, match="step"):
        run_features(run, "tracking", step="midpoint")


def test_gaps_are_dropped(audi_model):
    run = drive(audi_model, n=100)
    keep = np.ones(100, bool)
    keep[[30, 31, 60]] = False
    Z, _ = dynamics_features(run.slice(keep), audi_model, "tracking")
    assert len(Z) == 96 - 2  # 97 samples, 96 pairs, two of them across a gap


def test_run_without_vehicle_needs_one(audi_model):
    run = drive(audi_model, n=20)
    run.meta.pop("vehicle_toml")
    with pytest.raises(InputError, match="--vehicle"):
        run_features(run, "tracking")
    Z, _ = run_features(run, "tracking", vehicle=load_vehicle("audi_tt_cup"))
    assert len(Z) == 19


def test_opponent_features_on_a_closed_track():
    L = 100.0
    n = 60
    t = 0.1 * np.arange(n)
    s_opp = np.mod(80.0 + 5.0 * t, L)  # crosses the lap line at t = 4 s
    s_ego = np.mod(s_opp - 3.0, L)
    opp = {"s": s_opp, "e_y": 0.2 * np.sin(t), "e_psi": 0.01 * np.cos(t), "v_x": np.full(n, 5.0), "yaw_rate": np.full(n, 0.05)}
    ego = {"s": s_ego, "e_y": np.full(n, -0.3), "e_psi": np.zeros(n), "v_x": np.full(n, 5.2), "yaw_rate": np.zeros(n)}
    kappa = lambda s: np.where(np.mod(s, L) < 50.0, 0.0, 0.1)  # noqa: E731
    Z, Y = opponent_features(ego, opp, kappa, length=L, t=t)
    assert Z.shape == (n - 1, 11) and Y.shape == (n - 1, 5)
    assert len(FEATURE_MAPS["opponent"].input_names) == 11 and len(FEATURE_MAPS["opponent"].output_names) == 5
    np.testing.assert_allclose(Z[:, 3], 3.0, atol=1e-9)  # gap in s, wrapped across the lap line
    np.testing.assert_allclose(Y[:, 0], 0.5, atol=1e-9)  # ds per step, no -L jump
    np.testing.assert_allclose(Z[:, 0], ego["e_y"][:-1] - opp["e_y"][:-1])
    np.testing.assert_allclose(Y[:, 1], np.diff(opp["e_y"]))
    k0 = Z[:, 8]
    np.testing.assert_array_equal(k0, kappa(s_opp[:-1]))
    assert np.any(Z[:, 10] != Z[:, 8])  # the lookahead sees the change of curvature first
    with pytest.raises(InputError, match="aligned"):
        opponent_features({k: v[:-1] for k, v in ego.items()}, opp, kappa, L)


def test_wrap_ds():
    np.testing.assert_allclose(wrap_ds(np.array([-99.0, 99.0, 10.0]), 100.0), [1.0, -1.0, 10.0])
    np.testing.assert_allclose(wrap_ds(np.array([-99.0]), None), [-99.0])
