"""Planning: the GP-free minimum-curvature first path and the minimum-lap-time NLP (paper appendix)."""

from gprace.plan.curvature import curvature_plan, lateral_limit, line_plan, racing_line
from gprace.plan.nlp import PlanSettings, plan_min_time
from gprace.plan.plan import PLAN_COLUMNS, Plan, read_plan, track_hash
from gprace.plan.steady import max_corner_speed, steady_state_inputs

__all__ = ["curvature_plan", "lateral_limit", "line_plan", "racing_line", "PlanSettings", "plan_min_time", "PLAN_COLUMNS", "Plan", "read_plan",
           "track_hash", "max_corner_speed", "steady_state_inputs"]
