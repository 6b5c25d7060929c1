"""The time trial's tracking MPC (paper problem "tracking_problem") and its sparse QP.

Public surface::

    from gprace.mpc import TrackingMPC, MPCSettings, SparseQP, QPResult, QPStatus

:mod:`~gprace.mpc.tracking` (linearisation, GP compensation, chance-constraint tightening) and
:mod:`~gprace.mpc.qp` (the QP in one layout for every solver backend, result and status).
"""

from gprace._lazy import lazy_face

__all__, __getattr__ = lazy_face(__name__, {
    "tracking": "TrackingMPC MPCSettings", "qp": "SparseQP QPResult QPStatus LtvProblem Weights"})
