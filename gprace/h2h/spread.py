"""Spread of the head-to-head figures: bootstrap over tracks and spread over seeds of the chain.

Every figure of the table (border hits, collisions, overtakes, overtake time, e_y error per step)
is a weighted sum over the evaluation tracks, so one function, :func:`figures`, computes it for
the plain table (weights 1) and for every bootstrap resample at once (weights = how often each
track was drawn, ``(B, n)``). The chains of all seeds race the same evaluation scenarios, so a
resample draws the same tracks for every seed and the bootstrap interval of the seed mean covers
the choice of scenarios, while the spread over seeds (sample standard deviation) covers
collection, training and exploration.

A claim of the paper (exploration against the baseline) is a difference ``explore - baseline``
with a claimed sign. It ``holds`` only where, in every seed, the 95 % bootstrap interval of the
difference lies on the claimed side of zero; it ``fails`` where in every seed it lies on the other
side; ``seeds disagree`` where some seeds show it and others the opposite, ``not resolved``
otherwise (the difference is within the spread), and ``too few samples for a verdict`` where
fewer tracks than :data:`gprace.verdict.MIN_SAMPLES` are behind it (:mod:`gprace.verdict`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gprace.verdict import verdict

if TYPE_CHECKING:
    from gprace.h2h.records import RaceAttrs, Record

BOOTSTRAP = 2000
LEVEL = 0.95


@dataclass
class TrackData:
    """One chain's results per evaluation track (the unit of the bootstrap)."""

    border: dict[str, np.ndarray]  # raced predictor -> (n,) 0/1
    collision: dict[str, np.ndarray]
    overtake_time: dict[str, np.ndarray]  # (n,) seconds, NaN without an overtake (or a failed run)
    inside: np.ndarray  # (n,) every raced predictor ran and stayed inside
    err_sum: dict[str, np.ndarray]  # offline predictor -> (n, K) sum of |e_y| errors of the track's start times
    err_count: np.ndarray  # (n,) start times per track

    @property
    def n(self) -> int:
        return len(self.inside)


def track_data(raced: dict[str, list[Record[RaceAttrs]]], errors: dict[str, np.ndarray], tracks: np.ndarray, n: int) -> TrackData:
    """From the run records of each raced predictor (one per track) and the offline errors
    ``{predictor: (K, columns)}`` with the track of every column ``tracks (columns,)``."""
    border, collision, ot = {}, {}, {}
    inside = np.ones(n, dtype=bool)
    for p, recs in raced.items():
        a = [r.attrs for r in recs]
        ok = np.array([x.ok for x in a], dtype=bool)
        border[p] = np.array([x.border_hit for x in a], float) * ok
        collision[p] = np.array([x.collision for x in a], float) * ok
        ot[p] = np.where(ok, np.array([x.overtake_time for x in a], float), np.nan)
        inside &= ok & (border[p] == 0)
    tracks = np.asarray(tracks, int)
    count = np.bincount(tracks, minlength=n).astype(float)
    err_sum = {q: np.stack([np.bincount(tracks, weights=E[k], minlength=n) for k in range(E.shape[0])], axis=1)
               if E.shape[1] else np.zeros((n, E.shape[0])) for q, E in errors.items()}
    return TrackData(border, collision, ot, inside, err_sum, count)


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


