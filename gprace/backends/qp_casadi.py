"""``casadi`` QP backend: a conic plugin shipped with the casadi wheel (default ``qrqp``).

The QP is handed over in the same sparse standard form as the ``clarabel`` backend: the solver
object is built once per horizon from the sparsity patterns of ``P`` and ``M``; each call passes the
new values. Measured here with casadi 3.8.2: ``qrqp`` (active set) solves every test problem to
1e-6 of Clarabel; ``ipqp`` stopped at its iteration limit ("LDL factorization has zeros in D") on
this formulation although docs/reference.md#measured reports it working on another, so it is selectable
(``CasadiQP(plugin="ipqp")``) but not the default; ``qpoases`` is an order of magnitude slower.
"""

from __future__ import annotations

import time

import numpy as np

from gprace.mpc.qp import LtvProblem, QPResult, QPStatus, SparseQP, Weights, check_result, fail_result, nonfinite_result
from gprace.solvers import conic_status


class CasadiQP:
    name = "casadi"

    def __init__(self, N: int, weights: Weights = Weights(), plugin: str = "qrqp", tol: float = 1e-9) -> None:
        import casadi as ca

        self.ca = ca
        self.form = SparseQP(N, weights)
        self.N = N
        f = self.form
        P = f.P
        # simple bounds (inputs, slack >= 0) go to lbx/ubx; keep the equality, lateral, grip and
        # steering-rate rows of M
        g0 = f.neq
        nub = 2 * 2 * N
        # the two-sided rows of the lateral and grip blocks (their slack >= 0 rows become bounds)
        lat = g0 + nub + np.arange(6 * N).reshape(2 * N, 3)[:, :2].ravel()
        self._rows = np.concatenate([np.arange(g0), lat, f.i_rate + np.arange(2 * N)])
        Mi = f.M.copy()
        Mi.data = np.arange(1, Mi.nnz + 1, dtype=float)
        M = Mi[self._rows, :].tocsc()
        M.sort_indices()
        self._take = M.data.astype(int) - 1
        self._lat = lat
        self._Hsp = ca.Sparsity(P.shape[0], P.shape[1], P.indptr.tolist(), P.indices.tolist())
        self._Asp = ca.Sparsity(M.shape[0], M.shape[1], M.indptr.tolist(), M.indices.tolist())
        opts: dict = {"error_on_fail": False}
        if plugin == "ipqp":
            opts.update({"print_iter": False, "print_header": False, "print_info": False,
                         "constr_viol_tol": tol, "dual_inf_tol": tol})
        elif plugin == "qrqp":
            opts.update({"print_iter": False, "print_header": False, "print_info": False})
        self.plugin = plugin
        self.solver = ca.conic("mpc_qp", plugin, {"h": self._Hsp, "a": self._Asp}, opts)
        self._H = ca.DM(self._Hsp, P.data)
        self._lba = np.concatenate([np.zeros(f.neq), np.full(len(lat) + 2 * N, -np.inf)])

    def solve(self, pb: LtvProblem) -> QPResult:
        ca, f = self.ca, self.form
        bad = nonfinite_result(pb, f"casadi/{self.plugin}")
        if bad is not None:
            return bad
        t0 = time.perf_counter()
        vals, b = f.fill(pb)
        uba = b[self._rows]
        lba = self._lba.copy()
        lba[: f.neq] = uba[: f.neq]
        N = self.N
        lbx = np.concatenate([np.tile(pb.u_lo, N), np.full(6 * N, -np.inf), np.zeros(2 * N)])
        ubx = np.concatenate([np.tile(pb.u_hi, N), np.full(6 * N, np.inf), np.full(2 * N, np.inf)])
        a = ca.DM(self._Asp, vals[self._take])
        try:  # CasADi raises RuntimeError when the plugin itself fails (error_on_fail is off)
            sol = self.solver(h=self._H, g=f.q(pb), a=a, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        except RuntimeError as exc:
            return fail_result(self.N, QPStatus.FAILED, f"casadi/{self.plugin}: {exc}", time.perf_counter() - t0)
        st = self.solver.stats()
        dt = time.perf_counter() - t0
        status = conic_status(st)
        z = np.asarray(sol["x"]).ravel()
        x, u, eps = f.unpack(z)
        obj = float(sol["cost"]) + f.constant(pb) if status.usable else np.nan
        return check_result(QPResult(status, x, u, eps, obj, dt, int(st.get("iter_count", 0) or 0), str(st.get("return_status", ""))))
