"""Active exploration (paper Algorithm 1), shared by the time trial and head-to-head."""

from gprace.explore.algorithm import CandidateGrid, candidate_grid, select_target

__all__ = ["CandidateGrid", "candidate_grid", "select_target"]
