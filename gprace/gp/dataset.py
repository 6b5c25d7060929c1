"""GP datasets on disk: artifacts of kind ``dataset``, one layout for every writer (``select-data``,
the time-trial loops ``iterate`` and ``learn``, the head-to-head protocol) and one reader.

Arrays ``Z (n, d)`` and ``Y (n, p)``, plus any arrays a writer keeps beside them
(:attr:`GPDataset.extra`: the head-to-head's ``run`` index per point, ``learn``'s new samples
``Z_new``, ``Y_new``, ``block_new``); attributes ``feature_map``, ``input_names``,
``output_names`` and how the points were chosen (``selection``, ``max_points``, ``n_seen``,
``dt``, ``step``, ``sources`` ...); the fixed hyperparameters used by the diverse selection, if
any, in the group ``selection_hyper`` (so that a continued selection uses the same kernel).

Older files still read (:func:`read_dataset`): the head-to-head's kind ``h2h_dataset`` (feature map
``opponent``), names in ``inputs``/``outputs`` (the head-to-head's), and the loops' datasets
without names (feature map in ``gp``; inputs ``z0, z1, ...``, outputs ``y0, ...``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gprace.errors import ArtifactError
from gprace.gp.base import GPHyper

KIND = "dataset"
OLD_KINDS = ("h2h_dataset",)  # the head-to-head's own kind before issue 40, read as feature map "opponent"


@dataclass
class GPDataset:
    Z: np.ndarray
    Y: np.ndarray
    feature_map: str
    input_names: list[str]
    output_names: list[str]
    attrs: dict[str, Any] = field(default_factory=dict)
    hyper: GPHyper | None = None
    source: str = "<memory>"
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_seen(self) -> int:
        return int(self.attrs.get("n_seen", len(self.Z)) or len(self.Z))


def loop_dataset(kind: str, feature_set: str, Z: np.ndarray, Y: np.ndarray, attrs: dict[str, Any],
                 extra: dict[str, np.ndarray] | None = None) -> GPDataset:
    """A dataset of the time-trial loops: a ``tracking`` or ``planning`` GP's points with the
    inputs of ``feature_set`` (:func:`gprace.gp.features.dyn_feature_set`) and their outputs."""
    from gprace.gp.features import DYN_OUTPUTS, dyn_feature_set

    return GPDataset(Z, Y, kind, list(dyn_feature_set(feature_set)), list(DYN_OUTPUTS[kind]), dict(attrs),
                     extra=dict(extra or {}))


def write_dataset(path: str | Path, ds: GPDataset, config_hash: str = "", seed: int = 0) -> Path:
    from gprace.io.artifacts import Artifact, write_artifact

    attrs = dict(ds.attrs)
    attrs.update(feature_map=ds.feature_map, input_names=list(ds.input_names), output_names=list(ds.output_names))
    groups = {}
    if ds.hyper is not None:
        groups["selection_hyper"] = ds.hyper.to_arrays()
        attrs["selection_kernel"] = ds.hyper.kernel
    arrays = {"Z": np.asarray(ds.Z, float), "Y": np.asarray(ds.Y, float), **ds.extra}
    art = Artifact(KIND, arrays=arrays, attrs=attrs, groups=groups, config_hash=config_hash, seed=seed)
    return write_artifact(path, art)


def read_dataset(path: str | Path) -> GPDataset:
    """The dataset at ``path``, of this layout or an older one (module docstring)."""
    from gprace.io.artifacts import read_artifact

    return dataset_of(read_artifact(path, (KIND, *OLD_KINDS)), str(path))


def dataset_of(art, source: str = "<memory>") -> GPDataset:
    """The dataset an artifact of a dataset kind holds (:func:`read_dataset` without the file:
    for a caller that has read the artifact already, such as the report)."""
    attrs = dict(art.attrs)
    arrays = dict(art.arrays)
    try:
        Z = np.asarray(arrays.pop("Z"), dtype=float)
        Y = np.asarray(arrays.pop("Y"), dtype=float)
    except KeyError as exc:
        raise ArtifactError(f"{source}: dataset without array {exc.args[0]!r}") from None
    if Z.ndim != 2 or Y.ndim != 2 or len(Z) != len(Y):
        raise ArtifactError(f"{source}: dataset arrays Z {Z.shape} and Y {Y.shape} do not match")
    fm = attrs.pop("feature_map", None)
    if fm is None:  # older layouts: the loops named their GP in "gp", the head-to-head its kind
        fm = attrs.get("gp", "opponent" if art.kind in OLD_KINDS else "")
    names_in = _names(attrs, "input_names", "inputs", "z", Z.shape[1])
    names_out = _names(attrs, "output_names", "outputs", "y", Y.shape[1])
    hyper = None
    if "selection_hyper" in art.groups:
        hyper = GPHyper.from_arrays(str(attrs.get("selection_kernel", "se")), art.groups["selection_hyper"])
    return GPDataset(Z, Y, str(fm), names_in, names_out, attrs, hyper, source, arrays)


def _names(attrs: dict[str, Any], key: str, old_key: str, prefix: str, n: int) -> list[str]:
    """Column names from ``key`` (popped), else from an older layout's ``old_key``, else numbered."""
    names = attrs.pop(key, None)
    if names is None:
        names = attrs.pop(old_key, None)
    return [f"{prefix}{i}" for i in range(n)] if names is None else [str(x) for x in names]


def is_dataset(path: str | Path) -> bool:
    """True for an HDF5 artifact of kind ``dataset`` (or an older kind of one; used to tell
    datasets from runs)."""
    path = Path(path)
    if path.suffix.lower() == ".csv" or not path.exists():
        return False
    try:
        import h5py

        with h5py.File(path, "r") as f:
            kind = f.attrs.get("kind", "")
            return (kind.decode() if isinstance(kind, bytes) else str(kind)) in (KIND, *OLD_KINDS)
    except OSError:
        return False
