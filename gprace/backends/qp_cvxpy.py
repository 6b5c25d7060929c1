"""``cvxpy-clarabel`` QP backend: the readable reference formulation in CVXPY, parametrised (DPP).

The problem is written as in the paper, stage by stage, with the LTV matrices, references and
bounds as CVXPY parameters: CVXPY compiles it once and each call only stuffs the new parameter
values before Clarabel solves it.
"""

from __future__ import annotations

import time

import numpy as np

from gprace.mpc.qp import EY, NUS, NXS, STEER_OPEN, LtvProblem, QPResult, QPStatus, Weights, check_result, fail_result, nonfinite_result
from gprace.solvers import cvxpy_status


class CvxpyClarabelQP:
    name = "cvxpy-clarabel"

    def __init__(self, N: int, weights: Weights = Weights()) -> None:
        import cvxpy as cp

        self.cp = cp
        self.N = N
        self.weights = w = weights
        self.A = [cp.Parameter((NXS, NXS)) for _ in range(N)]
        self.B = [cp.Parameter((NXS, NUS)) for _ in range(N)]
        self.c = cp.Parameter((N, NXS))
        self.Ax0 = cp.Parameter(NXS)  # A_0 x_0, computed outside (a parameter times a parameter is not DPP)
        self.xref = cp.Parameter((N, NXS))
        self.uref = cp.Parameter((N, NUS))
        self.ey_lo = cp.Parameter(N)
        self.ey_hi = cp.Parameter(N)
        self.u_lo = cp.Parameter(NUS)
        self.u_hi = cp.Parameter(NUS)
        self.delta_prev = cp.Parameter()
        self.a_prev = cp.Parameter()
        self.grip_G = cp.Parameter((N, NXS))
        self.grip_lo = cp.Parameter(N)
        self.grip_hi = cp.Parameter(N)
        self.steer_step = cp.Parameter(nonneg=True)
        x = cp.Variable((N, NXS))      # x_1 .. x_N
        u = cp.Variable((N, NUS))      # u_0 .. u_{N-1}
        eps = cp.Variable(N)           # lateral slack
        eta = cp.Variable(N)           # grip slack
        self.x, self.u, self.eps = x, u, eps
        sq, sr = np.sqrt(np.asarray(w.Q, float)), np.sqrt(np.asarray(w.R, float))
        cost = cp.sum_squares(cp.multiply(x - self.xref, np.tile(sq, (N, 1))))
        cost += cp.sum_squares(cp.multiply(u - self.uref, np.tile(sr, (N, 1))))
        steer = cp.hstack([u[0, 0] - self.delta_prev, u[1:, 0] - u[:-1, 0]])
        cost += w.r_delta * cp.sum_squares(steer)
        accel = cp.hstack([u[0, 1] - self.a_prev, u[1:, 1] - u[:-1, 1]])
        cost += w.r_accel * cp.sum_squares(accel)
        cost += w.slack_l1 * cp.sum(eps) + w.slack_l2 * cp.sum_squares(eps)
        cost += w.grip_l1 * cp.sum(eta) + w.grip_l2 * cp.sum_squares(eta)
        cons = []
        cons.append(x[0] == self.Ax0 + self.B[0] @ u[0] + self.c[0])
        for k in range(1, N):
            cons.append(x[k] == self.A[k] @ x[k - 1] + self.B[k] @ u[k] + self.c[k])
        cons += [u <= np.ones((N, 1)) @ cp.reshape(self.u_hi, (1, NUS), order="C"),
                 u >= np.ones((N, 1)) @ cp.reshape(self.u_lo, (1, NUS), order="C")]
        cons += [x[:, EY] <= self.ey_hi + eps, x[:, EY] >= self.ey_lo - eps, eps >= 0]
        grip = cp.sum(cp.multiply(self.grip_G, x), axis=1)  # G_k x_k per step
        cons += [grip <= self.grip_hi + eta, grip >= self.grip_lo - eta, eta >= 0]
        cons += [steer <= self.steer_step, steer >= -self.steer_step]
        self.problem = cp.Problem(cp.Minimize(cost), cons)

    def solve(self, pb: LtvProblem) -> QPResult:
        cp = self.cp
        bad = nonfinite_result(pb, "cvxpy-clarabel")
        if bad is not None:
            return bad
        t0 = time.perf_counter()
        for k in range(self.N):
            self.A[k].value = pb.A[k]
            self.B[k].value = pb.B[k]
        self.c.value, self.Ax0.value = pb.c, pb.A[0] @ pb.x0
        self.xref.value, self.uref.value = pb.xref, pb.uref
        self.ey_lo.value, self.ey_hi.value = pb.ey_lo, pb.ey_hi
        self.u_lo.value, self.u_hi.value = pb.u_lo, pb.u_hi
        self.delta_prev.value = pb.delta_prev
        self.steer_step.value = STEER_OPEN if pb.steer_step is None else float(pb.steer_step)
        self.a_prev.value = pb.a_prev
        self.grip_G.value, self.grip_lo.value, self.grip_hi.value = pb.grip()
        try:
            self.problem.solve(solver=cp.CLARABEL, warm_start=False)
        except cp.error.SolverError as exc:  # CVXPY's word for a solver that gave no answer
            return fail_result(self.N, QPStatus.FAILED, f"cvxpy-clarabel: {exc}", time.perf_counter() - t0)
        dt = time.perf_counter() - t0
        st = self.problem.status
        status = cvxpy_status(st)
        if not status.usable:
            return fail_result(self.N, status, f"cvxpy-clarabel: {st}", dt)
        stats = self.problem.solver_stats
        return check_result(QPResult(status, np.asarray(self.x.value), np.asarray(self.u.value), np.asarray(self.eps.value),
                                     float(self.problem.value), dt, int(stats.num_iters or 0), st))
