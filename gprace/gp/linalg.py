"""Small dense linear-algebra helpers shared by the GP backends and the data selection."""

from __future__ import annotations

import numpy as np

from gprace.errors import SolverError

_JITTERS = (0.0, 1e-10, 1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4)


def cholesky(K: np.ndarray, what: str = "kernel matrix") -> np.ndarray:
    """Lower Cholesky factor of a symmetric positive (semi)definite ``K``.

    If ``K`` is numerically indefinite (duplicate inputs with tiny noise), a growing jitter
    relative to the mean diagonal is added, up to 1e-4; beyond that a :class:`SolverError`
    suggests what to change.
    """
    scale = float(np.mean(np.diag(K))) if K.size else 1.0
    if not np.isfinite(scale) or scale <= 0.0:
        scale = 1.0
    for jit in _JITTERS:
        try:
            if jit == 0.0:
                return np.linalg.cholesky(K)
            Kj = K.copy()
            Kj[np.diag_indices_from(Kj)] += jit * scale
            return np.linalg.cholesky(Kj)
        except np.linalg.LinAlgError:
            continue
    raise SolverError(
        f"{what} ({K.shape[0]} x {K.shape[0]}) is not positive definite even with jitter 1e-4; "
        "raise the noise lower bound or remove duplicate inputs"
    )


def pack_lower(L: np.ndarray) -> np.ndarray:
    """The lower triangle of a square matrix, row by row, as a 1-D array."""
    return L[np.tril_indices(L.shape[0])]


def unpack_lower(packed: np.ndarray, n: int) -> np.ndarray:
    """Inverse of :func:`pack_lower`: a C-contiguous lower-triangular ``(n, n)`` matrix."""
    L = np.zeros((n, n))
    L[np.tril_indices(n)] = packed
    return L
