"""The diagnosis pipeline: locate -> name -> model -> show (see ``docs/decisions.md``, diagnose).

:func:`diagnose` takes recordings and the nominal vehicle and returns the JSON-ready report of
the issue's contract plus the augmented :class:`~gprace.config.VehicleConfig`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from gprace.config import EffectConfig, VehicleConfig
from gprace.diagnose import core, locate, name as nm
from gprace.diagnose.core import CHANNELS, DYNAMIC, TESTED
from gprace.errors import InputError
from gprace.io.runs import Run
from gprace.model import EFFECTS, NominalModel

HORIZON = 15
"""Multi-step horizon [steps] (0.75 s at 20 Hz): long enough that structured error outgrows the
one-step sensor noise, short enough that open-loop predictions stay on the recorded path."""

MAX_EFFECTS = 3
MIN_WINDOWS = 150
UNEXPLAINED_SHARE = 0.1
"""A named effect whose channels keep more than this share of their structured error is not
trusted: the residual says the physics is something else (reported unexplained, not misnamed)."""

_ALIAS = {3: 2, 4: 1}  # e_psi error comes from yaw rate, e_y error from v_y


@dataclass
class Diagnosis:
    report: dict[str, Any]
    vehicle: VehicleConfig  # augmented (equal to the input when nothing was named)
    plot_data: dict[str, Any]


def excitation(data: core.Dataset) -> dict[str, str]:
    """Effects the recordings cannot identify, with the reason (missing excitation)."""
    vx, r, ax, delta = data.Y[:, 0], data.Y[:, 2], data.U[:, 1], data.U[:, 0]
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
    return out


def _stats_and_local(data, starts, H, Ed, Et, regions_by_c) -> list[locate.ChannelStat]:
    cs = locate.channel_stats(data, starts, Ed, Et)
    for st, c in zip(cs, TESTED):
        rg = regions_by_c.get(c, [])
        # a localised error counts only when it repeats: seen in at least two laps
        local = [g for g in rg if g.laps_seen >= 2 and g.excess > 0.5 * st.rmse_twin**2]
        if local and not st.structured:
            st.structured = True
            st.statistic = max(st.statistic, max(g.z for g in local))
    return cs


def diagnose(runs: list[Run], vehicle: VehicleConfig, *, horizon: int = HORIZON, seed: int = 0,
             augmented_name: str | None = None, log: Callable[[str], None] | None = None) -> Diagnosis:
    t0 = time.perf_counter()
    log = log or (lambda s: None)
    H = int(horizon)
    data = core.build_dataset(runs, min_samples=max(200, 10 * H))
    starts = data.windows(H)
    if len(starts) < MIN_WINDOWS:
        raise InputError(f"{data.sources[0]}: only {len(starts)} gap-free {H}-step windows; need {MIN_WINDOWS}")
    m0 = NominalModel(vehicle)
    sub = 2
    log(f"diagnose: {data.n} samples, {len(data.L)} recording(s), {data.laps_total} lap(s), horizon {H}")

    # ---- locate ------------------------------------------------------------------------
    sigma = core.estimate_noise(m0, data, starts, H, sub, seed=seed)
    Ed0 = core.errors(data, starts, core.predict(m0, data, starts, H, sub))
    twin = core.make_twin(m0, data, starts, H, sigma, seed=seed + 1)
    Et0 = core.twin_errors(m0, data, starts, twin, sub)
    regions = {c: locate.find_regions(data, starts, H, Ed0, Et0, c) for c in TESTED}
    stats0 = _stats_and_local(data, starts, H, Ed0, Et0, regions)
    structured = {c for st, c in zip(stats0, TESTED) if st.structured}
    dyn_struct = {_ALIAS.get(c, c) for c in structured}
    not_ident = excitation(data)
    scale = np.array([stats0[c].rmse_twin for c in DYNAMIC])
    mse_twin = np.array([st.rmse_twin**2 for st in stats0])
    log(f"diagnose: noise sigma {np.round(sigma, 4).tolist()}, structured: "
        f"{[CHANNELS[c] for c in sorted(structured)] or 'none'}")

    # ---- name ----------------------------------------------------------------------------
    prob = nm.Problem(vehicle, data, H, scale, substeps=1)
    fit_stride = max(1, len(starts) // 400)
    fit_w = starts[::fit_stride]
    screen_w = starts[:: max(1, len(starts) // 200)]
    eval_w = starts[:: max(1, len(starts) // 2500)]
    fold = nm.folds(data, eval_w)
    bid = locate.blocks(data, eval_w)
    reg_init = {c: [(g.s_start, g.s_end) for g in regions.get(c, [])] for c in DYNAMIC}
    for c in (3, 4):
        reg_init.setdefault(_ALIAS[c], []).extend((g.s_start, g.s_end) for g in regions.get(c, []))

    chosen: list[nm.Fit] = []
    effects_out: list[dict[str, Any]] = []
    searched: list[dict[str, Any]] = []
    if dyn_struct:
        for _round in range(MAX_EFFECTS):
            if len(chosen) >= 2:  # the earlier effects were fitted without the latest one: refit
                for i, f in enumerate(chosen):
                    prob.base = [g.effect() for j, g in enumerate(chosen) if j != i]
                    chosen[i] = nm.refit(prob, f, fit_w)
                    effects_out[i]["_fit"] = chosen[i]
            prob.base = [f.effect() for f in chosen]
            cur = prob.model()
            if chosen:  # stop when what is left is noise (against the same twin floor)
                Ec = core.errors(data, starts, core.predict(cur, data, starts, H, _sub(cur, sub)))
                rc = {c: locate.find_regions(data, starts, H, Ec, Et0, c) for c in TESTED}
                left = {_ALIAS.get(c, c) for st, c in zip(_stats_and_local(data, starts, H, Ec, Et0, rc), TESTED)
                        if st.structured}
                if not left:
                    break
                dyn_struct = left
            l0_ch = np.mean(prob.residuals(cur, eval_w) ** 2, axis=1)
            l0 = l0_ch.mean(axis=1)
            names = [n for n in EFFECTS if n not in {f.name for f in chosen} and n not in not_ident
                     and {CHANNELS.index(ch) for ch in EFFECTS[n].channels} & dyn_struct]
            fits = []
            for n in names:
                inits = nm.starts_for(n, reg_init)
                if not inits:
                    continue
                f = nm.fit_effect(prob, n, screen_w, inits, max_nfev=20)
                if f is not None:
                    fits.append(f)
            if not fits:
                break
            fits.sort(key=lambda f: f.cost)
            top = [nm.refit(prob, f, fit_w, max_nfev=20) for f in fits[: nm.SCREEN_TOP]]
            cv = {}
            for f in top:
                cv[f.name] = nm.cv_channel_losses(prob, f, eval_w, fold, fit_stride=max(1, len(eval_w) // 400))
            best = min(top, key=lambda f: cv[f.name].mean())
            l1 = cv[best.name].mean(axis=1)
            rel, t = nm.gain_test(l0, l1, bid)
            log(f"diagnose: round {_round + 1}: best {best.name} held-out gain {100 * rel:.1f}% (t = {t:.1f})")
            searched.append({"round": _round + 1, "candidates": {f.name: float(cv[f.name].mean()) for f in top},
                             "baseline": float(l0.mean())})
            gain = float(l0.mean() - l1.mean())
            excess = max(l0.mean() - 1.0, 1e-12)
            # few independent blocks (a short window effect) -> weaker t, accepted only when the
            # held-out gain removes at least half of the remaining excess
            sig = t > nm.T_GAIN or (t > nm.T_GAIN_STRONG and gain > 0.5 * excess)
            if not (sig and gain > nm.MIN_GAIN and gain > nm.MIN_EXCESS_SHARE * excess):
                break
            group = [best]
            for f in top:
                if f is best:
                    continue
                lf = cv[f.name].mean(axis=1)
                rel_f, t_f = nm.gain_test(l0, lf, bid)
                _, t_diff = nm.gain_test(lf, l1, bid)
                if (lf.mean() - l1.mean()) <= nm.AMBIGUOUS_SHARE * (l0.mean() - l1.mean()) and t_diff < 2.0 \
                        and t_f > nm.T_GAIN:
                    group.append(f)
            named = min(group, key=lambda f: (len(f.free), cv[f.name].mean()))
            l_named = cv[named.name]
            amb = [f.name for f in group if f is not named]
            chosen.append(named)
            ch = [CHANNELS.index(c) for c in EFFECTS[named.name].channels]
            effects_out.append({
                "name": named.name, "_fit": named, "channels": list(EFFECTS[named.name].channels),
                "heldout_rmse_before": {CHANNELS[c]: float(np.sqrt(l0_ch[:, c].mean()) * scale[c]) for c in ch},
                "heldout_rmse_after": {CHANNELS[c]: float(np.sqrt(l_named[:, c].mean()) * scale[c]) for c in ch},
                "improvement": float(1.0 - np.sqrt(l_named.mean() / l0_ch.mean())),
                "ambiguous_with": amb,
            })

    # one pass of refits with the others fixed (joint consistency), then intervals
    for i, f in enumerate(chosen):
        prob.base = [g.effect() for j, g in enumerate(chosen) if j != i]
        chosen[i] = nm.fit_effect(prob, f.name, fit_w, [f.values()], max_nfev=30) or f
        chosen[i].ci = nm.interval95(prob, chosen[i], fit_w)
        effects_out[i]["_fit"] = chosen[i]

    # ---- show: stats after, held-out RMSE before/after ------------------------------------
    prob.base = []
    aug_effects = [f.effect() for f in chosen]
    m1 = NominalModel(vehicle, aug_effects)
    if chosen:
        Ed1 = core.errors(data, starts, core.predict(m1, data, starts, H, _sub(m1, sub)))
        twin1 = core.make_twin(m1, data, starts, H, sigma, seed=seed + 2)
        Et1 = core.twin_errors(m1, data, starts, twin1, _sub(m1, sub))
    else:
        Ed1, Et1 = Ed0, Et0
    regions1 = {c: locate.find_regions(data, starts, H, Ed1, Et1, c) for c in TESTED}
    stats1 = _stats_and_local(data, starts, H, Ed1, Et1, regions1)
    # held-out (cross-validated) RMSE per channel of the augmented model
    heldout_after = _heldout(prob, chosen, eval_w, fold, fit_stride) if chosen else None
    l_nom = np.mean(prob.residuals(m0, eval_w) ** 2, axis=1).mean(axis=0)

    # unexplained structured error, and effects whose channels keep most of theirs
    ex0 = np.array([max(s.rmse**2 - s.rmse_twin**2, 0.0) for s in stats0])
    ex1 = np.array([max(s.rmse**2 - s.rmse_twin**2, 0.0) for s in stats1])
    share_left = np.where(ex0 > 0, ex1 / np.maximum(ex0, 1e-300), 0.0)
    rejected = []
    for eo in list(effects_out):
        chs = [TESTED.index(CHANNELS.index(c)) for c in eo["channels"]]
        bad = [i for i in chs if stats1[i].structured and share_left[i] > UNEXPLAINED_SHARE]
        if bad:
            rejected.append((eo, bad))
    if rejected:  # fall back: name nothing on channels the catalogue cannot explain
        keep = [eo for eo in effects_out if eo not in [r[0] for r in rejected]]
        effects_out = keep
        chosen = [eo["_fit"] for eo in keep]
        aug_effects = [f.effect() for f in chosen]
        m1 = NominalModel(vehicle, aug_effects)
        if chosen:
            Ed1 = core.errors(data, starts, core.predict(m1, data, starts, H, _sub(m1, sub)))
            Et1 = core.twin_errors(m1, data, starts, core.make_twin(m1, data, starts, H, sigma, seed=seed + 2),
                                   _sub(m1, sub))
        else:
            Ed1, Et1 = Ed0, Et0
        regions1 = {c: locate.find_regions(data, starts, H, Ed1, Et1, c) for c in TESTED}
        stats1 = _stats_and_local(data, starts, H, Ed1, Et1, regions1)
        ex1 = np.array([max(s.rmse**2 - s.rmse_twin**2, 0.0) for s in stats1])
        heldout_after = _heldout(prob, chosen, eval_w, fold, fit_stride) if chosen else None

    verdict = "mismatch" if structured else "no_significant_mismatch"
    if verdict == "no_significant_mismatch":
        effects_out, chosen, aug_effects = [], [], []
    aug_vehicle = vehicle.model_copy(update={"effects": tuple(vehicle.effects) + tuple(
        EffectConfig(name=f.name, params={k: float(v) for k, v in f.values().items()}) for f in chosen)})

    channels_json = []
    for st, s1, c in zip(stats0, stats1, TESTED):
        d = {"name": st.name, "structured": st.structured, "statistic": round(float(st.statistic), 3),
             "rmse_nominal": float(st.rmse), "rmse_noise_floor": float(st.rmse_twin),
             "rmse_augmented": float(s1.rmse)}
        if c in DYNAMIC:
            d["heldout_rmse_nominal"] = float(np.sqrt(l_nom[c]) * scale[c])
            d["heldout_rmse_augmented"] = float(np.sqrt(heldout_after[c]) * scale[c]) if heldout_after is not None \
                else d["heldout_rmse_nominal"]
        if st.structured:
            d["regime"] = locate.regime(data, starts, H, Ed0, Et0, c)
        channels_json.append(d)
    regions_json = []
    for c in TESTED:
        if c not in structured:
            continue
        for g in regions[c]:
            regions_json.append({"channel": g.channel, "s_start": round(g.s_start, 1), "s_end": round(g.s_end, 1),
                                 "description": f"{g.description}; seen in {g.laps_seen} of {g.laps_total} lap(s)"})
    eff_json = []
    for eo in effects_out:
        f = eo["_fit"]
        spec = EFFECTS[f.name].params
        ci = getattr(f, "ci", {})
        params = {}
        for k, v in f.values().items():
            if k in nm.FIXED:
                continue
            lo, hi = ci.get(k, (float("nan"), float("nan")))
            params[k] = {"value": float(v), "ci95": [float(lo), float(hi)], "unit": spec[k].unit}
        eff_json.append({"name": f.name, "parameters": params, "channels": eo["channels"],
                         "heldout_rmse_before": eo["heldout_rmse_before"], "heldout_rmse_after": eo["heldout_rmse_after"],
                         "improvement": round(eo["improvement"], 4), "ambiguous_with": eo["ambiguous_with"]})
    unexplained = {}
    for st, s1, c in zip(stats0, stats1, TESTED):
        if st.structured and s1.structured:
            unexplained[st.name] = float(np.sqrt(ex1[TESTED.index(c)]))
    unexpl_regions = []
    for c in TESTED:
        if stats1[TESTED.index(c)].structured and chosen:
            for g in regions1[c]:
                unexpl_regions.append({"channel": g.channel, "s_start": round(g.s_start, 1), "s_end": round(g.s_end, 1),
                                       "description": f"unexplained after the named effects: {g.description}"})
    regions_json.extend(unexpl_regions)
    tot0 = float(ex0[: len(DYNAMIC)].sum() and sum(ex0[i] / stats0[i].rmse_twin**2 for i in range(3)))
    tot1 = float(sum(ex1[i] / stats1[i].rmse_twin**2 for i in range(3)))
    explained = (1.0 - tot1 / tot0) if tot0 > 0 else 0.0
    notes = []
    if rejected:
        for eo, bad in rejected:
            notes.append(f"{eo['name']} fits part of the error but leaves "
                         f"{', '.join(CHANNELS[TESTED[i]] for i in bad)} structured: not named")
    if not_ident:
        notes.append("not identifiable from these recordings: " + "; ".join(
            f"{e} ({why})" for e, why in not_ident.items()))
    report = {
        "verdict": verdict,
        "channels": channels_json,
        "regions": regions_json,
        "effects": eff_json,
        "unexplained": unexplained,
        "augmented_vehicle": augmented_name,
        "explained_share": round(max(min(explained, 1.0), 0.0), 4) if verdict == "mismatch" else 0.0,
        "not_identifiable": [{"effect": e, "reason": why} for e, why in not_ident.items()],
        "notes": notes,
        "noise_sigma": {CHANNELS[i]: float(sigma[i]) for i in range(6)},
        "samples": int(data.n), "horizon": H, "runtime_s": round(time.perf_counter() - t0, 2),
    }
    plot_data = {"data": data, "starts": starts, "H": H, "Ed0": Ed0, "Et0": Et0, "Ed1": Ed1,
                 "structured": structured, "effects": [f.name for f in chosen]}
    return Diagnosis(report, aug_vehicle, plot_data)


def _sub(model: NominalModel, sub: int) -> int:
    s = sub
    for e in model.effects:
        if "tau" in e.values:
            s = max(s, int(np.ceil(0.05 / max(e.values["tau"], 1e-3))))
    return min(s, 20)


def _heldout(prob: nm.Problem, chosen: list[nm.Fit], eval_w, fold, fit_stride) -> np.ndarray:
    """Cross-validated per-channel mean normalised squared error of the augmented model."""
    out = np.empty((len(eval_w), 3))
    for fo in np.unique(fold):
        tr = eval_w[fold != fo][:: max(1, len(eval_w) // 500)]
        te = fold == fo
        fits = list(chosen)
        for i, f in enumerate(fits):
            prob.base = [g.effect() for j, g in enumerate(fits) if j != i]
            fits[i] = nm.refit(prob, f, tr)
        prob.base = []
        m = prob.model([f.effect() for f in fits])
        out[te] = np.mean(prob.residuals(m, eval_w[te]) ** 2, axis=1)
    prob.base = []
    return out.mean(axis=0)
