"""The comparison table: one chain per seed, its spread over seeds and the paper's claims."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gprace.h2h.protocol.evaluation import calibrate, coverage, offline_error_data, race_predictors
from gprace.h2h.protocol.settings import Settings, chain_dir
from gprace.h2h.protocol.training import models, report_fits
from gprace.h2h.records import RaceAttrs, Record

if TYPE_CHECKING:
    from gprace.h2h.spread import TrackData

def table(st: Settings, raced: dict[str, list[Record[RaceAttrs]]], errors: dict[str, np.ndarray]) -> dict:
    """The paper's table of one seed (:func:`gprace.h2h.table.chain_table`): racing results per
    raced predictor and offline e_y errors per predictor, with the settings and conditions."""
    from gprace.h2h.table import chain_table

    settings = {k: v for k, v in st.model_dump(mode="json").items() if k not in ("workers", "executor", "scheduler", "resume")}
    return chain_table(settings, st.conditions(), {p: raced[p] for p in st.raced}, errors, st.tracks)


def run_chain(st: Settings, out: Path) -> tuple[dict, "TrackData", dict]:
    """One seed of the whole chain (collection, training, exploration, evaluation) in ``out``:
    its table, its results per track and its fit reports."""
    from gprace.h2h.spread import track_data

    paths = models(st, out)
    cal = calibrate(st, out, paths)
    raced = race_predictors(st, out, paths, cal)
    errors, tracks, spread = offline_error_data(st, out, raced, paths)
    fits = report_fits(paths, st.seed)
    tab = table(st, raced, errors)
    tab["coverage"], tab["calibration"] = coverage(spread, errors, cal), cal
    return tab, track_data(raced, errors, tracks, st.tracks), fits


def head2head(st: Settings, out: Path) -> dict:
    """The protocol over ``st.seeds``: one chain per seed (:func:`chain_dir`), every batch through
    the executor; the table of the first seed plus ``per_seed`` tables, ``fits`` (quality reports),
    ``spread`` (every figure over seeds and its bootstrap interval over tracks) and ``claims``."""
    from gprace.h2h.spread import summarise
    from gprace.h2h.table import H2HTable, write_table

    tables, data, fits = {}, [], {}
    for s in st.seeds:
        tab, td, fit = run_chain(st.model_copy(update={"seed": s}), chain_dir(out, s))
        tables[str(s)], fits[str(s)] = tab, fit
        data.append(td)
    spread = summarise(data)
    first = tables[str(st.seeds[0])]
    tab = {**first, "seeds": list(st.seeds), "per_seed": tables, "fits": fits,
           "spread": {k: v for k, v in spread.items() if not k.startswith("diff.")},
           "claims": {k[len("diff."):]: v for k, v in spread.items() if k.startswith("diff.")}}
    tab["settings"] = {k: v for k, v in first["settings"].items() if k != "seed"}
    return write_table(out / "table.json", H2HTable.model_validate(tab))
