"""Marginal-likelihood objectives with analytic gradients (pure functions, normalised data).

Hyperparameter vector for one output: ``theta = [log ls_1..log ls_d, log sf2, log sn2]`` (length
scales, signal variance, noise variance). Both functions return ``(value, gradient)`` of the
quantity to *maximise*. Outputs ``y (n,)``, or ``(n, q)`` for ``q`` outputs that share one kernel
and noise: the value is then the sum of the ``q`` single-output values (one factorisation serves
all columns).

- :func:`exact_lml`: ``log N(y | 0, K + sn2 I)``; O(n^3), used by tests and small fits.
- :func:`vfe_bound`: Titsias' (2009) variational lower bound for inducing inputs ``Zu``,
  ``log N(y | 0, Qff + sn2 I) - tr(Kff - Qff) / (2 sn2)`` with ``Qff = Kfu Kuu^-1 Kuf``,
  in O(n m^2) time and O(n m) memory. With ``Zu`` equal to the data it equals :func:`exact_lml`
  (up to the jitter on ``Kuu``).

Derivation of the VFE gradient (``A = Lu^-1 Kuf / sn``, ``B = I + A A^T``, ``Kuu = Lu Lu^T``):
with ``Sigma = Qff + sn2 I`` and ``beta = Sigma^-1 y``, the derivatives of the bound with respect
to the kernel blocks are ``dF/dKuf = (H beta) beta^T + Lu^-T (I - B^-1) A / sn`` and
``dF/dKuu = -(H beta)(H beta)^T / 2 + Lu^-T (2I - B^-1 - B) Lu^-1 / 2`` with
``H beta = Lu^-T B^-1 A y / sn``; they are contracted with the elementwise kernel derivatives
of :mod:`gprace.gp.kernels`, so no n x n matrix is ever formed.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_solve, solve_triangular

from gprace.gp.kernels import kernel_and_grad_factor, scaled_sqdiff
from gprace.gp.linalg import cholesky

_LOG2PI = float(np.log(2.0 * np.pi))


def _unpack(theta: np.ndarray, d: int) -> tuple[np.ndarray, float, float]:
    theta = np.asarray(theta, dtype=float)
    return np.exp(theta[:d]), float(np.exp(theta[d])), float(np.exp(theta[d + 1]))


def exact_lml(kernel_name: str, theta: np.ndarray, Z: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """Exact log marginal likelihood of ``y (n,)`` or ``(n, q)`` at inputs ``Z (n, d)`` and its gradient."""
    n, d = Z.shape
    y = np.asarray(y, dtype=float).reshape(n, -1)
    q = y.shape[1]
    ls, sf2, sn2 = _unpack(theta, d)
    K, F = kernel_and_grad_factor(kernel_name, Z, Z, ls, sf2)
    Ky = K.copy()
    Ky[np.diag_indices(n)] += sn2
    L = cholesky(Ky, "exact GP kernel matrix")
    alpha = cho_solve((L, True), y, check_finite=False)
    value = -0.5 * float(np.sum(y * alpha)) - q * (float(np.log(np.diag(L)).sum()) + 0.5 * n * _LOG2PI)
    W = alpha @ alpha.T - q * cho_solve((L, True), np.eye(n), check_finite=False)  # dF/dKy * 2
    grad = np.empty(d + 2)
    for j in range(d):
        grad[j] = 0.5 * float(np.sum(W * F * scaled_sqdiff(Z, Z, ls, j)))
    grad[d] = 0.5 * float(np.sum(W * K))
    grad[d + 1] = 0.5 * sn2 * float(np.trace(W))
    return value, grad


def vfe_bound(
    kernel_name: str,
    theta: np.ndarray,
    Z: np.ndarray,
    y: np.ndarray,
    Zu: np.ndarray,
    jitter: float = 1e-6,
) -> tuple[float, np.ndarray]:
    """Titsias' collapsed VFE bound and its gradient.

    ``Z (n, d)`` data inputs, ``y (n,)`` or ``(n, q)`` outputs, ``Zu (m, d)`` inducing inputs
    (fixed). ``jitter`` is relative to the signal variance: ``Kuu + jitter * sf2 * I``.
    """
    n, d = Z.shape
    y = np.asarray(y, dtype=float).reshape(n, -1)
    q = y.shape[1]
    m = Zu.shape[0]
    ls, sf2, sn2 = _unpack(theta, d)
    sn = np.sqrt(sn2)
    Kuu, Fuu = kernel_and_grad_factor(kernel_name, Zu, Zu, ls, sf2)
    Kuu[np.diag_indices(m)] += jitter * sf2
    Kuf, Fuf = kernel_and_grad_factor(kernel_name, Zu, Z, ls, sf2)
    Lu = cholesky(Kuu, "inducing-point kernel matrix")
    A = solve_triangular(Lu, Kuf, lower=True, check_finite=False)
    A /= sn
    AAT = A @ A.T
    B = AAT + np.eye(m)
    LB = cholesky(B, "VFE matrix B")
    Ay = A @ y
    c = solve_triangular(LB, Ay, lower=True, check_finite=False) / sn
    trAAT = float(np.trace(AAT))
    value = (
        q * (-0.5 * n * _LOG2PI - float(np.log(np.diag(LB)).sum()) - 0.5 * n * np.log(sn2)
             - 0.5 * n * sf2 / sn2 + 0.5 * trAAT)
        - 0.5 * float(np.sum(y * y)) / sn2
        + 0.5 * float(np.sum(c * c))
    )

    Binv = cho_solve((LB, True), np.eye(m), check_finite=False)
    v1 = Binv @ Ay
    beta = (y - A.T @ v1) / sn2
    Hb = solve_triangular(Lu, v1, lower=True, trans="T", check_finite=False) / sn
    R = A - Binv @ A
    Duf = solve_triangular(Lu, R, lower=True, trans="T", check_finite=False)
    Duf *= q / sn
    Duf += Hb @ beta.T
    X = 2.0 * np.eye(m) - Binv - B
    S = solve_triangular(Lu, X, lower=True, trans="T", check_finite=False)  # Lu^-T X
    S = solve_triangular(Lu, S.T, lower=True, trans="T", check_finite=False)  # Lu^-T X Lu^-1
    Duu = 0.25 * q * (S + S.T) - 0.5 * (Hb @ Hb.T)

    grad = np.empty(d + 2)
    DufF = Duf * Fuf
    DuuF = Duu * Fuu
    for j in range(d):
        grad[j] = float(np.sum(DufF * scaled_sqdiff(Zu, Z, ls, j))) + float(np.sum(DuuF * scaled_sqdiff(Zu, Zu, ls, j)))
    grad[d] = float(np.sum(Duf * Kuf)) + float(np.sum(Duu * Kuu)) - 0.5 * q * n * sf2 / sn2
    dsn2 = (
        0.5 * float(np.sum(beta * beta))
        - 0.5 * q * (n - m + float(np.trace(Binv))) / sn2
        + 0.5 * q * (n * sf2 - sn2 * trAAT) / sn2**2
    )
    grad[d + 1] = sn2 * dsn2
    return float(value), grad
