"""Locate: which channels carry structured error, where along the track, in which regime.

The statistic of a channel compares the multi-step prediction error of the model on the data
with the same error on its noise twin (the model with the estimated sensor noise, cut into the
same windows). Per window ``k`` the mean squared error over the horizon is ``m(k)``; windows are
grouped into blocks of about two seconds and the paired block differences
``d_b = mean(m_data) - mean(m_twin)`` give a t-like statistic ``z = mean(d) / se(d)``.
A channel is *structured* when ``z`` exceeds :data:`Z_STRUCTURED` and the data's error exceeds the
twin's by the factor :data:`RATIO_STRUCTURED` (statistically significant and practically
relevant: a few percent of excess over pure noise is not a finding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprace.diagnose.core import CHANNELS, TESTED, Dataset

Z_STRUCTURED = 4.0
RATIO_STRUCTURED = 1.3
BLOCK_SECONDS = 2.0
BIN_METRES = 10.0


@dataclass
class ChannelStat:
    name: str
    structured: bool
    statistic: float
    ratio: float
    rmse: float  # multi-step RMSE of the model on the data (all horizon steps)
    rmse_twin: float  # the same on the noise twin (noise floor)
    structured_rms: float  # sqrt(max(mse - mse_twin, 0))


def blocks(data: Dataset, starts: np.ndarray, seconds: float = BLOCK_SECONDS) -> np.ndarray:
    """Block id of each window: contiguous ~``seconds`` stretches inside one recording."""
    B = max(int(round(seconds / data.dt)), 1)
    first = np.array([np.flatnonzero(data.rec == r)[0] for r in range(len(data.L))])
    rec = data.rec[starts]
    return rec * 10**7 + (starts - first[rec]) // B


def window_mse(E: np.ndarray) -> np.ndarray:
    """(m, 6) mean squared error over the horizon; twin errors (R, m, H, 6) averaged over R."""
    if E.ndim == 4:
        return np.mean(E**2, axis=(0, 2))
    return np.mean(E**2, axis=1)


def channel_stats(data: Dataset, starts: np.ndarray, Ed: np.ndarray, Et: np.ndarray,
                  channels=TESTED) -> list[ChannelStat]:
    md, mt = window_mse(Ed), window_mse(Et)
    bid = blocks(data, starts)
    _, inv = np.unique(bid, return_inverse=True)
    nb = inv.max() + 1
    cnt = np.bincount(inv, minlength=nb)
    out = []
    for c in channels:
        d = (np.bincount(inv, md[:, c], nb) - np.bincount(inv, mt[:, c], nb)) / cnt
        se = np.std(d, ddof=1) / np.sqrt(nb) if nb > 1 else np.inf
        z = float(np.mean(d) / se) if se > 0 else 0.0
        mse_d, mse_t = float(md[:, c].mean()), float(mt[:, c].mean())
        ratio = mse_d / mse_t if mse_t > 0 else np.inf
        out.append(ChannelStat(
            name=CHANNELS[c], structured=bool(z > Z_STRUCTURED and ratio > RATIO_STRUCTURED),
            statistic=z, ratio=ratio, rmse=float(np.sqrt(mse_d)), rmse_twin=float(np.sqrt(mse_t)),
            structured_rms=float(np.sqrt(max(mse_d - mse_t, 0.0))),
        ))
    return out


# --------------------------------------------------------------------------------------------
# where and when


@dataclass
class Region:
    channel: str
    s_start: float
    s_end: float
    excess: float  # mean excess MSE inside (data - twin), channel units squared
    laps_seen: int
    laps_total: int
    description: str
    z: float = 0.0  # significance of the region's excess


def _mid_s(data: Dataset, starts: np.ndarray, H: int) -> np.ndarray:
    """Track position of each window's middle (wrapped into the lap)."""
    su = data.s_unwrapped()
    mid = 0.5 * (su[starts] + su[starts + H])
    L = data.L[data.rec[starts]]
    return np.where(np.isfinite(L), np.mod(mid, np.where(np.isfinite(L), L, 1.0)), mid)


def track_profile(data: Dataset, starts: np.ndarray, H: int, E: np.ndarray, c: int,
                  bin_m: float = BIN_METRES) -> tuple[np.ndarray, np.ndarray]:
    """Signed mean error of channel ``c`` along the track: (bin centres, mean error per bin)."""
    s = _mid_s(data, starts, H)
    e = E[:, :, c].mean(axis=1) if E.ndim == 3 else E[:, :, :, c].mean(axis=(0, 2))
    edges = np.arange(0.0, np.nanmax(s) + bin_m, bin_m)
    b = np.clip(np.digitize(s, edges) - 1, 0, len(edges) - 1)
    nb = len(edges)
    cnt = np.bincount(b, minlength=nb)
    mean = np.bincount(b, e, nb) / np.maximum(cnt, 1)
    mean[cnt == 0] = np.nan
    return edges + 0.5 * bin_m, mean


def _bin_z(s, e, lap, edges, H):
    """Per-bin signed mean error, its z-score and per-lap means (windows overlap ~H-fold)."""
    nb = len(edges)
    b = np.clip(np.digitize(s, edges) - 1, 0, nb - 1)
    cnt = np.bincount(b, minlength=nb)
    mean = np.bincount(b, e, nb) / np.maximum(cnt, 1)
    sq = np.bincount(b, e * e, nb) / np.maximum(cnt, 1)
    sd = np.sqrt(np.maximum(sq - mean**2, 0.0))
    return b, cnt, mean, sd


