"""Artifacts (HDF5) and runs (HDF5, CSV): round trips and every kind of bad file."""

from __future__ import annotations

import numpy as np
import pytest

from gprace import __version__
from gprace.errors import ArtifactError, InputError
from gprace.io import RUN_COLUMNS, Artifact, Run, read_artifact, read_run, write_artifact, write_run, write_run_csv


def _run(n: int = 50, seed: int = 0) -> Run:
    rng = np.random.default_rng(seed)
    t = 0.05 * np.arange(n)
    data = {
        "t": t, "s": 20.0 * t, "e_y": rng.normal(0, 0.5, n), "e_psi": rng.normal(0, 0.02, n),
        "v_x": 20.0 + rng.normal(0, 1, n), "v_y": rng.normal(0, 0.3, n), "yaw_rate": rng.normal(0, 0.2, n),
        "delta": rng.normal(0, 0.03, n), "a_x": rng.normal(0, 2, n), "kappa": np.full(n, 0.01),
        "lap": np.zeros(n), "border_hit": (rng.random(n) < 0.1).astype(float),
    }
    return Run(data, {"vehicle_toml": 'name = "x"\n', "track": "gprace_ring", "dt": 0.05, "plant": "frenet"})


def test_run_hdf5_round_trip(tmp_path):
    run = _run()
    p = write_run(run, tmp_path / "run.h5", config_hash="abc123", seed=7)
    back = read_run(p)
    assert set(back.data) == set(run.data)
    for k in run.data:
        np.testing.assert_array_equal(back[k], run[k])
    assert back.meta == run.meta
    art = read_artifact(p, "run")
    assert (art.config_hash, art.seed, art.gprace_version, art.schema) == ("abc123", 7, __version__, 1)
    assert art.created.endswith("+00:00")
    np.testing.assert_array_equal(back.states(), np.column_stack([run[c] for c in ("v_x", "v_y", "yaw_rate", "e_psi", "e_y", "s")]))


def test_run_csv_round_trip_keeps_extra_columns_in_any_order(tmp_path):
    run = _run()
    p = write_run_csv(run, tmp_path / "run.csv")
    back = read_run(p)
    for k in run.data:
        np.testing.assert_allclose(back[k], run[k], rtol=1e-9, atol=1e-12)
    # any column order, surrounding spaces in the header
    cols = list(reversed(list(run.data)))
    lines = [" , ".join(cols)] + [",".join(repr(float(run[c][i])) for c in cols) for i in range(run.n)]
    q = tmp_path / "rev.csv"
    q.write_text("\n".join(lines) + "\n")
    np.testing.assert_array_equal(read_run(q)["v_x"], run["v_x"])


def test_artifact_round_trip_with_groups_and_structured_attrs(tmp_path):
    art = Artifact(
        "model",
        arrays={"alpha": np.arange(6.0).reshape(3, 2), "ids": np.array([1, 2, 3])},
        attrs={"kernel": "se", "lengthscales": [1.0, 2.0], "options": {"a": 1, "b": [1, "x"]}, "none": None, "n": 3},
        groups={"vy": {"X": np.eye(3)}, "r": {"X": np.ones((2, 2))}},
        config_hash="h", seed=3,
    )
    p = write_artifact(tmp_path / "sub" / "m.h5", art)
    back = read_artifact(p, ("model", "dataset"))
    np.testing.assert_array_equal(back.arrays["alpha"], art.arrays["alpha"])
    np.testing.assert_array_equal(back.groups["vy"]["X"], np.eye(3))
    assert back.attrs["options"] == {"a": 1, "b": [1, "x"]} and back.attrs["none"] is None
    assert back.attrs["kernel"] == "se" and back.attrs["n"] == 3
    np.testing.assert_array_equal(back.attrs["lengthscales"], [1.0, 2.0])
    assert not list(p.parent.glob(".*tmp"))  # atomic write leaves no temporary file


def test_wrong_artifact_kind(tmp_path):
    p = write_artifact(tmp_path / "plan.h5", Artifact("plan", arrays={"s": np.arange(3.0)}))
    with pytest.raises(ArtifactError, match=r"plan.h5: is a 'plan' artifact, expected 'run'"):
        read_run(p)


