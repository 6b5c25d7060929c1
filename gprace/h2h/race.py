"""One head-to-head race: two 1:10 cars, the blocking opponent MPC and the ego NMPC.

``run_race(task)`` is the module-level function the executor calls; ``task`` is a
:class:`~gprace.h2h.tasks.RaceTask` (or its dict), which pickles for local processes and Dask
alike, and everything random in it derives from ``task.seed`` (identical results whoever runs it):

* ``track``: track spec (:func:`gprace.h2h.geometry.make_track`),
* ``seed``: start configuration and GP sampling seed,
* ``predictor``: ``gp`` | ``cv`` | ``oracle``; ``model``: GP model path for ``gp``,
* ``alpha``: exploration weight (> 0 needs ``explore_data``: a dataset file with Z, Y),
* ``config``: :class:`H2HConfig` fields (optional), ``duration``: run length for exploration
  episodes (then the race does not stop at the overtake).

Starts (docs/reference.md#head-to-head): opponent ``s`` in [0.9, 1.2] m, ego in [0.2, 0.4] m, lateral offset within
+-0.3 x width, heading error +-0.02 rad, speed 0.65 to 1.3 m/s; on a closed track the whole grid is
shifted by a random arc length. The plant integrates both cars with RK4 and 10 sub-steps per
0.1 s (the frenet plant's compiled step, curvature re-evaluated at every stage). The race ends
1.5 s after the ego's centre passes the opponent's, when a car reaches the end of an open track,
when a car leaves the track or spins (the stop rule of :mod:`gprace.sim.stop`: more than two car
widths outside a border, ``|e_psi| > 1.2``), or at ``max_time``.

The opponent avoids the ego too (the same soft ellipse constraint, around the ego's constant-velocity
prediction): a blocker steers across the ego's path but does not drive into it.

Per step the opponent solves first (it sees the ego's current state), then the ego's predictor
forecasts the opponent (the oracle reads the opponent's fresh plan), then the ego solves, then both
inputs are applied together.

Noise (``config.sensor_std``, ``config.process_std``, both zero by default): every step both
controllers, the predictor and the exploration see measured states, the true states plus white
Gaussian noise; after every plant step each car's true state gets white Gaussian process noise.
Each kind draws from its own generator seeded by ``(seed, stream)``, so the start grid and the
GP samples are those of the noiseless race and a zero std draws nothing (the noiseless race is
unchanged to the bit). Border hits, collisions, overtakes and the race's end use the true states;
the record keeps the measured ones as ``ego_meas`` / ``opp_meas`` (the GP data are built from them).
"""

from __future__ import annotations

import functools
import threading
import time
from typing import Callable

import numpy as np

from gprace.executor import single_thread_blas
from gprace.h2h.config import H2HConfig
from gprace.h2h.geometry import border_hits, collisions, global_pose, make_track
from gprace.h2h.nmpc import NMPC, StageData
from gprace.h2h.predictors import Context, gap_s, make_predictor
from gprace.h2h.tasks import BuildTask, RaceTask
from gprace.model.dynamics import State
from gprace.plants.frenet import compiled_step
from gprace.sim.stop import stop_kind

S, EY = State.S, State.E_Y  # the state entries the race code reads by name

_LOCAL = threading.local()  # per thread (Dask threads): NMPCs hold solver state
MAX_CONTROLLERS = 4  # configurations kept per thread (a study switches between a few)
SENSOR_STREAM, PROCESS_STREAM = 1, 2


def state_noise(seed: int, stream: int, std) -> Callable[[], np.ndarray] | None:
    """A function drawing (2, 6) noise (both cars, std per state) from its own seeded generator;
    None when every std is zero (nothing is drawn)."""
    std = np.asarray(std, float)
    if not std.any():
        return None
    rng = np.random.default_rng([int(seed), int(stream)])
    return lambda: rng.standard_normal((2, len(std))) * std


@functools.cache
def _model():
    """The 1:10 car of both NMPCs (the race configuration names no vehicle)."""
    from gprace.config import load_vehicle
    from gprace.model import NominalModel

    return NominalModel(load_vehicle("barc_1_10"))


