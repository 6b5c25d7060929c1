"""One table of solver outcomes for every optimiser gprace calls (issue 40).

The QP backends (Clarabel directly, through CVXPY, CasADi's conic plugins), the planner's and the
head-to-head NLPs (IPOPT through CasADi) each report success in their own words. Every caller reads
them through :class:`SolveStatus`, so "solved", "usable but counted", "infeasible", "out of
iterations" and "failed" mean the same everywhere (acados keeps one such status table for all its
solvers). A solver *call* that fails is a status; building the problem is not guarded: a shape or
type error there is a bug and is raised.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping

import numpy as np


class SolveStatus(enum.Enum):
    SOLVED = "solved"
    INACCURATE = "inaccurate"      # solved to reduced accuracy: used, but counted
    INFEASIBLE = "infeasible"
    MAX_ITER = "max_iter"          # iteration or time limit
    FAILED = "failed"              # numerical error, non-finite data or solution

    @property
    def usable(self) -> bool:
        return self in (SolveStatus.SOLVED, SolveStatus.INACCURATE)


S = SolveStatus

#: Clarabel's ``SolverStatus`` names (the part after the dot).
CLARABEL: Mapping[str, SolveStatus] = {
    "Solved": S.SOLVED, "AlmostSolved": S.INACCURATE,
    "PrimalInfeasible": S.INFEASIBLE, "DualInfeasible": S.INFEASIBLE,
    "AlmostPrimalInfeasible": S.INFEASIBLE, "AlmostDualInfeasible": S.INFEASIBLE,
    "MaxIterations": S.MAX_ITER, "MaxTime": S.MAX_ITER,
}

#: CVXPY's problem statuses (strings of ``cvxpy.settings``).
CVXPY: Mapping[str, SolveStatus] = {
    "optimal": S.SOLVED, "optimal_inaccurate": S.INACCURATE,
    "infeasible": S.INFEASIBLE, "unbounded": S.INFEASIBLE,
    "infeasible_inaccurate": S.INFEASIBLE, "unbounded_inaccurate": S.INFEASIBLE,
    "user_limit": S.MAX_ITER,
}

#: IPOPT's ``return_status`` strings (as CasADi reports them) when CasADi's ``success`` is false.
IPOPT: Mapping[str, SolveStatus] = {
    "Solve_Succeeded": S.SOLVED, "Solved_To_Acceptable_Level": S.INACCURATE,
    "Infeasible_Problem_Detected": S.INFEASIBLE, "Maximum_Iterations_Exceeded": S.MAX_ITER,
    "Maximum_CpuTime_Exceeded": S.MAX_ITER, "Maximum_WallTime_Exceeded": S.MAX_ITER,
}


def clarabel_status(status) -> SolveStatus:
    return CLARABEL.get(str(status).split(".")[-1], S.FAILED)


def cvxpy_status(status: str) -> SolveStatus:
    return CVXPY.get(str(status), S.FAILED)


def ipopt_status(stats: Mapping) -> SolveStatus:
    """Status of an IPOPT solve from CasADi's ``solver.stats()``: CasADi's own ``success`` flag
    decides "usable" (it accepts some acceptable-level exits), the return status the rest."""
    name = str(stats.get("return_status", ""))
    if stats.get("success", False):
        return S.SOLVED if name == "Solve_Succeeded" else S.INACCURATE
    return IPOPT.get(name, S.FAILED)


def conic_status(stats: Mapping) -> SolveStatus:
    """Status of a CasADi ``conic`` solve (qrqp, ipqp, ...) from its ``stats()``."""
    if stats.get("success", False):
        return S.SOLVED
    return S.MAX_ITER if "iter" in str(stats.get("return_status", "")).lower() else S.FAILED


def all_finite(*arrays) -> bool:
    """True when every array holds finite numbers only (problem data checked before a solve)."""
    return all(bool(np.all(np.isfinite(np.asarray(a, dtype=float)))) for a in arrays)