def find_regions(data: Dataset, starts: np.ndarray, H: int, Ed: np.ndarray, Et: np.ndarray, c: int,
                 bin_m: float = BIN_METRES, max_regions: int = 5) -> list[Region]:
    """Stretches of track where channel ``c`` has a signed error bias that the noise twin does
    not show, repeated lap after lap.

    Per ``bin_m`` bin of track position (window middle) the mean signed error over the horizon
    is compared with its spread in the noise twin: ``z = mean / (sd_twin / sqrt(n_eff))`` with
    ``n_eff = count / H`` (overlapping windows). The threshold is calibrated on the twin itself:
    ``max(4, 1.25 * max_bins |z_twin|)``, so a long track with many bins does not raise false
    alarms. Hot bins (gaps of up to three bins bridged) merge into regions; a region counts the laps in
    which its bias has the same sign and at least half the size.
    """
    s = _mid_s(data, starts, H)
    ed = Ed[:, :, c].mean(axis=1)
    et = Et[0, :, :, c].mean(axis=1)
    md, mt = window_mse(Ed)[:, c], window_mse(Et)[:, c]
    lap = data.lap[starts]
    edges = np.arange(0.0, np.nanmax(s) + bin_m, bin_m)
    nb = len(edges)
    b, cnt, mean_d, _ = _bin_z(s, ed, lap, edges, H)
    _, _, mean_t, sd_t = _bin_z(s, et, lap, edges, H)
    sd_ref = np.where(sd_t > 0, sd_t, np.nanmedian(sd_t[cnt > 1]) if np.any(cnt > 1) else 1.0)
    neff = np.maximum(cnt / H, 1.0)
    z = mean_d / (sd_ref / np.sqrt(neff))
    zt = mean_t / (sd_ref / np.sqrt(neff))
    ok = cnt >= 3
    thr = max(4.0, 1.25 * float(np.max(np.abs(zt[ok])))) if ok.any() else 4.0
    hot = ok & (np.abs(z) > thr)
    laps = np.unique(lap)
    seen = np.zeros(nb, dtype=int)
    for lp in laps:  # few laps: a loop over laps, not samples
        m = lap == lp
        cl = np.bincount(b[m], minlength=nb)
        el = np.bincount(b[m], ed[m], nb) / np.maximum(cl, 1)
        seen += (cl > 0) & (np.sign(el) == np.sign(mean_d)) & (np.abs(el) > 0.5 * np.abs(mean_d))
    idx = np.flatnonzero(hot)
    regions: list[Region] = []
    if len(idx) == 0:
        return regions
    groups = np.split(idx, np.flatnonzero(np.diff(idx) > 4) + 1)
    for g in groups:
        lo, hi = int(g[0]), int(g[-1])
        sel = slice(lo, hi + 1)
        in_r = (b >= lo) & (b <= hi)
        exc = float(np.mean(md[in_r] - mt[in_r]))
        regions.append(Region(
            channel=CHANNELS[c], s_start=float(edges[lo]), s_end=float(edges[hi] + bin_m), excess=exc,
            laps_seen=int(np.median(seen[sel][hot[sel]])), laps_total=len(laps),
            description=_regime_text(data, starts[in_r], H), z=float(np.max(np.abs(z[sel]))),
        ))
    regions.sort(key=lambda r: -abs(r.excess) * (r.s_end - r.s_start))
    return regions[:max_regions]


def _regime_text(data: Dataset, starts: np.ndarray, H: int) -> str:
    if len(starts) == 0:
        return ""
    idx = (starts[:, None] + np.arange(H + 1)[None, :]).ravel()
    vx = data.Y[idx, 0]
    ay = np.abs(vx * data.Y[idx, 2])
    ax = data.A[idx]
    brake = float(np.mean(ax < -1.0))
    kind = "braking" if brake > 0.5 else ("accelerating" if np.mean(ax > 1.0) > 0.5 else "steady speed")
    corner = "cornering" if np.median(ay) > 3.0 else "straight"
    return (f"{corner}, {kind}: v_x {np.median(vx):.1f} m/s, |a_y| {np.median(ay):.1f} m/s^2, "
            f"braking {100 * brake:.0f}% of the time")


def regime(data: Dataset, starts: np.ndarray, H: int, Ed: np.ndarray, Et: np.ndarray, c: int) -> str:
    """In which operating regime channel ``c``'s excess error concentrates (speed, |a_y|, braking)."""
    md, mt = window_mse(Ed)[:, c], window_mse(Et)[:, c]
    ex = md - mt
    vx = data.Y[starts, 0]
    ay = np.abs(vx * data.Y[starts, 2])
    ax = data.A[starts]
    parts = []
    for label, x in (("speed", vx), ("lateral acceleration", ay)):
        lo, hi = np.quantile(x, [1 / 3, 2 / 3])
        a, b = ex[x <= lo].mean(), ex[x >= hi].mean()
        if max(a, b) > 0:
            r = (b + 1e-12) / (abs(a) + 1e-12)
            if r > 2:
                parts.append(f"grows with {label} (x{min(r, 99):.1f} top vs bottom third)")
            elif r < 0.5:
                parts.append(f"falls with {label}")
    br = ax < -1.0
    if br.any() and (~br).any():
        a, b = ex[~br].mean(), ex[br].mean()
        if b > 2 * max(a, 0) and b > 0:
            parts.append("concentrated under braking")
    return "; ".join(parts) if parts else "spread over all regimes"
