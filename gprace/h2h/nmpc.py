"""The head-to-head NMPC (paper problem "opponent_problem"), one builder for both cars.

    min  alpha J_expl + (1 - alpha) (sum q_c e_y^2 + u'R u + du'R_d du - q_s (s_N - s_0))
         + soft-constraint penalties (+ the opponent's blocking term)
    s.t. x_{k+1} = RK4(x_k, u_k, kappa_k)        Frenet dynamic bicycle (gprace.model), dt/substeps,
                                                 kinematic at a crawl (:func:`blended_rk4`)
         -w_r + c(e_psi) <= e_y <= w_l - c(e_psi) soft (slack per stage; c covers the footprint
                                                 at any heading, :func:`border_margin`)
         u_min <= u <= u_max,  v_x <= v_max,  v_x - v_soft <= slack
         1 - E_k(disk_j) <= slack                 ego only: 4 disks outside each predicted ellipse

Decision variables are ordered stage-wise ``[u_0, x_1, sl_1, u_1, x_2, sl_2, ...]`` with each
stage's dynamics constraint before its path constraints (the ordering fatrop and sparse linear
solvers like). The NLP is SX, solved by IPOPT (MUMPS) through ``nlpsol`` and warm-started with the
previous primal and dual solution shifted by one stage (the new last states extrapolated).

Collision geometry. The ellipse around an opponent pose lives in the global frame, rotated by the
opponent's heading. The ego's global position is a function of (s, e_y) through the track; inside
the NLP it is linearised per stage around the previous plan: ``p = c_k + t_k (s - sigma_k) + n_k e_y``
and heading ``theta_k + kappa_k (s - sigma_k) + e_psi``. The warm start keeps ``s - sigma_k`` at a
few centimetres, so the error is second order (kappa (s - sigma)^2 / 2 < 1 mm here).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from gprace.h2h.config import H2HConfig, MPCConfig
from gprace.interrupt import check as check_interrupt
from gprace.model import NominalModel, State
from gprace.model.nominal import rk4_expression
from gprace.solvers import SolveStatus, all_finite, ipopt_status

NX, NU, NS = 6, 2, 3  # states, inputs, slacks per stage (track, speed, collision)
N_GLOBAL = 9  # x0 (6), u_prev (2), alpha
N_STAGE = 19
# per-stage parameter offsets
KAPPA, WL, WR, EY_OTHER, W_BLOCK, S_REF, EY_REF, V_REF = range(8)
LIN_CX, LIN_CY, LIN_TH, LIN_SIG, LIN_KAP = range(8, 13)
OPP_X, OPP_Y, OPP_PSI, OPP_A, OPP_B, OPP_ON = range(13, 19)
DISK_OFFSETS = (-0.135, -0.045, 0.045, 0.135)
IPOPT_OPTIONS = {
    # one acceptable iterate (|KKT| <= 1e-4) ends a solve: 17 % fewer iterations than three in a
    # replay of 560 race solves, first inputs within 1.6e-3 (p95) of the tight solution, no more
    # failures (docs/decisions.md, issue 17)
    "print_level": 0, "sb": "yes", "tol": 1e-6, "acceptable_tol": 1e-4, "acceptable_iter": 1,
    "warm_start_init_point": "yes", "warm_start_bound_push": 1e-6, "warm_start_mult_bound_push": 1e-6,
    "mu_strategy": "adaptive", "linear_solver": "mumps",
    # without MUMPS's scaling and permuting of the KKT matrix: solutions agree to 1e-11, and the
    # solve took 5 to 13 % less CPU in two of three replays of 566 to 650 race solves (no
    # difference in the third, under heavy load; docs/decisions.md)
    "mumps_permuting_scaling": 0, "mumps_scaling": 0,
}

V_X_MIN = 0.05  # [m/s] lower bound of v_x in the NLP (the dynamic model is singular at standstill)
# The prediction model turns kinematic at a crawl: the dynamic bicycle's lateral mode has an
# eigenvalue of about -22/v_x per second (1:10 car), so RK4 with the NLP's 0.05 s sub-step is
# unstable below about 0.4 m/s (|h lambda| > 2.79; 10.9 at 0.1 m/s, where one sub-step amplifies
# an error 400 times). Blended by a smooth step of v_x between these speeds [m/s]:
KIN_BLEND = (0.25, 0.5)
KIN_TAU = 0.05  # [s] v_y and the yaw rate relax to their kinematic values (h / tau = 1: stable)
# The border margin is the configured one (half the car's length) up to a heading error of about
# 0.29 rad, and beyond it the footprint's lateral extent plus this buffer [m] (2 x the e_y sensor std):
MARGIN_BUFFER = 0.01
MARGIN_SMOOTH = 0.005  # [m] the quadratic joining the two
STALE_STEPS = 2  # fallbacks in a row on the shifted plan before the steering holds the heading
HOLD_GAIN = 1.0  # [rad/rad] heading error to steering of that hold


def blended_rk4(model: NominalModel, dt: float, substeps: int):
    """CasADi ``F(x, u, kappa)``: RK4 over ``dt`` of the Frenet dynamic bicycle blended into a
    kinematic bicycle at low speed, ``f = w f_dyn + (1 - w) f_kin`` with ``w`` a smooth step of
    ``v_x`` over :data:`KIN_BLEND` (racing stacks blend the same way; the kinematic model has no
    tyre mode to go unstable). ``f_kin``: ``v_x' = a_x`` minus rolling and air resistance,
    ``v_y`` and the yaw rate relaxing to ``v_x tan(delta) l_r / L`` and ``v_x tan(delta) / L``
    (time constant :data:`KIN_TAU`); the Frenet rows (``e_psi``, ``e_y``, ``s``) are the same in
    both. Above ``KIN_BLEND[1]`` it is the dynamic model's RK4, bit for bit."""
    import casadi as ca

    p, (v0, v1) = model.params, KIN_BLEND
    x, u, kappa = ca.SX.sym("x", model.nx), ca.SX.sym("u", 2), ca.SX.sym("kappa")
    fd = model.casadi_f()(x, u, kappa)
    vx, L = x[State.V_X], p.lf + p.lr
    t = ca.fmin(ca.fmax((vx - v0) / (v1 - v0), 0.0), 1.0)
    w = t * t * (3.0 - 2.0 * t)
    yaw_kin = vx * ca.tan(u[0]) / L
    fk = ca.vertcat(u[1] - p.crr * p.g - p.cxw * vx * vx / p.m, (p.lr * yaw_kin - x[State.V_Y]) / KIN_TAU,
                    (yaw_kin - x[State.YAW_RATE]) / KIN_TAU)
    f = ca.Function("f_blend", [x, u, kappa], [ca.vertcat(w * fd[:3] + (1.0 - w) * fk, fd[3:])])
    xn = rk4_expression(lambda xx: f(xx, u, kappa), x, dt, substeps)
    return ca.Function("rk4_blend", [x, u, kappa], [xn], ["x", "u", "kappa"], ["x_next"])


