"""The ``randomized`` plant: the documented family, its physics, actuator, delay and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import make_circle
from gprace.cli import main
from gprace.config import PlantConfig, SimulateConfig, config_hash, load_plant
from gprace.errors import ConfigError
from gprace.model import NominalModel
from gprace.plants import approximate, make_plant
from gprace.plants.randomized import DRAW_ORDER, RandomizedOptions, draw, ranges, steering_path

OFF = dict(grip_front=1, grip_rear=1, downforce=0, cog_height=0, load_sensitivity=0, combined_slip=False,
           steering_lag=0, steering_rate=math.inf, relaxation_length=0, yaw_inertia=1, drag=1, measurement_delay=0)
"""Every effect of the family switched off: the nominal bicycle."""


def _plant(vehicle, track, dt=0.05, **options):
    return make_plant(PlantConfig(kind="randomized", vehicle=vehicle, options=options), track, dt)


def _drive(plant, x0, n=60, seed=0):
    """States after ``n`` periods of a lively steering and throttle/brake sequence."""
    rng = np.random.default_rng(seed)
    plant.reset(x0, np.array([0.0, 0.0]))
    out = []
    for k in range(n):
        u = np.array([0.03 * math.sin(0.4 * k) + 0.005 * rng.standard_normal(), 3.0 * math.cos(0.23 * k)])
        plant.step(u)
        out.append(plant.state)
    return np.array(out)


# --------------------------------------------------------------------------------------------
# the family


def test_the_same_seed_draws_the_same_car_and_drives_it_the_same(audi, circle_track):
    x0 = np.array([25.0, 0.0, 0.25, 0.0, 0.0, 0.0])
    a, b, c = (_plant(audi, circle_track, seed=s) for s in (7, 7, 8))
    assert a.describe() == b.describe() and a.describe() != c.describe()
    np.testing.assert_array_equal(_drive(a, x0), _drive(b, x0))
    assert np.abs(_drive(a, x0) - _drive(c, x0)).max() > 1e-3
    # the noise seed (PlantConfig.seed, varied per run by simulate and iterate) is not the car
    d = make_plant(PlantConfig(kind="randomized", vehicle=audi, seed=99, options={"seed": 7}), circle_track, 0.05)
    assert d.describe() == a.describe()


@pytest.mark.parametrize("vehicle_name", ["audi", "bmw"])
def test_draws_cover_their_documented_ranges_and_stay_inside(vehicle_name, request):
    vehicle = request.getfixturevalue(vehicle_name)
    opts = RandomizedOptions()
    rg = ranges(opts, vehicle)
    n = 3000
    draws = {k: np.empty(n) for k in DRAW_ORDER}
    for i in range(n):
        v = draw(opts.model_copy(update={"seed": i}), vehicle).values
        for k in DRAW_ORDER:
            draws[k][i] = v[k]
    for k, (lo, hi) in rg.items():
        x = draws[k]
        assert x.min() >= lo and x.max() <= hi, k
        if hi > lo:  # uniform: reaches both ends, mean and spread of U(lo, hi)
            span = hi - lo
            assert x.min() < lo + 0.01 * span and x.max() > hi - 0.01 * span, k
            assert abs(x.mean() - 0.5 * (lo + hi)) < 4 * span / math.sqrt(12 * n), k
            assert x.std() == pytest.approx(span / math.sqrt(12), rel=0.05), k
    # the documented ranges themselves (docs/plants.md)
    assert rg["grip_front"] == rg["grip_rear"] == (0.8, 1.05)
    assert rg["downforce"] == (0.0, 1.5) and rg["yaw_inertia"] == (0.75, 1.25) and rg["drag"] == (0.7, 1.5)
    assert rg["cog_height"] == (0.3, 0.6) and rg["relaxation_length"] == (0.0, 1.5)
    assert rg["steering_lag"] == (0.0, 0.08) and rg["measurement_delay"] == (0.0, 2.0)
    # draws are independent (no pair correlated beyond sampling noise)
    M = np.array([draws[k] for k in DRAW_ORDER if rg[k][1] > rg[k][0]])
    C = np.corrcoef(M)
    assert np.abs(C[np.triu_indices_from(C, 1)]).max() < 5 / math.sqrt(n)


def test_overriding_one_range_leaves_the_other_draws_alone(audi):
    a = draw(RandomizedOptions(seed=4), audi).values
    b = draw(RandomizedOptions(seed=4, grip_rear=(0.8, 1.0), steering_lag=0.04), audi).values
    assert b["steering_lag"] == 0.04 and 0.8 <= b["grip_rear"] <= 1.0
    for k in DRAW_ORDER:
        if k not in ("grip_rear", "steering_lag"):
            assert a[k] == b[k], k


def test_length_ranges_scale_with_a_small_car():
    from gprace.config import load_vehicle

    barc = load_vehicle("barc_1_10")
    rg = ranges(RandomizedOptions(), barc)
    k = barc.wheelbase / 2.5
    assert rg["cog_height"] == pytest.approx((0.3 * k, 0.6 * k)) and rg["relaxation_length"] == pytest.approx((0.0, 1.5 * k))


# --------------------------------------------------------------------------------------------
# physics


def test_every_effect_off_is_the_nominal_model(audi):
    """A real check of the dynamics: with the family's effects off the double-track car, its
    actuator and its delay reduce to the nominal bicycle (RK4 with 20 substeps as reference)."""
    from gprace.tracks import load_track

    track = load_track("gprace_ring")
    plant = _plant(audi, track, **OFF)
    m = NominalModel(audi)
    table, L = track.casadi_kappa(), track.length
    kappa = lambda s: np.asarray(table(np.mod(s, L))).ravel()  # noqa: E731
    x = np.array([25.0, 0.2, 0.1, 0.02, 0.5, 10.0])
    plant.reset(x, np.array([0.0, 0.0]))
    for k in range(50):
        u = np.array([0.02 * math.sin(k / 5), 1.0 * math.cos(k / 3)])
        x = m.rk4(x, u, kappa, 0.05, 20)
        y = plant.step(u)
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-6)


def test_all_effects_on_integrate_accurately(audi, circle_track):
    """The plant's RK4 period against the same model at 4 times the substeps."""
    opts = dict(seed=3, relaxation_length=0.3, steering_lag=0.03, measurement_delay=0)
    x0 = np.array([30.0, 0.0, 0.3, 0.0, 0.0, 0.0])
    fine = make_plant(PlantConfig(kind="randomized", vehicle=audi, substeps=40, options=opts), circle_track, 0.05)
    coarse = _plant(audi, circle_track, **opts)
    A, B = _drive(coarse, x0), _drive(fine, x0)
    assert np.abs(A[:, :5] - B[:, :5]).max() < 1e-4
    assert np.abs(A[:, 1]).max() > 0.3  # the manoeuvre is lively


