"""Head-to-head protocol: executors agree, failed runs are recorded and skipped, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gprace.cli import main
from gprace.errors import InputError, UnknownBackendError
from gprace.h2h import protocol as P
from gprace.h2h.predictors import make_predictor, read_opponent_gp
from gprace.h2h.records import ErrorAttrs, RaceAttrs, read_record

TINY = dict(tracks=2, raced=("cv",), offline=("cv",), max_time=1.5, samples=5)


def _batch(out: Path, **kw) -> tuple[dict, dict]:
    st = P.Settings(**{**TINY, **kw})
    raced = P.race_predictors(st, out, {})
    errors = P.offline_errors(st, out, raced, {})
    return P.table(st, raced, errors), raced


def _comparable(tab: dict) -> dict:
    tab = json.loads(json.dumps(tab))
    for row in tab["racing"].values():
        row.pop("ego_solve_ms_median")  # wall-clock time: the only thing allowed to differ
    return tab


def test_local_and_dask_give_identical_tables(tmp_path):
    from dask.distributed import LocalCluster

    local, rec_local = _batch(tmp_path / "local")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        dask, rec_dask = _batch(tmp_path / "dask", executor="dask", scheduler=cluster.scheduler_address)
    assert _comparable(local) == _comparable(dask)
    for a, b in zip(rec_local["cv"], rec_dask["cv"]):
        np.testing.assert_array_equal(a.arrays["ego"], b.arrays["ego"])
        np.testing.assert_array_equal(a.arrays["opp"], b.arrays["opp"])
    assert local["racing"]["cv"]["runs"] == 2 and local["racing"]["cv"]["failed"] == 0
    assert local["ey_error"]["cv"]["points"] > 0
    # per-run records are HDF5 artifacts
    rec = read_record(tmp_path / "local" / "eval" / "cv" / "run_00000.h5", RaceAttrs)
    assert rec.attrs.ok and rec.arrays["ego"].shape[1] == 6


def test_tasks_run_with_one_blas_thread_from_the_first_one():
    """SciPy's own OpenBLAS loads lazily; the first task of a fresh process must be limited too
    (otherwise it rounds differently from the later ones and a race takes another course)."""
    import subprocess
    import sys

    code = (
        "from threadpoolctl import threadpool_info\n"
        "from gprace.executor import single_thread_blas\n"
        "def task():\n"
        "    import scipy.linalg\n"
        "    return sorted((i['filepath'], i['num_threads']) for i in threadpool_info())\n"
        "print(single_thread_blas(task)())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    libs = eval(out)  # noqa: S307 -- our own repr of a list of tuples
    assert any("scipy" in path or "openblas" in path for path, _ in libs)
    assert all(n == 1 for _, n in libs), libs


def test_offline_errors_are_recorded_and_reused(tmp_path, monkeypatch):
    st = P.Settings(**{**TINY, "workers": 1, "resume": True})
    raced = P.race_predictors(st, tmp_path, {})
    first = P.offline_errors(st, tmp_path, raced, {})
    assert sorted(p.name for p in (tmp_path / "errors" / "cv").iterdir()) == ["run_00000.h5", "run_00001.h5"]

    def recomputed(task):
        raise AssertionError("an offline error task ran again")

    monkeypatch.setattr(P.evaluation, "offline_errors_task", recomputed)
    again = P.offline_errors(st, tmp_path, raced, {})
    assert first["cv"].shape[1] > 0
    np.testing.assert_array_equal(first["cv"], again["cv"])


def test_report_draws_the_errors_of_a_race_from_its_stored_record_only(tmp_path, monkeypatch):
    from gprace.report.collect import scan
    from gprace.report.sections import h2h as collect

    st = P.Settings(**{**TINY, "workers": 1})
    raced = P.race_predictors(st, tmp_path, {})

    def no_simulation(task):  # the report computes nothing
        raise AssertionError("the report ran an offline error task")

    race = tmp_path / "eval" / "cv" / "run_00000.h5"
    rec = read_record(race, RaceAttrs)
    with monkeypatch.context() as m:
        m.setattr(P.evaluation, "offline_errors_task", no_simulation)
        # no errors/ yet: no figure, and one note naming the race and the command that stores them
        assert collect._errors_along(race, rec, [])[0] is None
        sec = collect.h2h_section(scan(tmp_path))
    notes = [n for n in sec.missing if "no stored offline errors" in n]
    assert len(notes) == 1 and "cv/run_00000.h5" in notes[0] and "gprace eval head2head" in notes[0]
    assert "error_along_run" not in {i.name for i in sec.items}
    P.offline_errors(st, tmp_path, raced, {})
    monkeypatch.setattr(P.evaluation, "offline_errors_task", no_simulation)
    (t, E), why = collect._errors_along(race, rec, [])
    stored = read_record(tmp_path / "errors" / "cv" / "run_00000.h5", ErrorAttrs)
    np.testing.assert_array_equal(E["cv"], stored.arrays["cv"])
    assert len(t) == E["cv"].shape[1] and why == ""
    assert "error_along_run" in {i.name for i in collect.h2h_section(scan(tmp_path)).items}
    # the stored record of another race is not taken for this one
    other = tmp_path / "errors" / "cv" / "run_00001.h5"
    other.replace(tmp_path / "errors" / "cv" / "run_00000.h5")
    errs, why = collect._errors_along(race, rec, [])
    assert errs is None and "of another race" in why


def test_task_hash_follows_file_contents_not_locations():
    t = {"id": "eval-gp-0", "seed": 3, "model": "/a/models/explore.h5", "model_hash": "abc"}
    moved = {**t, "id": "other", "model": "/b/models/explore.h5"}
    assert P.task_hash(t) == P.task_hash(moved)  # a copied --out directory is reused
    assert P.task_hash(t) != P.task_hash({**t, "model_hash": "abd"})  # a refitted model is not
    assert P.task_hash(t) != P.task_hash({**t, "seed": 4})


def test_failed_run_is_recorded_skipped_and_resumed(tmp_path):
    st = P.Settings(**{**TINY, "tracks": 3})
    tasks = P.eval_tasks(st, "cv", None)
    tasks[1] = tasks[1].model_copy(update={"predictor": "gp", "model": str(tmp_path / "missing.h5")})  # this run raises
    recs = P.run_tasks(tasks, tmp_path / "runs", st, "test")
    assert [r.attrs.ok for r in recs] == [True, False, True]
    assert "missing.h5" in recs[1].attrs.error
    on_disk = read_record(tmp_path / "runs" / "run_00001.h5", RaceAttrs)
    assert on_disk.attrs.ok is False and on_disk.attrs.error == recs[1].attrs.error
    tab = P.table(st, {"cv": recs}, {})
    assert tab["racing"]["cv"]["failed"] == 1 and tab["racing"]["cv"]["runs"] == 3
    # resume: only the failed run is attempted again
    calls = []

    def counting(task):
        calls.append(task.seed)
        return P.race_with_data(task)

    st = st.model_copy(update={"resume": True})
    again = P.run_tasks(tasks, tmp_path / "runs", st, "test", fn=counting)
    assert calls == [tasks[1].seed]
    np.testing.assert_array_equal(again[0].arrays["ego"], recs[0].arrays["ego"])


def test_unknown_predictor():
    with pytest.raises(UnknownBackendError, match="cv, gp, oracle"):
        make_predictor("kalman", 9)
    assert main(["eval", "head2head", "--tracks", "1", "--predictors", "kalman", "--out", "/tmp/unused_h2h"]) == 2


def test_model_with_wrong_feature_layout(tmp_path):
    from gprace.gp import make_gp, save_model

    rng = np.random.default_rng(0)
    Z, Y = rng.normal(size=(30, 3)), rng.normal(size=(30, 2))
    gp = make_gp("exact", kernel="matern15", optimize=False).fit(Z, Y)
    bad = tmp_path / "tracking.h5"
    save_model(bad, gp, {"feature_map": "tracking", "input_names": ["v_y", "yaw_rate", "delta"],
                         "output_names": ["e_vy", "e_r"]})
    with pytest.raises(InputError, match="opponent"):
        read_opponent_gp(bad)
    data = tmp_path / "d.h5"
    P.data._write_dataset(data, rng.normal(size=(5, 11)), rng.normal(size=(5, 5)), np.zeros(5), {}, {})
    rc = main(["h2h", "explore", "--out", str(tmp_path / "o"), "--init-model", str(bad), "--init-data", str(data),
               "--explore-minutes", "0.01"])
    assert rc == 2
    assert not (tmp_path / "o" / "explore" / "runs").exists()  # nothing ran


def test_unreachable_scheduler_loses_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    (out / "collect").mkdir(parents=True)
    keep = out / "collect" / "dataset.h5"
    keep.write_bytes(b"finished work")
    rc = main(["eval", "head2head", "--tracks", "2", "--out", str(out), "--executor", "dask",
               "--scheduler", "tcp://127.0.0.1:1"])
    assert rc == 2
    assert "cannot reach Dask scheduler" in capsys.readouterr().err
    assert keep.read_bytes() == b"finished work"


def test_zero_tracks(capsys):
    assert main(["eval", "head2head", "--tracks", "0", "--out", "/tmp/unused_h2h"]) == 2
    assert "--tracks must be >= 1" in capsys.readouterr().err
    with pytest.raises(InputError):
        P.Settings(tracks=0)


def test_exploration_width_outside_the_loop_validity(capsys, tmp_path):
    assert main(["eval", "head2head", "--explore-width", "3", "--out", str(tmp_path / "out")]) == 2
    assert "--explore-width" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # rejected before any work


# ----------------------------------------------------------------------------------------------
# spread over seeds and bootstrap over tracks
def _hand_made(times_e, times_b, err_e, err_b, hits_e=(0, 0, 0, 0)):
    """4 tracks, raced explore and baseline; offline errors with K = 1 and one column per track
    (track 3 two columns)."""
    from gprace.h2h.records import RaceAttrs, Record
    from gprace.h2h.spread import track_data

    def recs(times, hits):
        return [Record({}, RaceAttrs(ok=True, border_hit=bool(h), collision=False, overtake_time=t))
                for t, h in zip(times, hits)]

    tracks = np.array([0, 1, 2, 3, 3])
    errors = {"explore": np.array([err_e]), "baseline": np.array([err_b])}
    return track_data({"explore": recs(times_e, hits_e), "baseline": recs(times_b, (0, 0, 0, 0))}, errors, tracks, 4)


def test_figures_and_their_resamples_on_hand_made_numbers():
    from gprace.h2h.spread import figures

    nan = np.nan
    td = _hand_made([2.0, nan, 4.0, 6.0], [3.0, 5.0, nan, 7.0], [1, 2, 3, 4, 6], [2, 2, 2, 2, 2], hits_e=(0, 0, 1, 0))
    f = figures(td, np.ones((1, 4)))
    assert f["explore.overtakes"][0] == 3 and f["baseline.overtakes"][0] == 3
    assert f["explore.border_hits"][0] == 1 and f["diff.border_hits"][0] == 1
    # track 2 is out (explore hit the border): overtake times over tracks 0, 1 and 3
    assert f["explore.overtake_time"][0] == pytest.approx(4.0) and f["baseline.overtake_time"][0] == pytest.approx(5.0)
    assert f["diff.overtake_time"][0] == pytest.approx(((2 - 3) + (6 - 7)) / 2)  # paired, both overtook
    assert f["explore.ey_error_1"][0] == pytest.approx(16 / 5) and f["diff.ey_error_1"][0] == pytest.approx(16 / 5 - 2)
    # a resample is the table of the duplicated tracks: track 3 twice, track 1 twice, 0 and 2 never
    w = figures(td, np.array([[0, 2, 0, 2]]))
    assert w["explore.overtakes"][0] == 2 and w["explore.ey_error_1"][0] == pytest.approx((2 * 2 + 2 * 10) / 6)
    assert w["explore.overtake_time"][0] == pytest.approx(6.0) and w["diff.overtake_time"][0] == pytest.approx(-1.0)


def test_spread_over_seeds_and_claims():
    from gprace.h2h.spread import seed_stats, summarise, verdict

    s = seed_stats([0.02, 0.03, 0.025])
    assert s["mean"] == pytest.approx(0.025) and s["seed_std"] == pytest.approx(0.005)
    assert s["min"] == 0.02 and s["max"] == 0.03 and seed_stats([1.0])["seed_std"] is None
    assert verdict([[-3, -1], [-2, -0.5]]) == "holds"
    assert verdict([[-3, -1], [-2, 0.5]]) == "not resolved"  # one seed within its track spread
    assert verdict([[-3, -1], [1, 2]]) == "seeds disagree"
    assert verdict([[1, 2], [0.5, 3]]) == "fails"
    assert verdict([[1, 2]], claimed=+1) == "holds"

    nan = np.nan
    t = [1.0, 1.0, 1.0, 1.0]
    a = _hand_made(t, t, [1, 1.1, 0.9, 1.0, 1.05], [2, 2.1, 1.9, 2.0, 2.05])  # explore better on every track
    b = _hand_made(t, t, [1.5, 1.6, 1.4, 1.5, 1.55], [2, 2.1, 1.9, 2.0, 2.05])
    c = _hand_made(t, t, [3, 3.1, 2.9, 3.0, 3.05], [2, 2.1, 1.9, 2.0, 2.05])  # worse in this seed
    two = summarise([a, b], B=300)
    row = two["diff.ey_error_1"]
    assert row["values"] == pytest.approx([-1.0, -0.5]) and row["mean"] == pytest.approx(-0.75)
    assert row["seed_std"] == pytest.approx(np.std([-1.0, -0.5], ddof=1))
    assert row["ci"][0] <= -0.75 <= row["ci"][1]
    # four tracks: every one agrees, but no verdict from so few (issue 38; gprace.verdict.MIN_SAMPLES)
    assert row["tracks"] == 4 and row["verdict"] == "too few samples for a verdict"
    assert two["explore.ey_error_1"]["mean"] == pytest.approx((1.01 + 1.51) / 2)
    assert summarise([a, c], B=300)["diff.ey_error_1"]["verdict"] == "too few samples for a verdict"
    assert np.isnan(summarise([_hand_made([nan] * 4, t, [1] * 5, [1] * 5)], B=50)["diff.overtake_time"]["values"][0])


def test_seeds_option_and_chain_layout(tmp_path):
    assert P.parse_seeds("3") == (0, 1, 2) and P.parse_seeds("0,4,7") == (0, 4, 7) and P.parse_seeds("5,") == (5,)
    for bad in ("0", "a", "1,1", "-1,2"):
        with pytest.raises(InputError, match="--seeds"):
            P.parse_seeds(bad)
    assert main(["eval", "head2head", "--seeds", "x", "--out", str(tmp_path / "o")]) == 2
    # seed 0 is the single-seed protocol (same folder, same run seeds: finished work is reused)
    st = P.Settings()
    assert P.chain_dir(tmp_path, 0) == tmp_path and P.chain_dir(tmp_path, 2) == tmp_path / "seed_2"
    assert [t.seed for t in P.collect_tasks(st, 2)] == [P.SEED_COLLECT, P.SEED_COLLECT + 1]
    other = P.collect_tasks(P.Settings(seed=1), 2)
    assert {t.seed for t in other}.isdisjoint({P.SEED_COLLECT, P.SEED_COLLECT + 1})
    assert P.eval_tasks(P.Settings(seed=1, tracks=2), "cv", None) == P.eval_tasks(P.Settings(tracks=2), "cv", None)


def test_train_refuses_a_degenerate_fit_and_reports_a_sound_one(tmp_path, capsys, monkeypatch):
    """An opponent dataset whose last output is pure noise: `h2h train` exits 2 with one line and
    writes no model (nothing can race it); without that output the report is printed and stored.
    (The reference's 300 points that make "no signal" a refusal are lowered to keep the test fast.)"""
    from threadpoolctl import threadpool_limits

    from gprace.gp import quality

    monkeypatch.setattr(quality, "REFERENCE_POINTS", 100)

    rng = np.random.default_rng(0)
    n = 200
    Z = rng.normal(size=(n, 11))
    Y = np.column_stack([np.sin(Z[:, 0]), 0.5 * Z[:, 1], np.tanh(Z[:, 2]), Z[:, 3] * 0.2, rng.normal(size=n)])
    bad, good = tmp_path / "bad.h5", tmp_path / "good.h5"
    P.data._write_dataset(bad, Z, Y, np.zeros(n), {}, {})
    Y[:, 4] = np.cos(Z[:, 4])
    P.data._write_dataset(good, Z, Y, np.zeros(n), {}, {})
    with threadpool_limits(limits=1):
        assert main(["h2h", "train", str(bad), str(tmp_path / "m_bad.h5")]) == 2
        err = capsys.readouterr().err
        # the stage's start line, then one error line naming the output
        errors = [ln for ln in err.splitlines() if ln.startswith("error:")]
        assert len(errors) == 1 and "dyaw_rate_opp" in errors[0] and "refused" in errors[0]
        assert err.strip().splitlines()[-1] == errors[0]
        assert not (tmp_path / "m_bad.h5").exists()
        assert main(["h2h", "train", str(good), str(tmp_path / "m.h5")]) == 0
    out = capsys.readouterr().out
    assert "Fit quality" in out and "dyaw_rate_opp" in out
    q = P.fit_report(tmp_path / "m.h5")
    assert not q.degenerate and q.outputs[-1] == "dyaw_rate_opp" and max(q.heldout) < 0.95


# task hashes written by the protocol when its tasks were plain dicts (commit 422047a): an --out
# folder of that version must be reused by the typed tasks (issue 40)
DICT_ERA_HASHES = {
    (): {"collect": "4a1bcd1282807d1a", "init": "99bb7d36c7e3d6bc", "calib": "ba961752adbd6853",
         "calib_gp": "792e688562aa0c39", "eval_cv": "4fee79a201caf260", "eval_gp": "6c971d6990fa542d"},
    (("process_noise", 0.5), ("seed", 2), ("sensor_noise", 0.0), ("stretches", 3), ("width", 0.9)): {
        "collect": "afccbab4fab74006", "init": "4b029e4a539bd5de", "calib": "4f9e85bbe2a85f0b",
        "calib_gp": "eece625b66e2b130", "eval_cv": "ae13777973445067", "eval_gp": "fa448338bc9b31c0"},
    (("baseline_tracks", "eval"), ("blocking_weight", 3.0), ("max_time", 8.0), ("samples", 10)): {
        "collect": "5520f2359d90cd76", "init": "5520f2359d90cd76", "calib": "d435c3ef39fcec8a",
        "calib_gp": "a0ffabe891a8f2e8", "eval_cv": "7e4b2c6ef5488b47", "eval_gp": "6470ced36ac9baf9"},
}


@pytest.mark.parametrize("conditions", list(DICT_ERA_HASHES))
def test_typed_tasks_hash_as_the_dict_tasks_did(tmp_path, conditions):
    model = tmp_path / "m.h5"
    model.write_bytes(b"model-bytes")  # the model's hash enters the GP tasks
    st = P.Settings(tracks=2, runs=2, init_runs=1, calib_runs=2, **dict(conditions))
    cal = {"scale": [[1.0, 2.0]], "floor": [[0.0, 0.1]]}
    first = {"collect": P.collect_tasks(st, 2)[0], "init": P.collect_tasks(st, 2, "eval")[0],
             "calib": P.calib_tasks(st)[0], "calib_gp": P.calib_tasks(st, "explore", model, cal, 2, 2)[0],
             "eval_cv": P.eval_tasks(st, "cv", None)[0], "eval_gp": P.eval_tasks(st, "baseline", model, cal)[0]}
    assert {k: P.task_hash(t) for k, t in first.items()} == DICT_ERA_HASHES[conditions]
    for t in first.values():  # a task read back from its record is the same task
        assert type(t).of(t.as_dict()) == t and P.task_hash(t.as_dict()) == t.hash()
