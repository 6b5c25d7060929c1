"""A raceline's references rebuilt with the tracking GP (issue 39): the steady corner of the
nominal model plus the GP's mean recovers the sideslip and steering of a car with more grip than
the nominal model, where the nominal corner does not."""

from __future__ import annotations

import numpy as np

from gprace.config import EffectConfig, load_vehicle
from gprace.gp.features import dyn_inputs
from gprace.model import NominalModel
from gprace.plan.steady import steady_state_inputs
from gprace.timetrial.learning import GPPredictor, fit_hyper
from gprace.plan.raceline import compensated_corner

DT = 0.05
FULL = ("v_x", "v_y", "yaw_rate", "delta", "a_x")


class _ExactError:
    """The true one-step error of a known car (the reference the GP should approach)."""

    def __init__(self, true, nominal, kappa):
        self.true, self.nominal, self.kappa = true, nominal, kappa

    def at(self, X, U):
        err = self.true.rk4(X, U, self.kappa, DT) - self.nominal.rk4(X, U, self.kappa, DT)
        return err[:, 1:3], np.zeros((len(X), 2))


def _corners(model, v, kappa):
    vy, r, delta = steady_state_inputs(model, v, kappa)
    return np.column_stack([v, vy, r, np.zeros_like(v), np.zeros_like(v), np.zeros_like(v)]), delta


def test_compensated_corner_recovers_the_grippier_cars_sideslip():
    veh = load_vehicle("audi_tt_cup")
    nominal = NominalModel(veh)
    true = NominalModel(veh, extra_effects=[EffectConfig(name="tire_friction", params={"front": 1.3, "rear": 1.3})])
    rng = np.random.default_rng(3)
    g = nominal.params.mu * 9.81
    # corners up to 1.15 of the nominal grip (the grippier car holds them), 20 to 40 m/s
    v = rng.uniform(20.0, 40.0, 300)
    kappa = rng.choice([-1.0, 1.0], 300) * rng.uniform(0.2, 1.15, 300) * g / v**2
    exact = _ExactError(true, nominal, kappa)
    X0, d0 = _corners(nominal, v, kappa)
    vy_true, d_true = compensated_corner(true, _ExactError(true, true, kappa), X0, d0, kappa, DT)
    X_true = X0.copy()
    X_true[:, 1] = vy_true
    # the GP learns the error around the true car's corners, as from laps of that car
    Xs = np.repeat(np.column_stack([X_true[:, :3], np.zeros((300, 3))]), 2, axis=0)
    Xs[:, 1] += rng.normal(0.0, 0.3, len(Xs))
    Us = np.column_stack([np.repeat(d_true, 2) + rng.normal(0.0, 0.005, len(Xs)), np.zeros(len(Xs))])
    k2 = np.repeat(kappa, 2)
    Y = (true.rk4(Xs, Us, k2, DT) - nominal.rk4(Xs, Us, k2, DT))[:, 1:3]
    gp = GPPredictor(fit_hyper(dyn_inputs(Xs, Us, FULL), Y, max_fit_points=200), "tracking", inputs=FULL)
    vy_gp, d_gp = compensated_corner(nominal, gp, X0, d0, kappa, DT)
    assert np.max(np.abs(exact.at(X_true, np.column_stack([d_true, 0 * d_true]))[0])) > 0  # the cars differ
    err_nominal = np.sqrt(np.mean((X0[:, 1] - X_true[:, 1]) ** 2))
    err_gp = np.sqrt(np.mean((vy_gp - X_true[:, 1]) ** 2))
    assert err_gp < 0.1 * err_nominal, (err_gp, err_nominal)
    assert np.sqrt(np.mean((d_gp - d_true) ** 2)) < 0.1 * np.sqrt(np.mean((d0 - d_true) ** 2))
