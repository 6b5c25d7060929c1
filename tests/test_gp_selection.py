"""Diverse data selection: the paper's rules, incremental factor updates, the random baseline."""

from __future__ import annotations

import numpy as np
import pytest

from gprace.errors import ConfigError, InputError
from gprace.gp import make_gp
from gprace.gp.selection import DiverseSelector, random_subsample, reservoir_merge, select_diverse


def _f(Z):
    return np.column_stack([np.sin(2 * Z[:, 0]) * np.cos(Z[:, 2]), 0.5 * Z[:, 1] ** 2 - Z[:, 2]])


def _data(n, seed=0, scale=1.0, noise=0.03):
    rng = np.random.default_rng(seed)
    Z = scale * rng.normal(size=(n, 3))
    return Z, _f(Z) + noise * rng.standard_normal((n, 2))


def _hyper(ls=((0.8, 2.0, 1.5), (2.0, 0.9, 1.2)), noise=(1e-2, 3e-3)):
    Z, Y = _data(200, seed=99)
    return make_gp("exact", optimize=False, length_scale=np.array(ls), noise=np.array(noise)).fit(Z, Y).hyper_


def naive_select(hyper, Z, Y, M, kappa=4.0, gate_below=0.5, max_snr=1e3):
    """Reference implementation: every decision from a fresh inverse (O(M^3) per point)."""
    Zn, Yn = hyper.zn(Z), hyper.yn(Y)
    sf2 = np.exp(hyper.log_sf2)
    sn2 = np.maximum(np.exp(hyper.log_sn2), sf2 / max_snr)
    slots_z, slots_y = [], []
    for z, y in zip(Zn, Yn):
        n = len(slots_z)
        var, mu, loo = np.empty(hyper.p), np.empty(hyper.p), []
        for o in range(hyper.p):
            if n:
                D = np.array(slots_z)
                Kinv = np.linalg.inv(hyper.k(o, D, D) + sn2[o] * np.eye(n))
                k = hyper.k(o, D, z[None])[:, 0]
                var[o] = sf2[o] - k @ Kinv @ k
                mu[o] = k @ Kinv @ np.array(slots_y)[:, o]
                loo.append(1.0 / np.diag(Kinv) - sn2[o])
            else:
                var[o], mu[o] = sf2[o], 0.0
        out = np.any((var < gate_below * sf2) & (np.abs(y - mu) > kappa * np.sqrt(var + sn2)))
        if out:
            continue
        if n < M:
            slots_z.append(z)
            slots_y.append(y)
            continue
        loo = np.array(loo)
        if not np.any(var > np.median(loo, axis=1)):
            continue
        jo = np.argmin(loo, axis=1)
        ratio = var / loo[np.arange(hyper.p), jo]
        j = jo[np.argmax(ratio)]
        slots_z[j], slots_y[j] = z, y
    return np.array(slots_z) * hyper.z_scale + hyper.z_mean


def _rows(A):
    return A[np.lexsort(A.T[::-1])]


@pytest.mark.parametrize("block", [1, 7, 64])
def test_decisions_match_a_fresh_factorisation_reference(block):
    hyper = _hyper()
    Z, Y = _data(160, seed=1, scale=1.3)
    Y[[40, 90]] += 3.0  # two glitches inside the covered region
    sel = DiverseSelector(hyper, 15, block=block)
    sel.update(Z, Y)
    ref = naive_select(hyper, Z, Y, 15)
    np.testing.assert_allclose(_rows(sel.Z), _rows(ref), rtol=1e-12, atol=1e-12)
    assert sel.stats.seen == 160 and sel.stats.replaced > 10
    assert sel.stats.inserted + sel.stats.replaced + sel.stats.rejected_outlier + sel.stats.rejected_variance == 160


def test_incremental_inverse_matches_fresh_factorisation():
    sel = DiverseSelector(_hyper(), 60, block=32, refresh_every=10**9)
    Z, Y = _data(1500, seed=2, scale=1.5)
    sel.update(Z, Y)
    assert sel.stats.replaced > 50 and sel.stats.refreshes == 0
    assert sel.factor_error() < 1e-9
    for o in range(2):
        fresh = sel.fresh_inverse(o)
        np.testing.assert_allclose(sel.inverse(o), fresh, rtol=1e-8, atol=1e-9 * np.abs(fresh).max())
        np.testing.assert_allclose(sel.diag[o], np.diag(fresh), rtol=1e-8)
    mean, var = sel.posterior(Z[:5])
    for o in range(2):  # posterior from the maintained inverse == posterior from a fresh one
        act = sel.active
        K = sel.hyper.k(o, sel.Zs[act], sel.hyper.zn(Z[:5]))
        Pf = sel.fresh_inverse(o)[np.ix_(act, act)]
        np.testing.assert_allclose(mean[:, o], K.T @ Pf @ sel.Ys[act, o], rtol=1e-8, atol=1e-10)


