"""Cross-validation by linearised refits: each fold's parameters in one Gauss-Newton step.

Naming an effect, keeping it (parsimony) and applying a calibration are all decided by held-out
prediction: the parameters are refitted without one fold (a lap) and judged on it. Refitting by
iterations costs a dozen batched model evaluations per fold; here the refits share one Jacobian:

1. the residuals and their forward-difference Jacobian at the full fit, on every evaluation
   window, in ONE batched evaluation (one parameter set per parameter, as in the fits);
2. per fold, a Levenberg-Marquardt step from the full fit on the other folds' windows (the
   full fit is already the optimum of nearly the same data, so one step from it is the refit to
   first order), clipped to the bounds;
3. the held-out residuals of every fold in ONE exact evaluation, each window with its own fold's
   parameters (per-window parameter arrays).

A *block* is the free parameters of one catalogue effect; several blocks are refitted jointly.
(The calibration's own cross-validation iterates: it moves far from the nominal car, where one
step falls short: measured on the INI F1TENTH run, 62 % held-out gain by one step, 84 % by
iterations.)
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from gprace.diagnose.core import DYNAMIC, errors, lag_states, predict
from gprace.model import EFFECTS

DAMPING = 1e-3
"""Levenberg-Marquardt damping of the fold step, relative to the diagonal of J^T J."""


@dataclass(frozen=True)
class Block:
    """Free parameters of one catalogue effect (or, ``name`` None, of the calibration: ``params``
    its :class:`~gprace.diagnose.calibrate.CalParam` list, coordinates relative to the problem's
    vehicle) with their bounds and finite-difference step."""

    name: str | None
    free: tuple[str, ...]
    fixed: dict
    x: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    step: float
    params: tuple = ()


def effect_block(fit, data, vehicle=None) -> Block:
    """The block of a fitted effect (:class:`gprace.diagnose.name.Fit`); a profile as a block with
    nothing free (held at its own fit: its smoothing is chosen inside its fit)."""
    from gprace.diagnose import name as nm

    if fit.profile is not None:
        return Block(fit.name, (), fit.values(), np.zeros(0), np.zeros(0), np.zeros(0), 1e-3)

    lo, hi = nm._bounds(fit.name, fit.free, data, vehicle)
    step = 1e-3 if any(k.startswith("s_") for k in fit.free) else float(np.sqrt(np.finfo(float).eps))
    return Block(fit.name, tuple(fit.free), dict(fit.fixed), np.asarray(fit.x, float), lo, hi, step)


def calibration_block(params, x, lo, hi) -> Block:
    """The calibration's parameters as a block (for joint fits with an effect)."""
    return Block(None, tuple(p.name for p in params), {}, np.asarray(x, float), np.asarray(lo, float),
                 np.asarray(hi, float), float(np.sqrt(np.finfo(float).eps)), tuple(params))


def _model(prob, blocks: list[Block], X: np.ndarray):
    """The model with every block's parameters taken from the per-window rows ``X`` (m, P)."""
    from gprace.diagnose import calibrate as cal

    effects, j, upd = [], 0, {}
    for b in blocks:
        cols = X[:, j:j + len(b.free)]
        j += len(b.free)
        if b.name is None:
            veh = prob.vehicle
            upd.update(cal.params_update(veh, {p.name: cal.from_coord(p, cols[:, i], cal.nominal_value(veh, p))
                                               for i, p in enumerate(b.params)}))
            continue
        vals = dict(b.fixed)
        vals.update({k: cols[:, i] for i, k in enumerate(b.free)})
        if "s_start" in vals:  # as in the fits: a window at least 1 m long
            vals["s_end"] = np.maximum(vals["s_end"], vals["s_start"] + 1.0)
        effects.append(EFFECTS[b.name](**vals))
    model = prob.model(effects)
    if upd:
        model.params = replace(model.params, **upd)
    return model


