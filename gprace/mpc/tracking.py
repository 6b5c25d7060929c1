"""The GP-compensated tracking MPC (paper section "Minimum Lap Time Application", eq. "mpc_problem").

Each control period:

1. **Reference** from the plan, time-indexed from the car's position: the plan time ``t0`` at the
   measured ``s``, then the plan at ``t0 + k dt``; progress is expressed relative to the car.
2. **Exploration** (paper Algorithm 1, only when ``alpha > 0``): the feature the reference would
   visit, ``z~ = [v_y, yaw_rate, delta]`` of its first step, is traded against the candidates'
   precomputed weighted variances; the chosen ``z_ref`` replaces the ``v_y``, ``yaw_rate`` and
   ``delta`` references over the horizon (the inverse feature map). **Decision:** one target per
   control period, held over the horizon (the paper changes it "at each iteration of the MPC").
   With ``alpha = 0`` the reference is left untouched, so the controller is exactly the plain
   tracking MPC. **Decision:** only candidates within ``explore_radius`` = 0.5 (distance scaled by the
   data's standard deviation per feature) of ``z~`` compete: on the hidden-effects Audi the full
   grid's extreme corners (e.g. large lateral velocity with opposite steering) spun the car within
   two seconds at alpha = 0.857; the paper's GT Sport car evidently tolerated more. Nor does it
   explore while the reference brakes harder than ``explore_brake`` of the braking limit over the
   horizon (the hidden-effects car spun at the hairpin entry when it did).
3. **Linearisation** of the Euler-discretised nominal model along the previous solution shifted by
   one step (first period: the reference), all horizon points in one compiled CasADi call.
4. **GP compensation**: the tracking GP's mean of the one-step errors of ``[v_y, yaw_rate]`` at the
   features ``[v_y, yaw_rate, delta]`` of that nominal trajectory enters the affine term.
   Its gradient enters ``A`` and ``B`` (linearised with the nominal model), except where the
   nominal lateral block (``v_y``, ``yaw_rate``) of a step is already unstable (spectral radius at
   least 1: tires linearised at or past their peak) and the gradient would make it more so: there
   it is shrunk until it does not (``gp_stable``, :func:`stable_share`; beyond the paper, issue 37),
   and where it would leave the steering less than ``gp_steer_keep`` of its nominal effect on the
   yaw rate (:func:`steer_share`). The gradient fades as the GP nears its prior: each step keeps
   ``1 - extrapolation`` of it (``gp_trust``, :func:`trust_share`).
5. **Chance-constraint tightening**: ``Sigma_{k+1} = A_k Sigma_k A_k^T + diag(0, var_vy, var_r, 0..)``
   from ``Sigma_0 = 0`` (GP latent variances); ``gamma_k = sqrt(2) sigma_ey,k erfinv(2 beta - 1)``.
5b. **Grip** (beyond the paper; Liniger et al. 2015, Kabzan et al. 2019 bound tire slip or the
   friction ellipse in the racing MPC itself): the rear slip angle
   ``alpha_r = -atan((v_y - l_r r) / v_x)``, linearised along the nominal trajectory, is kept within
   ``grip_share`` of the nominal rear tire's peak slip angle ``tan(pi / (2 C_r)) / B_r``, softened
   by its own slack and tightened like ``e_y`` by ``sqrt(2) sigma_alpha,k erfinv(2 beta - 1)`` with
   ``sigma_alpha^2 = g_k Sigma_k g_k^T``. The car is lost through v_y and yaw rate, which the
   paper's QP does not bound; the peak slip angle does not depend on mu, so the bound holds on a
   car with less grip than the model. ``grip = False`` gives the paper's QP.
   The paper prints ``erf`` here; the one-sided quantile of ``Pr[e_y + eps <= w] >= beta`` is the
   INVERSE error function (``erfinv(2 beta - 1) = Phi^-1(beta) / sqrt 2``). ``gamma`` is 0 at zero
   GP variance and grows with it; beta = 0.6 gives ``gamma = 0.253 sigma``.
6. **QP** through the ``gprace.solver`` registry. A failed solve falls back to the previous
   solution shifted by one step (counted in ``fallbacks``); a lap never crashes on a solver.

5c. **Input bounds from the tires** (beyond the paper; issue 37): the steering of the period is
   kept within ``front_share`` of the nominal front tire's peak slip angle of the front axle's
   heading (:meth:`TrackingMPC.front_bounds`), and drive and braking inside the friction ellipse
   of the plan's limits at the lateral acceleration the car uses (:meth:`TrackingMPC.ellipse_bounds`).
   While the car is faster than its reference, drive is held to the most the reference asks over
   the horizon (:func:`fast_drive_cap`).
   The nominal model knows neither a tire past its peak nor combined slip; without these bounds
   the QP steered a sliding car to full lock and asked for full drive at the lateral limit.
   With that bound, the **linearisation point** keeps its steering within ``LINEARISE_FRONT`` of
   the peak slip: past the peak the tangent says that more steering turns the car less, and the
   QP steered in to stop an over-rotation. After its first step it keeps the rear within the grip
   rows' bound (:func:`rear_within`): linearised where its own prediction had let the rear go past
   the peak, the QP's next prediction diverged further.

Beyond the paper, two run-time hooks:

- **Delay** (``settings.delay``, :mod:`gprace.mpc.delay`): the measured state is first predicted
  over the total actuator and measurement delay with the nominal model and the inputs already
  sent; the QP starts from that state.
- **Speed factor** (``speed_factor`` in (0, 1], set by the stability envelope,
  :mod:`gprace.mpc.stability`): the reference runs slower, at ``rho`` times the plan's speed
  (plan time advances by ``rho dt`` per step; speeds and yaw rate times ``rho``, the acceleration
  times ``rho^2``). 1 leaves the reference untouched. A plan can be swapped between periods
  (:meth:`TrackingMPC.set_plan`, the shakedown's widening).
"""

