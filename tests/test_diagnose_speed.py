"""Speed of the diagnosis without changing what it finds (issue 36, stop 45): the compiled kernel
split over threads gives the one-call predictions bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gprace.config import load_vehicle
from gprace.diagnose import core, fastpredict
from gprace.diagnose.synth import record
from gprace.model import EFFECTS

TRACKS = Path("/work/shared/data/tumftm-racetrack-database/tracks")
pytestmark = pytest.mark.skipif(not TRACKS.exists(), reason="TUM racetrack database not available")


@pytest.fixture(scope="module")
def setup():
    from gprace.backends.compiled import compiler
    from gprace.tracks.loaders import load_track

    if compiler() is None:
        pytest.skip("no C compiler")
    audi = load_vehicle("audi_tt_cup")
    track = load_track(TRACKS / "Norisring.csv")
    run = record(audi, track, [], laps=0.5, seed=4, substeps=5)
    return audi, track, core.build_dataset([run])


def test_threaded_kernel_equals_one_call(setup, monkeypatch):
    """Chunks on threads: per-window parameters, lags in a permuted order and a batched profile
    (its per-window table rows cut per profile) give exactly the single call's states."""
    from gprace.diagnose import profiles as pf

    audi, track, data = setup
    starts = data.windows(15)[::3]
    m = len(starts)
    basis = pf.Basis(float(track.length), 48, 6)
    rng = np.random.default_rng(1)
    cases = [
        [],
        [EFFECTS["steering_lag"](tau=0.08), EFFECTS["drivetrain_lag"](tau=0.2),
         EFFECTS["combined_slip"](k=np.linspace(0.1, 1.0, m))],
        [pf.batched_effect("road_bank_profile", basis, 0.03 * rng.standard_normal((3, basis.K)), np.arange(m) % 3),
         pf.batched_effect("friction_profile", basis, 1.0 + 0.1 * rng.standard_normal((2, basis.K)), np.arange(m) % 2),
         EFFECTS["downforce"](c_l=np.linspace(0.0, 2.0, m))],
    ]
    for effects in cases:
        model = core.model_for(audi, data, effects)
        assert fastpredict.plan(model) is not None
        out = {}
        for threads in (1, 2, 3):
            monkeypatch.setattr(fastpredict, "_threads", lambda t=threads: t)
            monkeypatch.setattr(fastpredict, "MIN_CHUNK_STEPS", 1)
            out[threads] = core.predict(model, data, starts, 15, 2)
        assert np.array_equal(out[1], out[2]) and np.array_equal(out[1], out[3])
        assert np.isfinite(out[1]).all()


def test_thread_count_from_the_environment(monkeypatch):
    """The variable sets the threads; a word instead of a number is a one-line configuration error."""
    from gprace.errors import ConfigError

    fastpredict._threads.cache_clear()
    try:
        monkeypatch.setenv(fastpredict.THREADS_ENV, "1")
        assert fastpredict._threads() == 1
        fastpredict._threads.cache_clear()
        monkeypatch.setenv(fastpredict.THREADS_ENV, "two")
        with pytest.raises(ConfigError, match=fastpredict.THREADS_ENV):
            fastpredict._threads()
    finally:
        fastpredict._threads.cache_clear()


# ------------------------------------------------------------------------------------------
# the search: ranking, threads, sensor effects below the noise


_RUNS: dict = {}


def _run(audi, track, effects, seed, laps=1.6):
    from gprace.config import EffectConfig

    key = (repr(effects), seed, laps)
    if key not in _RUNS:
        _RUNS[key] = record(audi, track, [EffectConfig(name=n, params=p) for n, p in effects], laps=laps,
                            seed=seed, substeps=5)
    return _RUNS[key]


