"""Recordings ("runs"): time series of the Frenet state and inputs.

Columns (SI units; DESIGN.md section 7): ``t, s, e_y, e_psi, v_x, v_y, yaw_rate, delta, a_x,
kappa``. Extra columns (``lap``, ``a_x_cmd``, ``border_hit`` ...) are kept. ``s`` is the arc
length along the track within the lap, in ``[0, L)`` for closed tracks. A run may carry the
nominal vehicle it was recorded against (``meta["vehicle_toml"]``), its track (``meta["track"]``)
and its period (``meta["dt"]``).

HDF5 runs are artifacts of kind ``run``; CSV runs have a header row, any column order.

gprace's own closed loops (``simulate``, the time trial's drive) mark their runs with
``meta[OWN_RUN] = True``: the unit check is meant for a user's files, and on a lap in which the
car spun it would read the slide as a units error (v_y of 8 m/s looks like km/h). Structure,
finiteness and time order are still checked.

``meta["inputs"]`` says what the input columns hold (issue 36): ``{"delta": "commanded" |
"measured", "a_x": "commanded" | "measured" | "derived" | "absent"}`` (plus ``"v_cmd":
"commanded"`` with a speed-command column); a run without it is read as
:data:`DEFAULT_INPUTS`. HDF5 keeps it as an attribute; a CSV run written with it gets its meta in
``<name>.meta.json`` beside it, with the CSV's sha256, and :func:`read_run` reads it back when
the sha256 still matches.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gprace.errors import InputError, at_row
from gprace.interrupt import check
from gprace.io.artifacts import Artifact, read_artifact, staged, write_artifact

RUN_COLUMNS = ("t", "s", "e_y", "e_psi", "v_x", "v_y", "yaw_rate", "delta", "a_x", "kappa")
STATE_COLUMNS = ("v_x", "v_y", "yaw_rate", "e_psi", "e_y", "s")
INPUT_COLUMNS = ("delta", "a_x")
DEFAULT_INPUTS = {"delta": "commanded", "a_x": "commanded"}
"""What a run without ``meta["inputs"]`` holds: gprace's own recordings log the commands."""

# Plausibility limits on ROBUST statistics of the whole file (a quantile, never the maximum: a
# spin or a slide in one corner is data, handled by gprace.io.envelope, not a units error):
# column -> (quantile of |x|, limit in SI units, probable wrong unit when above)
OWN_RUN = "own_run"  # meta key: a run recorded by gprace's own loop (no user-file unit check)

_PLAUSIBLE = {
    "v_x": (0.5, 120.0, "km/h instead of m/s?"),
    "v_y": (0.9, 8.0, "km/h instead of m/s?"),
    "yaw_rate": (0.9, 6.0, "deg/s instead of rad/s?"),  # a 1:10 car turns at 3 rad/s; deg/s is also named by the heading check
    "e_psi": (0.9, 1.0, "degrees instead of rad?"),  # a car drifting round a skidpad holds 0.9 rad
    "delta": (0.9, 0.5, "degrees instead of rad? steering-wheel instead of road-wheel angle?"),
    "a_x": (0.9, 30.0, "not m/s^2?"),
}


@dataclass
class Run:
    data: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    source: str = "<memory>"

    def __post_init__(self) -> None:
        check_columns(self.data, self.source, units=not self.meta.get(OWN_RUN, False))

    @property
    def n(self) -> int:
        return len(self.data["t"])

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[name]
        except KeyError:
            raise InputError(f"{self.source}: no column {name!r}") from None

    @property
    def dt(self) -> float:
        if "dt" in self.meta and self.meta["dt"]:
            return float(self.meta["dt"])
        return float(np.median(np.diff(self.data["t"])))

    def states(self) -> np.ndarray:
        """(n, 6) array in the model's state order ``[v_x, v_y, yaw_rate, e_psi, e_y, s]``."""
        return np.column_stack([self.data[c] for c in STATE_COLUMNS])

    def inputs(self) -> np.ndarray:
        """(n, 2) array ``[delta, a_x]``."""
        return np.column_stack([self.data[c] for c in INPUT_COLUMNS])

    @property
    def inputs_kind(self) -> dict[str, str]:
        """``meta["inputs"]``, or :data:`DEFAULT_INPUTS` for a run without it."""
        return {**DEFAULT_INPUTS, **(self.meta.get("inputs") or {})}

    def vehicle(self):
        """The nominal vehicle the run carries, or None."""
        from gprace.config import VehicleConfig, validate
        import tomllib

        text = self.meta.get("vehicle_toml")
        if not text:
            return None
        return validate(VehicleConfig, tomllib.loads(text), f"{self.source} (embedded vehicle)")

    def slice(self, mask: np.ndarray) -> "Run":
        return Run({k: v[mask] for k, v in self.data.items()}, dict(self.meta), self.source)


