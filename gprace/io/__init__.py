"""Artifacts (HDF5 with provenance) and recordings (HDF5 or CSV)."""

from gprace.io.artifacts import Artifact, read_artifact, write_artifact
from gprace.io.runs import RUN_COLUMNS, Run, read_run, write_run, write_run_csv

__all__ = ["Artifact", "read_artifact", "write_artifact", "RUN_COLUMNS", "Run", "read_run", "write_run", "write_run_csv"]
