"""What the machine has, for sizes checked before any work (dictionary sizes, laps, periods).

A size a command cannot hold is refused where it starts, in one line that gives the memory it
needs, what is available and the largest size that fits, instead of a ``MemoryError`` after part
of the work. Available memory is the kernel's estimate of what can be allocated without swapping
(``MemAvailable``), bounded by the memory limit of the process's cgroup (containers, batch
schedulers); elsewhere the physical memory.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from gprace.errors import InputError

SHARE = 0.8
"""Share of the available memory one command may plan to use (the rest: the interpreter, the
libraries, other processes' growth while it runs)."""


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_room() -> int | None:
    """Bytes left under the cgroup v2 (or v1) memory limit of this process, if it has one."""
    for limit, used in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                        ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            text = Path(limit).read_text().strip()
            if text == "max" or int(text) >= 1 << 60:  # no limit (v1 writes a huge number)
                return None
            return max(int(text) - int(Path(used).read_text().strip()), 0)
        except (OSError, ValueError):
            continue
    return None


def available_memory() -> int:
    """Bytes this process can still allocate (see the module docstring)."""
    found = [v for v in (_meminfo_available(), _cgroup_room()) if v is not None]
    if found:
        return min(found)
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover -- no sysconf: do not refuse on a guess
        return 1 << 62


def human(nbytes: float) -> str:
    """``12.3 GB``, ``512 MB`` (decimal units)."""
    for unit, size in (("EB", 1e18), ("PB", 1e15), ("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if nbytes >= size:
            return f"{nbytes / size:.3g} {unit}"
    return f"{nbytes / 1e3:.3g} kB"


def largest(need: Callable[[int], float], budget: float, upper: int = 1 << 62) -> int:
    """The largest ``n >= 0`` with ``need(n) <= budget`` (``need`` non-decreasing), by bisection."""
    if need(0) > budget:
        return 0
    lo, hi = 0, 1
    while hi < upper and need(hi) <= budget:
        lo, hi = hi, min(2 * hi, upper)
    if need(hi) <= budget:
        return hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if need(mid) <= budget else (lo, mid)
    return lo


def check_size(what: str, n: float, need: Callable[[int], float], unit: str = "",
               say: Callable[[int], str] | None = None) -> None:
    """Refuse ``n`` (named ``what``, e.g. ``--max-points 100000``) if ``need(n)`` bytes exceed the
    share :data:`SHARE` of the available memory; the message gives the largest ``n`` that fits
    (``say(n)`` phrases it, e.g. in laps rather than steps)."""
    budget = SHARE * available_memory()
    nbytes = need(int(min(n, 1 << 62)))
    if nbytes <= budget:
        return
    top = largest(need, budget)
    raise InputError(f"{what} needs about {human(nbytes)} of memory, more than this machine has available "
                     f"({human(budget / SHARE)}); at most {say(top) if say else f'{top:,}{unit}'} fit")
