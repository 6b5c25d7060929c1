"""The time trial on cars it has never met (issue 37): ``iterate`` on a family of unseen plants.

Runs ``gprace iterate`` (2 trials, 5 iterations, the default alphas 0.857, 0.714, 0) on

- 20 seeded ``randomized`` plants (the plant family of issue 37, docs/plants.md; cars 1..20, odd
  seeds around bmw_320i, even ones around audi_tt_cup). Where that plant kind is not installed,
  frenet stand-ins drawn from the same distribution where the effect catalogue can express it
  (:func:`standin`: grip per axle 0.8 to 1.05, downforce 0 to 1.5 of the Audi's coefficient, CoG
  height 0.3 to 0.6 m with load transfer, combined slip, steering lag 0 to 80 ms, yaw inertia +-25
  %, drag 0.7 to 1.5x; no tire relaxation and no measurement delay); ``--standins`` runs those;
- ``commonroad-mb`` (when installed) and ``commonroad-std`` (bmw_commonroad), nominal vehicle bmw_320i;
- ``audi_hidden``.

All experiments go into one executor batch (:func:`gprace.timetrial.iterate.iterate_many`), each in
``benchmarks/out/timetrial_unseen/<plant>/``; a rerun resumes every unfinished step. Prints one
JSON row per plant: laps completed of laps driven (iteration 0 included), the iteration-0 lap, the
best alpha-0 lap (mean over trials), the oracle lap where the physics are known and the share of
the gap it closed, stability interventions, GP error and coverage of the last iteration; then the
acceptance checks (0 lost laps on every plant; best alpha-0 lap faster than iteration 0 on >= 90 %
of the plants; median share of the gap closed >= 60 % where the oracle is known).

Usage: ``nice python benchmarks/timetrial_unseen.py [--only NAME,NAME] [--plants N] [--standins] [--trials T]
[--iterations I] [--seed S] [--workers W] [--chunk C] [--executor dask --scheduler ADDR] [--out DIR] [--table] [--markdown]``
(``--table``: print the table, run nothing; its acceptance counts the finished plants only).
Long: about 2 minutes of CPU per trial and plant.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

OUT = Path(__file__).parent / "out" / "timetrial_unseen"
VEHICLES = ("audi_tt_cup", "bmw_320i")
DOWNFORCE = 1.5  # N s^2/m^2: audi_hidden's coefficient, the "typical" of the stand-ins' range


def standin(seed: int) -> dict:
    """A frenet plant drawn from the issue-37 distribution (catalogue effects only), as TOML data."""
    rng = np.random.default_rng(1000 + seed)
    u = lambda a, b: float(rng.uniform(a, b))  # noqa: E731
    vehicle = VEHICLES[seed % 2]
    from gprace.config import load_vehicle

    drag = load_vehicle(vehicle).drag_coefficient
    effects = [{"name": "tire_friction", "front": u(0.8, 1.05), "rear": u(0.8, 1.05)},
               {"name": "downforce", "c_l": u(0.0, 1.5) * DOWNFORCE, "balance": u(0.35, 0.55)},
               {"name": "load_transfer", "cog_height": u(0.3, 0.6)},
               {"name": "combined_slip", "k": 1.0},
               {"name": "yaw_inertia", "factor": u(0.75, 1.25)}]
    lag = u(0.0, 0.08)
    if lag > 1e-3:
        effects.append({"name": "steering_lag", "tau": lag})
    if drag > 0:
        effects.append({"name": "aero_drag", "c_d": (u(0.7, 1.5) - 1.0) * drag})
    return {"kind": "frenet", "vehicle": vehicle, "substeps": 10, "seed": seed, "effects": effects,
            "noise": {"v_x": 0.02, "v_y": 0.01, "yaw_rate": 0.005, "e_psi": 0.002, "e_y": 0.02, "s": 0.05}}


def randomized(seed: int) -> dict:
    """A ``randomized`` plant (docs/plants.md): car ``seed`` of the family around its vehicle."""
    return {"kind": "randomized", "vehicle": VEHICLES[seed % 2], "substeps": 10, "seed": 0, "options": {"seed": seed},
            "noise": {"v_x": 0.02, "v_y": 0.01, "yaw_rate": 0.005, "e_psi": 0.002, "e_y": 0.02, "s": 0.05}}


def plants(n: int, folder: Path, standins: bool = False) -> dict[str, tuple[str, str]]:
    """``name -> (plant TOML or shipped name, nominal vehicle)``; writes the TOMLs into ``folder``."""
    import tomli_w

    from gprace.backends import plants as registry

    have = set(registry.names())
    folder.mkdir(parents=True, exist_ok=True)
    out: dict[str, tuple[str, str]] = {}
    use_randomized = "randomized" in have and not standins
    for seed in range(1, n + 1):
        data, name = (randomized(seed), f"randomized_{seed:02d}") if use_randomized else (standin(seed), f"standin_{seed:02d}")
        path = folder / f"{name}.toml"
        path.write_text(tomli_w.dumps(data))
        out[name] = (str(path), data["vehicle"])
    if "commonroad-mb" in have:
        path = folder / "commonroad_mb.toml"
        path.write_text(tomli_w.dumps({"kind": "commonroad-mb", "vehicle": "bmw_320i", "seed": 0,
                                       "noise": {"v_x": 0.02, "v_y": 0.01, "yaw_rate": 0.005, "e_psi": 0.002,
                                                 "e_y": 0.02, "s": 0.05}}))
        out["commonroad_mb"] = (str(path), "bmw_320i")
    else:
        print("commonroad-mb: plant kind not installed; left out", file=sys.stderr)
    out["commonroad_std"] = ("bmw_commonroad", "bmw_320i")
    out["audi_hidden"] = ("audi_hidden", "audi_tt_cup")
    return out


def row(summary: dict) -> dict:
    """One plant's figures from its iterate summary."""
    rows = summary["rows"]
    trials = summary["per_trial"]
    oracle = summary.get("oracle") or {}
    o_lap = None
    if oracle.get("known"):
        o_lap = oracle.get("driven") if oracle.get("completed") else oracle.get("planned")
    last = max((a for a in summary["by_iteration"]), key=lambda a: a["iteration"], default={})
    it0 = [t["iteration0"] for t in trials]
    best = [t["best_alpha0"] for t in trials]
    closed = [t["gap_closed_best"] for t in trials]
    return {
        "laps": f"{sum(r['completed'] for r in rows)}/{len(rows)}",
        "lost": [f"trial {r['trial']} iteration {r['iteration']}: {r['reason']}" for r in rows if not r["completed"]],
        "iteration0": _mean(it0), "best_alpha0": _mean(best),
        "faster_than_iteration0": bool(all(np.isfinite(b) and b < a for a, b in zip(it0, best))) if trials else False,
        "oracle": o_lap, "oracle_basis": oracle.get("basis") if oracle.get("known") else "unknown",
        "gap_closed": _mean(closed) if o_lap is not None else None,
        "interventions": int(sum(r.get("interventions", 0) for r in rows)),
        "interventions_iteration0": int(sum(r.get("interventions", 0) for r in rows if r["iteration"] == 0)),
        "fell_back": int(sum(str(r.get("plan_source", "")).startswith(("back", "last good")) for r in rows)),
        "delay_estimated": _mean([r.get("delay", np.nan) for r in rows if r["iteration"] == 0]),
        "err_tracking": last.get("err_tracking"), "err_planning": last.get("err_planning"),
        "cov_tracking": last.get("cov_tracking"), "cov_planning": last.get("cov_planning"),
    }


