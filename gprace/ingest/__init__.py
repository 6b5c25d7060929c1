"""Real recordings in: global-frame CSV logs, ROS 1/2 bags and MCAP, MDF4 -> Frenet runs.

>>> from gprace.ingest import import_recording
>>> run, track = import_recording("log.mcap", track="Monza.csv", dt=0.05)

``mapping`` (the recording map, TOML), ``readers`` (one per format), ``process`` (resampling,
gaps, unit checks, projection), ``refline`` (reference line from the driven path), ``dispatch``
(:func:`~gprace.ingest.dispatch.read_any`: a run or a raw recording, imported), ``commands`` (``gprace import``).
"""

from gprace.ingest.dispatch import read_any
from gprace.ingest.importer import import_recording
from gprace.ingest.mapping import RecordingMap, load_map

__all__ = ["RecordingMap", "import_recording", "load_map", "read_any"]