def border_margin(epsi, margin: float, length: float, width: float):
    """The distance the car's centre keeps from a border at heading error ``epsi`` (CasADi):
    ``margin`` as long as it covers the footprint's lateral extent ``l/2 |sin e_psi| + w/2 cos e_psi``
    plus :data:`MARGIN_BUFFER`, beyond that the extent (joined by a quadratic over
    :data:`MARGIN_SMOOTH`, so the margin is once differentiable and exactly ``margin`` below about
    0.29 rad: the NLP there is the one without this term). A margin of half the length alone covers
    the corners only up to 0.43 rad, and most border hits after the runs of failed solves were gone
    were crawls along a border at 0.5 to 0.78 rad (docs/decisions.md, issue 17)."""
    import casadi as ca

    ext = 0.5 * length * ca.sqrt(ca.sin(epsi) ** 2 + 1e-6) + 0.5 * width * ca.cos(epsi) + MARGIN_BUFFER
    r, d = ext - margin, MARGIN_SMOOTH
    return margin + ca.if_else(r <= 0, 0, ca.if_else(r < d, r * r / (2 * d), r - d / 2))


@dataclass
class StageData:
    """Numeric per-stage data (arrays of length N); built by the caller each step."""

    kappa: np.ndarray
    wl: np.ndarray
    wr: np.ndarray
    ey_other: np.ndarray | None = None
    w_block: np.ndarray | None = None
    ref: np.ndarray | None = None  # (N, 3): s, e_y, v_x
    lin: np.ndarray | None = None  # (N, 5): cx, cy, theta, sigma, kappa
    opp: np.ndarray | None = None  # (N, 6): x, y, psi, a, b, on