def _mean(values) -> float:
    a = np.asarray([np.nan if v is None else v for v in values], float)
    return float(np.mean(a[np.isfinite(a)])) if np.isfinite(a).any() else float("nan")


def acceptance(table: dict) -> dict:
    """The issue's three checks over the rows."""
    rows = list(table.values())
    lost = {name: r["lost"] for name, r in table.items() if r["lost"]}
    faster = [r["faster_than_iteration0"] for r in rows]
    closed = [r["gap_closed"] for r in rows if r["gap_closed"] is not None and np.isfinite(r["gap_closed"])]
    return {
        "plants": len(rows), "lost_laps": sum(len(v) for v in lost.values()), "plants_with_lost_laps": sorted(lost),
        "zero_lost_laps": not lost,
        "share_faster_than_iteration0": float(np.mean(faster)) if faster else float("nan"),
        "faster_ok": bool(faster) and float(np.mean(faster)) >= 0.9,
        "median_gap_closed": float(np.median(closed)) if closed else float("nan"), "plants_with_oracle": len(closed),
        "gap_ok": bool(closed) and float(np.median(closed)) >= 0.6,
    }


def main(argv=None) -> None:
    from gprace.console import jsonable
    from gprace.errors import GpraceError
    from gprace.timetrial.iterate import IterateSettings, build_summary, iterate_many

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", type=int, default=20, help="seeded randomized plants")
    ap.add_argument("--only", default="", help="comma-separated plant names to run, in this order (default: all)")
    ap.add_argument("--standins", action="store_true", help="frenet stand-ins instead of the randomized plants")
    ap.add_argument("--trials", type=int, default=2)
    ap.add_argument("--iterations", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0, help="iterate's seed (trial t: seed + t): sensor noise, GP fits "
                    "and the dictionary's selection; another seed repeats the benchmark on new draws")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--chunk", type=int, default=0, help="plants per batch, batches in turn (0: all in one batch)")
    ap.add_argument("--executor", default="local")
    ap.add_argument("--scheduler", default=None)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--table", action="store_true", help="only print the table (no runs); the acceptance over "
                    "the finished plants")
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table instead of JSON")
    a = ap.parse_args(argv)
    family = plants(a.plants, a.out / "plants", a.standins)
    if a.only:  # in the order given: on a loaded machine the first ones finish first
        keep = [k for k in a.only.split(",") if k]
        unknown = [k for k in keep if k not in family]
        if unknown:
            ap.error(f"--only: unknown plant(s) {', '.join(unknown)}; known: {', '.join(family)}")
        family = {k: family[k] for k in keep}
    experiments = [(IterateSettings(trials=a.trials, iterations=a.iterations, seed=a.seed, plant=plant,
                                    vehicle=vehicle),
                    a.out / name) for name, (plant, vehicle) in family.items()]
    # batches of --chunk plants, one after the other: a plant's oracle lap runs at the end of its
    # batch, so on a loaded machine the first plants finish whole (oracle included) first
    size = a.chunk if a.chunk > 0 else len(experiments)
    for at in range(0, 0 if a.table else len(experiments), max(size, 1)):
        try:
            iterate_many(experiments[at:at + size], executor=a.executor, workers=a.workers, scheduler=a.scheduler)
        except GpraceError as exc:  # failed trials are reported in the rows; the summaries are written
            print(f"timetrial_unseen: {exc}", file=sys.stderr)
    table = {}
    for (name, _), (st, folder) in zip(family.items(), experiments):
        try:
            summary = build_summary(folder)
            table[name] = {**row(summary), "finished": len(summary["rows"]) == st.trials * (st.iterations + 1)
                           and (folder / "oracle.json").exists()}
        except GpraceError as exc:
            table[name] = {"error": str(exc), "lost": [str(exc)], "faster_than_iteration0": False, "gap_closed": None,
                           "finished": False}
    done = {k: v for k, v in table.items() if v["finished"]}
    result = {"rows": table, "acceptance": acceptance(done if a.table else table)}
    print(markdown(result) if a.markdown else json.dumps(jsonable(result), indent=1))


