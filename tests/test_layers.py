"""The layers of the package (issue 40), as ``.importlinter`` states them: the contract holds on
the checkout, and it breaks on a copy of the package given one import that crosses a layer."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT = [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports; "
        "sys.exit(lint_imports(config_filename='.importlinter', no_cache=True))"]


def _lint(where: Path) -> subprocess.CompletedProcess:
    # run in `where`, whose gprace is the one analysed (the current directory comes first on sys.path)
    return subprocess.run(LINT, cwd=where, capture_output=True, text=True, timeout=300)


def test_the_checkout_keeps_its_layers():
    res = _lint(ROOT)
    assert res.returncode == 0, res.stdout[-3000:]
    assert "3 kept, 0 broken" in res.stdout


@pytest.mark.parametrize("low, high", [("gprace/config.py", "gprace.timetrial.iterate"),
                                        ("gprace/gp/kernels.py", "gprace.cli"),
                                        ("gprace/tracks/track.py", "gprace.ingest.importer"),
                                        ("gprace/config.py", "gprace.model.effects"),  # the cycles of issue 40
                                        ("gprace/gp/base.py", "gprace.backends.gp_exact")])
def test_an_import_that_crosses_a_layer_breaks_the_contract(tmp_path, low, high):
    shutil.copytree(ROOT / "gprace", tmp_path / "gprace", ignore=shutil.ignore_patterns("__pycache__", "data"))
    shutil.copy(ROOT / ".importlinter", tmp_path / ".importlinter")
    target = tmp_path / low
    target.write_text(target.read_text() + f"\n\ndef _crossing():\n    import {high}  # noqa: F401\n")
    res = _lint(tmp_path)
    # (config -> a workflow also reaches gprace.model through it: both contracts break)
    assert res.returncode != 0 and "broken" in res.stdout and " 0 broken" not in res.stdout, res.stdout[-2000:]
    assert high.rsplit(".", 1)[0] in res.stdout
