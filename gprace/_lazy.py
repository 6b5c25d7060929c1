"""Lazy public faces: a package names its public objects and the private module each lives in.

``gprace --help`` imports every stage's ``commands`` module, hence every stage package; a package
face that imported its numerics eagerly would pull CasADi, SciPy and h5py into ``--help``. So a
package's ``__init__`` declares ``{module: names}`` and resolves a name on first use (PEP 562).
"""

from __future__ import annotations

import importlib
from typing import Any, Callable


def lazy_face(package: str, modules: dict[str, str]) -> tuple[list[str], Callable[[str], Any]]:
    """``__all__`` and the module ``__getattr__`` of ``package``; ``modules`` maps each module
    (relative to the package) to the public names it defines, space-separated."""
    home = {name: module for module, names in modules.items() for name in names.split()}

    def __getattr__(name: str) -> Any:
        if name not in home:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{home[name]}"), name)

    return sorted(home), __getattr__