def test_truncated_and_foreign_hdf5(tmp_path):
    p = write_run(_run(), tmp_path / "run.h5")
    blob = p.read_bytes()
    p.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(ArtifactError, match="not an HDF5 file"):
        read_run(p)
    import h5py

    q = tmp_path / "foreign.h5"
    with h5py.File(q, "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(ArtifactError, match="not a gprace artifact"):
        read_artifact(q)
    with pytest.raises(InputError, match="no such file"):
        read_run(tmp_path / "absent.h5")


def _csv(tmp_path, run: Run, edit=None, name="bad.csv") -> str:
    p = write_run_csv(run, tmp_path / name)
    if edit is not None:
        p.write_text(edit(p.read_text()))
    return p


@pytest.mark.parametrize("col", ["t", "v_y", "kappa"])
def test_csv_missing_column_is_named(tmp_path, col):
    run = _run()
    data = {k: v for k, v in run.data.items()}
    text_cols = [c for c in data if c != col]
    p = tmp_path / "m.csv"
    p.write_text(",".join(text_cols) + "\n" + "\n".join(",".join(str(data[c][i]) for c in text_cols) for i in range(run.n)))
    with pytest.raises(InputError, match=rf"m.csv: missing column {col}$"):
        read_run(p)


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_csv_non_finite_value_names_column_and_row(tmp_path, bad):
    run = _run()
    run.data["yaw_rate"][6] = float(bad)
    p = tmp_path / "nf.csv"
    np.savetxt(p, np.column_stack([run.data[c] for c in run.data]), delimiter=",", header=",".join(run.data), comments="")
    with pytest.raises(InputError, match=rf"column 'yaw_rate' has a non-finite value \({bad}\) at row 7"):
        read_run(p)


def test_csv_speeds_in_kmh_fail_the_plausibility_check(tmp_path):
    run = _run()
    run.data["v_x"] = run.data["v_x"] * 3.6 * 2  # 144 km/h written as a number of km/h
    p = tmp_path / "kmh.csv"
    np.savetxt(p, np.column_stack([run.data[c] for c in run.data]), delimiter=",", header=",".join(run.data), comments="")
    with pytest.raises(InputError, match=r"column 'v_x' .* (implausible in SI units|times the speed along the path).*km/h"):
        read_run(p)


def test_csv_empty_header_only_truncated_and_garbage(tmp_path):
    run = _run()
    p = tmp_path / "e.csv"
    p.write_text("")
    with pytest.raises(InputError, match="e.csv: empty file"):
        read_run(p)
    p.write_text(",".join(RUN_COLUMNS) + "\n")
    with pytest.raises(InputError, match="0 sample"):
        read_run(p)
    q = _csv(tmp_path, run, lambda s: s[: len(s) - 25].rstrip("\n"), name="trunc.csv")
    with pytest.raises(InputError, match=r"trunc.csv: row 50 \(line 51\) has \d+ fields, header has 12 \(truncated file\?\)"):
        read_run(q)
    q = _csv(tmp_path, run, lambda s: s.replace("\n0.05,", "\n0.05x,", 1), name="garbage.csv")
    with pytest.raises(InputError, match=r"column 't' row 2 \(line 3\): '0.05x' is not a number"):
        read_run(q)
    b = tmp_path / "bin.csv"
    b.write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(InputError, match="not a text CSV"):
        read_run(b)


def test_time_must_increase(tmp_path):
    run = _run()
    run.data["t"][10] = run.data["t"][9]
    with pytest.raises(InputError, match="'t' is not strictly increasing at row 11"):
        Run(run.data, {}, "mem")


def test_simulated_run_round_trips(tmp_path, audi):
    from conftest import make_circle
    from gprace.config import PlantConfig, SimulateConfig
    from gprace.sim import simulate

    run = simulate(PlantConfig(vehicle=audi), make_circle(), SimulateConfig(laps=0.05))
    back = read_run(write_run(run, tmp_path / "sim.h5"))
    assert back.vehicle() == audi and back.dt == 0.05
    back_csv = read_run(write_run(run, tmp_path / "sim.csv"))
    np.testing.assert_allclose(back_csv.states(), run.states(), rtol=1e-9)


def test_artifact_array_names_with_slashes_round_trip(tmp_path):
    """h5py stores 'a/b' as a nested group; reading must give the same flat names back."""
    arrays = {"hyper/length_scales": np.array([0.5, 2.0]), "hyper/noise": np.array(1e-3), "Z": np.eye(2)}
    path = write_artifact(tmp_path / "m.h5", Artifact("gp_model", arrays=arrays, groups={"g": {"x/y": np.ones(3)}}))
    back = read_artifact(path, "gp_model")
    assert set(back.arrays) == set(arrays)
    for k, v in arrays.items():
        np.testing.assert_array_equal(back.arrays[k], v)
    np.testing.assert_array_equal(back.groups["g"]["x/y"], np.ones(3))
