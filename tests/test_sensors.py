"""The sensor calibration (gprace.mpc.sensors): a gyro bias and a turned velocity frame are read
from a run through the localisation's position and heading, and undone exactly."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.config import EffectConfig, PlantConfig, SimulateConfig, load_vehicle
from gprace.model import NominalModel
from gprace.mpc import sensors as S
from gprace.sim import simulate
from gprace.timetrial.learning import in_control
from gprace.tracks import load_track


def test_the_calibration_undoes_what_the_biased_sensors_do():
    """Analytic: the catalogue's sensor effects, then the calibration of their own values, give the
    true states back (to rounding); the positions are left alone."""
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(5, 60, 50), rng.normal(0, 1, 50), rng.normal(0, 0.5, 50),
                         rng.normal(0, 0.1, 50), rng.normal(0, 2, 50), rng.uniform(0, 2000, 50)])
    effects = [EffectConfig(name="gyro_bias", params={"bias": 0.031}),
               EffectConfig(name="velocity_misalignment", params={"angle": -0.022})]
    measured = NominalModel(load_vehicle("audi_tt_cup"), effects).measure(X)
    assert np.abs(measured - X)[:, 1].max() > 0.5  # the frame's turn shows as side-slip velocity
    back = S.SensorCalibration(yaw_rate_bias=0.031, velocity_angle=-0.022).apply(measured)
    np.testing.assert_allclose(back, X, atol=1e-12)
    assert S.SensorCalibration().apply(measured) is measured  # no calibration: the measurement itself


def test_longest_stretch_of_a_mask():
    ok = np.array([1, 1, 0, 1, 1, 1, 0, 0, 1], bool)
    assert S.longest_stretch(ok) == slice(3, 6)
    assert S.longest_stretch(np.zeros(4, bool)) == slice(0, 0)
    assert S.longest_stretch(np.ones(4, bool)) == slice(0, 4)


@pytest.fixture(scope="module")
def ring():
    return load_track("gprace_ring")


def _run(ring, effects, laps=0.6, seed=5):
    audi = load_vehicle("audi_tt_cup")
    noise = {"v_x": 0.02, "v_y": 0.01, "yaw_rate": 0.005, "e_psi": 0.002, "e_y": 0.02, "s": 0.05}
    plant = PlantConfig(vehicle=audi, effects=tuple(effects), noise=noise, seed=seed)
    return simulate(plant, ring, SimulateConfig(laps=laps, speed_scale=0.7, weave_amplitude=0.4,
                                                 weave_wavelength=200.0))


def test_a_hidden_gyro_bias_and_velocity_frame_are_recovered_from_a_noisy_run(ring):
    """Recovery of hidden parameters: a weaving run of a car whose gyro reads 0.03 rad/s high and whose
    velocity frame is turned by -0.015 rad (0.6 m/s of phantom side-slip velocity at 40 m/s)."""
    effects = [EffectConfig(name="gyro_bias", params={"bias": 0.03}),
               EffectConfig(name="velocity_misalignment", params={"angle": -0.015})]
    run = _run(ring, effects)
    X = run.states()
    raw = S.read(X, run["t"], in_control(X), ring)
    assert raw["yaw_rate_bias"] == pytest.approx(0.03, abs=5e-4)
    assert raw["velocity_angle"] == pytest.approx(-0.015, abs=5e-4)
    assert raw["speed_scale"] == pytest.approx(1.0, abs=2e-3)
    cal = S.of_run(run, ring, in_control)
    assert not cal.identity
    fixed = S.corrected(run, cal)
    assert fixed.meta["sensors"] == cal.as_dict()
    # corrected, the run reads as the sensors of a true car: nothing beyond the dead bands
    assert S.of_run(fixed, ring, in_control).identity


def test_sensors_that_read_true_are_left_alone(ring):
    """The same car without the sensor errors: the readings stay inside the dead bands, so the
    loop drives it exactly as without the calibration (the run itself comes back)."""
    run = _run(ring, [])
    X = run.states()
    raw = S.read(X, run["t"], in_control(X), ring)
    assert abs(raw["yaw_rate_bias"]) < 0.25 * S.DEAD_BAND["yaw_rate_bias"]
    assert abs(raw["velocity_angle"]) < 0.25 * S.DEAD_BAND["velocity_angle"]
    cal = S.of_run(run, ring, in_control)
    assert cal.identity and S.corrected(run, cal) is run


def test_a_run_too_short_to_read_reads_nothing(ring):
    run = _run(ring, [EffectConfig(name="gyro_bias", params={"bias": 0.03})], laps=0.15)
    assert run["t"][-1] < S.MIN_DURATION
    X = run.states()
    assert all(np.isnan(v) for v in S.read(X, run["t"], in_control(X), ring).values())
    assert S.of_run(run, ring, in_control).identity


def test_the_oracle_knows_the_plants_sensor_errors():
    from gprace.timetrial.oracle import true_sensors

    effects = [EffectConfig(name="downforce", params={"c_l": 1.0}), EffectConfig(name="gyro_bias", params={"bias": -0.01}),
               EffectConfig(name="velocity_misalignment", params={"angle": 0.02})]
    assert true_sensors(effects) == S.SensorCalibration(yaw_rate_bias=-0.01, velocity_angle=0.02)
    assert true_sensors(effects[:1]).identity


def test_the_loop_reads_the_sensors_from_the_reference_run_longest_in_control(ring):
    """A calibration run cut short (a spin within 20 s) leaves the held-out run to read the sensors from."""
    from gprace.timetrial.iterate.chain import _sensor_run

    short, long = _run(ring, [], laps=0.15), _run(ring, [], laps=0.4)
    assert _sensor_run({"calib": short, "heldout": long}) is long
    assert _sensor_run({"calib": long, "heldout": short}) is long
    assert _sensor_run({"calib": None, "heldout": short}) is short
