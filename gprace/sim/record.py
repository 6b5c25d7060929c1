"""Pieces shared by every closed loop that records a :class:`~gprace.io.runs.Run`
(``simulate``'s reference controller, the time trial's MPC): footprint border hits, the standard
run columns, lap times. All vectorised over the recorded samples.
"""

from __future__ import annotations

import numpy as np


def border_hits(track, X: np.ndarray, length: float, width: float) -> np.ndarray:
    """(n,) bool: the car's rectangular footprint crosses a track edge at true Frenet states X (n, 6).

    Half lateral extent of the footprint: ``|l/2 sin e_psi| + |w/2 cos e_psi|``.
    """
    X = np.atleast_2d(X)
    ext = np.abs(0.5 * length * np.sin(X[:, 3])) + np.abs(0.5 * width * np.cos(X[:, 3]))
    return (X[:, 4] + ext > track.width_left(X[:, 5])) | (X[:, 4] - ext < -track.width_right(X[:, 5]))


def run_columns(track, dt: float, Y: np.ndarray, U: np.ndarray) -> dict[str, np.ndarray]:
    """The DESIGN.md run columns from measurements Y (n, 6) and applied inputs U (n, 2)."""
    s = track.wrap(Y[:, 5])
    return {
        "t": dt * np.arange(len(Y)), "s": s, "e_y": Y[:, 4], "e_psi": Y[:, 3], "v_x": Y[:, 0],
        "v_y": Y[:, 1], "yaw_rate": Y[:, 2], "delta": U[:, 0], "a_x": U[:, 1], "kappa": track.kappa(s),
    }


def lap_times_of(t: np.ndarray, lap: np.ndarray) -> list[float]:
    """Completed lap times [s]: from the start (s = 0 at t = 0) to each lap-counter increment."""
    idx = np.flatnonzero(np.diff(lap) > 0) + 1
    starts = np.concatenate([[0], idx])
    return [float(t[b] - t[a]) for a, b in zip(starts[:-1], starts[1:])]
