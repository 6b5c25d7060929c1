"""Seeded random open tracks for head-to-head training and evaluation (docs/reference.md#head-to-head).

A track is a lead-in straight followed by ``n_stretches`` stretches (default 5, about 30 m: room
for an overtake at the 1.3 to 1.6 m/s of the 1:10 cars), each drawn uniformly from:

* ``curve``: a 4 m straight, an arc of swept angle U(pi/5, pi/1.2) and radius U(0.39, 0.79) m,
  then a 5 m straight;
* ``chicane``: two opposite arcs of swept angle U(pi/7, pi/3) each and radius U(0.375, 1.5) m,
  0.5 m apart;
* ``straight``: a straight of length U(2, 6) m (the sources give no length; our choice).

Each curve and chicane turns left or right with probability 1/2. The lead-in (default 2 m) gives
the starting grid of the head-to-head runs (cars start at s <= 1.2 m) a straight to start on.
A draw whose stretches come back within one track width of an earlier part of the track more
than :data:`OVERLAP_GAP` metres of arc length away is rejected and redrawn from the same
generator, so the result still depends only on the seed.

Note on width: with the default 1.5 m (docs/reference.md#head-to-head: one width) the half width is larger than
most of these radii, so on the inside of a tight arc the border lies beyond the centre of
curvature and Frenet coordinates are only valid for ``e_y * kappa < 1``. The source used 0.75 m
for these training tracks; pass ``width=0.75`` to reproduce that.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gprace.errors import InputError
from gprace.tracks.segments import SegmentTrack, build_track, centre_line
from gprace.tracks.track import Track

KINDS = ("curve", "chicane", "straight")
OVERLAP_GAP = 12.0
"""Arc-length separation [m] beyond which two parts of a random track must not overlap."""


def _stretch(kind: str, rng: np.random.Generator) -> list[dict]:
    side = 1.0 if rng.random() < 0.5 else -1.0
    if kind == "curve":
        angle = side * rng.uniform(np.pi / 5, np.pi / 1.2)
        radius = rng.uniform(0.39, 0.79)
        return [
            {"type": "straight", "length": 4.0},
            {"type": "arc", "radius": radius, "angle": angle},
            {"type": "straight", "length": 5.0},
        ]
    if kind == "chicane":
        angle = side * rng.uniform(np.pi / 7, np.pi / 3)
        radius = rng.uniform(0.375, 1.5)
        return [{"type": "chicane", "radius": radius, "angle": angle, "gap": 0.5}]
    if kind == "straight":
        return [{"type": "straight", "length": rng.uniform(2.0, 6.0)}]
    raise InputError(f"random track: unknown stretch kind {kind!r} (valid: {', '.join(KINDS)})")


def random_track_spec(
    seed: int,
    n_stretches: int = 5,
    width: float = 1.5,
    kinds: tuple[str, ...] = KINDS,
    lead_in: float = 2.0,
    max_tries: int = 200,
) -> SegmentTrack:
    """The segment description of :func:`random_track` (write it with ``spec.to_toml()``)."""
    if n_stretches < 1:
        raise InputError(f"random track: n_stretches must be >= 1, got {n_stretches}")
    if not width > 0:
        raise InputError(f"random track: width must be positive, got {width}")
    for k in kinds:
        if k not in KINDS:
            raise InputError(f"random track: unknown stretch kind {k!r} (valid: {', '.join(KINDS)})")
    rng = np.random.default_rng(seed)
    for _ in range(max_tries):
        segs = [{"type": "straight", "length": lead_in}] if lead_in > 0 else []
        for _ in range(n_stretches):
            segs += _stretch(kinds[rng.integers(len(kinds))], rng)
        spec = SegmentTrack.model_validate(
            {"name": f"random-{seed}", "closed": False, "width": width, "segments": segs}
        )
        if not _overlaps(spec, width):
            return spec
    raise InputError(f"random track: no non-overlapping track in {max_tries} draws (seed {seed})")


def random_track(seed: int, **options: Any) -> Track:
    """An open random track; the same arguments give the identical track. ``options`` are those
    of :func:`random_track_spec` (``n_stretches``, ``width``, ``kinds``, ``lead_in``,
    ``max_tries``), with its defaults: one place for them."""
    spec = random_track_spec(seed, **options)
    return build_track(spec, spec.name, f"random track (seed {seed})")


def _overlaps(spec: SegmentTrack, width: float) -> bool:
    from scipy.spatial import cKDTree

    x, y, _, _, _ = centre_line(spec, "random track", ds=0.05)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
    pairs = cKDTree(np.column_stack([x, y])).query_pairs(width, output_type="ndarray")
    return bool(len(pairs)) and bool(np.any(np.abs(s[pairs[:, 0]] - s[pairs[:, 1]]) > OVERLAP_GAP))
