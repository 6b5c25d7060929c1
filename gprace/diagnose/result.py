"""The diagnosis result (``gprace diagnose ... --json``): one schema, built by the pipeline and read
only through :func:`parse_result` / :func:`read_result`.

The JSON is :meth:`DiagnosisResult.to_json` (``null`` for a number that is not one; a reader gets
NaN back). ``version`` is :data:`RESULT_VERSION`. A result without it is the layout of before the
schema: the same keys, without the stored residual profile, some of them missing in
older or hand-trimmed files; it is read with one warning and the defaults below, and never
rewritten (users keep it where they saved it; only readers meet it). A newer version is refused
with a one-line :class:`~gprace.errors.InputError`.

The residual profile is what the residual-along-track figure draws: the diagnosis computes it
once, so the report and ``--plot`` draw it without simulating anything again.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_serializer, model_validator

from gprace.config import Frozen
from gprace.console import jsonable
from gprace.io.records import NAN, Num, parse_record, read_json

RESULT_VERSION = 2
"""2 (issue 36): the inputs and calibration sections, calibrated RMSEs per channel, the envelope's scale."""
SIGNIFICANT = 5
"""Significant digits of the stored profile's errors (a 10 m bin's mean error; the JSON stays small)."""


class SubsetPredictability(Frozen):
    """A regime or stretch of the lap where the channel's error is predictable out of sample."""

    subset: str = Field(description="the subset: a regime ('drive while cornering') or 's 200..400 m'")
    t: Num = Field(description="paired block t of the held-out gain in the subset")
    heldout_share: Num = Field(description="held-out share of the subset's error mean square predicted")


class Predictability(Frozen):
    """Held-out predictability of a channel's multi-step error from regime and place."""

    t: Num = Field(description="paired block t of the held-out gain over all windows")
    heldout_share: Num = Field(description="held-out share of the error mean square predicted, all windows")
    where: list[SubsetPredictability] = Field(default_factory=list,
                                              description="subsets whose test passed the corrected threshold")


_ABSENT_WHEN_NONE = frozenset({"predictability", "heldout_rmse_nominal", "heldout_rmse_augmented", "regime",
                               "rmse_calibrated", "heldout_rmse_calibrated"})


class Channel(Frozen):
    """One tested channel (v_x, v_y, yaw_rate, e_psi, e_y): structured error or noise."""

    name: str = Field(description="channel name")
    structured: bool = Field(description="the nominal model's error on it is structured, not noise")
    statistic: Num = Field(description="structure statistic (twin comparison, raised by a repeated region)")
    rmse_nominal: Num = Field(description="multi-step RMSE of the nominal model")
    rmse_noise_floor: Num = Field(NAN, description="multi-step RMSE of the nominal model on its noise twin")
    rmse_augmented: Num = Field(NAN, description="multi-step RMSE of the augmented model")
    predictability: Predictability | None = Field(None, description="held-out predictability of the error")
    heldout_rmse_nominal: float | None = Field(
        None, description="dynamic channels only: cross-validated RMSE of the nominal model")
    heldout_rmse_augmented: float | None = Field(
        None, description="dynamic channels only: cross-validated RMSE of the augmented model")
    rmse_calibrated: float | None = Field(
        None, description="multi-step RMSE of the calibrated model (only when a calibration was applied)")
    heldout_rmse_calibrated: float | None = Field(
        None, description="dynamic channels, calibration applied: cross-validated RMSE of the calibrated model")
    regime: str | None = Field(None, description="structured channels only: where and when the error grows")

    @model_serializer(mode="wrap")
    def _drop_absent(self, handler):
        """Keys a channel does not have (held-out RMSE of e_psi, regime of a noise channel) stay out
        of the JSON, as before the schema."""
        return {k: v for k, v in handler(self).items() if not (v is None and k in _ABSENT_WHEN_NONE)}


class Region(Frozen):
    """A stretch of track where a channel's error repeats lap after lap."""

    channel: str = Field(description="channel name")
    s_start: Num = Field(description="start [m]")
    s_end: Num = Field(description="end [m]")
    description: str = Field("", description="regime there and in how many laps it was seen; or "
                             "'unexplained after the named effects: ...'")


def _without_false_flag(out: dict) -> dict:
    if out.get("at_bound") is False:
        out.pop("at_bound")
    return out


