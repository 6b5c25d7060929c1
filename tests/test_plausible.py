"""Issue 38, item 6: a vehicle no car could be is refused with the plausible range, one a real car
could be but few are is warned; shipped and real cars of every size pass."""

from __future__ import annotations

import math

import pytest

from gprace.cli import main
from gprace.config import (K_PLAUSIBLE, MU_POSSIBLE, VehicleConfig, configs_dir, load_plant, load_vehicle,
                           validate)
from gprace.errors import ConfigError


@pytest.fixture(autouse=True)
def _fresh_warnings(monkeypatch):
    monkeypatch.delenv("GPRACE_DEBUG", raising=False)
    import gprace.config as C

    monkeypatch.setattr(C, "_WARNED", set())


@pytest.fixture
def audi_dict(audi):
    return audi.model_dump()


# a 790 kg racing car (the Indy Autonomous Challenge's Dallara AV-21: published mass, wheelbase,
# track and yaw inertia) and an F1-like car, next to the shipped ones
IAC = dict(name="iac_av21", mass=790.0, yaw_inertia=1000.0, l_f=1.7238, l_r=1.2460, width=1.93, length=4.88,
           cog_height=0.275, mu=1.6)
F1 = dict(name="f1_like", mass=798.0, yaw_inertia=1200.0, l_f=2.0, l_r=1.6, width=2.0, length=5.6, cog_height=0.28,
          mu=1.8)


def test_shipped_and_real_cars_of_every_size_pass_without_a_warning(capsys, audi_dict):
    for p in sorted((configs_dir() / "vehicles").glob("*.toml")):
        load_vehicle(p)
    for p in sorted((configs_dir() / "plants").glob("*.toml")):
        load_plant(p)
    for car in (IAC, F1):
        VehicleConfig(**{**audi_dict, **car})
    assert capsys.readouterr().err == ""
    barc = load_vehicle("barc_1_10")
    assert barc.mass < 3 and barc.wheelbase == pytest.approx(barc.length)  # the 1:10 car: footprint = wheelbase


@pytest.mark.parametrize("change,needles", [
    ({"mu": 10.0}, ("mu", "10", f"possible {MU_POSSIBLE[0]:g} to {MU_POSSIBLE[1]:g}")),
    ({"mu": 0.01}, ("mu", "0.01", "possible")),
    ({"mass": 1161250.0}, ("yaw_inertia", "radius of gyration", "plausible", "kg m^2", "grams")),
    ({"yaw_inertia": 2.1e7}, ("yaw_inertia", "half the car's diagonal", "plausible")),
    ({"l_f": 3.0}, ("l_f + l_r", "longer than the car's length")),
    ({"cog_height": 2.5}, ("cog_height", "above the car's width")),
    ({"mass": float("inf")}, ("mass", "finite")),
])
def test_an_impossible_vehicle_is_refused_with_the_range(audi_dict, change, needles):
    with pytest.raises(ConfigError) as exc:
        validate(VehicleConfig, {**audi_dict, **change}, "car.toml")
    msg = str(exc.value)
    assert msg.startswith("car.toml: ") and "\n" not in msg
    for n in needles:
        assert n in msg, (n, msg)


def test_the_plausible_inertia_range_is_the_one_refused_around(audi_dict):
    """The range the message gives is what the radius of gyration bounds mean for this car."""
    a = VehicleConfig(**audi_dict)
    lo, hi = (a.mass * (k * a.wheelbase) ** 2 for k in K_PLAUSIBLE)
    assert lo < a.yaw_inertia < hi
    with pytest.raises(ConfigError, match=f"plausible {lo:.4g} to {hi:.4g} kg m\\^2"):
        validate(VehicleConfig, {**audi_dict, "yaw_inertia": 0.001 * lo}, "car.toml")


@pytest.mark.parametrize("change,needle", [
    ({"mu": 2.5}, "mu 2.5 is outside the usual"),
    ({"mu": 0.2}, "mu 0.2 is outside the usual"),
    ({"cog_height": 0.9}, "rolls over at 1.1 g, before the tires slide"),
    ({"yaw_inertia": 4000.0}, "radius of gyration of 0.74 times the wheelbase"),
    ({"length": 7.0}, "the wheelbase l_f + l_r = 2.506 m is 0.36 of the car's length"),
])
def test_an_unusual_vehicle_is_warned_once(capsys, audi_dict, change, needle):
    for _ in range(3):  # loaded again and again (every worker, every step): one warning
        VehicleConfig(**{**audi_dict, **change})
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("warning: vehicle audi_tt_cup: ") and needle in err[0], err


def test_mu_ten_is_refused_by_the_commands_in_one_line(capsys, tmp_path):
    car = tmp_path / "car.toml"
    car.write_text((configs_dir() / "vehicles" / "audi_tt_cup.toml").read_text().replace("mu = 1.5", "mu = 10.0"))
    assert "mu = 10.0" in car.read_text()
    for argv in (["plan", "--vehicle", car, "-o", tmp_path / "p.h5"], ["iterate", "--vehicle", car, "--out", tmp_path / "it"]):
        assert main([str(a) for a in argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "mu: 10 is no tire-road friction ratio" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["car.toml"]


def test_gyration_bound_holds_for_any_mass_inside_the_footprint():
    """The refusal above the half diagonal is physics, not taste: no mass distribution inside the
    footprint has a larger radius of gyration about a point inside it (checked on random ones)."""
    import numpy as np

    rng = np.random.default_rng(0)
    length, width = 4.2, 2.0
    for _ in range(200):
        pts = rng.uniform([-length / 2, -width / 2], [length / 2, width / 2], size=(rng.integers(1, 20), 2))
        m = rng.random(len(pts))
        cog = (m[:, None] * pts).sum(0) / m.sum()
        k = math.sqrt((m * ((pts - cog) ** 2).sum(1)).sum() / m.sum())
        assert k <= 0.5 * math.hypot(length, width) + 1e-12


def test_iterate_warns_when_the_nominal_vehicle_is_not_the_plants(capsys):
    """``--vehicle`` is not read from the plant: a model of another car is warned before any lap,
    naming both cars; the plant's own vehicle is not."""
    from gprace.timetrial.iterate.settings import IterateSettings, _check_start

    _check_start(IterateSettings(plant="bmw_commonroad", vehicle="bmw_320i"))
    assert capsys.readouterr().err == ""
    _check_start(IterateSettings(plant="bmw_commonroad", vehicle="audi_tt_cup"))
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("warning: iterate: the nominal vehicle is 'audi_tt_cup'"), err
    assert "built on 'bmw_320i'" in err[0] and "--vehicle bmw_320i" in err[0]
