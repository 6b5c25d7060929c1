"""Planning time of a full lap: the default circuit and a ~5 km real circuit (TUM database).

Prints a JSON table: lap time, nodes, IPOPT iterations and wall time, cold (from the
minimum-curvature guess) and warm (from the cold solution).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

REAL = Path(__file__).resolve().parents[2] / "shared/data/tumftm-racetrack-database/tracks/Sakhir.csv"


def main(real: str = str(REAL)) -> None:
    from gprace.config import load_vehicle
    from gprace.model import NominalModel
    from gprace.plan import PlanSettings, plan_min_time
    from gprace.tracks import load_track

    m = NominalModel(load_vehicle("audi_tt_cup"))
    rows = []
    for name in ("gprace_ring", real):
        tr = load_track(name)
        t0 = time.perf_counter()
        p = plan_min_time(tr, m, PlanSettings(ds=6.0))
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        w = plan_min_time(tr, m, PlanSettings(ds=6.0), warm=p)
        warm = time.perf_counter() - t0
        rows.append({"track": tr.name, "length_m": tr.length, "nodes": p.n, "lap_time_s": p.lap_time,
                     "cold_s": cold, "cold_iter": p.meta["iterations"], "warm_s": warm, "warm_iter": w.meta["iterations"]})
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main(*sys.argv[1:])