@dataclass
class Solution:
    X: np.ndarray  # (N+1, 6) planned states, X[0] = x0
    U: np.ndarray  # (N, 2)
    slack: np.ndarray  # (N, 3)
    ok: bool
    status: str
    seconds: float
    fallback: bool = False


@dataclass
class NMPC:
    """Build once per (vehicle, settings, collision flag); call :meth:`solve` every step."""

    model: NominalModel
    mpc: MPCConfig
    h2h: H2HConfig
    collision: bool = False
    failures: int = 0
    solves: int = 0
    _warm: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        import casadi as ca

        N, c, h = self.h2h.horizon, self.mpc, self.h2h
        F = blended_rk4(self.model, h.dt, c.substeps)
        p = ca.SX.sym("p", N_GLOBAL + N_STAGE * N)
        x0, u_prev, alpha = p[0:6], p[6:8], p[8]
        w, g, lbg, ubg = [], [], [], []
        lbw, ubw = [], []
        racing, explore, penalty = 0, 0, 0
        xk, uk_prev = x0, u_prev
        R, Rd = np.array(c.r_input), np.array(c.r_rate)
        for k in range(N):
            q = p[N_GLOBAL + N_STAGE * k: N_GLOBAL + N_STAGE * (k + 1)]
            u = ca.SX.sym(f"u{k}", NU)
            x = ca.SX.sym(f"x{k + 1}", NX)
            sl = ca.SX.sym(f"sl{k + 1}", NS)
            w += [u, x, sl]
            lbw += [-c.steering_max, c.accel[0]] + [V_X_MIN, -5, -10, -np.pi, -5, -1e3] + [0, 0, 0]
            ubw += [c.steering_max, c.accel[1]] + [c.speed_max, 5, 10, np.pi, 5, 1e6] + [np.inf] * 3
            # dynamics first, then the stage's path constraints
            g.append(x - F(xk, u, q[KAPPA]))
            lbg += [0.0] * NX
            ubg += [0.0] * NX
            ey, s, vx = x[State.E_Y], x[State.S], x[State.V_X]
            margin = border_margin(x[State.E_PSI], c.border_margin, h.car_length, h.car_width)
            g.append(ey - (q[WL] - margin) - sl[0])
            g.append(-(q[WR] - margin) - ey - sl[0])
            g.append(vx - c.speed_soft - sl[1])
            lbg += [-np.inf] * 3
            ubg += [0.0] * 3
            if self.collision:
                dsg = s - q[LIN_SIG]
                th = q[LIN_TH]
                px = q[LIN_CX] + ca.cos(th) * dsg - ca.sin(th) * ey
                py = q[LIN_CY] + ca.sin(th) * dsg + ca.cos(th) * ey
                psi = th + q[LIN_KAP] * dsg + x[State.E_PSI]
                co, so = ca.cos(q[OPP_PSI]), ca.sin(q[OPP_PSI])
                for d in DISK_OFFSETS:
                    rx = px + d * ca.cos(psi) - q[OPP_X]
                    ry = py + d * ca.sin(psi) - q[OPP_Y]
                    lx = co * rx + so * ry
                    ly = -so * rx + co * ry
                    e = (lx / q[OPP_A]) ** 2 + (ly / q[OPP_B]) ** 2
                    g.append(q[OPP_ON] * (1 - e) - sl[2])
                    lbg.append(-np.inf)
                    ubg.append(0.0)
            du = u - uk_prev
            racing += c.q_contour * ey**2 + ca.dot(R * u, u) + ca.dot(Rd * du, du)
            racing += q[W_BLOCK] * (ey - q[EY_OTHER]) ** 2
            qs, qe, qv = h.q_explore
            explore += qs * (s - q[S_REF]) ** 2 + qe * (ey - q[EY_REF]) ** 2 + qv * (vx - q[V_REF]) ** 2
            penalty += c.border_linear * sl[0] + c.border_quadratic * sl[0] ** 2
            penalty += c.slack_linear * sl[2] + c.slack_quadratic * sl[2] ** 2
            penalty += c.speed_slack * sl[1] ** 2
            xk, uk_prev = x, u
        racing -= c.q_progress * (xk[State.S] - x0[State.S])
        J = alpha * explore + (1 - alpha) * racing + penalty
        wv = ca.vertcat(*w)
        gv = ca.vertcat(*g)
        opts = {
            "print_time": False,
            "error_on_fail": False,
            "calc_lam_p": False,  # the parameters' multipliers are never read: one function call less
            "ipopt": dict(IPOPT_OPTIONS, max_iter=c.max_iter),
        }
        nlp = {"x": wv, "p": p, "f": J, "g": gv}
        if c.compiled:
            from gprace.backends.compiled import compiled_nlpsol

            self._solver = compiled_nlpsol("h2h_nmpc", "ipopt", nlp, opts)
        else:
            self._solver = ca.nlpsol("h2h_nmpc", "ipopt", nlp, opts)
        self._lbw, self._ubw = np.array(lbw, float), np.array(ubw, float)
        self._lbg, self._ubg = np.array(lbg, float), np.array(ubg, float)
        self._nw, self._ng = wv.shape[0], gv.shape[0]
        self._stage_w = NU + NX + NS
        self._stage_g = len(lbg) // N

    # ------------------------------------------------------------------------------------------
    def reset(self) -> None:
        self._warm = {}

    def params(self, x0: np.ndarray, u_prev: np.ndarray, alpha: float, st: StageData) -> np.ndarray:
        N = self.h2h.horizon
        P = np.zeros((N, N_STAGE))
        P[:, KAPPA], P[:, WL], P[:, WR] = st.kappa, st.wl, st.wr
        if st.ey_other is not None:
            P[:, EY_OTHER], P[:, W_BLOCK] = st.ey_other, st.w_block
        if st.ref is not None:
            P[:, S_REF:V_REF + 1] = st.ref
        if st.lin is not None:
            P[:, LIN_CX:LIN_KAP + 1] = st.lin
        if st.opp is not None:
            P[:, OPP_X:OPP_ON + 1] = st.opp
        else:
            P[:, OPP_A] = P[:, OPP_B] = 1.0
        return np.concatenate([x0[:6], u_prev, [alpha], P.ravel()])

    def initial_guess(self, x0: np.ndarray) -> np.ndarray:
        """Constant-speed roll-out along the centre-line direction (cold start)."""
        N = self.h2h.horizon
        wv = np.zeros((N, self._stage_w))
        for k in range(N):
            xk = x0[:6].copy()
            xk[State.S] = x0[State.S] + (k + 1) * self.h2h.dt * max(x0[State.V_X], 0.3)
            xk[State.E_PSI] = 0.0
            xk[State.V_Y] = xk[State.YAW_RATE] = 0.0
            wv[k, NU:NU + NX] = xk
        return wv.ravel()

    def guess_states(self, x0: np.ndarray) -> np.ndarray:
        """Planned states (N+1, 6) of the current warm start (for stage data / GP inputs)."""
        N = self.h2h.horizon
        w = self._warm.get("x")
        w = self.initial_guess(x0) if w is None else w
        X = w.reshape(N, self._stage_w)[:, NU:NU + NX]
        return np.vstack([x0[:6], X])

    def solve(self, x0: np.ndarray, u_prev: np.ndarray, alpha: float, st: StageData) -> Solution:
        N = self.h2h.horizon
        p = self.params(np.asarray(x0, float), np.asarray(u_prev, float), alpha, st)
        w0 = self._warm.get("x")
        if w0 is None:
            w0 = self.initial_guess(x0)
        args = {"x0": w0, "p": p, "lbx": self._lbw, "ubx": self._ubw, "lbg": self._lbg, "ubg": self._ubg}
        if "lam_g" in self._warm:
            args["lam_g0"], args["lam_x0"] = self._warm["lam_g"], self._warm["lam_x"]
        self.solves += 1
        t0 = time.perf_counter()
        cold = "lam_g" not in self._warm
        try:
            for attempt in range(3 if cold else 1):  # a cold start may continue from its last iterate
                res = self._solver(**args)
                check_interrupt()  # IPOPT stops at Ctrl-C as if it had failed: no fallback, no retry
                stats = self._solver.stats()
                status = str(stats.get("return_status", ""))
                outcome = ipopt_status(stats)
                wv = np.asarray(res["x"]).ravel()
                finite = all_finite(wv)
                ok = outcome.usable and finite
                if ok or outcome is not SolveStatus.MAX_ITER or not finite:
                    break
                args.update(x0=wv, lam_g0=np.asarray(res["lam_g"]).ravel(), lam_x0=np.asarray(res["lam_x"]).ravel())
        except RuntimeError as exc:  # CasADi's word for a failed evaluation: must not end the race
            ok, status, wv, res = False, f"exception: {exc}", None, None
        dt = time.perf_counter() - t0
        if not ok:
            self.failures += 1
            return self._fallback(x0, status, dt, float(st.kappa[0]))
        W = wv.reshape(N, self._stage_w)
        sol = Solution(
            X=np.vstack([np.asarray(x0, float)[:6], W[:, NU:NU + NX]]), U=W[:, :NU].copy(),
            slack=W[:, NU + NX:].copy(), ok=True, status=status, seconds=dt,
        )
        self._warm = {
            "x": shift_plan(wv, self._stage_w), "lam_g": _shift(np.asarray(res["lam_g"]).ravel(), self._stage_g),
            "lam_x": _shift(np.asarray(res["lam_x"]).ravel(), self._stage_w), "last": sol,
        }
        return sol

    def _fallback(self, x0: np.ndarray, status: str, seconds: float, kappa0: float) -> Solution:
        """The input after a failed solve: the previous plan shifted by one step (braking if there is
        none). Two guards keep a run of failures safe (docs/decisions.md, issue 17):

        * the acceleration never takes ``v_x`` below :data:`V_X_MIN` in one step: the NLP bounds
          ``v_x`` from below, so a car braked under it (or into reverse, as a repeated braking input
          did) makes every following NLP infeasible;
        * after :data:`STALE_STEPS` fallbacks in a row the plan is stale, and the steering holds the
          heading along the track (:func:`heading_hold`) instead of repeating the plan's last input,
          often full lock.
        """
        N = self.h2h.horizon
        last: Solution | None = self._warm.get("last")
        streak = self._warm.get("streak", 0) + 1
        if last is None:  # nothing to shift: gentle braking down to a crawl (steering: the hold below)
            brake = self.mpc.accel[0] * 0.5 if x0[State.V_X] > 0.2 else 0.0
            U = np.tile([0.0, brake], (N, 1))
            X = np.tile(np.asarray(x0, float)[:6], (N + 1, 1))
        else:
            U = np.vstack([last.U[1:], last.U[-1:]])
            X = np.vstack([np.asarray(x0, float)[:6], last.X[2:], last.X[-1:]])
        if last is None or streak > STALE_STEPS:
            U[0, 0] = heading_hold(x0, kappa0, self.model.params.lf + self.model.params.lr, self.mpc.steering_max)
        floor = min((V_X_MIN - x0[State.V_X]) / self.h2h.dt, self.mpc.accel[1])  # reaches V_X_MIN in one step
        U[0, 1] = max(U[0, 1], floor)
        sol = Solution(X=X, U=U, slack=np.zeros((N, NS)), ok=False, status=status, seconds=seconds, fallback=True)
        # the next solve starts from the shifted guess, without duals (they belong to another problem)
        if last is not None:
            self._warm = {"x": shift_plan(self._warm["x"], self._stage_w), "last": sol, "streak": streak}
        return sol


