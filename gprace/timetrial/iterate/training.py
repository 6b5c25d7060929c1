"""Step (2) of an iteration: both GPs refitted on their dictionaries and calibrated, and the
exploration candidates (Algorithm 1) where the iteration explores."""

from __future__ import annotations

import numpy as np

from gprace.timetrial.iterate.chain import _Chain


def _retrain(c: _Chain, i: int) -> None:
    """(2) Both GPs on their dictionaries, calibrated; the exploration candidates of the tracking GP
    (only where the iteration explores: alpha > 0)."""
    from gprace.gp.dataset import read_dataset
    from gprace.io.artifacts import Artifact, write_artifact
    from gprace.timetrial import learning as L

    di = c.dir(i)
    for kind in ("tracking", "planning"):
        a = read_dataset(di / f"data_{kind}.h5")
        hyper = L.load_predictor(c.folder / f"hyper_{kind}.h5", kind).gp
        gp = L.refit_fixed(hyper, a.Z, a.Y)
        L.save_predictor(di / f"gp_{kind}.h5", gp, kind, {"iteration": i, "trial": c.trial}, c.st.features,
                         L.calibrate(gp, calib=c.calib[kind]))
        if kind == "tracking" and c.st.alpha(i) > 0:  # alpha = 0 never uses the candidates (issue 37)
            grid = make_grid(gp, a.Z, c.mpc, c.st.grid_values)
            write_artifact(di / "candidates.h5", Artifact("candidates", {"Z": grid.Z, "v": grid.v, "scale": grid.scale}))


def make_grid(gp, Z: np.ndarray, mpc, n_values: int):
    """Algorithm 1's candidates from typical values of the data, with ``S``-weighted variances.

    ``S = diag(Q_vy, Q_r)``: the MPC's weights on the two compensated states.
    """
    from gprace.explore.algorithm import CandidateGrid, candidate_grid, weighted_variance

    C = candidate_grid(Z, n_values)
    _, var = gp.predict(C)
    S = np.array([mpc.weights.Q[1], mpc.weights.Q[2]])
    scale = np.maximum(Z.std(axis=0), 1e-9)
    return CandidateGrid(C, weighted_variance(var, S), scale)
