"""The nominal vehicle model (one definition, numpy and CasADi), the effect catalogue, and the vehicle and
plant configurations loaded for use (checked against the catalogue)."""

from gprace.model.dynamics import INPUT, NU, NX, STATE, Input, Params, State, dynamics
from gprace.model.effects import EFFECTS, Effect, ParamSpec, make_effect
from gprace.model.configs import check_effects, load_plant, load_vehicle
from gprace.model.nominal import NominalModel

__all__ = ["INPUT", "NU", "NX", "STATE", "Input", "State", "Params", "dynamics", "EFFECTS", "Effect", "ParamSpec", "make_effect", "NominalModel",
           "check_effects", "load_vehicle", "load_plant"]
