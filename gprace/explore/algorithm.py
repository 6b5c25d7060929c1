"""Paper Algorithm 1: choose the target GP feature ``z_ref`` among candidates.

Candidates ``{z^(i)}`` are built combinatorially from typical values of each controllable
feature seen in previous data (:func:`candidate_grid`); their weighted posterior variances
``v_i = ||Sigma(z^(i))||_S^2`` are computed once after each retrain (``CandidateGrid.variance``).
At run time :func:`select_target` ranks the candidates by distance to the feature the
performance objective would visit (``D_i``: rank in the list sorted by distance, so the nearest
gets the LARGEST score when ranks are reversed as below) and by weighted variance (``V_i``), and
picks ``argmax_i alpha V_i + (1 - alpha) D_i``.

Rank convention (the paper leaves the direction implicit): ``V_i`` is the position in the list
sorted by ascending variance (largest variance -> largest V), ``D_i`` the position in the list
sorted by descending distance (nearest -> largest D). Hence alpha = 0 returns the nearest
candidate and alpha = 1 the most uncertain one; ``reverse_distance=True`` (head-to-head stalemate
breaking) flips the distance ranking so the farthest configuration is preferred.
With alpha = 0 callers skip the reference update entirely, which reproduces plain tracking.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CandidateGrid:
    """Candidates ``Z`` (n_G, d), their weighted variances ``v`` (n_G,) and feature scales."""

    Z: np.ndarray
    v: np.ndarray
    scale: np.ndarray  # per-feature scale used in the distance (std of the data)


def candidate_grid(samples: np.ndarray, n_values: int | list[int] = 7, quantiles: tuple[float, float] = (0.02, 0.98)) -> np.ndarray:
    """Combinatorial grid of typical values: ``n_values`` quantiles per feature of ``samples`` (n, d)."""
    samples = np.asarray(samples, dtype=float)
    d = samples.shape[1]
    counts = [n_values] * d if isinstance(n_values, int) else list(n_values)
    axes = [np.quantile(samples[:, j], np.linspace(quantiles[0], quantiles[1], counts[j])) for j in range(d)]
    return np.array(list(itertools.product(*axes)), dtype=float)


def weighted_variance(var: np.ndarray, S: np.ndarray | None = None) -> np.ndarray:
    """``v_i = ||Sigma(z_i)||_S^2`` for diagonal GP covariances ``var`` (n, p): ``sum_j S_jj var_ij^2``."""
    var = np.asarray(var, dtype=float)
    w = np.ones(var.shape[1]) if S is None else np.diag(np.atleast_2d(S)) if np.ndim(S) == 2 else np.asarray(S, dtype=float)
    return (var**2) @ w


def _ranks(values: np.ndarray) -> np.ndarray:
    """Position (0-based) of each entry in the ascending sort (ties broken by index)."""
    r = np.empty(len(values), dtype=float)
    r[np.argsort(values, kind="stable")] = np.arange(len(values))
    return r


def select_target(grid: CandidateGrid, z_tilde: np.ndarray, alpha: float, reverse_distance: bool = False) -> int:
    """Index ``i*`` of the target candidate for the performance feature ``z_tilde`` (d,)."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    d = np.linalg.norm((grid.Z - np.asarray(z_tilde)) / grid.scale, axis=1)
    D = _ranks(d) if reverse_distance else _ranks(-d)
    V = _ranks(grid.v)
    return int(np.argmax(alpha * V + (1.0 - alpha) * D))
