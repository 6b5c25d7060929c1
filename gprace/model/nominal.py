""":class:`NominalModel`: numeric (vectorised numpy) and symbolic (CasADi) faces of one model."""

from __future__ import annotations

from functools import cache, cached_property
from typing import Any, Callable, Sequence

import numpy as np

from gprace.config import EffectConfig, VehicleConfig
from gprace.model.dynamics import NU, NX, STATE, Params, State, dynamics
from gprace.model.effects import Effect, make_effect
from gprace.model.ops import NP, CasadiOps

Kappa = float | np.ndarray | Callable[[np.ndarray], np.ndarray]


class NominalModel:
    """The vehicle model of a :class:`VehicleConfig` (its ``effects`` included).

    Numeric methods take ``X`` (n, nx) or (nx,), ``U`` (n, 2) or (2,), ``kappa`` (n,) or a scalar
    and return arrays of the same leading shape. ``nx = 6 + effect states``. ``longitudinal`` says
    what the second input is (:data:`~gprace.model.dynamics.LONGITUDINAL`: a commanded ``a_x``
    by default, a measured one, or a speed command).
    """

    def __init__(self, vehicle: VehicleConfig, extra_effects: Sequence[EffectConfig | Effect] = (),
                 longitudinal: str = "force") -> None:
        self.vehicle = vehicle
        self.params = Params.from_vehicle(vehicle, longitudinal)
        effects = [make_effect(e) for e in vehicle.effects]
        effects += [e if isinstance(e, Effect) else make_effect(e) for e in extra_effects]
        self.effects: list[Effect] = effects
        z0 = 0
        for e in effects:
            e.z0 = z0
            z0 += e.n_states
        self.nx = NX + z0
        self.nu = NU

    # numeric ---------------------------------------------------------------------------------
    def f(self, X: np.ndarray, U: np.ndarray, kappa: Any) -> np.ndarray:
        X, U, single = _as2d(X, self.nx), _as2d(U, NU), np.ndim(X) == 1
        k = np.broadcast_to(np.asarray(kappa, dtype=float), X.shape[:1])
        out = dynamics(list(X.T), list(U.T), k, self.params, self.effects, NP)
        res = np.column_stack([np.broadcast_to(o, X.shape[:1]) for o in out])
        return res[0] if single else res

    def euler(self, X: np.ndarray, U: np.ndarray, kappa: Any, dt: float) -> np.ndarray:
        """The paper's discretisation ``x+ = x + f(x, u) T`` (eq. nominal_discrete_time_bicycle)."""
        return X + dt * self.f(X, U, kappa)

    def rk4(self, X: np.ndarray, U: np.ndarray, kappa: Kappa, dt: float, substeps: int = 1) -> np.ndarray:
        """Classical RK4 with ``substeps``; ``kappa`` may be a function of s (re-evaluated per stage)."""
        kfun = kappa if callable(kappa) else (lambda s, k=kappa: k)
        h = dt / substeps
        x = np.array(X, dtype=float)
        for _ in range(substeps):
            k1 = self.f(x, U, kfun(x[..., 5]))
            x2 = x + 0.5 * h * k1
            k2 = self.f(x2, U, kfun(x2[..., 5]))
            x3 = x + 0.5 * h * k2
            k3 = self.f(x3, U, kfun(x3[..., 5]))
            x4 = x + h * k3
            k4 = self.f(x4, U, kfun(x4[..., 5]))
            x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    def initial_state(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Append effect states (actuator lags start at the first command)."""
        single = np.ndim(x6) == 1
        x6, u = _as2d(x6, NX), _as2d(u, NU)
        out = np.hstack([x6] + [e.initial_states(u) for e in self.effects if e.n_states])
        return out[0] if single else out

    def measure(self, X: np.ndarray) -> np.ndarray:
        """Measured Frenet states (n, 6) from model states: sensor effects applied."""
        X = _as2d(X, self.nx)
        y = {name: X[:, i].copy() for i, name in enumerate(STATE)}
        for e in self.effects:
            e.measure(y)
        return np.column_stack([y[n] for n in STATE])

    # symbolic --------------------------------------------------------------------------------
    @cached_property
    def _ca(self):
        import casadi as ca

        return ca

    def casadi_f(self):
        """``casadi.Function('f', [x(nx), u(2), kappa], [xdot])``."""
        return self._sym("f")

    def casadi_euler(self, dt: float):
        return self._sym("euler", dt)

    def casadi_rk4(self, dt: float, substeps: int = 1):
        """RK4 with curvature held at its value at the start of the step."""
        return self._sym("rk4", dt, substeps)

    def symbolic(self, x, u, kappa):
        """Continuous dynamics as a CasADi expression of given symbols (for NLP builders)."""
        ca = self._ca
        return ca.vertcat(*dynamics([x[i] for i in range(self.nx)], [u[0], u[1]], kappa, self.params, self.effects, _casadi_ops()))

    def rk4_expression(self, x, u, kappa_of_s, dt: float, substeps: int = 1):
        """CasADi expression of ``x`` after ``dt`` by RK4 with ``substeps``; ``kappa_of_s(s)`` gives the
        curvature (a constant, or a CasADi lookup re-evaluated at every stage)."""
        F = self.casadi_f()  # built once per model; calling it on symbols inlines the same operations
        return rk4_expression(lambda xx: F(xx, u, kappa_of_s(xx[State.S])), x, dt, substeps)

    def jacobians(self, x: np.ndarray, u: np.ndarray, kappa: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``A = d x+/d x`` and ``B = d x+/d u`` of the Euler step at one point (CasADi AD)."""
        A, B = self._sym("jac", dt)(x, u, kappa)
        return np.asarray(A), np.asarray(B)

    def _sym(self, kind: str, dt: float = 0.0, substeps: int = 1):
        key = (kind, dt, substeps)
        cache = self.__dict__.setdefault("_fcache", {})
        if key in cache:
            return cache[key]
        ca = self._ca
        x = ca.SX.sym("x", self.nx)
        u = ca.SX.sym("u", NU)
        k = ca.SX.sym("kappa")
        xdot = self.symbolic(x, u, k)
        if kind == "f":
            fn = ca.Function("f", [x, u, k], [xdot], ["x", "u", "kappa"], ["xdot"])
        elif kind == "euler":
            fn = ca.Function("euler", [x, u, k], [x + dt * xdot], ["x", "u", "kappa"], ["x_next"])
        elif kind == "rk4":
            xn = self.rk4_expression(x, u, lambda s: k, dt, substeps)
            fn = ca.Function("rk4", [x, u, k], [xn], ["x", "u", "kappa"], ["x_next"])
        elif kind == "jac":
            xn = x + dt * xdot
            fn = ca.Function("linearised", [x, u, k], [ca.jacobian(xn, x), ca.jacobian(xn, u)], ["x", "u", "kappa"], ["A", "B"])
        else:  # pragma: no cover
            raise ValueError(kind)
        cache[key] = fn
        return fn


def rk4_expression(f, x, dt: float, substeps: int = 1):
    """``x`` after ``dt`` by classical RK4 of ``x' = f(x)`` with ``substeps`` (CasADi expressions)."""
    h = dt / substeps
    for _ in range(substeps):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


@cache
def _casadi_ops() -> CasadiOps:
    return CasadiOps()


def _as2d(a: np.ndarray, width: int) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        a = a[None, :]
    if a.shape[-1] != width:
        raise ValueError(f"expected arrays with {width} columns, got shape {a.shape}")
    return a
