"""Screen: is a channel's error *predictable* from where the car is and what it is doing?

The noise twin (:mod:`gprace.diagnose.locate`) compares error sizes with white sensor noise. Real
sensor noise is coloured (a GNSS/INS filter), which makes multi-step errors grow with the horizon
as model error does, and an error that lives in a few percent of the samples (a steering lag in
fast transients, a traction ellipse on full-drive corner exits) is diluted in a whole-file mean.
What separates physics from noise whatever its colour is that physics *repeats*: the error is a
function of the operating point (speed, lateral and longitudinal acceleration, steering rate ...)
or of the place on the lap (seen again in other laps); noise is not.

So every window's mean signed multi-step error (normalised by the noise floor) is regressed on
regime features of the window and on a lap-repeat feature (the mean error at the same place in
*other* laps), and predicted out of sample (five interleaved folds of ~2 s blocks, longer than the
noise correlation). Features use the recorded commands and the large, well-measured states only
(never ``v_y``, whose sensor noise propagates into the error and would be "predicted").

The held-out squared-error reduction per block gives a paired t-statistic, over all windows and
within each operating regime and each tenth of the lap, so a concentrated effect is tested where
it acts. The thresholds of the regime and region tests are Bonferroni-corrected for the number of
tests (channels x subsets), so a null recording stays clean.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

from gprace.diagnose.core import CHANNELS, Dataset
from gprace.diagnose.locate import blocks
from gprace.model import State

T_GLOBAL = 4.5
"""Paired block t of the held-out gain over all windows for a channel to be predictable."""
GAIN_GLOBAL = 0.05
"""... and the share of the error's mean square that the features predict out of sample."""
GAIN_SUBSET = 0.15
"""Share predicted inside a regime or region subset for a concentrated finding."""
FAMILY_ALPHA = 0.01
"""Family-wise false-alarm probability of all subset tests of one recording (Bonferroni)."""
T_SUBSET_MIN = 5.0
"""Floor of the subset threshold (block t-statistics of a few blocks have heavy tails)."""
MIN_BLOCKS = 8
FOLDS = 5
RIDGE = 1e-2
REPEAT_BIN_M = 20.0


@dataclass(frozen=True)
class SubsetTest:
    label: str  # "drive while cornering", "s 200..400 m", ...
    t: float
    gain: float  # held-out share of the subset's error mean square predicted
    share: float  # share of windows in the subset


@dataclass(frozen=True)
class Predictability:
    channel: str
    t: float  # paired block t of the held-out gain, all windows
    gain: float  # held-out share of the error mean square predicted, all windows
    subsets: tuple[SubsetTest, ...]  # subset tests that passed the corrected threshold
    t_subset: float  # threshold used for the subsets (Bonferroni)

    @property
    def strong(self) -> bool:
        return (self.t > T_GLOBAL and self.gain > GAIN_GLOBAL) or bool(self.subsets)


SMOOTH_S = 1.0
"""Length [s] of the trailing moving average of the measured states used as features: it ends
before the window's first sample, so it holds none of the sensor noise of the window's own
measurements (which propagates into the window's error and would otherwise be "predicted")."""


def _smooth(data: Dataset, x: np.ndarray) -> np.ndarray:
    """Trailing moving average of ``x`` over the SMOOTH_S before each sample (per recording; the
    first sample uses itself)."""
    w = max(int(round(SMOOTH_S / data.dt)), 1)
    out = np.empty_like(x)
    for r in np.unique(data.rec):  # a few recordings
        m = np.flatnonzero(data.rec == r)
        c = np.concatenate([[0.0], np.cumsum(x[m])])
        i = np.arange(len(m))
        lo, hi = np.maximum(i - w, 0), np.maximum(i, 1)
        out[m] = (c[hi] - c[lo]) / (hi - lo)
    return out


def features(data: Dataset, starts: np.ndarray, H: int) -> np.ndarray:
    """(m, p) regime features of each window: speed, lateral and longitudinal acceleration and
    their products, steering and its rate, drive/brake rates, curvature demand, yaw rate.
    Commands are used as recorded (no sensor noise); measured states averaged over the second
    before the window (:data:`SMOOTH_S`)."""
    k = starts
    vx = _smooth(data, data.Y[:, State.V_X])[k]
    r = _smooth(data, data.Y[:, State.YAW_RATE])[k]
    ay = vx * r
    d0, a0 = data.U[k, 0], data.A[k]  # a_x as recorded (a command, a measurement, or derived)
    T = H * data.dt
    dd = (data.U[k + H - 1, 0] - d0) / T
    da = (data.A[k + H - 1] - a0) / T
    ap, am = np.maximum(a0, 0.0), np.minimum(a0, 0.0)
    aya = np.abs(ay)
    kv2 = data.kappa[k] * vx * vx
    F = np.column_stack([vx, vx * vx, ay, aya, ay * aya, a0, ap, am, ap * aya, am * aya, d0, dd, dd * vx,
                         da, kv2, r, d0 * vx * vx, ap * ay])
    return F


