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


def main(folder: Path, png: Path) -> None:
    rows = json.loads((folder / "summary.json").read_text())["rows"]
    for r in rows:
        print(f"iteration {r['iteration']} trial {r['trial']}: planned {r['planned']:.2f} s, "
              f"driven {r['driven']:.2f} s, GP errors tracking {r['err_tracking']:.3g} planning {r['err_planning']:.3g}")
    data = {k: np.array([r[k] for r in rows], float) for k in ("iteration", "planned", "driven")}
    fig_lap_times({folder.name: data}).savefig(png, dpi=100)
    print(f"figure: {png}")


if __name__ == "__main__":
    folder = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("timetrial_out/exploration")
    main(folder, Path(sys.argv[2]) if len(sys.argv) > 2 else Path("lap_times.png"))
