"""Time trial: driving plans with the tracking MPC, exploration, the iterative double-GP loop.

Public surface::

    from gprace.timetrial import DriveSettings, IterateSettings, iterate_many, read_record, IterationRecord
    from gprace.timetrial import IterateSummary, read_summary

The stage functions are named like their modules: ``gprace.timetrial.drive.drive``,
``gprace.timetrial.iterate.iterate``, ``gprace.timetrial.compare.compare``.

:mod:`~gprace.timetrial.drive` (one run of a plan), :mod:`~gprace.timetrial.learning` (the GP
compensation of the tracking MPC), :mod:`~gprace.timetrial.grip` (the friction envelope the plan may
use), :mod:`~gprace.timetrial.iterate` (the paper's loop, resumable), :mod:`~gprace.timetrial.compare`
and :mod:`gprace.cli.timetrial` (CLI).
"""

from gprace._lazy import lazy_face

__all__, __getattr__ = lazy_face(__name__, {
    "drive": "DriveSettings", "iterate": "iterate_many IterateSettings",
    "record": "IterationRecord read_record IterateSummary read_summary", "learning": "load_predictor"})
