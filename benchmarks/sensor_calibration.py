"""The sensor calibration of ``gprace iterate`` (:mod:`gprace.mpc.sensors`) on cars it has never met.

Two questions, each over a family, on the calibration run ``iterate`` drives before the first lap
(the reference controller weaving at 0.9 of its profile, :mod:`gprace.timetrial.iterate.data`), or the
held-out run where that one stays longer in control (the runs ``iterate`` reads them from):

- **false alarms**: on the cars of ``benchmarks/timetrial_unseen.py`` (randomized plants 1..N,
  commonroad_std, commonroad_mb, audi_hidden), whose sensors read true, the yaw-rate bias and the
  velocity frame's angle must stay inside the dead bands, so the laps are driven exactly as without
  the calibration. Prints the raw readings and the largest of each;
- **recovery**: frenet stand-ins of the issue-37 distribution (``timetrial_unseen.standin``) given a
  gyro bias drawn from [-0.05, 0.05] rad/s and a velocity frame turned by [-0.03, 0.03] rad, on
  circuits drawn from gprace_ring and the TUM database: the readings against the hidden values.

Usage: ``nice python benchmarks/sensor_calibration.py [--plants N] [--cars M] [--seeds 0,1] [--workers W]``.
Prints one JSON object (rows and a summary). About 5 s of CPU per reference run.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
TUM = HERE.parents[1] / "shared" / "data" / "tumftm-racetrack-database" / "tracks"
CIRCUITS = ("gprace_ring", "Monza", "Spielberg", "Suzuka", "Zandvoort", "BrandsHatch", "Norisring", "Sakhir")


def _track(name: str) -> str:
    return name if name == "gprace_ring" else str(TUM / f"{name}.csv")


def read_car(task: dict) -> dict:
    """One car: its calibration run driven as ``iterate`` drives it, and the sensors read from it."""
    import tomli_w

    from gprace.config import load_plant
    from gprace.mpc.sensors import DEAD_BAND, dead_banded, read
    from gprace.io.runs import read_run
    from gprace.timetrial.iterate.chain import _sensor_run
    from gprace.timetrial.iterate.data import _reference_run
    from gprace.timetrial.iterate.settings import IterateSettings
    from gprace.timetrial.learning import in_control
    from gprace.tracks import load_track

    with tempfile.TemporaryDirectory(prefix="gprace_sensors_") as tmp:
        out = Path(tmp)
        plant = task["plant"]
        if isinstance(plant, dict):
            (out / "plant.toml").write_text(tomli_w.dumps(plant))
            plant = str(out / "plant.toml")
        st = IterateSettings(plant=plant, vehicle=task["vehicle"], track=_track(task["track"]), seed=task["seed"])
        load_plant(st.plant)
        runs = {}
        for name in ("calib", "heldout"):
            _reference_run(st, out, name)
            runs[name] = read_run(out / f"{name}.h5")
    track = load_track(st.track)
    run = _sensor_run(runs)
    X = run.states()
    raw = read(X, run["t"], in_control(X), track)
    used = dead_banded(raw)
    row = {"name": task["name"], "track": task["track"], "seed": task["seed"], "read_from": next(k for k in runs if runs[k] is run),
           "samples": int(run.n),
           "completed": bool(run.meta.get("completed")), **{f"read_{k}": v for k, v in raw.items()},
           "corrected": not used.identity, **used.as_dict()}
    for k in DEAD_BAND:
        if k in task:
            row[f"true_{k}"] = task[k]
    return row


def tasks(plants: int, cars: int, seeds: list[int]) -> list[dict]:
    sys.path.insert(0, str(HERE))
    from timetrial_unseen import VEHICLES, randomized, standin

    out = []
    for seed in seeds:
        for k in range(1, plants + 1):
            out.append({"name": f"randomized_{k:02d}", "plant": randomized(k), "vehicle": VEHICLES[k % 2],
                        "track": "gprace_ring", "seed": seed})
        for name, vehicle in (("bmw_commonroad", "bmw_320i"), ("bmw_commonroad_mb", "bmw_320i"),
                              ("audi_hidden", "audi_tt_cup")):
            out.append({"name": name, "plant": name, "vehicle": vehicle, "track": "gprace_ring", "seed": seed})
    rng = np.random.default_rng(2026)
    for k in range(1, cars + 1):
        data = standin(100 + k)
        bias, angle = float(rng.uniform(-0.05, 0.05)), float(rng.uniform(-0.03, 0.03))
        data["effects"] += [{"name": "gyro_bias", "bias": bias}, {"name": "velocity_misalignment", "angle": angle}]
        out.append({"name": f"biased_{k:02d}", "plant": data, "vehicle": data["vehicle"],
                    "track": CIRCUITS[int(rng.integers(len(CIRCUITS)))], "seed": 0,
                    "yaw_rate_bias": bias, "velocity_angle": angle})
    return out


def summary(rows: list[dict]) -> dict:
    from gprace.mpc.sensors import DEAD_BAND

    clean = [r for r in rows if not r["name"].startswith("biased")]
    biased = [r for r in rows if r["name"].startswith("biased")]
    out: dict = {"clean_cars": len(clean), "false_alarms": sum(r["corrected"] for r in clean),
                 "too_short": sum(not np.isfinite(r["read_yaw_rate_bias"]) for r in rows),
                 "read_from_heldout": sum(r["read_from"] == "heldout" for r in rows)}
    for k in DEAD_BAND:
        vals = [abs(r[f"read_{k}"]) for r in clean if np.isfinite(r[f"read_{k}"])]
        out[f"clean_max_abs_{k}"] = max(vals, default=float("nan"))
        err = [abs(r[k] - r[f"true_{k}"]) for r in biased]
        out[f"biased_max_error_{k}"] = max(err, default=float("nan"))
        out[f"biased_median_error_{k}"] = float(np.median(err)) if err else float("nan")
    out["biased_cars"] = len(biased)
    out["biased_not_corrected"] = [r["name"] for r in biased if not r["corrected"]]
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", type=int, default=20, help="randomized plants of the false-alarm set")
    ap.add_argument("--cars", type=int, default=20, help="stand-ins with hidden sensor errors")
    ap.add_argument("--seeds", default="0,1", help="noise seeds of the false-alarm set")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    from gprace.executor import run_batch

    todo = tasks(a.plants, a.cars, [int(s) for s in a.seeds.split(",")])
    done = run_batch(read_car, todo, workers=a.workers, label="sensor calibration runs")
    rows = [r.value for r in done if r.ok]
    failed = [{"task": t["name"], "error": r.error.splitlines()[0]} for t, r in zip(todo, done) if not r.ok]
    json.dump({"rows": rows, "failed": failed, "summary": summary(rows)}, sys.stdout, indent=1, default=float)
    print()


if __name__ == "__main__":
    main()
