"""The nominal vehicle model (one definition, numpy and CasADi) and the effect catalogue."""

from gprace.model.dynamics import INPUT, NU, NX, STATE, Input, Params, State, dynamics
from gprace.model.effects import EFFECTS, Effect, ParamSpec, make_effect
from gprace.model.nominal import NominalModel

__all__ = ["INPUT", "NU", "NX", "STATE", "Input", "State", "Params", "dynamics", "EFFECTS", "Effect", "ParamSpec", "make_effect", "NominalModel"]