def markdown(result: dict) -> str:
    """The rows and the acceptance as a Markdown table (unfinished plants marked)."""
    def f(v, fmt="{:.2f}"):
        return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else fmt.format(v)

    lines = ["| plant | laps | iter. 0 | best alpha 0 | oracle | gap closed | interventions (it. 0) | fell back | "
             "GP err track / plan | cov track / plan |", "| --- " * 10 + "|"]
    for name, r in result["rows"].items():
        if "error" in r:
            lines.append(f"| {name} | error: {r['error']} |" + " |" * 8)
            continue
        lines.append(f"| {name}{'' if r['finished'] else ' (running)'} | {r['laps']} | {f(r['iteration0'])} | "
                     f"{f(r['best_alpha0'])} | {f(r['oracle'])} {r['oracle_basis'] or ''} | {f(r['gap_closed'])} | "
                     f"{r['interventions']} ({r['interventions_iteration0']}) | {r['fell_back']} | "
                     f"{f(r['err_tracking'])} / {f(r['err_planning'])} | {f(r['cov_tracking'])} / {f(r['cov_planning'])} |")
    acc = result["acceptance"]
    lines.append("")
    lines.append(f"plants {acc['plants']}; lost laps {acc['lost_laps']} {acc['plants_with_lost_laps']}; best alpha-0 lap "
                 f"faster than iteration 0 on {f(acc['share_faster_than_iteration0'])}; median gap closed "
                 f"{f(acc['median_gap_closed'])} over {acc['plants_with_oracle']} plants with an oracle")
    for name, r in result["rows"].items():
        for lost in r.get("lost", []):
            lines.append(f"- {name}: {lost}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
