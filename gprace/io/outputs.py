"""Where a command writes: checked before any work, and one run at a time in a run folder.

Every command that writes declares its outputs (``gprace.cli.OUTPUTS``), and the CLI opens them
with :class:`Outputs` before the command starts:

- a file (``-o run.h5``, ``--plot fig.png``): the nearest folder of it that exists must take a new
  file (an empty hidden file is made there and removed at once), so a read-only or full folder
  is one line before the work instead of an ``OSError`` after it;
- a folder the command only fills (``report --png DIR``): the same check;
- a run folder (``--out DIR`` of ``iterate``, ``eval timetrial``, ``eval head2head``, ``h2h
  collect|explore``): created if missing and locked for the whole run (:class:`FolderLock`), so a
  second run into it is refused with a line naming the first (pid, host, command, start time)
  instead of both doing all the work and overwriting each other. A folder inside a locked one is
  refused the same way.

A folder the command created and left empty (a refused setting, an interrupt before any work) is
removed again, so a refused command leaves nothing behind.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from gprace.errors import InputError
from gprace.io.artifacts import check_folder, check_output

LOCK_NAME = ".gprace.lock"
"""The lock file of a run folder (hidden: the report's scan and the stages skip it)."""

Kind = Literal["file", "folder", "run"]

try:  # POSIX: the kernel releases the lock when its process ends, however it ends
    import fcntl
except ImportError:  # pragma: no cover -- Windows: the lock file alone, its pid checked
    fcntl = None


def _nearest(path: Path) -> Path:
    """``path`` or its nearest parent that exists."""
    return next((p for p in (path, *path.parents) if p.exists()), Path(path.anchor or "."))


def check_writable(path: str | Path, option: str, kind: Kind = "file") -> Path:
    """``path`` as an output of ``kind`` that can be written, or a one-line InputError: a file or a
    folder in the way (:func:`~gprace.io.artifacts.check_output`, :func:`~gprace.io.artifacts.check_folder`),
    or a folder where no file can be made (read-only, no permission, full)."""
    path = Path(path)
    try:  # the file system may refuse the name itself (too long, bad characters)
        if kind == "file":
            check_output(path, option)
            where = _nearest(path.parent)
        else:
            check_folder(path, option)
            where = _nearest(path)
    except OSError as exc:
        raise InputError(f"{option} {path}: the file system refuses this name ({exc.strerror or exc})") from None
    try:
        fd, probe = tempfile.mkstemp(prefix=".gprace-write-check-", dir=where)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(f"{option} {path}: cannot write in {where} ({exc.strerror or exc})") from None
    return path


def _now() -> str:
    return _dt.datetime.now().astimezone().isoformat(timespec="seconds")


def _describe(holder: dict) -> str:
    """``pid 123 on host, `gprace iterate ...`, started ...`` from a lock's content."""
    if not holder.get("pid"):
        return "another gprace run"
    return (f"pid {holder['pid']} on {holder.get('host', '?')} (`{holder.get('command', 'gprace')}`, "
            f"started {holder.get('started', '?')})")


def _read_holder(fd_or_path) -> dict:
    try:
        if isinstance(fd_or_path, int):
            os.lseek(fd_or_path, 0, os.SEEK_SET)
            text = os.read(fd_or_path, 65536).decode("utf-8", "replace")
        else:
            text = Path(fd_or_path).read_text(encoding="utf-8", errors="replace")
        holder = json.loads(text)
        return holder if isinstance(holder, dict) else {}
    except (OSError, ValueError):
        return {}


def _pid_alive(holder: dict) -> bool:
    """Without ``fcntl``: is the holder of a lock still running (another host: assumed so)?"""
    if holder.get("host") != socket.gethostname():
        return True
    try:
        os.kill(int(holder.get("pid", 0)), 0)
    except (ProcessLookupError, ValueError):
        return False
    except PermissionError:
        return True
    return True


@dataclass
class FolderLock:
    """An exclusive lock on a run folder, held from :meth:`acquire` to :meth:`release`.

    ``.gprace.lock`` in the folder holds the holder's pid, host, command and start time, and is
    ``flock``-ed while the run lasts: the kernel releases it when the process ends, so a lock left
    by a killed run is stale and the next run takes it over (with a note naming the dead run).
    """

    folder: Path
    option: str = "--out"
    command: str = "gprace"
    took_over: dict = field(default_factory=dict)
    _fd: int | None = None

    @property
    def path(self) -> Path:
        return self.folder / LOCK_NAME

    def acquire(self) -> FolderLock:
        self._check_parents()
        for _ in range(5):  # the lock file may be replaced under us (a holder removing it as it ends)
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise InputError(f"{self.option} {self.folder}: cannot write there ({exc.strerror or exc})") from None
            if not self._lock(fd):
                holder = _read_holder(fd)
                os.close(fd)
                raise InputError(f"{self.option} {self.folder}: in use by {_describe(holder)}; wait for it to end "
                                 f"or use another {self.option}")
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        else:  # pragma: no cover -- five replacements in a row
            raise InputError(f"{self.option} {self.folder}: its lock keeps changing; another run is starting there")
        self.took_over = _read_holder(fd)
        mine = {"pid": os.getpid(), "host": socket.gethostname(), "command": self.command, "started": _now()}
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, json.dumps(mine).encode())
        os.fsync(fd)
        self._fd = fd
        return self

    def _lock(self, fd: int) -> bool:
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return True
            except BlockingIOError:
                return False
        holder = _read_holder(fd)
        return not holder or not _pid_alive(holder)

    def _check_parents(self) -> None:
        """A run folder inside another run's folder is refused too (``eval timetrial`` writes
        ``--out/exploration``, which ``iterate --out`` could otherwise write at the same time)."""
        for parent in self.folder.resolve().parents:
            lock = parent / LOCK_NAME
            if not lock.is_file():
                continue
            try:
                fd = os.open(lock, os.O_RDONLY)
            except OSError:
                continue
            try:
                free = self._lock(fd)
                holder = {} if free else _read_holder(fd)
            finally:
                os.close(fd)  # closing drops a lock taken only to look
            if not free:
                raise InputError(f"{self.option} {self.folder}: inside {parent}, which is in use by {_describe(holder)}; "
                                 f"wait for it to end or use another {self.option}")

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)  # while still locked: a waiting run then makes a new file
        finally:
            os.close(self._fd)
            self._fd = None


