"""Configuration: shipped files load, errors name the TOML path, TOML round trip."""

from __future__ import annotations

import tomllib

import pytest

from gprace.config import (
    PlantConfig, VehicleConfig, configs_dir, dumps_toml, load_plant, load_toml, load_vehicle, read_toml,
)
from gprace.errors import ConfigError, InputError


@pytest.mark.parametrize("path", sorted((configs_dir() / "vehicles").glob("*.toml")), ids=lambda p: p.stem)
def test_shipped_vehicles_load(path):
    v = load_vehicle(path.stem)
    assert v.name == path.stem and v.wheelbase > 0 and v.limits.accel_min < 0 < v.limits.accel_max


@pytest.mark.parametrize("path", sorted((configs_dir() / "plants").glob("*.toml")), ids=lambda p: p.stem)
def test_shipped_plants_load_and_build(path, circle_track):
    from gprace.plants import make_plant

    p = load_plant(path.stem)
    plant = make_plant(p, circle_track, 0.05)
    assert plant.NAME == p.kind


def test_shipped_set_is_complete():
    assert {"audi_nominal", "audi_hidden", "bmw_commonroad", "barc_nominal"} <= {
        p.stem for p in (configs_dir() / "plants").glob("*.toml")}
    hidden = load_plant("audi_hidden")
    assert {e.name for e in hidden.effects} >= {"downforce", "load_transfer", "combined_slip", "steering_lag"}
    assert not hidden.vehicle.effects  # the nominal vehicle does not know them


def test_bmw_nominal_is_the_commonroad_parameter_set(bmw):
    from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

    p = parameters_vehicle2()
    assert (bmw.mass, bmw.l_f, bmw.l_r, bmw.yaw_inertia) == pytest.approx((p.m, p.a, p.b, p.I_z))
    assert bmw.mu == pytest.approx(p.tire.p_dy1, rel=1e-4) and bmw.tire.c_front == pytest.approx(p.tire.p_cy1)
    # cornering stiffness per unit load equals the Pacejka K_y / F_z = |p_ky1|
    assert bmw.mu * bmw.tire.b_front * bmw.tire.c_front == pytest.approx(abs(p.tire.p_ky1), rel=1e-4)


def _vehicle_text(**replace: str) -> str:
    text = (configs_dir() / "vehicles" / "audi_tt_cup.toml").read_text()
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    return text


def test_unknown_key_error_names_the_toml_path(tmp_path):
    f = tmp_path / "car.toml"
    f.write_text(_vehicle_text(**{"b_front = 10.0": "b_frnt = 10.0"}))
    with pytest.raises(ConfigError) as e:
        load_vehicle(str(f))
    msg = str(e.value)
    assert str(f) in msg and "tire.b_frnt: unknown key" in msg and "\n" not in msg


def test_missing_required_key(tmp_path):
    f = tmp_path / "car.toml"
    f.write_text(_vehicle_text(**{"mass = 1161.25\n": ""}))
    with pytest.raises(ConfigError, match=r"car.toml: mass: required key missing"):
        load_vehicle(str(f))


def test_out_of_range_and_wrong_type(tmp_path):
    f = tmp_path / "car.toml"
    f.write_text(_vehicle_text(**{"mu = 1.5": "mu = -1.5"}))
    with pytest.raises(ConfigError, match=r"mu: Input should be greater than 0"):
        load_vehicle(str(f))
    f.write_text(_vehicle_text(**{"mu = 1.5": 'mu = "high"'}))
    with pytest.raises(ConfigError, match=r"\bmu\b"):
        load_vehicle(str(f))


def test_bad_effect_in_a_plant_file_names_the_effect(tmp_path):
    """The configuration layer reads the structure; the model layer's loaders check the effects
    against the catalogue when the file is loaded for use (issue 40: no config <-> model cycle)."""
    from gprace.model import load_plant

    f = tmp_path / "plant.toml"
    f.write_text('vehicle = "audi_tt_cup"\n[[effects]]\nname = "downforce"\nc_l = 1.0\n[[effects]]\nname = "aero_dreg"\n')
    with pytest.raises(ConfigError, match=r"plant.toml: effects.1: unknown effect 'aero_dreg'; catalogue: aero_drag"):
        load_plant(str(f))
    f.write_text('vehicle = "audi_tt_cup"\n[[effects]]\nname = "downforce"\nc_lift = 1.0\n')
    with pytest.raises(ConfigError, match=r"effects.0: effect 'downforce': unknown parameter\(s\) c_lift; valid: c_l, balance"):
        load_plant(str(f))
    f.write_text('vehicle = "audi_tt_cup"\n[[effects]]\nname = "steering_lag"\ntau = 5.0\n')
    with pytest.raises(ConfigError, match=r"tau = 5.0 outside"):
        load_plant(str(f))


def test_plant_vehicle_include_is_relative_to_the_plant_file(tmp_path):
    (tmp_path / "cars").mkdir()
    (tmp_path / "cars" / "mine.toml").write_text(_vehicle_text(**{'name = "audi_tt_cup"': 'name = "mine"'}))
    f = tmp_path / "plant.toml"
    f.write_text('kind = "frenet"\nvehicle = "cars/mine.toml"\n[noise]\nv_x = 0.1\n')
    p = load_plant(str(f))
    assert p.vehicle.name == "mine" and p.noise.v_x == 0.1
    f.write_text('vehicle = "cars/nope.toml"\n')
    with pytest.raises(InputError, match="nope.toml: no such file"):
        load_plant(str(f))


def test_syntax_errors_missing_files_and_sections(tmp_path):
    f = tmp_path / "broken.toml"
    f.write_text("mass = = 3\n")
    with pytest.raises(ConfigError, match="broken.toml: not valid TOML"):
        read_toml(f)
    with pytest.raises(InputError, match="no such file"):
        load_vehicle(str(tmp_path / "absent.toml"))
    with pytest.raises(InputError, match="shipped: .*audi_tt_cup"):
        load_vehicle("audi_tt_cop")
    f.write_text("[other]\nx = 1\n")
    with pytest.raises(ConfigError, match=r"missing section \[vehicle\]"):
        load_toml(f, VehicleConfig, section="vehicle")


def test_toml_writer_round_trips_a_plant(tmp_path):
    p = load_plant("audi_hidden")
    f = tmp_path / "p.toml"
    f.write_text(p.to_toml())
    q = load_toml(f, PlantConfig)
    assert q == p and q.digest() == p.digest()
    data = {"a": 1, "b": {"c": [1.0, 2.0]}, "effects": [{"name": "drag", "params": {"k": 0.5}}]}
    assert tomllib.loads(dumps_toml(data)) == {"a": 1, "b": {"c": [1.0, 2.0]}, "effects": [{"name": "drag", "k": 0.5}]}


def test_configs_are_frozen(audi):
    with pytest.raises(Exception):
        audi.mass = 1.0
