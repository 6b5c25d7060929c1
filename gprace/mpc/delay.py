"""Actuator and measurement delays: predicting over them, aligning recorded data, estimating them.

A car whose steering acts ``a`` seconds after the command (an actuator's dead time; a first-order
lag of time constant ``tau`` acts roughly like a dead time ``tau``) and whose measurements reach
the controller ``m`` seconds late behaves, for the controller, like one total delay ``D = m + a``:
the measurement ``y_k`` is the state at ``t_k - m`` and the command sent now acts from ``t_k + a``.
With ``D = (n + f) dt`` (``n`` whole periods and a fraction ``f``) the input acting on the car over
the measured period ``[t_k, t_k+1)`` (shifted by ``m``) is ``u_{k-n-1}`` for its first ``f dt`` and
``u_{k-n}`` for the rest.

* :func:`predict` (the tracking MPC, every period): the state at ``t_k + a`` from ``y_k`` and the
  inputs already sent, integrated with the nominal model (RK4) over ``D``; the MPC then plans from
  there, as if its first input acted at once.
* :func:`acting_inputs` and :func:`acting_step` (the GPs' data): the inputs that really acted over
  each recorded period and the one-step prediction with them, so the GPs learn the residual of the
  same delay-aware step the MPC predicts with.
* :func:`estimate` (the shakedown): the dead time and the first-order lag of the steering as the
  yaw rate shows them. For each pair on a grid (dead time 0 to 2 periods, lag 0 to 100 ms) a small
  linear model of the yaw acceleration (``r/v_x``, ``v_y/v_x``, the delayed and lagged steering,
  that times ``v_x``, a constant; coefficients free, so a wrong grip or inertia in the nominal
  model does not bias the timing) is fitted by least squares to the central difference of the
  measured yaw rate, over the lap and the calibration run together (the pair is chosen as below).
  A pure dead time alone read a 40 ms lag as 10 to 15 ms; with both shapes on the
  grid, an Audi with a steering lag of 0 / 40 / 80 ms and 0 to 2 periods of measurement delay is
  read within 25 ms. On the cars of the randomized family (closed loop, rate-limited actuators,
  relaxation) the error is larger: measured -0.05 to +0.14 s on single laps, about +-0.03 s on
  the reference controller's weaving runs (docs/decisions.md). Longer delays are not estimated
  (a closed loop that oscillates fits ever better towards any grid edge); a longer known delay is
  configured (``VehicleConfig.actuator_delay`` / ``measurement_delay`` or ``--delay``).

  Two checks keep a closed loop's artefact from being read as a delay (measured on the reference
  controller's calibration runs of 28 cars, the Audi, the BMW and 26 randomized ones, on
  gprace_ring, Norisring and Spielberg; docs/decisions.md):

  - a candidate whose fit steers the wrong way (the yaw acceleration's gain on the steering, at
    the median speed, not positive) is not a delay of the car: the fit explains the loop's own
    oscillation in antiphase. On the Audi with a 50 ms steering lag on Norisring the best fit was
    such a candidate, at the grid's far corner (0.2 s); the shakedown predicting over it started a
    yaw oscillation on the start straight and lost the car;
  - the data often cannot tell neighbouring delays apart (a calm lap, a closed loop whose
    steering follows the state). So the estimate is not the best fit alone but the mean over the
    grid of the candidates that steer the right way, each weighted by how well it fits: the
    Gaussian likelihood of its residual sum of squares, ``(sse / sse_min) ** (-n_eff / 2)``, on the
    effective sample size the best fit's residual autocorrelation leaves (a flat prior over the
    grid). Sharp data give the best fit; flat data a delay between the candidates they cannot
    tell apart. Measured on the reference controller's calibration runs of 37 cars with known delays
    (randomized 1 to 26 on gprace_ring, 1 to 8 on Norisring, audi_hidden on gprace_ring, Norisring
    and Spielberg; docs/decisions.md, issue 37, stop 49), against the total of measurement delay,
    steering lag and the tire relaxation time at 30 m/s: mean absolute error 0.040 -> 0.030 s,
    largest under-estimate -0.119 -> -0.071 s, largest over-estimate +0.040 -> +0.018 s, against
    stop 47's rule (of the candidates within a chi-square margin of the best, the one nearest a
    prior of 80 ms), which pulled every long delay of the family down towards 80 ms: the
    shakedown of a randomized Audi with 0.15 s of delay and 1.35 m of relaxation predicted over
    0.088 s and spun under braking from 58 m/s.

  Of the loop's own laps (the shakedown's, during and after it) the time trial reads only the
  samples in control with both tires below their peak (:func:`gprace.timetrial.grip.below_peak`):
  the linear model of the yaw acceleration does not hold in a slide, and one slide of a shakedown
  lap (a randomized Audi, the rear at 2.3 times its peak slip angle for 6 % of the lap) moved its
  estimate from 0.11 s to the grid's far corner. The calibration run keeps its samples past the
  peak: without them the estimates came nearer the physical delays on average, but a car with a
  high CoG, predicted over 0.13 instead of 0.11 s, lost three GP laps (docs/decisions.md, issue
  37, stop 50).
"""

