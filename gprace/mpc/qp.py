"""The tracking QP (paper eq. "mpc_problem") as data, its sparse standard form, and solver results.

Decision variables, written **relative to the current position** (progress ``s`` measured from
the car, so every number in the QP is of the size of the deviations it controls; docs/reference.md#measured:
absolute progress made Clarabel report "Solved" with errors of 5e-2 m/s^2):

    z = [u_0 .. u_{N-1} (2N), x_1 .. x_N (6N), eps_1 .. eps_N (N), eta_1 .. eta_N (N)]

    min  sum_{k=1..N} |x_k - xref_k|_Q^2 + sum_{k=0..N-1} |u_k - uref_k|_R^2
         + r_delta sum_{k=0..N-1} (delta_k - delta_{k-1})^2 + r_accel sum_{k=0..N-1} (a_k - a_{k-1})^2
         + rho_1 sum eps_k + rho_2 sum eps_k^2
         + rho_g1 sum eta_k + rho_g2 sum eta_k^2
    s.t. x_{k+1} = A_k x_k + B_k u_k + c_k              (x_0 given; c_k holds the GP mean)
         u_lo <= u_k <= u_hi
         ey_lo_k - eps_k <= e_y,k <= ey_hi_k + eps_k,  eps_k >= 0
         g_lo_k - eta_k <= G_k x_k <= g_hi_k + eta_k,   eta_k >= 0   (grip row, see below)
         |delta_k - delta_{k-1}| <= steer_step               (the actuator's rate limit)

The grip row ``G_k x_k`` (only ``v_x, v_y, yaw_rate`` enter) is the linearised rear slip angle of
the tracking MPC (:mod:`gprace.mpc.tracking`), softened by its own slack ``eta``. A problem
without a grip constraint leaves ``G_k = 0`` and wide bounds: the structure is always the same.

``delta_{-1}`` and ``a_{-1}`` are the last applied steering angle and acceleration command. The
``r_accel`` term is beyond the paper: without it the QP switched between full braking and full
drive within 0.2 s in a fast chicane, which locked the rear wheels of the commonroad BMW. The lateral bounds are soft (exact L1 penalty
``rho_1`` large): a racing MPC must return an input even when a disturbance has already pushed the
car past a tightened bound. ``Q`` and ``R`` are diagonal.

The steering-rate rows are beyond the paper too: the commonroad BMW's servo turns at most
0.4 rad/s, and a QP that did not know it asked for reversals of 0.2 rad within 0.4 s in the
S-bend of gprace_ring, so its predictions assumed a wheel the car cannot turn. (The spin there had
another cause, the curvature held constant over a step: :mod:`gprace.mpc.tracking`.) They are
hard: ``delta_k = delta_{-1}`` always satisfies them. ``steer_step = None`` leaves them open
(``STEER_OPEN``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import Field
from scipy import sparse

from gprace.config import Frozen
from gprace.model.dynamics import NU as NUS
from gprace.model.dynamics import NX as NXS
from gprace.model.dynamics import State
from gprace.solvers import SolveStatus, all_finite

EY = State.E_Y
GRIP_STATES = (State.V_X, State.V_Y, State.YAW_RATE)  # state entries a grip row may weigh
GRIP_OPEN = 1.0          # bound of an inactive grip row (its coefficients are zero)
STEER_OPEN = 10.0        # steering change per step [rad] of an open rate row
ETA_UNIT = 0.01          # the grip slack's unit in the standard form [rad]: keeps its weights near the others


QPStatus = SolveStatus  # the name the MPC and its backends have always used


@dataclass
class QPResult:
    status: QPStatus
    x: np.ndarray            # (N, 6) predicted states x_1..x_N (relative s)
    u: np.ndarray            # (N, 2) inputs u_0..u_{N-1}
    eps: np.ndarray          # (N,) slack of the lateral bounds
    objective: float = np.nan
    solve_time: float = 0.0  # wall time of the backend call [s]
    iterations: int = 0
    message: str = ""


class Weights(Frozen):
    """Diagonal weights of the tracking cost."""

    Q: tuple[float, float, float, float, float, float] = Field(
        (1.0, 2.0, 20.0, 200.0, 20.0, 0.5), description="state weights: v_x, v_y, yaw_rate, e_psi, e_y, s")
    R: tuple[float, float] = Field((20.0, 0.02), description="input weights: delta, a_x")
    r_delta: float = Field(2000.0, ge=0, description="weight of (delta_k - delta_{k-1})^2")
    r_accel: float = Field(0.5, ge=0, description="weight of (a_k - a_{k-1})^2")
    slack_l1: float = Field(2000.0, ge=0, description="linear penalty of the border slack")
    slack_l2: float = Field(2000.0, ge=0, description="quadratic penalty of the border slack")
    grip_l1: float = Field(1e5, ge=0, description="linear penalty of the grip rows' slack (per rad of rear slip "
                           "beyond its bound): an exact penalty")
    grip_l2: float = Field(1e6, ge=0, description="quadratic penalty of the grip rows' slack")


@dataclass
class LtvProblem:
    """One QP instance: LTV data over the horizon, references and bounds (all relative to the car)."""

    A: np.ndarray         # (N, 6, 6)
    B: np.ndarray         # (N, 6, 2)
    c: np.ndarray         # (N, 6)
    x0: np.ndarray        # (6,)
    xref: np.ndarray      # (N, 6) for k = 1..N
    uref: np.ndarray      # (N, 2) for k = 0..N-1
    ey_lo: np.ndarray     # (N,)
    ey_hi: np.ndarray     # (N,)
    u_lo: np.ndarray      # (2,)
    u_hi: np.ndarray      # (2,)
    delta_prev: float
    weights: Weights = field(default_factory=Weights)
    grip_G: np.ndarray | None = None   # (N, 6) grip row per step (None: no grip constraint)
    grip_lo: np.ndarray | None = None  # (N,)
    grip_hi: np.ndarray | None = None  # (N,)
    a_prev: float = 0.0                # last applied acceleration command (for the r_accel term)
    steer_step: float | None = None    # largest steering change per step [rad] (rate limit x dt)

    @property
    def N(self) -> int:
        return self.A.shape[0]

    def finite(self) -> bool:
        """True when the dynamics and references are finite numbers (a model that blew up is a
        failed solve, reported before any backend sees it)."""
        return all_finite(self.A, self.B, self.c, self.x0, self.xref, self.uref)

    def grip(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(G (N, 6), lo (N,), hi (N,))`` of the grip rows (inactive rows if there are none)."""
        N = self.N
        if self.grip_G is None:
            return np.zeros((N, NXS)), np.full(N, -GRIP_OPEN), np.full(N, GRIP_OPEN)
        return np.asarray(self.grip_G, float), np.asarray(self.grip_lo, float), np.asarray(self.grip_hi, float)


