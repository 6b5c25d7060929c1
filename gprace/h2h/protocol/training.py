"""The protocol's opponent GPs: fits checked against the validation set, diverse selections."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from gprace.config import config_hash
from gprace.errors import InputError
from gprace.h2h.predictors import FEATURE_MAP, FEATURES, OUTPUTS
from gprace.h2h.protocol.data import _cached, _hash_file, collect, explore, read_dataset
from gprace.h2h.protocol.settings import GP_SETTINGS, QUALITY_VERSION, Settings

def train(dataset: Path, model: Path, st: Settings, size: int | None = None, hyper_model: Path | None = None,
          initial: Path | None = None, seed: int = 0, validation: Path | None = None) -> Path:
    """Fit the opponent GP (Matern 1.5) on a dataset, checked by :func:`gprace.gp.quality.checked_fit`.

    With ``size``, the points are first streamed through the GP layer's diverse selection
    (:func:`gprace.gp.selection.select_diverse`) with the hyperparameters of ``hyper_model``,
    starting from the dictionary ``initial`` (a dataset) when given; the GP is then refitted on
    the selected dictionary. The fit's quality report (held-out points: ``validation``, a dataset)
    is stored in the model's ``quality`` attribute; a degenerate fit is retried and then refused
    (:class:`~gprace.errors.FitError`), and no model file is written.
    """
    from gprace.gp.quality import checked_fit
    from gprace.h2h.predictors import load_opponent_gp, save_opponent_gp

    key = {"data": _hash_file(dataset), "size": size, "backend": st.backend, "exact_max": st.exact_max,
           "inducing": st.inducing, "seed": seed, "optimize": st.optimize,
           "hyper": _hash_file(hyper_model) if hyper_model else None, "initial": _hash_file(initial) if initial else None,
           "validation": _hash_file(validation) if validation else None, "quality": QUALITY_VERSION,
           "gp_settings": GP_SETTINGS}
    if _cached(model, key):
        return model
    Z, Y = read_dataset(dataset)
    extra = {}
    if size is not None:
        from gprace.gp.selection import select_diverse

        if hyper_model is None:
            raise InputError("diverse selection needs a fitted GP for its hyperparameters")
        hyper = load_opponent_gp(hyper_model).hyper_
        init = read_dataset(initial) if initial is not None else None
        Z, Y, stats = select_diverse(hyper, Z, Y, size, initial=init)
        extra = {f"selection_{k}": int(v) for k, v in stats.as_dict().items()}
    backend = st.backend if st.backend != "auto" else ("exact" if len(Z) <= st.exact_max else "sparse")
    settings: dict[str, Any] = {"kernel": "matern15", "seed": seed, "optimize": st.optimize}
    settings.update(GP_SETTINGS.get(backend, {}))
    if backend == "sparse":
        settings["n_inducing"] = min(st.inducing, len(Z))
    import time

    from gprace.console import console

    console.info(f"h2h train: fitting the {backend} opponent GP on {len(Z)} points ({model.name})")
    t0 = time.perf_counter()
    Zv, Yv = read_dataset(validation) if validation is not None else (None, None)
    gp, quality = checked_fit(backend, settings, Z, Y, Zv, Yv, outputs=OUTPUTS, inputs=FEATURES, what=str(model))
    meta = {"fit_s": time.perf_counter() - t0, "feature_map": FEATURE_MAP, "input_names": list(FEATURES), "output_names": list(OUTPUTS),
            "n_points": len(Z), "y_std": json.dumps(Y.std(axis=0).tolist()), "quality": quality.to_json(), **extra}
    model.parent.mkdir(parents=True, exist_ok=True)
    return save_opponent_gp(model, gp, meta, config_hash=config_hash(key), seed=seed)


def fit_report(model: Path | dict):
    """The :class:`~gprace.gp.quality.FitQuality` stored with a model (its path, or its attributes
    already read), None for a model from before the reports."""
    from gprace.gp.quality import FitQuality
    from gprace.h2h.predictors import read_opponent_gp

    attrs = model if isinstance(model, dict) else read_opponent_gp(model)[1]
    text = attrs.get("quality")
    return FitQuality.from_json(str(text)) if text else None


def models(st: Settings, out: Path) -> dict[str, Path]:
    """All GP models of the protocol (cached): baseline (all collection data), init (first
    ``init_runs``), explore (diverse selection of init + exploration data, init's hyperparameters),
    select (diverse selection of the baseline data, baseline's hyperparameters, same size). Every
    fit is checked against the validation set (see :func:`train`; :func:`report_fits` prints them)."""
    d = collect(st, out)
    m = out / "models"
    fit = dict(seed=st.seed, validation=d["validation"])
    paths = {"baseline": train(d["collect"], m / "baseline.h5", st, **fit), "init": train(d["init"], m / "init.h5", st, **fit)}
    ex = explore(st, out, paths["init"], d["init"])
    paths["explore"] = train(ex, m / "explore.h5", st, size=st.dict_size, hyper_model=paths["init"], initial=d["init"], **fit)
    from gprace.h2h.predictors import read_opponent_gp

    n_explore = int(read_opponent_gp(paths["explore"])[1].get("n_points", st.dict_size))
    paths["select"] = train(d["collect"], m / "select.h5", st, size=n_explore, hyper_model=paths["baseline"], **fit)
    return paths


def report_fits(paths: dict[str, Path], seed: int = 0) -> dict[str, Any]:
    """Read every model's quality report once, print one line per model (and its warnings);
    ``{name: report as a dict}``."""
    from gprace.console import console

    out = {}
    for name, path in paths.items():
        q = fit_report(path)
        out[name] = asdict(q)
        worst = int(np.argmax(np.asarray(q.heldout) / np.asarray(q.reference)))
        console.info(f"fit {name}{'' if seed == 0 else f' (seed {seed})'}: held-out error "
                     f"{' '.join(f'{h:.3f}' for h in q.heldout)} (exact GP on {q.reference_points} points: "
                     f"{' '.join(f'{r:.3f}' for r in q.reference)}), noise max {max(q.noise):.2g}, worst "
                     f"{q.outputs[worst]}, attempts {q.attempts}")
        if q.cautions():
            console.warn(f"fit {name}: {q.cautions()}")
    return out