class Parameter(Frozen):
    """A fitted parameter of a named effect."""

    value: Num = Field(description="fitted value")
    ci95: list[Num] = Field(min_length=2, max_length=2, description="95 % interval [low, high] (null: not computed)")
    unit: str = Field("", description="unit of the value")
    at_bound: bool = Field(False, description="pressed against a bound of what the car can have physically "
                                               "(gprace.diagnose.name.physical_bounds)")

    @model_serializer(mode="wrap")
    def _drop_false(self, handler):
        """A parameter inside its bounds keeps the JSON it had before the flag existed."""
        return _without_false_flag(handler(self))


class EffectProfile(Frozen):
    """A profile effect's values along the lap (road_bank_profile, road_grade_profile,
    friction_profile): linear between knots, periodic over the lap."""

    s: list[Num] = Field(description="knot positions along the lap [m]")
    value: list[Num] = Field(description="value at each knot (unit below)")
    ci95_low: list[Num] = Field(description="pointwise 95 % interval, lower end")
    ci95_high: list[Num] = Field(description="pointwise 95 % interval, upper end")
    unit: str = Field("", description="unit of the values")
    lap_length: Num = Field(description="period of the profile [m]")
    smoothing: Num = Field(NAN, description="roughness penalty chosen by cross-validation (relative to the data)")
    edf: Num | None = Field(None, description="effective degrees of freedom of the fitted profile")
    at_bound: bool = Field(False, description="a knot value pressed against a bound of what the car can have "
                                              "physically (gprace.diagnose.name.physical_bounds)")

    @model_serializer(mode="wrap")
    def _drop_false(self, handler):
        return _without_false_flag(handler(self))

    @model_validator(mode="after")
    def _one_value_per_knot(self) -> "EffectProfile":
        n = len(self.s)
        for key in ("value", "ci95_low", "ci95_high"):
            if len(getattr(self, key)) != n:
                raise ValueError(f"profile.{key} has {len(getattr(self, key))} values for {n} knots")
        return self


class Effect(Frozen):
    """A catalogue effect the diagnosis named, fitted and verified."""

    name: str = Field(description="catalogue name (gprace.model.EFFECTS)")
    parameters: dict[str, Parameter] = Field(description="free parameters (fixed ones left out)")
    channels: list[str] = Field(default_factory=list, description="channels the effect acts on")
    heldout_rmse_before: dict[str, Num] = Field(default_factory=dict,
                                                description="per channel: held-out RMSE before it was added")
    heldout_rmse_after: dict[str, Num] = Field(default_factory=dict,
                                               description="per channel: held-out RMSE with it")
    improvement: Num = Field(NAN, description="relative held-out RMSE reduction when it was added")
    ambiguous_with: list[str] = Field(default_factory=list, description="effects that fit about as well")
    significant_where: str = Field("all windows", description="where its held-out gain was significant")
    profile: EffectProfile | None = Field(None, description="profile effects only: the values along the lap")

    @model_serializer(mode="wrap")
    def _drop_absent(self, handler):
        """Effects without a profile keep the JSON they had before profiles existed."""
        out = handler(self)
        if out.get("profile") is None:
            out.pop("profile", None)
        return out


class CalibratedParameter(Frozen):
    """A nominal parameter the diagnosis fitted (gprace.diagnose.calibrate)."""

    name: str = Field(description="parameter (cornering_stiffness_front, steering_offset, speed_loop_rate, ...)")
    field: str = Field(description="the vehicle TOML field it sets (the speed loop's two set speed_loop_tau "
                       "and speed_loop_gain together)")
    unit: str = Field("", description="unit of the value")
    nominal: Num = Field(description="value in the nominal vehicle")
    value: Num = Field(description="calibrated value")
    ci95: list[Num] = Field(min_length=2, max_length=2, description="95 % interval (cluster sandwich)")
    spread_ratio: Num = Field(NAN, description="posterior / prior spread (identified below 1/5)")
    at_bound: bool = Field(False, description="pressed against a bound of its physical range")
    relevance: Num = Field(NAN, description="growth of the noise-normalised mean square error if it were put "
                           "back to nominal (the others refitted)")
    changed: bool = Field(False, description="its 95 % interval excludes the nominal value and the relevance "
                          "exceeds 0.01 (1 % of the noise floor)")


class NotIdentified(Frozen):
    """A nominal parameter the recordings do not identify (kept at its nominal value)."""

    name: str = Field(description="parameter")
    reason: str = Field(description="how far the data narrow its stated range")


class Calibration(Frozen):
    """The calibration of the nominal parameters before any effect is named (issue 36)."""

    applied: bool = Field(description="the calibrated values are in the augmented vehicle (held-out gain significant)")
    tested: bool = Field(True, description="its held-out gain was tested (False: the named effects explained "
                         "the structured error before it was needed)")
    considered: list[str] = Field(default_factory=list, description="parameters the inputs let it test")
    heldout_gain: Num = Field(0.0, description="relative held-out loss reduction over the nominal model (by lap)")
    t: Num = Field(0.0, description="paired block statistic of that gain")
    significant_where: str = Field("", description="where the gain was significant ('' when it was not)")
    parameters: list[CalibratedParameter] = Field(default_factory=list, description="identified parameters")
    not_identified: list[NotIdentified] = Field(default_factory=list, description="kept at their nominal values")


