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
