"""Issue 36, stop 44: the naming round's choice among significant candidates, and the physical
bounds of effect parameters (friction factors inside what mu can be)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gprace.config import EffectConfig, load_vehicle
from gprace.diagnose import core, name as nm
from gprace.diagnose.diagnose import Ctx, _pick
from gprace.diagnose.synth import record

TRACKS = Path("/work/shared/data/tumftm-racetrack-database/tracks")


def _ctx(m: int, per_block: int = 5) -> Ctx:
    """What the significance test reads of a context: block ids of the windows, no subsets."""
    return Ctx(prob=None, fit_w=np.arange(m), screen_w=np.arange(m), eval_w=np.arange(m), fold=np.arange(m) % 4,
               bid=np.arange(m) // per_block, fit_stride=1, subsets=(), t_subset=4.0)


def test_a_significant_candidate_is_chosen_over_a_larger_but_noisy_one():
    """Round losses as on the IAC log: v_x far above its floor (a measured a_x), so the total loss
    is v_x's. A grade acting on v_x lowers the total most, but by noise (block t about 1); a
    velocity misalignment lowers v_y in every block. The round names the misalignment (the old
    rule took the lowest total loss, found it not significant and stopped); with the grade's
    gain made consistent, the grade is chosen (the best by loss among the significant)."""
    rng = np.random.default_rng(1)
    m = 800
    l0 = np.column_stack([20.0 + rng.gamma(2.0, 1.0, m), 3.0 + 0.3 * rng.standard_normal(m), np.ones(m)])
    grade, mis = l0.copy(), l0.copy()
    grade[:, 0] -= 1.5 + 40.0 * rng.standard_normal(m)  # large mean gain, no consistency
    mis[:, 1] -= 1.0 + 0.3 * rng.standard_normal(m)  # smaller, consistent
    top = [nm.Fit("road_grade", ["angle"], np.array([0.01]), {}), nm.Fit("velocity_misalignment", ["angle"],
                                                                           np.array([0.008]), {})]
    cv = {"road_grade": grade, "velocity_misalignment": mis}
    assert cv["road_grade"].mean() < cv["velocity_misalignment"].mean()  # the old rule's choice
    ctx = _ctx(m)
    best = _pick(ctx, l0, cv, top, 0, lambda s: None)
    assert best is not None and best.name == "velocity_misalignment"
    cv["road_grade"] = l0 - np.array([4.0, 0.0, 0.0]) - 0.1 * np.abs(rng.standard_normal((m, 1))) * [1, 0, 0]
    assert _pick(ctx, l0, cv, top, 0, lambda s: None).name == "road_grade"
    cv["road_grade"], cv["velocity_misalignment"] = l0 + 0.0, l0 + 0.0
    assert _pick(ctx, l0, cv, top, 0, lambda s: None) is None  # nothing gains: the round stops


def test_physical_bounds_of_effect_parameters():
    """A friction factor keeps mu x factor among the tire-road ratios that exist; a downforce's
    load at the top speed stays within -0.5..4 weights; a CoG height below l_r; others keep the
    catalogue's bounds."""
    audi = load_vehicle("audi_tt_cup")
    slick = audi.model_copy(update={"mu": 1.5})
    assert nm.physical_bounds("tire_friction", "rear", slick, None) == pytest.approx((0.2, 2.0))
    assert nm.physical_bounds("friction_profile", "values", slick.model_copy(update={"mu": 2.5}), None)[1] \
        == pytest.approx(1.2)
    assert nm.physical_bounds("friction_patch", "factor", slick.model_copy(update={"mu": 0.3}), None)[0] \
        == pytest.approx(0.05 / 0.3)
    assert nm.physical_bounds("tire_friction", "rear", None, None) == (0.2, 3.0)  # no vehicle: the catalogue's
    assert nm.physical_bounds("load_transfer", "cog_height", audi, None) == (0.0, audi.l_r)
    assert nm.physical_bounds("steering_lag", "tau", audi, None) == (1e-3, 1.0)
    assert nm.at_bound("tire_friction", "rear", 2.0, slick, None) and not nm.at_bound("tire_friction", "rear", 1.2, slick, None)


@pytest.mark.skipif(not TRACKS.exists(), reason="TUM racetrack database not available")
def test_a_friction_factor_cannot_leave_its_physical_bound(monkeypatch):
    """A recording whose front axle has 0.7 of the nominal grip: the fit recovers about 0.7 with
    the usual bounds; with the tire-road ratios that exist starting at 0.85 mu (patched), the
    factor stops at 0.85 and is flagged at its bound (the fit never leaves physics)."""
    import gprace.config as config
    from gprace.tracks.loaders import load_track

    audi = load_vehicle("audi_tt_cup")
    track = load_track(TRACKS / "Norisring.csv")
    r = record(audi, track, [EffectConfig(name="tire_friction", params={"front": 0.7, "rear": 1.0})],
               laps=1.0, seed=5, speed_scale=0.8, substeps=5)
    data = core.build_dataset([r])
    starts = data.windows(15)[::3]
    prob = nm.Problem(audi, data, 15, np.array([0.05, 0.05, 0.01]))
    init = [{"front": 1.0, "rear": 1.0}]
    free = nm.fit_effect(prob, "tire_friction", starts, init, max_nfev=30)
    assert abs(free.values()["front"] - 0.7) < 0.08, free.values()
    monkeypatch.setattr(config, "MU_POSSIBLE", (0.85 * audi.mu, 3.0))
    lo, hi = nm.physical_bounds("tire_friction", "front", audi, data)
    assert lo == pytest.approx(0.85)
    held = nm.fit_effect(prob, "tire_friction", starts, init, max_nfev=30)
    front = held.values()["front"]
    assert lo - 1e-9 <= front < lo + 0.01 and nm.at_bound("tire_friction", "front", front, audi, data)
    assert held.cost > free.cost  # the bound costs fit: the data wanted less grip


def test_at_bound_is_in_the_json_only_when_true():
    """A parameter at its physical bound says so; one inside keeps the JSON it had before the flag."""
    from gprace.diagnose.result import Parameter

    assert Parameter(value=2.0, ci95=[1.8, 2.0], at_bound=True).model_dump()["at_bound"] is True
    assert "at_bound" not in Parameter(value=1.2, ci95=[1.0, 1.4]).model_dump()