def test_the_family_changes_the_limit_not_the_linear_range(audi):
    """Grip moves the peak force, not the cornering stiffness; load sensitivity on the rated load
    makes the front-heavy car understeer a little; lateral load transfer costs grip at the limit."""
    from scipy.optimize import fsolve

    from gprace.model.ops import NP
    from gprace.plants import double_track as dt

    def steady(p, v, R=100.0):
        def res(z):
            vy, d, ax = z
            r = v / R
            x = [v, vy, r, 0, 0, 0, d - math.atan((vy + p.lf * r) / v), -math.atan((vy - p.lr * r) / v), 0.0, v * r]
            return dt.derivative(x, d, ax, 1 / R, p, NP)[:3]

        z, _, ok, _ = fsolve(res, [0.0, 0.03, 0.0], full_output=True)
        return z[1] if ok == 1 else math.nan

    base = draw(RandomizedOptions(**OFF), audi).params
    worn = draw(RandomizedOptions(**{**OFF, "grip_front": 0.8, "grip_rear": 0.8}), audi).params
    sens = draw(RandomizedOptions(**{**OFF, "load_sensitivity": 0.2}), audi).params
    assert steady(worn, 10.0) == pytest.approx(steady(base, 10.0), rel=1e-3)  # a_y = 1 m/s^2
    assert math.isnan(steady(worn, 36.0)) and not math.isnan(steady(base, 36.0))  # 13 m/s^2: past the worn limit
    # understeer: the steering needed grows with speed (the nominal Audi is neutral)
    assert steady(sens, 25.0) > steady(sens, 10.0) * 1.02 and steady(base, 25.0) == pytest.approx(steady(base, 10.0), rel=1e-3)
    tall = draw(RandomizedOptions(**{**OFF, "cog_height": 0.6, "load_sensitivity": 0.2}), audi).params
    low = draw(RandomizedOptions(**{**OFF, "cog_height": 0.0, "load_sensitivity": 0.2}), audi).params
    v_lim = [max(v for v in np.arange(20.0, 42.0, 0.25) if not math.isnan(steady(p, v))) for p in (tall, low)]
    assert v_lim[0] < v_lim[1]


def test_relaxation_lags_the_tire_by_sigma_over_v(audi, circle_track):
    """The front slip angle state follows a steering step with time constant sigma / v_x."""
    sigma, v = 1.2, 30.0
    plant = _plant(audi, circle_track, dt=0.01, **{**OFF, "relaxation_length": sigma})
    plant.reset(np.array([v, 0.0, 0.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0]))
    a = []
    for _ in range(4):  # 40 ms: the car barely yaws, the tire winds up
        plant.step(np.array([0.02, 0.0]))
        a.append(plant.full_state[6])
    t = 0.01 * np.arange(1, 5)
    np.testing.assert_allclose(a, 0.02 * (1 - np.exp(-t * v / sigma)), rtol=0.05)


