"""Re-drives of a time-trial benchmark's laps on new noise draws (issue 37): how likely each lap is
to lose the car.

``benchmarks/timetrial_unseen.py`` drives every lap once. A lap at the edge is lost on some noise
draws and not on others, so its lost-lap count is one draw of a handful of coin tosses, and two
rules cannot be told apart by it (docs/decisions.md, issue 37, stops 59 and 60). This script reads
a finished benchmark folder and drives again, on ``--draws`` new sensor-noise seeds each, every GP
lap (iteration 1 and later) that needed the stability envelope at least ``--min-events`` times
(interventions and weaves) or was lost: the lap's own plan, tracking GP, exploration candidates
and envelope band, as ``iterate`` drove it (:func:`gprace.timetrial.iterate.driving.drive_lap`).

Prints one JSON row per lap (its events, whether the benchmark's own draw completed it, the draws
and how many were lost) and a summary: the **expected number of lost laps** of the run, the sum
over the re-driven laps of the share of their draws lost, the benchmark's own draw included. Laps
not re-driven count 0: calm laps (no envelope event) were not seen lost in the re-drives of stops
59 and 60. The expected number is what a rule should be judged on next to the benchmark's count;
it still reads the plans the benchmark's own draws led to.

Results are appended to ``ROOT/redrive.jsonl`` as they finish; a rerun resumes.

Usage: ``nice python benchmarks/timetrial_redrive.py ROOT [--only NAME,NAME] [--min-events N]
[--draws K] [--workers W]``. About 5 to 40 s of CPU per draw.
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from functools import lru_cache
from pathlib import Path


def noise_seed(draw: int, iteration: int) -> int:
    """Sensor-noise seed of re-drive ``draw`` of ``iteration`` (the benchmark's own is the trial's
    seed times 100 plus the iteration; stop 59's re-drives used these)."""
    return 7919 * (draw + 1) + iteration


def laps(root: Path, only: set[str], min_events: int) -> list[dict]:
    """The GP laps of ``root``'s plants to re-drive: lost, or ``min_events`` envelope events or more."""
    from gprace.timetrial.record import read_record

    out = []
    for path in sorted(root.glob("*/trial_*/iter_*/record.json")):
        plant, trial, it = path.parts[-4], int(path.parts[-3][6:]), int(path.parts[-2][5:])
        if it == 0 or (only and plant not in only):
            continue
        r = read_record(path)
        if r.envelope_events >= min_events or not r.completed:
            out.append({"plant": plant, "trial": trial, "iteration": it, "alpha": float(r.alpha),
                        "events": r.envelope_events, "own_completed": bool(r.completed)})
    return out


@lru_cache(maxsize=8)
def _trial(folder: str, trial: int):
    """The trial's chain (track, model, plant, reference runs), built once per worker and trial."""
    from gprace.timetrial.iterate.chain import _chain

    settings = json.loads((Path(folder) / "settings.json").read_text())
    return _chain({"out": folder, "trial": trial, "settings": settings.get("settings", settings)})


def redrive(task: tuple) -> dict:
    """One draw of one lap: ``{..lap, "draw", "completed", "reason"}``."""
    root, lap, draw = task
    from gprace.timetrial.iterate.driving import drive_lap

    c = _trial(str(Path(root) / lap["plant"]), lap["trial"])
    run = drive_lap(c, lap["iteration"], lap["alpha"], seed=noise_seed(draw, lap["iteration"]))
    return {**lap, "draw": draw, "completed": bool(run.meta["completed"]), "reason": str(run.meta.get("reason", ""))[:80]}


def summary(rows: list[dict]) -> dict:
    """Per lap: draws and lost (the benchmark's own draw included); the expected lost laps."""
    per: dict[tuple, dict] = {}
    for r in rows:
        key = (r["plant"], r["trial"], r["iteration"])
        lap = per.setdefault(key, {"plant": r["plant"], "trial": r["trial"], "iteration": r["iteration"],
                                   "events": r["events"], "own_completed": r["own_completed"],
                                   "draws": 1, "lost": int(not r["own_completed"])})
        lap["draws"] += 1
        lap["lost"] += int(not r["completed"])
    table = sorted(per.values(), key=lambda v: (v["plant"], v["trial"], v["iteration"]))
    return {"laps": table, "laps_redriven": len(table), "draws": sum(v["draws"] for v in table),
            "lost_draws": sum(v["lost"] for v in table),
            "laps_lost_on_some_draw": sum(v["lost"] > 0 for v in table),
            "lost_in_the_benchmark": sum(not v["own_completed"] for v in table),
            "expected_lost_laps": round(sum(v["lost"] / v["draws"] for v in table), 3)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="a benchmarks/timetrial_unseen.py output folder")
    ap.add_argument("--only", default="", help="comma-separated plant names (default: all)")
    ap.add_argument("--min-events", type=int, default=3, help="re-drive laps with at least this many envelope events")
    ap.add_argument("--draws", type=int, default=2, help="new noise draws per lap")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    if not a.root.is_dir():
        ap.error(f"{a.root}: no such folder")
    if a.draws < 1 or a.min_events < 0 or a.workers < 1:
        ap.error("--draws and --workers must be >= 1, --min-events >= 0")
    cache = a.root / "redrive.jsonl"
    done = [json.loads(line) for line in cache.read_text().splitlines() if line.strip()] if cache.exists() else []
    seen = {(r["plant"], r["trial"], r["iteration"], r["draw"]) for r in done}
    chosen = laps(a.root, {p for p in a.only.split(",") if p}, a.min_events)
    todo = [(str(a.root), lap, k) for lap in chosen
            for k in range(a.draws) if (lap["plant"], lap["trial"], lap["iteration"], k) not in seen]
    print(f"timetrial_redrive: {len(todo)} draws to drive ({len(done)} cached)", file=sys.stderr)
    with ProcessPoolExecutor(a.workers) as pool, cache.open("a") as f:
        for row in pool.map(redrive, todo):
            f.write(json.dumps(row) + "\n")
            f.flush()
            done.append(row)
    wanted = {(lap["plant"], lap["trial"], lap["iteration"]) for lap in chosen}
    rows = [r for r in done if (r["plant"], r["trial"], r["iteration"]) in wanted and r["draw"] < a.draws]
    print(json.dumps(summary(rows), indent=1))


if __name__ == "__main__":
    main()
