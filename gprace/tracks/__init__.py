"""Race tracks: the :class:`Track` geometry, loaders (TUM CSV, two boundary files, segment TOML,
shipped names), laps recognised from data (:mod:`gprace.tracks.laps`) and a seeded random
generator of head-to-head training tracks.

>>> from gprace.tracks import load_track
>>> track = load_track("gprace_ring")            # or a .csv / .toml path
>>> s, e_y = track.to_frenet(*track.to_global(100.0, 2.0))
"""

from gprace.tracks.laps import PathLaps, path_laps, wrap_frenet
from gprace.tracks.loaders import DEFAULT_TRACK, load_track, shipped_tracks
from gprace.tracks.random import random_track
from gprace.tracks.track import Track, TrackSamples

__all__ = ["DEFAULT_TRACK", "PathLaps", "Track", "TrackSamples", "load_track", "path_laps", "random_track",
           "shipped_tracks", "wrap_frenet"]
