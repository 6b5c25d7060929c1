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



def test_a_closed_pipe_ends_the_command_quietly(monkeypatch, capsys):
    """`gprace iterate --help | head`: the reader closed the pipe while the help was still being
    written (click's echo of the help's tail raised BrokenPipeError). The command ends with 141
    (128 + SIGPIPE, as a shell tool) and writes no line, not an internal error."""
    import gprace.cli as cli

    def closed_pipe(cmd):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(cli, "_prepare", closed_pipe)
    assert cli.main(["iterate", "--help"]) == 141
    assert capsys.readouterr().err == ""
