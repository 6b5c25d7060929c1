"""gprace learn / eval learn on a simulated 1:10 car with hidden physics, through files only (issue 39).

One lap of the BARC car with worn front tires and a steering lag on the head-to-head loop is
driven by the nominal MPC, exported to a global-frame CSV by code of this test (the centre line
sampled every 5 cm, x = c + e_y n, yaw = heading + e_psi), and learned from. Small GP settings keep
the module's fixture near 20 s.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

PLANT = """kind = "frenet"
vehicle = "barc_1_10"
substeps = 10
seed = 0

[[effects]]
name = "tire_friction"
front = 0.85

[[effects]]
name = "steering_lag"
tau = 0.05

[noise]
v_x = 0.005
v_y = 0.002
yaw_rate = 0.005
e_psi = 0.002
e_y = 0.002
s = 0.002
"""
FAST = {"dictionary_size": 200, "max_fit_points": 60}


def export_global(run, track, path: Path, shift=(0.0, 0.0)) -> Path:
    """The run in the global frame, as a logger would write it (independent of gprace's importer)."""
    smp = track.sample(0.05)
    sw = np.mod(run["s"], track.length)
    xs, ys = np.append(smp.x, smp.x[0]), np.append(smp.y, smp.y[0])
    sp = np.append(smp.s, track.length)
    cx, cy = np.interp(sw, sp, xs), np.interp(sw, sp, ys)
    h = np.interp(sw, sp, np.append(smp.heading, smp.heading[0] + 2 * np.pi))
    x = cx - np.sin(h) * run["e_y"] + shift[0]
    y = cy + np.cos(h) * run["e_y"] + shift[1]
    yaw = np.angle(np.exp(1j * (h + run["e_psi"])))
    cols = {"t": run["t"], "x": x, "y": y, "yaw": yaw, **{k: run[k] for k in ("v_x", "v_y", "yaw_rate", "delta", "a_x")}}
    np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="", fmt="%.9g")
    return path


@pytest.fixture(scope="module")
def looped(tmp_path_factory):
    from gprace.config import load_plant, load_vehicle
    from gprace.learn.workflow import LearnSettings, learn
    from gprace.model import NominalModel
    from gprace.plan import curvature_plan
    from gprace.timetrial.drive import drive
    from gprace.tracks import load_track

    d = tmp_path_factory.mktemp("learn")
    (d / "plant.toml").write_text(PLANT)
    track = load_track("h2h_loop")
    model = NominalModel(load_vehicle("barc_1_10"))
    plan0 = curvature_plan(track, model, ds=0.15, speed_scale=0.7, a_lat=4.0)
    run = drive(plan0, load_plant(d / "plant.toml"), track, model, seed=1)
    assert run.meta["completed"]
    log = export_global(run, track, d / "lap0.csv")
    st = LearnSettings(track="h2h_loop", vehicle="barc_1_10", alpha=0.5, **FAST)
    rec = learn([log], st, d / "out")
    return {"dir": d, "out": d / "out", "rec": rec, "run": run, "track": track, "model": model, "log": log, "settings": st}


def test_learn_writes_the_next_iteration(looped):
    from gprace.tracks.raceline import raceline_summary, read_raceline

    rec, it = looped["rec"], looped["out"] / "iter_01"
    assert rec["iteration"] == 1 and rec["recordings"][0]["laps"] and rec["completed"]
    assert rec["recordings"][0]["sha256"] and rec["vehicle"]["name"] == "barc_1_10"
    # the plan is faster than the lap it learned from and inside the measured limits (the first
    # iteration does not widen them: it does not know what the car's own plan asked for)
    assert rec["plan"]["planned_lap_time"] < rec["recordings"][0]["best_lap"]
    np.testing.assert_allclose(rec["limits"], np.minimum(np.array(rec["grip"]["measured"]), rec["grip"]["cap"]), rtol=1e-9)
    for name in ("raceline_tum.csv", "raceline_f1tenth.csv"):
        info = raceline_summary(read_raceline(it / name), looped["track"], 0.5 * looped["model"].vehicle.width)
        assert info["inside"] and info["lap_time_s"] == pytest.approx(rec["plan"]["planned_lap_time"], rel=0.03)
    assert rec["prediction"]["grip_places"] and rec["prediction"]["band_max_m"] > 0
    ref = np.genfromtxt(it / "explore_reference.csv", delimiter=",", names=True)
    assert ref["explore"].sum() > 0 and set(rec["exports"]) >= {"candidates.h5", "explore_reference.csv"}