class InputTest(Frozen):
    """An effect the recordings' inputs cannot test."""

    effect: str = Field(description="catalogue name")
    reason: str = Field(description="why")


class Inputs(Frozen):
    """The recordings' inputs as the model used them, and what each channel could test."""

    delta: str | None = Field(None, description="steering: commanded or measured")
    a_x: str | None = Field(None, description="a_x: commanded, measured, derived or absent")
    v_cmd: str | None = Field(None, description="a speed command, when the log has one")
    longitudinal: str = Field(description="how v_x is driven: force (a_x commanded), speed (speed loop) or kinematic")
    tests: dict[str, str] = Field(default_factory=dict, description="per dynamic channel: what its error can test")
    not_testable: list[InputTest] = Field(default_factory=list, description="effects these inputs cannot test")


class NotIdentifiable(Frozen):
    """A catalogue effect the recordings cannot identify."""

    effect: str = Field(description="catalogue name")
    reason: str = Field(description="the missing excitation")


class Exclusion(Frozen):
    """A stretch of a recording cut out by the model's envelope (gprace.io.envelope)."""

    reason: str = Field(description="spin, standstill, reversing or gap")
    first_row: int = Field(description="first excluded row")
    last_row: int = Field(description="last excluded row (inclusive)")
    t_start: Num = Field(description="time at the start [s]")
    t_end: Num = Field(description="time at the end [s]")
    s_start: Num = Field(description="track position at the start [m]")
    s_end: Num = Field(description="track position at the end [m]")
    samples: int = Field(ge=0, description="excluded samples")
    seconds: Num = Field(description="excluded duration [s]")


class Excluded(Frozen):
    """What the envelope cut out of one recording."""

    source: str = Field(description="the recording")
    samples: int = Field(ge=0, description="samples in the recording")
    samples_excluded: int = Field(0, ge=0, description="samples cut out")
    seconds_excluded: Num = Field(0.0, description="seconds cut out (gaps not counted)")
    samples_moving: int | None = Field(None, ge=0, description="samples driving forward faster than the "
                                       "standstill speed (absent in results of before issue 36)")
    moving_kept: int | None = Field(None, ge=0, description="of those, the samples kept")
    standstill_speed: float | None = Field(None, description="speed [m/s] below which the car counted as standing "
                                           "(scaled to the car and the recording)")
    excluded: list[Exclusion] = Field(default_factory=list, description="the stretches cut out")

    @model_serializer(mode="wrap")
    def _drop_absent(self, handler):
        """The envelope's scale (issue 36) stays out of results that did not record it."""
        return {k: v for k, v in handler(self).items()
                if not (v is None and k in ("samples_moving", "moving_kept", "standstill_speed"))}


class ResidualProfile(Frozen):
    """Binned mean multi-step error along the track per dynamic channel, nominal and augmented
    model, and the noise twin's 1-sigma level: the residual-along-track figure's data."""

    bin_m: float = Field(gt=0, description="bin width [m]")
    s: list[Num] = Field(description="bin centres [m]")
    before: dict[str, list[Num]] = Field(description="per channel: mean error per bin of the nominal model "
                                         "(null: no window in the bin)")
    after: dict[str, list[Num]] = Field(description="per channel: the same for the augmented model "
                                        "(equal to before when nothing was named)")
    noise: dict[str, Num] = Field(description="per channel: RMS error of the nominal model on its noise twin "
                                  "(the +-1 sigma band)")

    @model_validator(mode="after")
    def _one_value_per_bin(self) -> "ResidualProfile":
        """Every channel in before, after and noise, with one value per bin."""
        if not set(self.before) == set(self.after) == set(self.noise):
            raise ValueError("before, after and noise must name the same channels")
        for key, per in (("before", self.before), ("after", self.after)):
            for ch, v in per.items():
                if len(v) != len(self.s):
                    raise ValueError(f"{key}.{ch} has {len(v)} values for {len(self.s)} bins")
        return self


