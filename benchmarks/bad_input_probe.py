"""Bad input per command, counted: how each ended (exit code, one stderr line or not, the contract).

Runs every case of ``tests/bad_inputs.py``: each class of bad input given to each command that
reads it (missing, empty, directory, garbage, truncated, NaN, text, units x3.6 and x57.3, spin,
reversed and duplicated time, unknown keys and names, out-of-range numbers) once and in a seeded
draw of more rows, columns, cut points, blobs, spins and values; then the rows of issue 38 as
classes with seeded variants: Ctrl-C and SIGTERM in the long commands, sizes beyond the data and
the machine (dictionary sizes, --max-points, laps, periods, horizons), read-only output folders,
a second run into a folder in use and the lock of a killed run, the claims table of 2 tracks,
implausible vehicles, `show` of every JSON kind, -q after the subcommand, the plant simulate
names; and the reader rows of issue 38 (BOM, CRLF, ';', ns/us time, map paths, constant
channels, a log of another track, s without a track), counted apart as the ingest helper's; and
the bad-input lines of issues 36, 37 and 39 (``--only issue36-39``: a map naming a column the file
lacks, a clock running backwards, crossing boundary files, a recording with no moving sample; a
``randomized`` plant with an unknown key or a range upside down, a delay beyond the MPC horizon;
recordings of different tracks to ``learn``, a raceline whose columns do not match its format, an
``--out`` folder holding another car's iterations or an iterate experiment), counted per owner.

An interrupt is sent only while the command runs: a command that ended before the drawn moment
is judged as a finished run and counted under ``ended_before_signal``.

The contract: a refusal exits 2 with exactly one ``error:`` line naming the culprit and nothing
left in the output folder; an interrupt exits 130 with one line; an accepted input exits 0
without error lines; never an internal error or a traceback. Prints a JSON table per command,
the totals per owner, and the cases that broke the contract.

Usage: python benchmarks/bad_input_probe.py [--per-class 3] [--expensive 1] [--seed 0]
       [--only issue38|ingest|issue16|issue36-39]
"""

from __future__ import annotations

import importlib.util
import json
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _arg(name: str, default: str) -> str:
    return sys.argv[sys.argv.index(name) + 1] if name in sys.argv else default


def _cases_module():
    spec = importlib.util.spec_from_file_location("bad_inputs", ROOT / "tests" / "bad_inputs.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bad_inputs"] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def _cases(B, rng: np.random.Generator, per_class: int, expensive: int, only: str) -> list:
    groups = {"issue16": lambda: B.all_cases() + B.variant_cases(rng, per_class),
              "issue38": lambda: B.issue38_cases(rng, per_class, expensive),
              "ingest": lambda: B.ingest_cases(rng),
              "issue36-39": lambda: B.later_cases(rng, per_class)}
    return [c for name, make in groups.items() if only in ("", name) for c in make()]


def _row() -> dict:
    return {"tried": 0, "exit": Counter(), "refusals": 0, "refusals_one_line": 0, "contract_kept": 0,
            "internal_errors": 0, "tracebacks": 0, "wrong_exit_0": 0, "ended_before_signal": 0, "classes": set()}


def main() -> None:
    B = _cases_module()
    rng = np.random.default_rng(int(_arg("--seed", "0")))
    cases = _cases(B, rng, int(_arg("--per-class", "3")), int(_arg("--expensive", "1")), _arg("--only", ""))
    table: dict[str, dict] = defaultdict(_row)
    owners: dict[str, dict] = defaultdict(_row)
    broken = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        base = B.base_recording(root)
        for i, c in enumerate(cases):
            folder = root / f"case_{i}"
            folder.mkdir()
            t = time.perf_counter()
            try:
                res = B.run_case(c, folder, base)
            except Exception as exc:  # noqa: BLE001 -- a case that cannot even be made is counted, not fatal
                res = B.Outcome(-1, [f"probe: the case could not run: {type(exc).__name__}: {exc}"], [])
            problems = res.problems(c.expect)
            refusal = isinstance(c.expect, B.Refused) or (isinstance(c.expect, B.Interrupted) and res.signalled)
            for row in (table[c.command], owners[c.owner]):
                row["tried"] += 1
                row["exit"][res.code] += 1
                row["refusals"] += refusal
                row["refusals_one_line"] += refusal and len([ln for ln in res.stderr if ln.startswith("error:")]) == 1
                row["contract_kept"] += not problems
                row["internal_errors"] += res.internal_error
                row["tracebacks"] += res.traceback
                row["wrong_exit_0"] += res.code == 0 and bool(problems)  # an exit-0 output the contract calls wrong
                row["ended_before_signal"] += not res.signalled  # judged as a finished run: no signal was sent
                row["classes"].add(c.kind.split(" ")[0] if c.kind.startswith("--") else c.kind)
            if problems:
                broken.append({"command": c.command, "input": c.kind, "owner": c.owner, "problems": problems,
                               "stderr": res.stderr[-1:], "seconds": round(time.perf_counter() - t, 1)})

    def dump(rows: dict) -> dict:
        return {k: {**{f: v[f] for f in ("tried", "refusals", "refusals_one_line", "contract_kept", "internal_errors",
                                          "tracebacks", "wrong_exit_0", "ended_before_signal")},
                    "exit": {str(code): n for code, n in sorted(v["exit"].items())}, "classes": len(v["classes"])}
                for k, v in sorted(rows.items())}

    out = {"cases": len(cases), "seconds": round(time.perf_counter() - t0, 1), "per_command": dump(table),
           "per_owner": dump(owners), "broken": broken}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