from __future__ import annotations

from functools import cached_property
from typing import ClassVar

import numpy as np
from pydantic import Field, model_validator
from scipy.special import erfinv

from gprace.config import CommandSettings
from gprace.errors import ConfigError
from gprace.gp.features import DYN_INPUTS, dyn_inputs
from gprace.model.dynamics import Input, State, peak_slip
from gprace.mpc.qp import EY, LtvProblem, Weights

FEATURES = DYN_INPUTS
EXPLORED = ("v_y", "yaw_rate", "delta")  # features Algorithm 1 may move the reference to
FRONT_SHARE = 1.25  # default front slip bound: share of the nominal front tire's peak slip angle
LINEARISE_FRONT = 0.8  # front slip of the linearisation point: share of the nominal front peak slip angle
ELLIPSE = 1.0  # default friction ellipse of the longitudinal command: share of the plan's limits
BRAKE_HEADROOM = 0.15  # braking beyond the plan's limit the ellipse leaves for tracking (MPCSettings.brake_headroom)
RECOVER_STEPS = 10  # periods over which a rear slip beyond its bound is brought back
KAPPA_DS = 1.0  # half-width [m] of the central difference giving the curvature's slope
_REF = {"v_x": ("x", State.V_X), "v_y": ("x", State.V_Y), "yaw_rate": ("x", State.YAW_RATE),
        "delta": ("u", Input.DELTA), "a_x": ("u", Input.A_X)}
GP_STATES = slice(State.V_Y, State.YAW_RATE + 1)  # the states the GP corrects: v_y, yaw_rate


class MPCSettings(CommandSettings):
    """The tracking MPC (paper problem "tracking_problem")."""

    OPTIONS: ClassVar[dict[str, str]] = {"explore_radius": "--explore-radius", "N": "horizon N"}

    N: int = Field(20, ge=1, description="horizon [steps]")
    dt: float = Field(0.05, gt=0, description="step [s]")
    beta: float = Field(0.6, gt=0, lt=1, description="probability of each chance constraint, in (0, 1)")
    solver: str = Field("clarabel", description="QP backend (registry gprace.solver)")
    margin: float = Field(0.1, ge=0, description="distance kept from the border on top of half the car width [m]")
    integrator: str = Field("rk4", description='prediction step: "rk4" (default) or "euler" (the paper\'s)')
    explore_radius: float = Field(0.5, gt=0, description="exploration trust region: candidates within this scaled "
                                  "distance of z~ (a scaled feature distance)")
    explore_brake: float = Field(0.5, ge=0, description="no exploration while the reference brakes harder than this "
                                 "share of the limit")
    grip: bool = Field(True, description="bound the rear slip angle (False: the paper's QP)")
    grip_share: float = Field(0.9, gt=0, le=2, description="share of the nominal rear tire's peak slip angle")
    front_share: float | None = Field(FRONT_SHARE, gt=0, le=5, description="steering kept within this share of the "
                                      "nominal front tire's peak slip angle of the car's heading at the front axle "
                                      "(None: no bound)")
    ellipse: float | None = Field(ELLIPSE, gt=0, le=5, description="drive and braking held inside the friction ellipse of "
                                  "this share of the plan's limits at the lateral acceleration used (None: no bound)")
    slip_by_speed: bool = Field(False, description="the rear slip row may be met by a higher v_x (the nominal "
                                "model's view; False: only by v_y and yaw rate)")
    brake_headroom: float = Field(BRAKE_HEADROOM, ge=0, le=1, description="braking the ellipse allows beyond the "
                                  "plan's braking limit, as a share of it, so that a car faster than its reference "
                                  "in a braking zone planned at the limit can still get back to it")
    ellipse_floor: float = Field(0.2, ge=0, le=1, description="share of the drive and braking limits the ellipse "
                                 "always leaves")
    hold_drive_when_fast: bool = Field(True, description="while the car is faster than its reference, drive is held "
                                       "to the most the reference asks over the horizon (at least none)")
    weights: Weights = Field(default_factory=Weights, description="weights of the tracking cost")
    delay: float = Field(0.0, ge=0, description="total actuator and measurement delay [s] the MPC predicts over "
                         "(gprace.mpc.delay); at most the horizon N dt")
    gp_steer_keep: float = Field(0.25, ge=0, le=1, description="share of the nominal model's steering gain on the yaw "
                                 "rate the tracking GP's gradient always leaves (0: none; :func:`steer_share`)")
    gp_stable: bool = Field(True, description="where the nominal model's predicted lateral dynamics (v_y, yaw rate) "
                            "are unstable, the tracking GP's gradient may not make them more so (it is shrunk)")
    gp_trust: bool = Field(True, description="the tracking GP's gradient at each horizon step is scaled by one minus "
                           "its extrapolation there (latent std over prior std: 0 on dense data, 1 at the prior; "
                           ":func:`trust_share`)")

    @model_validator(mode="after")
    def _check(self) -> MPCSettings:
        from gprace.mpc.delay import check

        quantile_factor(self.beta)
        if self.integrator not in ("euler", "rk4"):
            raise ValueError(f"unknown integrator {self.integrator!r}; available: euler, rk4")
        try:
            check(self.delay, self.N, self.dt, "--delay")
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        return self


def covariances(A: np.ndarray, var: np.ndarray) -> np.ndarray:
    """State covariances ``Sigma_k (N, 6, 6)`` for steps ``k = 1..N``.

    ``Sigma_{k+1} = A_k Sigma_k A_k^T + Sigma_GP,k`` with ``Sigma_0 = 0`` (the current state is
    measured), ``Sigma_GP,k = diag(0, var_vy, var_r, 0, 0, 0)``.
    """
    N = A.shape[0]
    S = np.zeros((6, 6))
    out = np.empty((N, 6, 6))
    for k in range(N):  # recursion over the horizon (N = 20 small matrices)
        S = A[k] @ S @ A[k].T
        S[State.V_Y, State.V_Y] += var[k, 0]
        S[State.YAW_RATE, State.YAW_RATE] += var[k, 1]
        out[k] = S
    return out