def test_screen_ranks_the_hidden_effect_first(setup):
    """One naming round on a recording with a concealed downforce: the screening (linearised
    prescreen of every candidate, screening fits, cross-validation of the best) picks downforce."""
    from gprace.diagnose import diagnose as dg

    audi, track, _ = setup
    p = dg.prepare([_run(audi, track, [("downforce", {"c_l": 2.5})], seed=6)], 15, audi.wheelbase)
    s = dg.screen(p, audi, 0)
    ctx = dg._context(p, audi, s)
    prob = ctx.prob
    cv, top = dg._best_effect(prob, dg.locate_windows(s), s, ctx, set(s.nominal.dynamic_structured), [], 0,
                              lambda m: None)
    l0 = np.mean(prob.residuals(prob.model(), ctx.eval_w) ** 2, axis=1)
    best = dg._pick(ctx, l0, cv, top, 0, lambda m: None)
    assert best is not None and best.name == "downforce", {f.name: cv[f.name].mean() for f in top}
    assert abs(best.values()["c_l"] - 2.5) < 0.5


def test_threaded_diagnosis_names_what_one_thread_names(setup, monkeypatch):
    """The whole diagnosis with the kernel on threads gives the report of one thread: the same
    named effects with the same parameters (the kernel's chunks are bit-identical)."""
    from gprace.diagnose.diagnose import diagnose

    audi, track, _ = setup
    run = _run(audi, track, [("downforce", {"c_l": 2.5})], seed=6)
    monkeypatch.setattr(fastpredict, "_threads", lambda: 2)
    monkeypatch.setattr(fastpredict, "MIN_CHUNK_STEPS", 1)
    two = diagnose([run], audi).report
    monkeypatch.setattr(fastpredict, "_threads", lambda: 1)
    one = diagnose([run], audi).report
    assert [e["name"] for e in two["effects"]] == [e["name"] for e in one["effects"]] == ["downforce"]
    assert two["effects"][0]["parameters"] == one["effects"][0]["parameters"]


def test_sensor_offset_is_measured_against_the_noise_floor(setup):
    """A gyro bias changes the yaw rate by itself; a turned velocity frame changes v_y by about
    v_x sin(angle); an effect on the dynamics has no such size (None)."""
    from gprace.diagnose import name as nm

    audi, _, data = setup
    scale = np.array([0.1, 0.05, 0.01])
    prob = nm.Problem(audi, data, 15, scale)
    gyro = nm.Fit("gyro_bias", ["bias"], np.array([0.004]), {})
    assert nm.sensor_snr(prob, gyro) == pytest.approx(0.4, rel=1e-9)
    a = 0.002
    mis = nm.Fit("velocity_misalignment", ["angle"], np.array([a]), {})
    expect = np.sqrt(np.mean((data.Y[:, 0] * np.sin(a) + data.Y[:, 1] * (np.cos(a) - 1)) ** 2)) / 0.05
    assert nm.sensor_snr(prob, mis) == pytest.approx(expect, rel=1e-3)
    assert nm.sensor_snr(prob, nm.Fit("downforce", ["c_l"], np.array([2.0]), {})) is None


