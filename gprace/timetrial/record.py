"""The time trial's records, one schema each, written and read only through this module:

* the iteration record (``trial_J/iter_II/record.json``): :class:`IterationRecord`, through
  :func:`write_record` and :func:`read_record`;
* the run summary (``summary.json``, what ``gprace iterate --json`` and ``eval iterate`` print):
  :class:`IterateSummary`, built by :func:`gprace.timetrial.summary.build_summary`, read by
  :func:`read_summary`. It is derived from the records: a summary of another layout is not
  migrated; readers (the report, ``gprace eval iterate FOLDER``) summarise the records instead,
  and the next ``gprace iterate`` into the folder rewrites it.

The file is JSON with ``null`` for a number that is not one (a lap not completed has no driven
time); :func:`read_record` gives it back as NaN. Both readers return the frozen models, never dicts:
read a field as an attribute (``rec.driven``) and make a changed copy with ``model_copy(update=...)``. ``version`` is :data:`RECORD_VERSION`. A record
without it is the layout of before the schema (2026-11-24): the same fields, any of them but the
lap's (iteration, trial, alpha, planned, driven, completed) missing in older folders; it is
migrated once (rewritten with the defaults below and the version) with a warning, so an old
folder resumes and reports.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import Field, model_validator

from gprace.config import Frozen
from gprace.console import jsonable
from gprace.errors import InputError
from gprace.io.artifacts import write_text_atomic
from gprace.io.records import NAN, Num, parse_record, read_json, validated

RECORD_VERSION = 1
SUMMARY_VERSION = 1


class _ReadByKey:
    """Read-only ``rec["field"]`` and ``rec.get("field", default)`` on a frozen record: the guard's
    functions (``gprace.timetrial.guard``) read laps by key, as ``gprace learn`` keeps them in dicts;
    code of the time trial reads attributes. Nothing can be set through it."""

    def __getitem__(self, key: str) -> Any:
        if key not in type(self).model_fields:
            raise KeyError(key)
        return getattr(self, key)

    def get(self, key: str, default: Any = None) -> Any:
        return getattr(self, key) if key in type(self).model_fields else default


class IterationRecord(_ReadByKey, Frozen):
    """One driven lap of one iteration of one trial, and the GPs it was driven with."""

    version: int = Field(RECORD_VERSION, description="layout version of the record")
    iteration: int = Field(ge=0, description="0: the nominal model's lap; i >= 1: after i GP updates")
    trial: int = Field(ge=0, description="independent repetition")
    alpha: Num = Field(description="exploration weight the lap was driven with")
    planned: Num = Field(description="the plan's lap time [s]")
    driven: Num = Field(description="the driven lap time [s]; NaN if the lap was not completed")
    completed: bool = Field(description="the lap was completed")
    reason: str = Field("", description="why the run stopped early (empty if it did not)")
    gap: Num = Field(NAN, description="driven minus planned [s] (an old record without it: computed)")
    solve_median_ms: Num = Field(NAN, description="median QP solve time of the tracking MPC [ms]")
    solve_p99_ms: Num = Field(NAN, description="99th percentile of the QP solve time [ms]")
    border_hits: int = Field(0, ge=0, description="steps with a wheel outside a border")
    fallbacks: int = Field(0, ge=0, description="steps driven on the previous solution (a QP failed)")
    samples: int = Field(0, ge=0, description="samples of the run")
    replan_failed: bool = Field(False, description="the re-plan failed and an earlier plan was driven")
    err_tracking: Num = Field(NAN, description="tracking GP: normalised RMS error on the held-out run")
    dict_tracking: int = Field(0, ge=0, description="tracking GP: dictionary size")
    cov_tracking: Num = Field(NAN, description="tracking GP: share of held-out errors in its 95 % band")
    err_planning: Num = Field(NAN, description="planning GP: normalised RMS error on the held-out run")
    dict_planning: int = Field(0, ge=0, description="planning GP: dictionary size")
    cov_planning: Num = Field(NAN, description="planning GP: share of held-out errors in its 95 % band")
    limits: list[float] = Field(default_factory=list, description="friction ellipse the plan used: lateral, "
                                "drive, brake [m/s^2]")
    envelope: list[float] = Field(default_factory=list, description="measured lateral, drive and brake "
                                  "accelerations of the in-control samples [m/s^2]")
    utilisation: Num = Field(NAN, description="robust peak rear slip over the nominal tire's peak slip")
    status: str = Field("", description="good, lost (not completed) or slower (an alpha-0 lap slower than the best so "
                        "far); empty in records before issue 37")
    interventions: int = Field(0, ge=0, description="stability-envelope interventions during the lap")
    eased_steps: int = Field(0, ge=0, description="periods driven with the reference speed eased")
    weaves: int = Field(0, ge=0, description="growing yaw weaves the stability envelope saw during the lap")
    band: list[float] = Field(default_factory=list, description="stability-envelope bands at the end of the lap "
                              "(gprace.mpc.stability.SIGNALS: e_r, e_beta, d_r, d_beta)")
    delay: Num = Field(NAN, description="total steering and measurement delay the MPC predicted over [s] (iteration 0: "
                       "the shakedown's estimate or the known delay)")
    delay_source: str = Field("", description="known (configured) or estimated (the shakedown)")
    plan_source: str = Field("", description="where the driven plan came from: shakedown, curvature plan, replan, "
                             "back to iteration k, last good plan, replan failed")
    safety: dict[str, float | str] = Field(default_factory=dict, description="the plan's predicted safety "
                                           "(gprace.timetrial.guard.plan_safety)")
    sensors: dict[str, float] = Field(default_factory=dict, description="iteration 0: the sensor calibration every "
                                      "lap was corrected by (gprace.mpc.sensors: yaw_rate_bias [rad/s], velocity_angle "
                                      "[rad]); empty when the sensors read true")

    @property
    def envelope_events(self) -> int:
        """The times the lap needed the stability envelope: its interventions and weaves (a weave
        counts as the envelope's for the limits, :mod:`gprace.timetrial.grip`)."""
        return self.interventions + self.weaves

    @model_validator(mode="before")
    @classmethod
    def _gap_of_old_record(cls, data: Any) -> Any:
        if isinstance(data, dict) and "gap" not in data and all(
                isinstance(data.get(k), (int, float)) for k in ("driven", "planned")):
            data = {**data, "gap": data["driven"] - data["planned"]}
        return data


class SummaryRow(IterationRecord):
    """An iteration record in the summary, with the share of the gap to the oracle it closed."""

    gap_closed: Num = Field(NAN, description="(iteration-0 lap - this lap) / (iteration-0 lap - oracle lap) "
                              "of the trial; NaN without an oracle")


class FailedLap(Frozen):
    trial: int = Field(ge=0, description="the trial whose lap failed")
    reason: str = Field(description="where and why (the lap's record)")


class IterationSummary(Frozen):
    """One iteration over all trials: means and spreads of the laps, the GPs' worst coverage."""

    iteration: int = Field(ge=0, description="the iteration")
    alpha: Num = Field(description="exploration weight of the iteration")
    trials: int = Field(ge=0, description="trials with a record for this iteration")
    planned_mean: Num = Field(description="mean planned lap time [s]")
    planned_std: Num = Field(description="its standard deviation over trials [s]")
    driven_mean: Num = Field(description="mean driven lap time of the completed laps [s]")
    driven_std: Num = Field(description="its standard deviation [s]")
    gap_mean: Num = Field(description="mean driven minus planned lap time [s]")
    err_tracking: Num = Field(description="mean held-out error of the tracking GP (NaN at iteration 0)")
    err_planning: Num = Field(description="mean held-out error of the planning GP (NaN at iteration 0)")
    cov_tracking: Num = Field(description="worst 95 %-band coverage of the tracking GP over trials")
    cov_planning: Num = Field(description="worst 95 %-band coverage of the planning GP over trials")
    gap_closed_min: Num = Field(description="smallest share of the gap to the oracle closed over trials")
    completed: int = Field(ge=0, description="completed laps")
    failed: list[FailedLap] = Field(description="the laps not completed")
    interventions: int = Field(0, ge=0, description="stability-envelope interventions over the trials' laps")


class TrialSummary(Frozen):
    """One trial: its iteration-0 lap and its best racing lap (alpha 0, after exploring)."""

    trial: int = Field(ge=0, description="the trial")
    iteration0: Num = Field(description="driven lap time of iteration 0 [s]")
    best_alpha0: Num = Field(description="best completed alpha-0 lap after iteration 0 [s]")
    best_iteration: int | None = Field(description="the iteration of that lap (None: none completed)")
    gap_closed_best: Num = Field(description="share of the gap to the oracle that lap closed")


class IterateSummary(Frozen):
    """``summary.json`` of an iterate folder: the experiment, the oracle lap, every record, and the
    aggregates by iteration and by trial."""

    version: int = Field(SUMMARY_VERSION, description="layout version of the summary")
    settings: dict[str, Any] = Field(description="the experiment (settings.json)")
    oracle: dict[str, Any] | None = Field(description="oracle.json (None before the oracle lap is done)")
    rows: list[SummaryRow] = Field(description="every finished record, by iteration and trial")
    by_iteration: list[IterationSummary] = Field(description="aggregates per iteration")
    per_trial: list[TrialSummary] = Field(description="aggregates per trial")


def write_json(path: Path, obj) -> None:
    """``obj`` as JSON (NaN as ``null``), atomically: a killed run leaves the old file or the new
    one, never half of one. Every JSON file of an iterate folder is written by it."""
    write_text_atomic(path, json.dumps(jsonable(obj), indent=1, allow_nan=False))


def write_record(path: Path, record: IterationRecord) -> None:
    write_json(path, record.model_dump())


def read_record(path: Path, migrate: bool = True) -> IterationRecord:
    """The record at ``path`` (NaN for ``null``), validated by :class:`IterationRecord`.
    A record of the layout before the schema is read with a warning and, with ``migrate``,
    rewritten in the current layout (a reader that only looks, like the report, passes False)."""
    path = Path(path)
    data = read_json(path, "iteration record")
    rec, old = parse_record(IterationRecord, data, str(path), "iteration record",
                            "missing fields set to their defaults" + ("; migrated" if migrate else ""))
    if old and migrate:
        write_record(path, rec)
    return rec


def read_summary(path: Path) -> IterateSummary:
    """``summary.json`` validated by :class:`IterateSummary` (NaN for ``null``). A summary
    of another layout (written before its schema, or by a newer gprace) is an :class:`InputError`
    saying how to rebuild it from the records."""
    path = Path(path)
    data = read_json(path, "summary")
    version = data.get("version") if isinstance(data, dict) else None
    if version != SUMMARY_VERSION:
        raise InputError(f"{path}: summary of layout {version or 'before version 1'}, this gprace reads "
                         f"{SUMMARY_VERSION}; `gprace eval iterate {path.parent}` summarises the records instead")
    return validated(IterateSummary, data, str(path))