def controllers(cfg: H2HConfig) -> tuple[NMPC, NMPC]:
    """(ego, opponent) NMPCs, built once per thread and configuration (the last
    :data:`MAX_CONTROLLERS` configurations are kept)."""
    cache = getattr(_LOCAL, "controllers", None)
    if cache is None:
        cache = _LOCAL.controllers = {}
    key = cfg.model_dump_json()
    if key not in cache:
        m = _model()
        if len(cache) >= MAX_CONTROLLERS:
            cache.pop(next(iter(cache)))  # the oldest
        cache[key] = (NMPC(m, cfg.ego, cfg, collision=True), NMPC(m, cfg.opponent, cfg, collision=True))
    ego, opp = cache[key]
    ego.reset(), opp.reset()
    ego.failures = ego.solves = opp.failures = opp.solves = 0
    return ego, opp


def build_controller(task: BuildTask | dict) -> str:
    """Build one car's NMPC (``task.car``: ego | opponent) of a race configuration
    (``task.config``), which compiles its NLP once per machine. The two cars' NLPs differ in
    their constants, so they are two libraries of 25 to 50 s of compiler each; built side by side
    before the first batch instead of one after the other inside it (:func:`gprace.h2h.protocol.run_tasks`)."""
    task = BuildTask.of(task)
    cfg = H2HConfig(**task.config)
    NMPC(_model(), getattr(cfg, task.car), cfg, collision=True)
    return task.car


