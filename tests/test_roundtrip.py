"""One verdict per drive (issue 36 item 7): a run ``gprace simulate`` wrote in the Frenet frame,
exported to the global frame by code of this test (the centre line sampled every 5 cm and
interpolated here; x = centre + e_y * normal, yaw = heading + e_psi; body velocities, yaw rate,
steering and a_x as recorded) and imported with the same track, is the same run; diagnose gives
both the same verdict and the same named effects."""

from __future__ import annotations

import json

import numpy as np
import pytest

from test_import import _cli
from shared_data import TUM_TRACKS

from gprace.io.runs import read_run
from gprace.tracks import load_track

TRACK = TUM_TRACKS / "Norisring.csv"
pytestmark = pytest.mark.skipif(not TRACK.exists(), reason="TUM racetrack database not available")
EPOCH = 1000.0

PLANT = """kind = "frenet"
vehicle = "audi_tt_cup"
substeps = 4
seed = 0

[noise]
v_x = 0.02
v_y = 0.01
yaw_rate = 0.005
e_psi = 0.002
e_y = 0.02
s = 0.05

[[effects]]
name = "road_bank"
angle = 0.1
s_start = 700.0
s_end = 1100.0
"""


def export_global(run, track) -> dict[str, np.ndarray]:
    """The run in the global frame, from the centre line's samples only (no Frenet code of gprace)."""
    smp = track.sample(0.05)
    L = track.length
    S = np.r_[smp.s, L]
    X, Y = np.r_[smp.x, smp.x[0]], np.r_[smp.y, smp.y[0]]
    H = np.unwrap(np.r_[smp.heading, smp.heading[0]])
    s = np.mod(run["s"], L)
    cx, cy, hd = np.interp(s, S, X), np.interp(s, S, Y), np.interp(s, S, H)
    return {"t": run["t"] + EPOCH, "x": cx - np.sin(hd) * run["e_y"], "y": cy + np.cos(hd) * run["e_y"],
            "yaw": hd + run["e_psi"], "v_x": run["v_x"], "v_y": run["v_y"], "yaw_rate": run["yaw_rate"],
            "delta": run["delta"], "a_x": run["a_x"]}


@pytest.fixture(scope="module")
def trip(tmp_path_factory):
    d = tmp_path_factory.mktemp("trip")
    (d / "plant.toml").write_text(PLANT)
    code, _, err = _cli("-q", "simulate", "--plant", d / "plant.toml", "--track", TRACK, "--laps", "1.6",
                        "--dt", "0.05", "--weave", "0.4", "-o", d / "sim.h5")
    assert code == 0, err
    sim = read_run(d / "sim.h5")
    cols = export_global(sim, load_track(TRACK))
    np.savetxt(d / "car.csv", np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="",
               fmt="%.12g")
    code, _, err = _cli("import", d / "car.csv", "--track", TRACK, "--dt", "0.05", "-o", d / "imp.h5")
    assert code == 0, err
    return d, sim, read_run(d / "imp.h5")


def test_the_imported_run_is_the_simulated_one(trip):
    """Measured: s 5e-6 m, e_y 3e-5 m, e_psi 2.5e-6 rad, kappa 3e-8 1/m, velocities 5e-11."""
    _, sim, imp = trip
    assert imp.n == sim.n and imp.meta["gaps"] == 0
    idx = np.rint((imp["t"] + imp.meta["t0"] - EPOCH) / 0.05).astype(int)
    assert np.array_equal(idx, np.arange(sim.n))
    L = imp.meta["track_length"]
    tol = {"s": 1e-3, "e_y": 1e-3, "e_psi": 1e-4, "kappa": 1e-6, "v_x": 1e-8, "v_y": 1e-8, "yaw_rate": 1e-8,
           "delta": 1e-8, "a_x": 1e-8}
    for c, t in tol.items():
        diff = imp[c] - sim[c][idx]
        if c == "s":
            diff = (diff + 0.5 * L) % L - 0.5 * L
        if c == "e_psi":
            diff = np.angle(np.exp(1j * diff))
        assert np.abs(diff).max() < t, (c, np.abs(diff).max())
    assert np.array_equal(imp["lap"], sim["lap"][idx])
    assert imp.inputs_kind == sim.inputs_kind == {"delta": "commanded", "a_x": "commanded"}


@pytest.mark.slow  # two diagnoses, ~40 s on a shared 2-core machine
def test_diagnose_names_the_same_effects_on_both(trip):
    d, _, _ = trip
    reports = []
    for f in ("sim.h5", "imp.h5"):
        code, out, err = _cli("-q", "diagnose", d / f, "--vehicle", "audi_tt_cup", "--json")
        assert code == 0, err
        reports.append(json.loads(out))
    a, b = reports
    assert a["verdict"] == b["verdict"] == "mismatch"
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]] == ["road_bank"]
    pa, pb = a["effects"][0]["parameters"], b["effects"][0]["parameters"]
    for k in ("angle", "s_start", "s_end"):
        assert abs(pa[k]["value"] - pb[k]["value"]) < 1e-3 * max(1.0, abs(pa[k]["value"]))
    assert abs(pa["angle"]["value"] - 0.1) < 0.02
