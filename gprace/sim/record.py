"""Pieces shared by every closed loop that records a :class:`~gprace.io.runs.Run`
(``simulate``'s reference controller, the time trial's MPC): footprint border hits, the standard
run columns, lap times. All vectorised over the recorded samples.
"""

from __future__ import annotations

import numpy as np

from gprace.model.dynamics import Input, State


def border_hits(track, X: np.ndarray, length: float, width: float) -> np.ndarray:
    """(n,) bool: the car's rectangular footprint crosses a track edge at true Frenet states X (n, 6).

    Half lateral extent of the footprint: ``|l/2 sin e_psi| + |w/2 cos e_psi|``.
    """
    X = np.atleast_2d(X)
    epsi, ey, s = X[:, State.E_PSI], X[:, State.E_Y], X[:, State.S]
    ext = np.abs(0.5 * length * np.sin(epsi)) + np.abs(0.5 * width * np.cos(epsi))
    return (ey + ext > track.width_left(s)) | (ey - ext < -track.width_right(s))


def run_columns(track, dt: float, Y: np.ndarray, U: np.ndarray) -> dict[str, np.ndarray]:
    """The DESIGN.md run columns from measurements Y (n, 6) and applied inputs U (n, 2)."""
    s = track.wrap(Y[:, State.S])
    return {
        "t": dt * np.arange(len(Y)), "s": s, "e_y": Y[:, State.E_Y], "e_psi": Y[:, State.E_PSI],
        "v_x": Y[:, State.V_X], "v_y": Y[:, State.V_Y], "yaw_rate": Y[:, State.YAW_RATE],
        "delta": U[:, Input.DELTA], "a_x": U[:, Input.A_X], "kappa": track.kappa(s),
    }


def lap_times_of(t: np.ndarray, lap: np.ndarray) -> list[float]:
    """Completed lap times [s]: from the start (s = 0 at t = 0) to each lap-counter increment."""
    idx = np.flatnonzero(np.diff(lap) > 0) + 1
    starts = np.concatenate([[0], idx])
    return [float(t[b] - t[a]) for a, b in zip(starts[:-1], starts[1:])]
