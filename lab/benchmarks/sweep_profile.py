"""Where a sweep's CPU goes: a small capability map run in this process, serially, with timers
(``time.process_time``) around the parts of a survival trial -- the compiled loop's calls
(``Segment.run``), the QP decisions between them (``Segment.decide``, where it exists), the periods the
objects take (``AdaptiveController.compute``, ``Simulator.step``), building the plant and the controller,
the walks to the push onsets (``ClosedLoop.walk_to``, where it exists). Parts nest (``Segment.run``
includes the records it builds), so the shares do not add up to 100 %.

    python -m lab.benchmarks.sweep_profile [--phases 2] [--json FILE]

Run it in another tree with that tree's sources on ``PYTHONPATH`` (and its own ``NUMBA_CACHE_DIR``) to
compare two versions: the parts missing there are left out. The machine is shared: the figures are this
run's, under whatever load there was (recorded).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path


def profile(phases: int) -> dict:
    from biped_sim.plant import rigid
    from biped_controller.core.control import controller as C
    from biped_controller.closed_loop import runner, segment
    from biped_controller.studies import capability_map as cm
    from biped_controller.studies.trial import runs, trials

    acc: dict[str, list] = {}

    def wrap(owner, name: str, key: str) -> None:
        if not hasattr(owner, name):
            return
        f = getattr(owner, name)

        def timed(*a, **k):
            t0 = time.process_time()
            try:
                return f(*a, **k)
            finally:
                e = acc.setdefault(key, [0.0, 0])
                e[0] += time.process_time() - t0
                e[1] += 1
        setattr(owner, name, timed)

    trials.survives(runs.paper_push(100.0, start=0.1), "both")   # compile and load outside the timed part
    for owner, name, key in ((segment.Segment, "run", "compiled loop (Segment.run)"),
                             (segment.Segment, "decide", "QP decisions in the loop (Segment.decide)"),
                             (C.AdaptiveController, "compute", "objects: controller period"),
                             (rigid.Simulator, "step", "objects: plant period"),
                             (C.AdaptiveController, "__init__", "building the controller"),
                             (rigid.Simulator, "__init__", "building the plant"),
                             (getattr(runner, "ClosedLoop", None), "walk_to", "walks to the onsets (shared)")):
        if owner is not None:
            wrap(owner, name, key)
    spec = cm.MapSpec(phases=cm.phases_of(phases))
    load0 = os.getloadavg()
    t0 = time.process_time()
    run = cm.run_map(spec)
    total = time.process_time() - t0
    parts = {k: {"cpu_s": v[0], "calls": v[1], "share": v[0] / total, "us_per_call": 1e6 * v[0] / v[1]}
             for k, v in acc.items()}
    return {"cells": len(spec.cells()), "simulations": run.simulated, "cpu_s": total,
            "ms_per_simulation": 1e3 * total / run.simulated, "parts": parts,
            "load_average_before": list(load0), "load_average_after": list(os.getloadavg())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phases", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    r = profile(a.phases)
    print(f"{r['cells']} cells, {r['simulations']} simulations, CPU {r['cpu_s']:.2f} s "
          f"({r['ms_per_simulation']:.1f} ms per simulation), load {r['load_average_before']}")
    for k, v in sorted(r["parts"].items(), key=lambda kv: -kv[1]["cpu_s"]):
        print(f"  {k:44s} {v['cpu_s']:7.2f} s {100 * v['share']:5.1f} % {v['calls']:8d} calls {v['us_per_call']:9.1f} us/call")
    if a.json is not None:
        a.json.write_text(json.dumps(r, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
