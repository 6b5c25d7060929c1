"""The head-to-head comparison table (``table.json``): one schema, built by the protocol from its
records (:func:`chain_table` per seed, :func:`H2HTable` over seeds), written by
:func:`write_table` and read only through :func:`read_table`.

The file is what it was before the schema (2026-11-24) plus ``version`` (:data:`TABLE_VERSION`):
the same keys and numbers, ``null`` where a figure has no value, ``NaN`` where a seed's figure is
not a number. A table without ``version`` is that older layout (or a hand-trimmed one): read with
one warning, the parts it lacks empty, and never rewritten (it is a result, not a cache). A newer
version, or a field the schema refuses, is a one-line :class:`~gprace.errors.InputError`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import Field

from gprace.config import Frozen
from gprace.io.records import Num, parse_record, read_json

if TYPE_CHECKING:
    from gprace.h2h.records import RaceAttrs, Record

TABLE_VERSION = 2  # 2: the claims' tracks, and "too few samples for a verdict" (issue 38)


class FailedRace(Frozen):
    scenario: int = Field(ge=0, description="the evaluation scenario (track) whose race failed")
    reason: str = Field(description="the first line of its error")


class RacingRow(Frozen):
    """One raced predictor over the evaluation scenarios of one seed."""

    runs: int = Field(ge=0, description="races")
    failed: int = Field(0, ge=0, description="races that did not run to their end")
    failed_where: list[FailedRace] = Field(default_factory=list, description="the failed races")
    border_hits: int = Field(0, ge=0, description="finished races in which the ego touched a border")
    collisions: int = Field(0, ge=0, description="finished races in which the cars touched")
    overtakes: int = Field(0, ge=0, description="races with an overtake")
    overtake_time_mean: float | None = Field(None, description="mean overtake time over the scenarios every "
                                             "raced predictor finished inside the track [s]")
    overtake_time_std: float | None = Field(None, description="its standard deviation [s]")
    overtake_scenarios: int = Field(0, ge=0, description="scenarios behind the mean overtake time")
    fallbacks_ego: int = Field(0, ge=0, description="steps the ego drove on its previous plan")
    ego_solve_ms_median: float | None = Field(None, description="median NMPC solve time of the ego [ms]")


class ErrorRow(Frozen):
    """A predictor's offline e_y error over all closed-loop opponent trajectories, per step ahead."""

    mean: list[Num] = Field(description="mean absolute error at 1..K steps ahead [m]")
    std: list[Num] = Field(description="its standard deviation [m]")
    points: int = Field(ge=0, description="start times behind it")


class CoverageRow(Frozen):
    """Share of the evaluation errors inside the predicted 2-sigma band, per step ahead."""

    s: list[Num] = Field(description="s error, with the calibrated band")
    ey: list[Num] = Field(description="e_y error, with the calibrated band")
    s_raw: list[Num] = Field(description="s error, with the predictor's own band")
    ey_raw: list[Num] = Field(description="e_y error, with the predictor's own band")
    points: int = Field(ge=0, description="start times")
    calibrated: bool = Field(description="the predictor has a calibration")


class ChainTable(Frozen):
    """The table of one seed of the whole chain."""

    settings: dict[str, Any] = Field(default_factory=dict, description="the protocol's settings (no executor "
                                     "settings)")
    conditions: dict[str, Any] = Field(default_factory=dict, description="noise, baseline tracks, blocking "
                                       "weight and exploration time, in the units the race uses")
    common_inside: int = Field(0, ge=0, description="scenarios every raced predictor finished inside the track")
    racing: dict[str, RacingRow] = Field(default_factory=dict, description="per raced predictor")
    ey_error: dict[str, ErrorRow] = Field(default_factory=dict, description="per predictor")
    coverage: dict[str, CoverageRow] = Field(default_factory=dict, description="per predictor with a spread")
    calibration: dict[str, Any] = Field(default_factory=dict, description="per predictor: the spread's scale "
                                        "and floor the races used (gprace.h2h.spread)")


class Figure(Frozen):
    """One figure of the table over seeds."""

    values: list[Num] = Field(description="per seed")
    mean: float | None = Field(description="mean over seeds (None: no seed has a value)")
    seed_std: float | None = Field(description="sample standard deviation over seeds (None: one seed)")
    min: float | None = Field(description="smallest over seeds")
    max: float | None = Field(description="largest over seeds")
    ci: list[float | None] = Field(description="95 % bootstrap interval over tracks of the seed mean")


