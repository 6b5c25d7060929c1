"""GP datasets on disk: artifacts of kind ``dataset`` (written by ``select-data``).

Arrays ``Z (n, d)`` and ``Y (n, p)``; attributes ``feature_map``, ``input_names``,
``output_names`` and how the points were chosen (``selection``, ``max_points``, ``n_seen``,
``dt``, ``step``, ``sources``); the fixed hyperparameters used by the diverse selection, if any,
in the group ``selection_hyper`` (so that a continued selection uses the same kernel).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gprace.errors import ArtifactError
from gprace.gp.base import GPHyper

KIND = "dataset"


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

    @property
    def n_seen(self) -> int:
        return int(self.attrs.get("n_seen", len(self.Z)) or len(self.Z))


def write_dataset(path: str | Path, ds: GPDataset, config_hash: str = "", seed: int = 0) -> Path:
    from gprace.io.artifacts import Artifact, write_artifact

    attrs = dict(ds.attrs)
    attrs.update(feature_map=ds.feature_map, input_names=list(ds.input_names), output_names=list(ds.output_names))
    groups = {}
    if ds.hyper is not None:
        groups["selection_hyper"] = ds.hyper.to_arrays()
        attrs["selection_kernel"] = ds.hyper.kernel
    art = Artifact(KIND, arrays={"Z": np.asarray(ds.Z, float), "Y": np.asarray(ds.Y, float)}, attrs=attrs,
                   groups=groups, config_hash=config_hash, seed=seed)
    return write_artifact(path, art)


def read_dataset(path: str | Path) -> GPDataset:
    from gprace.io.artifacts import read_artifact

    art = read_artifact(path, KIND)
    attrs = dict(art.attrs)
    try:
        Z = np.asarray(art.arrays["Z"], dtype=float)
        Y = np.asarray(art.arrays["Y"], dtype=float)
    except KeyError as exc:
        raise ArtifactError(f"{path}: dataset without array {exc.args[0]!r}") from None
    if Z.ndim != 2 or Y.ndim != 2 or len(Z) != len(Y):
        raise ArtifactError(f"{path}: dataset arrays Z {Z.shape} and Y {Y.shape} do not match")
    fm = str(attrs.pop("feature_map", ""))
    names_in = [str(x) for x in attrs.pop("input_names", [f"z{i}" for i in range(Z.shape[1])])]
    names_out = [str(x) for x in attrs.pop("output_names", [f"y{i}" for i in range(Y.shape[1])])]
    hyper = None
    if "selection_hyper" in art.groups:
        hyper = GPHyper.from_arrays(str(attrs.get("selection_kernel", "se")), art.groups["selection_hyper"])
    return GPDataset(Z, Y, fm, names_in, names_out, attrs, hyper, str(path))


def is_dataset(path: str | Path) -> bool:
    """True for an HDF5 artifact of kind ``dataset`` (used to tell datasets from runs)."""
    path = Path(path)
    if path.suffix.lower() == ".csv" or not path.exists():
        return False
    try:
        import h5py

        with h5py.File(path, "r") as f:
            kind = f.attrs.get("kind", "")
            return (kind.decode() if isinstance(kind, bytes) else str(kind)) == KIND
    except OSError:
        return False