# --------------------------------------------------------------------------------------------
# actuator and measurement


def test_steering_path_is_the_rate_limited_lag():
    """Closed form against a fine Euler integration of ``delta' = clip((cmd - delta)/tau, +-rate)``."""
    t = np.linspace(0.0, 0.3, 301)
    for tau, rate, d0, cmd in [(0.05, 0.5, 0.0, 0.1), (0.08, 0.8, 0.1, -0.05), (0.0, 0.4, 0.0, 0.05), (0.03, 100.0, 0.0, 0.1)]:
        h, d, ref = 1e-6, d0, []
        for k in range(int(0.3 / h) + 1):
            if k % 1000 == 0:
                ref.append(d)
            slope = (cmd - d) / tau if tau > 0 else math.copysign(math.inf, cmd - d) if cmd != d else 0.0
            step = min(max(slope, -rate), rate) * h
            d = d + step if tau > 0 or abs(step) < abs(cmd - d) else cmd
        np.testing.assert_allclose(steering_path(d0, cmd, tau, rate, t), ref, atol=2e-5)


def test_plant_steering_follows_lag_and_rate_limit(audi, circle_track):
    """Step responses of the actuator inside the plant: 40 ms lag, then a 0.3 rad/s rate limit
    (0.3 times the Audi's 1 rad/s), and the command clipped to the nominal steering_max."""
    def angles(plant, cmd, n=4):
        out = []
        for _ in range(n):
            plant.step(np.array([cmd, 0.0]))
            out.append(plant.full_state[-1])
        return out

    x0 = np.array([20.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    plant = _plant(audi, circle_track, **{**OFF, "steering_lag": 0.04})
    plant.reset(x0)
    np.testing.assert_allclose(angles(plant, 0.01), 0.01 * (1 - np.exp(-0.05 * np.arange(1, 5) / 0.04)), rtol=1e-12)
    plant = _plant(audi, circle_track, **{**OFF, "steering_rate": 0.3})
    plant.reset(x0)
    np.testing.assert_allclose(angles(plant, 0.04), [0.015, 0.03, 0.04, 0.04], atol=1e-12)
    plant.step(np.array([5.0, 0.0]))
    assert plant.full_state[-1] == pytest.approx(0.04 + 0.015)
    for _ in range(30):
        plant.step(np.array([5.0, 0.0]))
    assert plant.full_state[-1] == pytest.approx(audi.limits.steering_max)


@pytest.mark.parametrize("delay", [0.0, 1.0, 1.5, 2.0])
def test_measurement_is_the_true_state_delay_periods_ago(audi, delay):
    track = make_circle(100.0, 10.0)
    plant = _plant(audi, track, **{**OFF, "measurement_delay": delay})
    x0 = np.array([25.0, 0.0, 0.25, 0.0, 0.0, 600.0])  # crosses the line: s wraps
    Y, X = [plant.reset(x0)], [x0]
    for k in range(12):
        Y.append(plant.step(np.array([0.026 + 0.01 * math.sin(k), 0.5])))
        X.append(plant.state)
    X = np.array(X)
    X[:, 5] = np.unwrap(X[:, 5], period=track.length)
    j, f = int(delay), delay - int(delay)
    for k in range(3, 13):
        want = (1 - f) * X[k - j] + f * X[k - j - 1]
        want[5] %= track.length
        np.testing.assert_allclose(Y[k], want, atol=1e-9)
    assert plant.describe()["measurement_delay_s"] == pytest.approx(0.05 * delay)


# --------------------------------------------------------------------------------------------
# driving, describing, the oracle's model


@pytest.mark.parametrize("seed", [0, 1])
def test_drawn_cars_are_drivable_by_simulate(seed):
    """The reference driver (no delay compensation) at 0.6 of the nominal limits, half a lap of
    the ring, on cars whose measurement delay stays within a period (docs/plants.md: beyond that
    the reference driver's feedback loses the car; the time trial must compensate)."""
    from gprace.tracks import load_track

    pc = load_plant("audi_randomized")
    pc = pc.model_copy(update={"options": {"seed": seed, "measurement_delay": [0.0, 1.0]}})
    run = simulate_run(pc, load_track("gprace_ring"), SimulateConfig(laps=0.5, speed_scale=0.6))
    assert run.meta["completed"] and np.all(run["border_hit"] == 0)


def simulate_run(pc, track, cfg):
    from gprace.sim import simulate

    return simulate(pc, track, cfg)


def test_describe_reports_the_drawn_car(audi, circle_track):
    d = _plant(audi, circle_track, seed=5).describe()
    assert d["kind"] == "randomized" and d["seed"] == 5 and d["nominal"] == "audi_tt_cup"
    assert set(DRAW_ORDER) <= set(d)
    assert d["downforce_c_l"] == pytest.approx(d["downforce"] * 0.25 * audi.mass * 9.81 / (0.7 * 70.0) ** 2)
    assert d["yaw_inertia_kg_m2"] == pytest.approx(d["yaw_inertia"] * audi.yaw_inertia)
    import json

    json.dumps(d)  # plain data for run metadata


def test_the_approximation_is_closer_to_the_car_than_the_nominal_model(audi):
    """Near the limit (60 to 95 % of the drawn grip) the catalogue approximation predicts the
    drawn car's v_y and yaw-rate derivatives better than the nominal model, on several cars."""
    from gprace.model.ops import NP
    from gprace.plants import double_track as dt

    rng = np.random.default_rng(0)
    for seed in range(5):
        pc = PlantConfig(kind="randomized", vehicle=audi, options={"seed": seed})
        car = draw(RandomizedOptions(seed=seed), audi)
        ap = approximate(pc)
        assert ap.known and not ap.exact and ap.missing
        approx = NominalModel(ap.vehicle, ap.effects)
        nominal = NominalModel(audi)
        p = car.params
        n = 400
        v = rng.uniform(20, 45, n)
        ay = rng.uniform(0.6, 0.95, n) * min(p.mu_f, p.mu_r) * 9.81 * rng.choice([-1, 1], n)
        r = ay / v
        vy = rng.normal(0, 0.02, n) * v
        d = (audi.wheelbase * r / v) + rng.normal(0, 0.005, n)
        ax = rng.uniform(-3, 2, n)
        x = [v, vy, r, 0 * v, 0 * v, 0 * v, d - np.arctan((vy + p.lf * r) / v), -np.arctan((vy - p.lr * r) / v), ax, ay]
        truth = np.array(dt.derivative(x, d, ax, 0.0, p, NP))[1:3].T
        X6 = np.column_stack([v, vy, r, 0 * v, 0 * v, 0 * v])
        U = np.column_stack([d, ax])
        e_ap = approx.f(approx.initial_state(X6, U), U, 0.0)[:, 1:3] - truth
        e_nom = nominal.f(X6, U, 0.0)[:, 1:3] - truth
        assert np.sqrt(np.mean(e_ap**2)) < 0.8 * np.sqrt(np.mean(e_nom**2)), seed


def test_frenet_plant_approximation_is_exact_and_commonroad_unknown():
    hidden = load_plant("audi_hidden")
    ap = approximate(hidden)
    assert ap.known and ap.exact and [e.name for e in ap.effects] == [e.name for e in hidden.effects]
    assert not approximate(load_plant("bmw_commonroad")).known


# --------------------------------------------------------------------------------------------
# configuration


def test_empty_options_keep_the_hash_of_older_files():
    pc = load_plant("audi_hidden")
    data = pc.model_dump(mode="json")
    del data["options"]
    assert pc.digest() == config_hash(data)
    assert load_plant("audi_randomized").digest() != load_plant("audi_randomized").model_copy(
        update={"options": {"seed": 1}}).digest()


@pytest.mark.parametrize("line, needles", [
    ("grip_rer = [0.8, 1.0]", ("options: grip_rer: unknown key", "did you mean 'grip_rear'")),
    ("grip_rear = [1.0, 0.8]", ("options: grip_rear: the range is upside down",)),
    ("steering_lag = [-0.01, 0.05]", ("options: steering_lag: the range must lie within [0, 1]",)),
    ("measurement_delay = \"two\"", ("options: measurement_delay",)),
])
def test_bad_options_are_one_line_and_exit_2(tmp_path, capsys, line, needles):
    f = tmp_path / "car.toml"
    f.write_text(f'kind = "randomized"\nvehicle = "audi_tt_cup"\n\n[options]\nseed = 1\n{line}\n')
    with pytest.raises(ConfigError):
        load_plant(str(f))
    assert main(["simulate", "--plant", str(f), "--laps", "0.01", "-o", str(tmp_path / "r.h5")]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error: ") and "car.toml" in err[0], err
    for n in needles:
        assert n in err[0], err[0]
    assert not (tmp_path / "r.h5").exists()


def test_options_for_a_kind_without_options_and_effects_on_randomized_are_refused(audi, circle_track):
    with pytest.raises(ValueError, match="plant 'frenet' takes no options"):
        PlantConfig(kind="frenet", vehicle=audi, options={"seed": 1})
    from gprace.config import EffectConfig

    cfg = PlantConfig(kind="randomized", vehicle=audi, effects=(EffectConfig(name="downforce", params={"c_l": 1.0}),))
    with pytest.raises(ConfigError, match="draws its own physics"):
        make_plant(cfg, circle_track, 0.05)
