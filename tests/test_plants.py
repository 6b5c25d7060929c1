"""Plants (frenet, commonroad-std), the reference controller and ``simulate``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import fsolve

from conftest import TUM_TRACKS, make_circle
from gprace.config import G, EffectConfig, NoiseConfig, PlantConfig, SimulateConfig, load_plant
from gprace.errors import UnknownBackendError
from gprace.model import NominalModel
from gprace.plants import make_plant
from gprace.sim import lap_times, simulate, speed_profile


def test_frenet_plant_without_effects_is_the_nominal_model(audi, circle_track):
    dt, sub = 0.05, 7
    plant = make_plant(PlantConfig(kind="frenet", vehicle=audi, substeps=sub), circle_track, dt)
    m = NominalModel(audi)
    x = np.array([20.0, 0.1, 0.2, 0.01, 0.3, 600.0])  # near the end of the lap: s wraps
    y = plant.reset(x)
    np.testing.assert_array_equal(y, x)  # no noise configured
    rng = np.random.default_rng(1)
    L = circle_track.length
    # the plant reads kappa from the track's CasADi B-spline table: use the same curvature here
    table = circle_track.casadi_kappa()
    kappa = lambda s: np.asarray(table(np.mod(s, L))).ravel()  # noqa: E731
    for _ in range(30):
        u = np.array([0.03, 0.5]) + rng.normal(0, [0.01, 0.5])
        x = m.rk4(x, u, kappa, dt, sub)
        y = plant.step(u)
        np.testing.assert_allclose(y[:5], x[:5], rtol=0, atol=1e-10)
        assert y[5] == pytest.approx(x[5] % L, abs=1e-9)
    assert plant.lap == 1


def test_frenet_plant_noise_has_the_configured_spread(audi, circle_track):
    sd = dict(v_x=0.1, v_y=0.05, yaw_rate=0.01, e_psi=0.002, e_y=0.2, s=0.5)
    plant = make_plant(PlantConfig(vehicle=audi, noise=NoiseConfig(**sd), seed=3), circle_track, 0.05)
    x = np.array([20.0, 0.0, 0.2, 0.0, 0.0, 100.0])
    Y = np.array([plant.reset(x) for _ in range(4000)]) - x
    np.testing.assert_allclose(Y.std(axis=0), list(sd.values()), rtol=0.06)
    assert np.all(np.abs(Y.mean(axis=0)) < 4 * np.array(list(sd.values())) / np.sqrt(4000))


def test_plant_registry(audi, circle_track):
    from gprace.plants.commonroad import CommonRoadSTDPlant

    assert isinstance(make_plant(PlantConfig(kind="commonroad-std", vehicle=audi), circle_track, 0.05), CommonRoadSTDPlant)
    with pytest.raises(UnknownBackendError, match="available: commonroad-std, frenet, randomized"):
        make_plant(PlantConfig(kind="frenetic", vehicle=audi), circle_track, 0.05)


@pytest.mark.parametrize("track_name", ["circle", "Suzuka"])
def test_commonroad_plant_places_the_car_at_the_frenet_state(bmw, track_name):
    from gprace.tracks import load_track

    track = make_circle() if track_name == "circle" else load_track(f"{TUM_TRACKS}/{track_name}.csv")
    plant = make_plant(PlantConfig(kind="commonroad-std", vehicle=bmw), track, 0.05)
    for s in np.linspace(0, track.length, 7, endpoint=False):
        x0 = np.array([15.0, 0.4, 0.1, 0.05, -1.2, s])
        plant.reset(x0)
        z = plant.global_state
        assert z[3] == pytest.approx(np.hypot(15.0, 0.4)) and z[6] == pytest.approx(np.arctan2(0.4, 15.0))
        # the observation of the placed car is the Frenet state it was placed at
        np.testing.assert_allclose(plant._observe(list(z)), x0, atol=1e-7)


def _agreement(bmw, v):
    """commonroad-std vs the nominal bicycle of bmw_320i: 3 s of constant inputs on a circle."""
    track = make_circle(100.0, 30.0)
    kappa = 0.01
    m = NominalModel(bmw)

    def res(z):
        vy, delta, ax = z
        return m.f(np.array([v, vy, v * kappa, 0, 0, 0]), np.array([delta, ax]), kappa)[:3]

    vy, delta, ax = fsolve(res, [0.0, 2.6 * kappa, 0.0])  # the nominal model's steady state
    x0 = np.array([v, vy, v * kappa, 0.0, 0.0, 0.0])
    u = np.array([delta, ax])
    dt = 0.05
    plant = make_plant(PlantConfig(kind="commonroad-std", vehicle=bmw), track, dt)
    plant.reset(x0, u)
    xs, P, N = x0.copy(), [], []
    for _ in range(60):
        plant.step(u)
        xs = m.rk4(xs, u, track.kappa, dt, 10)
        P.append(plant.state)
        N.append(xs.copy())
    P, N = np.array(P), np.array(N)
    return np.abs(P[:, 2] - N[:, 2]).max() / (v * kappa), np.abs(P[:, 4] - N[:, 4]).max()


def test_commonroad_and_nominal_agree_at_low_lateral_acceleration(bmw):
    dr, dey = _agreement(bmw, 10.0)  # a_y = 1 m/s^2
    assert dr < 0.01 and dey < 0.02


def test_commonroad_and_nominal_diverge_near_the_limit(bmw):
    dr, dey = _agreement(bmw, 30.0)  # a_y = 9 m/s^2 = 0.87 mu g
    assert dr > 0.05 and dey > 1.0


# --------------------------------------------------------------------------------------------
# controller and simulate


def test_speed_profile_is_friction_limited_and_brakes_ahead(audi):
    s = np.linspace(0.0, 600.0, 601)
    kappa = np.where(s >= 400.0, 1.0 / 50.0, 0.0)  # 400 m straight, then an arc of radius 50 m
    v = speed_profile(s, kappa, audi, 0.8, closed=False)
    v_arc = np.sqrt(0.8 * audi.mu * G * 50.0)
    np.testing.assert_allclose(v[s >= 400.0], v_arc, rtol=1e-12)
    a_b = 0.8 * min(-audi.limits.accel_min, 0.8 * audi.mu * G)  # planned braking on the straight
    i = 300  # 100 m before the arc: v^2 = v_arc^2 + 2 a_b d (the arc's a_y limits the first metre)
    assert v[i] == pytest.approx(np.sqrt(v_arc**2 + 2 * a_b * 100.0), rel=0.01)
    assert np.all(np.diff(v[:400]) <= 1e-12) or v[0] == pytest.approx(audi.limits.speed_max)


def test_simulate_on_a_circle_holds_the_line_at_the_profile_speed(audi):
    track = make_circle(100.0, 6.0)
    cfg = SimulateConfig(dt=0.05, laps=1.2, speed_scale=0.5)
    run = simulate(PlantConfig(vehicle=audi), track, cfg)
    v_ref = np.sqrt(0.5 * audi.mu * G * 100.0)
    assert run.meta["completed"]
    assert np.abs(run["e_y"]).max() < 0.3 and np.all(run["border_hit"] == 0)
    np.testing.assert_allclose(np.hypot(run["v_x"], run["v_y"]), v_ref, rtol=0.02)
    assert run["lap"][-1] == 1 and np.all(np.diff(run["lap"]) >= 0)
    assert lap_times(run)[0] == pytest.approx(track.length / v_ref, rel=0.03)
    np.testing.assert_allclose(np.diff(run["t"]), 0.05)
    np.testing.assert_allclose(run["kappa"], 0.01, rtol=1e-4)


def test_simulate_weaves_with_the_requested_amplitude(audi):
    track = make_circle(100.0, 6.0)
    cfg = SimulateConfig(dt=0.05, laps=1.0, speed_scale=0.5, weave_amplitude=0.5, weave_wavelength=157.08)
    run = simulate(PlantConfig(vehicle=audi), track, cfg)
    target = 0.5 * (6.0 - 0.5 * audi.width)
    assert np.abs(run["e_y"]).max() == pytest.approx(target, rel=0.3)
    assert np.abs(run["yaw_rate"] - run["v_x"] * 0.01).max() > 0.05  # the weave excites the yaw


def test_simulate_records_the_nominal_vehicle_and_stops_at_the_end_of_an_open_track(audi):
    from gprace.tracks import Track

    s = np.linspace(0, 300, 61)
    x = np.where(s < 150, s, 150 + 80 * np.sin((s - 150) / 80))
    y = np.where(s < 150, 0.0, 80 * (1 - np.cos((s - 150) / 80)))
    track = Track(x, y, np.full(61, 5.0), np.full(61, 5.0), closed=False, name="open")
    plant = load_plant("audi_hidden")
    run = simulate(plant, track, SimulateConfig(laps=3))
    assert run.meta["completed"]
    assert run["s"][-1] >= track.length - 0.1 * run["v_x"][-1] - 1.0 and run["s"][-2] < track.length
    assert run.vehicle() == plant.vehicle and not run.vehicle().effects  # the hidden effects stay hidden
    assert run.meta["plant"] == "frenet" and run.meta["plant_hash"] == plant.digest()
    assert run.meta["track"] == "open" and run.meta["dt"] == 0.05
    assert set(run.data) >= {"t", "s", "e_y", "e_psi", "v_x", "v_y", "yaw_rate", "delta", "a_x", "kappa", "lap", "border_hit"}
    lim = plant.vehicle.limits
    assert np.abs(run["delta"]).max() <= lim.steering_max
    assert np.abs(np.diff(run["delta"])).max() <= lim.steering_rate_max * 0.05 + 1e-12
    assert run["a_x"].min() >= lim.accel_min and run["a_x"].max() <= lim.accel_max


def test_simulate_seed_changes_only_the_noise(audi):
    track = make_circle(100.0, 6.0)
    pc = load_plant("audi_nominal")
    a = simulate(pc, track, SimulateConfig(laps=0.1, seed=0))
    b = simulate(pc, track, SimulateConfig(laps=0.1, seed=0))
    c = simulate(pc, track, SimulateConfig(laps=0.1, seed=1))
    np.testing.assert_array_equal(a["e_y"], b["e_y"])
    assert not np.array_equal(a["e_y"], c["e_y"])
    assert np.abs(a["v_x"][:20] - c["v_x"][:20]).max() < 0.2


def test_simulate_drives_the_commonroad_plant_round_the_circle(bmw):
    track = make_circle(100.0, 6.0)
    run = simulate(load_plant("bmw_commonroad"), track, SimulateConfig(laps=0.4, dt=0.05))
    assert run.meta["completed"] and run.meta["plant"] == "commonroad-std"
    assert np.abs(run["e_y"]).max() < 1.0
    assert run.vehicle().name == "bmw_320i"


@pytest.mark.slow
@pytest.mark.parametrize("plant", ["audi_nominal", "audi_hidden", "bmw_commonroad"])
def test_simulate_completes_a_lap_of_the_default_track(plant):
    from gprace.tracks import load_track

    run = simulate(load_plant(plant), load_track("gprace_ring"), SimulateConfig(laps=1))
    assert run.meta["completed"] and np.abs(run["e_y"]).max() < 5.5


def test_simulate_stops_early_when_the_car_cannot_follow(audi, capsys):
    """A car with a third of the grip the controller assumes slides off; the run ends cleanly."""
    slippery = PlantConfig(vehicle=audi, effects=(EffectConfig(name="tire_friction", params={"front": 0.3, "rear": 0.3}),))
    run = simulate(slippery, make_circle(100.0, 6.0), SimulateConfig(laps=1.0, speed_scale=1.0))
    assert not run.meta["completed"]
    assert run["t"][-1] < 30.0 and run.n >= 2
    assert "simulate: the car" in capsys.readouterr().err


def test_commonroad_plant_rejects_effects(bmw, circle_track):
    from gprace.errors import ConfigError

    cfg = PlantConfig(kind="commonroad-std", vehicle=bmw, effects=(EffectConfig(name="downforce", params={"c_l": 1.0}),))
    with pytest.raises(ConfigError, match=r"effects \(downforce\) work only with 'frenet'"):
        make_plant(cfg, circle_track, 0.05)


def test_border_hits_is_the_footprint_against_the_edges(circle_track):
    """Analytic footprint: straight car (e_psi = 0) hits when |e_y| + w/2 passes the width;
    turned 90 deg the half-extent is l/2."""
    from gprace.sim.record import border_hits

    wl = float(circle_track.width_left(0.0))
    wr = float(circle_track.width_right(0.0))
    length, width = 4.0, 2.0
    X = np.zeros((6, 6))
    X[:, 4] = [wl - 1.01, wl - 0.99, -wr + 1.01, -wr + 0.99, wl - 2.01, wl - 1.99]
    X[4:, 3] = np.pi / 2
    np.testing.assert_array_equal(border_hits(circle_track, X, length, width), [False, True, False, True, False, True])


def test_one_stop_rule_names_off_track_spin_and_stall():
    from gprace.sim.stop import SPIN_EPSI, stop_kind, stop_reason

    ok = np.array([20.0, 0.5, 0.1, 0.2, 1.0, 100.0])
    assert stop_reason(ok, 5.0, 5.0, 2.0, 1.0) == ""
    off = ok.copy()
    off[4] = 9.1  # more than two car widths outside the left border
    assert "left the track at s = 100.0" in stop_reason(off, 5.0, 5.0, 2.0, 1.0)
    spin = ok.copy()
    spin[3] = SPIN_EPSI + 0.01
    assert "spun" in stop_reason(spin, 5.0, 5.0, 2.0, 1.0)
    slide = ok.copy()
    slide[1] = 0.6 * 20.0 + 2.01
    assert "spun" in stop_reason(slide, 5.0, 5.0, 2.0, 1.0)
    slow = ok.copy()
    slow[0] = 0.9
    assert "stalled" in stop_reason(slow, 5.0, 5.0, 2.0, 1.0)
    # the kinds the race records; without a stall speed a standing car goes on
    assert [stop_kind(x, 5.0, 5.0, 2.0, 1.0) for x in (ok, off, spin, slide, slow)] == [
        "", "off_track", "spun", "spun", "stalled"]
    assert stop_kind(slow * [0, 1, 1, 1, 1, 1], 5.0, 5.0, 2.0) == ""
