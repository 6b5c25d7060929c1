"""The diagnosis pipeline: envelope -> screen -> locate -> name -> fit -> verify -> report.

Each stage is a function returning a small frozen result (see ``docs/decisions.md``, diagnose):

- :func:`prepare` cuts every recording to the model's envelope (:mod:`gprace.io.envelope`: spins,
  standstill, reversing, time gaps) and stacks what is left;
- :func:`screen` estimates the sensor noise, evaluates the nominal model (multi-step errors, noise
  twin, predictability of the error per regime and per region of the lap) and says which
  channels carry structured error;
- :func:`calibrate` fits the nominal parameters the recordings identify (cornering stiffness,
  steering offset and gain, yaw inertia, drag, rolling resistance, the speed loop, peak friction
  at the limit; :mod:`gprace.diagnose.calibrate`) and applies them when their held-out gain is
  significant: the missing physics is then named against the calibrated car;
- :func:`locate` turns the regions found on structured channels into starting windows;
- :func:`name` adds catalogue effects one by one, each only when it improves held-out prediction
  beyond the effects already chosen (over all windows or where it acts);
- :func:`fit` refits the chosen effects jointly and computes their intervals;
- :func:`verify` drops effects that the others make redundant (parsimony: they trade off and are
  reported as ambiguous), re-evaluates the augmented model and withdraws a name whose channels stay
  structured (reported as unexplained, never misnamed).

:func:`diagnose` runs the stages and returns the result (:class:`~gprace.diagnose.result.DiagnosisResult`,
the issue's contract plus the residual profile along the track) and the augmented
:class:`~gprace.config.VehicleConfig`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Callable

import numpy as np
from scipy.stats import norm

from gprace.config import EffectConfig, VehicleConfig
from gprace.diagnose import calibrate as cal, core, crossval as cv_, locate, name as nm, profiles as pf_, screen as scr
from gprace.diagnose.core import CHANNELS, DYNAMIC, TESTED
from gprace.diagnose.laps import wrap_runs
from gprace.diagnose.profiles import leading, window_or_profile, worth_cross_validating
from gprace.diagnose.result import DiagnosisResult, residual_profile
from gprace.errors import InputError
from gprace.io.envelope import EnvelopeReport, envelope
from gprace.io.runs import Run
from gprace.model import EFFECTS, Input, NominalModel, State

HORIZON = 15
"""Multi-step horizon [steps] (0.75 s at 20 Hz): long enough that structured error outgrows the
one-step sensor noise, short enough that open-loop predictions stay on the recorded path."""

MAX_EFFECTS = 3
CAL_CV_NFEV = 4
"""Model evaluations of each fold's calibration refit (warm-started at the full fit)."""
MIN_WINDOWS = 150
UNEXPLAINED_SHARE = 0.1
"""A named effect whose channels keep more than this share of their structured error is not
trusted: the residual says the physics is something else (reported unexplained, not misnamed)."""
T_WEAK = 3.0
"""Predictability t that confirms a twin finding (the twin alone cannot tell coloured noise)."""
REGION_SNR = 1.0
"""Relevance floor of a located region: its structured error (mean square in excess of the noise
twin's) must be at least the noise floor's mean square there, i.e. a signal-to-noise ratio of 1
where the effect acts. An engineer does not call a bias smaller than the sensor noise at that
place a mismatch, however often it repeats: one 10 m bin of a null recording repeated in 3 of
5 laps with 0.7x the noise RMS (0.2x over the whole channel) was a false alarm at the old 0.5.
Local physics is far above it (bank, grade, friction patch: 14x to 600x on the independent
source; a steering lag's corners 2x to 4x)."""

_ALIAS = {3: 2, 4: 1}  # e_psi error comes from yaw rate, e_y error from v_y


@dataclass
class Diagnosis:
    """What :func:`diagnose` found, and the vehicle with the named effects added."""

    result: DiagnosisResult
    vehicle: VehicleConfig  # augmented (equal to the input when nothing was named)

    @cached_property
    def report(self) -> dict[str, Any]:
        """The result as a dict (NaN where a number is not one): what ``--json`` prints."""
        return self.result.model_dump()


# --------------------------------------------------------------------------------------------
# stage results


@dataclass(frozen=True)
class Prepared:
    """Recordings inside the envelope, stacked; the windows every later stage predicts over."""

    data: core.Dataset
    starts: np.ndarray
    H: int
    envelopes: tuple[EnvelopeReport, ...]
    notes: tuple[str, ...] = ()  # laps recognised in recordings whose s runs on (gprace.diagnose.laps)


@dataclass(frozen=True)
class Evaluation:
    """How one model predicts the recordings: errors, noise twin, statistics, regions."""

    Ed: np.ndarray  # (m, H, 6) data errors
    Et: np.ndarray  # (R, m, H, 6) twin errors
    stats: tuple[locate.ChannelStat, ...]  # per TESTED channel (twin comparison)
    regions: dict[int, list[locate.Region]]
    pred: tuple[scr.Predictability, ...]  # per TESTED channel (held-out predictability)
    structured: frozenset[int]  # TESTED channel indices

    @property
    def dynamic_structured(self) -> frozenset[int]:
        return frozenset(_ALIAS.get(c, c) for c in self.structured)


@dataclass(frozen=True)
class Screened:
    sigma: np.ndarray  # (6,) sensor noise
    nominal: Evaluation
    scale: np.ndarray  # (3,) noise-floor RMSE of the dynamic channels
    not_identifiable: dict[str, str]


@dataclass(frozen=True)
class Located:
    windows: dict[int, list[tuple[float, float]]]  # dynamic channel -> candidate (s_start, s_end)


@dataclass(frozen=True)
class NamedEffect:
    fit: nm.Fit
    heldout_before: dict[str, float]
    heldout_after: dict[str, float]
    improvement: float
    ambiguous_with: tuple[str, ...] = ()
    where: str = "all windows"  # where the held-out gain was significant

    @property
    def name(self) -> str:
        return self.fit.name

    @property
    def channels(self) -> list[str]:
        return list(EFFECTS[self.fit.name].channels)


@dataclass(frozen=True)
class Named:
    effects: tuple[NamedEffect, ...]
    searched: tuple[dict, ...]


@dataclass(frozen=True)
class Verified:
    effects: tuple[NamedEffect, ...]
    augmented: Evaluation
    heldout_after: np.ndarray | None  # (3,) normalised held-out MSE of the augmented model
    notes: tuple[str, ...] = field(default_factory=tuple)
    partial: tuple[NamedEffect, ...] = ()
    """Effects that improve held-out prediction but leave their channels structured: in the
    augmented model (the fit improves), not named (the physics may be something else)."""

    @property
    def modelled(self) -> tuple[NamedEffect, ...]:
        return self.effects + self.partial


@dataclass(frozen=True)
class Ctx:
    """What the fitting stages share (windows subsampled for speed, folds, blocks)."""

    prob: nm.Problem
    fit_w: np.ndarray
    screen_w: np.ndarray
    eval_w: np.ndarray
    fold: np.ndarray
    bid: np.ndarray
    fit_stride: int
    subsets: tuple[tuple[str, np.ndarray], ...]  # regimes / regions over eval_w
    t_subset: float
    heldout_memo: dict = field(default_factory=dict, compare=False, repr=False)
    """Cross-validated losses per set of fitted effects (parsimony and the final held-out fit
    ask for the same set more than once)."""
    skip: frozenset = frozenset()
    """Catalogue effects not tried: the calibration fits their parameter as a nominal one, or the
    recordings' inputs cannot test them."""
    refused: dict = field(default_factory=dict, compare=False, repr=False)
    """Profile candidates refused as no road property, {name: why} (the report's notes): values
    at their physical bound, or an error that repeats with the driven line but follows the state."""