def row_groups(X: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """``(rows, groups)``: the distinct rows of ``X`` (m, P) as ``np.unique(X, axis=0)`` gives them,
    and for each the indices of the rows of ``X`` equal to it. Equal rows mostly come in runs (a
    Jacobian's parameter sets repeated per window), so the runs are found first and only their
    first rows are sorted: O(m P) instead of a sort of all m rows (measured on the INI F1TENTH
    log: ``np.unique`` over every row was a quarter of the diagnosis's CPU)."""
    new = np.ones(len(X), dtype=bool)
    new[1:] = np.any(X[1:] != X[:-1], axis=1)
    rows, inv = np.unique(X[new], axis=0, return_inverse=True)
    label = inv.ravel()[np.cumsum(new) - 1]
    order = np.argsort(label, kind="stable")
    return rows, np.split(order, np.cumsum(np.bincount(label, minlength=len(rows)))[:-1])


def residual_rows(prob, blocks: list[Block], X: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(m, H, 3) normalised multi-step errors, window ``i`` with the parameters ``X[i]``."""
    m = len(starts)
    model = _model(prob, blocks, X)
    Z0 = None
    if model.nx > 6:  # lag states from the command history, per distinct parameter row
        rows, groups = row_groups(X)
        Z0 = np.empty((m, model.nx - 6))
        for r, idx in enumerate(groups):
            mr = _model(prob, blocks, rows[r:r + 1])
            mr.params = replace(mr.params, **{f.name: (float(v[0]) if isinstance(v := getattr(mr.params, f.name),
                                                                               np.ndarray) else v)
                                               for f in fields(mr.params)})
            for e in mr.effects:
                e.values = {k: (float(v[0]) if isinstance(v, np.ndarray) else v) for k, v in e.values.items()}
            Z0[idx] = lag_states(mr, prob.data)[starts[idx]]
    E = errors(prob.data, starts, predict(model, prob.data, starts, prob.H, prob._substeps(model), Z0=Z0))
    return E[..., list(DYNAMIC)] / prob.scale


def jacobian(prob, blocks: list[Block], starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``R0`` (m, n) at the blocks' parameters and their Jacobian ``J`` (m, n, P),
    forward differences one-sided inside the bounds, in one batched evaluation."""
    x = np.concatenate([b.x for b in blocks])
    lo = np.concatenate([b.lo for b in blocks])
    hi = np.concatenate([b.hi for b in blocks])
    step = np.concatenate([np.full(len(b.x), b.step) for b in blocks])
    P, m = len(x), len(starts)
    h = step * np.where(x >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x))
    h = np.where((x + h > hi) | (x + h < lo), -h, h)
    h = (x + h) - x
    sets = np.vstack([x] + [x + np.eye(P)[i] * h[i] for i in range(P)])
    R = residual_rows(prob, blocks, np.repeat(sets, m, axis=0), np.tile(starts, P + 1))
    R = np.where(np.isfinite(R), R, 1e3).reshape(P + 1, m, -1)
    return R[0], np.moveaxis((R[1:] - R[0]) / h[:, None, None], 0, -1)


BACKTRACK = 3
"""Halvings of a prescreen step that does worse than its starting point."""
FIT_WINDOWS = 600
"""Windows (spread over the recording) whose Jacobian the fold steps use."""


def cv_losses(prob, blocks: list[Block], starts: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """(m, 3) held-out per-window, per-channel normalised MSE of the model with ``blocks``, each
    fold's parameters refitted without it by one linearised step (module doc)."""
    x = np.concatenate([b.x for b in blocks])
    lo = np.concatenate([b.lo for b in blocks])
    hi = np.concatenate([b.hi for b in blocks])
    sub = np.arange(0, len(starts), max(1, len(starts) // FIT_WINDOWS))
    R0, J = jacobian(prob, blocks, starts[sub])
    X = np.empty((len(starts), len(x)))
    for f in np.unique(fold):
        te = fold == f
        tr = np.flatnonzero(fold[sub] != f)
        X[te] = _step(J[tr].reshape(-1, len(x)), R0[tr].ravel(), x, lo, hi)
    return np.mean(residual_rows(prob, blocks, X, starts) ** 2, axis=1)


def _step(J: np.ndarray, r: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The damped Gauss-Newton step from ``x`` inside the bounds: a parameter the step would push
    past its bound is held there and the others solved again (a small active set)."""
    A0, g0 = J.T @ J, J.T @ r
    free = np.ones(len(x), dtype=bool)
    out = x.copy()
    for _ in range(len(x) + 1):
        if not free.any():
            return out
        A = A0[np.ix_(free, free)]
        A = A + DAMPING * np.diag(np.maximum(np.diag(A), 1e-12))
        fixed_shift = A0[np.ix_(free, ~free)] @ (out[~free] - x[~free])
        try:
            dx = -np.linalg.solve(A, g0[free] + fixed_shift)
        except np.linalg.LinAlgError:
            return x.copy()
        new = x[free] + dx
        lo_f, hi_f = lo[free], hi[free]
        past = (new < lo_f) | (new > hi_f)
        idx = np.flatnonzero(free)
        out[idx] = np.clip(new, lo_f, hi_f)
        if not past.any():
            return out
        free[idx[past]] = False
    return out


def prescreen(prob, name: str, starts: np.ndarray, inits: list[dict]):
    """One damped Gauss-Newton step of effect ``name`` from each starting point (window effects on
    the windows that can reach their region, edges kept near it, as in the fits), judged by the
    exact cost after the step on all ``starts``: the best as a :class:`~gprace.diagnose.name.Fit`
    (or None). A true effect removes most of its excess in its first step (its parameters enter
    smoothly); the ranking needs no more, and costs (p + 2) evaluations instead of about 4 p + 5
    for five trust-region iterations."""
    from gprace.diagnose import name as nm

    free = nm.free_params(name)
    fixed = {k: EFFECTS[name].params[k].default for k in EFFECTS[name].params if k in nm.FIXED}
    lo_all, hi_all = nm._bounds(name, free, prob.data, prob.vehicle)
    step = 1e-3 if any(k.startswith("s_") for k in free) else float(np.sqrt(np.finfo(float).eps))
    best = None
    for init in inits:
        near, lo, hi = starts, lo_all.copy(), hi_all.copy()
        if "s_start" in init:
            a, b = init["s_start"], init["s_end"]
            near = nm._near(prob, starts, a, b, margin=nm.NEAR_MARGIN)
            if len(near) < 5:
                continue
            i0, i1 = free.index("s_start"), free.index("s_end")
            lo[i0], hi[i0] = a - nm.NEAR_MARGIN, max(a + 1.0, 0.5 * (a + b))
            lo[i1], hi[i1] = min(b - 1.0, 0.5 * (a + b) + 1.0), b + nm.NEAR_MARGIN
        x0 = np.clip(np.array([init[k] for k in free], dtype=float), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        block = Block(name, tuple(free), fixed, x0, lo, hi, step)
        R0, J = jacobian(prob, [block], near)
        x1 = _step(J.reshape(-1, len(free)), R0.ravel(), x0, lo, hi)
        # the step's exact cost where it acts; halved while it does worse than the start (an
        # effect that enters non-linearly: a friction ellipse's floor, a lag's time constant)
        c0 = float(np.mean(R0**2))
        for _ in range(BACKTRACK + 1):
            R1 = residual_rows(prob, [block], np.tile(x1, (len(near), 1)), near)
            c1 = float(np.mean(np.where(np.isfinite(R1), R1, 1e3) ** 2))
            if c1 <= c0:
                break
            x1 = x0 + 0.5 * (x1 - x0)
        if len(near) != len(starts):  # the cost over all windows (unchanged far from a window)
            R1 = residual_rows(prob, [block], np.tile(x1, (len(starts), 1)), starts)
        cost = float(np.mean(np.where(np.isfinite(R1), R1, 1e3) ** 2))
        if best is None or cost < best.cost:
            best = nm.Fit(name, list(free), x1, fixed, cost)
    return best


def joint_fit(prob, blocks: list[Block], starts: np.ndarray, max_nfev: int = 15, ftol: float = 1e-8) -> list[Block]:
    """Bounded least squares of all blocks' parameters together (the Jacobian batched), from
    their current values; the blocks at the solution."""
    from gprace.diagnose.core import batched_least_squares

    x0 = np.concatenate([b.x for b in blocks])
    lo = np.concatenate([b.lo for b in blocks])
    hi = np.concatenate([b.hi for b in blocks])
    m = len(starts)

    def batch(Xs):
        Xs = np.asarray(Xs)
        R = residual_rows(prob, blocks, np.repeat(Xs, m, axis=0), np.tile(starts, len(Xs)))
        R = R.reshape(len(Xs), -1)
        return np.where(np.isfinite(R), R, 1e3)

    sol = batched_least_squares(batch, x0, lo, hi, np.maximum((hi - lo) / np.sqrt(12.0), 1e-6), max_nfev, ftol=ftol)
    out, j = [], 0
    for b in blocks:
        out.append(replace(b, x=sol.x[j:j + len(b.x)]))
        j += len(b.x)
    return out