def start_states(track, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    w = float(track.width_left(0.0) + track.width_right(0.0))
    base = rng.uniform(0.0, track.length) if track.closed else 0.0

    def car(lo, hi):
        return np.array([rng.uniform(0.65, 1.3), 0.0, 0.0, rng.uniform(-0.02, 0.02),
                         rng.uniform(-0.3, 0.3) * w, base + rng.uniform(lo, hi)])

    opp = car(0.9, 1.2)
    ego = car(0.2, 0.4)
    return ego, opp


def extend(a: np.ndarray, n: int) -> np.ndarray:
    """Rows 1..K -> n rows: linear extrapolation of the last two rows (held if K == 1)."""
    a = np.asarray(a, float)
    while len(a) < n:
        nxt = 2 * a[-1] - a[-2] if len(a) >= 2 else a[-1]
        a = np.vstack([a, nxt])
    return a[:n]


def ellipse_data(track, cfg: H2HConfig, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(N, 6) x, y, psi, a, b, on of the forbidden ellipse around each predicted opponent pose."""
    x, y, psi = global_pose(track, mean)
    r = cfg.disk_radius
    a = cfg.mpc_length / np.sqrt(2) + r + cfg.std_factor * std[:, 0]
    b = cfg.mpc_width / np.sqrt(2) + r + cfg.std_factor * std[:, 1]
    return np.column_stack([x, y, psi, a, b, np.ones(len(x))])


def usable_widths(track, s: np.ndarray, kappa_max_ey: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """Track widths for the controllers, capped on the inside of tight arcs where the Frenet model
    is singular (``kappa e_y -> 1``): at most ``kappa_max_ey / |kappa|`` toward the centre of curvature."""
    k = track.kappa(track.wrap(s))
    wl, wr = np.asarray(track.width_left(s), float), np.asarray(track.width_right(s), float)
    with np.errstate(divide="ignore"):
        cap = kappa_max_ey / np.maximum(np.abs(k), 1e-9)
    wl = np.where(k > 0, np.minimum(wl, cap), wl)
    wr = np.where(k < 0, np.minimum(wr, cap), wr)
    return wl, wr


def _linearisation(track, G: np.ndarray, kfun) -> np.ndarray:
    """(N, 5) centre-line points, headings, arc lengths and curvatures of a plan's states 1..N."""
    sig = G[1:, S]
    cx, cy = track.to_global(sig, np.zeros(len(sig)))
    return np.column_stack([cx, cy, track.heading(sig), sig, kfun(sig)])


def _opponent_stage(track, cfg: H2HConfig, opp_mpc: NMPC, cv_ego, opp: np.ndarray, ego: np.ndarray,
                    kfun) -> StageData:
    """The opponent's stage data: blocking while the ego is behind (its centre more than a car
    length back; alongside, the opponent holds its line instead of steering into the ego), and the
    ego seen at constant velocity."""
    N = cfg.horizon
    gap = float(gap_s(track, opp[S], ego[S]))
    wblock = cfg.opponent.q_block / (1.0 + gap) ** 2 if gap > cfg.car_length else 0.0
    Go = opp_mpc.guess_states(opp)
    wl, wr = usable_widths(track, Go[1:, S])
    ego_cv = cv_ego.predict(Context(track, Go, ego)).mean
    return StageData(kappa=kfun(Go[:-1, S]), wl=wl, wr=wr, ey_other=np.full(N, ego[EY]), w_block=np.full(N, wblock),
                     lin=_linearisation(track, Go, kfun), opp=ellipse_data(track, cfg, extend(ego_cv, N), np.zeros((N, 2))))


def _ego_stage(track, cfg: H2HConfig, ego_mpc: NMPC, predictor, explorer, ego: np.ndarray, opp: np.ndarray,
               opp_plan: np.ndarray, kfun) -> StageData:
    """The ego's stage data: the opponent predicted from its previous open-loop plan, inflated by
    the predicted spread, and the exploration reference when the ego explores."""
    N = cfg.horizon
    Ge = ego_mpc.guess_states(ego)
    pred = predictor.predict(Context(track, Ge, opp, opp_plan))
    mean, std = extend(pred.mean, N), extend(pred.std, N)
    ref = None
    if explorer is not None:
        explorer.target_gaps(track, ego, opp)
        ref = explorer.reference(track, ego, mean, cfg.ego.border_margin)
    wl, wr = usable_widths(track, Ge[1:, S])
    return StageData(kappa=kfun(Ge[:-1, S]), wl=wl, wr=wr, ref=ref, lin=_linearisation(track, Ge, kfun),
                     opp=ellipse_data(track, cfg, mean, std))


def _race_end(track, cfg: H2HConfig, X: np.ndarray, t: float, t_overtake: float, duration) -> str | None:
    """Why the race ends after this step (None: it goes on)."""
    if not np.all(np.isfinite(X)):
        return "diverged"
    # a car left the track or spun: the one stop rule (no stall speed: a blocked car may stand)
    stop = [stop_kind(x, float(track.width_left(x[S])), float(track.width_right(x[S])), cfg.car_width) for x in X]
    if any(stop):
        return next(k for k in stop if k)
    if not duration and not np.isnan(t_overtake) and t >= t_overtake + cfg.after_overtake - 1e-9:
        return "overtaken"
    if not track.closed and np.max(X[:, S]) >= track.length - cfg.end_margin:
        return "track_end"
    return None


@single_thread_blas
def run_race(task: RaceTask | dict) -> dict:
    """One race of ``task`` (track, seed, predictor, ...): per step the opponent's NMPC, the ego's
    prediction and NMPC, one plant step of both cars; the states, inputs and outcome as a record."""
    task = RaceTask.of(task)
    cfg = H2HConfig(**task.config)
    track = make_track(task.track)
    rng = np.random.default_rng(task.seed)
    N, dt = cfg.horizon, cfg.dt
    predictor = make_predictor(task.predictor, cfg.pred_steps, dt, task.model, cfg.samples,
                               seed=task.seed + 7919, calibration=task.calibration)
    alpha = float(task.alpha or 0.0)
    explorer = _explorer(task, cfg, predictor, alpha)
    ego_mpc, opp_mpc = controllers(cfg)
    cv_ego = make_predictor("cv", N, dt)
    ego, opp = start_states(track, rng)
    duration = task.duration
    max_time = float(duration) if duration else cfg.max_time

    X = np.vstack([ego, opp])
    measure = state_noise(task.seed, SENSOR_STREAM, cfg.sensor_std)
    disturb = state_noise(task.seed, PROCESS_STREAM, cfg.process_std)
    Xm = X + measure() if measure else X  # what the controllers and the predictor see
    hist_m = [Xm.copy()]
    Uprev = np.zeros((2, 2))
    plant = compiled_step(_model(), track, dt, cfg.plant_substeps).map(2)  # both cars in one call
    kfun = lambda s: track.kappa(track.wrap(s))  # noqa: E731
    hist_x, hist_u, ego_ms, fb, targets = [X.copy()], [], [], [], []
    t_overtake, end_reason = np.nan, "time"
    for step in range(int(round(max_time / dt))):
        ego, opp = Xm[0], Xm[1]
        sol_o = opp_mpc.solve(opp, Uprev[1], 0.0, _opponent_stage(track, cfg, opp_mpc, cv_ego, opp, ego, kfun))
        st_e = _ego_stage(track, cfg, ego_mpc, predictor, explorer, ego, opp, sol_o.X, kfun)
        if explorer is not None:
            targets.append(explorer.target.copy())
        sol_e = ego_mpc.solve(ego, Uprev[0], alpha, st_e)
        U = np.vstack([sol_e.U[0], sol_o.U[0]])
        X = np.asarray(plant(X.T, U.T)).T
        if disturb:
            X = X + disturb()
        Xm = X + measure() if measure else X
        Uprev = U
        hist_x.append(X.copy())
        hist_m.append(Xm.copy())
        hist_u.append(U.copy())
        ego_ms.append(1e3 * sol_e.seconds)
        fb.append((sol_e.fallback, sol_o.fallback))
        t = (step + 1) * dt
        if np.isnan(t_overtake) and np.all(np.isfinite(X)) and gap_s(track, X[1, S], X[0, S]) < 0:
            t_overtake = t
        end = _race_end(track, cfg, X, t, t_overtake, duration)
        if end is not None:
            end_reason = end
            break
    return _record(task, cfg, track, predictor, alpha, explorer, end_reason, t_overtake, np.array(hist_x),
                   hist_u, hist_m if measure else None, ego_ms, fb, targets)


def _explorer(task: RaceTask, cfg: H2HConfig, predictor, alpha: float):
    """The exploring ego's target picker (Algorithm 1 on its dataset), None when alpha is 0."""
    if alpha <= 0:
        return None
    from gprace.gp.dataset import read_dataset
    from gprace.h2h.explore import Explorer

    data = read_dataset(task.explore_data)
    return Explorer.from_data(predictor.gp, data.Z, data.Y, alpha,
                              stalemate_steps=cfg.stalemate_steps, stalemate_tol=cfg.stalemate_tol,
                              hold_steps=cfg.hold_steps)


def _record(task: RaceTask, cfg: H2HConfig, track, predictor, alpha: float, explorer, end_reason: str,
            t_overtake: float, H: np.ndarray, hist_u: list, hist_m: list | None, ego_ms: list, fb: list,
            targets: list) -> dict:
    """The race record: states (T+1, 2, 6) of both cars, inputs, border hits, collisions, outcome."""
    dt = cfg.dt
    Xe, Xo = H[:, 0], H[:, 1]
    be = border_hits(track, Xe, cfg.car_length, cfg.car_width)
    bo = border_hits(track, Xo, cfg.car_length, cfg.car_width)
    col = collisions(track, Xe, Xo, cfg.car_length, cfg.car_width)
    fb = np.array(fb, dtype=bool).reshape(-1, 2)
    U = np.array(hist_u).reshape(-1, 2, 2)
    arrays = {
        "t": dt * np.arange(len(H)), "ego": Xe, "opp": Xo, "u_ego": U[:, 0], "u_opp": U[:, 1],
        "ego_solve_ms": np.array(ego_ms), "fallback_ego": fb[:, 0], "fallback_opp": fb[:, 1],
        "border_ego": be, "border_opp": bo, "collision": col,
    }
    if hist_m is not None:
        M = np.array(hist_m)
        arrays["ego_meas"], arrays["opp_meas"] = M[:, 0], M[:, 1]
    if targets:
        arrays["targets"] = np.array(targets)
    attrs = {
        "track": track.name, "track_length": float(track.length), "seed": task.seed,
        "predictor": task.label or predictor.name, "alpha": alpha, "end_reason": end_reason,
        "overtake_time": float(t_overtake), "border_hit": bool(be.any()), "border_hit_opp": bool(bo.any()),
        "collision": bool(col.any()), "steps": len(H) - 1, "fallbacks_ego": int(fb[:, 0].sum()),
        "fallbacks_opp": int(fb[:, 1].sum()), "stalemates": int(explorer.stalemates) if explorer else 0,
    }
    return {"arrays": arrays, "attrs": attrs}


def time_race(task: RaceTask | dict) -> tuple[dict, float]:
    t0 = time.perf_counter()
    out = run_race(task)
    return out, time.perf_counter() - t0
