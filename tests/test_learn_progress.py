"""Progress an engineer can plan by, and the MCAP of an iterate folder (issue 39).

``iterate``'s bar counts laps (reference runs, every trial's iterations, the oracle lap) from the
steps' markers, so it moves while trials run in other processes; ``learn``'s bar names its stages.
No timing is asserted: the counts, the ETA's arithmetic, and what a bar shows on a terminal.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from gprace.console import Console, eta_seconds


def _terminal(monkeypatch) -> Console:
    """A console whose stderr is a terminal, written to a buffer."""
    from rich.console import Console as RichConsole

    c = Console()
    c.err = RichConsole(file=io.StringIO(), force_terminal=True, width=150, highlight=False)
    monkeypatch.setattr("sys.stderr.isatty", lambda: True, raising=False)
    return c


def test_eta_is_the_rate_of_this_session():
    # 3 laps done in 600 s since the bar started (work done before a resume does not count): 7 left
    assert eta_seconds(3, 7, 600.0) == pytest.approx(1400.0)
    assert eta_seconds(0, 7, 600.0) is None and eta_seconds(2, None, 10.0) is None


def test_polled_bar_counts_what_the_function_says_and_an_inner_bar_does_not_replace_it(monkeypatch):
    c = _terminal(monkeypatch)
    done = [2]  # two laps were done before (a resumed experiment)
    with c.polled("iterate: 10 laps", 10, lambda: done[0], unit="laps", interval=0.01) as bar:
        assert bar.live
        task = bar._p.tasks[0]
        assert task.completed == 2 and task.fields["base"] == 2
        with c.progress("iterate: 1 trial(s)", 1) as inner:  # the batch's bar inside
            assert not inner.live
            inner.advance()
        done[0] = 7
    assert task.completed == 7  # read once more at the end
    text = c.err.file.getvalue()
    assert "7/10 laps" in text and "ETA" in text and "iterate: 1 trial(s)" in text


def test_learn_bar_names_its_stages(monkeypatch, tmp_path):
    """The stage callback of ``learn``: each finished stage moves the bar one step and names the next."""
    import contextlib

    from gprace.cli import learn as commands
    from gprace.learn.workflow import STAGES

    shown = []

    class Bar:
        def update(self, completed=None, description=None):
            shown.append((completed, description))

    @contextlib.contextmanager
    def progress(description, total=None, completed=0, unit=""):
        shown.append((completed, description))
        yield Bar()

    def fake_learn(paths, st, out, progress=None, checked=None):
        for s in STAGES:
            progress(s)
        raise SystemExit(0)

    monkeypatch.setattr("gprace.console.console.progress", progress)
    monkeypatch.setattr("gprace.learn.workflow.learn", fake_learn)
    monkeypatch.setattr("gprace.learn.workflow.check_inputs", lambda *a: None)  # checked before the bar: tested apart
    with pytest.raises(SystemExit):
        commands.learn_cmd([tmp_path / "x.csv"], "h2h_loop", "barc_1_10", tmp_path / "o", None, None, 0.05, 100, "full",
                           "diverse", 0, None, False, None, 0.05, 0.15, True)
    assert shown[1] == (None, "learn: importing the recordings")
    del shown[1]
    assert [n for n, _ in shown] == list(range(len(STAGES) + 1))
    assert shown[1][1] == "learn: selecting the GPs' data" and shown[3][1] == "learn: re-planning the lap (IPOPT)"
    assert shown[-1][1] == "learn: done"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A tiny iterate (1 trial, iterations 0..2, no oracle), with the lap count seen after every step marker."""
    pytest.importorskip("gprace.gp")
    from gprace.timetrial.iterate import IterateSettings, Steps, iterate, lap_markers

    st = IterateSettings(alphas=(0.5, 0.0), iterations=2, trials=1, track="circle_100", plant="audi_nominal",
                         dictionary_size=150, max_fit_points=80, plan_ds=8.0, heldout_laps=0.3, grid_values=4, oracle=False)
    out = tmp_path_factory.mktemp("iterate") / "exp"
    laps = lap_markers(st, out)
    seen = []
    mark = Steps.mark

    def counting(self, name):
        mark(self, name)
        seen.append((name, sum(p.exists() for p in laps)))

    mp = pytest.MonkeyPatch()
    mp.setattr(Steps, "mark", counting)
    try:
        summary = iterate(st, out)
    finally:
        mp.undo()
    return {"settings": st, "out": out, "laps": laps, "seen": seen, "summary": summary}


def test_iterate_counts_laps_not_trials(tiny):
    """Reference runs (held-out, calibration), iterations 0, 1, 2 of the trial and the oracle step:
    6 laps; the count moves by one exactly when a lap is driven, never on select, retrain or plan."""
    laps, seen = tiny["laps"], tiny["seen"]
    assert len(laps) == 2 + 3 + 1 and all(p.exists() for p in laps)
    before = 0
    for name, n in seen:
        lap = name in ("heldout", "calib", "oracle") or name.endswith("_drive")
        assert n == before + (1 if lap else 0), (name, n, before)
        before = n
    assert before == len(laps)
    # a rerun of a finished experiment starts its bar full (ETA base = everything)
    assert sum(p.exists() for p in laps) == len(laps)


def test_iterate_mcap_has_every_lap_and_the_band_where_a_gp_drove(tiny, tmp_path):
    from mcap.reader import make_reader

    from gprace.report.mcap import write_iterate
    from gprace.io.runs import read_run

    path = write_iterate(tiny["out"], tmp_path / "it.mcap")
    with path.open("rb") as f:
        reader = make_reader(f)
        summ = reader.get_summary()
        topics = {c.topic: summ.schemas[c.schema_id].name for c in summ.channels.values()}
        counts = {summ.channels[k].topic: v for k, v in summ.statistics.channel_message_counts.items()}
        along = {}
        for _, channel, msg in reader.iter_messages(topics=[f"/plan/trial_0/iter_0{i}/along" for i in range(3)]):
            along.setdefault(channel.topic, []).append(json.loads(msg.data))
    assert topics["/track"] == "foxglove.SceneUpdate" and topics["/log"] == "foxglove.Log"
    for i in range(3):
        name = f"trial_0/iter_0{i}"
        assert topics[f"/plan/{name}/path"] == "foxglove.PosesInFrame"
        assert counts[f"/run/{name}/pose"] == read_run(tiny["out"] / name / "run.h5").n
        rows = along[f"/plan/{name}/along"]
        # iteration 0 is driven without a GP: no band; from iteration 1 on the tracking GP's band
        assert ("band" in rows[0]) == (i > 0)
        if i:
            band = np.array([r["band"] for r in rows])
            assert np.all(np.isfinite(band)) and np.all(band > 0)
