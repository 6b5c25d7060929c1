"""Choice of inducing inputs from the data (for the ``sparse`` backend)."""

from __future__ import annotations

import numpy as np


def unique_rows(Z: np.ndarray) -> np.ndarray:
    """Indices of the first occurrence of each distinct row, in data order."""
    _, first = np.unique(Z, axis=0, return_index=True)
    return np.sort(first)


def kmeanspp_indices(Z: np.ndarray, m: int, seed: int = 0) -> np.ndarray:
    """Indices of ``m`` rows of ``Z (n, d)`` spread over the data (k-means++ seeding).

    Each new point is drawn with probability proportional to its squared distance from the
    points already chosen, so dense regions get more points and no region is left empty.
    With ``n <= m`` all distinct rows are returned; duplicates are never chosen twice.
    """
    n = Z.shape[0]
    if n <= m:
        return unique_rows(Z)
    rng = np.random.default_rng(seed)
    chosen = np.empty(m, dtype=np.int64)
    chosen[0] = rng.integers(n)
    d2 = np.sum((Z - Z[chosen[0]]) ** 2, axis=1)
    k = 1
    while k < m:
        total = float(d2.sum())
        if total <= 0.0:  # fewer distinct rows than m
            break
        c = np.cumsum(d2)
        i = int(np.searchsorted(c, rng.random() * c[-1], side="right"))
        i = min(i, n - 1)
        if d2[i] <= 0.0:
            continue
        chosen[k] = i
        np.minimum(d2, np.sum((Z - Z[i]) ** 2, axis=1), out=d2)
        k += 1
    return np.sort(chosen[:k])
