""":class:`Plan`: a lap as arrays over the track's arc length, and its artifact (kind ``plan``).

A plan holds, at ``n`` nodes ``s_k = k L / n`` of a closed track, the state and inputs the car
should have there and the time ``t_k`` at which it gets there (``t_0 = 0``; ``lap_time`` is the
time back at ``s = L``). Controllers look it up by time (``at_time``) after finding the time of
their own position (``time_at``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from gprace.errors import InputError
from gprace.io.artifacts import Artifact, read_artifact, write_artifact

PLAN_COLUMNS = ("s", "e_y", "e_psi", "v_x", "v_y", "yaw_rate", "delta", "a_x", "t")


def track_hash(track) -> str:
    """Fingerprint of a track's geometry (curvature and widths every 5 m), 16 hex digits."""
    smp = track.sample(5.0)
    blob = np.round(np.concatenate([[track.length], smp.kappa, smp.wl, smp.wr]), 6).tobytes()
    return hashlib.sha256(blob).hexdigest()[:16]


@dataclass
class Plan:
    s: np.ndarray
    e_y: np.ndarray
    e_psi: np.ndarray
    v_x: np.ndarray
    v_y: np.ndarray
    yaw_rate: np.ndarray
    delta: np.ndarray
    a_x: np.ndarray
    t: np.ndarray
    lap_time: float
    track: str
    track_length: float
    track_hash: str
    vehicle: str = ""
    method: str = "min_time"
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.s)

    def states(self) -> np.ndarray:
        """(n, 6) states ``[v_x, v_y, yaw_rate, e_psi, e_y, s]``."""
        return np.column_stack([self.v_x, self.v_y, self.yaw_rate, self.e_psi, self.e_y, self.s])

    def inputs(self) -> np.ndarray:
        return np.column_stack([self.delta, self.a_x])

    # lookups -----------------------------------------------------------------------------------
    @cached_property
    def _lookup(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, t, table)`` closed by the first node again at ``(L, lap_time)``, built once per plan
        (the MPC looks the plan up every period; a plan's arrays are not changed after creation).
        ``table`` holds all eight columns of :meth:`at_time` for one lookup."""
        table = np.column_stack([self.v_x, self.v_y, self.yaw_rate, self.e_psi, self.e_y, self.s, self.delta, self.a_x])
        end = table[:1].copy()
        end[0, 5] = self.track_length
        return np.append(self.s, self.track_length), np.append(self.t, self.lap_time), np.vstack([table, end])

    def time_at(self, s: np.ndarray | float) -> np.ndarray:
        """Plan time at arc length ``s`` (wrapped into the lap), linear between nodes."""
        sp, tp, _ = self._lookup
        return np.interp(np.mod(s, self.track_length), sp, tp)

    def at_time(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States (m, 6) and inputs (m, 2) at plan times ``t`` (periodic in the lap time).

        ``s`` is returned unwrapped: ``s(t + lap_time) = s(t) + L``.
        """
        t = np.asarray(t, dtype=float)
        T, L = self.lap_time, self.track_length
        laps = np.floor(t / T)
        tw = t - laps * T
        _, tp, table = self._lookup
        i = np.clip(np.searchsorted(tp, tw, side="right") - 1, 0, len(tp) - 2)
        w = np.clip((tw - tp[i]) / np.maximum(tp[i + 1] - tp[i], 1e-12), 0.0, 1.0)[:, None]
        out = (1.0 - w) * table[i] + w * table[i + 1]
        out[:, 5] += laps * L
        return out[:, :6], out[:, 6:]

    def check_track(self, track, where: str = "plan") -> None:
        """Raise InputError unless the plan was made on this track geometry."""
        h = track_hash(track)
        if h != self.track_hash:
            raise InputError(
                f"{where}: planned on track {self.track!r} (L = {self.track_length:.1f} m, hash {self.track_hash}), "
                f"not on {track.name!r} (L = {track.length:.1f} m, hash {h})"
            )

    # artifact ----------------------------------------------------------------------------------
    def to_artifact(self) -> Artifact:
        return Artifact(
            kind="plan",
            arrays={c: np.asarray(getattr(self, c), dtype=float) for c in PLAN_COLUMNS},
            attrs={
                "track": self.track, "track_length": float(self.track_length), "track_hash": self.track_hash,
                "lap_time": float(self.lap_time), "vehicle": self.vehicle, "method": self.method, "meta": dict(self.meta),
            },
        )

    @classmethod
    def from_artifact(cls, art: Artifact, source: str = "plan") -> "Plan":
        missing = [c for c in PLAN_COLUMNS if c not in art.arrays]
        if missing:
            raise InputError(f"{source}: plan without array(s) {', '.join(missing)}")
        for k in ("track", "track_length", "track_hash", "lap_time"):
            if k not in art.attrs:
                raise InputError(f"{source}: plan without attribute {k!r}")
        arrays = {c: np.asarray(art.arrays[c], dtype=float) for c in PLAN_COLUMNS}
        for c, a in arrays.items():
            if not np.all(np.isfinite(a)):
                raise InputError(f"{source}: plan array {c!r} has non-finite values")
        return cls(
            **arrays, lap_time=float(art.attrs["lap_time"]), track=str(art.attrs["track"]),
            track_length=float(art.attrs["track_length"]), track_hash=str(art.attrs["track_hash"]),
            vehicle=str(art.attrs.get("vehicle", "")), method=str(art.attrs.get("method", "")),
            meta=dict(art.attrs.get("meta") or {}),
        )

    def write(self, path: str | Path) -> Path:
        return write_artifact(path, self.to_artifact())


def read_plan(path: str | Path, track=None) -> Plan:
    """Read a plan artifact; with ``track`` given, check it was planned on that track."""
    plan = Plan.from_artifact(read_artifact(path, "plan"), str(path))
    if track is not None:
        plan.check_track(track, str(path))
    return plan