class Claim(Figure):
    """Exploration minus baseline for one of the paper's claims."""

    seed_ci: list[list[float | None]] = Field(description="each seed's 95 % interval over tracks")
    tracks: int | None = Field(None, description="tracks behind the difference, fewest over seeds (None: a table "
                               "of before version 2)")
    verdict: str = Field(description="holds, fails, seeds disagree, not resolved or too few samples for a verdict "
                         "(gprace.verdict)")

    def shown_verdict(self, tracks: int | None = None) -> str:
        """The verdict, or too few samples where the tracks behind it (``tracks`` for a table of
        before version 2, which stored no count) are below the minimum (gprace.verdict)."""
        from gprace.verdict import MIN_SAMPLES, TOO_FEW

        n = self.tracks if self.tracks is not None else tracks
        return TOO_FEW if n is not None and n < MIN_SAMPLES else self.verdict


class H2HTable(ChainTable):
    """``table.json``: the first seed's table, every seed's, the fits, and the figures over seeds."""

    version: int = Field(TABLE_VERSION, description="layout version of the table")
    seeds: list[int] = Field(default_factory=lambda: [0], description="the chains (--seeds)")
    per_seed: dict[str, ChainTable] = Field(default_factory=dict, description="per seed: its table")
    fits: dict[str, dict[str, Any]] = Field(default_factory=dict, description="per seed and model: the fit "
                                            "quality report (gprace.gp.quality.FitQuality)")
    spread: dict[str, Figure] = Field(default_factory=dict, description="per predictor and figure")
    claims: dict[str, Claim] = Field(default_factory=dict, description="per claim: exploration - baseline")


def racing_row(recs: list[Record[RaceAttrs]], inside: np.ndarray) -> dict:
    """One raced predictor's row; overtake times over the scenarios ``inside``."""
    ok = [r.attrs for r in recs if r.attrs.ok]
    ot = np.array([r.attrs.overtake_time if r.attrs.ok else np.nan for r in recs], float)
    common = ot[inside]
    common = common[np.isfinite(common)]
    ms = np.concatenate([np.asarray(r.arrays.get("ego_solve_ms", [])) for r in recs if r.attrs.ok]) if ok else np.zeros(0)
    return {
        "runs": len(recs), "failed": len(recs) - len(ok),
        "failed_where": [{"scenario": i, "reason": (r.attrs.error or "failed").strip().splitlines()[0]}
                         for i, r in enumerate(recs) if not r.attrs.ok],
        "border_hits": sum(a.border_hit for a in ok),
        "collisions": sum(a.collision for a in ok),
        "overtakes": int(np.isfinite(ot).sum()),
        "overtake_time_mean": float(common.mean()) if len(common) else None,
        "overtake_time_std": float(common.std()) if len(common) else None,
        "overtake_scenarios": int(len(common)),
        "fallbacks_ego": sum(a.fallbacks_ego for a in ok),
        "ego_solve_ms_median": float(np.median(ms)) if len(ms) else None,
    }


def chain_table(settings: dict, conditions: dict, raced: dict[str, list[Record[RaceAttrs]]],
                errors: dict[str, np.ndarray], tracks: int) -> dict:
    """The table of one seed: racing rows of the raced predictors over ``tracks`` scenarios and the
    offline errors ``{predictor: (K, start times)}``."""
    inside = np.ones(tracks, dtype=bool)
    for recs in raced.values():
        for i, r in enumerate(recs):
            inside[i] &= r.attrs.ok and not r.attrs.border_hit
    err = {p: {"mean": E.mean(axis=1).tolist() if E.shape[1] else [], "std": E.std(axis=1).tolist() if E.shape[1] else [],
               "points": int(E.shape[1])} for p, E in errors.items()}
    return {"settings": settings, "conditions": conditions, "common_inside": int(inside.sum()),
            "racing": {p: racing_row(recs, inside) for p, recs in raced.items()}, "ey_error": err}


def failed_races_text(row: RacingRow, most: int = 5) -> str:
    """'k of n' failed races of one predictor's row, and where (scenario and reason)."""
    text = f"{row.failed} of {row.runs}"
    if row.failed_where:
        text += ": " + "; ".join(f"scenario {f.scenario}: {f.reason}" for f in row.failed_where[:most])
        text += f"; ... ({len(row.failed_where) - most} more)" if len(row.failed_where) > most else ""
    return text


def write_table(path: str | Path, table: H2HTable) -> dict:
    """Write ``table`` atomically (a figure that is not a number as ``NaN``, as before the schema);
    returns its dump."""
    from gprace.console import json_default
    from gprace.io.artifacts import write_text_atomic

    dump = table.model_dump()
    write_text_atomic(path, json.dumps(dump, indent=2, default=json_default))
    return dump


def read_table(path: str | Path) -> H2HTable:
    """``table.json`` through :class:`H2HTable` (an old layout: one warning, never rewritten)."""
    return parse_table(read_json(path, "head-to-head table"), str(path))


def parse_table(data: Any, where: str) -> H2HTable:
    """A parsed ``table.json`` through :class:`H2HTable`."""
    return parse_record(H2HTable, data, where, "head-to-head table", "the parts it lacks are empty")[0]
