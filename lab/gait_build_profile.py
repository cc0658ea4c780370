"""Where does a full gait-family build's time go? One build of a robot's family in one process (``workers=1``,
the same file as with two: ``gaits.build``), counting per phase the solves, SLSQP iterations, NLP evaluations
and the seconds inside the evaluation and inside SLSQP's own code.

    .venv/bin/python -m lab.gait_build_profile [--robot biped7] [--no-speed] --json results/gait_build/profile.json

Phases are told apart by the build's own progress messages (the solves between two messages belong to the phase
the second one closes). The evaluation's time is measured around ``evaluate`` when it computes (a cache hit is
not counted); SLSQP's own time is the rest of ``minimize``. Counts are deterministic; seconds depend on the load,
recorded beside them.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from biped_controller.gaits import build
from biped_controller.gaits.fast_eval import FastStepOptimizer
from biped_controller.gaits.optimizer import StepOptimizer, load_gait_settings


class Counter:
    def __init__(self):
        self.rows: list[dict] = []
        self.cur = self._new("start")
        self.t0 = time.perf_counter()

    @staticmethod
    def _new(name: str) -> dict:
        return {"phase": name, "solves": 0, "iterations": 0, "evaluations": 0, "evaluate_s": 0.0, "solve_s": 0.0,
                "diagnose_s": 0.0, "diagnoses": 0, "successes": 0}

    def close(self, msg: str) -> None:
        self.cur["phase"] = msg
        self.cur["wall_s"] = time.perf_counter() - self.t0
        self.rows.append(self.cur)
        self.cur = self._new("")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--robot", default="biped7")
    ap.add_argument("--no-speed", action="store_true")
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args(argv)
    from biped_model.robot import resolve_robot
    from biped_controller.studies import provenance
    provenance.track(args.json, argv=argv)
    r = resolve_robot(args.robot)
    st = load_gait_settings(r.gait_path)
    cnt = Counter()
    ev_orig = FastStepOptimizer.evaluate
    solve_orig = StepOptimizer.solve
    diag_orig = StepOptimizer.diagnose

    def evaluate(self, z):
        if z.tobytes() == self._cache_key:
            return ev_orig(self, z)
        t = time.perf_counter()
        out = ev_orig(self, z)
        cnt.cur["evaluate_s"] += time.perf_counter() - t
        cnt.cur["evaluations"] += 1
        return out

    def solve(self, *a, **k):
        t = time.perf_counter()
        sol = solve_orig(self, *a, **k)
        cnt.cur["solve_s"] += time.perf_counter() - t
        cnt.cur["solves"] += 1
        cnt.cur["iterations"] += sol.iterations
        cnt.cur["successes"] += int(sol.success)
        return sol

    def diagnose(self, *a, **k):
        t = time.perf_counter()
        diag_orig(self, *a, **k)
        cnt.cur["diagnose_s"] += time.perf_counter() - t
        cnt.cur["diagnoses"] += 1

    FastStepOptimizer.evaluate = evaluate
    StepOptimizer.solve = solve
    StepOptimizer.diagnose = diagnose
    log_orig = build._log

    def log(progress, t0, msg):
        cnt.close(msg)
        log_orig(progress, t0, msg)
    build._log = log
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    data, times = build.build_family(st, desc=None if r.is_default else r.description(), workers=1,
                                     speed=not args.no_speed)
    wall = time.perf_counter() - t0
    cnt.close("after the last message (diagnostics of the held-out, validation)")
    tot = {k: sum(row[k] for row in cnt.rows) for k in ("solves", "iterations", "evaluations", "evaluate_s", "solve_s",
                                                         "diagnose_s", "diagnoses")}
    tot["slsqp_and_overhead_s"] = tot["solve_s"] - tot["evaluate_s"]
    out = {"robot": r.name, "workers": 1, "wall_s": wall, "build_times_s": times, "phases": cnt.rows,
           "totals": tot, "evaluate_ms_per_call": 1e3 * tot["evaluate_s"] / max(1, tot["evaluations"]),
           "iterations_per_solve": tot["iterations"] / max(1, tot["solves"]),
           "load_before": list(load0), "load_after": list(os.getloadavg()), "cpu_count": os.cpu_count()}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    for row in cnt.rows:
        print(f"{row['wall_s']:7.1f} s  solves {row['solves']:4d}  it {row['iterations']:6d}  ev {row['evaluations']:6d}  "
              f"eval {row['evaluate_s']:6.1f} s  solve {row['solve_s']:6.1f} s  diag {row['diagnose_s']:5.1f} s  {row['phase']}")
    print("totals", tot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
