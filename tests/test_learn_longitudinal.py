"""Issue 39: a log without an a_x column (the INI F1TENTH runs) gets the body's longitudinal
acceleration ``dv_x/dt - r v_y``, and learn reads it with the model's kinematic v_x equation
(``v_x' = a_x + r v_y``), so the nominal model predicts v_x from it without counting ``r v_y``
twice; a gprace run (commanded a_x) keeps the force model; recordings of both kinds together are
refused.

The logs are synthetic and kinematically exact (a car on a path of the track with a speed that
changes and a body slip of up to 0.15 rad, so ``r v_y`` is large), a family over seeds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gprace.errors import InputError

DT = 0.02
TRACK = "gprace_ring"


def drive_log(seed: int, seconds: float = 12.0) -> dict:
    from gprace.tracks import load_track

    rng = np.random.default_rng(seed)
    track = load_track(TRACK)
    t = DT * np.arange(int(round(seconds / DT)) + 1)
    V = rng.uniform(15.0, 30.0) + rng.uniform(1.0, 2.0) * np.sin(2 * np.pi * t / rng.uniform(6.0, 10.0))
    s = rng.uniform(0.0, track.length) + np.concatenate([[0.0], np.cumsum(0.5 * (V[1:] + V[:-1]) * DT)])
    e_y = 1.5 * np.sin(2 * np.pi * t / rng.uniform(2.0, 4.0))
    x, y = track.to_global(np.mod(s, track.length), e_y)
    heading = np.unwrap(np.arctan2(np.gradient(y, t), np.gradient(x, t)))
    beta = 0.15 * np.sin(2 * np.pi * t / rng.uniform(1.5, 3.0))
    yaw = heading - beta
    r = np.gradient(yaw, t)
    delta = np.arctan(2.5 * np.gradient(heading, t) / V)
    return {"t": t, "x": x, "y": y, "yaw": np.angle(np.exp(1j * yaw)), "v_x": V * np.cos(beta), "v_y": V * np.sin(beta),
            "yaw_rate": r, "delta": delta}


def _write(cols: dict, path: Path) -> Path:
    np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="", fmt="%.12g")
    return path


@pytest.mark.parametrize("seed", (0, 1, 2))
def test_a_derived_a_x_drives_v_x_as_the_kinematic_model_reads_it(tmp_path, seed):
    from gprace.config import load_vehicle
    from gprace.ingest.importer import import_recording
    from gprace.learn.workflow import longitudinal_mode
    from gprace.model import NominalModel

    run, trk = import_recording(_write(drive_log(seed), tmp_path / "log.csv"), track=TRACK, dt=0.05)
    assert run.meta["inputs"]["a_x"] == "derived"
    mode = longitudinal_mode([run])
    assert mode == "kinematic"
    X, U = run.states(), run.inputs()
    # the body-frame relation the importer keeps: a_x = dv_x/dt - r v_y
    rv = X[:, 2] * X[:, 1]
    dv = np.gradient(X[:, 0], run["t"])
    inner = slice(2, -2)
    np.testing.assert_allclose(U[inner, 1], (dv - rv)[inner], atol=1e-9)
    assert np.median(np.abs(rv)) > 0.3  # r v_y matters in these logs
    # one step of the model from the recorded state and inputs: v_x as the log has it, within a
    # fraction of the error of dv_x/dt as the input (r v_y counted twice: dt r v_y a step)
    model = NominalModel(load_vehicle("audi_tt_cup"), longitudinal=mode)

    def step_error(U):
        return np.abs(model.rk4(X[:-1], U[:-1], trk.kappa, run.dt)[:, 0] - X[1:, 0])[inner]

    double = U.copy()
    double[:, 1] = U[:, 1] + rv
    assert np.median(step_error(U)) < 0.5 * np.median(step_error(double))
    assert np.median(step_error(double)) > 0.5 * run.dt * np.median(np.abs(rv))


def test_commanded_and_derived_a_x_are_not_learned_together(tmp_path):
    from types import SimpleNamespace

    from gprace.learn.workflow import longitudinal_mode

    def run(kind):  # what longitudinal_mode reads of a run: its meta
        return SimpleNamespace(meta={"inputs": {"delta": "commanded", "a_x": kind}} if kind else {})

    assert longitudinal_mode([run(None), run("commanded")]) == "force"  # gprace runs: the paper's force model
    assert longitudinal_mode([run("measured"), run("derived")]) == "kinematic"
    with pytest.raises(InputError, match="mix a commanded a_x"):
        longitudinal_mode([run("commanded"), run("derived")])