class DiagnosisResult(Frozen):
    """What ``gprace diagnose`` found: verdict, channels, regions, named effects, the residual
    profile, and what it could not see."""

    version: int = Field(RESULT_VERSION, description="layout version of the result")
    verdict: Literal["mismatch", "no_significant_mismatch"] = Field(description="structured error or not")
    channels: list[Channel] = Field(description="every tested channel")
    regions: list[Region] = Field(default_factory=list, description="located regions of structured channels "
                                  "(and those left unexplained after the named effects)")
    effects: list[Effect] = Field(default_factory=list, description="named effects (empty without a mismatch)")
    partial_effects: list[Effect] = Field(default_factory=list, description="effects that improve held-out "
                                          "prediction but leave their channels structured: in the augmented "
                                          "vehicle, not named (issue 36)")
    unexplained: dict[str, Num] = Field(default_factory=dict,
                                        description="per channel: structured error RMS the effects leave")
    augmented_vehicle: str | None = Field(None, description="file the augmented vehicle was written to")
    explained_share: Num = Field(0.0, description="share of the structured error the effects explain")
    not_identifiable: list[NotIdentifiable] = Field(default_factory=list,
                                                    description="effects these recordings cannot identify")
    excluded: list[Excluded] = Field(default_factory=list, description="per recording: what the envelope cut out")
    notes: list[str] = Field(default_factory=list, description="notes for the reader")
    noise_sigma: dict[str, Num] = Field(default_factory=dict, description="per channel: estimated sensor noise")
    samples: int = Field(0, ge=0, description="samples diagnosed (0: not recorded)")
    horizon: int = Field(0, ge=0, description="multi-step horizon [steps] (0: not recorded)")
    runtime_s: Num = Field(NAN, description="wall time of the diagnosis [s]")
    residual_profile: ResidualProfile | None = Field(
        None, description="the residual along the track (None: a result of before the schema)")
    inputs: Inputs | None = Field(None, description="the inputs and what they let the diagnosis test (issue 36)")
    calibration: Calibration | None = Field(None, description="the calibrated nominal parameters (issue 36)")

    @model_serializer(mode="wrap")
    def _drop_absent(self, handler):
        """Sections a result of before issue 36 does not have stay out of its JSON."""
        out = handler(self)
        if not out.get("partial_effects") and out.get("inputs") is None:  # a result of before issue 36
            out.pop("partial_effects", None)
        return {k: v for k, v in out.items() if not (v is None and k in ("inputs", "calibration"))}

    def to_json(self) -> dict[str, Any]:
        """The JSON-ready dump (NaN as None): what ``--json`` prints."""
        return jsonable(self.model_dump())

    def findings(self) -> dict[str, dict[str, float]]:
        """Everything the diagnosis found in the catalogue's terms: the named effects and the
        effects that the changed calibrated parameters stand for (``cornering_stiffness``,
        ``steering_offset``, ``aero_drag`` ...; :func:`gprace.diagnose.calibrate.as_effects`),
        with their parameter values."""
        from gprace.diagnose.calibrate import as_effects

        out: dict[str, dict[str, float]] = {}
        if self.calibration is not None and self.calibration.applied:
            out.update(as_effects([p.model_dump() for p in self.calibration.parameters]))
        for e in self.effects:
            out[e.name] = {k: float(p.value) for k, p in e.parameters.items()}
        return out


def residual_profile(s: np.ndarray, before: dict[str, np.ndarray], after: dict[str, np.ndarray],
                     noise: dict[str, float], bin_m: float) -> dict[str, Any]:
    """The profile's fields from arrays: bin centres to 0.1 m, errors to :data:`SIGNIFICANT` digits."""
    return {"bin_m": float(bin_m), "s": [round(float(x), 1) for x in s],
            "before": {c: _significant(v) for c, v in before.items()},
            "after": {c: _significant(v) for c, v in after.items()},
            "noise": {c: _significant([v])[0] for c, v in noise.items()}}


def _significant(values) -> list[float]:
    return [float(f"{float(x):.{SIGNIFICANT}g}") if math.isfinite(x) else NAN for x in values]


def parse_result(data: Any, where: str) -> DiagnosisResult:
    """``data`` (a parsed diagnosis JSON, or a result dict) validated by :class:`DiagnosisResult`.

    A layout of before the schema (no ``version``) is read with one warning; a newer version, or
    data the schema refuses, is a one-line :class:`~gprace.errors.InputError` naming ``where``.
    """
    if isinstance(data, DiagnosisResult):
        return data
    return parse_record(DiagnosisResult, data, where, "diagnosis result",
                        "missing fields set to their defaults, no stored residual profile")[0]


def read_result(path: str | Path) -> DiagnosisResult:
    """The diagnosis result saved at ``path`` (``gprace diagnose ... --json > path``)."""
    return parse_result(read_json(path, "diagnosis result"), str(path))