from __future__ import annotations

import numpy as np

from gprace.errors import ConfigError
from gprace.model.dynamics import Input, State

MAX_PERIODS = 2.0     # longest dead time the estimator considers [periods]
GRID = 0.25           # candidate spacing [periods]
MIN_SAMPLES = 100     # in-control samples with speed the estimator needs
PRIOR = 0.08          # [s] the delay assumed without data: the middle of the family's 0 to 180 ms
LAGS = np.array([0.0, 0.01, 0.02, 0.03, 0.045, 0.06, 0.08, 0.1])  # candidate lag time constants [s]


def check(delay: float, horizon: int, dt: float, where: str = "delay") -> float:
    """``delay`` [s] if the MPC can predict over it (0 <= delay <= horizon dt), else a ConfigError."""
    if not np.isfinite(delay) or delay < 0:
        raise ConfigError(f"{where}: must be a finite number of seconds >= 0, got {delay}")
    if delay > horizon * dt + 1e-12:
        raise ConfigError(f"{where}: {delay:g} s is longer than the MPC horizon ({horizon} x {dt:g} s = "
                          f"{horizon * dt:g} s); the controller cannot predict over it")
    return float(delay)


def split(delay: float, dt: float) -> tuple[int, float]:
    """``(n, f)`` with ``delay = (n + f) dt``, ``0 <= f < 1`` (a fraction below 1e-6 counts as 0)."""
    periods = delay / dt
    n = int(np.floor(periods + 1e-6))
    f = periods - n
    return n, (0.0 if f < 1e-6 else float(f))


def predict(step, y: np.ndarray, sent: np.ndarray, delay: float, dt: float) -> np.ndarray:
    """State after the delay: ``y`` (6,) integrated over ``delay`` with the inputs ``sent`` (n+1, 2),
    oldest first, that act over it (``sent[-1]`` is the last input sent); ``step(x, u, h)`` is the
    model's integration over ``h`` seconds."""
    n, f = split(delay, dt)
    x = np.asarray(y, dtype=float)
    if f > 0:
        x = step(x, sent[-n - 1], f * dt)
    for j in range(n):
        x = step(x, sent[len(sent) - n + j], dt)
    return x


def history_length(delay: float, dt: float) -> int:
    """Inputs :func:`predict` needs: ``n + 1``."""
    return split(delay, dt)[0] + 1


