"""Bad input per command, counted: how each ended (exit code, one stderr line or not, the contract).

Runs every case of ``tests/bad_inputs.py`` (each class of bad input given to each command that
reads it: missing, empty, directory, garbage, truncated, NaN, text, units x3.6 and x57.3, spin,
reversed and duplicated time, unknown keys and names, out-of-range numbers) once, then a seeded
draw of more rows, columns, cut points, blobs, spins and values of the same classes, all
in-process through the CLI entry. The contract: exit 2 with exactly one ``error:`` line naming
the culprit and nothing left in the output folder; a spin exits 0 with the one exclusion note.
Prints a JSON table per command and the cases that broke the contract (none expected).

Usage: python benchmarks/bad_input_probe.py [--per-class 3] [--seed 0]
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


def main() -> None:
    B = _cases_module()
    cases = B.all_cases() + B.variant_cases(np.random.default_rng(int(_arg("--seed", "0"))), int(_arg("--per-class", "3")))
    table: dict[str, dict] = defaultdict(lambda: {"tried": 0, "exit": Counter(), "one_line": 0, "contract_kept": 0,
                                                  "classes": set()})
    broken = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        base = B.base_recording(root)
        for i, c in enumerate(cases):
            folder = root / f"case_{i}"
            folder.mkdir()
            res = B.run_cli(c.argv(folder, base), folder / "out")
            row = table[c.command]
            row["tried"] += 1
            row["exit"][res.code] += 1
            row["one_line"] += res.one_line
            row["classes"].add(c.kind.split(" ")[0] if c.kind.startswith("--") else c.kind)
            problems = res.problems(c.expect)
            row["contract_kept"] += not problems
            if problems:
                broken.append({"command": c.command, "input": c.kind, "problems": problems, "stderr": res.stderr[-1:]})
    out = {"cases": len(cases), "seconds": round(time.perf_counter() - t0, 1),
           "per_command": {k: {"tried": v["tried"], "exit": {str(code): n for code, n in sorted(v["exit"].items())},
                               "one_line": v["one_line"], "contract_kept": v["contract_kept"],
                               "classes": len(v["classes"])} for k, v in sorted(table.items())},
           "broken": broken}
    out["total"] = {"tried": len(cases), "exit_2": sum(v["exit"].get(2, 0) for v in table.values()),
                    "exit_0_excluded": sum(v["exit"].get(0, 0) for v in table.values()),
                    "other_exit": sum(n for v in table.values() for code, n in v["exit"].items() if code not in (0, 2)),
                    "one_line": sum(v["one_line"] for v in table.values()),
                    "contract_kept": sum(v["contract_kept"] for v in table.values())}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