def figures(td: TrackData, W: np.ndarray) -> dict[str, np.ndarray]:
    """Every figure and every claim's difference for track weights ``W (B, n)``: ``{name: (B,)}``.

    Names: ``<predictor>.border_hits``, ``.collisions``, ``.overtakes``, ``.overtake_time`` (mean
    over the tracks where every raced predictor stayed inside and this one overtook, as in the
    table), ``<predictor>.ey_error_<k>`` (k = 1..K), and for the claims ``diff.<figure>`` =
    explore - baseline (overtake time paired: tracks where both overtook)."""
    W = np.atleast_2d(np.asarray(W, float))
    out: dict[str, np.ndarray] = {}
    for p in td.border:
        t = td.overtake_time[p]
        m = td.inside & np.isfinite(t)
        out[f"{p}.border_hits"] = W @ td.border[p]
        out[f"{p}.collisions"] = W @ td.collision[p]
        out[f"{p}.overtakes"] = W @ np.isfinite(t).astype(float)
        out[f"{p}.overtake_time"] = _ratio(W @ np.where(m, t, 0.0), W @ m.astype(float))
    den = W @ td.err_count
    for q, S in td.err_sum.items():
        for k in range(S.shape[1]):
            out[f"{q}.ey_error_{k + 1}"] = _ratio(W @ S[:, k], den)
    if "explore" in td.border and "baseline" in td.border:
        for f in ("border_hits", "collisions", "overtakes"):
            out[f"diff.{f}"] = out[f"explore.{f}"] - out[f"baseline.{f}"]
        te, tb = td.overtake_time["explore"], td.overtake_time["baseline"]
        both = td.inside & np.isfinite(te) & np.isfinite(tb)
        out["diff.overtake_time"] = _ratio(W @ np.where(both, te - tb, 0.0), W @ both.astype(float))
    if "explore" in td.err_sum and "baseline" in td.err_sum:
        for k in range(td.err_sum["explore"].shape[1]):
            out[f"diff.ey_error_{k + 1}"] = out[f"explore.ey_error_{k + 1}"] - out[f"baseline.ey_error_{k + 1}"]
    return out


def resample_weights(n: int, B: int = BOOTSTRAP, seed: int = 0) -> np.ndarray:
    """``(B, n)``: how often each of ``n`` tracks is drawn in each of ``B`` resamples."""
    return np.random.default_rng(seed).multinomial(n, np.full(n, 1.0 / n), size=B).astype(float)


def _interval(v: np.ndarray) -> list[float | None]:
    v = v[np.isfinite(v)]
    if not len(v):
        return [None, None]
    a = 100 * (1 - LEVEL) / 2
    return [float(np.percentile(v, a)), float(np.percentile(v, 100 - a))]


