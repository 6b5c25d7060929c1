"""CasADi NLP solvers whose functions are compiled C, built once per machine and cached on disk.

IPOPT spends most of a head-to-head NMPC solve in the Hessian of the Lagrangian, which CasADi's
SX virtual machine evaluates interpretively (measured: 6.8 of 10 ms per solve). CasADi's own
``jit`` option compiles it, but again in every process (20 to 50 s each), which a batch of
races in fresh worker processes cannot afford. Here the NLP's functions are generated once
(``generate_dependencies``), compiled to a shared library named by the hash of the C source, and
every later process loads that library (``nlpsol(name, "ipopt", "lib.so")``): the first build
pays the compiler, later ones about 0.1 s.

Cache folder: ``$GPRACE_CACHE`` or ``~/.cache/gprace``. A file lock lets one process compile
while the others wait for its library; the library is written under a temporary name and renamed.
Without a C compiler, or if the build fails, the plain (interpreted) solver is returned with a
warning: slower, same results.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

from gprace.console import console

FLAGS = ("-O1", "-fPIC", "-shared")  # -O1: most of -O2's speed at a fraction of its build time
_CWD = threading.Lock()  # the working directory is per process: one code generation at a time


def cache_dir() -> Path:
    root = os.environ.get("GPRACE_CACHE")
    return Path(root).expanduser() if root else Path.home() / ".cache" / "gprace"


def compiler() -> str | None:
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


def compiled_nlpsol(name: str, plugin: str, nlp: dict, opts: dict):
    """``casadi.nlpsol(name, plugin, nlp, opts)`` with the NLP functions compiled and cached."""
    import casadi as ca

    interpreted = ca.nlpsol(name, plugin, nlp, opts)
    lib = _compiled(interpreted.generate_dependencies, name, "NLP")
    return interpreted if lib is None else ca.nlpsol(name, plugin, str(lib), opts)


def compiled_function(f):
    """A ``casadi.Function`` evaluated by compiled C (cached like the NLPs; same results).

    The tracking MPC's linearisation over the horizon: measured 1.6 ms interpreted, 0.4 ms
    compiled per period (machine under load), bit-identical outputs.
    """
    import casadi as ca

    lib = _compiled(f.generate, f.name(), "function")
    return f if lib is None else ca.external(f.name(), str(lib))


def compiled_source(name: str, source: str, flags: tuple[str, ...], what: str, libs: tuple[str, ...] = (),
                    fallback: str = "it runs interpreted") -> Path | None:
    """The cached shared library of the C ``source`` compiled with ``flags`` (part of its name),
    or None. It is linked in a second step without them: linked with ``-ffast-math``, GCC adds a
    start-up file that switches the whole process to flushing subnormal numbers to zero, which
    changes every other computation (a k-d tree of scipy recursed until the stack overflowed).
    ``libs``: libraries it needs beside libm (e.g. ``-lmvec``); then an undefined symbol fails the
    link (a library without a function it calls) instead of the later load. ``fallback``: what
    runs instead when the build fails (said in the warning)."""

    def generate(file: str) -> str:
        Path(file).write_text(source)
        return file

    link = ("-shared", "-Wl,--no-undefined", *libs) if libs else ("-shared",)
    return _compiled(generate, name, what, (*flags, "-fPIC"), link, fallback)


def _compiled(generate, name: str, what: str, flags: tuple[str, ...] = FLAGS,
              link: tuple[str, ...] | None = None, fallback: str = "it runs interpreted") -> Path | None:
    """The cached library of the C that ``generate(file)`` writes, or None (``fallback``, warned)."""
    cc = compiler()
    if cc is None:
        console.warn(f"no C compiler found (set CC); the {what} {name!r} runs interpreted, 2 to 4 times slower")
        return None
    try:
        return _build(generate, name, cc, what, flags, link)
    except (OSError, RuntimeError, subprocess.SubprocessError) as exc:  # a failed build only costs speed
        # (a compiler that fails or is missing, a cache folder that cannot be written, CasADi's code generation)
        console.warn(f"compiling the {what} {name!r} failed ({str(exc).splitlines()[0][:200]}); {fallback}")
        return None


def _build(generate, name: str, cc: str, what: str, flags: tuple[str, ...] = FLAGS,
           link: tuple[str, ...] | None = None) -> Path:
    with tempfile.TemporaryDirectory(prefix="gprace_cc_") as tmp:
        with _CWD:  # CasADi's code generation writes into the working directory (no path allowed)
            here = os.getcwd()
            os.chdir(tmp)
            try:
                src = Path(tmp) / generate(f"{name}.c")
            finally:
                os.chdir(here)
        code = src.read_bytes()
        digest = hashlib.sha256(code + " ".join((cc, *flags, *(link or ()))).encode()).hexdigest()[:20]
        out = cache_dir() / f"{name}_{digest}.so"
        if out.exists():
            return out
        out.parent.mkdir(parents=True, exist_ok=True)
        with _locked(out.with_suffix(".lock")):  # one compiler per library, the others wait
            if not out.exists():
                console.info(f"compiling the {what} {name!r} once for this machine (cached in {out.parent})")
                part = out.with_suffix(f".{os.getpid()}.part")
                if link is None:
                    steps = [[cc, *flags, str(src), "-o", str(part), "-lm"]]
                else:  # compile, then link without the compile flags (see compiled_source)
                    obj = str(src.with_suffix(".o"))
                    libs = [a for a in link if a.startswith("-l")]  # after the object, which needs them
                    opts = [a for a in link if not a.startswith("-l")]
                    steps = [[cc, *flags, "-c", str(src), "-o", obj], [cc, *opts, obj, "-o", str(part), *libs, "-lm"]]
                for cmd in steps:
                    proc = subprocess.run(cmd, capture_output=True, text=True)
                    if proc.returncode != 0:
                        part.unlink(missing_ok=True)
                        raise RuntimeError(proc.stderr.strip() or f"{cc} exited with {proc.returncode}")
                os.replace(part, out)
        return out


@contextmanager
def _locked(path: Path):
    try:
        import fcntl
    except ImportError:  # no POSIX locks: concurrent builders each compile, the rename keeps it valid
        yield
        return
    with open(path, "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