def test_buffers_are_preallocated_and_reused():
    sel = DiverseSelector(_hyper(), 40, block=16)
    ptrs = [P.__array_interface__["data"][0] for P in sel.P]
    sel.update(*_data(600, seed=3, scale=1.4))
    assert sel.stats.replaced > 20
    assert [P.__array_interface__["data"][0] for P in sel.P] == ptrs
    assert all(P.shape == (40, 40) for P in sel.P)


def test_median_rule_refuses_redundant_points_and_takes_novel_ones():
    hyper = _hyper()
    Z, Y = _data(30, seed=4)
    sel = DiverseSelector(hyper, 30).initialize(Z, Y)
    loo_before = sel.loo_variance()
    sel.update(Z[:10] + 1e-4, Y[:10])  # near duplicates: variance far below the median
    assert sel.stats.rejected_variance == 10 and sel.stats.replaced == 0
    far = np.array([[6.0, -6.0, 6.0]])
    sel.update(far, _f(far))
    assert sel.stats.replaced == 1
    assert np.any(np.all(np.isclose(sel.Z, far), axis=1))
    # the point that left was the least informative one (smallest leave-one-out variance)
    gone = np.setdiff1d(np.arange(30), [i for i in range(30) if np.any(np.all(np.isclose(sel.Z, Z[i]), axis=1))])
    assert len(gone) == 1
    o_worst = np.argmin(loo_before, axis=1)
    assert gone[0] in o_worst


def test_ratio_rule_picks_the_output_with_the_largest_gain():
    # output 0 varies only with z0, output 1 only with z1 (ARD length scales of 100 elsewhere)
    hyper = _hyper(ls=((0.5, 100.0, 100.0), (100.0, 0.5, 100.0)), noise=(1e-3, 1e-3))
    rng = np.random.default_rng(5)
    Z = np.column_stack([rng.uniform(-2, 2, 20), rng.uniform(-2, 2, 20), np.zeros(20)])
    Z[0, 0] = Z[1, 0] + 1e-3  # point 0 is redundant for output 0
    Z[2, 1] = Z[3, 1] + 1e-3  # point 2 is redundant for output 1
    Z[2, 1] = Z[3, 1] + 1e-3
    sel = DiverseSelector(hyper, 20, outlier_kappa=None).initialize(Z, _f(Z))
    loo = sel.loo_variance()
    jo = np.argmin(loo, axis=1)
    assert jo[0] != jo[1]
    new = np.array([[0.0, 5.0, 0.0]])  # novel only in z1: the big ratio is output 1's
    _, var = sel.posterior(new)
    ratios = var[0] / loo[[0, 1], jo]
    winner = jo[int(np.argmax(ratios))]
    sel.update(new, _f(new))
    assert sel.stats.replaced == 1
    assert not np.any(np.all(np.isclose(sel.Z, Z[winner]), axis=1))
    assert np.all([np.any(np.all(np.isclose(sel.Z, Z[i]), axis=1)) for i in range(20) if i != winner])


def test_outlier_gate():
    hyper = _hyper()
    Z, Y = _data(200, seed=6)
    sel = DiverseSelector(hyper, 200, outlier_kappa=4.0)
    sel.update(Z[:150], Y[:150])
    assert sel.stats.rejected_outlier == 0  # clean Gaussian data passes a 4-sigma gate
    z = Z[150:151] * 0.3
    bad = _f(z) + np.array([[5.0, 0.0]])  # a glitch where the dictionary is well informed
    sel.update(z, bad)
    assert sel.stats.rejected_outlier == 1 and sel.n_points == 150
    far = np.array([[7.0, 7.0, -7.0]])  # a region the dictionary has never seen: not judged
    sel.update(far, _f(far) + 5.0)
    assert sel.n_points == 151
    off = DiverseSelector(hyper, 200, outlier_kappa=None)
    off.update(Z[:150], Y[:150])
    off.update(z, bad)
    assert off.n_points == 151


