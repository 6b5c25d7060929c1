"""Where the shared read-only data sit (TUM circuits, real logs), from a checkout or a worktree.

``GPRACE_SHARED`` names the folder; otherwise the first ``shared/data`` found above the tests, else
this machine's ``/work/shared/data`` (a clone made elsewhere, as CI's may be).
"""

from __future__ import annotations

import os
from pathlib import Path


def shared_data() -> Path:
    env = os.environ.get("GPRACE_SHARED")
    if env:
        return Path(env) / "data"
    for parent in Path(__file__).resolve().parents:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return Path("/work/shared/data")  # this machine's copy, for a clone made elsewhere (CI)


TUM_TRACKS = shared_data() / "tumftm-racetrack-database" / "tracks"
REAL_LOGS = shared_data() / "real"
