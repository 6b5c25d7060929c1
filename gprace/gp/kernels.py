"""Stationary covariance functions with ARD length scales, as pure vectorised functions.

All functions work on inputs that are already normalised (see :class:`gprace.gp.base.GPHyper`)
and take the hyperparameters as plain values:

- ``ls``: length scales, shape ``(d,)``;
- ``sf2``: signal variance (the kernel's value at distance 0).

Kernels (``r`` is the ARD-scaled distance ``sqrt(sum_j (a_j - b_j)^2 / ls_j^2)``):

- ``"se"``: squared exponential ``sf2 * exp(-r^2 / 2)``;
- ``"matern15"``: Matern nu = 1.5, ``sf2 * (1 + sqrt(3) r) * exp(-sqrt(3) r)``.

For gradients, ``dK/dlog(ls_j) = grad_factor(...) * (a_j - b_j)^2 / ls_j^2`` (elementwise); the
factor is ``K`` for ``se`` and ``3 sf2 exp(-sqrt(3) r)`` for ``matern15``, which stays finite at
``r = 0``. ``dK/dlog(sf2) = K``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

KernelName = Literal["se", "matern15"]
KERNELS: tuple[str, ...] = ("se", "matern15")
_SQRT3 = float(np.sqrt(3.0))


def check_kernel(name: str) -> str:
    if name not in KERNELS:
        from gprace.errors import ConfigError

        raise ConfigError(f"unknown kernel {name!r}; available: {', '.join(KERNELS)}")
    return name


def sqdist(A: np.ndarray, B: np.ndarray, ls: np.ndarray) -> np.ndarray:
    """Squared ARD-scaled distances ``(n, m)`` between rows of ``A (n, d)`` and ``B (m, d)``."""
    a = A / ls
    b = B / ls
    d2 = np.einsum("ij,ij->i", a, a)[:, None] + np.einsum("ij,ij->i", b, b)[None, :]
    d2 -= 2.0 * (a @ b.T)
    np.maximum(d2, 0.0, out=d2)
    return d2


def from_sqdist(name: str, d2: np.ndarray, sf2: float) -> np.ndarray:
    """Kernel values from squared ARD-scaled distances ``d2``, computed in place: ``d2`` (a float
    array the caller no longer needs) is overwritten and returned (one allocation fewer per pass:
    the kernel block is a fifth of an opponent rollout)."""
    if name == "se":
        d2 *= -0.5
        np.exp(d2, out=d2)
    else:
        np.sqrt(d2, out=d2)
        d2 *= -_SQRT3  # -r
        e = np.exp(d2)
        np.subtract(1.0, d2, out=d2)  # 1 + r
        d2 *= e
    d2 *= sf2
    return d2


def scaled_block(name: str, b: np.ndarray, a: np.ndarray, a2: np.ndarray, sf2: float) -> np.ndarray:
    """Kernel ``(m, M)`` between queries ``b (m, d)`` and points ``a (M, d)``, both already divided
    by the length scales, with the points' squared norms ``a2 (M,)`` cached (repeated queries)."""
    d2 = np.einsum("ij,ij->i", b, b)[:, None] + a2[None, :]
    d2 -= 2.0 * (b @ a.T)
    np.maximum(d2, 0.0, out=d2)
    return from_sqdist(name, d2, sf2)


def kernel(name: str, A: np.ndarray, B: np.ndarray, ls: np.ndarray, sf2: float) -> np.ndarray:
    """Covariance matrix ``(n, m)`` of kernel ``name`` between ``A (n, d)`` and ``B (m, d)``."""
    return from_sqdist(name, sqdist(A, B, ls), sf2)


def kernel_and_grad_factor(
    name: str, A: np.ndarray, B: np.ndarray, ls: np.ndarray, sf2: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(K, F)`` with ``dK/dlog(ls_j) = F * (A[:, j, None] - B[None, :, j])**2 / ls_j**2``."""
    d2 = sqdist(A, B, ls)
    if name == "se":
        K = np.exp(-0.5 * d2)
        K *= sf2
        return K, K
    r = np.sqrt(d2)
    r *= _SQRT3
    e = np.exp(-r)
    K = (1.0 + r) * e
    K *= sf2
    e *= 3.0 * sf2
    return K, e


def scaled_sqdiff(A: np.ndarray, B: np.ndarray, ls: np.ndarray, j: int) -> np.ndarray:
    """``(A[:, j] - B[:, j])^2 / ls_j^2`` as an ``(n, m)`` array."""
    diff = (A[:, j, None] - B[None, :, j]) / ls[j]
    diff *= diff
    return diff