def check_columns(data: dict[str, np.ndarray], source: str, units: bool = True) -> None:
    """Columns, lengths, finiteness, time order and (``units``) units; rows as
    :func:`gprace.errors.at_row` counts them (samples from 1, the header of a CSV not counted)."""
    missing = [c for c in RUN_COLUMNS if c not in data]
    if missing:
        raise InputError(f"{source}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    n = len(data["t"])
    if n < 2:
        raise InputError(f"{source}: recording has {n} sample(s); need at least 2")
    for c in RUN_COLUMNS:
        a = np.asarray(data[c], dtype=float)
        if a.shape != (n,):
            raise InputError(f"{source}: column {c!r} has {a.shape} values, expected ({n},)")
        bad = ~np.isfinite(a)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"{source}: column {c!r} has a non-finite value ({a[i]}) at {at_row(i + 1)}")
        data[c] = a
    if np.any(np.diff(data["t"]) <= 0):
        i = int(np.argmax(np.diff(data["t"]) <= 0))
        raise InputError(f"{source}: column 't' is not strictly increasing at {at_row(i + 2)}")
    if not units:
        return
    from gprace.io.units import check_units

    check_units(data, source, _PLAUSIBLE)  # robust statistics + consistency between channels


def read_run(path: str | Path) -> Run:
    """A run from HDF5 or a Frenet CSV, and nothing else. A stage that also takes raw recordings
    (ROS bag / MCAP, MDF4, a global-frame CSV) reads through
    :func:`gprace.ingest.dispatch.read_any`, which imports them first."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a recording file (CSV or HDF5 run, or a raw recording)")
    if path.suffix.lower() == ".csv":
        return _read_csv(path)
    art = read_artifact(path, "run")
    return Run(dict(art.arrays), dict(art.attrs), str(path))


def write_run(run: Run, path: str | Path, config_hash: str = "", seed: int = 0) -> Path:
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return write_run_csv(run, path)
    return write_artifact(path, Artifact("run", arrays=dict(run.data), attrs=dict(run.meta), config_hash=config_hash, seed=seed))


def write_run_csv(run: Run, path: str | Path) -> Path:
    path = Path(path)
    cols = list(RUN_COLUMNS) + [c for c in run.data if c not in RUN_COLUMNS and np.ndim(run.data[c]) == 1]
    arr = np.column_stack([np.asarray(run.data[c], dtype=float) for c in cols])
    check()  # a run driven across Ctrl-C is not a result
    path.parent.mkdir(parents=True, exist_ok=True)
    with staged(path) as tmp:
        np.savetxt(tmp, arr, delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
    if "inputs" in run.meta:
        _write_sidecar(run.meta, path)
    return path


def sidecar(path: Path) -> Path:
    """``<name>.meta.json`` beside a CSV run."""
    return path.with_name(path.stem + ".meta.json")


def _write_sidecar(meta: dict, path: Path) -> None:
    import hashlib
    import json

    from gprace.io.artifacts import write_text_atomic

    doc = dict(meta, csv_sha256=hashlib.sha256(path.read_bytes()).hexdigest())
    write_text_atomic(sidecar(path), json.dumps(doc, indent=1, default=str))


def _read_sidecar(path: Path) -> dict:
    """The meta of a CSV run from its sidecar, when it was written for this very file."""
    import hashlib
    import json

    sc = sidecar(path)
    if not sc.is_file():
        return {}
    try:
        doc = json.loads(sc.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(doc, dict) or doc.pop("csv_sha256", None) != hashlib.sha256(path.read_bytes()).hexdigest():
        return {}
    return doc


def _read_csv(path: Path) -> Run:
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV file") from None
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    rows = list(csv.reader(line for _, line in lines))
    if not rows:
        raise InputError(f"{path}: empty file")
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    data: dict[str, list[float]] = {h: [] for h in header}
    for i, row in enumerate(body, start=1):  # rows count samples from 1 (at_row), as in check_columns
        where = at_row(i, lines[i][0])
        if len(row) != len(header):
            raise InputError(f"{path}: {where} has {len(row)} fields, header has {len(header)} (truncated file?)")
        for h, v in zip(header, row):
            try:
                data[h].append(float(v))
            except ValueError:
                raise InputError(f"{path}: column {h!r} {where}: {v!r} is not a number") from None
    arrays = {h: np.asarray(v, dtype=float) for h, v in data.items()}
    return Run(arrays, _read_sidecar(path), str(path))