def test_a_sensor_offset_below_half_the_noise_is_not_picked(setup):
    """The same significant held-out gain names a velocity misalignment of 0.01 rad (several v_y
    noise floors at race speed) and refuses one of 0.0001 rad (a fraction of a floor)."""
    from gprace.diagnose import name as nm
    from gprace.diagnose.diagnose import Ctx, _pick

    audi, _, data = setup
    m = 800
    prob = nm.Problem(audi, data, 15, np.array([0.1, 0.05, 0.01]))
    ctx = Ctx(prob=prob, fit_w=np.arange(m), screen_w=np.arange(m), eval_w=np.arange(m), fold=np.arange(m) % 4,
              bid=np.arange(m) // 5, fit_stride=1, subsets=(), t_subset=4.0)
    rng = np.random.default_rng(2)
    l0 = np.column_stack([np.ones(m), 3.0 + 0.3 * rng.standard_normal(m), np.ones(m)])
    l1 = l0.copy()
    l1[:, 1] -= 1.5 + 0.3 * rng.standard_normal(m)  # consistent, significant gain on v_y
    for angle, named in ((0.01, True), (0.0001, False)):
        f = nm.Fit("velocity_misalignment", ["angle"], np.array([angle]), {})
        best = _pick(ctx, l0, {f.name: l1}, [f], 0, lambda s: None)
        assert (best is not None) == named, (angle, nm.sensor_snr(prob, f))


@pytest.mark.parametrize("effects,seed", [([("downforce", {"c_l": 2.5})], 6), ([("steering_lag", {"tau": 0.08})], 7)])
def test_looser_naming_stop_names_what_the_default_stop_names(setup, monkeypatch, effects, seed):
    """The naming fits stop at a relative cost change of ``NAMING_FTOL`` (1e-4) instead of scipy's
    1e-8: the whole diagnosis names the same effects, and each named parameter lands inside the
    95 % interval of the default stop's fit."""
    from gprace.diagnose import name as nm
    from gprace.diagnose.diagnose import diagnose

    audi, track, _ = setup
    run = _run(audi, track, effects, seed=seed)
    fast = diagnose([run], audi).report
    monkeypatch.setattr(nm, "NAMING_FTOL", 1e-8)
    slow = diagnose([run], audi).report
    assert [e["name"] for e in fast["effects"]] == [e["name"] for e in slow["effects"]] == [effects[0][0]]
    for ef, es in zip(fast["effects"], slow["effects"]):
        for k, p in es["parameters"].items():
            lo, hi = p["ci95"]
            assert lo <= ef["parameters"][k]["value"] <= hi, (k, ef["parameters"][k], p)


def test_fold_refits_of_a_profile_share_one_jacobian_exactly(setup):
    """A profile candidate refitted on each cross-validation fold's training windows: the
    Jacobian evaluated once on their union and cut per fold gives each fold's own refit (one
    penalised Gauss-Newton iteration, smoothing kept) to rounding."""
    from gprace.diagnose import name as nm, profiles as pf

    audi, track, _ = setup
    data = core.build_dataset([_run(audi, track, [("downforce", {"c_l": 2.5})], seed=6)])  # 1.6 laps
    prob = nm.Problem(audi, data, 15, np.array([0.1, 0.05, 0.01]))
    starts = data.windows(15)[::4]
    fit = pf.fit_profile(prob, "road_bank_profile", starts, iterations=1)
    assert fit is not None
    fit.x = fit.x + 0.01 * np.sin(np.arange(len(fit.x)))  # away from its optimum: the refits move
    fold = np.arange(len(starts)) * 3 // len(starts)
    trains = [starts[fold != k][::2] for k in range(3)]
    shared = pf.fold_refits(prob, fit, trains)
    for tr, g in zip(trains, shared):
        own = pf.refit(prob, fit, tr, iterations=1, keep_smoothing=True)
        assert np.abs(own.x - fit.x).max() > 1e-4
        np.testing.assert_allclose(g.x, own.x, rtol=1e-9, atol=1e-12)
        assert g.cost == pytest.approx(own.cost, rel=1e-9)


def test_row_groups_match_numpy_unique():
    """The runs-first grouping of parameter rows (crossval.row_groups) gives np.unique's distinct
    rows, and each group holds exactly the rows equal to its row, in runs or shuffled."""
    from gprace.diagnose.crossval import row_groups

    rng = np.random.default_rng(0)
    for trial in range(200):
        base = rng.integers(0, 4, size=(rng.integers(1, 6), 3)).astype(float)
        X = np.repeat(base, rng.integers(1, 5), axis=0)
        X = X[rng.permutation(len(X))] if trial % 2 else X
        rows, groups = row_groups(X)
        ref, inv = np.unique(X, axis=0, return_inverse=True)
        assert np.array_equal(rows, ref)
        assert [sorted(g) for g in groups] == [list(np.flatnonzero(inv.ravel() == r)) for r in range(len(ref))]
