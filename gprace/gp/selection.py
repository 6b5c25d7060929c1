"""Diverse data selection (seed paper, "Diverse Data Selection", after Nguyen-Tuong & Peters 2011).

A dictionary of at most ``M`` points is kept per GP. Measurements are streamed through it in
order; for each one, with the selection kernel's hyperparameters FIXED (from a previous fit or a
quick fit on a subsample):

1. **Outlier gate** (project decision; the exact statistic of Kabzan et al. 2019, section V-B,
   could not be checked): the point is rejected if for any output
   ``|y - mu(z)| > kappa * sqrt(var(z) + sn2)``, with the posterior mean ``mu`` and latent
   variance ``var`` given the dictionary and the output's noise variance ``sn2``
   (``kappa = outlier_kappa``, default 4; ``None`` disables the gate). The gate is applied only
   where the dictionary informs the prediction, ``var(z) < gate_below * sf2`` (default 0.5): a
   measurement in a region the dictionary has never seen cannot be judged by it, and rejecting
   it there would throw away exactly the new, diverse data the selection is for.
2. **Entry** (the paper's rule): once the dictionary is full, a point enters only if its
   posterior variance given the dictionary exceeds the median, over the dictionary, of each
   point's posterior variance given all *other* dictionary points, for at least one output.
   The latter is the leave-one-out variance ``1 / [(K + sn2 I)^-1]_ii - sn2``, read from the
   diagonal of the inverse in O(M).
   **Decision:** while the dictionary holds fewer than ``M`` points every non-outlier point
   enters: with one or two points the median rule would refuse almost everything (the
   leave-one-out variance of a lone point is the prior variance) and the dictionary would never
   fill; a dictionary below capacity has no reason to refuse data.
3. **Replacement** when full: the point enters in place of the dictionary point of smallest
   leave-one-out variance. If outputs disagree on that point, the output with the largest ratio
   ``var_new / min_i var_loo_i`` decides (the paper's ratio rule).
4. No age decay: old points leave only when they are the least informative.

Cost: per output a preallocated ``M x M`` inverse ``P = (K + sn2 I)^-1`` is kept (empty slots
hold identity rows, so its size never changes). Outputs with identical hyperparameters (a shared
kernel, as the time trial's GPs have) have identical ``P``, variances and leave-one-out
variances: they share one inverse and one set of rank-one vectors, and only the posterior means
are kept per output (``share=False`` keeps one per output; the decisions are the same bit for
bit, half the work for two outputs). Replacing slot ``j`` by a new point is a
rank-one downdate ``P - p p^T / p_j`` (which removes the old point) followed by a rank-one
bordering update ``P + v v^T / s`` (which adds the new one), O(M^2). Candidates are processed in
blocks: ``W0 = P K(dictionary, block)`` is formed once per block by one matrix product; within
the block the current ``P`` and ``W`` are ``P0 + U S U^T`` and ``W0 + U E`` with the rank-one
vectors ``U`` of the changes so far, and the posterior means and variances of the remaining
candidates are updated in O(block) per change by the classical rank-one formulas, so every
decision is exact for the dictionary at that moment. At the end of a block the accumulated
vectors are applied to ``P`` in place (symmetric rank-k updates, ``dsyrk``, of the lower
triangle of the preallocated buffer). To bound round-off growth, ``P`` is recomputed from a fresh Cholesky factorisation every
``refresh_every`` changes (amortised; never per point).

``random_subsample`` and ``reservoir_merge`` are the uniform-sampling baseline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve
from scipy.linalg.blas import dsymm, dsyrk

from gprace.errors import ConfigError, InputError
from gprace.gp.base import GPHyper, check_training_data
from gprace.gp.linalg import cholesky


@dataclass
class SelectionStats:
    """Counters of what happened to streamed points."""

    seen: int = 0  # points offered
    inserted: int = 0  # added while the dictionary had room
    replaced: int = 0  # took the place of the point of smallest leave-one-out variance
    rejected_outlier: int = 0  # output more than kappa std from the dictionary's prediction
    rejected_variance: int = 0  # posterior variance not above the dictionary's median
    refreshes: int = 0  # full refactorisations of the dictionary's Cholesky factor

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


class DiverseSelector:
    """Streaming diverse dictionary of at most ``max_points`` points (see module docstring).

    ``hyper`` fixes the kernel, scalers and per-output hyperparameters (:class:`GPHyper`, e.g.
    ``gp.hyper_`` of a fitted backend). Use :meth:`initialize` to load an existing dictionary,
    :meth:`update` to stream measurements, :attr:`Z` / :attr:`Y` for the result.
    """

    def __init__(
        self,
        hyper: GPHyper,
        max_points: int,
        outlier_kappa: float | None = 4.0,
        gate_below: float = 0.5,
        max_snr: float = 1e3,
        block: int = 128,
        refresh_every: int = 2000,
        share: bool = True,
    ) -> None:
        if max_points < 1:
            raise ConfigError(f"max_points must be >= 1, got {max_points}")
        if outlier_kappa is not None and not outlier_kappa > 0:
            raise ConfigError(f"outlier_kappa must be positive (or None to disable), got {outlier_kappa}")
        self.hyper = hyper
        self.M = int(max_points)
        self.kappa = outlier_kappa
        self.gate_below = float(gate_below)
        self.block = int(max(1, block))
        self.refresh_every = int(max(1, refresh_every))
        p, d, M = hyper.p, hyper.d, self.M
        self.max_snr = float(max_snr)
        self._sf2 = np.exp(hyper.log_sf2)
        self._sn2 = np.maximum(np.exp(hyper.log_sn2), self._sf2 / self.max_snr)
        # outputs that share one kernel share the inverse (groups of identical hyperparameters)
        self._groups = hyper.groups() if share else [[o] for o in range(p)]
        self._rep = [g[0] for g in self._groups]  # the output whose hyperparameters a group uses
        self._gof = np.empty(p, dtype=int)  # group of each output
        for gi, g in enumerate(self._groups):
            self._gof[g] = gi
        ng = len(self._groups)
        # preallocated state (never reallocated per point) -------------------------------------
        # one Fortran-ordered inverse per group; only its lower triangle is maintained
        self._Pg = [np.eye(M, order="F") for _ in range(ng)]
        self.P = [self._Pg[self._gof[o]] for o in range(p)]  # per output (shared objects)
        self._diag = np.ones((ng, M))
        self.Zs = np.zeros((M, d))  # normalised inputs per slot
        self.Ys = np.zeros((M, p))  # normalised outputs per slot
        self.active = np.zeros(M, dtype=bool)
        tmax = 2 * self.block
        self._U = np.zeros((ng, M, tmax))  # rank-one vectors since the last flush
        self._E = np.zeros((ng, tmax, self.block))  # their coefficients on the block's W
        self._sig = np.zeros(tmax)
        self._t = 0
        self._changes_since_refresh = 0
        self.stats = SelectionStats()

    # -- results --------------------------------------------------------------------------------
    @property
    def n_points(self) -> int:
        return int(self.active.sum())

    @property
    def full(self) -> bool:
        return self.n_points >= self.M

    @property
    def Z(self) -> np.ndarray:
        """Dictionary inputs ``(n, d)`` in original units (slot order)."""
        return self.Zs[self.active] * self.hyper.z_scale + self.hyper.z_mean

    @property
    def Y(self) -> np.ndarray:
        """Dictionary outputs ``(n, p)`` in original units (slot order)."""
        return self.Ys[self.active] * self.hyper.y_scale + self.hyper.y_mean

    @property
    def diag(self) -> np.ndarray:
        """Diagonal ``(p, M)`` of each output's inverse."""
        return self._diag[self._gof]

    def loo_variance(self) -> np.ndarray:
        """Latent leave-one-out variance ``(p, n)`` of each dictionary point (normalised units)."""
        return 1.0 / self.diag[:, self.active] - self._sn2[:, None]

    def posterior(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and latent variance ``(m, p)`` (normalised units) of the dictionary GP at ``Z``
        (original units), computed from the maintained inverse."""
        self._flush()
        Zn = self.hyper.zn(np.asarray(Z, dtype=float))
        mean = np.empty((Zn.shape[0], self.hyper.p))
        var = np.empty_like(mean)
        act = self.active.astype(float)[:, None]
        for gi, o in enumerate(self._rep):
            K = np.asfortranarray(self.hyper.k(o, self.Zs, Zn) * act)
            W = dsymm(1.0, self._Pg[gi], K, lower=1)
            for q in self._groups[gi]:
                mean[:, q] = self.Ys[:, q] @ W
            var[:, self._groups[gi]] = (self._sf2[o] - np.einsum("ij,ij->j", K, W))[:, None]
        return mean, var

    def _check(self, Z: np.ndarray, Y: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
        Z, Y = check_training_data(Z, Y, where)
        if Z.shape[1] != self.hyper.d or Y.shape[1] != self.hyper.p:
            raise InputError(
                f"{where}: expected {self.hyper.d} inputs and {self.hyper.p} outputs, got {Z.shape[1]} and {Y.shape[1]}"
            )
        return self.hyper.zn(Z), self.hyper.yn(Y)

    # -- bulk load and refresh ----------------------------------------------------------------------
    def initialize(self, Z: np.ndarray, Y: np.ndarray) -> "DiverseSelector":
        """Load up to ``max_points`` points as the dictionary (one fresh factorisation)."""
        Zn, Yn = self._check(Z, Y, "selection: initial dictionary")
        n = Zn.shape[0]
        if n > self.M:
            raise InputError(f"selection: initial dictionary has {n} points, more than max_points={self.M}")
        self.active[:] = False
        self.Zs[:] = 0.0
        self.Ys[:] = 0.0
        self.Zs[:n] = Zn
        self.Ys[:n] = Yn
        self.active[:n] = True
        self._t = 0
        self.refresh()
        self.stats.refreshes -= 1  # the initial factorisation is not a refresh
        return self

    def fresh_inverse(self, o: int) -> np.ndarray:
        """``(K + sn2 I)^-1`` of output ``o`` computed from scratch (identity on empty slots)."""
        idx = np.flatnonzero(self.active)
        M = self.M
        Pf = np.zeros((M, M))
        Pf[np.diag_indices(M)] = 1.0
        if idx.size:
            Za = self.Zs[idx]
            K = self.hyper.k(o, Za, Za)
            K[np.diag_indices(idx.size)] += self._sn2[o]
            L = cholesky(K, "selection kernel matrix")
            Pf[np.ix_(idx, idx)] = cho_solve((L, True), np.eye(idx.size), check_finite=False)
        return Pf

    def refresh(self) -> None:
        """Recompute every inverse from a fresh factorisation (bounds round-off growth)."""
        self._t = 0
        for gi, o in enumerate(self._rep):
            self._Pg[gi][:] = self.fresh_inverse(o)
            self._diag[gi] = np.diagonal(self._Pg[gi])
        self._changes_since_refresh = 0
        self.stats.refreshes += 1

    def factor_error(self) -> float:
        """Largest deviation of the incrementally updated inverse from a fresh one, relative to
        the largest entry of the fresh inverse (for tests and diagnostics)."""
        self._flush()
        err = 0.0
        for gi, o in enumerate(self._rep):
            Pf = self.fresh_inverse(o)
            D = np.tril(self._Pg[gi]) - np.tril(Pf)
            err = max(err, float(np.max(np.abs(D)) / np.max(np.abs(Pf))))
        return err

    def inverse(self, o: int) -> np.ndarray:
        """The maintained inverse of output ``o`` as a full symmetric matrix (a copy)."""
        self._flush()
        L = np.tril(self.P[o])
        return L + np.tril(L, -1).T

    # -- low-rank accumulation ----------------------------------------------------------------------
    def _flush(self) -> None:
        """Apply the pending rank-one terms to the preallocated inverses, in place."""
        t = self._t
        if t == 0:
            return
        neg, pos = self._sig[:t] < 0, self._sig[:t] > 0
        for gi in range(len(self._groups)):
            U = self._U[gi, :, :t]
            # symmetric rank-k updates of the lower triangle, in place
            if neg.any():
                dsyrk(-1.0, U[:, neg], beta=1.0, c=self._Pg[gi], lower=1, overwrite_c=1)
            if pos.any():
                dsyrk(1.0, U[:, pos], beta=1.0, c=self._Pg[gi], lower=1, overwrite_c=1)
        self._t = 0

    def _column(self, gi: int, j: int, t: int) -> np.ndarray:
        """Column ``j`` of group ``gi``'s current inverse: lower-triangle storage plus pending terms."""
        PF = self._Pg[gi]
        col = np.empty(self.M)
        col[j:] = PF[j:, j]
        col[:j] = PF[j, :j]
        if t:
            Ut = self._U[gi, :, :t]
            col += Ut @ (self._sig[:t] * Ut[j])
        return col

    # -- streaming ------------------------------------------------------------------------------------
    def update(self, Z: np.ndarray, Y: np.ndarray) -> SelectionStats:
        """Stream measurements ``Z (n, d)``, ``Y (n, p)`` through the dictionary, in order."""
        Zn, Yn = self._check(Z, Y, "selection: new data")
        n = Zn.shape[0]
        start = 0
        while start < n:
            # small blocks while filling (nearly every point changes the dictionary)
            b = self.block if self.full else min(self.block, 32)
            stop = min(n, start + b)
            self._process_block(Zn[start:stop], Yn[start:stop])
            start = stop
            if self._changes_since_refresh >= self.refresh_every:
                self.refresh()
        return self.stats

    def _process_block(self, C: np.ndarray, Yc: np.ndarray) -> None:
        p, gof = self.hyper.p, self._gof
        B = C.shape[0]
        self._flush()
        act = self.active.astype(float)[:, None]
        # kernel columns, W = P K and the variances per group; the means per output
        Kc = [np.asfortranarray(self.hyper.k(o, self.Zs, C) * act) for o in self._rep]
        W0 = [dsymm(1.0, self._Pg[gi], Kc[gi], lower=1) for gi in range(len(self._rep))]
        var = np.stack([self._sf2[o] - np.einsum("ij,ij->j", Kc[gi], W0[gi]) for gi, o in enumerate(self._rep)])
        mu = np.stack([self.Ys[:, o] @ W0[gof[o]] for o in range(p)])
        sn2 = self._sn2[:, None]
        gate = self.gate_below * self._sf2[:, None]
        self.stats.seen += B
        pos = 0
        while pos < B:
            v = np.maximum(var[:, pos:], 0.0)[gof]
            if self.kappa is not None:
                out = np.any((v < gate) & (np.abs(Yc[pos:].T - mu[:, pos:]) > self.kappa * np.sqrt(v + sn2)), axis=0)
            else:
                out = np.zeros(B - pos, dtype=bool)
            full = self.full
            if full:
                loo = 1.0 / self._diag[:, self.active][gof] - sn2
                med = np.median(loo, axis=1)
                enter = np.any(v > med[:, None], axis=0)
            else:
                enter = np.ones(B - pos, dtype=bool)
            hit = np.flatnonzero(enter & ~out)
            last = B - pos if hit.size == 0 else int(hit[0])
            self.stats.rejected_outlier += int(np.sum(out[:last]))
            self.stats.rejected_variance += int(np.sum(~enter[:last] & ~out[:last]))
            if hit.size == 0:
                break
            c = pos + last
            if not full:
                j = int(np.argmin(self.active))  # first free slot
                self.stats.inserted += 1
            else:
                idx = np.flatnonzero(self.active)
                jo = np.argmin(loo, axis=1)
                ratio = v[:, last] / np.maximum(loo[np.arange(p), jo], 1e-300)
                j = int(idx[jo[int(np.argmax(ratio))]])
                self.stats.replaced += 1
            self._replace(j, c, C, Yc, Kc, W0, var, mu)
            pos = c + 1
        self._flush()

    def _replace(self, j: int, c: int, C: np.ndarray, Yc: np.ndarray, Kc: list[np.ndarray],
                 W0: list[np.ndarray], var: np.ndarray, mu: np.ndarray) -> None:
        """Put candidate ``c`` of the block into slot ``j``: downdate (remove the slot's point or
        placeholder), then bordering update (add the candidate). Updates the block's posterior
        ``var`` (per group) and ``mu`` (per output) for candidates ``c+1..`` and records the two
        rank-one vectors of each group."""
        t = self._t
        x = C[c:c + 1]
        for gi, o in enumerate(self._rep):
            outs = self._groups[gi]
            U, E, sig = self._U[gi], self._E[gi][:, :C.shape[0]], self._sig
            Ut, Et = U[:, :t], E[:t]
            # current column j of P and row j of W = P K
            pcol = self._column(gi, j, t)
            pj = pcol[j]
            wj = W0[gi][j, c:] + Ut[j] @ Et[:, c:]
            # 1. downdate: P1 = P - pcol pcol^T / pj
            var[gi, c:] += wj * wj / pj
            for q in outs:
                mu[q, c:] -= (self.Ys[:, q] @ pcol) * wj / pj
            self._diag[gi] -= pcol * pcol / pj
            sq = np.sqrt(pj)
            U[:, t] = pcol / sq
            E[t, :c] = 0.0
            E[t, c:] = -wj / sq
            sig[t] = -1.0
            # 2. insert x at slot j: b = P1 k(dictionary without j, x)
            Ut1, Et1 = U[:, :t + 1], E[:t + 1]
            b = W0[gi][:, c] + Ut1 @ Et1[:, c]
            b[j] = 0.0
            k = Kc[gi][:, c].copy()
            k[j] = 0.0
            s = max(self._sf2[o] + self._sn2[o] - float(k @ b), self._sn2[o])
            r = self.hyper.k(o, x, C[c:])[0]
            g = k @ W0[gi][:, c:] + (k @ Ut1) @ Et1[:, c:] - r  # k^T W1 - r
            var[gi, c:] -= g * g / s
            for q in outs:
                mu[q, c:] += (float(self.Ys[:, q] @ b) - Yc[c, q]) * g / s
            b[j] = -1.0  # v = b - e_j
            self._diag[gi] += b * b / s
            sq = np.sqrt(s)
            U[:, t + 1] = b / sq
            E[t + 1, :c] = 0.0
            E[t + 1, c:] = g / sq
            sig[t + 1] = 1.0
            Kc[gi][j, c:] = r
        self._t = t + 2
        self.Zs[j] = C[c]
        self.Ys[j] = Yc[c]
        self.active[j] = True
        self._changes_since_refresh += 1


# ------------------------------------------------------------------------------------------------
# baseline: uniform random subsample
# ------------------------------------------------------------------------------------------------
def random_subsample(Z: np.ndarray, Y: np.ndarray, M: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A uniform random subsample of at most ``M`` rows (in data order), the comparison baseline."""
    Z, Y = check_training_data(Z, Y, "random subsample")
    n = Z.shape[0]
    if n <= M:
        return Z.copy(), Y.copy()
    idx = np.sort(np.random.default_rng(seed).choice(n, M, replace=False))
    return Z[idx], Y[idx]


def reservoir_merge(
    Z_old: np.ndarray, Y_old: np.ndarray, n_seen: int, Z_new: np.ndarray, Y_new: np.ndarray, M: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, int]:
    """Continue a uniform subsample: ``(Z_old, Y_old)`` is a uniform sample of ``n_seen`` points;
    the result is a uniform sample of at most ``M`` of all ``n_seen + n_new`` points.

    The number taken from the new points is hypergeometric, so the merge is exactly uniform.
    Returns ``(Z, Y, n_seen_total)``.
    """
    rng = np.random.default_rng(seed)
    n_old, n_new = Z_old.shape[0], Z_new.shape[0]
    n_seen = max(int(n_seen), n_old)
    total = n_seen + n_new
    m = min(M, total)
    from_new = int(rng.hypergeometric(n_new, n_seen, m)) if n_new and n_seen else (m if n_new else 0)
    from_new = min(from_new, n_new)
    from_old = min(m - from_new, n_old)
    i_old = np.sort(rng.choice(n_old, from_old, replace=False)) if from_old < n_old else np.arange(n_old)
    i_new = np.sort(rng.choice(n_new, from_new, replace=False))
    Z = np.concatenate([Z_old[i_old], Z_new[i_new]])
    Y = np.concatenate([Y_old[i_old], Y_new[i_new]])
    return Z, Y, total


def selector_bytes(M: int, p: int, d: int, block: int = 128) -> float:
    """Memory of a :class:`DiverseSelector` of ``M`` slots for ``p`` outputs and ``d`` inputs [bytes]:
    the ``p`` inverses ``M x M``, the rank-one buffers ``p x M x 2 block``, a block's kernel
    columns and the slots' data, in float64."""
    return 8.0 * (p * M * M + 3 * p * M * block + M * (d + 2 * p + 1))


def dictionary_bytes(M: int, p: int, d: int) -> float:
    """Memory of a dictionary of ``M`` points kept by diverse selection and fitted by an exact GP
    (``p`` outputs, ``d`` inputs) [bytes]: the selector (:func:`selector_bytes`) and, per output,
    the GP's kernel matrix and its Cholesky factor."""
    return selector_bytes(M, p, d) + 16.0 * p * M * M


def select_diverse(
    hyper: GPHyper, Z: np.ndarray, Y: np.ndarray, M: int, outlier_kappa: float | None = 4.0,
    initial: tuple[np.ndarray, np.ndarray] | None = None, what: str = "the dictionary size",
) -> tuple[np.ndarray, np.ndarray, SelectionStats]:
    """Convenience: stream ``(Z, Y)`` into a dictionary (optionally starting from ``initial``).

    The dictionary never holds more points than it is given, so its slots are made for at most
    that many (``M`` beyond the data keeps all of it, at the cost of the data, not of ``M``); if
    even those do not fit in memory, an InputError names ``what`` (the option that set ``M``).
    """
    from gprace.resources import check_size

    n = (len(initial[0]) if initial is not None else 0) + len(Z)
    M = max(1, min(int(M), n))
    check_size(f"{what}: a diverse dictionary of {M:,} points", M, lambda m: selector_bytes(m, hyper.p, hyper.d),
               " points")
    sel = DiverseSelector(hyper, M, outlier_kappa)
    if initial is not None and len(initial[0]):
        Zi, Yi = initial
        if Zi.shape[0] <= M:
            sel.initialize(Zi, Yi)
        else:
            Z, Y = np.concatenate([Zi, Z]), np.concatenate([Yi, Y])
    sel.update(Z, Y)
    return sel.Z, sel.Y, sel.stats


__all__ = [
    "DiverseSelector", "SelectionStats", "random_subsample", "reservoir_merge", "select_diverse", "selector_bytes",
    "dictionary_bytes",
]
