"""Controller step of modes wbc and hybrid beside none and both, side by side in one run.

``.venv/bin/python -m benchmarks.wbc_step [--force 553.125] [--wbc-force 240] [--steps 4] [--replays 3]
[--json results/benchmarks/wbc_step.json] [--results results/benchmarks/results.json]``

Records two push runs at the paper's cell (25 ms from t = 0.2315 s): mode ``both`` at ``--force`` (the hard
run of ``scripts/bench``) and mode ``wbc`` at ``--wbc-force`` (a push it survives, near its limit), and replays
their states (t, q, q', stance) through a fresh controller of each mode, interleaved replay by replay, timing
``AdaptiveController.compute`` (time.perf_counter_ns), fast engine: the compiled period, and for wbc / hybrid
the compiled whole-body stage (``wbc_kernels``; PIQP only when its active set does not settle). Rows:

* ``none``, ``both``, ``hybrid``, ``wbc (both's states)``: the states of the ``both`` run (for wbc far from its
  own reference: its stage is active in many periods, the hard case);
* ``wbc``: the states of its own run (the key ``controller.step_p50_us_wbc``: the controller's workload in its
  own closed loop).

Targets (compiled steps p50 <= 30 us) are printed, never asserted. Keys
``controller.step_p50_us_wbc``, ``controller.step_p50_us_hybrid`` (and ``controller.step_p50_us_both_wbc_run``,
the plain compiled step of the same run) are merged into ``--results`` (``keys``, section ``wbc_step``).
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import time
from pathlib import Path
from time import perf_counter_ns

import numpy as np

from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR

MODES = ("none", "both", "wbc", "hybrid")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--force", type=float, default=553.125)
    ap.add_argument("--wbc-force", type=float, default=230.0)
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--replays", type=int, default=3)
    ap.add_argument("--json", type=Path, default=RESULTS_DIR / "wbc_step.json")
    ap.add_argument("--results", type=Path, default=RESULTS_DIR / "results.json")
    a = ap.parse_args(argv)
    provenance.track(a.json, a.results, argv=argv)   # record of each file written (results/README.md)
    from biped_controller.core.control.config import load_controller_config
    from biped_controller.core.control.controller import AdaptiveController
    from biped_controller.core.qp.problem import ACTIVE, INFEASIBLE_FALLBACK, SOLVER_ERROR
    from biped_controller.closed_loop.runner import run
    from biped_sim.plant.push import Push
    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily

    desc, family = load_description(), GaitFamily.load()
    runs = {}
    for name, mode, force in (("both", "both", a.force), ("wbc", "wbc", a.wbc_force)):
        r = run(steps=a.steps, mode=mode, pushes=(Push(0.2315, 0.025, force),))
        runs[name] = {"states": [(rec.t, np.array(rec.q), np.array(rec.qd), rec.stance) for rec in r.records],
                      "mode": mode, "force": force, "fallen": bool(r.fallen), "steps_walked": r.steps_walked}
    rows = (("none", "none", "both"), ("both", "both", "both"), ("hybrid", "hybrid", "both"),
            ("wbc (both's states)", "wbc", "both"), ("wbc", "wbc", "wbc"), ("both (wbc's states)", "both", "wbc"))
    out = {"meta": {"date": time.strftime("%Y-%m-%d %H:%M:%S"), "cpus": os.cpu_count(),
                    "load_avg_1min_start": os.getloadavg()[0], "python": platform.python_version(),
                    "replays": a.replays,
                    "runs": {k: {kk: v for kk, v in r.items() if kk != "states"} | {"periods": len(r["states"])}
                             for k, r in runs.items()}},
           "rows": {}}
    times = {name: [] for name, _, _ in rows}
    solved = {name: [0, 0] for name, _, _ in rows}       # whole-body QP changed w: [compiled/PIQP any, total]
    counts = {name: {} for name, _, _ in rows}          # compiled stage: solved by the active set / by PIQP
    cfgs = {mode: load_controller_config(mode=mode) for _, mode, _ in rows}
    for _ in range(a.replays):                            # interleaved: every row sees the same machine load
        for name, mode, src in rows:
            states = runs[src]["states"]
            ctrl = AdaptiveController(cfgs[mode], family, desc)
            ctrl.reset(states[0][3])
            gc.collect()
            tl = times[name]
            for t, q, qd, st in states:
                t0 = perf_counter_ns()
                o = ctrl.compute(t, q, qd, st)
                tl.append(perf_counter_ns() - t0)
                solved[name][0] += o.status.wbc_status in (ACTIVE, INFEASIBLE_FALLBACK, SOLVER_ERROR)
                solved[name][1] += 1
            if ctrl.compiled_period is not None and ctrl.compiled_period.wk is not None:
                for k, v in ctrl.compiled_period.stage_counts.items():
                    counts[name][k] = counts[name].get(k, 0) + v
    out["meta"]["load_avg_1min_end"] = os.getloadavg()[0]
    for name, mode, src in rows:
        us = np.asarray(times[name], float) / 1e3
        out["rows"][name] = {"mode": mode, "states_of": f"{runs[src]['mode']} at {runs[src]['force']} N",
                             "p50_us": float(np.percentile(us, 50)), "p99_us": float(np.percentile(us, 99)),
                             "steps": int(us.size), "whole_body_changed_w": int(solved[name][0]),
                             "compiled_stage": counts[name]}
        r = out["rows"][name]
        print(f"{name:<20} p50 {r['p50_us']:7.1f} us  p99 {r['p99_us']:8.1f} us  steps {us.size}  "
              f"whole-body stage changed w in {r['whole_body_changed_w']} {counts[name]}  ({r['states_of']})")
    R_ = out["rows"]
    out["keys"] = {"controller.step_p50_us_wbc": R_["wbc"]["p50_us"],
                   "controller.step_p50_us_hybrid": R_["hybrid"]["p50_us"],
                   "controller.step_p50_us_both_wbc_run": R_["both"]["p50_us"]}
    out["target"] = {k: {"value": out["keys"][k], "target": "<= 30", "met": out["keys"][k] <= 30}
                     for k in ("controller.step_p50_us_wbc", "controller.step_p50_us_hybrid")}
    a.json.write_text(json.dumps(out, indent=1) + "\n")
    if a.results is not None and a.results.exists():
        res = json.loads(a.results.read_text())
        res["wbc_step"] = out
        res.setdefault("keys", {}).update(out["keys"])
        a.results.write_text(json.dumps(res, indent=1, default=float) + "\n", encoding="utf-8")
    print(json.dumps(out["target"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