def quantile_factor(beta: float) -> float:
    """``sqrt(2) erfinv(2 beta - 1)``: the one-sided ``beta`` quantile of a unit Gaussian."""
    if not 0.0 < beta < 1.0:
        raise ConfigError(f"beta must be in (0, 1), got {beta}")
    return float(np.sqrt(2.0) * erfinv(2.0 * beta - 1.0))  # the paper's "erf" read as its inverse


def tightening(A: np.ndarray, var: np.ndarray, beta: float) -> tuple[np.ndarray, np.ndarray]:
    """``(gamma (N,), sigma_ey (N,))`` for steps ``k = 1..N`` from ``A`` (N, 6, 6), GP variances (N, 2)."""
    q = quantile_factor(beta)
    sig = np.sqrt(np.maximum(covariances(A, var)[:, EY, EY], 0.0))
    return q * sig, sig


def rear_slip_rows(X: np.ndarray, lr: float, v_min: float) -> tuple[np.ndarray, np.ndarray]:
    """Rear slip angle ``alpha_r (n,)`` at states ``X (n, 6)`` and its gradient rows ``G (n, 6)``.

    ``alpha_r = -atan((v_y - l_r r) / v_x)`` with ``v_x`` floored at ``v_min`` (as the model).
    """
    vx = np.maximum(X[:, State.V_X], v_min)
    w = X[:, State.V_Y] - lr * X[:, State.YAW_RATE]
    den = vx**2 + w**2
    G = np.zeros((len(X), 6))
    G[:, State.V_X] = np.where(X[:, State.V_X] > v_min, w / den, 0.0)
    G[:, State.V_Y] = -vx / den
    G[:, State.YAW_RATE] = lr * vx / den
    return -np.arctan(w / vx), G