def seed_stats(values: list[float]) -> dict:
    """Mean, sample standard deviation (None for one seed), min and max over seeds (NaN ignored)."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    return {"mean": float(v.mean()) if len(v) else None,
            "seed_std": float(v.std(ddof=1)) if len(v) > 1 else None,
            "min": float(v.min()) if len(v) else None, "max": float(v.max()) if len(v) else None}


def summarise(per_seed: list[TrackData], B: int = BOOTSTRAP, seed: int = 0) -> dict[str, dict]:
    """Per figure: ``values`` per seed, their :func:`seed_stats` and ``ci``, the bootstrap interval
    over tracks of the seed mean; for ``diff.*`` also ``seed_ci`` (each seed's interval) and the
    ``verdict`` (see the module docstring)."""
    n = per_seed[0].n
    W = resample_weights(n, B, seed)
    ones = np.ones((1, n))
    plain = [figures(td, ones) for td in per_seed]
    boot = [figures(td, W) for td in per_seed]
    out = {}
    for name in plain[0]:
        vals = [float(f[name][0]) for f in plain]
        with np.errstate(invalid="ignore"):
            mean_boot = np.mean(np.stack([b[name] for b in boot]), axis=0)
        row = {"values": vals, **seed_stats(vals), "ci": _interval(mean_boot)}
        if name.startswith("diff."):
            row["seed_ci"] = [_interval(b[name]) for b in boot]
            row["tracks"] = min(claim_tracks(td).get(name, td.n) for td in per_seed)
            row["verdict"] = verdict(row["seed_ci"], claimed=CLAIMED_SIGN.get(name.split(".", 1)[1], -1), n=row["tracks"])
        out[name] = row
    return out


CLAIMED_SIGN = {"overtakes": +1}
"""The paper claims exploration lowers every difference (errors, border hits, collisions,
overtake time) except the number of overtakes, which it raises."""


def claim_tracks(td: TrackData) -> dict[str, int]:
    """Per claim (``diff.*``): the tracks behind its difference, the samples of its bootstrap: every
    track for the counts, the tracks where both predictors overtook inside for the overtake time,
    the tracks with offline start times for the e_y errors."""
    out: dict[str, int] = {}
    if "explore" in td.border and "baseline" in td.border:
        for f in ("border_hits", "collisions", "overtakes"):
            out[f"diff.{f}"] = td.n
        both = td.inside & np.isfinite(td.overtake_time["explore"]) & np.isfinite(td.overtake_time["baseline"])
        out["diff.overtake_time"] = int(both.sum())
    if "explore" in td.err_sum and "baseline" in td.err_sum:
        for k in range(td.err_sum["explore"].shape[1]):
            out[f"diff.ey_error_{k + 1}"] = int((td.err_count > 0).sum())
    return out


# ----------------------------------------------------------------------------------------------
# calibrated spread of the predictions
CALIB_LEVEL = 0.94
"""Share of the calibration errors the calibrated 2-sigma band covers (per step and output); a
little below 0.95 so that fresh errors of the same distribution land in 90 to 95 %."""


def fit_calibration(err: np.ndarray, std: np.ndarray, level: float = CALIB_LEVEL) -> dict:
    """The calibration ``{"scale", "floor"}`` ((K, 2) each, columns s and e_y) of one predictor from
    its absolute errors ``err`` and raw predicted standard deviations ``std`` (2, K, n) (outputs s,
    e_y; K steps; n start times of held-out races): the calibrated std is ``scale * std + floor``.

    Where the predictor has a spread (most start times std > 0), ``scale`` is the ``level``
    quantile of ``|err| / (2 std)``, so ``2 * scale * std`` covers that share of the errors (an
    over-confident predictor gets a large scale, an honest one about 1); where it has none (the
    constant-velocity predictor), ``floor`` is half the ``level`` quantile of ``|err|``, a band of
    the predictor's typical error."""
    err, std = np.abs(np.asarray(err, float)), np.asarray(std, float)
    if err.shape != std.shape or err.ndim != 3 or err.shape[0] != 2 or err.shape[2] < 1:
        raise ValueError(f"calibration: errors and spreads must both be (2, K, n >= 1), got {err.shape} and {std.shape}")
    has = (std > 0).mean(axis=2) > 0.5  # (2, K)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(std > 0, err / (2.0 * std), np.nan)
    scale = np.where(has, np.nan_to_num(np.nanquantile(np.where(has[..., None], ratio, 0.0), level, axis=2)), 0.0)
    floor = np.where(has, 0.0, 0.5 * np.quantile(err, level, axis=2))
    return {"scale": scale.T.tolist(), "floor": floor.T.tolist(), "level": level, "points": int(err.shape[2])}


SETTLE_TOL = 0.1  # a fitted scale or floor this much below the one the races drove with asks for another pass


def settled(driving: dict, fitted: dict, tol: float = SETTLE_TOL) -> bool:
    """Whether races driven with the calibration ``driving`` confirm it: every scale and floor
    ``fitted`` on them is at least ``(1 - tol)`` times the one they drove with.

    The errors depend on the ellipses the ego drives with: wider ellipses keep it back, so the
    opponent blocks less and the errors shrink. A calibration fitted on races driven with a larger
    one is too small for the races it will drive itself (measured: exploration 9-step e_y scale
    3.88 -> 1.43, coverage 88.7 % instead of 94 %); when the fit does not fall below what the races
    drove with, :func:`at_least` of the two covers the races it drives (docs/decisions.md)."""
    for key in ("scale", "floor"):
        d, f = np.asarray(driving[key], float), np.asarray(fitted[key], float)
        if np.any(f[d > 0] < (1.0 - tol) * d[d > 0]):
            return False
    return True


def at_least(driving: dict, fitted: dict) -> dict:
    """The element-wise larger of two calibrations (scale and floor), ``fitted``'s other keys."""
    return {**fitted, **{k: np.maximum(np.asarray(driving[k], float), np.asarray(fitted[k], float)).tolist()
                         for k in ("scale", "floor")}}


def band_coverage(err: np.ndarray, std: np.ndarray, calibration: dict | None = None) -> np.ndarray:
    """(2, K): share of the absolute errors ``err`` (2, K, n) inside the 2-sigma band of the
    (calibrated) standard deviations ``std`` (2, K, n); NaN without points."""
    from gprace.h2h.predictors import calibrated_std

    err, std = np.abs(np.asarray(err, float)), np.asarray(std, float)
    if err.shape[2] == 0:
        return np.full(err.shape[:2], np.nan)
    sig = calibrated_std(std.transpose(2, 1, 0), calibration).transpose(2, 1, 0)
    return np.mean(err <= 2.0 * sig, axis=2)
