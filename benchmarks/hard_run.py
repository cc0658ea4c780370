"""Section 0 of ``scripts/bench``: the recorded hard run, the largest forward push (25 ms at t = 0.2315 s,
mode both) that does not fall, found by bisection; its periods are the controller replay of section 1, its QP
instances the solver comparison of section 2."""
from __future__ import annotations

import time

import numpy as np

from benchmarks.common import PUSH_DURATION, PUSH_START, ctrl_cfg, log, robot_files, sim_cfg


def push_run(force: float, steps: int, mode: str = "both", keep_qp: bool = True):
    from biped_controller.closed_loop.runner import run
    from biped_sim.plant.push import Push
    scfg = sim_cfg()
    desc, family = robot_files()
    return run(steps=steps, mode=mode, pushes=(Push(PUSH_START, PUSH_DURATION, force),), keep_qp=keep_qp,
               sim_config=scfg, ctrl_config=ctrl_cfg(mode, period=scfg.control_period), family=family, desc=desc)


def qp_counts(res) -> dict:
    st = np.array([q[3] for q in res.qp_instances], dtype=int)
    return {k: int(np.sum(st == v)) for k, v in (("unconstrained", 0), ("active", 1), ("infeasible", 2),
                                                  ("solver_error", 3))}


def find_hard_run(quick: bool) -> dict:
    """Largest forward push (start 0.2315 s, 25 ms, mode both) that does not fall within ``steps`` impacts,
    by bisection: a QP workload for the solver comparison, not a survival trial (``info["survived"]`` is
    "did not fall"; the survival rule of the studies is ``trial.survival``).

    Each probe runs with keep_qp=True; the QP instances of every probe (surviving or not) are
    kept for the solver comparison, tagged with their force.
    """
    probes, instances = [], []
    if quick:
        lo, hi, iters, steps = 40.0, 40.0, 0, 1
    else:
        lo, hi, iters, steps = 0.0, 100.0, 8, 3
    def probe(F, st):
        t0 = time.perf_counter()
        r = push_run(F, st)
        info = {"force": F, "steps": st, "survived": not r.fallen, "fall_cause": r.fall_cause,
                "periods": len(r.records), "wall_s": time.perf_counter() - t0, **qp_counts(r)}
        probes.append(info)
        instances.extend((F, q) for q in r.qp_instances)
        log(f"probe F={F:.2f} N: {'survived' if info['survived'] else 'fell (' + r.fall_cause + ')'}, "
            f"active QPs {info['active']}, infeasible {info['infeasible']}")
        return r
    if quick:   # one falling probe: active (and possibly infeasible) QPs for the solver table
        probe(100.0, 1)
    else:
        r = probe(hi, steps)
        while not r.fallen and hi < 3200.0:   # upper edge not bracketed yet: double
            lo, hi = hi, 2.0 * hi
            r = probe(hi, steps)
        for _ in range(iters):
            if hi - lo < 0.5:
                break
            mid = round(0.5 * (lo + hi), 2)
            r = probe(mid, steps)
            if r.fallen:
                hi = mid
            else:
                lo = mid
    return {"force": lo, "probes": probes, "instances": instances, "bracket": [lo, hi]}
