"""``python -m gprace.cli`` (as benchmarks call it) runs the same app as the ``gprace`` command."""

from __future__ import annotations

import subprocess
import sys

from gprace import __version__


def test_python_m_gprace_cli_runs_the_app(tmp_path):
    ok = subprocess.run([sys.executable, "-m", "gprace.cli", "--version"], capture_output=True, text=True, cwd=tmp_path)
    assert ok.returncode == 0 and ok.stdout.strip() == f"gprace {__version__}"
    bad = subprocess.run([sys.executable, "-m", "gprace.cli", "run", "--plan", str(tmp_path / "none.h5"), "-o", "r.h5"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "none.h5" in bad.stderr
