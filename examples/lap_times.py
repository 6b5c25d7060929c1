"""Lap times of a ``gprace iterate`` folder from Python: the summary as a table and the paper's
lap-time figure (planned, driven, difference per iteration, spread over trials) as a PNG.

    python examples/lap_times.py ITERATE_DIR [PNG]      (e.g. timetrial_out/exploration laps.png)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from gprace.report.figures import fig_lap_times


def _num(v) -> float:
    """A number of summary.json: non-finite ones (a lost lap's time, iteration 0's GP errors) are null."""
    return float("nan") if v is None else float(v)


def main(folder: Path, png: Path) -> None:
    rows = json.loads((folder / "summary.json").read_text())["rows"]
    for r in rows:
        print(f"iteration {r['iteration']} trial {r['trial']}: planned {_num(r['planned']):.2f} s, "
              f"driven {_num(r['driven']):.2f} s, GP errors tracking {_num(r['err_tracking']):.3g} "
              f"planning {_num(r['err_planning']):.3g}")
    data = {k: np.array([_num(r[k]) for r in rows], float) for k in ("iteration", "planned", "driven")}
    fig_lap_times({folder.name: data}).savefig(png, dpi=100)
    print(f"figure: {png}")


if __name__ == "__main__":
    folder = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("timetrial_out/exploration")
    main(folder, Path(sys.argv[2]) if len(sys.argv) > 2 else Path("lap_times.png"))
