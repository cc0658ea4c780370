"""How fast can the probabilistic 25 ms MuJoCo slice run at best on this approach? Counts the control periods a
seeded-map store's cells simulated and prices them at MuJoCo's own steps alone (the floor no Python saving
lowers), against the 30-minute target (issue 43).

    .venv/bin/python -m lab.slice_floor STORE.jsonl --walk-periods N --mj-step-us US [--cores 2] --json F

Per cell: the pushed trials' periods (a trial that fell: its fall time over the control period; one that did
not: ``--walk-periods``, the periods of an unpushed walk of the same impacts, which such a trial runs) and the
unpushed walks' (one per seed and mode: ``--walk-periods`` each, each worker's repeats not counted). The floor is
those periods times ``--mj-step-us`` (MuJoCo's steps of one control period) over ``--cores``. Estimates from
the records (the periods are counted from fall times, not measured); the inputs are named in the JSON.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("store", type=Path)
    ap.add_argument("--walk-periods", type=float, required=True, help="control periods of an unpushed walk")
    ap.add_argument("--mj-step-us", type=float, required=True, help="[us] MuJoCo's steps of one control period")
    ap.add_argument("--period", type=float, default=0.001, help="[s] the control period")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args(argv)
    from biped_controller.studies import provenance
    provenance.track(args.json, argv=argv)
    cells = []
    for line in args.store.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        rec = json.loads(line)
        key, res = rec["key"], rec["result"]
        trials = [t for r in res.values() for t in r["trials"]]
        fell = [t for t in trials if t.get("fall_time") is not None]
        pushed = sum(t["fall_time"] / args.period for t in fell) + (len(trials) - len(fell)) * args.walk_periods
        walks = key["seeds"] * len(res) * args.walk_periods
        cells.append({"direction": key["direction"], "phase": key["phase"], "trials": len(trials),
                      "fell": len(fell), "pushed_periods": pushed, "walk_periods": walks})
    periods = sum(c["pushed_periods"] + c["walk_periods"] for c in cells)
    n = len(cells)
    per_cell = periods / n if n else 0.0
    out = {"store": str(args.store), "inputs": {"walk_periods": args.walk_periods, "mj_step_us": args.mj_step_us,
                                               "period_s": args.period, "cores": args.cores},
           "cells": cells, "cell_count": n, "periods_per_cell": per_cell,
           "walk_share": sum(c["walk_periods"] for c in cells) / periods if periods else 0.0,
           "floor_cpu_s_per_cell": per_cell * args.mj_step_us * 1e-6,
           "floor_40_cells_wall_min": 40 * per_cell * args.mj_step_us * 1e-6 / args.cores / 60.0}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(f"{n} cells, {per_cell:.0f} control periods a cell ({100 * out['walk_share']:.0f} % unpushed walks); "
          f"MuJoCo's steps alone {out['floor_cpu_s_per_cell']:.1f} CPU s a cell, the 40-cell slice "
          f"{out['floor_40_cells_wall_min']:.1f} min on {args.cores} free cores")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
