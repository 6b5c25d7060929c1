"""The paper's comparison: Double GP + exploration vs the Double GP baseline (random selection, alpha 0).

For each plant (``audi_hidden``: frenet with hidden effects; ``commonroad-std``) runs
``gprace iterate`` twice (3 trials each) into ``benchmarks/out/<plant>_<variant>`` (resumable) and
prints per iteration the driven lap time (mean, std), planned-vs-driven gap and both GPs'
errors on the held-out weaving run, as a JSON table. Long: minutes per variant.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

VARIANTS = {"exploration": dict(alphas=(0.857, 0.714, 0.0), selection="diverse"),
            "baseline": dict(alphas=(0.0,), selection="random")}


PLANTS = (("audi_hidden", "audi_tt_cup"), ("bmw_commonroad", "bmw_320i"))  # (plant, nominal vehicle)


def main(iterations: int = 7, trials: int = 3, plants=PLANTS) -> None:
    from gprace.timetrial.iterate import IterateSettings, build_summary, iterate

    out = {}
    for plant, vehicle in plants:
        for name, kw in VARIANTS.items():
            folder = Path(__file__).parent / "out" / f"{plant}_{name}"
            st = IterateSettings(iterations=iterations, trials=trials, plant=plant, vehicle=vehicle, **kw)
            try:
                iterate(st, folder, workers=2)
            except Exception as exc:  # report what finished
                print(f"{plant}/{name}: {exc}", file=sys.stderr)
            out[f"{plant}/{name}"] = build_summary(folder)["by_iteration"]
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    # usage: timetrial_compare.py [ITERATIONS [TRIALS [PLANT,PLANT]]]
    it = int(sys.argv[1]) if len(sys.argv) > 1 else 7
    tr = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    chosen = sys.argv[3].split(",") if len(sys.argv) > 3 else [p for p, _ in PLANTS]
    main(it, tr, tuple(pv for pv in PLANTS if pv[0] in chosen))
