"""``gprace select-data``, ``retrain`` and ``evaluate gp`` end to end on synthetic recordings."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_gp_features import drive

from gprace.cli import main
from gprace.config import EffectConfig, load_vehicle
from gprace.io.runs import write_run, write_run_csv
from gprace.model import NominalModel


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Three recordings of a car with downforce its nominal model (audi_tt_cup) leaves out (the
    third without sensor noise, so that GP errors on it measure the learned function)."""
    d = tmp_path_factory.mktemp("gp_runs")
    nominal = load_vehicle("audi_tt_cup")
    true = NominalModel(nominal, [EffectConfig(name="downforce", params={"c_l": 3.0, "balance": 0.45})])
    paths = []
    rng = np.random.default_rng(0)
    for seed in range(3):
        run = drive(true, n=300, seed=seed)
        for col, std in (("v_y", 0.004), ("yaw_rate", 0.002)):  # sensor noise (not on the test run)
            run.data[col] = run.data[col] + (std * rng.standard_normal(run.n) if seed < 2 else 0.0)
        run.meta["vehicle_toml"] = nominal.to_toml()  # recorded against the nominal model
        paths.append(write_run(run, d / f"run{seed}.h5"))
    run.meta.pop("vehicle_toml")
    paths.append(write_run_csv(run, d / "bare.csv"))  # a CSV recording carries no vehicle
    return paths


def _json(capsys, argv):
    code = main(argv + ["--json"])
    out = capsys.readouterr().out
    assert code == 0, out
    return json.loads(out)


def test_select_retrain_evaluate(runs, tmp_path, capsys):
    data = tmp_path / "data.h5"
    res = _json(capsys, ["select-data", str(runs[0]), str(runs[1]), "--gp", "tracking", "--max-points", "120",
                         "-o", str(data)])
    assert res["points"] == 120 and res["new_samples"] == 598
    assert res["stats"]["replaced"] > 0 and "quick fit" in res["stats"]["hyperparameters_from"]
    # continue from the dataset: same hyperparameters, samples seen accumulate
    data2 = tmp_path / "data2.h5"
    res2 = _json(capsys, ["select-data", str(data), str(runs[2]), "--max-points", "120", "-o", str(data2)])
    assert res2["n_seen"] == 598 + 299 and res2["continued_from"] == str(data)
    assert "dataset" in res2["stats"]["hyperparameters_from"]

    for backend, extra in (("exact", []), ("sparse", ["--opt", "n_inducing=60"])):
        model = tmp_path / f"{backend}.h5"
        fit = _json(capsys, ["retrain", str(data), "--backend", backend, "-o", str(model)] + extra)
        assert fit["points"] == 120 and set(fit["outputs"]) == {"v_y", "yaw_rate"}
        ev = _json(capsys, ["evaluate", "gp", str(model), str(runs[2])])
        for name, m in ev["outputs"].items():  # the GP removes most of the model error
            assert m["rmse"] < m["nominal_rmse"] and m["mae"] < 0.5 * m["nominal_rmse"], (backend, name, m)
            assert m["inside_95"] > 0.8
        assert ev["outputs"]["v_y"]["rmse"] < 0.5 * ev["outputs"]["v_y"]["nominal_rmse"]
    # human-readable output too
    assert main(["evaluate", "gp", str(tmp_path / "exact.h5"), str(runs[2])]) == 0
    assert "nominal RMSE" in capsys.readouterr().out


def test_random_selection_and_planning(runs, tmp_path, capsys):
    data = tmp_path / "rand.h5"
    res = _json(capsys, ["select-data", str(runs[0]), "--gp", "planning", "--selection", "random",
                         "--max-points", "50", "-o", str(data)])
    assert res["points"] == 50
    res = _json(capsys, ["select-data", str(data), str(runs[1]), "--gp", "planning", "--selection", "random",
                         "--max-points", "50", "-o", str(tmp_path / "rand2.h5")])
    assert res["points"] == 50 and res["n_seen"] == 598
    from gprace.gp.dataset import read_dataset

    ds = read_dataset(tmp_path / "rand2.h5")
    assert ds.feature_map == "planning" and ds.output_names == ["dv_y_dt", "dyaw_rate_dt"]
    assert ds.input_names == ["v_y", "yaw_rate", "delta"]


def test_vehicle_option_for_bare_csv(runs, tmp_path, capsys):
    out = tmp_path / "d.h5"
    assert main(["select-data", str(runs[3]), "--max-points", "40", "-o", str(out)]) == 2
    assert "--vehicle" in capsys.readouterr().err
    assert main(["select-data", str(runs[3]), "--max-points", "40", "--selection", "random", "--vehicle", "audi_tt_cup",
                 "-o", str(out)]) == 0


def test_bad_inputs(runs, tmp_path, capsys):
    data = tmp_path / "d.h5"
    assert main(["select-data", str(runs[0]), "--max-points", "40", "--selection", "random", "-o", str(data)]) == 0
    capsys.readouterr()
    # a dataset is not a model
    assert main(["evaluate", "gp", str(data), str(runs[0])]) == 2
    assert "expected 'gp_model'" in capsys.readouterr().err
    # unknown backend lists the available ones
    assert main(["retrain", str(data), "--backend", "nope", "-o", str(tmp_path / "m.h5")]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and "exact" in err and "sparse" in err
    # a dataset of another feature map cannot be continued
    assert main(["select-data", str(data), str(runs[1]), "--gp", "planning", "-o", str(tmp_path / "x.h5")]) == 2
    assert "feature map" in capsys.readouterr().err
    # NaN in a CSV recording
    text = runs[3].read_text().splitlines()
    cols = text[1].split(",")
    cols[6] = "nan"
    text[1] = ",".join(cols)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(text) + "\n")
    assert main(["select-data", str(bad), "--vehicle", "audi_tt_cup", "-o", str(tmp_path / "y.h5")]) == 2
    assert "non-finite" in capsys.readouterr().err
    # unknown options
    assert main(["select-data", str(runs[0]), "--selection", "greedy", "-o", str(tmp_path / "z.h5")]) == 2
    assert "diverse, random" in capsys.readouterr().err
    assert main(["retrain", str(data), "--opt", "oops", "-o", str(tmp_path / "m.h5")]) == 2
    # a constant dataset does not crash the fit
    from gprace.gp.dataset import GPDataset, write_dataset

    const = write_dataset(tmp_path / "c.h5", GPDataset(np.random.default_rng(0).normal(size=(30, 3)), np.ones((30, 2)),
                                                         "tracking", ["v_y", "yaw_rate", "delta"], ["v_y", "yaw_rate"]))
    assert main(["retrain", str(const), "-o", str(tmp_path / "c_model.h5")]) == 0
