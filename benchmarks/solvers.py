"""Section 2 of ``scripts/bench``: small-QP solvers side by side [us per solve] on the QP instances of the
hard run's probes (section 0), each answer checked against the exact solver before it is timed."""
from __future__ import annotations

import gc
import math
from time import perf_counter_ns

import numpy as np

from biped_controller.core.control.controller_layout import QP_ROWS

from benchmarks.common import MATCH_TOL, pct


SOLVER_KW = {
    "daqp": {},
    "quadprog": {},
    "osqp": {"eps_abs": 1e-10, "eps_rel": 1e-10, "max_iter": 20000, "polish": True},
    "proxqp": {"eps_abs": 1e-10, "eps_rel": 0.0},
    "piqp": {},
}


def _solvers(W):
    from biped_controller.core.qp.solver import AdaptationQP, solve_with_qpsolvers
    from biped_controller.core.qp.exact import solve_exact

    held = AdaptationQP(len(W), QP_ROWS, W)   # the controller's production object
    out = {
        "exact (qp_exact)": lambda G, h, x: solve_exact(G, h, x, W),
        "PIQP held (AdaptationQP)": lambda G, h, x: held.solve(G, h, x),
        "PIQP via qpsolvers": lambda G, h, x: solve_with_qpsolvers(G, h, x, W, "piqp", **SOLVER_KW["piqp"]),
    }
    for name, key in (("DAQP", "daqp"), ("quadprog", "quadprog"), ("OSQP", "osqp"), ("ProxQP", "proxqp")):
        out[f"{name} via qpsolvers"] = (lambda k: lambda G, h, x: solve_with_qpsolvers(G, h, x, W, k, **SOLVER_KW[k]))(key)
    return out


def bench_solvers(instances, W, min_samples: int, max_repeats: int) -> dict:
    from biped_controller.core.qp.exact import solve_exact

    constrained, unconstrained, forces = [], 0, set()
    for F, (G, h, xs, _status) in instances:
        if np.all(G @ xs - h <= 0.0):
            unconstrained += 1
            continue
        constrained.append((F, G, h, xs))
        forces.add(F)
    solvers = _solvers(W)
    names = list(solvers)
    times = {n: [] for n in names}
    fails = {n: 0 for n in names}
    fail_detail = {n: [] for n in names}
    n_inf = 0
    reps = 0
    if constrained:
        reps = int(min(max_repeats, max(1, math.ceil(min_samples / len(constrained)))))
    gc.collect()
    for F, G, h, xs in constrained:
        ex = solve_exact(G, h, xs, W)
        n_inf += int(ex.status == 2)
        scale = max(1.0, float(np.max(np.abs(ex.x))))
        ok = {}
        for n in names:
            try:
                r = solvers[n](G, h, xs)
                err = float(np.max(np.abs(r.x - ex.x)))
            except Exception as exc:  # noqa: BLE001
                err, r = math.inf, None
                fail_detail[n].append(f"{type(exc).__name__}: {exc}")
            ok[n] = err <= MATCH_TOL * scale
            if not ok[n]:
                fails[n] += 1
                if len(fail_detail[n]) < 5:
                    fail_detail[n].append(f"F={F} |dx|={err:.3g} status={getattr(r, 'status', None)}")
        # side by side: round-robin over the solvers, reps times
        for _ in range(reps):
            for n in names:
                if not ok[n]:
                    continue
                f = solvers[n]
                t0 = perf_counter_ns()
                f(G, h, xs)
                times[n].append(perf_counter_ns() - t0)
    table = {}
    for n in names:
        table[n] = {**pct(np.asarray(times[n], dtype=float) / 1000.0), "failures": fails[n],
                    "failure_examples": fail_detail[n]}
    correct = [n for n in names if fails[n] == 0 and table[n]["n"]] or [n for n in names if table[n]["n"]]
    fastest = min(correct, key=lambda n: table[n]["p50"]) if correct else None
    for n in names:
        p = table[n]["p50"]
        table[n]["ratio_to_fastest"] = (p / table[fastest]["p50"]) if (fastest and p) else None
    # unconstrained instances: what the production object costs when x* is feasible (no solver call)
    from biped_controller.core.qp.solver import AdaptationQP
    held = AdaptationQP(len(W), QP_ROWS, W)
    un_t = []
    k = 0
    for F, (G, h, xs, _s) in instances:
        if np.all(G @ xs - h <= 0.0):
            t0 = perf_counter_ns()
            held.solve(G, h, xs)
            un_t.append(perf_counter_ns() - t0)
            k += 1
            if k >= min_samples:
                break
    return {"instances_total": len(instances), "instances_constrained": len(constrained),
            "instances_infeasible": n_inf, "instances_unconstrained": unconstrained,
            "repeats_per_instance": reps, "forces_contributing": sorted(forces), "match_tol": MATCH_TOL,
            "solver_settings": SOLVER_KW, "fastest_correct": fastest, "table_us": table,
            "unconstrained_early_out_us": pct(np.asarray(un_t, dtype=float) / 1000.0)}