def acting_inputs(U: np.ndarray, delay: float, dt: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``(U_late, U_early, f)``: per recorded period ``k`` the inputs ``u_{k-n}`` and ``u_{k-n-1}``
    that acted over it (the first sample repeated before the recording started)."""
    n, f = split(delay, dt)
    idx = np.arange(len(U))
    return U[np.maximum(idx - n, 0)], U[np.maximum(idx - n - 1, 0)], f


def blended(U: np.ndarray, delay: float, dt: float) -> np.ndarray:
    """The mean input over each recorded period (the GP's input feature under a delay)."""
    late, early, f = acting_inputs(U, delay, dt)
    return (1.0 - f) * late + f * early


def acting_step(model, X: np.ndarray, U: np.ndarray, kappa, dt: float, delay: float) -> np.ndarray:
    """One-step predictions ``(n, 6)`` from recorded states ``X`` with the inputs that acted
    (vectorised): RK4 over ``f dt`` with ``u_{k-n-1}``, then over ``(1 - f) dt`` with ``u_{k-n}``."""
    late, early, f = acting_inputs(U, delay, dt)
    x = X
    if f > 0:
        x = model.rk4(x, early, kappa, f * dt)
    return model.rk4(x, late, kappa, (1.0 - f) * dt)


def skipped(delay: float, dt: float) -> int:
    """Leading samples whose acting inputs were sent before the recording began."""
    n, f = split(delay, dt)
    return n + (1 if f > 0 else 0)


def estimate(X: np.ndarray, U: np.ndarray, dt: float, mask: np.ndarray | None = None,
             more: tuple = ()) -> tuple[float, float]:
    """``(dead_time, lag)`` [s] of the steering as the yaw rate shows it (see the module docstring);
    NaNs when fewer than ``MIN_SAMPLES`` usable samples (in control, above 5 m/s) exist or no
    candidate's fit steers the right way. Both are likelihood-weighted means over the grid's
    candidates (module docstring). ``more`` are further recordings ``(X, U, mask)`` of the same car
    (the calibration run): their rows join the same fits. The controller predicts over the sum."""
    parts = [_regressors(X, U, mask, dt)] + [_regressors(*m, dt=dt) for m in more]
    parts = [p for p in parts if p is not None]
    if sum(len(p[0]) for p in parts) < MIN_SAMPLES:
        return float("nan"), float("nan")
    shifts = np.arange(0.0, MAX_PERIODS + 1e-9, GRID)
    sse = np.zeros((len(shifts), len(LAGS)))
    steers_right = np.ones(sse.shape, dtype=bool)
    for part in parts:
        for i in range(len(shifts)):  # a small grid of least-squares fits (9 x 8)
            for j in range(len(LAGS)):
                res, gain = _yaw_fit(part, i, j)
                sse[i, j] += res @ res
                steers_right[i, j] &= gain > 0.0
    if not steers_right.any():
        return float("nan"), float("nan")
    best = np.unravel_index(int(np.argmin(np.where(steers_right, sse, np.inf))), sse.shape)
    n_eff = sum(_effective_samples(_yaw_fit(part, *best)[0]) for part in parts)
    w = likelihood_weights(sse, steers_right, n_eff)
    return float(w.sum(axis=1) @ (shifts * dt)), float(w.sum(axis=0) @ LAGS)


def likelihood_weights(sse: np.ndarray, ok: np.ndarray, n_eff: float) -> np.ndarray:
    """Normalised weights of the candidates ``ok`` from their residual sums of squares ``sse``: the
    Gaussian likelihood with the noise variance profiled out, ``(sse / sse_min) ** (-n_eff / 2)``
    (in logs, so a sharp surface does not underflow); 0 elsewhere."""
    masked = np.where(ok, sse, np.inf)
    w = np.exp(-0.5 * n_eff * np.log(masked / masked.min()))  # exp(-inf) = 0 where not ok
    return w / w.sum()


def _yaw_fit(part: tuple, i: int, j: int) -> tuple[np.ndarray, float]:
    """Residuals of one recording's yaw-acceleration fit with candidate ``(i, j)`` (dead time,
    lag) and the fit's steering gain at the recording's median speed."""
    r_dot, base, steer, vx = part
    A = np.column_stack([base, steer[i, j], steer[i, j] * vx])
    coef, *_ = np.linalg.lstsq(A, r_dot, rcond=None)
    return r_dot - A @ coef, float(coef[-2] + coef[-1] * np.median(vx))


def _effective_samples(res: np.ndarray) -> float:
    """Independent samples a residual series is worth: ``n (1 - rho) / (1 + rho)`` with ``rho`` its
    lag-one autocorrelation (an AR(1) reading; 1 at least)."""
    if len(res) < 3:
        return float(len(res))
    rho = float(np.clip(np.corrcoef(res[:-1], res[1:])[0, 1], 0.0, 0.99))
    return max(len(res) * (1.0 - rho) / (1.0 + rho), 1.0)


def _regressors(X: np.ndarray, U: np.ndarray, mask: np.ndarray | None = None, dt: float = 0.05):
    """``(r_dot, base, steer (shifts, lags, m), v_x)`` of one recording's usable rows, or None."""
    from scipy.signal import lfilter

    n = len(X)
    vx = np.maximum(X[:, State.V_X], 1.0)
    ok = (X[:, State.V_X] > 5.0) if mask is None else (np.asarray(mask, bool) & (X[:, State.V_X] > 5.0))
    ok[: int(np.ceil(MAX_PERIODS)) + 2] = False
    ok[-2:] = False
    if ok.sum() < 10:
        return None
    idx = np.arange(n, dtype=float)
    shifts = np.arange(0.0, MAX_PERIODS + 1e-9, GRID)
    steer = np.empty((len(shifts), len(LAGS), int(ok.sum())))
    for i, d in enumerate(shifts):
        # the steering at t - d, seen through the zero-order hold (u_j acts over [t_j, t_j+1))
        delayed = np.interp(np.clip(idx - d - 0.5, 0, n - 1), idx, U[:, Input.DELTA])
        for j, tau in enumerate(LAGS):
            if tau > 0:
                a = np.exp(-dt / tau)
                steer[i, j] = lfilter([1.0 - a], [1.0, -a], delayed, zi=[a * delayed[0]])[0][ok]
            else:
                steer[i, j] = delayed[ok]
    r_dot = np.gradient(X[:, State.YAW_RATE], dt)[ok]
    base = np.column_stack([X[:, State.YAW_RATE] / vx, X[:, State.V_Y] / vx, np.ones(n)])[ok]
    return r_dot, base, steer, vx[ok]
