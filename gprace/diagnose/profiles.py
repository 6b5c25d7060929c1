"""Profiles along the lap: bank, grade and friction as penalised splines in lap position.

A profile effect (``road_bank_profile``, ``road_grade_profile``, ``friction_profile`` in
:mod:`gprace.model.effects`) is linear between knots spaced ``h`` apart around the lap, i.e. a
degree-1 B-spline whose coefficients are its values at the knots (what the catalogue class
stores, so the fitted profile and the evaluated one are the same function). It is fitted to the
same normalised multi-step errors as every other candidate, with a roughness penalty on the
periodic second differences of the coefficients (a P-spline):

    min_c  |r(c)|^2 + lambda |D c|^2        (road_grade_profile: mean grade 0, a closed lap)

by Gauss-Newton. The Jacobian costs ``G + 1`` model evaluations, not one per knot: knots ``j``
and ``j + G`` are further apart than any window's path, so the knots of one colour group
``j mod G`` are perturbed together and each window's response is credited to the one knot of the
group its path touches. The smoothing ``lambda`` is chosen by cross-validation over the folds of
the naming stage (by lap with three or more laps), on the linearised problem. Pointwise 95 %
intervals come from a cluster-robust (2-s blocks) sandwich plus the penalty's bias term (the
Bayesian covariance of a penalised spline, scaled by the same design effect).

The naming stage treats a profile as one more candidate; :func:`leading` counts a profile and
its window (``road_bank`` for ``road_bank_profile``) as one slot, and :func:`window_or_profile`
keeps the window unless the profile predicts held-out windows significantly better (parsimony).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from gprace.diagnose.core import DYNAMIC, Dataset, errors, lag_states, predict
from gprace.diagnose.locate import blocks
from gprace.model import EFFECTS

EPS = 1e-3
"""Finite-difference step on a knot value (rad or friction factor): the effects are close to linear
in it, and a 1 mrad bank moves a 15-step v_y prediction far above rounding."""
LAMBDA_GRID = 10.0 ** np.linspace(-4.0, 4.0, 17)
"""Smoothing candidates relative to the data term's scale (mean diagonal of J'J over that of D'D)."""
KNOTS_MAX = 200
"""At most this many knots per lap (a 5 km lap: 25 m apart)."""
MIN_LAP_COVER = 1.2
"""Recorded distance needed, in laps: a profile fitted to one passage explains nothing held out."""
MIN_LAPS_SEEN = 1
"""A knot is fitted only where the fit's windows pass it in at least this many laps; elsewhere the
profile is held at its neutral value (no interval). 2 was tried (what one passage shows at a place
is no property of the road: the IAC fold trained on 1.45 laps fitted a grade along the part seen
once and the held-out lap's v_x got twice worse; with 2 it did not) and not kept: on a 1.6-lap
recording a friction profile restricted to the part seen twice followed an effect outside the
catalogue that repeats there and was named beside combined_slip (docs/decisions.md, diag3)."""


@dataclass(frozen=True)
class Basis:
    """Knots ``j h`` (``j = 0..K-1``) around a lap of length ``L``; ``G`` colour groups."""

    L: float
    K: int
    G: int

    @property
    def h(self) -> float:
        return self.L / self.K

    @property
    def knots(self) -> np.ndarray:
        return np.arange(self.K) * self.h

    def locate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Left knot index and the weight of the right one at positions ``s`` (wrapped)."""
        u = np.mod(s, self.L) / self.h
        i = np.floor(u)
        return i.astype(int) % self.K, u - i

    def penalty(self) -> np.ndarray:
        """``D'D`` of the periodic second differences (K, K)."""
        K = self.K
        D = np.zeros((K, K))
        j = np.arange(K)
        D[j, (j - 1) % K] += 1.0
        D[j, j] -= 2.0
        D[j, (j + 1) % K] += 1.0
        return D.T @ D


@dataclass
class ProfileFit:
    """What a profile fit carries besides its knot values (stored on :class:`~gprace.diagnose.name.Fit`)."""

    basis: Basis
    neutral: float  # the value meaning "no effect" (0 rad, friction factor 1)
    lam: float = np.nan  # smoothing actually used (absolute)
    free: np.ndarray | None = None  # (K,) knots fitted (seen in MIN_LAPS_SEEN laps); the others neutral
    edf: float = np.nan  # effective degrees of freedom
    lower: np.ndarray | None = None  # pointwise 95 % interval of the values at the knots
    upper: np.ndarray | None = None