@dataclass
class Output:
    option: str
    path: Path
    kind: Kind


class Outputs:
    """The outputs of one command, checked and (run folders) locked; a context manager.

    ``command``: the command line (named in the lock); ``resume``: what to do after an interrupt
    (``"rerun the same command to resume"``).
    """

    def __init__(self, outputs: list[Output], command: str = "gprace", resume: str = "") -> None:
        self.outputs = outputs
        self.command = command
        self.resume = resume
        self.started = _dt.datetime.now().timestamp()
        self.locks: list[FolderLock] = []
        self.created: list[Path] = []

    def __enter__(self) -> Outputs:
        from gprace.console import console

        for o in self.outputs:
            check_writable(o.path, o.option, o.kind)
        entered = False
        try:
            for o in self.outputs:
                if o.kind != "run":
                    continue
                missing = [p for p in (o.path, *o.path.parents) if not p.exists()]
                try:
                    o.path.mkdir(parents=True, exist_ok=True)
                except OSError as exc:
                    raise InputError(f"{o.option} {o.path}: cannot create it ({exc.strerror or exc})") from None
                self.created += reversed(missing)
                lock = FolderLock(o.path, o.option, self.command).acquire()
                self.locks.append(lock)
                if lock.took_over:
                    console.warn(f"{o.option} {o.path}: took over the lock of {_describe(lock.took_over)}, which is "
                                 "no longer running")
            entered = True
        finally:
            if not entered:  # a refusal or Ctrl-C half-way: release what was taken
                self.close()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for lock in reversed(self.locks):
            lock.release()
        self.locks = []
        for d in reversed(self.created):  # deepest first; only while empty
            try:
                d.rmdir()
            except OSError:
                break
        self.created = []

    def written(self) -> list[Path]:
        """Outputs this command wrote (files modified, run folders with content, since it started)."""
        out = []
        for o in self.outputs:
            p = o.path
            if o.kind == "file" and p.is_file() and p.stat().st_mtime >= self.started - 1:
                out.append(p)
            elif o.kind != "file" and p.is_dir() and any(c.name != LOCK_NAME for c in p.iterdir()):
                out.append(p)
        return out

    def interrupted_line(self) -> str:
        """The one line of an interrupted command: what was kept, and how to go on."""
        runs = [o.path for o in self.outputs if o.kind == "run"]
        kept = self.written()
        if runs:
            where = ", ".join(str(p) for p in runs)
            what = f"the finished steps are kept in {where}" if kept else f"nothing was finished yet in {where}"
            return f"interrupted; {what}; {self.resume or 'rerun the same command to resume'}"
        if kept:
            return f"interrupted; written before the interrupt: {', '.join(map(str, kept))}; rerun the command for the rest"
        files = [str(o.path) for o in self.outputs]
        none = "nothing was written" + (f" ({', '.join(files)} only when the command finishes)" if files else "")
        return f"interrupted; {none}; rerun the command"
