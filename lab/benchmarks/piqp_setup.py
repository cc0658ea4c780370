"""The cost of setting every PIQP solve up from its instance (``solver.AdaptationQP``, what makes a QP answer
a function of its instance alone) against the held update it replaced (each PIQP object set up on its
first solve, then updated: the previous instance's scaling left in its data; docs/capability_map.md, "One
trial, one record").

    python -m lab.benchmarks.piqp_setup [--json OUT] [--rounds 4] [--phases 4] [--repeats 20]

Two measurements, the two paths taken in turn in one process (setup then update in even rounds, update
then setup in odd ones):

* ``qp``: ``AdaptationQP.solve`` on the controller's own QPs with x* infeasible (MuJoCo, 4 steps with a
  push of 600 N and -900 N in mode both, 700 N in mode all; ``runner.run(keep_qp=True)``), each instance
  ``--repeats`` times with the garbage collector off: the mean wall time per solve [us].
* ``map``: a MuJoCo map slice in this process (mode both, 25 ms, both directions, ``--phases`` onset
  phases, the default search, no store), its wall and CPU time [s]; this process's loop pool and the
  survival bands emptied before each run, so every run walks to its onsets and computes its band.

Writes the figures (each round's and the medians) with a provenance record.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np

from biped_controller.studies import provenance

OUT = Path(__file__).resolve().parents[2] / "results" / "mujoco_sweeps" / "piqp_setup_cost.json"
PATHS = ("setup", "update")


@contextlib.contextmanager
def held_update():
    """``solver.held_update_run`` (the held update this cost comparison measures against) in place of
    ``AdaptationQP._run`` inside the block."""
    from biped_controller.core.qp import solver as qs
    setup_run = qs.AdaptationQP._run
    qs.AdaptationQP._run = qs.held_update_run
    try:
        yield
    finally:
        qs.AdaptationQP._run = setup_run


def path(name: str):
    return held_update() if name == "update" else contextlib.nullcontext()


def instances(settings) -> list[tuple]:
    from biped_sim.plant.push import Push

    from biped_controller.core.qp.problem import constraint_values
    from biped_controller.closed_loop import runner
    out = []
    for mode, force in (("both", 600.0), ("both", -900.0), ("all", 700.0)):
        res = runner.run(4, mode, (Push(0.2315, 0.025, force),), sim_config=settings.sim_config(),
                         ctrl_config=settings.ctrl_config(mode), keep_qp=True)
        out += [(mode, G, h, xs) for G, h, xs, _ in res.qp_instances if np.any(constraint_values(G, xs, h) > 0)]
    return out


def time_qp(inst: list[tuple], repeats: int) -> float:
    """Mean wall time per ``AdaptationQP.solve`` [us] over ``inst`` x ``repeats`` (new solvers, warmed)."""
    from biped_controller.core.qp.solver import AdaptationQP
    qps = {m: AdaptationQP(3 if m == "all" else 2, next(G.shape[0] for mm, G, _, _ in inst if mm == m),
                           np.ones(3 if m == "all" else 2)) for m in {i[0] for i in inst}}
    for m, G, h, xs in inst:
        qps[m].solve(G, h, xs)
    gc.collect()
    gc.disable()
    try:
        t0 = time.perf_counter_ns()
        for _ in range(repeats):
            for m, G, h, xs in inst:
                qps[m].solve(G, h, xs)
        return (time.perf_counter_ns() - t0) / (repeats * len(inst)) / 1e3
    finally:
        gc.enable()


def time_map(settings, phases: int) -> tuple[float, float, int]:
    """(wall [s], CPU [s], simulations) of the map slice, from an empty loop pool and band cache."""
    from biped_controller.studies.capmap.driver import run_map
    from biped_controller.studies.capmap.executors import SerialExecutor
    from biped_controller.studies.capmap.spec import MapSpec, phases_of
    from biped_controller.studies.trial import controller, runs
    runs.loop_pool.cache_clear()
    controller._walk_band.cache_clear()
    spec = MapSpec(modes=("both",), phases=phases_of(phases), durations=(0.025,), settings=settings)
    gc.collect()
    c0, t0 = time.process_time(), time.perf_counter()
    out = run_map(spec, SerialExecutor())
    return time.perf_counter() - t0, time.process_time() - c0, out.simulated


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, default=OUT)
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--phases", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=20)
    a = ap.parse_args(argv)
    if a.rounds < 1 or a.phases < 1 or a.repeats < 1:
        ap.error("--rounds, --phases and --repeats must be >= 1")
    provenance.track(a.json, argv=argv, plant="mujoco")
    from biped_controller.studies.trial.settings import run_settings
    settings = run_settings(None, ["plant=mujoco"])
    inst = instances(settings)
    qp = {p: [] for p in PATHS}
    mp = {p: [] for p in PATHS}
    for r in range(a.rounds):
        for p in (PATHS if r % 2 == 0 else PATHS[::-1]):
            with path(p):
                qp[p].append(time_qp(inst, a.repeats))
                wall, cpu, n = time_map(settings, a.phases)
            mp[p].append({"wall_s": wall, "cpu_s": cpu, "simulations": n})
    out = {
        "instances": len(inst), "repeats": a.repeats, "rounds": a.rounds,
        "map_slice": {"modes": ["both"], "directions": ["forward", "backward"], "phases": a.phases,
                      "durations": [0.025], "plant": "mujoco"},
        "qp_us_per_solve": qp, "map": mp,
        "median": {p: {"qp_us_per_solve": statistics.median(qp[p]),
                       "map_wall_s": statistics.median(r["wall_s"] for r in mp[p]),
                       "map_cpu_s": statistics.median(r["cpu_s"] for r in mp[p])} for p in PATHS},
        "load_average_at_end": list(os.getloadavg()),
    }
    m = out["median"]
    out["setup_over_update"] = {k: m["setup"][k] / m["update"][k] for k in m["setup"]}
    print(json.dumps(out, indent=1))
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