def test_diverse_selection_beats_random_on_a_skewed_stream():
    """With a stream that dwells in one region, the dictionary keeps the rare points."""
    rng = np.random.default_rng(8)
    hyper = _hyper()
    Zt = rng.uniform(-2.5, 2.5, (400, 3))
    wins = 0
    for seed in range(3):
        r = np.random.default_rng(seed)
        Z = np.concatenate([0.4 * r.normal(size=(1800, 3)), r.uniform(-2.5, 2.5, (200, 3))])
        Z = Z[r.permutation(len(Z))]
        Y = _f(Z) + 0.02 * r.standard_normal((len(Z), 2))
        Zd, Yd, _ = select_diverse(hyper, Z, Y, 80)
        Zr, Yr = random_subsample(Z, Y, 80, seed)
        errs = []
        for Zs, Ys in ((Zd, Yd), (Zr, Yr)):
            gp = make_gp("exact", optimize=False, length_scale=[[0.8, 2.0, 1.5], [2.0, 0.9, 1.2]]).fit(Zs, Ys)
            errs.append(np.sqrt(np.mean((gp.predict(Zt)[0] - _f(Zt)) ** 2)))
        wins += errs[0] < errs[1]
    assert wins == 3


def test_refresh_keeps_results():
    hyper = _hyper()
    Z, Y = _data(400, seed=9, scale=1.4)
    a = DiverseSelector(hyper, 30, refresh_every=5, block=16)
    b = DiverseSelector(hyper, 30, refresh_every=10**9, block=16)
    a.update(Z, Y)
    b.update(Z, Y)
    assert a.stats.refreshes > 3
    np.testing.assert_allclose(_rows(a.Z), _rows(b.Z))


def test_bad_input():
    sel = DiverseSelector(_hyper(), 10)
    Z, Y = _data(5)
    Z[2, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        sel.update(Z, Y)
    with pytest.raises(InputError, match="expected 3 inputs"):
        sel.update(np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(InputError, match="empty"):
        sel.update(np.zeros((0, 3)), np.zeros((0, 2)))
    with pytest.raises(InputError, match="more than max_points"):
        sel.initialize(*_data(11))
    with pytest.raises(ConfigError):
        DiverseSelector(_hyper(), 0)
    Z, Y = _data(40)
    dup = DiverseSelector(_hyper(), 20)
    dup.update(np.concatenate([Z[:5]] * 8), np.concatenate([Y[:5]] * 8))  # duplicates only
    assert dup.n_points == 20 and dup.factor_error() < 1e-8


def test_random_subsample_and_reservoir():
    Z, Y = _data(100)
    Zs, Ys = random_subsample(Z, Y, 30, seed=1)
    assert Zs.shape == (30, 3) and len(np.unique(Zs, axis=0)) == 30
    assert np.array_equal(random_subsample(Z, Y, 30, seed=1)[0], Zs)
    Zall, _ = random_subsample(Z, Y, 500, seed=1)
    assert len(Zall) == 100
    # reservoir merge is uniform: the share of new points matches their share of all points seen
    share = []
    for seed in range(200):
        Zm, Ym, n = reservoir_merge(Zs, Ys, 300, Z[:60] + 10.0, Y[:60], 30, seed=seed)
        assert n == 360 and len(Zm) == 30
        share.append(np.mean(Zm[:, 0] > 5.0))
    assert abs(np.mean(share) - 60 / 360) < 0.02


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_shared_kernel_shares_the_inverse_and_decides_as_one_per_output(seed):
    """Issue 37 (the README job's time): outputs with one kernel keep one inverse; on random
    data the dictionary, its order and the counters equal those of one inverse per output."""
    rng = np.random.default_rng(seed)
    Z, Y = _data(700, seed=seed, scale=1.2)
    Y[rng.choice(700, 5, replace=False)] += 2.5  # a few outliers for the gate
    Z0, Y0 = _data(80, seed=seed + 10)
    ls = np.exp(rng.uniform(-0.5, 0.8, 3))
    hyper = make_gp("exact", optimize=False, length_scale=np.vstack([ls, ls]), noise=np.full(2, 10 ** rng.uniform(-3, -1.5)),
                    shared_kernel=True).fit(Z0, Y0).hyper_
    assert hyper.groups() == [[0, 1]]
    shared = DiverseSelector(hyper, 60, block=32)
    single = DiverseSelector(hyper, 60, block=32, share=False)
    assert shared.P[0] is shared.P[1] and single.P[0] is not single.P[1]
    for sel in (shared, single):
        sel.initialize(Z0[:50], Y0[:50])
        sel.update(Z, Y)
    assert shared.stats.replaced > 50 and shared.stats.rejected_variance > 50
    np.testing.assert_array_equal(shared.Z, single.Z)
    np.testing.assert_array_equal(shared.Y, single.Y)
    assert shared.stats.as_dict() == single.stats.as_dict()
    np.testing.assert_array_equal(shared.loo_variance(), single.loo_variance())
    m1, v1 = shared.posterior(Z[:20])
    m2, v2 = single.posterior(Z[:20])
    np.testing.assert_array_equal(m1, m2)
    np.testing.assert_array_equal(v1, v2)
