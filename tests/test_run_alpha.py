"""``gprace run --alpha`` without ``--candidates``: the exploration grid comes from the GP's
training inputs in data units, for an exact and for a sparse model, and the lap completes.

The defect this guards against (issue 40): the grid was built from the exact backend's
normalised inputs (every feature spanning about -2..2 whatever its unit), and a sparse model,
which keeps no training inputs of its own, crashed.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gprace.cli import main

VALUES = 7  # candidate values per feature (run's grid)
QUANTILES = np.linspace(0.02, 0.98, VALUES)  # the typical values of each feature (Algorithm 1)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A plan of circle_100 and the tracking-GP training data of half a lap driven on it.

    The plant is the nominal car (audi_nominal), so the features the plan asks for lie inside
    the data and candidates fall within the exploration trust region. (On audi_hidden the plan
    of the nominal model asks for features about 7 standard deviations of the data away from
    what that car does, so a grid in data units rightly leaves nothing to explore.)"""
    from gprace.config import load_plant, load_vehicle
    from gprace.model import NominalModel
    from gprace.plan import curvature_plan
    from gprace.timetrial.drive import DriveSettings, drive
    from gprace.timetrial.learning import features
    from gprace.tracks import load_track

    d = tmp_path_factory.mktemp("run_alpha")
    tr, m = load_track("circle_100"), NominalModel(load_vehicle("audi_tt_cup"))
    plan = curvature_plan(tr, m, ds=6.0)
    plan.write(d / "plan.h5")
    run = drive(plan, load_plant("audi_nominal"), tr, m, DriveSettings(laps=0.5), seed=1)
    Z, Y = features(run, m, tr, "tracking", feature_set="paper")
    return d, Z[::2], Y[::2]


@pytest.mark.parametrize("backend,settings", [("exact", {}), ("sparse", {"n_inducing": 30, "max_iter": 60})])
def test_run_alpha_explores_on_a_grid_in_data_units(trained, backend, settings, monkeypatch, capsys):
    from gprace.gp import make_gp
    from gprace.timetrial import drive as drive_module
    from gprace.timetrial.learning import save_predictor

    d, Z, Y = trained
    gp = make_gp(backend, seed=0, **settings).fit(Z, Y)
    model = save_predictor(d / f"{backend}.h5", gp, "tracking", feature_set="paper")
    seen = {}
    real_drive = drive_module.drive

    def spy(*args, **kw):  # the real drive; keeps the grid run built
        seen["grid"] = kw.get("grid")
        return real_drive(*args, **kw)

    monkeypatch.setattr(drive_module, "drive", spy)
    code = main(["run", "--plan", str(d / "plan.h5"), "--plant", "audi_nominal", "--model", str(model),
                 "--alpha", "0.5", "-o", str(d / f"run_{backend}.h5"), "--json"])
    out = capsys.readouterr().out
    assert code == 0, out
    res = json.loads(out)

    g = seen["grid"]
    assert g.Z.shape == (VALUES ** Z.shape[1], Z.shape[1])
    # each feature's candidate values are the quantiles of the training inputs, in their units
    for j in range(Z.shape[1]):
        np.testing.assert_allclose(np.unique(g.Z[:, j]), np.unique(np.quantile(Z[:, j], QUANTILES)), rtol=1e-12)
    np.testing.assert_allclose(g.scale, Z.std(axis=0), rtol=1e-12)
    # the variances are the model's own at the candidates (S-weighted, so positive somewhere)
    assert np.all(np.isfinite(g.v)) and g.v.max() > 0

    # the lap completes, and the exploration acted (candidates lie near the features driven)
    assert res["completed"] and math.isfinite(res["lap_time"]), res
    from gprace.io.runs import read_run

    explored = read_run(d / f"run_{backend}.h5").data["explore"]
    assert explored.sum() > 0


def test_run_alpha_with_a_model_without_training_inputs_is_one_line(trained, tmp_path, capsys):
    """A model file from before the training inputs were stored: exit 2, one line, nothing written."""
    from gprace.gp import make_gp
    from gprace.gp.base import TRAIN_INPUTS
    from gprace.io.artifacts import read_artifact, write_artifact
    from gprace.timetrial.learning import save_predictor

    d, Z, Y = trained
    path = save_predictor(tmp_path / "m.h5", make_gp("exact", optimize=False).fit(Z[:40], Y[:40]), "tracking",
                          feature_set="paper")
    art = read_artifact(path, "gp_model")
    del art.arrays[TRAIN_INPUTS]
    write_artifact(tmp_path / "old.h5", art)
    out = tmp_path / "r.h5"
    code = main(["run", "--plan", str(d / "plan.h5"), "--plant", "audi_nominal", "--model", str(tmp_path / "old.h5"),
                 "--alpha", "0.5", "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "training inputs" in err[0], err
    assert not out.exists()
