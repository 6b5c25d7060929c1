"""Issue 38, item 3: where a command writes is checked before any work, and a run folder is
written by one run at a time (gprace.io.outputs)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from gprace.cli import main
from gprace.io.outputs import LOCK_NAME, FolderLock
from test_hardening import refused

HOLD = ("import sys, time\nfrom pathlib import Path\nfrom gprace.io.outputs import FolderLock\n"
        "FolderLock(Path(sys.argv[1]), command='gprace iterate --out ' + sys.argv[1]).acquire()\n"
        "print('locked', flush=True)\ntime.sleep(120)\n")


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("GPRACE_DEBUG", raising=False)


@pytest.fixture
def holder(tmp_path):
    """Another process holding the lock of ``tmp_path / 'run'``."""
    folder = tmp_path / "run"
    folder.mkdir()
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "locked"
    yield folder, p
    p.kill()
    p.wait()


@pytest.mark.parametrize("argv", [
    ["iterate", "--iterations", "1", "--out", "{run}"],
    ["eval", "head2head", "--tracks", "1", "--out", "{run}"],
    ["eval", "timetrial", "--out", "{run}"],
    ["h2h", "collect", "--runs", "1", "--init-runs", "1", "--out", "{run}"],
])
def test_a_second_run_into_a_folder_in_use_is_refused_naming_the_first(capsys, holder, argv):
    folder, p = holder
    before = sorted(folder.iterdir())
    line = refused(capsys, [a.format(run=folder) for a in argv], f"--out {folder}", f"in use by pid {p.pid}",
                   "gprace iterate --out", "started 20")
    assert sorted(folder.iterdir()) == before  # nothing written, the holder's lock untouched
    assert json.loads((folder / LOCK_NAME).read_text())["pid"] == p.pid, line


def test_a_folder_inside_one_in_use_is_refused(capsys, holder):
    folder, p = holder
    refused(capsys, ["iterate", "--out", folder / "exploration"], "inside", f"pid {p.pid}")
    assert not (folder / "exploration").exists()


def test_a_lock_left_by_a_killed_run_is_taken_over_with_a_note(capsys, tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "locked"
    p.send_signal(signal.SIGKILL)  # dies without removing its lock file
    p.wait()
    assert json.loads((folder / LOCK_NAME).read_text())["pid"] == p.pid
    code = main(["iterate", "--solver", "gurobi", "--out", str(folder)])  # takes the lock, then refuses the solver
    err = capsys.readouterr().err.splitlines()
    assert code == 2
    assert err[0].startswith(f"warning: --out {folder}: took over the lock of pid {p.pid}") and "no longer running" in err[0]
    assert err[1].startswith("error: ") and "gurobi" in err[1]
    assert not (folder / LOCK_NAME).exists() and folder.is_dir()  # released; the folder existed before


def test_the_lock_is_held_while_the_run_lasts_and_released_after(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    lock = FolderLock(folder, command="gprace test").acquire()
    r = subprocess.run([sys.executable, "-c", "import sys; from gprace.cli import main; sys.exit(main())",
                        "iterate", "--out", str(folder)], capture_output=True, text=True)
    assert r.returncode == 2 and f"in use by pid {os.getpid()}" in r.stderr and "`gprace test`" in r.stderr
    lock.release()
    assert not (folder / LOCK_NAME).exists()
    FolderLock(folder).acquire().release()  # free again


def _read_only_folder(tmp_path: Path) -> Path:
    """A folder no file can be made in: permissions for a normal user; a read-only tmpfs for root
    (root ignores permissions), skipped where it cannot be mounted."""
    ro = tmp_path / "ro"
    ro.mkdir()
    if os.geteuid() != 0:
        ro.chmod(0o555)
        return ro
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], capture_output=True)
    if r.returncode != 0:
        pytest.skip("running as root without a read-only mount: no folder is unwritable")
    return ro


@pytest.fixture
def read_only(tmp_path):
    ro = _read_only_folder(tmp_path)
    yield ro
    if os.geteuid() == 0:
        subprocess.run(["umount", str(ro)], capture_output=True)
    else:
        ro.chmod(0o755)


@pytest.mark.parametrize("argv,option", [
    (["iterate", "--out", "{ro}/it"], "--out"),
    (["simulate", "-o", "{ro}/r.h5"], "--output"),
    (["import", "{rec}", "-o", "{ro}/r.h5"], "--output"),
    (["report", "{here}", "-o", "{ro}/report.html"], "--out"),
    (["diagnose", "{rec}", "--vehicle", "audi_tt_cup", "-o", "{ro}/car.toml"], "--output"),
    (["select-data", "{rec}", "-o", "{ro}/sub/d.h5"], "--output"),
])
def test_an_unwritable_folder_is_refused_before_any_work(capsys, tmp_path, read_only, argv, option):
    rec = tmp_path / "log.csv"
    rec.write_text("t,x,y\n0,0,0\n")
    refused(capsys, [a.format(ro=read_only, rec=rec, here=tmp_path) for a in argv], option, f"cannot write in {read_only}")