def regimes(data: Dataset, starts: np.ndarray, H: int) -> list[tuple[str, np.ndarray]]:
    """Operating regimes and tenths of the lap as boolean masks over the windows."""
    k = starts
    vx = data.Y[k, 0]
    aya = np.abs(vx * data.Y[k, 2])
    ax = data.A[k]
    idx = k[:, None] + np.arange(H)[None, :]
    dd = np.abs(np.diff(data.U[idx, 0], axis=1)).max(axis=1)
    out = [
        ("hard cornering (top 10% |a_y|)", aya >= np.quantile(aya, 0.9)),
        ("drive while cornering", (ax > 0.3 * max(np.quantile(ax, 0.95), 1e-6)) & (aya > np.quantile(aya, 0.6))),
        ("braking", ax < min(np.quantile(ax, 0.15), -0.5)),
        ("fast steering (top 10% rate)", dd >= np.quantile(dd, 0.9)),
        ("high speed (top third)", vx >= np.quantile(vx, 2 / 3)),
        ("low speed (bottom third)", vx <= np.quantile(vx, 1 / 3)),
    ]
    L = data.L[data.rec[k]]
    if np.all(np.isfinite(L)) and len(np.unique(data.L)) == 1:
        Lv = float(L[0])
        s = np.mod(data.Y[k, 5], Lv)
        for i in range(10):
            a, b = i * Lv / 10, (i + 1) * Lv / 10
            out.append((f"s {a:.0f}..{b:.0f} m", (s >= a) & (s < b)))
    return out


def _repeat_feature(data: Dataset, starts: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Mean of ``y`` at the same place (20 m bin) in the OTHER laps (0 when no other lap)."""
    L = data.L[data.rec[starts]]
    if not np.all(np.isfinite(L)):
        return np.zeros(len(y))
    s = np.mod(data.Y[starts, 5], L)
    nb = int(np.max(L) // REPEAT_BIN_M) + 1
    b = np.minimum((s // REPEAT_BIN_M).astype(int), nb - 1)
    lap = data.lap[starts]
    _, li = np.unique(lap, return_inverse=True)
    nl = li.max() + 1
    key = li * nb + b
    tot_s = np.bincount(b, y, nb)
    tot_n = np.bincount(b, minlength=nb)
    own_s = np.bincount(key, y, nl * nb)[key]
    own_n = np.bincount(key, minlength=nl * nb)[key]
    n_other = tot_n[b] - own_n
    return np.where(n_other > 0, (tot_s[b] - own_s) / np.maximum(n_other, 1), 0.0)


def _block_t(d: np.ndarray, inv: np.ndarray, nb: int) -> float:
    sums = np.bincount(inv, d, nb)
    cnt = np.bincount(inv, minlength=nb)
    v = sums[cnt > 0] / cnt[cnt > 0]
    if len(v) < 2:
        return 0.0
    se = np.std(v, ddof=1) / np.sqrt(len(v))
    return float(np.mean(v) / se) if se > 0 else 0.0


def heldout_prediction(F: np.ndarray, y: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """Out-of-fold ridge predictions of ``y`` from standardised features ``F`` (with intercept)."""
    mu, sd = F.mean(axis=0), F.std(axis=0)
    Z = np.column_stack([np.ones(len(y)), (F - mu) / np.where(sd > 0, sd, 1.0)])
    pred = np.zeros(len(y))
    reg = RIDGE * len(y) * np.eye(Z.shape[1])
    reg[0, 0] = 0.0
    for f in np.unique(fold):
        tr, te = fold != f, fold == f
        A = Z[tr].T @ Z[tr] + reg * tr.mean()
        w = np.linalg.solve(A, Z[tr].T @ y[tr])
        pred[te] = Z[te] @ w
    return pred


def predictability(data: Dataset, starts: np.ndarray, H: int, E: np.ndarray, scale: np.ndarray,
                   channels: tuple[int, ...], n_family: int | None = None) -> list[Predictability]:
    """Held-out predictability of each channel's mean signed multi-step error (see module doc).

    ``E`` (m, H, 6) data errors, ``scale`` per channel noise-floor RMSE (for normalisation).
    """
    bid = blocks(data, starts)
    _, inv = np.unique(bid, return_inverse=True)
    nb = inv.max() + 1
    fold = inv % FOLDS
    F0 = features(data, starts, H)
    subs = [(lab, m) for lab, m in regimes(data, starts, H) if len(np.unique(inv[m])) >= MIN_BLOCKS]
    n_tests = n_family or max(len(subs) * len(channels), 1)
    t_sub = max(T_SUBSET_MIN, float(norm.isf(FAMILY_ALPHA / n_tests)))
    out = []
    for c in channels:
        y = E[:, :, c].mean(axis=1) / max(float(scale[c]), 1e-12)
        F = np.column_stack([F0, _repeat_feature(data, starts, y)])
        pred = heldout_prediction(F, y, fold)
        d = y * y - (y - pred) ** 2  # held-out squared-error reduction per window (relevance)
        sc = y * pred  # held-out score: mean 0 when the error is not predictable (significance)
        t = _block_t(sc, inv, nb)
        gain = float(d.sum() / max(np.sum(y * y), 1e-300))
        passed = []
        for lab, m in subs:
            ts = _block_t(sc[m], inv[m], nb)
            gs = float(d[m].sum() / max(np.sum(y[m] ** 2), 1e-300))
            if ts > t_sub and gs > GAIN_SUBSET:
                passed.append(SubsetTest(lab, round(ts, 2), round(gs, 3), round(float(m.mean()), 3)))
        out.append(Predictability(CHANNELS[c], round(t, 2), round(gain, 4), tuple(passed), round(t_sub, 2)))
    return out