def fast_drive_cap(v: float, v_ref: float, a_ref: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``hi`` with the drive held to ``max(a_ref.max(), 0)`` when the car is faster than its reference
    (``v > v_ref``; never below ``lo``).

    Drive beyond the reference's own, while the car is already faster than the reference, does not
    serve the tracking of the speed; to the nominal model, which has no combined slip, it costs no
    lateral grip, but on the car it takes grip from a rear axle working near its peak. Measured on
    a randomized Audi with a light rear (randomized_10, rear grip 0.85 of the front's 1.04): at the
    apex of gprace_ring's 18 m hairpin, 0.4 m/s faster than its reference, which braked at
    2.9 m/s^2, the MPC asked for +2 m/s^2 of drive for 0.2 s, the car ran 1.6 m/s faster than the
    reference and spun. Re-driven on 3 noise seeds, that lap is lost on 1 without
    the hold and on none with it (docs/decisions.md, issue 37, stop 58)."""
    if v <= v_ref:
        return hi
    hi = hi.copy()
    hi[Input.A_X] = max(min(hi[Input.A_X], max(float(np.max(a_ref)), 0.0)), lo[Input.A_X])
    return hi


def rear_within(X: np.ndarray, p, slip) -> np.ndarray:
    """States ``X (n, 6)`` with ``v_y`` clipped so that the rear slip angle
    ``-atan((v_y - l_r r) / v_x)`` is within ``slip`` (a number or one per state; a copy, yaw rate
    and speed are kept).

    The linearisation point of the tracking MPC after its first step is the previous solution,
    the QP's own prediction. Where that prediction carries the rear past its peak, the nominal
    model linearised there is unstable (spectral radius of the lateral block up to 1.19 per step),
    the next prediction diverges further, and linearising on it closes the loop. Measured on a
    randomized Audi's GP lap at a hairpin exit (docs/decisions.md, issue 37, stop 62): the
    predictions carried rear slip angles of 0.25 to 1.26 rad (peak 0.15) with speeds up to 43 m/s
    and 35 m of lateral offset; the braking alternated between -6.3 and +1.8 m/s^2 from one period
    to the next and the car stalled in the corner.
    """
    X = X.copy()
    vx = np.maximum(X[:, State.V_X], p.vmin)
    room = np.tan(slip) * vx
    centre = p.lr * X[:, State.YAW_RATE]
    X[:, State.V_Y] = np.clip(X[:, State.V_Y], centre - room, centre + room)
    return X


def front_heading(X: np.ndarray, lf: float, v_min: float) -> np.ndarray:
    """Heading ``atan((v_y + l_f r) / v_x) (n,)`` of the front axle's velocity at states ``X (n, 6)``
    (``v_x`` floored at ``v_min``, as the model): the steering angle at which the front slip is 0."""
    X = np.atleast_2d(X)
    return np.arctan((X[:, State.V_Y] + lf * X[:, State.YAW_RATE]) / np.maximum(X[:, State.V_X], v_min))


def spectral_radius2(M: np.ndarray) -> np.ndarray:
    """Spectral radius ``(n,)`` of 2x2 matrices ``M (n, 2, 2)`` (closed form)."""
    tr = M[:, 0, 0] + M[:, 1, 1]
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    disc = 0.25 * tr * tr - det
    real = 0.5 * np.abs(tr) + np.sqrt(np.maximum(disc, 0.0))
    return np.where(disc >= 0.0, real, np.sqrt(np.abs(det)))


STABLE_SHARES = np.linspace(1.0, 0.0, 9)  # shares of the gradient tried, largest first


def stable_share(A0: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Share ``t (N,)`` of the GP's gradient kept per step: 1 where the nominal block is stable
    (``rho(A0) < 1``), else the largest of :data:`STABLE_SHARES` with ``rho(A0 + t J) <= rho(A0)``.

    ``A0 (N, 2, 2)``: the nominal one-step Jacobian of ``(v_y, yaw_rate)`` on itself, ``J (N, 2, 2)``
    the tracking GP's gradient in the same block. Where the nominal prediction is stable the GP may
    take damping away, down to instability: an oversteering car above its critical speed is unstable,
    and the GP that says so is right (measured on a randomized BMW at 45 m/s: capping it there lost
    laps the full gradient completed). Where the nominal prediction is already unstable (the tires
    linearised at or past their peak: a slide in a hairpin) the GP, whose one-step errors were
    fitted on laps below that edge, may not add to it (t = 0 always qualifies).
    docs/decisions.md, issue 37, stop 49."""
    r0 = spectral_radius2(A0)
    bound = r0 + 1e-9
    t = np.zeros(len(A0))
    open_ = r0 >= 1.0
    t[~open_] = 1.0
    for share in STABLE_SHARES:
        if not open_.any():
            break
        ok = open_ & (spectral_radius2(A0 + share * J) <= bound)
        t[ok] = share
        open_ &= ~ok
    return t


def steer_share(b0: np.ndarray, jb: np.ndarray, keep: float) -> np.ndarray:
    """Share ``t (N,)`` of the GP's gradient kept per step so that the steering's one-step gain on
    the yaw rate, ``b0 + t jb``, stays at least ``keep`` times the nominal ``b0`` (where ``b0 > 0``;
    1 elsewhere and where the gradient adds gain).

    The GP may learn that the steering does less than the nominal model says (a lag, a weaker front
    axle); it may not turn the sign. Fitted on laps whose front axle went past its peak, the GP's
    gradient reversed the gain on 14 % of the horizon's steps of a randomized BMW's GP lap
    (nominal +0.09, with the GP -0.25 to -0.30 at 13 m/s out of the hairpin): the QP steered into
    an over-rotation, held the steering at its front bound while the car turned 0.4 rad/s more
    than the reference, and the car crossed the track and stalled. On completed laps of three other
    plants the GP left 0.19 to 0.57 of the nominal gain at the 0.1 % quantile, 0.37 to 0.61 at the 1 %
    (docs/decisions.md, issue 37, stop 61)."""
    b0, jb = np.asarray(b0, float), np.asarray(jb, float)
    t = np.ones(len(b0))
    cut = (b0 > 0.0) & (b0 + jb < keep * b0)
    t[cut] = (1.0 - keep) * b0[cut] / -jb[cut]
    return t


def trust_share(extrapolation: np.ndarray) -> np.ndarray:
    """Share ``t (N,)`` of the GP's gradient kept per step: ``1 - extrapolation`` (the latent std
    over the prior std, ``GPPredictor.extrapolation``), clipped to [0, 1]; 1 where it is unknown
    (NaN: a backend without a prior variance).

    At the edge of its data a squared-exponential GP's gradient is mostly its mean falling back to
    the prior, not the car. Measured on a randomized BMW's GP lap at 38 to 40 m/s in a long bend
    where the extrapolation read 0.69 to 0.97 (median 0.08 along the lap): with the GP's mean and
    its whole gradient the lap was lost on 4 of 4 noise draws, with either one alone on none, and
    with the gradient scaled by this share on none. On the same car's lap of another chain the
    whole GP lost 4 of 4 draws, the gradient scaled 3 of 4, the nominal model alone none: the mean
    at the edge of the data costs laps too (branch ``s63-mean`` scales it as well; not benchmarked
    whole; docs/decisions.md, issue 37, stops 62 and 63)."""
    return np.clip(1.0 - np.nan_to_num(np.asarray(extrapolation, float), nan=0.0), 0.0, 1.0)


def _at_s(X: np.ndarray, s0: float) -> np.ndarray:
    """States ``X (n, 6)`` with relative ``s`` moved by ``s0`` (a copy)."""
    X = X.copy()
    X[:, State.S] += s0
    return X


class Linearisation:
    """The step function mapped over the horizon, ``(X (N, 6), U (N, 2), K (N, 3)) -> (x_next
    (N, 6), A (N, 6, 6), B (N, 6, 2))``, evaluated into preallocated arrays with CasADi's buffer
    interface: the function writes its column-major outputs straight into C-ordered NumPy arrays
    (no DM objects; measured 3.1 -> 0.33 ms per call with the conversions and transposes, machine
    under load). One instance per controller (the buffers are its own)."""

    def __init__(self, f, N: int) -> None:
        self._buf, self._eval = f.buffer()
        self._args = [np.empty((N, 6)), np.empty((N, 2)), np.empty((N, 3))]
        self._res = [np.empty((N, 6)), np.empty((N, 6, 6)), np.empty((N, 6, 2))]
        for i, a in enumerate(self._args):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate(self._res):
            self._buf.set_res(i, memoryview(a))

    def __call__(self, X: np.ndarray, U: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        for a, v in zip(self._args, (X, U, K)):
            a[...] = v
        self._eval()
        return tuple(r.copy() for r in self._res)


class TrackingMPC:
    """Tracking MPC on one plan. ``gp`` predicts ``Z (m, 3) -> (mean (m, 2), var (m, 2))``."""

    def __init__(self, model, track, plan, settings: MPCSettings = MPCSettings(), gp=None, grid=None, alpha: float = 0.0) -> None:
        from gprace.registry import solvers

        if not 0.0 <= alpha <= 1.0:
            raise ConfigError(f"alpha must be in [0, 1], got {alpha}")
        if alpha > 0 and grid is None:
            raise ConfigError("exploration (alpha > 0) needs a candidate grid from a trained tracking GP")
        self.model, self.track, self.plan, self.settings = model, track, plan, settings
        self.gp, self.grid, self.alpha = gp, grid, float(alpha)
        self.inputs = tuple(getattr(gp, "inputs", DYN_INPUTS))  # a plain callable takes the paper's inputs
        self.N, self.dt = settings.N, settings.dt
        p = model.params
        self.slip_max = settings.grip_share * peak_slip(p.br, p.cr)
        self.front_max = None if settings.front_share is None else settings.front_share * peak_slip(p.bf, p.cf)
        self.quantile = quantile_factor(settings.beta)
        self.qp = solvers.create(settings.solver, settings.N, settings.weights)
        self._damped_qps: dict[float, object] = {}  # by steering-rate factor (the stability envelope damps the steering)
        self.steer_damping = 1.0
        self._lin = self._build_linearisation()
        lim = model.vehicle.limits
        self.u_lo = np.array([-lim.steering_max, lim.accel_min])
        self.u_hi = np.array([lim.steering_max, lim.accel_max])
        self.bounds = (self.u_lo, self.u_hi)  # this period's input bounds (the stability envelope narrows them)
        self.half = 0.5 * model.vehicle.width + settings.margin
        self.steer_step = lim.steering_rate_max * self.dt  # the actuator's rate limit per period
        self.prev_x: np.ndarray | None = None  # (N, 6) absolute s
        self.prev_u: np.ndarray | None = None  # (N, 2)
        self.delta_prev = self.a_prev = 0.0
        self.fallbacks = 0
        self.steps = 0
        self.last_target: np.ndarray | None = None
        self.speed_factor = 1.0
        self.gp_share: np.ndarray | None = None  # share of the GP's gradient used per step (last period)
        self.use_gp = True  # False: the nominal model alone this period (drive: while the envelope is active)
        self.delay = float(settings.delay)
        self.sent: np.ndarray | None = None  # inputs sent, oldest first (the delay's history)
        self.predicted: np.ndarray | None = None  # the state the last QP started from (after the delay)

    def _build_linearisation(self):
        import casadi as ca

        from gprace.compiled import compiled_function

        if self.model.nx != 6:
            raise ConfigError("tracking MPC: the controller's vehicle has effect states; use the stateless nominal vehicle")
        x = ca.SX.sym("x", 6)
        u = ca.SX.sym("u", 2)
        k = ca.SX.sym("k", 3)  # curvature, its slope and the arc length they are taken at
        # curvature affine in s over the step (RK4 stages and the Jacobian see it change): at
        # 40 m/s a step covers 2 m, and in the S-bend of gprace_ring kappa moves by 0.014 1/m
        # within one step. Held constant (the paper's), the heading predicted over one step was
        # off by 0.015 rad, i.e. 0.3 rad/s of yaw rate the QP then commanded: the nominal MPC
        # spun the commonroad BMW on a plan that drives straight through the bend.
        kappa_of_s = lambda ss: k[0] + k[1] * (ss - k[2])  # noqa: E731
        if self.settings.integrator == "euler":
            xn = x + self.dt * self.model.symbolic(x, u, kappa_of_s(x[State.S]))
        else:  # "rk4" (MPCSettings admits no other)
            xn = self.model.rk4_expression(x, u, kappa_of_s, self.dt)
        # Jacobians transposed and dense: column-major A_k^T is A_k in C order (see Linearisation)
        f = ca.Function("mpc_lin", [x, u, k], [xn, ca.densify(ca.jacobian(xn, x).T), ca.densify(ca.jacobian(xn, u).T)])
        return Linearisation(compiled_function(f.map(self.N)), self.N)

    def _build_delay_step(self):
        """``(x, u, [kappa, slope, s], h) -> x`` after ``h`` seconds (RK4, curvature affine in s):
        the prediction over the delay, compiled (numpy's RK4 took 6 ms of a 30 ms period under load)."""
        import casadi as ca

        from gprace.compiled import compiled_function

        x, u, k, h = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("k", 3), ca.SX.sym("h")
        xn = self.model.rk4_expression(x, u, lambda ss: k[0] + k[1] * (ss - k[2]), h)
        return compiled_function(ca.Function("mpc_delay_step", [x, u, k, h], [xn]))

    def _delay_step(self, x: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
        if self.__dict__.get("_step_fn") is None:
            self._step_fn = self._build_delay_step()
        s = float(x[State.S])
        kap, up, dn = self.track.kappa(np.array([s, s + KAPPA_DS, s - KAPPA_DS]))
        return np.asarray(self._step_fn(x, u, [kap, (up - dn) / (2 * KAPPA_DS), s], h)).ravel()

    def reset(self, delta_prev: float = 0.0, a_prev: float = 0.0) -> None:
        from gprace.mpc.delay import history_length

        self.prev_x = self.prev_u = None
        self.delta_prev, self.a_prev = float(delta_prev), float(a_prev)
        self.sent = np.tile([self.delta_prev, self.a_prev], (history_length(self.delay, self.dt), 1))

    def set_delay(self, delay: float) -> None:
        """Predict over ``delay`` [s] from the next period on (checked against the horizon)."""
        from gprace.mpc.delay import check, history_length

        self.delay = check(delay, self.N, self.dt)
        need = history_length(self.delay, self.dt)
        last = self.sent[-1:] if self.sent is not None else np.array([[self.delta_prev, self.a_prev]])
        old = self.sent if self.sent is not None else last
        self.sent = np.vstack([np.repeat(old[:1], max(need - len(old), 0), axis=0), old])[-need:]

    def set_plan(self, plan) -> None:
        """Track ``plan`` from the next period on (same track; the warm start is kept)."""
        self.plan = plan

    # --------------------------------------------------------------------------------------
    def reference(self, s_abs: float) -> tuple[np.ndarray, np.ndarray]:
        """``xref`` (N, 6) for k = 1..N with relative s, ``uref`` (N, 2) for k = 0..N-1 (at
        ``speed_factor`` times the plan's speed)."""
        rho = self.speed_factor
        t0 = float(self.plan.time_at(s_abs))
        ts = t0 + rho * self.dt * np.arange(self.N + 1)
        X, U = self.plan.at_time(ts)
        X[:, State.S] -= X[0, State.S]
        if rho != 1.0:
            X[:, State.V_X:State.YAW_RATE + 1] *= rho
            U[:, Input.A_X] *= rho * rho
        return X[1:], U[:-1]

    def explore(self, xref: np.ndarray, uref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Algorithm 1 on the reference (no-op at alpha = 0)."""
        if self.alpha == 0.0 or self.grid is None:
            return xref, uref
        from gprace.explore.algorithm import CandidateGrid, select_target

        if uref[:, Input.A_X].min() < self.settings.explore_brake * self.u_lo[Input.A_X]:
            return xref, uref  # braking zone: perform, do not explore
        z_tilde = dyn_inputs(xref[:1], uref[:1], self.inputs)[0]
        g = self.grid
        near = np.linalg.norm((g.Z - z_tilde) / g.scale, axis=1) <= self.settings.explore_radius
        if not near.any():
            return xref, uref
        sub = CandidateGrid(g.Z[near], g.v[near], g.scale)
        z = sub.Z[select_target(sub, z_tilde, self.alpha)]
        self.last_target = z
        # the inverse feature map: the lateral features become the reference over the horizon;
        # v_x and a_x (feature set "full") stay the performance reference's (decision: explore
        # the lateral dynamics, not the speed profile)
        xref, uref = xref.copy(), uref.copy()
        ref = {"x": xref, "u": uref}
        for j, name in enumerate(self.inputs):
            if name in EXPLORED:
                where, col = _REF[name]
                ref[where][:, col] = z[j]
        return xref, uref

    def build(self, x_meas: np.ndarray) -> tuple[LtvProblem, dict]:
        """The QP of this period (also used by benchmarks) and side information."""
        N = self.N
        s0 = float(x_meas[State.S])
        xref, uref = self.reference(s0)
        xr0 = xref
        xref, uref = self.explore(xref, uref)
        # nominal trajectory: previous solution shifted (or the reference), from the measured state
        if self.prev_x is None:
            Xb = np.vstack([x_meas, _at_s(xref[:-1], s0)])
            Ub = uref.copy()
        else:
            Xb = np.vstack([x_meas, self.prev_x[1:]])
            Ub = np.vstack([self.prev_u[1:], self.prev_u[-1:]])
        Xb[:, State.S] = np.maximum.accumulate(Xb[:, State.S])  # progress along the nominal cannot go back
        p = self.model.params
        if self.settings.grip:
            # a car already past the rear bound is brought back within RECOVER_STEPS, not at once:
            # measured in the fast chicane of gprace_ring, demanding it at the first step made the
            # QP yank the steering and spun the car the nominal MPC kept
            a_now = abs(float(rear_slip_rows(x_meas[None, :6], p.lr, p.vmin)[0][0]))
            back = a_now * (1.0 - np.arange(1, N + 1) / RECOVER_STEPS)  # (N,) for x_1..x_N
            # after its first step (the measured state) the linearisation point keeps the rear
            # within the bound the grip rows put on the QP (:func:`rear_within`)
            Xb[1:] = rear_within(Xb[1:], p, np.maximum(self.slip_max, back[:-1]))
        if self.front_max is not None:
            # linearise where the front tire still answers the steering: past its peak the tangent
            # says that more steering turns the car less, and the QP steers in to stop an
            # over-rotation. Measured on a randomized BMW's GP lap (docs/decisions.md, issue 37,
            # stop 51): along a warm start steered to 1.2 times the front peak, B[r, delta] fell
            # from +0.62 to -0.08 and the car left the track on the inside of a 40 m/s corner.
            # Stop 53: that lap re-driven completes on 4 of 4 noise seeds with this, 0 of 4 without
            kin = front_heading(Xb, p.lf, p.vmin)
            lin_max = LINEARISE_FRONT * peak_slip(p.bf, p.cf)
            Ub[:, Input.DELTA] = np.clip(Ub[:, Input.DELTA], kin - lin_max, kin + lin_max)
        sb = Xb[:, State.S]
        kap, k_up, k_dn = self.track.kappa(np.concatenate([sb, sb + KAPPA_DS, sb - KAPPA_DS])).reshape(3, -1)
        slope = (k_up - k_dn) / (2 * KAPPA_DS)
        xn, A, B = self._lin(Xb, Ub, np.column_stack([kap, slope, sb]))
        Xr = Xb.copy()
        Xr[:, State.S] -= s0
        xn[:, State.S] -= s0
        var = np.zeros((N, 2))
        mean = np.zeros((N, 2))
        if self.gp is not None and self.use_gp:
            if hasattr(self.gp, "at_with_gradient"):
                # the GP is linearised with the nominal model: its mean is evaluated on the nominal
                # trajectory (the paper) and its gradient enters A and B. Measured: with the mean
                # as a constant only, a GP that learned the steering lag (mean falling with delta)
                # made successive solutions flip sign until full lock on a straight.
                mean, var, J = self.gp.at_with_gradient(Xb, Ub)
                trust = self.settings.gp_trust and hasattr(self.gp, "extrapolation_of")
                A, B = self._compensate(A, B, J, self.gp.extrapolation_of(var) if trust else None)
            else:
                mean, var = self.gp(dyn_inputs(Xb, Ub, self.inputs))
        c = xn - np.einsum("kij,kj->ki", A, Xr) - np.einsum("kij,kj->ki", B, Ub)
        c[:, GP_STATES] += mean
        Sig = covariances(A, var)
        gamma = self.quantile * np.sqrt(np.maximum(Sig[:, EY, EY], 0.0))
        s_pred = Xb[:, State.S] + (xn[:, State.S] - Xr[:, State.S])  # absolute s at k = 1..N along the nominal
        hi = self.track.width_left(s_pred) - self.half - gamma
        lo = -self.track.width_right(s_pred) + self.half + gamma
        mid = 0.5 * (hi + lo)
        bad = lo > hi
        hi[bad], lo[bad] = mid[bad], mid[bad]
        x0 = x_meas.copy()
        x0[State.S] = 0.0
        grip = {}
        if self.settings.grip:
            # rear slip linearised about the REFERENCE x_1..x_N: a + G (x - xref). Measured: about
            # the previous solution (as the dynamics) the rows fed back on themselves, and an
            # alternating exploration target made successive solutions flip until full lock.
            a_r, G = rear_slip_rows(xr0, p.lr, p.vmin)
            if not self.settings.slip_by_speed:
                # the slip angle falls with v_x, but drive on a sliding rear axle takes its lateral
                # grip (combined slip, which the nominal model lacks): the row may not be met by
                # speeding up. Measured on the iteration-0 lap of a randomized BMW with a light
                # rear (docs/decisions.md, issue 37, stop 44): with the front bound alone it spun
                # in the hairpin, with this as well it completed
                G[:, State.V_X] = 0.0
            sig_a = np.sqrt(np.maximum(np.einsum("ki,kij,kj->k", G, Sig, G), 0.0))
            off = a_r - np.einsum("ki,ki->k", G, xr0)
            room = np.maximum(self.slip_max - self.quantile * sig_a, 0.2 * self.slip_max)
            # the uncertainty tightens the bound down to the reference's own rear slip, not below:
            # rows the reference breaks pull the car off its line to meet them. Measured on the
            # nominal plant at 0.95 of the lateral limit of circle_100 with a GP of variance 0.05:
            # rows tightened to 0.3 of the bound, below the reference's 0.68, put the car 0.32 m
            # off its line, 0.08 m with this floor (tests/test_mpc_tire_bounds.py). On a GP lap of
            # a randomized BMW it binds in 2 % of the periods, in the hairpin (issue 37, stop 51)
            room = np.maximum(room, np.minimum(np.abs(a_r), self.slip_max))
            room = np.maximum(room, back)
            grip = {"grip_G": G, "grip_lo": -room - off, "grip_hi": room - off}
        u_lo, u_hi = self.front_bounds(x_meas, *self.bounds)
        u_lo, u_hi = self.ellipse_bounds(x_meas, uref, u_lo, u_hi)
        if self.settings.hold_drive_when_fast:
            u_hi = fast_drive_cap(float(x_meas[State.V_X]), float(xref[0, State.V_X]), uref[:, Input.A_X], u_lo, u_hi)
        pb = LtvProblem(A, B, c, x0, xref, uref, lo, hi, u_lo, u_hi, self.delta_prev, self.settings.weights, **grip,
                        a_prev=self.a_prev, steer_step=self.steer_step)
        return pb, {"gamma": gamma, "s0": s0, "xref": xref, "uref": uref, "explored": xref is not xr0}

    def _compensate(self, A: np.ndarray, B: np.ndarray, J: np.ndarray,
                    extrapolation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` with the GP's gradient ``J (N, 2, d)`` added to the nominal Jacobians. With ``settings.gp_stable`` the gradient of a step is
        shrunk where the nominal lateral block is unstable and the gradient makes it more so
        (:func:`stable_share`), and where it would leave the steering less than ``gp_steer_keep``
        of its nominal gain on the yaw rate (:func:`steer_share`); and as the GP's
        ``extrapolation (N,)`` nears its prior (:func:`trust_share`; None: not read, as with
        ``settings.gp_trust`` off). ``self.gp_share (N,)`` keeps the share used."""
        N = len(A)
        JA = np.zeros((N, 2, 6))
        JB = np.zeros((N, 2, 2))
        for j, name in enumerate(self.inputs):
            where, col = _REF[name]
            (JA if where == "x" else JB)[:, :, col] += J[:, :, j]
        t = np.ones(N)
        if self.settings.gp_stable:
            t = stable_share(A[:, GP_STATES, GP_STATES], JA[:, :, GP_STATES])
        if self.settings.gp_steer_keep > 0:
            r, d = State.YAW_RATE, Input.DELTA
            t = np.minimum(t, steer_share(B[:, r, d], JB[:, r - GP_STATES.start, d], self.settings.gp_steer_keep))
        if extrapolation is not None:
            t = np.minimum(t, trust_share(extrapolation))
        self.gp_share = t
        A, B = A.copy(), B.copy()
        A[:, GP_STATES] += JA * t[:, None, None]
        B[:, GP_STATES] += JB * t[:, None, None]
        return A, B

    def front_bounds(self, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Input bounds with the steering kept near the front tire's peak (``settings.front_share``).

        The front slip angle is ``delta - atan((v_y + l_f r) / v_x)``; the steering range of this
        period is the one that keeps it within ``front_max`` at the state ``x`` the QP starts
        from, always joined with the steering the rate limit can reach from the last command (the
        QP stays feasible; a wheel far outside comes back at the actuator's rate). Beyond the
        peak the nominal tire gives no more force, and the linearised model no longer says which
        way the car turns: measured on a randomized BMW ploughing out of a slide at a corner exit,
        the QP ramped the steering at the rate limit to full lock (1.07 rad, front slip 5.7 times
        the peak) over 1.5 s while the yaw rate stayed near 0.3 rad/s, and the car stopped on the
        track (docs/decisions.md, issue 37, stop 44).
        """
        if self.front_max is None:
            return lo, hi
        p = self.model.params
        kin = float(front_heading(x, p.lf, p.vmin)[0])
        reach_lo, reach_hi = self.delta_prev - self.steer_step, self.delta_prev + self.steer_step
        b_lo = max(lo[Input.DELTA], min(kin - self.front_max, reach_hi))
        b_hi = min(hi[Input.DELTA], max(kin + self.front_max, reach_lo))
        if b_lo > b_hi:  # the box and the range do not meet: the bound nearest the box
            b_lo = b_hi = hi[Input.DELTA] if b_hi < kin else lo[Input.DELTA]
        lo, hi = lo.copy(), hi.copy()
        lo[Input.DELTA], hi[Input.DELTA] = b_lo, b_hi
        return lo, hi

    def plan_limits(self) -> np.ndarray:
        """The plan's limits ``(lateral, drive, brake)`` [m/s^2] (``plan.meta["limits"]``, what the
        car has been shown to take), else the nominal model's (:attr:`nominal_limits`)."""
        lim = self.plan.meta.get("limits")
        return np.asarray(lim, dtype=float) if lim is not None and len(lim) == 3 else self.nominal_limits

    @cached_property
    def nominal_limits(self) -> np.ndarray:
        """The nominal model's limits ``(lateral, drive, brake)`` [m/s^2], solved once per MPC: the
        lateral one is a steady-corner solve of about 15 ms, and the drive loop and the ellipse read
        the limits every period."""
        from gprace.plan.curvature import lateral_limit

        v = self.model.vehicle.limits
        return np.array([lateral_limit(self.model), v.accel_max, -v.accel_min])

    def ellipse_bounds(self, x: np.ndarray, uref: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The longitudinal range left by the friction ellipse of the plan's limits (``settings.ellipse``).

        The plan's limits ``(lateral, drive, brake)`` [m/s^2] (``plan.meta["limits"]``, what the car
        has been shown to take; else the nominal model's) and the lateral acceleration the car uses
        now, ``|v_x r|``: drive and braking are held to ``sqrt(1 - (a_y / lateral)^2)`` of their
        limits, never below ``ellipse_floor`` of them nor below what the reference itself asks now.
        The nominal model has no combined slip: to it, drive and braking cost the tires nothing
        sideways, and the QP used the whole range to make up a metre of progress while the car was
        cornering at its limit (measured: full drive, 3.5 m/s^2, at 9.1 m/s^2 lateral on a
        randomized BMW whose plan asked 0.3 there; the rear stepped out and the lap was lost;
        docs/decisions.md, issue 37, stop 44).

        The braking limit has ``brake_headroom`` on top. A plan brakes at its limit, and a tracking
        controller held to exactly the reference's own braking can never shed a speed excess it
        carries into the braking zone. Measured on the unseen plants: cars 1 to 2.5 m/s too fast
        from the braking point on, braking held at the plan's 3.2 to 3.8 m/s^2 on cars that can
        brake at 5, carried the excess into the corner and left the track or spun; of the 8 GP laps
        stop 49 lost, 7 complete with the headroom (docs/decisions.md, issue 37, stop 50).
        """
        share = self.settings.ellipse
        if share is None:
            return lo, hi
        lat, drive, brake = share * self.plan_limits()
        brake *= 1.0 + self.settings.brake_headroom
        use = min(1.0, abs(float(x[State.V_X] * x[State.YAW_RATE])) / max(lat, 1e-9))
        room = max(float(np.sqrt(1.0 - use * use)), self.settings.ellipse_floor)
        a_ref = uref[:1, Input.A_X]  # what the reference asks now (later steps are bounded again when they come)
        lo, hi = lo.copy(), hi.copy()
        hi[Input.A_X] = max(min(hi[Input.A_X], room * drive), min(float(a_ref.max()), hi[Input.A_X]), lo[Input.A_X])
        lo[Input.A_X] = min(max(lo[Input.A_X], -room * brake), max(float(a_ref.min()), lo[Input.A_X]), hi[Input.A_X])
        return lo, hi

    def _qp(self):
        """The QP of this period: :attr:`qp`, or with the steering-rate weight times ``steer_damping``
        when that is not 1 (made once per factor)."""
        f = float(self.steer_damping)
        if f == 1.0:
            return self.qp
        if f not in self._damped_qps:
            from gprace.registry import solvers

            w = self.settings.weights
            self._damped_qps[f] = solvers.create(self.settings.solver, self.N,
                                                 w.model_copy(update={"r_delta": w.r_delta * f}))
        return self._damped_qps[f]

    def step(self, x_meas: np.ndarray) -> tuple[np.ndarray, dict]:
        """Input for the measured state (6,); info has solve time, status, fallback flag."""
        from gprace.mpc.delay import predict

        self.steps += 1
        if self.sent is None:
            self.reset(self.delta_prev, self.a_prev)
        x = np.asarray(x_meas, dtype=float)
        if self.delay > 0:
            x = predict(self._delay_step, x, self.sent, self.delay, self.dt)
        self.predicted = x
        pb, info = self.build(x)
        res = self._qp().solve(pb)
        fallback = not res.status.usable
        if fallback:
            self.fallbacks += 1
            if self.prev_u is not None:
                u_seq = np.vstack([self.prev_u[1:], self.prev_u[-1:]])
                x_seq = np.vstack([self.prev_x[1:], self.prev_x[-1:]])
            else:
                u_seq = info["uref"].copy()
                x_seq = _at_s(info["xref"], info["s0"])
        else:
            u_seq = res.u
            x_seq = res.x.copy()
            x_seq[:, State.S] += info["s0"]
        self.prev_u, self.prev_x = u_seq, x_seq
        u = np.clip(u_seq[0], pb.u_lo, pb.u_hi)
        self.delta_prev, self.a_prev = float(u[Input.DELTA]), float(u[Input.A_X])
        self.sent = np.vstack([self.sent[1:], u[None, :]])
        info.update(solve_time=res.solve_time, status=res.status, fallback=fallback, iterations=res.iterations)
        return u, info