def nonfinite_result(pb: LtvProblem, backend: str) -> QPResult | None:
    """The FAILED result of a problem with non-finite data, or None when the data are finite."""
    return None if pb.finite() else fail_result(pb.N, QPStatus.FAILED, f"{backend}: non-finite problem data")


def fail_result(N: int, status: QPStatus, message: str, solve_time: float = 0.0) -> QPResult:
    return QPResult(status, np.full((N, NXS), np.nan), np.full((N, NUS), np.nan), np.full(N, np.nan),
                    np.nan, solve_time, 0, message)


def grip_bounds(pb: LtvProblem) -> tuple[np.ndarray, np.ndarray]:
    """Right-hand sides ``(hi, -lo)`` of the grip rows (shared by the standard-form backends)."""
    _, lo, hi = pb.grip()
    return hi, -lo


class SparseQP:
    """Standard form ``min 1/2 z'Pz + q'z  s.t.  Aeq z = beq,  G z <= h`` with a FIXED sparsity.

    The structure (which entries of ``A_k``, ``B_k`` exist: all of them, stored even when zero) is
    built once for a horizon ``N``; :meth:`fill` returns the new nonzero values in the stored order,
    so solvers update their matrices in place. ``M = [Aeq; G]`` is stacked for conic solvers.
    """

    def __init__(self, N: int, weights: Weights) -> None:
        self.N = N
        self.weights = weights
        nu, nx = NUS * N, NXS * N
        self.nz = nu + nx + 2 * N
        self.iu = lambda k: k * NUS
        self.ix = lambda k: nu + (k - 1) * NXS  # x_k, k = 1..N
        self.ie = lambda k: nu + nx + (k - 1)
        self.ig = lambda k: nu + nx + N + (k - 1)  # grip slack eta_k
        self.neq = NXS * N
        self.nin = 2 * NUS * N + 3 * N + 3 * N + 2 * N
        self.i_rate = self.neq + self.nin - 2 * N  # first steering-rate row of M
        self._build_P()
        self._build_M()

    # cost -----------------------------------------------------------------------------------
    def _build_P(self) -> None:
        N, w = self.N, self.weights
        Q, R = np.asarray(w.Q, float), np.asarray(w.R, float)
        d = np.zeros(self.nz)
        rows, cols, vals = [], [], []
        for k in range(N):
            d[self.iu(k): self.iu(k) + NUS] += 2 * R
            d[self.ix(k + 1): self.ix(k + 1) + NXS] += 2 * Q
            d[self.ie(k + 1)] += 2 * w.slack_l2
            d[self.ig(k + 1)] += 2 * w.grip_l2 * ETA_UNIT**2
        # input-rate terms r (u_k - u_{k-1})^2 for steering (j = 0) and acceleration (j = 1)
        for j, r in ((0, w.r_delta), (1, w.r_accel)):
            for k in range(N):
                d[self.iu(k) + j] += 2 * r
                if k >= 1:
                    d[self.iu(k - 1) + j] += 2 * r
                    a, b = self.iu(k - 1) + j, self.iu(k) + j
                    rows += [a, b]
                    cols += [b, a]
                    vals += [-2 * r, -2 * r]
        P = sparse.coo_matrix((np.concatenate([d, vals]), (np.concatenate([np.arange(self.nz), rows]),
                                                            np.concatenate([np.arange(self.nz), cols]))),
                              shape=(self.nz, self.nz)).tocsc()
        P.sort_indices()
        self.P = P
        self.P_triu = sparse.triu(P).tocsc()
        self.P_triu.sort_indices()
        self.Qd, self.Rd = Q, R

    def q(self, pb: LtvProblem) -> np.ndarray:
        N, w = self.N, self.weights
        q = np.zeros(self.nz)
        q[: NUS * N] = (-2 * self.Rd * pb.uref).ravel()
        q[NUS * N: NUS * N + NXS * N] = (-2 * self.Qd * pb.xref).ravel()
        q[NUS * N + NXS * N: NUS * N + NXS * N + N] = w.slack_l1
        q[NUS * N + NXS * N + N:] = w.grip_l1 * ETA_UNIT
        q[self.iu(0)] += -2 * w.r_delta * pb.delta_prev
        q[self.iu(0) + 1] += -2 * w.r_accel * pb.a_prev
        return q

    def constant(self, pb: LtvProblem) -> float:
        """Cost terms that do not depend on z (so objectives compare across backends)."""
        w = self.weights
        return float(np.sum(self.Qd * pb.xref**2) + np.sum(self.Rd * pb.uref**2) + w.r_delta * pb.delta_prev**2
                     + w.r_accel * pb.a_prev**2)

    # constraints ----------------------------------------------------------------------------
    def _build_M(self) -> None:
        """Pattern of ``M = [Aeq; G]``; values come from a flat vector through ``self._perm``."""
        N = self.N
        rows, cols, src = [], [], []  # src: index into the value vector of fill()
        self._n_val = 0

        def add(r, c, n_src):
            rows.append(r)
            cols.append(c)
            src.append(n_src)

        # value vector layout: [ones for x_{k+1} (6N)] [-A_k entries k>=1 (36(N-1))] [-B_k entries (12N)] [G values]
        off_I = 0
        off_A = off_I + NXS * N
        off_B = off_A + NXS * NXS * (N - 1)
        off_G = off_B + NXS * NUS * N
        for k in range(N):
            r0 = k * NXS
            for i in range(NXS):
                add(r0 + i, self.ix(k + 1) + i, off_I + k * NXS + i)
            if k >= 1:
                for i in range(NXS):
                    for j in range(NXS):
                        add(r0 + i, self.ix(k) + j, off_A + (k - 1) * 36 + i * NXS + j)
            for i in range(NXS):
                for j in range(NUS):
                    add(r0 + i, self.iu(k) + j, off_B + k * NXS * NUS + i * NUS + j)
        g = self.neq
        gvals = []
        # input bounds: u <= hi ; -u <= -lo
        for k in range(N):
            for j in range(NUS):
                add(g, self.iu(k) + j, off_G + len(gvals)); gvals.append(1.0); g += 1
                add(g, self.iu(k) + j, off_G + len(gvals)); gvals.append(-1.0); g += 1
        # lateral: e_y - eps <= hi ; -e_y - eps <= -lo ; -eps <= 0
        for k in range(1, N + 1):
            add(g, self.ix(k) + EY, off_G + len(gvals)); gvals.append(1.0)
            add(g, self.ie(k), off_G + len(gvals)); gvals.append(-1.0); g += 1
            add(g, self.ix(k) + EY, off_G + len(gvals)); gvals.append(-1.0)
            add(g, self.ie(k), off_G + len(gvals)); gvals.append(-1.0); g += 1
            add(g, self.ie(k), off_G + len(gvals)); gvals.append(-1.0); g += 1
        # grip: G_k x_k - eta <= hi ; -G_k x_k - eta <= -lo ; -eta <= 0 (G values after the fixed ones)
        # the eta entries and the steering-rate entries below are fixed values too; the grip
        # coefficients (filled per problem) come after them
        off_S = off_G + len(gvals) + 3 * N + (4 * N - 2)
        gfix = []
        for k in range(1, N + 1):
            for sign, row in ((1, 0), (-1, 1)):
                for j, st in enumerate(GRIP_STATES):
                    add(g + row, self.ix(k) + st, off_S + (k - 1) * 6 + row * 3 + j)
            for row in range(3):
                add(g + row, self.ig(k), off_G + len(gvals) + len(gfix)); gfix.append(-ETA_UNIT)
            g += 3
        gvals += gfix
        # steering rate: delta_k - delta_{k-1} <= d ; -(delta_k - delta_{k-1}) <= d (delta_{-1} in b)
        # (fixed values: stored after the grip-row entries, see _values_base)
        rfix = []
        for k in range(N):
            for sign in (1.0, -1.0):
                add(g, self.iu(k), off_G + len(gvals) + len(rfix)); rfix.append(sign)
                if k >= 1:
                    add(g, self.iu(k - 1), off_G + len(gvals) + len(rfix)); rfix.append(-sign)
                g += 1
        gvals += rfix
        self._gvals = np.array(gvals)
        self._off = (off_I, off_A, off_B, off_G)
        self._off_S = off_S
        nval = off_S + 6 * N
        M = sparse.coo_matrix((np.arange(1, len(rows) + 1, dtype=float), (rows, cols)), shape=(self.neq + self.nin, self.nz)).tocsc()
        M.sort_indices()
        order = M.data.astype(int) - 1          # position in the (rows, cols, src) lists
        self._perm = np.asarray(src)[order]     # value-vector index of each stored entry
        self._nval = nval
        M.data = self._values_base()[self._perm]
        self.M = M

    def _values_base(self) -> np.ndarray:
        v = np.zeros(self._nval)
        off_I, _, _, off_G = self._off
        v[off_I: off_I + NXS * self.N] = 1.0
        v[off_G: off_G + len(self._gvals)] = self._gvals
        return v

    def fill(self, pb: LtvProblem) -> tuple[np.ndarray, np.ndarray]:
        """``(M.data, b)`` for this problem: new nonzero values (stored order) and right-hand side."""
        N = self.N
        v = self._values_base()
        _, off_A, off_B, _ = self._off
        v[off_A: off_A + 36 * (N - 1)] = -pb.A[1:].reshape(-1)
        v[off_B: off_B + 12 * N] = -pb.B.reshape(-1)
        G, _, _ = pb.grip()
        Gs = G[:, GRIP_STATES]
        v[self._off_S:] = np.concatenate([Gs, -Gs], axis=1).reshape(-1)
        beq = pb.c.copy()
        beq[0] += pb.A[0] @ pb.x0
        hu = np.empty((N, NUS, 2))
        hu[:, :, 0] = pb.u_hi
        hu[:, :, 1] = -pb.u_lo
        hl = np.column_stack([pb.ey_hi, -pb.ey_lo, np.zeros(N)])
        hg = np.column_stack([*grip_bounds(pb), np.zeros(N)])
        d = STEER_OPEN if pb.steer_step is None else float(pb.steer_step)
        hr = np.full((N, 2), d)
        hr[0] += [pb.delta_prev, -pb.delta_prev]
        b = np.concatenate([beq.ravel(), hu.ravel(), hl.ravel(), hg.ravel(), hr.ravel()])
        return v[self._perm], b

    def unpack(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        N = self.N
        u = z[: NUS * N].reshape(N, NUS)
        x = z[NUS * N: NUS * N + NXS * N].reshape(N, NXS)
        eps = z[NUS * N + NXS * N: NUS * N + NXS * N + N]
        return x, u, eps


def check_result(res: QPResult, tol: float = 1e6) -> QPResult:
    """Demote a 'solved' result with non-finite or absurd numbers to FAILED."""
    if res.status.usable and (not np.all(np.isfinite(res.u)) or not np.all(np.isfinite(res.x)) or np.max(np.abs(res.u)) > tol):
        res.status = QPStatus.FAILED
        res.message = (res.message + "; non-finite solution").strip("; ")
    return res
