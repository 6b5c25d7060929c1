"""The diagnosis pipeline: envelope -> screen -> locate -> name -> fit -> verify -> report.

Each stage is a function returning a small frozen result (see ``docs/decisions.md``, diagnose):

- :func:`prepare` cuts every recording to the model's envelope (:mod:`gprace.io.envelope`: spins,
  standstill, reversing, time gaps) and stacks what is left;
- :func:`screen` estimates the sensor noise, evaluates the nominal model (multi-step errors, noise
  twin, predictability of the error per regime and per region of the lap) and says which
  channels carry structured error;
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
from gprace.diagnose import core, locate, name as nm, screen as scr
from gprace.diagnose.core import CHANNELS, DYNAMIC, TESTED
from gprace.diagnose.laps import wrap_runs
from gprace.diagnose.profiles import leading, window_or_profile
from gprace.diagnose.result import DiagnosisResult, residual_profile
from gprace.errors import InputError
from gprace.io.envelope import EnvelopeReport, envelope
from gprace.io.runs import Run
from gprace.model import EFFECTS, Input, NominalModel, State

HORIZON = 15
"""Multi-step horizon [steps] (0.75 s at 20 Hz): long enough that structured error outgrows the
one-step sensor noise, short enough that open-loop predictions stay on the recorded path."""

MAX_EFFECTS = 3
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


# --------------------------------------------------------------------------------------------
# stages


def prepare(runs: list[Run], H: int) -> Prepared:
    """Wrap s per lap where it runs on (:func:`gprace.diagnose.laps.wrap_runs`), cut every
    recording to the model's envelope, stack them, list the gap-free windows."""
    runs, lap_notes = wrap_runs(runs)
    kept, envs = [], []
    for r in runs:
        mask, rep = envelope(r.data, r.source)
        envs.append(rep)
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
    m0 = NominalModel(vehicle)
    sigma = core.estimate_noise(m0, p.data, p.starts, p.H, 2, seed=seed)
    ev = evaluate(p, m0, sigma, seed + 1)
    scale = np.array([ev.stats[c].rmse_twin for c in DYNAMIC])
    return Screened(sigma, ev, scale, excitation(p.data))


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
    fit_stride = max(1, len(starts) // 400)
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


def name(p: Prepared, s: Screened, loc: Located, ctx: Ctx, log: Callable[[str], None]) -> Named:
    """Greedy forward selection of catalogue effects by held-out gain beyond those already chosen."""
    chosen: list[NamedEffect] = []
    searched: list[dict] = []
    dyn_struct = set(s.nominal.dynamic_structured)
    if not dyn_struct:
        return Named((), ())
    for rnd in range(MAX_EFFECTS):
        fits = [e.fit for e in chosen]
        if len(fits) >= 2:  # the earlier effects were fitted without the latest one: refit
            fits = [nm.refit(_with_base(ctx.prob, fits, i), f, ctx.fit_w) for i, f in enumerate(fits)]
            chosen = [replace(e, fit=f) for e, f in zip(chosen, fits)]
        prob = replace(ctx.prob, base=[f.effect() for f in fits])
        cur = prob.model()
        if chosen:  # stop when what is left is noise (against the same noise estimate)
            left = evaluate(p, cur, s.sigma, 0, scale=s.scale, Et=s.nominal.Et).dynamic_structured
            if not left:
                break
            dyn_struct = set(left)
        l0_ch = np.mean(prob.residuals(cur, ctx.eval_w) ** 2, axis=1)
        l0 = l0_ch.mean(axis=1)
        names = [n for n in EFFECTS if n not in {f.name for f in fits} and n not in s.not_identifiable
                 and {CHANNELS.index(ch) for ch in EFFECTS[n].channels} & dyn_struct]
        log(f"diagnose: round {rnd + 1}: screening {len(names)} candidate effects")
        cands = []
        for n in names:  # a few iterations from every starting point, on the screening windows
            inits = nm.starts_for(n, loc.windows)
            f = nm.fit_effect(prob, n, ctx.screen_w, inits, max_nfev=nm.PRESCREEN_NFEV) if inits else None
            if f is not None:
                cands.append(f)
        if not cands:
            break
        cands.sort(key=lambda f: f.cost)
        # only the most promising continue to the full screening fit, warm-started
        # (a window and its profile share one slot: profiles.leading)
        cands = sorted((nm.refit(prob, f, ctx.screen_w, max_nfev=20) for f in leading(cands, nm.PRESCREEN_KEEP)),
                       key=lambda f: f.cost)
        top = [nm.refit(prob, f, ctx.fit_w, max_nfev=20) for f in leading(cands, nm.SCREEN_TOP)]
        cv = {f.name: nm.cv_channel_losses(prob, f, ctx.eval_w, ctx.fold,
                                            fit_stride=max(1, len(ctx.eval_w) // 400)) for f in top}
        top = window_or_profile(top, cv, ctx.bid)  # parsimony: the window unless the profile is better
        best = min(top, key=lambda f: cv[f.name].mean())
        l1 = cv[best.name].mean(axis=1)
        ok, where, t = _significant(ctx, l0, l1)
        log(f"diagnose: round {rnd + 1}: best {best.name} held-out gain "
            f"{100 * (l0.mean() - l1.mean()) / max(l0.mean(), 1e-12):.1f}% (t = {t:.1f}, {where or 'not significant'})")
        searched.append({"round": rnd + 1, "candidates": {f.name: float(cv[f.name].mean()) for f in top},
                         "baseline": float(l0.mean())})
        if not ok:
            break
        group = [best]
        for f in top:
            if f is best:
                continue
            lf = cv[f.name].mean(axis=1)
            _, t_f = nm.gain_test(l0, lf, ctx.bid)
            _, t_diff = nm.gain_test(lf, l1, ctx.bid)
            if (lf.mean() - l1.mean()) <= nm.AMBIGUOUS_SHARE * (l0.mean() - l1.mean()) and t_diff < 2.0 \
                    and t_f > nm.T_GAIN:
                group.append(f)
        named = min(group, key=lambda f: (len(f.free), cv[f.name].mean()))
        ln = cv[named.name]
        ch = [CHANNELS.index(c) for c in EFFECTS[named.name].channels]
        chosen.append(NamedEffect(
            fit=named,
            heldout_before={CHANNELS[c]: float(np.sqrt(l0_ch[:, c].mean()) * s.scale[c]) for c in ch},
            heldout_after={CHANNELS[c]: float(np.sqrt(ln[:, c].mean()) * s.scale[c]) for c in ch},
            improvement=float(1.0 - np.sqrt(ln.mean() / l0_ch.mean())),
            ambiguous_with=tuple(f.name for f in group if f is not named), where=where))
    return Named(tuple(chosen), tuple(searched))


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
    evaluation; an effect whose channels stay structured is withdrawn."""
    effects = list(named.effects)
    notes: list[str] = []
    if effects:
        log(f"diagnose: verifying {', '.join(e.name for e in effects)} on held-out windows (parsimony)")
    # parsimony: each effect must still improve held-out fit given all the others
    for i in range(len(effects) - 1, -1, -1):
        if len(effects) < 2:
            break
        fits = [e.fit for e in effects]
        l_all = _heldout_losses(ctx, fits)
        l_wo = _heldout_losses(ctx, [f for j, f in enumerate(fits) if j != i])
        ok, where, t = _significant(ctx, l_wo, l_all)
        if not ok:
            drop = effects.pop(i)
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
    m1 = NominalModel(vehicle, [e.fit.effect() for e in effects])
    ev1 = evaluate(p, m1, s.sigma, seed + 2, scale=s.scale) if effects else s.nominal
    ex0, ex1 = _excess(s.nominal), _excess(ev1)
    share_left = np.where(ex0 > 0, ex1 / np.maximum(ex0, 1e-300), 0.0)
    rejected = []
    for e in effects:
        chs = [TESTED.index(CHANNELS.index(c)) for c in e.channels]
        bad = [i for i in chs if TESTED[i] in ev1.structured and share_left[i] > UNEXPLAINED_SHARE]
        if bad:
            rejected.append((e, bad))
    if rejected:  # fall back: name nothing on channels the catalogue cannot explain
        for e, bad in rejected:
            notes.append(f"{e.name} fits part of the error but leaves "
                         f"{', '.join(CHANNELS[TESTED[i]] for i in bad)} structured: not named")
        effects = [e for e in effects if e not in [r[0] for r in rejected]]
        m1 = NominalModel(vehicle, [e.fit.effect() for e in effects])
        ev1 = evaluate(p, m1, s.sigma, seed + 2, scale=s.scale) if effects else s.nominal
    heldout = _heldout(ctx, [e.fit for e in effects]) if effects else None
    return Verified(tuple(effects), ev1, heldout, tuple(notes))


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
    p = prepare(runs, int(horizon))
    data = p.data
    for note in p.notes:
        log(f"diagnose: {note}")
    for env in p.envelopes:
        if env.excluded:
            log(f"diagnose: {env.note()}")
    log(f"diagnose: {data.n} samples, {len(data.L)} recording(s), {data.laps_total} lap(s), horizon {p.H}")
    s = screen(p, vehicle, seed)
    log(f"diagnose: noise sigma {np.round(s.sigma, 4).tolist()}, structured: "
        f"{[CHANNELS[c] for c in sorted(s.nominal.structured)] or 'none'}")
    loc = locate_windows(s)
    ctx = _context(p, vehicle, s)
    named = fit(ctx, name(p, s, loc, ctx, log))
    ver = verify(p, s, ctx, named, vehicle, seed, log)
    report = _report(p, s, ctx, named, ver, vehicle, augmented_name)
    report["residual_profile"] = residual_along_track(p, s.nominal, ver.augmented)
    report["runtime_s"] = round(time.perf_counter() - t0, 2)
    result = DiagnosisResult.model_validate(report)  # a failure here is a bug of the pipeline, not bad input
    effects = ver.effects if result.verdict == "mismatch" else ()
    aug_vehicle = vehicle.model_copy(update={"effects": tuple(vehicle.effects) + tuple(
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


def _report(p: Prepared, s: Screened, ctx: Ctx, named: Named, ver: Verified, vehicle: VehicleConfig,
            augmented_name: str | None) -> dict[str, Any]:
    nom, aug = s.nominal, ver.augmented
    structured = nom.structured
    verdict = "mismatch" if structured else "no_significant_mismatch"
    effects = ver.effects if verdict == "mismatch" else ()
    l_nom = np.mean(ctx.prob.residuals(NominalModel(vehicle), ctx.eval_w) ** 2, axis=1).mean(axis=0)
    channels_json = []
    for st, s1, pr, c in zip(nom.stats, aug.stats, nom.pred, TESTED):
        d = {"name": st.name, "structured": c in structured, "statistic": round(float(st.statistic), 3),
             "rmse_nominal": float(st.rmse), "rmse_noise_floor": float(st.rmse_twin),
             "rmse_augmented": float(s1.rmse),
             "predictability": {"t": pr.t, "heldout_share": pr.gain,
                                "where": [{"subset": x.label, "t": x.t, "heldout_share": x.gain} for x in pr.subsets]}}
        if c in DYNAMIC:
            d["heldout_rmse_nominal"] = float(np.sqrt(l_nom[c]) * s.scale[c])
            d["heldout_rmse_augmented"] = float(np.sqrt(ver.heldout_after[c]) * s.scale[c]) \
                if ver.heldout_after is not None else d["heldout_rmse_nominal"]
        if c in structured:
            d["regime"] = locate.regime(p.data, p.starts, p.H, nom.Ed, nom.Et, c)
            if pr.subsets:
                d["regime"] += "; predictable where: " + ", ".join(x.label for x in pr.subsets)
        channels_json.append(d)
    regions_json = []
    for c in TESTED:
        if c not in structured:
            continue
        for g in nom.regions[c]:
            regions_json.append({"channel": g.channel, "s_start": round(g.s_start, 1), "s_end": round(g.s_end, 1),
                                 "description": f"{g.description}; seen in {g.laps_seen} of {g.laps_total} lap(s)"})
    eff_json = []
    for e in effects:
        spec = EFFECTS[e.name].params
        params = {}
        for k, v in e.fit.scalars().items():
            if k in nm.FIXED:
                continue
            lo, hi = e.fit.ci.get(k, (float("nan"), float("nan")))
            params[k] = {"value": float(v), "ci95": [float(lo), float(hi)], "unit": spec[k].unit}
        eff_json.append({"name": e.name, "parameters": params, "channels": e.channels,
                         "heldout_rmse_before": e.heldout_before, "heldout_rmse_after": e.heldout_after,
                         "improvement": round(e.improvement, 4), "ambiguous_with": list(e.ambiguous_with),
                         "significant_where": e.where, "profile": e.fit.profile_json()})
    ex0, ex1 = _excess(nom), _excess(aug)
    unexplained = {}
    for st, c in zip(nom.stats, TESTED):
        if c in structured and c in aug.structured:
            unexplained[st.name] = float(np.sqrt(ex1[TESTED.index(c)]))
    for c in TESTED:
        if c in aug.structured and effects:
            for g in aug.regions[c]:
                regions_json.append({"channel": g.channel, "s_start": round(g.s_start, 1), "s_end": round(g.s_end, 1),
                                     "description": f"unexplained after the named effects: {g.description}"})
    tot0 = float(sum(ex0[i] / nom.stats[i].rmse_twin**2 for i in range(3)))
    tot1 = float(sum(ex1[i] / aug.stats[i].rmse_twin**2 for i in range(3)))
    explained = (1.0 - tot1 / tot0) if tot0 > 0 else 0.0
    notes = list(p.notes) + [env.note() for env in p.envelopes if env.excluded] + list(ver.notes)
    if s.not_identifiable:
        notes.append("not identifiable from these recordings: " + "; ".join(
            f"{e} ({why})" for e, why in s.not_identifiable.items()))
    return {
        "verdict": verdict,
        "channels": channels_json,
        "regions": regions_json,
        "effects": eff_json,
        "unexplained": unexplained,
        "augmented_vehicle": augmented_name,
        "explained_share": round(max(min(explained, 1.0), 0.0), 4) if verdict == "mismatch" else 0.0,
        "not_identifiable": [{"effect": e, "reason": why} for e, why in s.not_identifiable.items()],
        "excluded": [env.to_dict() for env in p.envelopes],
        "notes": notes,
        "noise_sigma": {CHANNELS[i]: float(s.sigma[i]) for i in range(6)},
        "samples": int(p.data.n), "horizon": p.H,
    }


# --------------------------------------------------------------------------------------------
# helpers


def excitation(data: core.Dataset) -> dict[str, str]:
    """Effects the recordings cannot identify, with the reason (missing excitation)."""
    vx, r = data.Y[:, State.V_X], data.Y[:, State.YAW_RATE]
    ax, delta = data.U[:, Input.A_X], data.U[:, Input.DELTA]
    ay = np.abs(vx * r)
    out: dict[str, str] = {}
    lateral = np.quantile(ay, 0.9) > 2.0
    speed_var = np.std(vx) > 1.0
    long_var = np.std(ax) > 0.3
    steer_var = np.std(delta) > 2e-3
    combined = np.mean((np.abs(ax) > 1.5) & (ay > 2.0)) > 0.02
    lat = ["downforce", "load_transfer", "tire_load_sensitivity", "combined_slip", "tire_friction",
           "cornering_stiffness", "friction_patch", "yaw_inertia"]
    if not lateral:
        for e in lat:
            out[e] = "no cornering (|a_y| stays below 2 m/s^2): tire and load effects are invisible"
    if not speed_var:
        for e in ("aero_drag", "rolling_resistance", "downforce"):
            out.setdefault(e, "speed nearly constant: speed-dependent forces cannot be told from constant ones")
    if not long_var:
        out.setdefault("drivetrain_lag", "a_x command nearly constant: a drivetrain lag has nothing to delay")
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


def _excess(ev: Evaluation) -> np.ndarray:
    return np.array([max(s.rmse**2 - s.rmse_twin**2, 0.0) for s in ev.stats])


def _with_base(prob: nm.Problem, fits: list[nm.Fit], i: int) -> nm.Problem:
    """The problem with every chosen effect but the i-th in the model (the i-th is being fitted)."""
    return replace(prob, base=[g.effect() for j, g in enumerate(fits) if j != i])


def _sub(model: NominalModel, sub: int) -> int:
    s = sub
    for e in model.effects:
        if "tau" in e.values:
            s = max(s, int(np.ceil(0.05 / max(e.values["tau"], 1e-3))))
    return min(s, 20)


def _heldout_losses(ctx: Ctx, fits: list[nm.Fit]) -> np.ndarray:
    """Cross-validated per-window normalised squared error (m,) of the model with ``fits``."""
    if not fits:
        return np.mean(ctx.prob.residuals(ctx.prob.model(), ctx.eval_w) ** 2, axis=(1, 2))
    return _heldout_channels(ctx, fits).mean(axis=1)


def _heldout_channels(ctx: Ctx, fits: list[nm.Fit]) -> np.ndarray:
    """(m, 3) cross-validated per-window, per-channel normalised squared error of the model with
    ``fits`` (each refitted without the held-out fold, the others fixed)."""
    key = tuple((f.name, f.x.tobytes()) for f in fits)
    if key not in ctx.heldout_memo:
        ctx.heldout_memo[key] = _cv_channels(ctx, fits)
    return ctx.heldout_memo[key]


def _cv_channels(ctx: Ctx, fits: list[nm.Fit]) -> np.ndarray:
    prob, eval_w, fold = ctx.prob, ctx.eval_w, ctx.fold
    out = np.empty((len(eval_w), 3))
    for fo in np.unique(fold):
        tr = eval_w[fold != fo][:: max(1, len(eval_w) // 500)]
        te = fold == fo
        fs = list(fits)
        for i, f in enumerate(fs):
            fs[i] = nm.refit(_with_base(prob, fs, i), f, tr)
        m = prob.model([f.effect() for f in fs])
        out[te] = np.mean(prob.residuals(m, eval_w[te]) ** 2, axis=1)
    return out


def _heldout(ctx: Ctx, fits: list[nm.Fit]) -> np.ndarray:
    """Cross-validated per-channel mean normalised squared error (3,) of the augmented model."""
    return _heldout_channels(ctx, fits).mean(axis=0)