@dataclass(frozen=True)
class Calibrated:
    """The calibration stage: the calibrated vehicle (the nominal one when not applied), the fit,
    its held-out test, and the screening of the calibrated model the effects are named against."""

    vehicle: VehicleConfig
    fit: cal.CalFit | None
    applied: bool
    baseline: Screened
    gain: float = 0.0  # held-out relative gain over the nominal model
    t: float = 0.0
    where: str = ""
    heldout: np.ndarray | None = None  # (m, 3) per-window, per-channel held-out losses, calibrated
    considered: tuple[str, ...] = ()
    round: int = -1  # the naming round in which it was applied
    tested: bool = False  # its held-out gain was tested (not when effects explained everything first)


# --------------------------------------------------------------------------------------------
# stages


def prepare(runs: list[Run], H: int, wheelbase: float | None = None) -> Prepared:
    """Wrap s per lap where it runs on (:func:`gprace.diagnose.laps.wrap_runs`), cut every
    recording to the model's envelope (judged on the scale of the car: its ``wheelbase``), stack
    them, list the gap-free windows."""
    runs, lap_notes = wrap_runs(runs)
    kept, envs = [], []
    for r in runs:
        mask, rep = envelope(r.data, r.source, wheelbase)
        envs.append(rep)
        if rep.samples_moving == 0:
            raise InputError(f"{r.source}: no moving sample (v_x never reaches the standstill speed "
                             f"{rep.standstill_speed:.2g} m/s of this car)")
        if not mask.any():
            raise InputError(f"{r.source}: no sample inside the model's envelope ({rep.note()})")
        kept.append(r if mask.all() else r.slice(mask))
    data = core.build_dataset(kept, min_samples=max(200, 10 * H))
    starts = data.windows(H)
    if len(starts) < MIN_WINDOWS:
        raise InputError(f"{data.sources[0]}: only {len(starts)} gap-free {H}-step windows; need {MIN_WINDOWS}")
    return Prepared(data, starts, H, tuple(envs), tuple(lap_notes))


def evaluate(p: Prepared, model: NominalModel, sigma: np.ndarray, seed: int, sub: int = 2,
             scale: np.ndarray | None = None, Et: np.ndarray | None = None) -> Evaluation:
    """Errors of ``model`` on the data and on its noise twin, and which channels are structured.

    A channel is structured when its error is predictable out of sample from regime and place
    (:mod:`gprace.diagnose.screen`, over all windows or within a regime / tenth of the lap), or
    when it repeats at one place in at least two laps, or when the twin comparison finds it and
    the predictability confirms it weakly (coloured sensor noise alone passes the twin test).
    """
    data, starts, H = p.data, p.starts, p.H
    s = _sub(model, sub)
    Ed = core.errors(data, starts, core.predict(model, data, starts, H, s))
    if Et is None:
        Et = core.twin_errors(model, data, starts, core.make_twin(model, data, starts, H, sigma, seed=seed), s)
    regions = {c: locate.find_regions(data, starts, H, Ed, Et, c) for c in TESTED}
    stats = locate.channel_stats(data, starts, Ed, Et)
    sc = np.array([st.rmse_twin for st in stats]) if scale is None else np.concatenate(
        [scale, [st.rmse_twin for st in stats[3:]]])
    pred = scr.predictability(data, starts, H, Ed, np.concatenate([sc, [1.0]]), TESTED)
    structured = set()
    for st, pr, c in zip(stats, pred, TESTED):
        local = [g for g in regions.get(c, []) if g.laps_seen >= 2 and g.excess > REGION_SNR * st.rmse_twin**2]
        if pr.strong or local or (st.structured and pr.t > T_WEAK):
            structured.add(c)
            if local:
                st.statistic = max(st.statistic, max(g.z for g in local))
        st.structured = c in structured
    return Evaluation(Ed, Et, tuple(stats), regions, tuple(pred), frozenset(structured))


def screen(p: Prepared, vehicle: VehicleConfig, seed: int) -> Screened:
    """Noise estimate and the nominal model's evaluation."""
    m0 = core.model_for(vehicle, p.data)
    sigma = core.estimate_noise(m0, p.data, p.starts, p.H, 2, seed=seed)
    ev = evaluate(p, m0, sigma, seed + 1)
    scale = np.array([ev.stats[c].rmse_twin for c in DYNAMIC])
    return Screened(sigma, ev, scale, excitation(p.data, vehicle.wheelbase))


def calibrate(p: Prepared, s: Screened, ctx: Ctx, vehicle: VehicleConfig, log: Callable[[str], None]) -> Calibrated:
    """Fit the nominal parameters the recordings identify, inside their bounds
    (:mod:`gprace.diagnose.calibrate`), and cross-validate them by lap (refitted without the
    held-out fold). The result is the first candidate of :func:`name`: applied there when it
    explains the structured error better than any catalogue effect and significantly. Nothing to
    calibrate when the nominal model leaves no structured error."""
    params = cal.applicable(p.data.longitudinal)
    none = Calibrated(vehicle, None, False, s, considered=tuple(q.name for q in params))
    if not s.nominal.structured or not params:
        return none
    lo, hi = cal.bounds(vehicle, params, cal.v_top(p.data))
    log(f"diagnose: calibrating {len(params)} nominal parameters ({', '.join(q.name for q in params)})")
    f = cal.identify(ctx.prob, params, cal.start(vehicle, params), lo, hi, ctx.fit_w, log=log)
    if not f.params:
        return replace(none, fit=f)
    return replace(none, fit=f, heldout=_cv_calibration(ctx, vehicle, f))


