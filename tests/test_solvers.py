"""The one solver-status table (issue 40): IPOPT, Clarabel, CVXPY and CasADi's conic plugins read
through the same five outcomes, checked against real solves where a solver can be made to end so."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from gprace.solvers import SolveStatus, clarabel_status, conic_status, cvxpy_status, ipopt_status


def _ipopt(f, g=None, lbg=None, ubg=None, **opts):
    x = ca.SX.sym("x", 2)
    nlp = {"x": x, "f": f(x)}
    if g is not None:
        nlp["g"] = g(x)
    s = ca.nlpsol("s", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes",
                                      **{f"ipopt.{k}": v for k, v in opts.items()}})
    args = {"x0": [3.0, -2.0]}
    if g is not None:
        args.update(lbg=lbg, ubg=ubg)
    s(**args)
    return s.stats()


def test_ipopt_outcomes_from_real_solves():
    quad = lambda x: (x[0] - 1) ** 2 + (x[1] + 0.5) ** 2  # noqa: E731
    assert ipopt_status(_ipopt(quad)) is SolveStatus.SOLVED
    acceptable = _ipopt(lambda x: (x[0] - 1) ** 4 + x[1] ** 4, tol=1e-30, acceptable_tol=1e-1, acceptable_iter=1)
    assert acceptable["return_status"] == "Solved_To_Acceptable_Level"
    assert ipopt_status(acceptable) is SolveStatus.INACCURATE and ipopt_status(acceptable).usable
    rosen = lambda x: 100 * (x[1] - x[0] ** 2) ** 2 + (1 - x[0]) ** 2  # noqa: E731
    assert ipopt_status(_ipopt(rosen, max_iter=2)) is SolveStatus.MAX_ITER
    infeasible = _ipopt(quad, g=lambda x: ca.vertcat(x[0] + x[1], x[0] + x[1]), lbg=[1.0, -np.inf], ubg=[np.inf, 0.0])
    assert ipopt_status(infeasible) is SolveStatus.INFEASIBLE
    assert not ipopt_status(infeasible).usable


def test_conic_outcomes_from_real_solves():
    H = ca.DM.eye(2)
    A = ca.DM([[1.0, 1.0], [1.0, 1.0]])
    qp = ca.conic("q", "qrqp", {"h": H.sparsity(), "a": A.sparsity()},
                  {"error_on_fail": False, "print_iter": False, "print_header": False, "print_info": False})
    qp(h=H, g=ca.DM([-1.0, 0.0]), a=A, lba=-1.0, uba=1.0)
    assert conic_status(qp.stats()) is SolveStatus.SOLVED
    qp(h=H, g=ca.DM([-1.0, 0.0]), a=A, lba=ca.DM([2.0, -np.inf]), uba=ca.DM([np.inf, 1.0]))  # x0 + x1 >= 2 and <= 1
    assert not conic_status(qp.stats()).usable


@pytest.mark.parametrize("name, status", [("Solved", "SOLVED"), ("AlmostSolved", "INACCURATE"),
                                          ("PrimalInfeasible", "INFEASIBLE"), ("MaxIterations", "MAX_ITER"),
                                          ("NumericalError", "FAILED"), ("InsufficientProgress", "FAILED")])
def test_clarabel_names(name, status):
    assert clarabel_status(f"SolverStatus.{name}") is SolveStatus[status]
    assert clarabel_status(name) is SolveStatus[status]


def test_clarabel_and_cvxpy_agree_on_a_real_infeasible_qp():
    import clarabel
    import cvxpy as cp
    from scipy import sparse

    P = sparse.csc_matrix(np.eye(2))
    A = sparse.csc_matrix(np.array([[1.0, 0.0], [-1.0, 0.0]]))
    b = np.array([-1.0, -1.0])  # x0 <= -1 and x0 >= 1
    st = clarabel.DefaultSettings()
    st.verbose = False
    sol = clarabel.DefaultSolver(P, np.zeros(2), A, b, [clarabel.NonnegativeConeT(2)], st).solve()
    x = cp.Variable(2)
    prob = cp.Problem(cp.Minimize(cp.sum_squares(x)), [x[0] <= -1, x[0] >= 1])
    prob.solve(solver=cp.CLARABEL)
    assert clarabel_status(sol.status) is cvxpy_status(prob.status) is SolveStatus.INFEASIBLE
