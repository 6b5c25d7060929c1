"""One figure for one result file (``gprace show FILE --plot PNG``), chosen by its kind.

- run (HDF5 or CSV): states and inputs against time; on the track map coloured by speed when
  the run names a loadable track (second figure);
- plan: the line on the track coloured by speed when its track loads, else profiles along s;
- dataset (any kind containing ``dataset``): scatter of the first two inputs coloured by output;
- GP model: posterior mean and standard deviation over two features with the dictionary points;
- h2h_run: the race on its track;
- diagnosis JSON: channels and windows, and the fitted parameters.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gprace.errors import InputError
from gprace.report import figures as F
from gprace.report.inspect import UNREADABLE, artifact_kind, json_kind, open_artifact

if TYPE_CHECKING:
    from gprace.h2h.records import RaceAttrs


def try_track(name: Any):
    """The track of that name or path, or None when it cannot be loaded (never raises)."""
    if not name or not isinstance(name, str):
        return None
    try:
        from gprace.tracks import load_track

        return load_track(name)
    except UNREADABLE:  # a missing track only removes the map
        return None


def h2h_track(attrs: RaceAttrs):
    """The track of a head-to-head race record (from its task's track spec), or None."""
    try:
        from gprace.h2h.geometry import make_track

        return make_track(attrs.task["track"])
    except (*UNREADABLE, ValueError, KeyError, TypeError):  # no task, or one of another layout: no map
        return None


def load_gp(path: str | Path):
    """``(gp, input_names, output_names, Zd)`` of a ``gp_model`` artifact; ``Zd`` the dictionary
    (training or inducing) points in input units, or None.

    The model comes from the GP layer's own reader (:func:`gprace.gp.load_model`); the points
    from the stored state (``state/Z`` of the exact backend, ``state/Zu`` of the sparse one),
    mapped back from the normalised units they are kept in.
    """
    from gprace.gp import load_model

    art = open_artifact(path, ("gp_model", "model"))
    arrays = art.arrays
    saved = load_model(path)
    gp, names_in, names_out = saved.gp, list(saved.input_names), list(saved.output_names)
    Zd = None
    for k in ("state/Z", "state/Zu"):
        if k in arrays and np.ndim(arrays[k]) == 2:
            Zd = np.asarray(arrays[k], float)
            break
    if Zd is not None and "hyper/z_mean" in arrays and Zd.shape[1] == len(arrays["hyper/z_mean"]):
        # the built-in backends store their points in normalised input units
        Zd = Zd * np.asarray(arrays["hyper/z_scale"], float) + np.asarray(arrays["hyper/z_mean"], float)
    if not names_in:
        names_in = [f"z{i}" for i in range(Zd.shape[1] if Zd is not None else 0)]
    return gp, names_in, names_out, Zd


def pick_features(names: list[str], wanted: tuple[str, str] | None = None) -> tuple[int, int]:
    """Indices of the two features to draw: ``wanted`` by name, else the first two."""
    if wanted:
        idx = []
        for w in wanted:
            if w in names:
                idx.append(names.index(w))
            elif w.isdigit() and int(w) < len(names):
                idx.append(int(w))
            else:
                raise InputError(f"--features: {w!r} is not an input of this model (inputs: {', '.join(names)})")
        return idx[0], idx[1]
    return 0, min(1, max(len(names) - 1, 0))


def figures_for(path: str | Path, features: tuple[str, str] | None = None, against: str = "t") -> list[tuple[str, Any]]:
    """``[(caption, Figure), ...]`` for one file (first = the main figure); runs are drawn
    against time (``against='t'``) or arc length (``'s'``)."""
    if against not in ("t", "s"):
        raise InputError(f"--against: 't' (time) or 's' (arc length), got {against!r}")
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        from gprace.ingest.dispatch import read_any

        run = read_any(path)
        return [(f"{path.name}: states and inputs", F.fig_run(run.data, against, title=path.name))]
    if suffix == ".json":
        obj = json.loads(path.read_text())
        if json_kind(obj) == "diagnosis":
            return [
                ("channels and windows", F.fig_channels(obj.get("channels", []), obj.get("regions", []))),
                ("fitted parameters", F.fig_parameters(obj.get("effects", []))),
            ]
        if json_kind(obj) == "h2h_table":
            return [("opponent prediction error", F.fig_pred_errors(obj.get("ey_error", {})))]
        raise InputError(f"{path}: no figure for this JSON (not a diagnosis or head-to-head table)")
    kind = artifact_kind(path)
    if kind is None:
        open_artifact(path)  # raises the precise error
    if kind == "h2h_run":
        return _race_figure(path)
    art = open_artifact(path)
    a, at = art.arrays, art.attrs
    if kind == "run":
        data = {k: v for k, v in a.items() if np.ndim(v) == 1}
        if against not in data:
            raise InputError(f"{path}: run without column {against!r}")
        out = [(f"{path.name}: states and inputs", F.fig_run(data, against, title=path.name))]
        track = try_track(at.get("track"))
        if track is not None and all(c in data for c in ("s", "e_y", "v_x")):
            out.append((f"{path.name}: driven line", F.fig_track_speed(track, data["s"], data["e_y"], data["v_x"],
                                                                      data.get("border_hit"), title=path.name)))
        return out
    if kind == "plan":
        track = try_track(at.get("track"))
        lt = at.get("lap_time")
        title = f"{path.name}" + (f", lap time {float(lt):.2f} s" if lt is not None else "")
        return [(f"{path.name}: plan", F.fig_plan(a, track, title=title))]
    if kind in ("gp_model", "model"):
        gp, names_in, names_out, Zd = load_gp(path)
        if Zd is None:
            raise InputError(f"{path}: the model stores no dictionary points to span a plot")
        i, j = pick_features(names_in, features)
        return [(f"{path.name}: posterior", F.fig_gp_posterior(gp.predict, Zd, names_in, names_out, i, j,
                                                               title=f"{path.name}: GP posterior"))]
    if "dataset" in kind:
        from gprace.gp.dataset import dataset_of

        ds = dataset_of(art, str(path))
        i, j = pick_features(ds.input_names, features)
        return [(f"{path.name}: inputs", F.fig_dataset(ds.Z, ds.Y, ds.input_names, ds.output_names, i, j, title=path.name))]
    # any other kind: points Z coloured by a per-point array, or columns against t or s
    Z = a.get("Z")
    if Z is not None and np.ndim(Z) == 2 and len(Z):
        other = next((v for k, v in a.items() if k != "Z" and np.ndim(v) in (1, 2) and len(v) == len(Z)), None)
        if other is not None:
            names_in = [str(x) for x in at.get("inputs", at.get("input_names", []))]
            i, j = pick_features(names_in or [f"z{k}" for k in range(np.shape(Z)[1])], features)
            return [(f"{path.name}: points", F.fig_dataset(Z, np.reshape(other, (len(Z), -1)), names_in,
                                                          [next(k for k, v in a.items() if v is other)], i, j,
                                                          title=f"{path.name} ({kind})"))]
    for x in ("t", "s"):
        if x in a and np.ndim(a[x]) == 1:
            cols = {k: v for k, v in a.items() if np.ndim(v) == 1 and len(v) == len(a[x])}
            if len(cols) > 1:
                return [(f"{path.name}: arrays", F.fig_run(cols, x, title=f"{path.name} ({kind})"))]
    raise InputError(f"{path}: no figure for artifacts of kind {kind!r} (no point set Z and no t or s column)")


def _race_figure(path: Path) -> list[tuple[str, Any]]:
    """A head-to-head race on its track, read through the race record's schema."""
    from gprace.h2h.records import RaceAttrs, read_record

    rec = read_record(path, RaceAttrs)
    track, a = h2h_track(rec.attrs), rec.arrays
    if track is None or "ego" not in a:
        raise InputError(f"{path}: race record without a loadable track or trajectories")
    return [(f"{path.name}: race", F.fig_race(track, a["ego"], a["opp"], a.get("border_ego"), title=path.name))]


def save_figures(figs: list[tuple[str, Any]], png: str | Path) -> list[Path]:
    """Write the first figure to ``png`` and the others to ``png`` with ``_2``, ``_3`` ... suffixes."""
    png = Path(png)
    if png.parent and not png.parent.exists():
        raise InputError(f"{png}: folder {png.parent} does not exist")
    out = []
    for k, (_, fig) in enumerate(figs):
        p = png if k == 0 else png.with_name(f"{png.stem}_{k + 1}{png.suffix or '.png'}")
        out.append(F.write_png(fig, p))
    return out