def _cv_calibration(ctx: Ctx, vehicle: VehicleConfig, f: cal.CalFit) -> np.ndarray:
    """(m, 3) held-out losses of the calibration ``f`` (the model's effects ``ctx.prob.base`` in),
    refitted without each fold by iterations: the calibration moves far from the nominal car,
    where one linearised step from the full fit falls short (INI F1TENTH: 62 % against 84 %)."""
    prob = ctx.prob
    lo, hi = cal.bounds(vehicle, f.params, cal.v_top(prob.data))
    out = np.empty((len(ctx.eval_w), 3))
    for fo in np.unique(ctx.fold):
        te = ctx.fold == fo
        tr = ctx.eval_w[~te][:: max(1, int((~te).sum()) // 400)]
        g = cal.fit(prob, f.params, f.x, lo, hi, tr, max_nfev=CAL_CV_NFEV)
        out[te] = np.mean(cal.residual_sets(prob, f.params, [g.x], ctx.eval_w[te])[0] ** 2, axis=1)
    return out


def _cal_channels(f: cal.CalFit) -> list[int]:
    return sorted(({1, 2} if any(q.needs == "lateral" for q in f.params) else set())
                  | ({0} if any(q.needs != "lateral" for q in f.params) else set()))


def _apply_calibration(p: Prepared, s: Screened, c: Calibrated, vehicle: VehicleConfig, seed: int,
                       log: Callable[[str], None]) -> Calibrated:
    """The calibrated vehicle and the screening of the calibrated model (for the report and as the
    baseline of the effects named after it)."""
    veh = cal.with_values(vehicle, cal.values(vehicle, c.fit.params, c.fit.x))
    ev = evaluate(p, core.model_for(veh, p.data), s.sigma, seed + 3, scale=s.scale)
    log(f"diagnose: calibrated model structured: {[CHANNELS[i] for i in sorted(ev.structured)] or 'none'}")
    return replace(c, vehicle=veh, applied=True, baseline=replace(s, nominal=ev))


def recalibrate(c: Calibrated, ctx: Ctx, named: Named, nominal: VehicleConfig) -> tuple[Calibrated, Named]:
    """The calibration and the named effects refitted together (warm-started), so a parameter that
    absorbed part of a missing effect before it was named gives it back; then the calibration's
    intervals with the effects in the model."""
    if not c.applied or not named.effects or c.fit is None:
        return c, named
    prob = replace(ctx.prob, vehicle=nominal, base=[])
    lo, hi = cal.bounds(nominal, c.fit.params, cal.v_top(prob.data))
    blocks = [cv_.calibration_block(c.fit.params, c.fit.x, lo, hi)]
    blocks += [cv_.effect_block(e.fit, prob.data, nominal) for e in named.effects]
    blocks = cv_.joint_fit(prob, blocks, ctx.fit_w, max_nfev=JOINT_NFEV)
    effects = tuple(e if e.fit.profile is not None else replace(e, fit=replace(e.fit, x=b.x))
                    for e, b in zip(named.effects, blocks[1:]))  # a profile is held at its own fit
    prob = replace(prob, base=[e.fit.effect() for e in effects])
    f = cal.covariance(prob, cal.fit(prob, c.fit.params, blocks[0].x, lo, hi, ctx.fit_w, max_nfev=5), lo, hi)
    f.dropped = c.fit.dropped
    c = replace(c, vehicle=cal.with_values(nominal, cal.values(nominal, f.params, f.x)), fit=f)
    return c, replace(named, effects=effects)


def locate_windows(s: Screened) -> Located:
    """Candidate windows (s_start, s_end) per dynamic channel from the located regions."""
    reg = s.nominal.regions
    out = {c: [(g.s_start, g.s_end) for g in reg.get(c, [])] for c in DYNAMIC}
    for c in (3, 4):
        out.setdefault(_ALIAS[c], []).extend((g.s_start, g.s_end) for g in reg.get(c, []))
    return Located(out)


def _context(p: Prepared, vehicle: VehicleConfig, s: Screened) -> Ctx:
    starts = p.starts
    prob = nm.Problem(vehicle, p.data, p.H, s.scale, substeps=1)
    fit_stride = max(1, -(-len(starts) // 400))  # at most 400 fit windows
    eval_w = starts[:: max(1, len(starts) // 2500)]
    subsets = tuple((lab, m) for lab, m in scr.regimes(p.data, eval_w, p.H) if m.sum() >= 20)
    t_sub = max(scr.T_SUBSET_MIN, float(norm.isf(scr.FAMILY_ALPHA / max(len(subsets) * MAX_EFFECTS, 1))))
    return Ctx(prob, starts[::fit_stride], starts[:: max(1, len(starts) // 200)], eval_w,
               nm.folds(p.data, eval_w), locate.blocks(p.data, eval_w), fit_stride, subsets, t_sub)


def _significant(ctx: Ctx, l0: np.ndarray, l1: np.ndarray) -> tuple[bool, str, float]:
    """Is the held-out gain of l1 over l0 significant and relevant, over all windows or where an
    effect acts (a regime or a tenth of the lap, threshold corrected for the number of subsets)?"""
    rel, t = nm.gain_test(l0, l1, ctx.bid)
    gain = float(l0.mean() - l1.mean())
    excess = max(l0.mean() - 1.0, 1e-12)
    # few independent blocks (a short window effect) -> weaker t, accepted only when the
    # held-out gain removes at least half of the remaining excess; heavy-tailed block gains
    # (a local effect met at different slip in every lap) -> the signed-rank test
    t = max(t, nm.rank_test(l0, l1, ctx.bid))
    sig = t > nm.T_GAIN or (t > nm.T_GAIN_STRONG and gain > 0.5 * excess)
    if sig and gain > nm.MIN_GAIN and gain > nm.MIN_EXCESS_SHARE * excess:
        return True, "all windows", t
    if gain <= 0:
        return False, "", t
    best = (False, "", t)
    for lab, m in ctx.subsets:  # concentrated effects: tested where they act
        _, ts = nm.gain_test(l0[m], l1[m], ctx.bid[m])
        g = float(l0[m].mean() - l1[m].mean())
        ex = max(l0[m].mean() - 1.0, 1e-12)
        if ts > ctx.t_subset and g > nm.MIN_EXCESS_SHARE * ex and g > 0.1 and ts > best[2]:
            best = (True, lab, ts)
    return best


def name(p: Prepared, s: Screened, loc: Located, ctx: Ctx, c: Calibrated, seed: int,
         log: Callable[[str], None]) -> tuple[Named, Calibrated]:
    """Greedy forward selection by held-out gain beyond what is already in the model. The first
    candidate is the calibration of the nominal parameters (issue 36): it is applied when no
    catalogue effect explains the structured error significantly better (a mis-set stiffness is
    calibrated, not named), and it stays a candidate, refitted with the effects chosen so far,
    until it is applied or fails its test (a missing downforce is named, not absorbed into
    stiffness factors)."""
    nominal = ctx.prob.vehicle
    chosen: list[NamedEffect] = []
    searched: list[dict] = []
    dyn_struct = set(s.nominal.dynamic_structured)
    if not dyn_struct:
        return Named((), ()), c
    candidate = c.fit is not None and bool(c.fit.params)
    for rnd in range(MAX_EFFECTS + 1):
        ctx_r = replace(ctx, prob=replace(ctx.prob, vehicle=c.vehicle if c.applied else nominal))
        fits = [e.fit for e in chosen]
        if len(fits) >= 2:  # the earlier effects were fitted without the latest one: refit
            fits = [nm.refit(_with_base(ctx_r.prob, fits, i), f, ctx.fit_w, ftol=nm.NAMING_FTOL)
                    for i, f in enumerate(fits)]
            chosen = [replace(e, fit=f) for e, f in zip(chosen, fits)]
        prob = replace(ctx_r.prob, base=[f.effect() for f in fits])
        cur = prob.model()
        if chosen or c.applied:  # stop when what is left is noise (against the same noise estimate)
            left = evaluate(p, cur, s.sigma, 0, scale=s.scale, Et=s.nominal.Et).dynamic_structured
            if not left:
                break
            dyn_struct = set(left)
        l0_ch = np.mean(prob.residuals(cur, ctx.eval_w) ** 2, axis=1)
        if candidate and chosen:  # the calibration with the effects named so far in the model
            c = _recalibrate(p, prob, ctx, nominal, c)
        best, cv, top = None, {}, []
        joint: dict[str, cv_.Block] = {}
        if len(chosen) < MAX_EFFECTS:
            cv, top = _best_effect(prob, loc, s, ctx, dyn_struct, fits, rnd, log)
            if c.applied and top:  # may the calibration give back what it absorbed of the effect?
                joint = _joint_with_calibration(replace(prob, vehicle=nominal), c, top, cv, ctx, log)
            best = _pick(ctx, l0_ch, cv, top, rnd, log)
            if top:
                searched.append({"round": rnd + 1, "candidates": {f.name: float(cv[f.name].mean()) for f in top},
                                 "baseline": float(l0_ch.mean())})
        # the calibration or the best effect first? (in a tie the calibration: calibrate, then name)
        cal_first = candidate and (best is None or not _clearly_better(
            ctx, cv[best.name].mean(axis=1), c.heldout.mean(axis=1)))
        effect_ok = False
        for what in (("calibration", "effect") if cal_first else ("effect", "calibration")):
            if what == "calibration" and candidate:
                chans = _cal_channels(c.fit)
                l0, l1 = l0_ch[:, chans].mean(axis=1), c.heldout[:, chans].mean(axis=1)
                ok, where, t = _significant(ctx, l0, l1)
                gain = float((l0.mean() - l1.mean()) / max(l0.mean(), 1e-12))
                log(f"diagnose: round {rnd + 1}: calibration held-out gain on "
                    f"{', '.join(CHANNELS[i] for i in chans)} {100 * gain:.1f}% (t = {t:.1f}, {where or 'not significant'})")
                c = replace(c, gain=gain, t=t, where=where if ok else "", tested=True)
                candidate = False
                if ok:
                    c = replace(_apply_calibration(p, s, c, nominal, seed, log), round=rnd)
                    break
            elif what == "effect" and best is not None:
                chb = _channels(best.name)
                l0 = l0_ch[:, chb].mean(axis=1)
                l1 = cv[best.name][:, chb].mean(axis=1)
                effect_ok, where, t = _significant(ctx, l0, l1)
                if effect_ok:
                    break
        else:  # neither was accepted
            break
        if not effect_ok:  # the calibration was applied: name effects against the calibrated car
            continue
        group = _ambiguity_group(ctx, best, top, cv, chb, l0, l1)
        named = min(group, key=lambda f: (len(f.free), cv[f.name].mean()))
        ln = cv[named.name]
        if named.name in joint:  # named with the calibration refitted beside it: keep that calibration
            xc = joint[named.name].x
            c = replace(c, fit=replace(c.fit, x=xc),
                        vehicle=cal.with_values(nominal, cal.values(nominal, c.fit.params, xc)))
        chosen.append(_named_effect(named, group, l0_ch, ln, s.scale, where))
    return Named(tuple(chosen), tuple(searched)), c


def _recalibrate(p: Prepared, prob, ctx: Ctx, nominal: VehicleConfig, c: Calibrated) -> Calibrated:
    """The calibration candidate refitted with the effects named so far in ``prob``'s model, and
    its held-out loss again."""
    bounds = cal.bounds(nominal, c.fit.params, cal.v_top(p.data))
    cf = cal.covariance(prob, cal.fit(prob, c.fit.params, c.fit.x, *bounds, ctx.fit_w, max_nfev=20), *bounds)
    cf.dropped = c.fit.dropped
    return replace(c, fit=cf, heldout=_cv_calibration(replace(ctx, prob=prob), nominal, cf))


def _ambiguity_group(ctx: Ctx, best, top, cv, chb, l0, l1) -> list:
    """``best`` and the candidates that explain nearly as much on its channels (within
    ``AMBIGUOUS_SHARE`` of its gain, not distinguishable from it, significant themselves)."""
    group = [best]
    for f in top:
        if f is best:
            continue
        lf = cv[f.name][:, chb].mean(axis=1)
        _, t_f = nm.gain_test(l0, lf, ctx.bid)
        _, t_diff = nm.gain_test(lf, l1, ctx.bid)
        if (lf.mean() - l1.mean()) <= nm.AMBIGUOUS_SHARE * (l0.mean() - l1.mean()) and t_diff < 2.0 \
                and t_f > nm.T_GAIN:
            group.append(f)
    return group


def _named_effect(named, group, l0_ch, ln, scale, where) -> NamedEffect:
    """The named fit with its held-out RMSEs before and after on its channels."""
    ch = _channels(named.name)
    return NamedEffect(
        fit=named,
        heldout_before={CHANNELS[i]: float(np.sqrt(l0_ch[:, i].mean()) * scale[i]) for i in ch},
        heldout_after={CHANNELS[i]: float(np.sqrt(ln[:, i].mean()) * scale[i]) for i in ch},
        improvement=float(1.0 - np.sqrt(ln[:, ch].mean() / l0_ch[:, ch].mean())),
        ambiguous_with=tuple(f.name for f in group if f is not named), where=where)


JOINT_TOP = 2
"""Candidates refitted jointly with the calibration once it is applied."""
JOINT_NFEV = 30
"""Evaluations of the final joint refit of the calibration and the named effects."""
JOINT_ROUND_NFEV = 10
"""Evaluations of a candidate's joint refit with the calibration (warm-started at both fits)."""
PRESCREEN_KEEP = 4
"""Candidates (or starting points) carried from the linearised prescreen to the screening fit."""
SCREEN_NFEV = 12
"""Evaluations of the screening fit (warm-started at the prescreen's step)."""


def _joint_with_calibration(prob: nm.Problem, c: Calibrated, top: list, cv: dict, ctx: Ctx,
                            log: Callable[[str], None]) -> dict[str, cv_.Block]:
    """The best candidates refitted together with the calibrated parameters (``prob`` on the
    nominal vehicle, the effects already chosen in it), cross-validated jointly. A calibrated
    inertia that took a steering lag's place, or a stiffness that took a downforce's, gives it
    back; a candidate keeps whichever held-out loss is lower (``top`` and ``cv`` updated in
    place). Returns, per candidate that gained, the calibration block it was fitted with."""
    lo, hi = cal.bounds(prob.vehicle, c.fit.params, cal.v_top(prob.data))
    joint = {}
    # a profile keeps its own fit (its smoothing is chosen inside it) and takes none of the
    # JOINT_TOP places: a bank profile mimicking what a calibrated stiffness left of a downforce
    # would otherwise keep the downforce from giving the stiffness back
    scalar = [f for f in sorted(top, key=lambda g: cv[g.name].mean()) if f.profile is None]
    for f in scalar[:JOINT_TOP]:
        blocks = [cv_.calibration_block(c.fit.params, c.fit.x, lo, hi), cv_.effect_block(f, prob.data, prob.vehicle)]
        blocks = cv_.joint_fit(prob, blocks, ctx.fit_w, max_nfev=JOINT_ROUND_NFEV, ftol=nm.NAMING_FTOL)
        lj = cv_.cv_losses(prob, blocks, ctx.eval_w, ctx.fold)
        if lj.mean() < cv[f.name].mean():
            log(f"diagnose: {f.name} with the calibration refitted beside it: held-out loss "
                f"{cv[f.name].mean():.3g} -> {lj.mean():.3g}")
            cv[f.name] = lj
            i = top.index(f)
            top[i] = nm.Fit(f.name, f.free, blocks[1].x, f.fixed, f.cost)
            joint[f.name] = blocks[0]
    return joint


def _pick(ctx: Ctx, l0_ch: np.ndarray, cv: dict, top: list, rnd: int,
          log: Callable[[str], None]) -> nm.Fit | None:
    """The round's effect: among the cross-validated candidates whose held-out gain on their own
    channels is significant (:func:`_significant`), the one with the lowest held-out loss over all
    channels; None when none is. Not the lowest loss first and then its test: one channel far
    above its noise floor (IAC: v_x, a measured a_x, 22 times) makes the total loss that
    channel's, and a candidate acting on it by a few per cent (a grade profile, t = 2) then hides
    a significant one on another channel (a velocity misalignment, 41 % on v_y, t = 5.8), and the
    round stopped with nothing named."""
    ok_fits = []
    for f in sorted(top, key=lambda g: cv[g.name].mean()):
        ch = _channels(f.name)
        l0, l1 = l0_ch[:, ch].mean(axis=1), cv[f.name][:, ch].mean(axis=1)
        ok, where, t = _significant(ctx, l0, l1)
        snr = nm.sensor_snr(ctx.prob, f) if ok and ctx.prob is not None else None  # a sensor offset's size
        if snr is not None and snr < nm.MIN_SENSOR_SNR:
            ok, where = False, f"below {nm.MIN_SENSOR_SNR} of the noise floor: {snr:.2f}"
        log(f"diagnose: round {rnd + 1}: {f.name} held-out gain on {', '.join(CHANNELS[i] for i in ch)} "
            f"{100 * (l0.mean() - l1.mean()) / max(l0.mean(), 1e-12):.1f}% (t = {t:.1f}, {where or 'not significant'})")
        if ok:
            ok_fits.append(f)
    return ok_fits[0] if ok_fits else None


def _clearly_better(ctx: Ctx, l_effect: np.ndarray, l_cal: np.ndarray) -> bool:
    """An effect wins over the calibration only when its held-out loss is lower and the paired
    block t of the difference exceeds 2: in a tie the nominal parameters are calibrated first."""
    if l_effect.mean() >= l_cal.mean():
        return False
    _, t = nm.gain_test(l_cal, l_effect, ctx.bid)
    return t > 2.0


def _best_effect(prob: nm.Problem, loc: Located, s: Screened, ctx: Ctx, dyn_struct: set, fits: list,
                 rnd: int, log: Callable[[str], None]) -> tuple[dict, list]:
    """The catalogue effects cross-validated this round: every candidate one linearised step
    from every starting point, the most promising fitted on, the best three cross-validated.
    ({name: (m, 3) held-out losses}, the cross-validated fits); :func:`_pick` chooses among them."""
    names = [n for n in EFFECTS if n not in {f.name for f in fits} and n not in s.not_identifiable
             and n not in ctx.skip and {CHANNELS.index(ch) for ch in EFFECTS[n].channels} & dyn_struct]
    log(f"diagnose: round {rnd + 1}: screening {len(names)} candidate effects")
    cands = []
    for n in names:  # one linearised step from every starting point (a profile: a few penalised
        inits = nm.starts_for(n, loc.windows)  # Gauss-Newton iterations), on the screening windows
        if not inits:
            continue
        f = (nm.fit_effect(prob, n, ctx.screen_w, inits, max_nfev=nm.PRESCREEN_NFEV) if EFFECTS[n].profile
             else cv_.prescreen(prob, n, ctx.screen_w, inits))
        if f is not None:
            cands.append(f)
    if not cands:
        return {}, []
    cands.sort(key=lambda f: f.cost)
    # only the most promising continue to the full screening fit, warm-started
    # (a window and its profile share one slot: profiles.leading)
    cands = sorted((nm.refit(prob, f, ctx.screen_w, max_nfev=SCREEN_NFEV, ftol=nm.NAMING_FTOL) for f in _slots(cands, PRESCREEN_KEEP)),
                   key=lambda f: f.cost)
    top = [nm.refit(prob, f, ctx.fit_w, max_nfev=20, ftol=nm.NAMING_FTOL) for f in _slots(cands, nm.SCREEN_TOP)]
    top = _road_profiles(prob, ctx, worth_cross_validating(top), log)
    cv = {f.name: _cv_channels(replace(ctx, prob=prob), [f]) for f in top}
    top = window_or_profile(top, cv, ctx.bid)  # parsimony: the window unless the profile is better
    return cv, top


def _road_profiles(prob: nm.Problem, ctx: Ctx, top: list, log: Callable[[str], None]) -> list:
    """``top`` without the profile candidates that are no property of the road (issue 36, stop
    48), each with its reason in ``ctx.refused``: values at their physical bound
    (:func:`~gprace.diagnose.profiles.at_bound`: a 34-degree bank on a road course), or, for a
    bank or grade, an error that repeats with the driven line but follows the car's state at the
    same place (:func:`~gprace.diagnose.profiles.line_check`). Checked before the
    cross-validation: a refused profile costs no fold refits."""
    out, R = [], None
    for f in top:
        if f.profile is None:
            out.append(f)
            continue
        bound = pf_.at_bound(f, prob.vehicle, prob.data)
        why = [pf_.bound_note(f, bound)] if bound is not None else []
        if f.name in pf_.ADDITIVE or f.name in pf_.SCALING:  # both reasons when both hold
            R = prob.residuals(prob.model(), ctx.eval_w) if R is None else R
            chk = pf_.line_check(prob, f.name, ctx.eval_w, ctx.fold, ctx.bid, R)
            if chk is not None and not chk.road:
                why.append(chk.note())
        if not why:
            out.append(f)
            continue
        ctx.refused[f.name] = "; ".join(why)
        log(f"diagnose: {ctx.refused[f.name]}")
    return out


def _inside_bounds(ctx: Ctx, effects: list[NamedEffect], vehicle: VehicleConfig, data: core.Dataset,
                   notes: list[str], log: Callable[[str], None]) -> list[NamedEffect]:
    """``effects`` without the profiles whose values reach their physical bound (no property of
    the road, :func:`~gprace.diagnose.profiles.at_bound`; a note each), the others refitted
    without them."""
    where = {e.name: pf_.at_bound(e.fit, vehicle, data) for e in effects if e.fit.profile is not None}
    if not any(where.values()):
        return effects
    for e in effects:
        if where.get(e.name):
            notes.append(pf_.bound_note(e.fit, where[e.name]))
            log(f"diagnose: {notes[-1]}")
    return _refit_each(ctx, [e for e in effects if not where.get(e.name)])  # they were fitted beside it


def _slots(cands: list, k: int) -> list:
    """The candidates carried on: the profiles among the ``k`` leading families
    (:func:`~gprace.diagnose.profiles.leading`) and, beside them, the ``k`` leading scalar
    effects. A profile follows anything that repeats at the same place lap after lap (a driver's
    speed, hence a downforce), so the profiles must not crowd the scalar effects out: with two
    profiles among the first three, a downforce behind a calibrated stiffness was never
    cross-validated nor refitted with the calibration, and a bank profile was named in its place."""
    prof = [f for f in leading(cands, k) if f.profile is not None]
    return sorted(leading([f for f in cands if f.profile is None], k) + prof, key=lambda f: f.cost)


def fit(ctx: Ctx, named: Named) -> Named:
    """One pass of joint refits (each with the others fixed), then 95% intervals."""
    fits = [e.fit for e in named.effects]
    for i, f in enumerate(fits):
        prob = _with_base(ctx.prob, fits, i)
        g = nm.fit_effect(prob, f.name, ctx.fit_w, [f.values()], max_nfev=30) or f
        g.ci = nm.interval95(prob, g, ctx.fit_w)
        fits[i] = g
    return replace(named, effects=tuple(replace(e, fit=f) for e, f in zip(named.effects, fits)))


def verify(p: Prepared, s: Screened, ctx: Ctx, named: Named, vehicle: VehicleConfig, seed: int,
           log: Callable[[str], None]) -> Verified:
    """Parsimony (drop an effect the others make redundant), then the augmented model's
    evaluation; an effect whose channels stay structured is not named but kept as *partial*."""
    effects = list(named.effects)
    notes: list[str] = []
    dropped: list[NamedEffect] = []
    effects = _inside_bounds(ctx, effects, vehicle, p.data, notes, log)  # the final refit may press a profile there
    if effects:
        log(f"diagnose: verifying {', '.join(e.name for e in effects)} on held-out windows (parsimony)")
    # parsimony: each effect must still improve held-out fit given all the others
    for i in range(len(effects) - 1, -1, -1):
        if len(effects) < 2:
            break
        fits = [e.fit for e in effects]
        ch = _channels(fits[i].name)
        l_all = _heldout_channels_of(ctx, fits)[:, ch].mean(axis=1)
        l_wo = _heldout_channels_of(ctx, [f for j, f in enumerate(fits) if j != i])[:, ch].mean(axis=1)
        ok, where, t = _significant(ctx, l_wo, l_all)
        if not ok:
            drop = effects.pop(i)
            dropped.append(drop)
            # the others were fitted beside it: refit them without it (a profile named next to
            # its window lacks what the window explained)
            effects = _refit_each(ctx, effects)
            shared = set(drop.channels)
            effects = [replace(e, ambiguous_with=tuple(dict.fromkeys(e.ambiguous_with + (drop.name,))))
                       if shared & set(e.channels) else e for e in effects]
            notes.append(f"{drop.name} adds nothing significant once "
                         f"{', '.join(e.name for e in effects)} {'is' if len(effects) == 1 else 'are'} in the model "
                         f"(t = {t:.1f}): they trade off, reported as ambiguous, not named")
            log(f"diagnose: {notes[-1]}")
    effects = _inside_bounds(ctx, effects, vehicle, p.data, notes, log)  # so may a refit after a drop
    m1 = core.model_for(vehicle, p.data, [e.fit.effect() for e in effects])
    ev1 = evaluate(p, m1, s.sigma, seed + 2, scale=s.scale) if effects else s.nominal
    ex0, ex1 = _excess(s.nominal), _excess(ev1)
    share_left = np.where(ex0 > 0, ex1 / np.maximum(ex0, 1e-300), 0.0)
    rejected = []
    for e in effects:
        chs = [TESTED.index(CHANNELS.index(c)) for c in e.channels]
        bad = [i for i in chs if TESTED[i] in ev1.structured and share_left[i] > UNEXPLAINED_SHARE]
        if bad:
            rejected.append((e, bad))
    partial = []
    if rejected:  # name nothing on channels the catalogue cannot explain; keep what it improves
        for e, bad in rejected:
            left = ', '.join(CHANNELS[TESTED[i]] for i in bad)
            if e.fit.profile is not None:
                notes.append(f"{e.name} fits part of the error but leaves {left} structured: not named and not "
                             f"kept (a profile follows whatever repeats at the same place lap after lap, as the "
                             f"driven line does; fitted beside an error it does not explain, its values are no "
                             f"property of the road)")
            else:
                notes.append(f"{e.name} fits part of the error but leaves {left} structured: not named (kept in "
                             f"the augmented model as a partial fit: it improves held-out prediction)")
        out = [r[0] for r in rejected]
        gone = [e for e in out if e.fit.profile is not None]
        if gone and any(set(d.channels) & set(g.channels) for d in dropped for g in gone):
            # parsimony dropped an effect beside a profile that is now left out: verify again
            # without the profile, so what it displaced is not lost with it
            keep = [e for e in named.effects if e.name not in {g.name for g in gone}]
            keep = _refit_each(ctx, keep)  # they were fitted beside the profile
            log(f"diagnose: {', '.join(g.name for g in gone)} left out: verifying again without "
                f"{'it' if len(gone) == 1 else 'them'}")
            again = verify(p, s, ctx, replace(named, effects=tuple(keep)), vehicle, seed, log)
            why = [n for n in notes if any(n.startswith(g.name) for g in gone)]
            return replace(again, notes=tuple(why) + again.notes)
        partial = [e for e in effects if e in out and e.fit.profile is None]
        effects = [e for e in effects if e not in out]
        if len(partial) < len(out):  # a profile left out: the others refitted without it, evaluated again
            if len(effects) + len(partial) > 1:
                both = _refit_each(ctx, effects + partial)
                effects, partial = both[: len(effects)], both[len(effects):]
            m1 = core.model_for(vehicle, p.data, [e.fit.effect() for e in effects + partial])
            ev1 = evaluate(p, m1, s.sigma, seed + 2, scale=s.scale) if effects or partial else s.nominal
    fits = [e.fit for e in effects + partial]
    heldout = _heldout(ctx, fits) if fits else None
    return Verified(tuple(effects), ev1, heldout, tuple(notes), tuple(partial))


# --------------------------------------------------------------------------------------------
# the pipeline


def diagnose(runs: list[Run], vehicle: VehicleConfig, *, horizon: int = HORIZON, seed: int = 0,
             augmented_name: str | None = None, log: Callable[[str], None] | None = None) -> Diagnosis:
    """Run the stages on ``runs`` against the nominal ``vehicle``.

    Linear algebra runs on one BLAS thread: the matrices are small (ridge regressions of ~20
    features, Jacobians of a few parameters), and on a shared machine a multi-threaded BLAS call
    waits for a time slice of every thread (measured: 0.15 s instead of 0.5 ms per ridge fold
    while another process held a core).
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return _diagnose(runs, vehicle, horizon=horizon, seed=seed, augmented_name=augmented_name, log=log)


def _diagnose(runs: list[Run], vehicle: VehicleConfig, *, horizon: int, seed: int,
              augmented_name: str | None, log: Callable[[str], None] | None) -> Diagnosis:
    t0 = time.perf_counter()
    log = log or (lambda s: None)
    p = prepare(runs, int(horizon), vehicle.wheelbase)
    data = p.data
    for note in p.notes:
        log(f"diagnose: {note}")
    for env in p.envelopes:
        if env.excluded:
            log(f"diagnose: {env.note()}")
    log(f"diagnose: {data.n} samples, {len(data.L)} recording(s), {data.laps_total} lap(s), horizon {p.H}, "
        f"inputs {data.inputs} (v_x by {data.longitudinal})")
    s = screen(p, vehicle, seed)
    log(f"diagnose: noise sigma {np.round(s.sigma, 4).tolist()}, structured: "
        f"{[CHANNELS[c] for c in sorted(s.nominal.structured)] or 'none'}")
    ctx = _context(p, vehicle, s)
    untestable = input_limits(data)
    c = calibrate(p, s, ctx, vehicle, log)
    skip = frozenset(untestable) | frozenset(q.supersedes for q in cal.PARAMS
                                             if q.supersedes and q.name in c.considered)
    ctx = replace(ctx, skip=skip)
    named, c = name(p, s, locate_windows(s), ctx, c, seed, log)
    ctx_c = replace(ctx, prob=replace(ctx.prob, vehicle=c.vehicle), heldout_memo={})
    c2, named = recalibrate(c, ctx_c, named, vehicle)
    if c2 is not c:
        ctx_c = replace(ctx_c, prob=replace(ctx_c.prob, vehicle=c2.vehicle), heldout_memo={})
        c = c2
    named = fit(ctx_c, named)
    # an effect is judged against what it was named on: the calibrated model when the
    # calibration came first, the nominal one otherwise
    ver = verify(p, c.baseline if c.applied and c.round == 0 else s, ctx_c, named, c.vehicle, seed, log)
    report = _report(p, s, ctx, c, named, ver, vehicle, augmented_name, untestable)
    report["residual_profile"] = residual_along_track(p, s.nominal, ver.augmented)
    report["runtime_s"] = round(time.perf_counter() - t0, 2)
    result = DiagnosisResult.model_validate(report)  # a failure here is a bug of the pipeline, not bad input
    mismatch = result.verdict == "mismatch"
    effects = ver.modelled if mismatch else ()
    base = c.vehicle if mismatch else vehicle
    aug_vehicle = base.model_copy(update={"effects": tuple(vehicle.effects) + tuple(
        EffectConfig(name=e.name, params=e.fit.config_params()) for e in effects)})
    return Diagnosis(result, aug_vehicle)


def residual_along_track(p: Prepared, nominal: Evaluation, augmented: Evaluation) -> dict[str, Any]:
    """The residual along the track, computed once so that no reader simulates it again: per
    dynamic channel the binned mean multi-step error of the nominal and the augmented model
    (:func:`~gprace.diagnose.locate.track_profile`) and the noise twin's RMS error (1 sigma)."""
    before, after, noise = {}, {}, {}
    for c in DYNAMIC:
        ch = CHANNELS[c]
        s, before[ch] = locate.track_profile(p.data, p.starts, p.H, nominal.Ed, c)
        _, after[ch] = locate.track_profile(p.data, p.starts, p.H, augmented.Ed, c)
        noise[ch] = float(np.sqrt(np.mean(nominal.Et[..., c] ** 2)))
    return residual_profile(s, before, after, noise, locate.BIN_METRES)


def _report(p: Prepared, s: Screened, ctx: Ctx, c: Calibrated, named: Named, ver: Verified,
            vehicle: VehicleConfig, augmented_name: str | None, untestable: dict[str, str]) -> dict[str, Any]:
    nom, aug = s.nominal, ver.augmented
    structured = nom.structured
    verdict = "mismatch" if structured else "no_significant_mismatch"
    effects = ver.effects if verdict == "mismatch" else ()
    l_nom = np.mean(ctx.prob.residuals(core.model_for(vehicle, p.data), ctx.eval_w) ** 2, axis=1).mean(axis=0)
    l_cal = c.heldout.mean(axis=0) if c.applied else l_nom
    l_aug = ver.heldout_after if ver.heldout_after is not None else l_cal
    channels_json = _channels_json(p, s, c, aug, l_nom, l_cal, l_aug)
    regions_json = []
    for ch in TESTED:
        if ch not in structured:
            continue
        for g in nom.regions[ch]:
            regions_json.append({"channel": g.channel, "s_start": round(g.s_start, 1), "s_end": round(g.s_end, 1),
                                 "description": f"{g.description}; seen in {g.laps_seen} of {g.laps_total} lap(s)"})
    fitted_on = c.vehicle if c.applied else vehicle  # the car the effects were fitted against

    eff_json = [_effect_json(e, fitted_on, p.data) for e in effects]
    partial_json = [_effect_json(e, fitted_on, p.data) for e in (ver.partial if verdict == "mismatch" else ())]
    ex0, ex1 = _excess(nom), _excess(aug)
    unexplained = {}
    for st, ch in zip(nom.stats, TESTED):
        if ch in structured and ch in aug.structured:
            unexplained[st.name] = float(np.sqrt(ex1[TESTED.index(ch)]))
    modelled = effects or partial_json
    after = "the calibration and the effects" if c.applied and modelled else (
        "the calibration" if c.applied else "the effects")
    for ch in TESTED:
        if ch in aug.structured and (modelled or c.applied):
            for g in aug.regions[ch]:
                regions_json.append({"channel": g.channel, "s_start": round(g.s_start, 1), "s_end": round(g.s_end, 1),
                                     "description": f"unexplained after {after}: {g.description}"})
    tot0 = float(sum(ex0[i] / nom.stats[i].rmse_twin**2 for i in range(3)))
    tot1 = float(sum(ex1[i] / aug.stats[i].rmse_twin**2 for i in range(3)))
    explained = (1.0 - tot1 / tot0) if tot0 > 0 else 0.0
    notes = list(p.notes) + [env.note() for env in p.envelopes if env.excluded] + list(ver.notes)
    notes += [why for n, why in ctx.refused.items() if n not in {e.name for e in ver.modelled}
              and not any(x.startswith(n) for x in ver.notes)]
    if s.not_identifiable:
        notes.append("not identifiable from these recordings: " + "; ".join(
            f"{e} ({why})" for e, why in s.not_identifiable.items()))
    return {
        "verdict": verdict,
        "channels": channels_json,
        "regions": regions_json,
        "effects": eff_json,
        "partial_effects": partial_json,
        "unexplained": unexplained,
        "augmented_vehicle": augmented_name,
        "explained_share": round(max(min(explained, 1.0), 0.0), 4) if verdict == "mismatch" else 0.0,
        "not_identifiable": [{"effect": e, "reason": why} for e, why in s.not_identifiable.items()],
        "excluded": [env.to_dict() for env in p.envelopes],
        "notes": notes,
        "noise_sigma": {CHANNELS[i]: float(s.sigma[i]) for i in range(6)},
        "samples": int(p.data.n), "horizon": p.H,
        "inputs": _inputs_json(p.data, untestable),
        "calibration": _calibration_json(c, vehicle, verdict),
    }


def _channels_json(p: Prepared, s: Screened, c: Calibrated, aug, l_nom, l_cal, l_aug) -> list[dict[str, Any]]:
    """One entry per tested channel: its test, RMSEs before and after, held-out losses, regime."""
    nom = s.nominal
    structured = nom.structured
    channels_json = []
    for st, s1, pr, ch in zip(nom.stats, aug.stats, nom.pred, TESTED):
        d = {"name": st.name, "structured": ch in structured, "statistic": round(float(st.statistic), 3),
             "rmse_nominal": float(st.rmse), "rmse_noise_floor": float(st.rmse_twin),
             "rmse_augmented": float(s1.rmse),
             "predictability": {"t": pr.t, "heldout_share": pr.gain,
                                "where": [{"subset": x.label, "t": x.t, "heldout_share": x.gain} for x in pr.subsets]}}
        if c.applied:
            d["rmse_calibrated"] = float(c.baseline.nominal.stats[TESTED.index(ch)].rmse)
        if ch in DYNAMIC:
            d["heldout_rmse_nominal"] = float(np.sqrt(l_nom[ch]) * s.scale[ch])
            if c.applied:
                d["heldout_rmse_calibrated"] = float(np.sqrt(l_cal[ch]) * s.scale[ch])
            d["heldout_rmse_augmented"] = float(np.sqrt(l_aug[ch]) * s.scale[ch])
        if ch in structured:
            d["regime"] = locate.regime(p.data, p.starts, p.H, nom.Ed, nom.Et, ch)
            if pr.subsets:
                d["regime"] += "; predictable where: " + ", ".join(x.label for x in pr.subsets)
        channels_json.append(d)
    return channels_json


def _effect_json(e: NamedEffect, fitted_on: VehicleConfig, data: core.Dataset) -> dict[str, Any]:
    """A named or partial effect as the JSON reports it (parameters with intervals, flagged at a bound)."""
    spec = EFFECTS[e.name].params
    params = {}
    for k, v in e.fit.scalars().items():
        if k in nm.FIXED:
            continue
        lo, hi = e.fit.ci.get(k, (float("nan"), float("nan")))
        params[k] = {"value": float(v), "ci95": [float(lo), float(hi)], "unit": spec[k].unit,
                     "at_bound": not k.startswith("s_") and nm.at_bound(e.name, k, float(v), fitted_on, data)}
    prof = e.fit.profile_json()
    if prof is not None:
        prof["at_bound"] = bool(np.any(nm.at_bound(e.name, "values", prof["value"], fitted_on, data)))
    return {"name": e.name, "parameters": params, "channels": e.channels,
            "heldout_rmse_before": e.heldout_before, "heldout_rmse_after": e.heldout_after,
            "improvement": round(e.improvement, 4), "ambiguous_with": list(e.ambiguous_with),
            "significant_where": e.where, "profile": prof}


def _inputs_json(data: core.Dataset, untestable: dict[str, str]) -> dict[str, Any]:
    """What the recordings' inputs are, how the model uses them, what each channel can test."""
    mode = data.longitudinal
    vx = {"force": "the longitudinal forces (powertrain command, drag, rolling resistance, grade)",
          "speed": "the car's speed loop and the longitudinal forces (drag, rolling resistance, grade)",
          "kinematic": ("nothing of the longitudinal forces: v_x follows the measured a_x"
                        + (" (only the road grade, which an accelerometer does not feel)"
                           if data.inputs.get("a_x") == "measured" else ""))}[mode]
    lat = "the lateral and yaw physics (tires, inertia, loads, steering and its lag"
    lat += ")" if data.inputs.get("delta") == "commanded" else ": a measured angle may still lead the tires)"
    return {**{k: data.inputs.get(k) for k in ("delta", "a_x", "v_cmd")}, "longitudinal": mode,
            "tests": {"v_x": vx, "v_y": lat, "yaw_rate": lat},
            "not_testable": [{"effect": e, "reason": why} for e, why in untestable.items()]}


def _calibration_json(c: Calibrated, vehicle: VehicleConfig, verdict: str) -> dict[str, Any]:
    applied = c.applied and verdict == "mismatch"
    params = c.fit.report(vehicle) if c.fit is not None and len(c.fit.params) else []
    return {"applied": applied, "tested": bool(c.tested), "considered": list(c.considered),
            "heldout_gain": round(float(c.gain), 4), "t": round(float(c.t), 2),
            "significant_where": c.where,
            "parameters": params,
            "not_identified": [{"name": n, "reason": why} for n, why in (c.fit.dropped.items() if c.fit else ())]}


# --------------------------------------------------------------------------------------------
# helpers


def excitation(data: core.Dataset, wheelbase: float | None = None) -> dict[str, str]:
    """Effects the recordings cannot identify, with the reason (missing excitation). Thresholds are
    accelerations in g and relative speed changes, so they hold for a 1:10 car as for a full-size one."""
    vx, r = data.Y[:, State.V_X], data.Y[:, State.YAW_RATE]
    ax, delta = data.A, data.U[:, Input.DELTA]
    ay = np.abs(vx * r)
    g = 9.81
    out: dict[str, str] = {}
    lateral = np.quantile(ay, 0.9) > 0.2 * g
    speed_var = np.std(vx) > 0.05 * max(float(np.mean(np.abs(vx))), 1e-9)
    long_var = np.std(ax) > 0.03 * g
    demand = vx * vx * delta / wheelbase if wheelbase else vx * delta * 10.0  # steering's lateral demand
    steer_var = np.std(demand) > 0.02 * g if wheelbase else np.std(delta) > 2e-3
    combined = np.mean((np.abs(ax) > 0.15 * g) & (ay > 0.2 * g)) > 0.02
    lat = ["downforce", "load_transfer", "tire_load_sensitivity", "combined_slip", "tire_friction",
           "cornering_stiffness", "friction_patch", "yaw_inertia"]
    if not lateral:
        for e in lat:
            out[e] = "no cornering (|a_y| stays below 0.2 g): tire and load effects are invisible"
    if not speed_var:
        for e in ("aero_drag", "rolling_resistance", "downforce"):
            out.setdefault(e, "speed nearly constant: speed-dependent forces cannot be told from constant ones")
    if not long_var:
        out.setdefault("drivetrain_lag", "a_x nearly constant: a drivetrain lag has nothing to delay")
    if not steer_var:
        out.setdefault("steering_lag", "steering nearly constant: a steering lag has nothing to delay")
        out.setdefault("yaw_inertia", "steering nearly constant: no yaw acceleration to weigh the inertia")
    if not combined:
        for e in ("load_transfer", "combined_slip"):
            out.setdefault(e, "no braking or drive while cornering: longitudinal-lateral coupling is invisible")
    for n, cls in EFFECTS.items():  # a profile is as visible as its window
        if cls.profile and cls.window_of in out:
            out.setdefault(n, out[cls.window_of])
    return out


def _refit_each(ctx: Ctx, effects: list[NamedEffect]) -> list[NamedEffect]:
    """Each effect refitted with the others fixed, its intervals again (after one was dropped)."""
    rest = [e.fit for e in effects]
    out = []
    for j, e in enumerate(effects):
        prob = _with_base(ctx.prob, rest, j)
        g = nm.refit(prob, e.fit, ctx.fit_w, max_nfev=30)
        g.ci = nm.interval95(prob, g, ctx.fit_w)
        out.append(replace(e, fit=g))
    return out


def input_limits(data: core.Dataset) -> dict[str, str]:
    """Catalogue effects the recordings' inputs cannot test, with the reason."""
    out: dict[str, str] = {}
    if data.longitudinal == "kinematic":
        why = f"a_x is {data.inputs.get('a_x')}: v_x follows it, the longitudinal forces are inside it"
        for e in ("aero_drag", "rolling_resistance", "drivetrain_lag"):
            out[e] = why
        if data.inputs.get("a_x") != "measured":
            out["road_grade"] = why + " (the grade too, unlike an accelerometer's)"
    return out


def _excess(ev: Evaluation) -> np.ndarray:
    return np.array([max(s.rmse**2 - s.rmse_twin**2, 0.0) for s in ev.stats])


def _with_base(prob: nm.Problem, fits: list[nm.Fit], i: int) -> nm.Problem:
    """The problem with every effect of ``fits`` but the i-th added to its model (the i-th is
    being fitted); the problem's own base (the effects chosen in earlier rounds) is kept: a
    candidate is refitted on top of them, as it is scored."""
    return replace(prob, base=list(prob.base) + [g.effect() for j, g in enumerate(fits) if j != i])


def _sub(model: NominalModel, sub: int) -> int:
    s = sub
    for e in model.effects:
        if "tau" in e.values:
            s = max(s, int(np.ceil(0.05 / max(e.values["tau"], 1e-3))))
    return min(s, 20)


def _channels(name: str) -> list[int]:
    """Indices of the dynamic channels a catalogue effect acts on."""
    return [CHANNELS.index(c) for c in EFFECTS[name].channels]


def _heldout_channels_of(ctx: Ctx, fits: list[nm.Fit]) -> np.ndarray:
    """Cross-validated per-window, per-channel normalised squared error (m, 3) of the model with
    ``fits`` (the model itself, nothing to refit, when there are none)."""
    if not fits:
        return np.mean(ctx.prob.residuals(ctx.prob.model(), ctx.eval_w) ** 2, axis=1)
    return _heldout_channels(ctx, fits)


def _heldout_channels(ctx: Ctx, fits: list[nm.Fit]) -> np.ndarray:
    """(m, 3) cross-validated per-window, per-channel normalised squared error of the model with
    ``fits`` (each refitted without the held-out fold, the others fixed)."""
    key = tuple((f.name, f.x.tobytes()) for f in fits)
    if key not in ctx.heldout_memo:
        ctx.heldout_memo[key] = _cv_channels(ctx, fits)
    return ctx.heldout_memo[key]


def _cv_channels(ctx: Ctx, fits: list[nm.Fit]) -> np.ndarray:
    """Every effect refitted jointly without each fold (one linearised step, :mod:`crossval`);
    with a profile among them, each refitted in turn by its own fit (a profile's smoothing is
    chosen inside its fit, not a block of the linearised step)."""
    prob, eval_w, fold = ctx.prob, ctx.eval_w, ctx.fold
    if not any(f.profile is not None for f in fits):
        return cv_.cv_losses(prob, [cv_.effect_block(f, prob.data, prob.vehicle) for f in fits], eval_w, fold)
    out = np.empty((len(eval_w), 3))
    folds = np.unique(fold)
    trains = [eval_w[fold != fo][:: max(1, len(eval_w) // 400)] for fo in folds]
    if len(fits) == 1:  # one profile (a candidate): one Jacobian for every fold's refit
        for fo, g in zip(folds, pf_.fold_refits(_with_base(prob, fits, 0), fits[0], trains)):
            out[fold == fo] = np.mean(prob.residuals(prob.model([g.effect()]), eval_w[fold == fo]) ** 2, axis=1)
        return out
    for fo, tr in zip(folds, trains):
        te = fold == fo
        fs = list(fits)
        for i, f in enumerate(fs):
            fs[i] = nm.refit(_with_base(prob, fs, i), f, tr, max_nfev=10)
        out[te] = np.mean(prob.residuals(prob.model([f.effect() for f in fs]), eval_w[te]) ** 2, axis=1)
    return out


def _heldout(ctx: Ctx, fits: list[nm.Fit]) -> np.ndarray:
    """Cross-validated per-channel mean normalised squared error (3,) of the augmented model."""
    return _heldout_channels(ctx, fits).mean(axis=0)
