"""Diagnose a recording: which physics does the nominal model leave out, and where?

The "real car" here is gprace's ``frenet`` plant with a road grade the nominal Audi TT Cup model
does not know about (6 % of a radian uphill between s = 200 m and 350 m of the 628 m circle). The
script records two laps to a CSV file, the format an engineer brings from a data logger
(columns t, s, e_y, e_psi, v_x, v_y, yaw_rate, delta, a_x, kappa in SI units), then asks
``gprace diagnose`` to find the mismatch blind, and draws the result into an HTML report.

    python examples/diagnose_recording.py [OUT_DIR]      (default: ./diagnose_out)
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from gprace.config import EffectConfig, load_vehicle
from gprace.diagnose.synth import record
from gprace.io.runs import write_run_csv
from gprace.tracks import load_track


def main(out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    # 1. a recording with a hidden effect (the diagnosis is not told about it)
    hidden = EffectConfig(name="road_grade", params={"angle": 0.06, "s_start": 200.0, "s_end": 350.0})
    run = record(load_vehicle("audi_tt_cup"), load_track("circle_100"), [hidden], laps=2, seed=3)
    write_run_csv(run, out / "recording.csv")

    # 2. the diagnosis, through the command line like any user would run it
    res = subprocess.run(
        ["gprace", "--quiet", "diagnose", str(out / "recording.csv"), "--vehicle", "audi_tt_cup", "--json",
         "-o", str(out / "augmented.toml")],
        capture_output=True, text=True, check=True,
    )
    report = json.loads(res.stdout)
    (out / "diagnosis.json").write_text(json.dumps(report, indent=2))
    print(f"verdict: {report['verdict']}")
    for e in report["effects"]:
        params = ", ".join(f"{k} = {v['value']:.4g} {v['unit']} [{v['ci95'][0]:.4g}, {v['ci95'][1]:.4g}]"
                           for k, v in e["parameters"].items())
        print(f"effect:  {e['name']}: {params}")

    # 3. one page with the residual along the track, channels, windows and parameters
    subprocess.run(["gprace", "--quiet", "report", str(out), "-o", str(out / "report.html")], check=True)
    print(f"report:  {out / 'report.html'}")
    return report


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("diagnose_out"))
