"""HDF5 artifacts: one file per stage output, with provenance in root attributes.

Layout: root attributes ``kind`` (run, dataset, model, plan, ...), ``schema`` (int),
``gprace_version``, ``config_hash``, ``seed``, ``created`` (ISO time) plus any scalar or string
``attrs`` of the stage; arrays under ``/data/<name>``; nested groups for structured payloads
(``/groups/<group>/<name>``). No pickle anywhere. Writes are atomic: a temporary file in the same
folder, then :func:`os.replace`. Nothing is written once the command was interrupted
(:func:`gprace.interrupt.check`): what a solver computed across Ctrl-C is not a result.
"""

from __future__ import annotations

import datetime as _dt
import os
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from gprace import __version__, interrupt
from gprace.errors import ArtifactError, InputError

SCHEMA = 1


@dataclass
class Artifact:
    kind: str
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    attrs: dict[str, Any] = field(default_factory=dict)
    groups: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    config_hash: str = ""
    seed: int = 0
    schema: int = SCHEMA
    created: str = ""
    gprace_version: str = __version__


def check_folder(path: str | Path, option: str = "--out") -> Path:
    """``path`` as a folder that can be used or created: an InputError if it, or a folder above
    it, is a file (checked before any work, so nothing is left behind)."""
    path = Path(path)
    for p in (path, *path.parents):
        if p.exists():
            if not p.is_dir():
                raise InputError(f"{option} {path}: {'' if p == path else f'{p} '}is a file, not a folder")
            break
    return path


def check_output(path: str | Path | None, option: str = "--output") -> Path | None:
    """``path`` as a file that can be written: an InputError if it is a folder or a file is in the
    way of its folder (checked where a command starts, before the work whose result it holds)."""
    if path is None:
        return None
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder, not a file")
    in_way = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if in_way is not None:
        raise InputError(f"{option} {path}: cannot create its folder {path.parent}: a file is in the way ({in_way})")
    return path


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through a hidden sibling and :func:`os.replace`: a killed
    run leaves the old file or the new one, never half of one (every JSON record, marker and page
    gprace writes goes through here; the scan skips the hidden sibling)."""
    interrupt.check()
    path = Path(path)
    with staged(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


@contextmanager
def staged(path: Path, tmp: Path | None = None):
    """Yield a hidden sibling of ``path`` to write; on success it replaces ``path``, on any failure
    (Ctrl-C included) it is removed and ``path`` is left as it was."""
    tmp = Path(tmp) if tmp is not None else path.with_name(f".{path.name}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)  # nothing left to remove after the replace


def write_artifact(path: str | Path, art: Artifact) -> Path:
    interrupt.check()
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{path}: cannot create its folder {path.parent}: a file is in the way") from None
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    with staged(path, tmp), h5py.File(tmp, "w") as f:
        f.attrs["kind"] = art.kind
        f.attrs["schema"] = int(art.schema)
        f.attrs["gprace_version"] = __version__
        f.attrs["config_hash"] = art.config_hash
        f.attrs["seed"] = int(art.seed)
        f.attrs["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        for k, v in art.attrs.items():
            f.attrs[k] = _attr(v)
        d = f.create_group("data")
        for k, v in art.arrays.items():
            d.create_dataset(k, data=np.asarray(v))
        g = f.create_group("groups")
        for gname, arrays in art.groups.items():
            sub = g.create_group(gname)
            for k, v in arrays.items():
                sub.create_dataset(k, data=np.asarray(v))
    return path


def read_artifact(path: str | Path, kind: str | tuple[str, ...] | None = None) -> Artifact:
    """Read an artifact; ``kind`` (one or several) is checked with a clear error."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    try:
        f = h5py.File(path, "r")
    except OSError:
        raise ArtifactError(f"{path}: not an HDF5 file (truncated or of another format)") from None
    with f:
        if "kind" not in f.attrs:
            raise ArtifactError(f"{path}: not a gprace artifact (no 'kind' attribute)")
        got = str(f.attrs["kind"])
        wanted = (kind,) if isinstance(kind, str) else kind
        if wanted is not None and got not in wanted:
            raise ArtifactError(f"{path}: is a {got!r} artifact, expected {' or '.join(map(repr, wanted))}")
        schema = int(f.attrs.get("schema", 0))
        if schema > SCHEMA:
            raise ArtifactError(f"{path}: schema {schema} is newer than this gprace ({SCHEMA}); upgrade gprace")
        reserved = {"kind", "schema", "gprace_version", "config_hash", "seed", "created"}
        attrs = {k: _unattr(v) for k, v in f.attrs.items() if k not in reserved}
        arrays = _flat(f["data"]) if "data" in f else {}
        groups = {}
        if "groups" in f:
            for gname, sub in f["groups"].items():
                groups[gname] = _flat(sub)
        return Artifact(
            kind=got,
            arrays=arrays,
            attrs=attrs,
            groups=groups,
            config_hash=str(f.attrs.get("config_hash", "")),
            seed=int(f.attrs.get("seed", 0)),
            schema=schema,
            created=str(f.attrs.get("created", "")),
            gprace_version=str(f.attrs.get("gprace_version", "")),
        )


def _flat(group: "h5py.Group", prefix: str = "") -> dict[str, np.ndarray]:
    """All datasets below ``group``; names with ``/`` (written as nested groups) come back whole."""
    out: dict[str, np.ndarray] = {}
    for k, v in group.items():
        if isinstance(v, h5py.Group):
            out.update(_flat(v, f"{prefix}{k}/"))
        else:
            out[f"{prefix}{k}"] = v[()]
    return out


def _attr(v: Any) -> Any:
    if v is None:
        return "__none__"
    if isinstance(v, (dict, list, tuple)) and not (isinstance(v, (list, tuple)) and all(isinstance(x, (int, float)) for x in v)):
        import json

        return "__json__" + json.dumps(v, default=_json_default)
    return v


def _unattr(v: Any) -> Any:
    if isinstance(v, bytes):
        v = v.decode()
    if isinstance(v, str):
        if v == "__none__":
            return None
        if v.startswith("__json__"):
            import json

            return json.loads(v[len("__json__"):])
    if isinstance(v, np.generic):
        return v.item()
    return v


def _json_default(o: Any) -> Any:
    """numpy values as JSON (:func:`gprace.console.json_default`); nothing else is stored as text."""
    from gprace.console import json_default

    if isinstance(o, (np.generic, np.ndarray)):
        return json_default(o)
    raise TypeError(f"cannot store {type(o).__name__} in an artifact attribute")