def is_profile(name: str) -> bool:
    return bool(getattr(EFFECTS[name], "profile", False))


def neutral(name: str) -> float:
    return 1.0 if EFFECTS[name].params["values"].unit == "-" else 0.0


def lap_length(data: Dataset) -> float | None:
    """The common lap length of the recordings, or None (no laps, or laps of different length)."""
    L = data.L
    if not np.all(np.isfinite(L)) or np.ptp(L) > 0.01 * np.min(L):
        return None
    covered = np.ptp(data.s_unwrapped()) if len(L) == 1 else sum(
        np.ptp(data.s_unwrapped()[data.rec == r]) for r in range(len(L)))
    if covered < MIN_LAP_COVER * float(np.median(L)):
        return None
    return float(np.median(L))


def make_basis(data: Dataset, H: int) -> Basis | None:
    """Knot spacing from the windows' path length (about a quarter of it, at most
    :data:`KNOTS_MAX` knots a lap); colour groups so that no window's path touches two knots of
    one group; ``K`` a multiple of ``G`` so the groups also hold across the start line. From all
    windows of the recordings, so every fit on a subset of them shares the knots."""
    L = lap_length(data)
    if L is None:
        return None
    P = _path_length(data, data.windows(H), H)
    h0 = max(L / KNOTS_MAX, min(P / 4.0, L / 24.0))
    K = max(int(round(L / h0)), 8)
    for _ in range(4):
        h = L / K
        G = int(np.ceil((P + 2.0 * h) / h)) + 2
        K_new = G * max(int(round(L / (h0 * G))), 2)
        if K_new == K:
            break
        K = K_new
    G = int(np.ceil((P + 2.0 * L / K) / (L / K))) + 2
    K = G * max(K // G, 2)
    return Basis(L, K, min(G, K))


def _path_length(data: Dataset, starts: np.ndarray, H: int) -> float:
    su = data.s_unwrapped()
    d = np.abs(su[starts + H] - su[starts])
    return float(np.quantile(d, 0.999)) + 1.0


# --------------------------------------------------------------------------------------------
# the model with a batch of profiles (one per window set)


@cache
def _batched_class(name: str):
    """The catalogue class with its knot values given per window set: ``values`` (k, K) and the set
    of each column of the batch. Same hooks, same interpolation (:meth:`ProfileEffect.value`)."""
    base = EFFECTS[name]

    class Batched(base):  # not registered in the catalogue: a fitting device
        def value(self, c):
            i, w = self._basis.locate(c.s)
            V, sid = self._V, self._sid
            return V[sid, i] * (1.0 - w) + V[sid, (i + 1) % self._basis.K] * w

        def table(self):  # for the compiled predictions (gprace.diagnose.fastpredict)
            return self._basis.knots, self._basis.L, np.atleast_2d(self._V), np.asarray(self._sid)

    Batched.__name__ = f"Batched{base.__name__}"
    return Batched


def batched_effect(name: str, basis: Basis, V: np.ndarray, set_index: np.ndarray):
    cls = _batched_class(name)
    e = cls(knots=basis.knots.tolist(), values=[neutral(name)] * basis.K, lap_length=basis.L)
    e._basis, e._V, e._sid = basis, np.atleast_2d(V), set_index
    return e


def residual_batch(prob, name: str, basis: Basis, V: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(k, m, H, 3) normalised errors with the profile of knot values ``V[i]`` (k, K), one batch."""
    V = np.atleast_2d(V)
    k, m = len(V), len(starts)
    eff = batched_effect(name, basis, V, np.repeat(np.arange(k), m))
    model = prob.model([eff])
    S = np.tile(starts, k)
    Z0 = np.tile(lag_states(model, prob.data)[starts], (k, 1)) if model.nx > 6 else None
    E = errors(prob.data, S, predict(model, prob.data, S, prob.H, prob._substeps(model), Z0=Z0))
    R = (E[..., list(DYNAMIC)] / prob.scale).reshape(k, m, prob.H, 3)
    return np.where(np.isfinite(R), R, 0.0)


# --------------------------------------------------------------------------------------------
# Jacobian by colour groups


def _touched(data: Dataset, starts: np.ndarray, H: int, basis: Basis) -> tuple[np.ndarray, np.ndarray]:
    """For every window and colour group: the knot (mod K) of that group its path can touch, and
    whether it touches one at all. ``(m, G)`` arrays."""
    su = data.s_unwrapped()
    a = np.minimum(su[starts], su[starts + H])
    b = np.maximum(su[starts], su[starts + H])
    h = basis.h
    margin = 0.5 * h
    jlo = np.floor((a - margin) / h).astype(int)
    jhi = np.ceil((b + margin) / h).astype(int)
    o = np.arange(basis.G)[None, :]
    # knot of group g at or above jlo: jlo + ((g - jlo) mod G)
    j = jlo[:, None] + np.mod(o - jlo[:, None], basis.G)
    ok = j <= jhi[:, None]
    return np.mod(j, basis.K), ok


def laps_seen(data: Dataset, starts: np.ndarray, H: int, basis: Basis) -> np.ndarray:
    """(K,) in how many different laps the windows ``starts`` pass each knot (its support: within
    one knot spacing of the window's path)."""
    su = data.s_unwrapped()
    a = np.minimum(su[starts], su[starts + H])
    b = np.maximum(su[starts], su[starts + H])
    h = basis.h
    jlo = np.floor(a / h - 1.0).astype(np.int64)
    jhi = np.ceil(b / h + 1.0).astype(np.int64)
    o = np.arange(int((jhi - jlo).max()) + 1)
    j = jlo[:, None] + o[None, :]
    ok = j <= jhi[:, None]
    rec = np.broadcast_to(data.rec[starts][:, None], j.shape)
    key = np.stack([np.mod(j, basis.K)[ok], rec[ok], np.floor_divide(j, basis.K)[ok]], axis=1)
    knot = np.unique(key, axis=0)[:, 0]
    return np.bincount(knot, minlength=basis.K)


def jacobian(prob, name: str, basis: Basis, v0: np.ndarray, starts: np.ndarray):
    """Residuals at ``v0`` (m*H*3,) and their sparse Jacobian in the knot values (m*H*3, K)."""
    from scipy import sparse

    G, K = basis.G, basis.K
    groups = np.arange(K) % G
    V = np.vstack([v0] + [v0 + EPS * (groups == g) for g in range(G)])
    R = residual_batch(prob, name, basis, V, starts)  # (G+1, m, H, 3)
    m, n = len(starts), prob.H * 3
    r0 = R[0].reshape(m, n)
    dR = (R[1:].reshape(G, m, n) - r0[None]) / EPS  # (G, m, n)
    col, ok = _touched(prob.data, starts, prob.H, basis)  # (m, G)
    rows = (np.arange(m)[:, None, None] * n + np.arange(n)[None, None, :])  # (m, 1, n)
    rows = np.broadcast_to(rows, (m, G, n))
    cols = np.broadcast_to(col[:, :, None], (m, G, n))
    vals = np.transpose(dR, (1, 0, 2))  # (m, G, n)
    keep = np.broadcast_to(ok[:, :, None], (m, G, n))
    J = sparse.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(m * n, K))
    return r0.ravel(), J


# --------------------------------------------------------------------------------------------
# penalised Gauss-Newton, smoothing by cross-validation


def _constraint(name: str, K: int, free: np.ndarray | None = None) -> np.ndarray | None:
    """Basis of the allowed coefficient space, or None when every profile is allowed: only the
    ``free`` knots move (:data:`MIN_LAPS_SEEN`), and a closed lap climbs as much as it falls
    (mean grade 0); bank and friction are otherwise free."""
    E = None if free is None or free.all() else np.eye(K)[:, free]
    if name != "road_grade_profile":
        return E
    F = K if E is None else E.shape[1]
    if F < 2:
        return np.zeros((K, 0))
    q, _ = np.linalg.qr(np.column_stack([np.ones(F), np.eye(F)[:, : F - 1]]))
    return q[:, 1:] if E is None else E @ q[:, 1:]


def _in(Z, M):
    """``Z' M Z`` (a matrix) or ``Z' M`` (a vector) in the allowed space; M itself without a constraint."""
    if Z is None:
        return M
    return Z.T @ M @ Z if M.ndim == 2 else Z.T @ M


def _out(Z, a):
    return a if Z is None else Z @ a


def _dense(M) -> np.ndarray:
    return M.toarray() if hasattr(M, "toarray") else np.asarray(M)


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    try:
        return cho_solve(cho_factor(A), b)
    except (LinAlgError, ValueError):
        return np.linalg.lstsq(A, b, rcond=None)[0]


def _cv_lambda(J, r, fold: np.ndarray, n: int, Z, P: np.ndarray, c0: np.ndarray, scale: float) -> float:
    """Smoothing (absolute) with the lowest held-out loss of the problem linearised at ``c0``:
    per fold, the penalised step fitted on the other folds' rows predicts the held-out rows."""
    rows_fold = np.repeat(fold, n)
    parts = []
    for f in np.unique(fold):
        te = rows_fold == f
        Jtr, rtr = J[~te], r[~te]
        A = _dense(Jtr.T @ Jtr)
        parts.append((_in(Z, A), _in(Z, A @ c0 - Jtr.T @ rtr), J[te], r[te]))
    Pz = _in(Z, P)
    best, best_loss = float(LAMBDA_GRID[len(LAMBDA_GRID) // 2] * scale), np.inf
    for lam in LAMBDA_GRID * scale:
        loss = 0.0
        for Az, bz, Jte, rte in parts:
            d = _out(Z, _solve(Az + lam * Pz, bz)) - c0
            e = rte + Jte @ d
            loss += float(e @ e)
        if loss < best_loss:
            best, best_loss = float(lam), loss
    return best


def fit_profile(prob, name: str, starts: np.ndarray, v_init: np.ndarray | None = None,
                iterations: int = 2, lam: float | None = None, basis: Basis | None = None,
                free: np.ndarray | None = None, first: tuple[np.ndarray, Any] | None = None):
    """Penalised Gauss-Newton fit of a profile effect; returns a :class:`~gprace.diagnose.name.Fit`
    (or None when the recordings have no laps to fit a profile over). ``lam`` None: the smoothing
    is chosen by cross-validation (:func:`_cv_lambda`) at the first iteration. ``free`` None: the
    knots fitted are those the recordings' windows pass in :data:`MIN_LAPS_SEEN` laps (:func:`laps_seen`); a
    refit on a training fold keeps the knots of the fit on all the recordings (cross-validation
    asks whether what one lap shows at a place predicts another lap there). ``first``: the residuals
    and Jacobian at ``v_init`` on ``starts``, when the caller has them (:func:`fold_refits`)."""
    from gprace.diagnose import name as nm

    basis = basis or make_basis(prob.data, prob.H)
    if basis is None or len(starts) < 20:
        return None
    K = basis.K
    base = neutral(name)
    if free is None and MIN_LAPS_SEEN <= 1:  # every knot: one no window passes follows its
        free = np.ones(K, dtype=bool)  # neighbours through the penalty (not the neutral value)
    elif free is None:  # from every window of the recordings: a subsample (the screening's) has gaps
        free = laps_seen(prob.data, prob.data.windows(prob.H), prob.H, basis) >= MIN_LAPS_SEEN
    if not free.any():
        return None
    Z = _constraint(name, K, free)
    if Z is not None and Z.shape[1] == 0:
        return None
    c = np.zeros(K)
    if v_init is not None:  # on these knots (a profile given on others is interpolated)
        v_init = np.asarray(v_init, float)
        k0 = np.arange(len(v_init)) * (basis.L / len(v_init))
        c = np.interp(basis.knots, k0, v_init, period=basis.L) - base
    c = _out(Z, _in(Z, c)) if Z is not None else c
    P = basis.penalty()
    lo, hi = (v - base for v in nm.physical_bounds(name, "values", prob.vehicle, prob.data))
    lo, hi = lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo)  # base + c stays inside despite rounding
    n = prob.H * 3
    best = None  # (penalised objective, c) of the best point evaluated
    for it in range(max(1, iterations)):
        r, J = first if (it == 0 and first is not None) else jacobian(prob, name, basis, base + c, starts)
        if lam is None:
            JtJ0 = _dense(J.T @ J)
            scale = max(float(np.mean(np.diag(JtJ0))), 1e-12) / max(float(np.mean(np.diag(P))), 1e-12)
            lam = _cv_lambda(J, r, nm.folds(prob.data, starts), n, Z, P, c, scale)
        obj = float(r @ r) + lam * float(c @ P @ c)
        if best is not None and obj > best[0]:  # the step overshot: halve it from the best point
            c = 0.5 * (c + best[1])
            continue
        best = (obj, c)
        JtJ = _dense(J.T @ J)
        a = _solve(_in(Z, JtJ) + lam * _in(Z, P), _in(Z, JtJ @ c - J.T @ r))
        c = np.clip(_out(Z, a), lo, hi)
    R = residual_batch(prob, name, basis, base + c, starts)[0]
    if best is not None and float(np.sum(R**2)) + lam * float(c @ P @ c) > best[0]:  # the last step made it worse
        c = best[1]
        R = residual_batch(prob, name, basis, base + c, starts)[0]
    cost = float(np.mean(R**2))
    fit = nm.Fit(name, [f"v{j}" for j in range(K)], c.copy(), {}, cost)
    fit.profile = ProfileFit(basis, base, lam=float(lam), free=free)
    fit.win = starts
    return fit


def refit(prob, fit, starts: np.ndarray, iterations: int = 1, keep_smoothing: bool = True):
    """The fit again on other windows (a training fold: smoothing and fitted knots kept), warm-started."""
    pf = fit.profile
    return fit_profile(prob, fit.name, starts, pf.neutral + fit.x, iterations=iterations,
                       lam=pf.lam if keep_smoothing else None, basis=pf.basis, free=pf.free) or fit


def fold_refits(prob, fit, trains: list[np.ndarray]) -> list:
    """:func:`refit` (one iteration, smoothing and knots kept) on each training set of windows,
    the Jacobian at the fit evaluated once on their union and cut per set: a window's rows do not
    depend on the other windows of the batch, so each refit is the one on its own windows, for
    one Jacobian instead of one per fold."""
    pf = fit.profile
    union = np.unique(np.concatenate(trains))
    r, J = jacobian(prob, fit.name, pf.basis, pf.neutral + fit.x, union)
    n = prob.H * 3
    out = []
    for tr in trains:
        rows = (np.searchsorted(union, tr)[:, None] * n + np.arange(n)[None, :]).ravel()
        out.append(fit_profile(prob, fit.name, tr, pf.neutral + fit.x, iterations=1, lam=pf.lam, basis=pf.basis,
                               free=pf.free, first=(r[rows], J[rows])) or fit)
    return out


def interval(prob, fit, starts: np.ndarray) -> None:
    """Pointwise 95 % interval of the values at the knots and the effective degrees of freedom
    (stored on ``fit.profile``): cluster-robust sandwich over 2-s blocks of windows plus the
    penalty's bias term (the Bayesian covariance's ``sigma^2 A^-1 lambda P A^-1``), scaled by the
    same design effect, both at the fit's smoothing."""
    from scipy import sparse

    pf = fit.profile
    basis, K = pf.basis, pf.basis.K
    r, J = jacobian(prob, fit.name, basis, pf.neutral + fit.x, starts)
    Z = _constraint(fit.name, K, pf.free)
    Jz = J if Z is None else J @ Z
    A_data = _dense(Jz.T @ Jz)
    Pz = _in(Z, basis.penalty())
    Ai = np.linalg.pinv(A_data + pf.lam * Pz)
    n = prob.H * 3
    _, blk = np.unique(np.repeat(blocks(prob.data, starts), n), return_inverse=True)
    B = sparse.csr_matrix((np.ones(len(blk)), (blk, np.arange(len(blk)))), shape=(blk.max() + 1, len(blk)))
    scores = _dense(B @ (Jz.multiply(r[:, None]) if sparse.issparse(Jz) else Jz * r[:, None]))
    V_data = Ai @ (scores.T @ scores) @ Ai
    edf = float(np.trace(Ai @ A_data))
    sigma2 = float(r @ r) / max(len(r) - edf, 1.0)
    iid = sigma2 * (Ai @ A_data @ Ai)
    deff = max(float(np.trace(V_data)) / max(float(np.trace(iid)), 1e-300), 1.0)
    V = V_data + deff * sigma2 * pf.lam * (Ai @ Pz @ Ai)
    if Z is not None:
        V = Z @ V @ Z.T
    sd = np.sqrt(np.maximum(np.diag(V), 0.0))
    if pf.free is not None:  # a knot held at neutral (seen in too few laps) has no interval
        sd = np.where(pf.free, sd, np.nan)
    v = pf.neutral + fit.x
    pf.lower, pf.upper, pf.edf = v - 1.96 * sd, v + 1.96 * sd, edf


# --------------------------------------------------------------------------------------------
# selection helpers for the naming stage


def family(name: str) -> str:
    """The window effect a profile belongs with (the name itself for every other effect)."""
    return getattr(EFFECTS[name], "window_of", None) or name


def leading(fits: list, k: int) -> list:
    """The first fits (sorted by cost) filling ``k`` slots, a window and its profile in one slot."""
    out, seen = [], []
    for f in fits:
        fam = family(f.name)
        if fam not in seen:
            if len(seen) >= k:
                continue
            seen.append(fam)
        out.append(f)
    return out


def worth_cross_validating(top: list) -> list:
    """``top`` without the profiles that cannot pass :func:`window_or_profile`: a profile fitted
    beside its window is cross-validated only when, in sample on the same windows, it gains more
    over the window than the parsimony margin (a tenth of the window's excess over the noise
    floor). Held out, a profile gains less over its window than in sample (its optimism, growing
    with its effective degrees of freedom, exceeds the window's), and the window's excess is
    larger: what fails the margin in sample fails it held out."""
    from gprace.diagnose import name as nm

    by = {f.name: f for f in top}
    out = []
    for f in top:
        w = by.get(getattr(EFFECTS[f.name], "window_of", None)) if is_profile(f.name) else None
        if w is not None and w.cost - f.cost <= nm.MIN_EXCESS_SHARE * max(w.cost - 1.0, 1e-12):
            continue
        out.append(f)
    return out


def window_or_profile(top: list, cv: dict[str, np.ndarray], bid: np.ndarray) -> list:
    """Parsimony between a window and its profile, both cross-validated: the profile stays only
    when its held-out gain over the window passes the naming stage's test (paired block t or
    signed-rank z above 3, or above 2 when it removes at least half of the window's remaining
    excess) and is more than a tenth of that excess; otherwise the window stays."""
    from gprace.diagnose import name as nm

    names = {f.name for f in top}
    drop = set()
    for f in top:
        w = getattr(EFFECTS[f.name], "window_of", None)
        if not is_profile(f.name) or w not in names:
            continue
        lw, lp = cv[w].mean(axis=1), cv[f.name].mean(axis=1)
        t = max(nm.gain_test(lw, lp, bid)[1], nm.rank_test(lw, lp, bid))
        gain, excess = float(lw.mean() - lp.mean()), max(float(lw.mean()) - 1.0, 1e-12)
        sig = t > nm.T_GAIN or (t > nm.T_GAIN_STRONG and gain > 0.5 * excess)
        drop.add(w if (sig and gain > nm.MIN_EXCESS_SHARE * excess) else f.name)
    return [f for f in top if f.name not in drop]


def to_json(fit, unit: str) -> dict[str, Any]:
    """The profile of a named effect for the ``--json`` output."""
    pf = fit.profile
    v = pf.neutral + fit.x

    def r(a):
        return [float(f"{x:.5g}") for x in a]

    nan = np.full(len(v), np.nan)
    return {"s": [round(float(x), 2) for x in pf.basis.knots], "value": r(v),
            "ci95_low": r(pf.lower if pf.lower is not None else nan),
            "ci95_high": r(pf.upper if pf.upper is not None else nan),
            "unit": unit, "lap_length": round(pf.basis.L, 3), "smoothing": float(f"{pf.lam:.4g}"),
            "edf": round(float(pf.edf), 2) if np.isfinite(pf.edf) else None}


# --------------------------------------------------------------------------------------------
# a road profile or a mismatch that repeats with the driven line (issue 36, stop 48)

ADDITIVE = {"road_bank_profile": (1,), "road_grade_profile": (0,)}
"""The profiles that add a force whatever the car's state (g sin(angle(s))), with the dynamic
channels they act on."""
SCALING = {"friction_profile": (1, 2)}
"""The profiles that scale the tyre forces: their error follows the state at a place by nature
(grip matters near the limit), so what they must show is a place the state alone does not explain."""
LINE_RIDGE = 1e-3
"""Ridge of the linear place and state regressions, relative to the mean diagonal of X'X."""


def state_features(data: Dataset, starts: np.ndarray, H: int) -> np.ndarray:
    """(m, q) what a model mismatch scales with, over each window: means over its samples of the
    lateral acceleration v_x r, v_x^2, the recorded a_x, the steering, v_y and the yaw rate,
    standardised, with their squares and pairwise products (a smooth function of the state to
    second order) and a constant."""
    from gprace.model import Input, State

    idx = starts[:, None] + np.arange(H + 1)[None, :]
    Y, U = data.Y[idx], data.U[idx]
    vx, vy, r = Y[..., State.V_X], Y[..., State.V_Y], Y[..., State.YAW_RATE]
    base = np.stack([(vx * r).mean(1), (vx * vx).mean(1), data.A[idx].mean(1), U[..., Input.DELTA].mean(1),
                     vy.mean(1), r.mean(1)], axis=1)
    z = (base - base.mean(0)) / np.maximum(base.std(0), 1e-12)
    i, j = np.triu_indices(z.shape[1])
    return np.column_stack([np.ones(len(starts)), z, z[:, i] * z[:, j]])


def place_features(basis: Basis, data: Dataset, starts: np.ndarray) -> np.ndarray:
    """(m, K) the degree-1 B-spline of the window's start in lap position (the profile's knots)."""
    from gprace.model import State

    i, w = basis.locate(data.Y[starts, State.S])
    X = np.zeros((len(starts), basis.K))
    X[np.arange(len(starts)), i] = 1.0 - w
    X[np.arange(len(starts)), (i + 1) % basis.K] += w
    return X


def _heldout_linear(X: np.ndarray, R: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """(m,) per-window held-out mean square of ``R`` (m, H) after the ridge regression on ``X``
    fitted without the window's fold."""
    out = np.empty(len(R))
    for f in np.unique(fold):
        te = fold == f
        A = X[~te].T @ X[~te]
        lam = LINE_RIDGE * max(float(np.mean(np.diag(A))), 1e-12)
        B = np.linalg.solve(A + lam * np.eye(A.shape[0]), X[~te].T @ R[~te])
        out[te] = np.mean((R[te] - X[te] @ B) ** 2, axis=1)
    return out


@dataclass(frozen=True)
class LineCheck:
    """Held-out losses (per window) of the profile's channels: left as they are (``none``),
    explained by place (a profile over lap position), by the car's state (a mismatch that scales
    with it) and by both; ``t_within``: paired block t of both against place (positive: at the
    same place the state still predicts the error); ``t_beyond``: of both against state
    (positive: the place adds what the state does not explain); ``road``: the verdict."""

    name: str
    place: np.ndarray
    state: np.ndarray
    both: np.ndarray
    none: np.ndarray
    t_within: float
    t_beyond: float
    road: bool

    def gains(self) -> tuple[float, float, float]:
        n = max(float(self.none.mean()), 1e-300)
        return tuple(float(1.0 - x.mean() / n) for x in (self.place, self.state, self.both))

    def note(self) -> str:
        gp, gs, gb = (round(100 * g) for g in self.gains())
        shares = (f"held out by lap, place explains {gp} % of its channels' error, the car's state {gs} %, "
                  f"both {gb} %")
        if self.name in SCALING:
            return (f"{self.name} repeats with the driven line: road or state mismatch, not named ({shares}: "
                    f"the place adds nothing the state does not explain, t = {self.t_beyond:.1f})")
        return (f"{self.name} repeats with the driven line: road or state mismatch, not named ({shares}: at the "
                f"same place the error still follows the state, t = {self.t_within:.1f}; a bank or grade adds "
                f"the same force whatever the state)")


def line_check(prob, name: str, starts: np.ndarray, fold: np.ndarray, bid: np.ndarray,
               R: np.ndarray | None = None) -> LineCheck | None:
    """Is what a profile explains a property of the road or a mismatch that repeats with the
    driven line? Both repeat at the same place every lap, so a profile over lap position predicts
    either on held-out laps. The windows' errors on the profile's channels are regressed (linear
    ridge, held out by the naming folds) on the place (the profile's knots), on the state alone
    (:func:`state_features`) and on both.

    - A bank or grade (:data:`ADDITIVE`) adds g sin(angle(s)) whatever the car's state; a model
      mismatch scales with the state (a_y, v_x^2, slip), which at one place differs a little
      from lap to lap. Not a road property when, at the same place, the state still predicts the
      error (both against place) and that matters: significant (paired block t or signed-rank z
      above ``T_GAIN_STRONG``) and more than ``MIN_EXCESS_SHARE`` of what the place explains, or
      significant above ``T_GAIN`` while the state alone predicts as well as the place (the
      naming stage's two-level test of :func:`~gprace.diagnose.diagnose._significant`). A bank
      where the car corners (TUM's oval: 30 degrees in the turns) is explained as well by the
      state as by the place, but nothing relevant is left for the state at a place: named.
    - A friction profile (:data:`SCALING`) follows the state at a place by nature; it is no
      road property when the place adds nothing significant (``T_GAIN_STRONG``) to what the
      state alone explains.

    When the place predicts nothing held out, nothing repeats with the line: the profile's own
    cross-validation decides. ``R`` (m, H, 3): the windows' normalised errors of the model the
    profile is added to (computed when None). None for other effects, recordings without laps,
    or a single fold."""
    from gprace.diagnose import name as nm

    ch = ADDITIVE.get(name) or SCALING.get(name)
    basis = make_basis(prob.data, prob.H) if ch is not None else None
    if basis is None or len(np.unique(fold)) < 2:
        return None
    if R is None:
        R = prob.residuals(prob.model(), starts)
    r = np.concatenate([R[..., c] for c in ch], axis=1)
    r = np.where(np.isfinite(r), r, 0.0)
    P, S = place_features(basis, prob.data, starts), state_features(prob.data, starts, prob.H)
    lp, ls, lb = (_heldout_linear(X, r, fold) for X in (P, S, np.hstack([P, S[:, 1:]])))
    t_w = max(nm.gain_test(lp, lb, bid)[1], nm.rank_test(lp, lb, bid))
    t_b = max(nm.gain_test(ls, lb, bid)[1], nm.rank_test(ls, lb, bid))
    extra, by_place = float(lp.mean() - lb.mean()), float(np.mean(r**2) - lp.mean())
    if by_place <= 0.0:  # nothing repeats with the line
        road = True
    elif name in SCALING:
        road = bool(t_b > nm.T_GAIN_STRONG and lb.mean() < ls.mean())
    else:
        follows = (t_w > nm.T_GAIN_STRONG and extra > nm.MIN_EXCESS_SHARE * by_place) or (
            t_w > nm.T_GAIN and ls.mean() <= lp.mean())
        road = not follows
    return LineCheck(name, lp, ls, lb, np.mean(r**2, axis=1), t_w, t_b, road)


# --------------------------------------------------------------------------------------------
# a profile pressed against its physical bound (issue 36, stop 48)

# A profile is at its bound when a knot is within name.at_bound's 1e-3 of the range (the fit's
# clip active), as a calibrated parameter is flagged. 1 % (a bank within 0.012 rad of 0.6 rad)
# was tried: the top fit of TUM's 30-degree oval overshot one knot to -0.593 rad (truth -0.524)
# and the bank was refused (recovery, seed 939504).


def at_bound(fit, vehicle, data: Dataset | None) -> str | None:
    """Where and how far a profile fit's values reach their physical bound
    (:func:`gprace.diagnose.name.at_bound`), as a
    phrase for the report; None when every fitted knot is inside."""
    from gprace.diagnose import name as nm

    pf = fit.profile
    if pf is None:
        return None
    lo, hi = nm.physical_bounds(fit.name, "values", vehicle, data)
    v = pf.neutral + fit.x
    free = pf.free if pf.free is not None else np.ones(len(v), dtype=bool)
    hit = free & nm.at_bound(fit.name, "values", v, vehicle, data)
    if not hit.any():
        return None
    unit = EFFECTS[fit.name].params["values"].unit
    s = pf.basis.knots[hit]
    j = int(np.flatnonzero(hit)[np.argmax(np.abs(v[hit] - pf.neutral))])
    bound = lo if abs(v[j] - lo) <= abs(v[j] - hi) else hi
    at = ", ".join(f"{x:.0f}" for x in s[:6]) + (", ..." if len(s) > 6 else "")
    return (f"{int(hit.sum())} of {int(free.sum())} knots at its physical bound {bound:.3g} {unit} (s = {at} m; "
            f"extreme {v[j]:.3g} {unit} at s = {pf.basis.knots[j]:.0f} m)")


def bound_note(fit, where: str) -> str:
    """The report's note on a profile refused at its bound (``where`` from :func:`at_bound`)."""
    what = {"road_bank_profile": "bank", "road_grade_profile": "grade"}.get(fit.name, "grip")
    return (f"{fit.name} not named: {where}; a road has no such {what}: the profile follows an error "
            f"that is something else (reported like a calibrated parameter pressed against its range)")
