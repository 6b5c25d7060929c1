"""Each package's public face, and the plugin surfaces outside packages build on (issue 18)."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys
import types

import pytest

import gprace

FACES = ["gprace.diagnose", "gprace.h2h", "gprace.io", "gprace.model", "gprace.mpc", "gprace.plan",
         "gprace.plants", "gprace.report", "gprace.sim", "gprace.timetrial", "gprace.tracks", "gprace.explore"]


@pytest.mark.parametrize("name", FACES)
def test_a_face_names_objects_not_modules(name):
    """Every public name resolves to the object its module defines, also after all the package's
    modules were imported (a public name that is also a module's name would then be the module)."""
    pkg = importlib.import_module(name)
    assert pkg.__all__, name
    before = {n: getattr(pkg, n) for n in pkg.__all__}
    for mod in pkgutil.iter_modules(pkg.__path__):
        importlib.import_module(f"{name}.{mod.name}")
    for n in pkg.__all__:
        obj = getattr(pkg, n)
        assert not isinstance(obj, types.ModuleType), f"{name}.{n} is a module"
        assert obj is before[n], f"{name}.{n} changed when the package's modules were imported"
    with pytest.raises(AttributeError, match="no attribute"):
        getattr(pkg, "not_a_public_name")


def test_the_cli_imports_no_numerics():
    """The lazy faces keep ``gprace --help`` light: importing the CLI pulls in no solver or learning stack."""
    code = "import sys, gprace.cli; print(sorted(m for m in ('casadi', 'cvxpy', 'clarabel', 'sklearn') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_plugin_surfaces_stay_where_outside_packages_import_them():
    from gprace.config import PlantConfig, VehicleConfig
    from gprace.gp.base import GPBackend
    from gprace.plants.base import Plant

    for attr in ("_noisy", "_wrap", "step", "reset"):
        assert callable(getattr(Plant, attr, None)), attr
    assert {"kind", "vehicle", "substeps", "seed"} <= set(PlantConfig.model_fields)
    assert {"mass", "width"} <= set(VehicleConfig.model_fields)
    assert {"fit", "predict"} <= set(dir(GPBackend))
    assert gprace.plants.Plant is Plant
