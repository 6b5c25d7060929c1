"""The CLI's one exit door: bad input -> exit 2, one line naming the culprit, no traceback."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.cli import main
from gprace.config import configs_dir
from gprace.io import read_run


def _err(capsys):
    out = capsys.readouterr()
    return out.out, out.err


def _one_line_error(capsys, *needles):
    out, err = _err(capsys)
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ") or "Error" in lines[0], err
    assert "Traceback" not in err + out
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("GPRACE_DEBUG", raising=False)


def test_missing_plant_file(capsys, tmp_path):
    assert main(["simulate", "--plant", str(tmp_path / "nope.toml"), "-o", str(tmp_path / "r.h5")]) == 2
    _one_line_error(capsys, "nope.toml", "no such file")


def test_bad_key_in_plant_file(capsys, tmp_path):
    f = tmp_path / "plant.toml"
    f.write_text('kind = "frenet"\nvehicle = "audi_tt_cup"\nsubstep = 4\n')
    assert main(["simulate", "--plant", str(f), "-o", str(tmp_path / "r.h5")]) == 2
    _one_line_error(capsys, "plant.toml", "substep: unknown key")


def test_bad_key_in_included_vehicle(capsys, tmp_path):
    text = (configs_dir() / "vehicles" / "audi_tt_cup.toml").read_text().replace("c_rear", "c_raer")
    (tmp_path / "car.toml").write_text(text)
    f = tmp_path / "plant.toml"
    f.write_text('vehicle = "car.toml"\n')
    assert main(["simulate", "--plant", str(f), "-o", str(tmp_path / "r.h5")]) == 2
    _one_line_error(capsys, "vehicle.tire.c_raer: unknown key")


def test_unknown_plant_kind_lists_the_valid_ones(capsys, tmp_path):
    f = tmp_path / "plant.toml"
    f.write_text('kind = "bicycle"\nvehicle = "audi_tt_cup"\n')
    assert main(["simulate", "--plant", str(f), "--track", "circle_100", "-o", str(tmp_path / "r.h5")]) == 2
    _one_line_error(capsys, "unknown plant 'bicycle'", "commonroad-std", "frenet")


def test_bad_effect_name(capsys, tmp_path):
    f = tmp_path / "plant.toml"
    f.write_text('vehicle = "audi_tt_cup"\n[[effects]]\nname = "downforse"\nc_l = 1\n')
    assert main(["simulate", "--plant", str(f), "-o", str(tmp_path / "r.h5")]) == 2
    _one_line_error(capsys, "effects.0", "unknown effect 'downforse'")


def test_invalid_toml(capsys, tmp_path):
    f = tmp_path / "plant.toml"
    f.write_text('vehicle = "audi_tt_cup\n')
    assert main(["simulate", "--plant", str(f), "-o", str(tmp_path / "r.h5")]) == 2
    _one_line_error(capsys, "plant.toml: not valid TOML")


def test_missing_track(capsys, tmp_path):
    assert main(["simulate", "--track", str(tmp_path / "t.csv"), "-o", str(tmp_path / "r.h5")]) == 2
    _one_line_error(capsys, "t.csv")


@pytest.mark.parametrize("opt,val", [("--dt", "-0.1"), ("--laps", "0"), ("--speed-scale", "3"), ("--weave", "-1"),
                                     ("--laps", "inf"), ("--dt", "nan")])
def test_bad_option_values(capsys, tmp_path, opt, val):
    """Named as the CLI spells the option (issue 38), infinite and NaN values too."""
    assert main(["simulate", opt, val, "--track", "circle_100", "-o", str(tmp_path / "r.h5")]) == 2
    _one_line_error(capsys, opt, val)


def test_usage_error_exits_2(capsys):
    assert main(["simulate", "--laps", "many"]) == 2
    out, err = _err(capsys)
    assert "Traceback" not in err and "Invalid value for '--laps'" in err


def test_simulate_end_to_end_writes_a_readable_run(capsys, tmp_path):
    h5, csv = tmp_path / "run.h5", tmp_path / "run.csv"
    rc = main(["simulate", "--plant", "audi_hidden", "--track", "circle_100", "--laps", "0.2", "--dt", "0.05",
               "--weave", "0.3", "--seed", "2", "-o", str(h5), "--csv", str(csv)])
    out, err = _err(capsys)
    assert rc == 0, err
    assert f"wrote {h5}" in out
    run = read_run(h5)
    assert run.meta["plant"] == "frenet" and run.meta["dt"] == 0.05 and run.meta["track"].endswith("circle_100.toml")
    assert run.vehicle().name == "audi_tt_cup" and not run.vehicle().effects
    assert run["s"][-1] > 0.19 * 628.0
    back = read_run(csv)
    np.testing.assert_allclose(back.states(), run.states(), rtol=1e-8, atol=1e-9)
    # reading it back through a command-line consumer path: a bad CSV is a one-line error
    csv.write_text(csv.read_text().replace("yaw_rate", "yawrate", 1))
    with pytest.raises(Exception, match="missing column yaw_rate"):
        read_run(csv)
