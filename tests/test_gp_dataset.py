"""One GP dataset layout, one reader and one writer (issue 40): the head-to-head's and the loops'
datasets are ``gprace.gp.dataset`` datasets, and the files of the layouts before it still read,
with the same points and names the report used to take from them."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.errors import InputError
from gprace.gp.dataset import GPDataset, is_dataset, loop_dataset, read_dataset, write_dataset
from gprace.gp.features import DYN_OUTPUTS, dyn_feature_set
from gprace.h2h.predictors import FEATURES, OUTPUTS
from gprace.io.artifacts import Artifact, read_artifact, write_artifact
from gprace.report.inspect import describe


@pytest.fixture
def points():
    rng = np.random.default_rng(4)
    return rng.normal(size=(40, len(FEATURES))), rng.normal(size=(40, len(OUTPUTS))), np.repeat(np.arange(4), 10)


def test_the_head_to_head_writes_the_one_layout(points, tmp_path):
    from gprace.h2h.protocol import data

    Z, Y, run = points
    p = data._write_dataset(tmp_path / "d.h5", Z, Y, run, {"tasks": ["a"]}, {"runs": 4, "source": "collect"})
    art = read_artifact(p)
    assert art.kind == "dataset" and "inputs" not in art.attrs
    ds = read_dataset(p)
    assert ds.feature_map == "opponent" and ds.input_names == list(FEATURES) and ds.output_names == list(OUTPUTS)
    np.testing.assert_array_equal(ds.Z, Z)
    np.testing.assert_array_equal(ds.Y, Y)
    np.testing.assert_array_equal(ds.extra["run"], run)
    assert ds.attrs["runs"] == 4 and ds.attrs["source"] == "collect" and ds.attrs["n"] == 40
    Zh, Yh = data.read_dataset(p)
    np.testing.assert_array_equal(Zh, Z)
    np.testing.assert_array_equal(Yh, Y)


def test_an_old_head_to_head_dataset_still_reads(points, tmp_path):
    """The layout of before issue 40: kind h2h_dataset, names in ``inputs``/``outputs``."""
    from gprace.h2h.protocol import data

    Z, Y, run = points
    p = write_artifact(tmp_path / "old.h5", Artifact("h2h_dataset", arrays={"Z": Z, "Y": Y, "run": run},
                                                     attrs={"runs": 4, "source": "explore", "inputs": list(FEATURES),
                                                            "outputs": list(OUTPUTS), "n": 40}))
    assert is_dataset(p)
    ds = read_dataset(p)
    assert ds.feature_map == "opponent" and ds.input_names == list(FEATURES) and ds.output_names == list(OUTPUTS)
    assert "inputs" not in ds.attrs and ds.attrs["source"] == "explore"
    np.testing.assert_array_equal(data.read_dataset(p)[0], Z)
    res = describe(p)["results"]  # what `gprace show` printed from it before: same names and points
    assert res["points"] == 40 and res["inputs"] == list(FEATURES) and res["outputs"] == list(OUTPUTS)
    np.testing.assert_allclose(res["output_std"], np.round(Y.std(axis=0), 6))


def test_an_old_loop_dataset_without_names_still_reads(tmp_path):
    """iterate's and learn's datasets of before: no names, the GP in ``gp``."""
    rng = np.random.default_rng(1)
    Z, Y = rng.normal(size=(12, 3)), rng.normal(size=(12, 2))
    p = write_artifact(tmp_path / "data_tracking.h5", Artifact("dataset", {"Z": Z, "Y": Y},
                                                               {"n_seen": 30, "gp": "tracking", "selection": "diverse"}))
    ds = read_dataset(p)
    assert ds.feature_map == "tracking" and ds.input_names == ["z0", "z1", "z2"] and ds.output_names == ["y0", "y1"]
    assert ds.n_seen == 30
    res = describe(p)["results"]
    assert res["inputs"] == ["z0", "z1", "z2"] and res["outputs"] == ["y0", "y1"] and res["selection"] == "diverse"


@pytest.mark.parametrize("kind, features", [("tracking", "paper"), ("planning", "full")])
def test_a_loop_dataset_names_its_feature_set(kind, features, tmp_path):
    rng = np.random.default_rng(2)
    d = len(dyn_feature_set(features))
    Z, Y = rng.normal(size=(9, d)), rng.normal(size=(9, 2))
    new = rng.normal(size=(5, d))
    p = write_dataset(tmp_path / "d.h5", loop_dataset(kind, features, Z, Y, {"n_seen": 14}, {"Z_new": new}))
    ds = read_dataset(p)
    assert ds.feature_map == kind and ds.input_names == list(dyn_feature_set(features))
    assert ds.output_names == list(DYN_OUTPUTS[kind]) and ds.n_seen == 14
    np.testing.assert_array_equal(ds.extra["Z_new"], new)
    assert describe(p)["results"]["inputs"] == list(dyn_feature_set(features))


def test_the_head_to_head_refuses_another_gps_dataset(tmp_path):
    from gprace.h2h.protocol import data

    rng = np.random.default_rng(3)
    p = write_dataset(tmp_path / "t.h5", GPDataset(rng.normal(size=(6, 3)), rng.normal(size=(6, 2)), "tracking",
                                                   ["v_y", "yaw_rate", "delta"], ["v_y", "yaw_rate"]))
    with pytest.raises(InputError, match="'tracking' GP.*'opponent'"):
        data.read_dataset(p)