def heading_hold(x0: np.ndarray, kappa: float, wheelbase: float, steering_max: float) -> float:
    """Steering that turns the car parallel to the track: the kinematic steering of the centre
    line's curvature, minus :data:`HOLD_GAIN` times the heading error (saturated)."""
    delta = np.arctan(wheelbase * kappa) - HOLD_GAIN * x0[State.E_PSI]
    return float(np.clip(delta, -steering_max, steering_max))


def _shift(v: np.ndarray, width: int) -> np.ndarray:
    """Drop the first stage block and repeat the last (warm start for the next period)."""
    return np.concatenate([v[width:], v[-width:]])


def shift_plan(w: np.ndarray, width: int) -> np.ndarray:
    """Primal warm start for the next period: the plan shifted by one stage, its new last states
    extrapolated linearly from the two before (inputs and slacks repeated).

    Repeating the last states (as :func:`_shift` does) leaves the last stage's dynamics violated by
    about ``v dt`` (0.1 m of ``s``), and IPOPT spent its first iterations on that; the linear
    extrapolation is off by the second difference only: 11 % fewer iterations per solve
    (docs/decisions.md). Needs at least three stages (N >= 3); with fewer, repeats.
    """
    v = _shift(w, width).reshape(-1, width)
    if len(v) >= 3:
        v[-1, NU:NU + NX] = 2.0 * v[-2, NU:NU + NX] - v[-3, NU:NU + NX]
    return v.ravel()
