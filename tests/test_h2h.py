"""Head-to-head building blocks: blocking opponent, ellipse constraints, GP rollouts."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.errors import InputError
from gprace.h2h.config import H2HConfig
from gprace.h2h.geometry import border_hits, global_pose, make_track, rect_overlap
from gprace.h2h.nmpc import NMPC, StageData
from gprace.h2h.predictors import FEATURES, OUTPUTS, GPPredictor, features
from gprace.h2h.race import _model, ellipse_data

CFG = H2HConfig()


@pytest.fixture(scope="module")
def straight():
    from gprace.tracks.random import random_track

    # kinds=("straight",): a straight open track, 0.75 m wide
    return random_track(1, n_stretches=3, width=0.75, kinds=("straight",))


def _opp_plan(mpc: NMPC, track, x0, ey_ego: float, block: bool, steps: int = 4) -> np.ndarray:
    mpc.reset()
    N = CFG.horizon
    sol = None
    for _ in range(steps):  # a few warm-started solves at the same state: converged plan
        G = mpc.guess_states(x0)
        st = StageData(kappa=track.kappa(G[:-1, 5]), wl=track.width_left(G[1:, 5]), wr=track.width_right(G[1:, 5]),
                       ey_other=np.full(N, ey_ego), w_block=np.full(N, 500.0 / 1.8**2 if block else 0.0))
        sol = mpc.solve(x0, np.zeros(2), 0.0, st)
        assert sol.ok
    return sol.X


def test_blocking_opponent_moves_toward_the_ego_side(straight):
    mpc = NMPC(_model(), CFG.opponent, CFG, collision=False)
    x0 = np.array([1.0, 0, 0, 0, 0.0, 2.0])
    for side in (+0.2, -0.2):
        free = _opp_plan(mpc, straight, x0, side, block=False)
        blocked = _opp_plan(mpc, straight, x0, side, block=True)
        # without blocking the opponent keeps the centre line; with it, it moves to the ego's side
        assert abs(free[-1, 4]) < 0.02
        assert np.sign(blocked[-1, 4]) == np.sign(side)
        assert abs(blocked[-1, 4]) > 0.5 * abs(side)


def _encounter(track, collision_on: bool, steps: int = 55):
    """Ego at 1.4 m/s on the centre line behind a scripted opponent crawling at 0.4 m/s, 0.1 m right of it."""
    ego_mpc = NMPC(_model(), CFG.ego, CFG, collision=True)
    model = _model()
    N = CFG.horizon
    x = np.array([1.4, 0, 0, 0, 0.0, 0.5])
    opp = np.array([0.4, 0, 0, 0, -0.1, 1.6])
    u = np.zeros(2)
    overlap = []
    for _ in range(steps):
        k = np.arange(1, N + 1)[:, None]
        mean = np.tile(opp, (N, 1))
        mean[:, 5:6] = opp[5] + 0.1 * k * opp[0]
        G = ego_mpc.guess_states(x)
        sig = G[1:, 5]
        cx, cy = track.to_global(sig, np.zeros(N))
        ell = ellipse_data(track, CFG, mean, np.zeros((N, 2)))
        ell[:, 5] = 1.0 if collision_on else 0.0
        st = StageData(kappa=track.kappa(G[:-1, 5]), wl=track.width_left(sig), wr=track.width_right(sig),
                       lin=np.column_stack([cx, cy, track.heading(sig), sig, track.kappa(sig)]), opp=ell)
        sol = ego_mpc.solve(x, u, 0.0, st)
        u = sol.U[0]
        x = model.rk4(x, u, track.kappa, CFG.dt, CFG.plant_substeps)
        opp = opp.copy()
        opp[5] += CFG.dt * opp[0]
        pa = np.column_stack(global_pose(track, x[None]))
        pb = np.column_stack(global_pose(track, opp[None]))
        overlap.append(bool(rect_overlap(pa, pb, CFG.car_length, CFG.car_width)[0]))
    return np.array(overlap), x, opp, ego_mpc


def test_ellipse_constraints_keep_footprints_apart(straight):
    overlap, x, opp, mpc = _encounter(straight, collision_on=True)
    assert not overlap.any()
    assert x[5] > opp[5]  # it went past, not just braked behind
    assert mpc.failures == 0
    # the same encounter without the constraint drives into the opponent: the test can fail
    overlap_off, *_ = _encounter(straight, collision_on=False, steps=15)
    assert overlap_off.any()


def test_border_hits_use_the_footprint(straight):
    L, W = CFG.car_length, CFG.car_width
    w = float(straight.width_left(3.0))
    inside = np.array([[1, 0, 0, 0.0, w - 0.5 * W - 0.01, 3.0]])
    rotated = np.array([[1, 0, 0, 0.3, w - 0.5 * W - 0.01, 3.0]])  # nose turned out: a corner crosses
    assert not border_hits(straight, inside, L, W)[0]
    assert border_hits(straight, rotated, L, W)[0]



@pytest.fixture(scope="module")
def toy_gp(straight):
    from gprace.gp import make_gp

    rng = np.random.default_rng(0)
    n = 120
    opp = np.column_stack([rng.uniform(0.8, 1.2, n), np.zeros(n), rng.normal(0, 0.1, n), rng.normal(0, 0.05, n),
                           rng.uniform(-0.3, 0.3, n), rng.uniform(1, 8, n)])
    ego = opp + np.column_stack([np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), rng.uniform(-0.3, 0.3, n),
                                 -rng.uniform(0.3, 1.0, n)])
    Z = features(straight, ego, opp)
    dey = 0.03 * np.tanh(3 * Z[:, 0]) - 0.02 * Z[:, 4]
    Y = np.column_stack([0.1 * opp[:, 0], dey, -0.05 * opp[:, 3], np.zeros(n), np.zeros(n)]) + 0.003 * rng.normal(size=(n, 5))
    return make_gp("exact", kernel="matern15", optimize=False, length_scale=2.0, noise=0.05).fit(Z, Y)


def test_rollout_matches_direct_monte_carlo(straight, toy_gp):
    K = 9
    ego_plan = np.tile([1.2, 0, 0, 0, 0.15, 1.5], (K + 1, 1))
    ego_plan[:, 5] += 0.12 * np.arange(K + 1)
    opp = np.array([1.0, 0, 0, 0.02, -0.05, 2.2])
    fast = GPPredictor(toy_gp, K, samples=4000, seed=1)
    paths = fast.rollout(straight, ego_plan, opp)  # (n, K, 6), one GP call per step
    # direct Monte-Carlo: every sample path on its own, one GP call per sample and step
    rng = np.random.default_rng(2)
    idx = [5, 4, 3, 0, 2]
    m = 300
    direct = np.empty((m, K, 6))
    for i in range(m):
        x = opp.copy()
        for k in range(K):
            mu, var = toy_gp.predict(features(straight, ego_plan[k], x[None]))
            x[idx] += mu[0] + np.sqrt(var[0]) * rng.standard_normal(5)
            direct[i, k] = x
    for col in (4, 5):
        a, b = paths[:, :, col], direct[:, :, col]
        se = np.sqrt(a.var(0) / len(a) + b.var(0) / len(b))
        assert np.all(np.abs(a.mean(0) - b.mean(0)) < 4.5 * se + 1e-9)
        ratio = a.std(0) / b.std(0)
        assert np.all((ratio > 0.8) & (ratio < 1.25))
    # the spread grows along the horizon (uncertainty propagates)
    assert paths[:, -1, 4].std() > paths[:, 0, 4].std()
    pred = fast.predict(type("C", (), {"track": straight, "ego_plan": ego_plan, "opp": opp})())
    assert pred.mean.shape == (K, 6) and pred.std.shape == (K, 2)
    assert len(FEATURES) == toy_gp.n_inputs_ and len(OUTPUTS) == toy_gp.n_outputs_


def test_random_track_spec_and_loop():
    loop = make_track({"kind": "loop"})
    assert loop.closed and 35.0 < loop.length < 37.5
    a = make_track({"kind": "random", "seed": 5, "width": 0.75})
    b = make_track({"kind": "random", "seed": 5, "width": 0.75})
    assert a.length == b.length and not a.closed
    narrow = make_track({"kind": "loop", "width": 0.75})  # same centre line at the racing width
    s = np.linspace(0.0, loop.length, 50, endpoint=False)
    np.testing.assert_allclose(loop.width_left(s) + loop.width_right(s), 1.5)
    np.testing.assert_allclose(narrow.width_left(s) + narrow.width_right(s), 0.75)
    np.testing.assert_allclose(narrow.kappa(s), loop.kappa(s))
    with pytest.raises(InputError, match="width"):
        make_track({"kind": "loop", "width": 3.0})


def test_exploration_targets_uncertainty_and_breaks_stalemates(straight, toy_gp):
    from gprace.h2h.explore import Explorer
    from gprace.h2h.predictors import CONTROLLABLE

    rng = np.random.default_rng(3)
    n = 200
    opp = np.column_stack([np.ones(n), np.zeros(n), np.zeros(n), np.zeros(n), rng.uniform(-0.2, 0.2, n), rng.uniform(2, 6, n)])
    ego = opp.copy()
    ego[:, 4] = rng.uniform(-0.25, 0.25, n)
    ego[:, 5] -= rng.uniform(0.3, 1.0, n)
    Z = features(straight, ego, opp)
    Y = toy_gp.predict(Z)[0]
    e_state, o_state = ego[0], opp[0]
    ex = Explorer.from_data(toy_gp, Z, Y, alpha=1.0, stalemate_steps=3, stalemate_tol=1e-6, hold_steps=2)
    # alpha = 1: the candidate of largest weighted variance
    z = features(straight, e_state, o_state)[0]
    Zc = np.tile(z, (len(ex.grid), 1))
    Zc[:, list(CONTROLLABLE)] = ex.grid
    v = toy_gp.predict(Zc)[1]
    w = v[:, 0] ** 2 * ex.S[0] + v[:, 1] ** 2 * ex.S[1]
    assert np.allclose(ex.target_gaps(straight, e_state, o_state), ex.grid[np.argmax(w)])
    # alpha = 0 keeps the nearest configuration; a frozen relative configuration (stalemate)
    # reverses the distance ranking: the farthest candidate is chosen and held
    ex0 = Explorer.from_data(toy_gp, Z, Y, alpha=0.0, stalemate_steps=3, stalemate_tol=1e-6, hold_steps=2)
    zc = z[list(CONTROLLABLE)]
    d = np.linalg.norm((ex0.grid - zc) / ex0.scale, axis=1)
    targets = [ex0.target_gaps(straight, e_state, o_state).copy() for _ in range(7)]
    assert np.allclose(targets[0], ex0.grid[np.argmin(d)])
    assert ex0.stalemates >= 1
    far = ex0.grid[np.argmax(d)]
    assert any(np.allclose(t, far) for t in targets)
    i = next(k for k, t in enumerate(targets) if np.allclose(t, far))
    assert np.allclose(targets[i + 1], far) and np.allclose(targets[i + 2], far)  # held
    ref = ex0.reference(straight, e_state, np.tile(o_state, (10, 1)), 0.13)
    assert ref.shape == (10, 3) and np.all(np.abs(ref[:, 1]) <= 0.375 - 0.13 + 1e-12)
