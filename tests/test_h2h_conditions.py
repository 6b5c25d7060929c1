"""Head-to-head conditions (noise, baseline tracks, blocking weight, exploration time) and the
calibrated spread of the opponent predictions (issue 17, items 1 and 3)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gprace.cli import main
from gprace.errors import InputError
from gprace.h2h import protocol as P
from gprace.h2h.config import H2HConfig, opponent_mpc
from gprace.h2h.predictors import Context, make_predictor
from gprace.h2h.race import PROCESS_STREAM, SENSOR_STREAM, state_noise
from gprace.h2h.records import RaceAttrs, read_record
from gprace.h2h.spread import CALIB_LEVEL, at_least, band_coverage, fit_calibration, settled


def _hashes(tasks: list[dict]) -> list[str]:
    return [P.task_hash(t) for t in tasks]


def _all_tasks(st: P.Settings) -> dict[str, list[str]]:
    return {"collect": _hashes(P.collect_tasks(st, 4)), "init": _hashes(P.collect_tasks(st, 2, "eval")),
            "calib": _hashes(P.calib_tasks(st)), "eval": _hashes(P.eval_tasks(st, "cv", None))}


def test_each_condition_changes_exactly_the_tasks_it_affects():
    base = P.Settings(tracks=3, calib_runs=2)
    ref = _all_tasks(base)
    # noiseless: the tasks carry no noise entry, as before the noise existed
    quiet = P.Settings(tracks=3, calib_runs=2, sensor_noise=0.0, process_noise=0.0)
    assert all("sensor_std" not in t.config and "process_std" not in t.config for t in P.collect_tasks(quiet, 3))
    assert P.collect_tasks(quiet, 1)[0].config == {"max_time": quiet.max_time, "samples": quiet.samples}
    for kw in ({"sensor_noise": 0.5}, {"process_noise": 2.0}, {"blocking_weight": 100.0}):
        other = _all_tasks(P.Settings(tracks=3, calib_runs=2, **kw))
        for stage in ref:  # noise and blocking act in every race
            assert not set(ref[stage]) & set(other[stage]), (kw, stage)
    # the baseline's tracks change its collection runs only; the exploration starts on eval-style runs
    assert P.Settings().baseline_tracks == "training"  # the default: Zhu et al.'s tracks
    on_eval = _all_tasks(P.Settings(tracks=3, calib_runs=2, baseline_tracks="eval"))
    train = P.Settings(tracks=3, calib_runs=2, baseline_tracks="training")
    other = _all_tasks(train)
    assert not set(on_eval["collect"]) & set(other["collect"])
    assert on_eval["init"] == other["init"] == on_eval["collect"][:2]
    assert ref == other
    assert ref["calib"] == other["calib"] and ref["eval"] == other["eval"]
    assert {t.track.kind for t in P.collect_tasks(train, 4)} == {"training"}
    # exploration time: only the exploration episodes (their number) change
    assert _all_tasks(P.Settings(tracks=3, calib_runs=2, explore_minutes=3.0)) == ref


def test_conditions_reach_the_race_config_and_the_table_settings():
    st = P.Settings(tracks=2, raced=(), offline=(), sensor_noise=2.0, process_noise=0.0, blocking_weight=120.0,
                    baseline_tracks="training", explore_minutes=4.0)
    cfg = H2HConfig(**st.race_config())
    np.testing.assert_allclose(cfg.sensor_std, 2.0 * np.array(P.SENSOR_STD))
    assert cfg.process_std == (0.0,) * 6
    assert cfg.opponent.q_block == 120.0
    assert cfg.opponent.model_copy(update={"q_block": opponent_mpc().q_block}) == opponent_mpc()
    assert "opponent" not in P.Settings().race_config()  # the default weight adds nothing
    tab = P.table(st, {}, {})
    for key, value in (("sensor_noise", 2.0), ("process_noise", 0.0), ("blocking_weight", 120.0),
                       ("baseline_tracks", "training"), ("explore_minutes", 4.0)):
        assert tab["settings"][key] == value
    assert tab["conditions"]["sensor_std"] == [2.0 * v for v in P.SENSOR_STD]
    assert tab["conditions"]["baseline_tracks"] == "training" and tab["conditions"]["explore_minutes"] == 4.0


def test_training_tracks_are_the_short_curve_and_chicane_tracks():
    from gprace.h2h.geometry import make_track

    tracks = [make_track({"kind": "training", "seed": s, "width": 0.75}) for s in range(6)]
    kinds = [t.name.split("-")[1] for t in tracks]
    assert kinds == ["curve", "chicane"] * 3
    assert all(6.0 < t.length < 16.0 for t in tracks)  # one stretch, not a 30 m evaluation track
    again = make_track({"kind": "training", "seed": 3, "width": 0.75})
    assert again.length == tracks[3].length


def test_injected_noise_has_the_stated_statistics_and_is_seeded():
    std = np.array([0.01, 0.02, 0.03, 0.0, 0.005, 0.5])
    draw = state_noise(7, SENSOR_STREAM, std)
    X = np.stack([draw() for _ in range(20000)])  # (n, 2 cars, 6)
    n = len(X) * 2
    flat = X.reshape(-1, 6)
    np.testing.assert_array_less(np.abs(flat.mean(axis=0)), 5 * std / np.sqrt(n) + 1e-15)
    np.testing.assert_allclose(flat.std(axis=0), std, rtol=0.02)
    assert np.all(flat[:, 3] == 0)
    again = state_noise(7, SENSOR_STREAM, std)
    np.testing.assert_array_equal(np.stack([again() for _ in range(20000)]), X)
    other = state_noise(7, PROCESS_STREAM, std)()
    assert not np.allclose(other, X[0])  # the two kinds draw from their own generators
    assert state_noise(7, SENSOR_STREAM, np.zeros(6)) is None


def test_a_noisy_race_sees_the_measured_states_and_is_deterministic():
    from gprace.h2h.race import run_race

    sensor = [0.01, 0.01, 0.02, 0.005, 0.005, 0.005]
    task = {"track": {"kind": "random", "seed": 3, "stretches": 1, "width": 0.75}, "seed": 11, "predictor": "cv",
            "config": {"max_time": 0.5, "sensor_std": sensor, "process_std": [0.01, 0.005, 0.02, 0, 0, 0]}}
    a, b = run_race(task), run_race(task)
    for key in ("ego", "opp", "ego_meas", "opp_meas"):
        np.testing.assert_array_equal(a["arrays"][key], b["arrays"][key])
    # the measurement is the true state plus the sensor stream's draws, step after step
    draw = state_noise(11, SENSOR_STREAM, sensor)
    for t in range(len(a["arrays"]["ego"])):
        d = draw()
        np.testing.assert_allclose(a["arrays"]["ego_meas"][t] - a["arrays"]["ego"][t], d[0], atol=1e-12)
        np.testing.assert_allclose(a["arrays"]["opp_meas"][t] - a["arrays"]["opp"][t], d[1], atol=1e-12)
    quiet = run_race({**task, "config": {"max_time": 0.5}})
    assert "ego_meas" not in quiet["arrays"]
    assert not np.allclose(quiet["arrays"]["opp"], a["arrays"]["opp"])  # process noise moved the cars


def test_a_race_ends_on_the_one_stop_rule():
    """Process noise throws the cars off the track, or turns them across it: the race ends at once
    and says which (gprace.sim.stop)."""
    from gprace.h2h.race import run_race

    task = {"track": {"kind": "random", "seed": 3, "stretches": 1, "width": 0.75}, "seed": 11, "predictor": "cv"}
    off = run_race({**task, "config": {"max_time": 2.0, "process_std": [0, 0, 0, 0, 3.0, 0]}})["attrs"]
    spun = run_race({**task, "config": {"max_time": 2.0, "process_std": [0, 0, 0, 3.0, 0, 0]}})["attrs"]
    assert (off["end_reason"], spun["end_reason"]) == ("off_track", "spun")
    assert off["steps"] < 5 and spun["steps"] < 5


def _synthetic(rng, n: int, K: int = 3):
    """Errors whose true std is 3 x the predicted one (an over-confident predictor)."""
    std = rng.uniform(0.01, 0.05, size=(2, K, n))
    return np.abs(3.0 * std * rng.standard_normal((2, K, n))), std


def test_calibrated_band_covers_90_to_95_percent_of_fresh_errors():
    rng = np.random.default_rng(0)
    err, std = _synthetic(rng, 20000)
    cal = fit_calibration(err, std)
    np.testing.assert_allclose(cal["scale"], 1.5 * 1.88, rtol=0.05)  # 3 x the 94 % two-sided z / 2
    fresh_err, fresh_std = _synthetic(rng, 20000)
    cov = band_coverage(fresh_err, fresh_std, cal)
    assert np.all((cov >= 0.90) & (cov <= 0.95)), cov
    raw = band_coverage(fresh_err, fresh_std)
    assert np.all(raw < 0.6)  # 2 predicted std cover |z| < 2/3 only
    assert abs(float(cov.mean()) - CALIB_LEVEL) < 0.01


def test_calibration_passes_settle_where_the_races_they_drive_are_covered():
    """The errors shrink when the ego drives with wider ellipses (it keeps back, the opponent blocks
    less): here the error spread is 1 + 4 / (1 + c) raw std for an ego driving with scale c. A
    calibration fitted on races driven with a larger one is too small for its own races; passing
    on the fit until the races confirm it, then keeping the larger of the two, covers them."""
    rng = np.random.default_rng(4)
    K, n = 3, 20000

    def races(c: np.ndarray):  # errors and raw spreads of races driven with scale c (K, 2)
        std = rng.uniform(0.01, 0.05, size=(2, K, n))
        return np.abs((1.0 + 4.0 / (1.0 + c.T[..., None])) * std * rng.standard_normal((2, K, n))), std

    def cov(cal):
        return band_coverage(*races(np.asarray(cal["scale"])), cal)

    first = {"scale": np.full((K, 2), 4.0).tolist(), "floor": np.zeros((K, 2)).tolist()}  # a wide first one
    once = fit_calibration(*races(np.asarray(first["scale"])))  # one driven pass
    assert not settled(first, once) and np.all(cov(once) < 0.90)
    driving, passes = once, 0
    while True:
        fitted = fit_calibration(*races(np.asarray(driving["scale"])))
        passes += 1
        if settled(driving, fitted):
            break
        driving = fitted
    final = at_least(driving, fitted)
    assert passes <= 4 and np.all(cov(final) >= 0.90), (passes, cov(final))
    assert np.all(np.asarray(final["scale"]) >= np.asarray(fitted["scale"]))


def test_a_predictor_without_spread_gets_a_floor_of_its_typical_error():
    rng = np.random.default_rng(1)
    K, n = 4, 20000
    scale = np.linspace(0.01, 0.04, K)[None, :, None]
    err = np.abs(scale * rng.standard_normal((2, K, n)))
    cal = fit_calibration(err, np.zeros_like(err))
    assert np.all(np.asarray(cal["scale"]) == 0)
    fresh = np.abs(scale * rng.standard_normal((2, K, n)))
    cov = band_coverage(fresh, np.zeros_like(fresh), cal)
    assert np.all((cov >= 0.90) & (cov <= 0.95)), cov
    # the constant-velocity predictor carries that floor as its spread
    from gprace.h2h.geometry import make_track

    cv = make_predictor("cv", K, 0.1, calibration=cal)
    track = make_track({"kind": "random", "seed": 1, "stretches": 1, "width": 0.75})
    pred = cv.predict(Context(track, np.zeros((K + 1, 6)), np.array([1.0, 0, 0, 0, 0.1, 2.0])))
    np.testing.assert_allclose(pred.std, np.asarray(cal["floor"]))
    np.testing.assert_array_equal(pred.raw_std, np.zeros((K, 2)))
    assert np.all(make_predictor("cv", K, 0.1).predict(Context(track, np.zeros((K + 1, 6)), np.ones(6))).std == 0)


def test_bad_calibration_is_refused():
    with pytest.raises(InputError, match="calibration"):
        make_predictor("cv", 3, calibration={"scale": [[1, 1]], "floor": [[0, 0]]})
    with pytest.raises(InputError, match="calibration"):
        make_predictor("cv", 1, calibration={"scale": [[1, -1]], "floor": [[0, 0]]})


@pytest.mark.parametrize("args, text", [
    (["--baseline-tracks", "curve"], "--baseline-tracks"),
    (["--blocking-weight", "-1"], "--blocking-weight"),
    (["--sensor-noise", "nan"], "--sensor-noise"),
    (["--process-noise", "-0.5"], "--process-noise"),
    (["--calib-runs", "0"], "--calib-runs"),
])
def test_bad_conditions_exit_2_with_one_line(tmp_path, capsys, args, text):
    code = main(["eval", "head2head", "--out", str(tmp_path / "out"), *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and text in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_calibration_reaches_the_races_and_the_coverage_table(tmp_path):
    st = P.Settings(tracks=2, raced=("cv",), offline=("cv",), max_time=1.5, samples=5, calib_runs=2, workers=1)
    cal = P.calibrate(st, tmp_path, {})
    assert set(cal) == {"cv"} and (tmp_path / "calib" / "calibration.json").exists()
    # driven passes: the raced predictor drives calib_runs more races per pass with the calibration of
    # the pass before (the first with the oracle pass's), on tracks of their own; each pass's fit is
    # on its own races alone, and the final calibration is the larger of the last pass's two
    history = json.loads((tmp_path / "calib" / "passes.json").read_text())
    drove = json.loads((tmp_path / "calib" / "calibration_oracle.json").read_text())["cv"]
    seen = {t.seed for t in P.calib_tasks(st)}
    for i, h in enumerate(history):
        assert h["drove_with"]["cv"] == drove
        folder = tmp_path / "calib" / ("cv" if i == 0 else f"pass{i + 2}/cv")
        own = [read_record(f, RaceAttrs) for f in sorted((folder / "runs").glob("*.h5"))]
        tasks = [r.attrs.task for r in own]
        assert len(own) == 2 and all(t["calibration"]["floor"] == drove["floor"] and t["predictor"] == "cv" for t in tasks)
        assert seen.isdisjoint(t["seed"] for t in tasks)
        seen |= {t["seed"] for t in tasks}
        _, arrays = P.evaluation._rollout_errors(st, own, folder / "runs", folder / "errors", ["cv"], {}, "check")
        assert h["fitted"]["cv"] == P.evaluation._fit_calibration(st, arrays, ["cv"])["cv"]
        assert h["settled"] == settled(drove, h["fitted"]["cv"])
        drove = h["fitted"]["cv"]
    assert 1 <= len(history) <= st.calib_passes and (history[-1]["settled"] or len(history) == st.calib_passes)
    assert all(not h["settled"] for h in history[:-1])
    assert cal["cv"] == at_least(history[-1]["drove_with"]["cv"], history[-1]["fitted"]["cv"])
    floor = np.asarray(cal["cv"]["floor"])
    assert floor.shape == (H2HConfig().pred_steps, 2) and np.all(floor > 0) and np.all(np.diff(floor[:, 1]) >= 0)
    raced = P.race_predictors(st, tmp_path, {}, cal)
    assert all(r.attrs.task["calibration"]["floor"] == cal["cv"]["floor"] for r in raced["cv"])
    errors, _, spread = P.offline_error_data(st, tmp_path, raced, {})
    cov = P.coverage(spread, errors, cal)["cv"]
    assert cov["points"] == errors["cv"].shape[1] > 0
    assert all(c == 0 for c in cov["ey_raw"][1:])  # no spread: the raw band covers nothing
    assert all(0 <= c <= 1 for c in cov["ey"]) and cov["calibrated"]


def test_race_inflates_the_ellipses_by_the_calibration(monkeypatch):
    """The calibration a task carries reaches the ego's collision ellipses: the constant-velocity
    predictor has no spread of its own, so its ellipses grow by exactly its calibrated floor."""
    import gprace.h2h.race as R

    seen = []
    real = R.ellipse_data

    def spy(track, cfg, mean, std):
        seen.append(np.asarray(std, float).copy())
        return real(track, cfg, mean, std)

    monkeypatch.setattr(R, "ellipse_data", spy)
    K = H2HConfig().pred_steps
    floor = np.column_stack([np.linspace(0.01, 0.05, K), np.linspace(0.02, 0.1, K)])
    task = {"track": {"kind": "random", "seed": 3, "stretches": 5, "width": 0.75}, "seed": 3, "predictor": "cv",
            "config": {"max_time": 0.5}}
    R.run_race(task)
    plain, seen[:] = list(seen), []
    R.run_race({**task, "calibration": {"scale": np.zeros((K, 2)).tolist(), "floor": floor.tolist()}})
    assert plain and all(np.all(s == 0) for s in plain)
    ego = seen[1::2]  # per step: the opponent's ellipses around the ego (no spread), then the ego's
    assert ego and all(np.allclose(s, R.extend(floor, len(s))) for s in ego) and all(np.all(s == 0) for s in seen[::2])


def test_constant_velocity_prediction_advances_every_step():
    """Held Frenet rates move the car by ``k dt`` times them at step k (regression: from 06c19f4 on
    every step held the first step's position, so the opponent saw the ego standing still)."""
    from gprace.h2h.geometry import make_track

    track = make_track({"kind": "random", "seed": 3, "stretches": 5, "width": 0.75})
    K, dt = 9, 0.1
    x = np.array([1.0, 0.05, 0.0, 0.02, 0.1, 2.0])
    kap = float(track.kappa(2.0))
    sdot = (x[0] * np.cos(x[3]) - x[1] * np.sin(x[3])) / (1.0 - kap * x[4])
    eydot = x[0] * np.sin(x[3]) + x[1] * np.cos(x[3])
    k = dt * np.arange(1, K + 1)
    mean = make_predictor("cv", K, dt).predict(Context(track, np.zeros((K + 1, 6)), x)).mean
    np.testing.assert_allclose(mean[:, 5], 2.0 + k * sdot, rtol=1e-12)
    np.testing.assert_allclose(mean[:, 4], 0.1 + k * eydot, rtol=1e-12)
    np.testing.assert_array_equal(mean[:, [0, 1, 2, 3]], np.tile(x[:4], (K, 1)))


def test_the_study_links_the_default_conditions_records_first(tmp_path):
    """A condition shares its stages with the default: where two conditions hold a record of the
    same run, the default's is the one linked (``baseline_eval_tracks`` sorts before it)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "h2h_study.py"
    spec = importlib.util.spec_from_file_location("h2h_study", path)
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    for cond in ("baseline_eval_tracks", "default", "no_blocking"):
        rec = tmp_path / cond / "collect" / "runs" / "run_00000.h5"
        rec.parent.mkdir(parents=True)
        rec.write_text(cond)
    only = tmp_path / "no_blocking" / "eval" / "cv" / "run_00003.h5"
    only.parent.mkdir(parents=True)
    only.write_text("no_blocking")
    dst = tmp_path / "explore_3min"
    assert study.link_records(tmp_path, dst) == 2
    assert (dst / "collect" / "runs" / "run_00000.h5").read_text() == "default"
    assert (dst / "eval" / "cv" / "run_00003.h5").read_text() == "no_blocking"
