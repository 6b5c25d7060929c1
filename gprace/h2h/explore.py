"""Active exploration of the opponent's reactions (paper "Active Exploration and EV Limitations").

Candidates differ from the current GP input only in the two features the ego controls, the lateral
gap ``e_y_ego - e_y_opp`` and the longitudinal gap ``s_opp - s_ego`` (a grid of typical values of the
training data); everything the ego cannot impose (opponent heading, speed, curvature) stays at its
current value, so the variance of each candidate is evaluated at run time with one GP call.
Algorithm 1 (:func:`gprace.explore.algorithm.select_target`) ranks them by weighted variance and
by distance to the current configuration ``z_tilde``.

Stalemate: when the relative configuration changes by less than ``stalemate_tol`` per step for
``stalemate_steps`` consecutive steps (the opponent mirrors the ego), the distance ranking is
reversed once (the farthest configuration is preferred) and that target is held for ``hold_steps``.

The ego's reference for J_expl at stage k: ``s_ref = s_opp,k - gap_s*``, ``e_y,ref = e_y_opp,k +
gap_ey*`` (clipped inside the track), ``v_ref`` = the ego's current speed; the opponent's
predicted states come from the predictor.
"""

from __future__ import annotations

import numpy as np

from gprace.explore.algorithm import CandidateGrid, candidate_grid, select_target, weighted_variance
from gprace.h2h.predictors import CONTROLLABLE, OUTPUTS, features


class Explorer:
    def __init__(self, gp, grid: np.ndarray, scale: np.ndarray, alpha: float, y_std: np.ndarray,
                 stalemate_steps: int = 8, stalemate_tol: float = 0.02, hold_steps: int = 5) -> None:
        self.gp = gp
        self.grid = np.asarray(grid, float)
        self.scale = np.maximum(np.asarray(scale, float), 1e-6)
        self.alpha = alpha
        # S weights: e_y and s outputs, each normalised by its training spread
        w = np.zeros(len(OUTPUTS))
        w[0], w[1] = 1.0 / y_std[0] ** 4, 1.0 / y_std[1] ** 4
        self.S = w
        self.stalemate_steps, self.stalemate_tol, self.hold_steps = stalemate_steps, stalemate_tol, hold_steps
        self.last: np.ndarray | None = None
        self.still = 0
        self.hold = 0
        self.target: np.ndarray | None = None
        self.stalemates = 0

    @classmethod
    def from_data(cls, gp, Z: np.ndarray, Y: np.ndarray, alpha: float, n_values: int = 7, **kw) -> "Explorer":
        C = np.asarray(Z, float)[:, list(CONTROLLABLE)]
        grid = candidate_grid(C, n_values)
        return cls(gp, grid, C.std(axis=0), alpha, np.maximum(np.asarray(Y, float).std(axis=0), 1e-9), **kw)

    def target_gaps(self, track, ego: np.ndarray, opp: np.ndarray) -> np.ndarray:
        """The (gap_ey, gap_s) target for this step."""
        z = features(track, ego, opp)[0]
        zc = z[list(CONTROLLABLE)]
        moved = np.inf if self.last is None else float(np.max(np.abs(zc - self.last)))
        self.last = zc
        self.still = self.still + 1 if moved < self.stalemate_tol else 0
        if self.hold > 0 and self.target is not None:
            self.hold -= 1
            return self.target
        reverse = self.still >= self.stalemate_steps
        Zc = np.tile(z, (len(self.grid), 1))
        Zc[:, list(CONTROLLABLE)] = self.grid
        _, var = self.gp.predict(Zc)
        g = CandidateGrid(self.grid, weighted_variance(var, self.S), self.scale)
        i = select_target(g, zc, self.alpha, reverse_distance=reverse)
        self.target = self.grid[i]
        if reverse:
            self.stalemates += 1
            self.still = 0
            self.hold = self.hold_steps
        return self.target

    def reference(self, track, ego: np.ndarray, opp_mean: np.ndarray, margin: float) -> np.ndarray:
        """(N, 3) reference s, e_y, v_x from the target gaps and the predicted opponent (N, 6)."""
        gap_ey, gap_s = self.target
        s_o, ey_o = opp_mean[:, 5], opp_mean[:, 4]
        ey = np.clip(ey_o + gap_ey, -track.width_right(s_o) + margin, track.width_left(s_o) - margin)
        return np.column_stack([s_o - gap_s, ey, np.full(len(s_o), ego[0])])
