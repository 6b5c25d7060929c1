"""Car footprints, border hits, collisions and the tracks of the head-to-head races.

Footprints are oriented rectangles. A border hit is a time step at which a footprint corner lies
beyond the track edge; corners are placed in Frenet coordinates (``e_y + along sin(e_psi) +
across cos(e_psi)``), exact on straights and within ``kappa * (L/2)^2 / 2`` (< 1 cm on the tightest
arc here) on curves. A collision is an overlap of the two rectangles in the global frame
(separating-axis test), vectorised over time.
"""

from __future__ import annotations

import functools
from typing import Literal

import numpy as np

from gprace.config import Frozen
from gprace.errors import InputError
from gprace.model.dynamics import State

LOOP_NAME = "h2h_loop"


def corner_offsets(length: float, width: float) -> np.ndarray:
    """(4, 2) corners (along, across) of a rectangle centred on the car."""
    a, b = 0.5 * length, 0.5 * width
    return np.array([[a, b], [a, -b], [-a, -b], [-a, b]])


def border_hits(track, X: np.ndarray, length: float, width: float) -> np.ndarray:
    """Boolean (T,) : some footprint corner outside ``[-w_r, w_l]`` for states X (T, 6)."""
    X = np.atleast_2d(X)
    c = corner_offsets(length, width)
    epsi, ey, s = (X[:, i, None] for i in (State.E_PSI, State.E_Y, State.S))
    lat = ey + c[:, 0] * np.sin(epsi) + c[:, 1] * np.cos(epsi)  # (T, 4)
    sc = s + c[:, 0] * np.cos(epsi) - c[:, 1] * np.sin(epsi)
    return np.any((lat > track.width_left(sc)) | (lat < -track.width_right(sc)), axis=1)


def global_pose(track, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Global ``x, y, psi`` of Frenet states X (T, 6)."""
    X = np.atleast_2d(X)
    s, ey, epsi = X[:, State.S], X[:, State.E_Y], X[:, State.E_PSI]
    x, y = track.to_global(s, ey)
    return np.asarray(x), np.asarray(y), np.asarray(track.heading(s)) + epsi


def rect_overlap(pa: np.ndarray, pb: np.ndarray, length: float, width: float) -> np.ndarray:
    """Separating-axis test of two equal rectangles; pa, pb (T, 3) = x, y, psi -> (T,) bool."""
    c = corner_offsets(length, width)

    def corners(p):
        cos, sin = np.cos(p[:, 2:3]), np.sin(p[:, 2:3])
        return np.stack([p[:, 0:1] + c[:, 0] * cos - c[:, 1] * sin, p[:, 1:2] + c[:, 0] * sin + c[:, 1] * cos], axis=-1)

    ca, cb = corners(pa), corners(pb)  # (T, 4, 2)
    sep = np.zeros(len(pa), dtype=bool)
    for p in (pa, pb):
        for ang in (p[:, 2], p[:, 2] + np.pi / 2):
            ax = np.stack([np.cos(ang), np.sin(ang)], axis=-1)[:, None, :]
            A, B = np.sum(ca * ax, axis=-1), np.sum(cb * ax, axis=-1)
            sep |= (A.max(1) < B.min(1)) | (B.max(1) < A.min(1))
    return ~sep


def collisions(track, Xa: np.ndarray, Xb: np.ndarray, length: float, width: float) -> np.ndarray:
    pa = np.column_stack(global_pose(track, Xa))
    pb = np.column_stack(global_pose(track, Xb))
    return rect_overlap(pa, pb, length, width)


# ----------------------------------------------------------------------------------------------
# tracks
@functools.lru_cache(maxsize=8)
def loop_track(width: float | None = None):
    """The closed exploration track: the shipped ``h2h_loop`` (1.5 m wide) or, with ``width``, the
    same centre line at another width (radii >= 1 m: valid up to 2 m)."""
    from gprace.tracks.loaders import tracks_dir
    from gprace.tracks.segments import SegmentTrack, build_track
    from gprace.config import read_toml, validate

    path = tracks_dir() / f"{LOOP_NAME}.toml"
    spec = validate(SegmentTrack, read_toml(path), str(path))
    if width is not None:
        if not 0.0 < width <= 2.0:
            raise InputError(f"exploration track width must be in (0, 2] m (the loop's tightest radius is "
                             f"1 m), got {width}")
        spec = spec.model_copy(update={"width": float(width)})
    return build_track(spec, LOOP_NAME, str(path))


TRAINING_SHAPES = ("curve", "chicane")


CHICANE_EXIT = 5.0  # m of straight after a training chicane (the curve's own exit straight)


@functools.lru_cache(maxsize=64)
def training_track(seed: int, width: float = 0.75):
    """A short training track of Zhu et al. 2022 (docs/reference.md#head-to-head): the random-track generator's 2 m
    lead-in and one ``curve`` (even seeds) or ``chicane`` (odd seeds) stretch; a chicane is
    followed by a :data:`CHICANE_EXIT` straight (the source gives none; without it the race
    would end 2 m after the start grid)."""
    from gprace.tracks.random import random_track_spec
    from gprace.tracks.segments import build_track

    shape = TRAINING_SHAPES[int(seed) % 2]
    spec = random_track_spec(int(seed), n_stretches=1, width=width, kinds=(shape,))
    if shape == "chicane":
        d = spec.model_dump()
        d["segments"].append({"type": "straight", "length": CHICANE_EXIT})
        spec = type(spec).model_validate(d)
    name = f"training-{shape}-{seed}"
    return build_track(spec.model_copy(update={"name": name}), name, f"training track (seed {seed})")


TRACK_KINDS = ("random", "training", "loop")


class TrackSpec(Frozen):
    """Where a race runs: ``random`` (seed, stretches, width), ``training`` (seed, width: the curve
    and chicane tracks) or ``loop`` (width, optional: the exploration's closed loop)."""

    kind: Literal["random", "training", "loop"]
    seed: int | None = None
    stretches: int | None = None
    width: float | None = None

    @classmethod
    def of(cls, spec: TrackSpec | dict) -> TrackSpec:
        if isinstance(spec, TrackSpec):
            return spec
        if spec.get("kind") not in TRACK_KINDS:
            raise InputError(f"track spec: unknown kind {spec.get('kind')!r} (valid: {', '.join(TRACK_KINDS)})")
        return cls.model_validate(spec)

    def as_dict(self) -> dict:
        """The spec as tasks and records have always stored it (unset entries left out)."""
        return self.model_dump(mode="json", exclude_none=True)


def make_track(spec: TrackSpec | dict):
    """Track from a task's spec (:class:`TrackSpec`, or its dict as a record stores it)."""
    spec = TrackSpec.of(spec)
    width = 0.75 if spec.width is None else float(spec.width)
    if spec.kind == "loop":
        return loop_track(None if spec.width is None else width)
    if spec.kind == "random":
        from gprace.tracks.random import random_track

        return random_track(int(spec.seed), n_stretches=5 if spec.stretches is None else int(spec.stretches), width=width)
    return training_track(int(spec.seed), width)