def test_the_portable_gp_of_an_iteration_is_the_iteration_s_gp(looped):
    from gprace.gp.export import PortableGP
    from gprace.io.artifacts import read_artifact
    from gprace.timetrial.learning import load_predictor

    it = looped["out"] / "iter_01"
    gp = load_predictor(it / "gp_tracking.h5", "tracking")
    Z = read_artifact(it / "data_tracking.h5", "dataset").arrays["Z_new"][::7]
    mean, latent, _ = PortableGP.load(it / "gp_tracking.portable.h5").predict(Z)
    m, v = gp(Z)
    np.testing.assert_allclose(mean, m, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(latent, v, rtol=1e-6, atol=1e-14)
    card = json.loads((it / "gp_tracking.card.json").read_text())
    assert card["controller_step"]["dt_s"] == 0.05 and card["vehicle"]["name"] == "barc_1_10"


def test_a_rerun_resumes_and_the_next_recording_is_the_next_iteration(looped, tmp_path):
    from gprace.learn.workflow import learn

    it = looped["out"] / "iter_01"
    before = (it / "plan.h5").stat().st_mtime_ns
    again = learn([looped["log"]], looped["settings"], looped["out"])
    assert again["already_done"] and (it / "plan.h5").stat().st_mtime_ns == before
    # killed after the plan: the export and prediction are redone, the plan is not
    for stage in ("export", "predict"):
        (looped["out"] / ".steps" / f"iter_01.{stage}.done").unlink()
    (it / "record.json").unlink()
    (it / "raceline_tum.csv").unlink()
    again = learn([looped["log"]], looped["settings"], looped["out"])
    assert not again["already_done"] and (it / "raceline_tum.csv").exists()
    assert (it / "plan.h5").stat().st_mtime_ns == before


def _errors(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error:")]


def test_bad_input_is_one_line_and_exit_2(looped, tmp_path, capsys):
    from gprace.cli import main

    # another car's folder
    assert main(["learn", str(looped["log"]), "--track", "h2h_loop", "--vehicle", "audi_tt_cup", "--out",
                 str(looped["out"])]) == 2
    err = _errors(capsys)
    assert len(err) == 1 and "iterations of car 'barc_1_10'" in err[0]
    # recordings of different tracks: the same lap moved 200 m away is another circuit
    far = export_global(looped["run"], looped["track"], tmp_path / "far.csv", shift=(200.0, 0.0))
    assert main(["learn", str(looped["log"]), str(far), "--track", "h2h_loop", "--vehicle", "barc_1_10",
                 "--out", str(tmp_path / "o")]) == 2
    err = _errors(capsys)
    assert len(err) == 1 and "recordings of different tracks" in err[0]
    # a gprace run of another track
    from gprace.io.runs import write_run

    write_run(looped["run"], tmp_path / "run.h5")
    assert main(["learn", str(tmp_path / "run.h5"), "--track", "circle_100", "--vehicle", "barc_1_10",
                 "--out", str(tmp_path / "o2")]) == 2
    err = _errors(capsys)
    assert len(err) == 1 and "recordings of different tracks" in err[0]


def test_eval_learn_finds_where_the_lap_left_the_band(looped, tmp_path, capsys):
    """A lap that follows the prediction exactly but for a 2 m stretch 4 bands off the line: eval
    learn reports that stretch (and only it) and the lap time error."""
    from gprace.cli import main
    from gprace.io.runs import Run, write_run
    from gprace.learn.predict import Prediction
    from gprace.learn.workflow import evaluate_learn

    it = looped["out"] / "iter_01"
    pred = Prediction.read(it / "prediction.h5")
    track = looped["track"]
    L, dt = track.length, 0.05
    sp = np.append(pred.s, L)
    v = np.append(pred.speed, pred.speed[0])
    # the predicted lap in time: s(t) from the speed along the line, ds/dt = v / (1 - kappa e_y)
    s_fine = np.linspace(0, 2.2 * L, 40000)
    sf = np.mod(s_fine[:-1], L)
    ef = np.interp(sf, sp, np.append(pred.e_y, pred.e_y[0]))
    tt = np.concatenate([[0.0], np.cumsum(np.diff(s_fine) * (1 - track.kappa(sf) * ef) / np.interp(sf, sp, v))])
    t = np.arange(0.0, tt[-1], dt)
    s = np.interp(t, tt, s_fine)
    sw = np.mod(s, L)
    e = np.interp(sw, sp, np.append(pred.e_y, pred.e_y[0]))
    band = np.interp(sw, sp, np.append(pred.band, pred.band[0]))
    bump = (sw > 10.0) & (sw < 12.0) & (s < L)
    e = e + np.where(bump, 4 * band, 0.0)
    n = len(t)
    run = Run({"t": t, "s": sw, "e_y": e, "e_psi": np.zeros(n), "v_x": np.interp(sw, sp, v), "v_y": np.zeros(n),
               "yaw_rate": np.zeros(n), "delta": np.zeros(n), "a_x": np.zeros(n), "kappa": track.kappa(sw),
               "lap": np.floor(s / L)}, {"dt": dt, "track": "h2h_loop", "track_length": L})
    write_run(run, tmp_path / "next.h5")
    res = evaluate_learn(looped["out"], tmp_path / "next.h5")
    lap = res["laps"][0]
    assert lap["time_s"] == pytest.approx(np.interp(L, s_fine, tt), abs=1.01 * dt)
    assert lap["time_error_s"] == pytest.approx(lap["time_s"] - pred.lap_time)
    assert len(lap["left_band"]) == 1
    b = lap["left_band"][0]
    assert 9.9 < b["s_start"] < 10.3 and 11.7 < b["s_end"] < 12.1
    assert b["deviation_m"] == pytest.approx(4 * b["band_m"], rel=0.05)
    capsys.readouterr()
    assert main(["eval", "learn", str(looped["out"]), str(tmp_path / "next.h5")]) == 0
    assert "left the band at s 10." in capsys.readouterr().out


def _pb_fields(buf: bytes) -> dict:
    """Protobuf wire format of one message: {field number: [values]} (varint, fixed64, bytes)."""
    out, i = {}, 0
    while i < len(buf):
        key, i = _varint(buf, i)
        f, wt = key >> 3, key & 7
        if wt == 0:
            val, i = _varint(buf, i)
        elif wt == 1:
            val, i = struct.unpack_from("<d", buf, i)[0], i + 8
        elif wt == 2:
            ln, i = _varint(buf, i)
            val, i = buf[i:i + ln], i + ln
        elif wt == 5:
            val, i = struct.unpack_from("<f", buf, i)[0], i + 4
        else:
            raise ValueError(wt)
        out.setdefault(f, []).append(val)
    return out


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift = val = 0
    while True:
        b = buf[i]
        i += 1
        val |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return val, i


def test_mcap_reads_back_with_its_channels_and_schemas(looped, tmp_path):
    """The MCAP of an iteration, read by the ``mcap`` reader: Foxglove's schemas on the geometry
    topics, the recorded poses at the recording's own positions and times, the plan along s."""
    from mcap.reader import make_reader

    from gprace.io.runs import read_run
    from gprace.learn.workflow import write_mcap

    path = write_mcap(looped["out"], 1, tmp_path / "it.mcap")
    rec = read_run(looped["out"] / "iter_01" / "rec_0.h5")
    with path.open("rb") as f:
        reader = make_reader(f)
        summ = reader.get_summary()
        topics = {c.topic: summ.schemas[c.schema_id].name for c in summ.channels.values()}
        assert topics["/track"] == "foxglove.SceneUpdate"
        assert topics["/plan/iteration_1/path"] == "foxglove.PosesInFrame"
        assert topics["/run/recording_0/pose"] == "foxglove.PoseInFrame"
        assert topics["/run/recording_0/state"] == "gprace.RunState" and topics["/log"] == "foxglove.Log"
        poses, states = [], []
        for schema, channel, msg in reader.iter_messages(topics=["/run/recording_0/pose", "/run/recording_0/state"]):
            (poses if channel.topic.endswith("pose") else states).append((msg.log_time, msg.data))
    assert len(poses) == len(states) == rec.n
    k = rec.n // 2
    pose = _pb_fields(_pb_fields(poses[k][1])[3][0])  # PoseInFrame.pose
    pos = _pb_fields(pose[1][0])  # Pose.position: x = 1, y = 2
    assert pos[1][0] == pytest.approx(rec["x"][k], abs=1e-9) and pos[2][0] == pytest.approx(rec["y"][k], abs=1e-9)
    assert poses[k][0] == int(rec["t"][k] * 1e9)
    st = json.loads(states[k][1])
    assert st["v_x"] == pytest.approx(rec["v_x"][k]) and st["s"] == pytest.approx(rec["s"][k])


def test_run_mcap_shows_the_plan_with_the_gp_band_and_the_lap(looped, tmp_path):
    """``run --mcap`` with the iteration's tracking GP: the band along the plan is learn's prediction
    of the same plan (same GP, step and horizon), and the car's poses are where its Frenet states
    put it (converted by this test's own global-frame export)."""
    from mcap.reader import make_reader

    from gprace.cli import main
    from gprace.io.runs import read_run
    from gprace.learn.predict import Prediction

    it, mc = looped["out"] / "iter_01", tmp_path / "r.mcap"
    assert main(["run", "--plan", str(it / "plan.h5"), "--track", "h2h_loop", "--plant", str(looped["dir"] / "plant.toml"),
                 "--vehicle", "barc_1_10", "--model", str(it / "gp_tracking.h5"), "--laps", "0.3",
                 "-o", str(tmp_path / "r.h5"), "--mcap", str(mc)]) == 0
    run = read_run(tmp_path / "r.h5")
    with mc.open("rb") as f:
        reader = make_reader(f)
        summ = reader.get_summary()
        topics = {c.topic: summ.schemas[c.schema_id].name for c in summ.channels.values()}
        assert topics["/track"] == topics["/plan/plan"] == "foxglove.SceneUpdate"
        assert topics["/plan/plan/path"] == "foxglove.PosesInFrame" and topics["/run/run/pose"] == "foxglove.PoseInFrame"
        assert topics["/plan/plan/along"] == "gprace.PlanAlong" and topics["/run/run/state"] == "gprace.RunState"
        along, poses = [], []
        for _, channel, msg in reader.iter_messages(topics=["/plan/plan/along", "/run/run/pose"]):
            if channel.topic.endswith("along"):
                along.append((msg.log_time, json.loads(msg.data)))
            else:
                poses.append(msg.data)
    pred = Prediction.read(it / "prediction.h5")
    band = np.array([a["band"] for _, a in sorted(along, key=lambda x: x[0])])
    np.testing.assert_allclose(band, pred.band, rtol=1e-6, atol=1e-9)
    assert {"sigma_vy", "sigma_r", "use", "speed"} <= set(along[0][1])
    assert len(poses) == run.n
    g = np.genfromtxt(export_global(run, looped["track"], tmp_path / "g.csv"), delimiter=",", names=True)
    for k in (0, run.n // 3, run.n - 1):
        pos = _pb_fields(_pb_fields(_pb_fields(poses[k])[3][0])[1][0])  # PoseInFrame.pose.position
        assert pos[1][0] == pytest.approx(g["x"][k], abs=5e-3) and pos[2][0] == pytest.approx(g["y"][k], abs=5e-3)


@pytest.mark.parametrize("laps, now, never_worse, good", [
    (((True, 60.0), (True, 59.0)), (True, 58.0), True, 3),  # every plan completed, each faster: the last
    (((True, 60.0), (False, None)), (True, 58.0), True, 3),  # plan 2 lost its lap, plan 3 completed
    (((True, 60.0), (True, 59.0)), (False, None), True, 0),  # plan 3 lost now, plans 1, 2 not below its level
    (((True, 60.0), (True, 59.0)), (False, None), False, 2),  # without the guard: the last completed
    (((False, None), (False, None)), (False, None), True, 0),  # only lost GP laps: the car's own plan
    (((True, 60.0), (True, 59.0)), (True, 61.0), True, 2),  # plan 3 slower (guard): back to plan 2
    (((True, 60.0), (True, 59.0)), (True, 61.0), False, 3),  # without the guard: the last completed
])
def test_the_plan_after_a_lost_lap_is_never_the_lost_plan(tmp_path, laps, now, never_worse, good):
    """Iteration 4's warm start and fallback, by iterate's rules: lap j is plan j driven in the
    recordings of iteration j + 1 (lap 0: the car's own plan, ``--driven``); the last good lap
    whose limits stay clear of the lost laps' (with the guard), else the last completed one."""
    from gprace.learn.workflow import Folder, lap_records, start_lap, write_json

    folder = Folder(tmp_path)
    lim = [[10.0, 5.0, 9.0], [11.0, 5.0, 10.0], [12.0, 5.0, 11.0], [11.3, 5.0, 10.4]]  # 3 clear of 2

    def facts(done, t):
        return [{"completed": done, "laps": [t] if done else [], "envelope": [10.0, 5.0, 9.0]}]

    for j, (done, t) in zip((1, 2, 3), ((True, 62.0), *laps)):
        folder.it(j).mkdir()
        write_json(folder.it(j) / "record.json", {"recordings": facts(done, t), "limits": lim[j],
                                                  "settings": {"alpha": None},
                                                  **({"driven": {"limits": lim[0]}} if j == 1 else {})})

    class C:
        k = 4
        st = type("S", (), {"slower_tolerance": 0.005})

    C.folder = folder
    recs = lap_records(C, facts(*now))
    assert [r["limits"] for r in recs] == lim
    assert [r["completed"] for r in recs] == [True, laps[0][0], laps[1][0], now[0]]
    assert start_lap(recs, never_worse, 0.05) == good
    assert good is None or recs[good]["completed"]


def test_learn_refuses_a_frenet_csv_of_another_track_in_one_line(tmp_path, capsys):
    """A gprace run saved as CSV names no track: its recorded curvature along s tells (issue 39)."""
    from gprace.cli import main

    ring = tmp_path / "ring.csv"
    assert main(["-q", "simulate", "--track", "gprace_ring", "--laps", "0.3", "-o", str(ring)]) == 0
    capsys.readouterr()
    out = tmp_path / "lo"
    assert main(["learn", str(ring), "--track", "circle_100", "--vehicle", "audi_tt_cup", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different tracks" in err[0] and "curvature" in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("driven, util, completed", [
    (None, 0.2, True),  # the car's own plan unknown: its measured envelope, not widened
    ([10.4, 6.0, 9.8], 0.2, True),  # known: widened from it by widen_max (little slip used), as iterate
    ([10.4, 6.0, 9.8], 0.6, True),  # more slip used: a smaller step (gprace.timetrial.grip.widening)
    ([10.4, 6.0, 9.8], 0.2, False),  # the lap was lost: narrowed below the plan's limits
])
def test_first_limits_follow_iterates_rule_from_the_driven_plan(tmp_path, audi, driven, util, completed):
    """learn's first limits are iterate's (``next_limits`` from the limits of the plan the car
    drove, ``--driven``), with the widening that depends on the rear-slip use."""
    from types import SimpleNamespace

    from gprace.learn.workflow import Folder, LearnSettings, next_plan_limits
    from gprace.model import NominalModel
    from gprace.timetrial import grip as G

    measured = [12.03, 6.0, 9.94]
    facts = [{"envelope": measured, "utilisation": util, "completed": completed, "border_hits": 0,
              "laps": [62.4] if completed else []}]
    st = LearnSettings(track="circle_100", vehicle="audi_tt_cup")
    model = NominalModel(audi)
    c = SimpleNamespace(st=st, k=1, folder=Folder(tmp_path), model=model, runs=lambda: [],
                        driven_info={"limits": driven} if driven else None)
    lim = next_plan_limits(c, facts)
    cap = G.nominal_cap(model, st.plan_grip)
    if driven is None:
        expect = np.minimum(measured, cap)
    else:
        shape = model.params.cr
        expect = G.next_limits(driven, measured, completed, util, cap, 0.05, widen_max=0.15, shape=shape)
        step = G.widening(util, 0.05, 0.15, shape=shape)
        if completed:  # the plan's own limits (below what was measured) widened by the step
            np.testing.assert_allclose(expect, np.minimum(np.minimum(measured, driven) * (1 + step), cap))
            linear = 0.15 if util <= 0.3 else 0.05 + 0.1 * (0.8 - util) / 0.5
            assert step == pytest.approx(min(linear, G.force_headroom(util, shape)))
        else:
            np.testing.assert_allclose(expect, np.minimum(np.array(driven) * 0.9, cap))
    np.testing.assert_allclose(lim["limits"], expect, rtol=1e-12)
    assert lim["previous_known"] == (driven is not None)
