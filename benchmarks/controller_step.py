"""Section 1 of ``scripts/bench``: the controller's step [us] split into its pieces, on a replay of the
recorded hard run (section 0) through fresh controllers."""
from __future__ import annotations

import gc
import math
from time import perf_counter_ns

import numpy as np

from benchmarks.common import ctrl_cfg, pct, robot_files, sim_cfg


def bench_controller(records, min_steps: int, mode: str = "both") -> dict:
    """Replay the recorded states (t, q, q', stance) through fresh controllers.

    Pass A (unwrapped): AdaptiveController.compute per step -> total.
    Pass B (instrumented): the same replay with timers around the controller's named steps:
    _model_terms (A, H, B, h_b and the observer's torso Jacobian row: one compiled call with the fast
    engine), _qp_rows (the whole assembly of eq. 21) and AdaptationQP.solve; "observer" and "tail" are
    now inside those (reported as 0).
    Passes repeat the recording until >= min_steps steps each.
    """
    from biped_controller.core.control.controller import AdaptiveController
    from biped_model.description import LEFT

    (desc, family), scfg = robot_files(), sim_cfg()
    ccfg = ctrl_cfg(mode, period=scfg.control_period)
    states = [(r.t, np.array(r.q), np.array(r.qd), r.stance) for r in records]
    reps = max(1, math.ceil(min_steps / len(states)))

    ccfg_ref = ctrl_cfg(mode, period=scfg.control_period, engine="reference")

    def fresh(cfg=ccfg, compiled=True):
        c = AdaptiveController(cfg, family, desc)
        c.reset(LEFT)
        if not compiled:
            c._kernel = None     # the controller's Python steps (on the compiled model terms)
        return c

    # pass A: total only, the production path (fast engine: one compiled call per period, the QP when
    # x* is infeasible), the reference engine (Pinocchio, Python steps) interleaved replay by replay
    total, total_ref = [], []
    decisions = []
    gc.collect()
    for rep in range(reps):
        ctrl = fresh()
        for t, q, qd, st in states:
            t0 = perf_counter_ns()
            out = ctrl.compute(t, q, qd, st)
            total.append(perf_counter_ns() - t0)
            if rep == 0:
                decisions.append((out.status.p_ddot, out.status.tau_ddot, out.status.qp_status))
        if rep < 2:
            ctrl = fresh(ccfg_ref)
            for t, q, qd, st in states:
                t0 = perf_counter_ns()
                ctrl.compute(t, q, qd, st)
                total_ref.append(perf_counter_ns() - t0)
    # pass B: instrumented
    acc = {"model": 0, "rows": 0, "observer": 0, "qp": 0}
    keep = {}
    piece = {k: [] for k in ("model", "rows", "tail", "observer", "qp", "total_instr", "rest")}
    qp_called = []

    def wrap(obj, name, key, capture=False):
        f = getattr(obj, name)

        def w(*a, **k):
            t0 = perf_counter_ns()
            r = f(*a, **k)
            acc[key] += perf_counter_ns() - t0
            if capture:
                keep[key] = r
            return r
        setattr(obj, name, w)

    gc.collect()
    for rep in range(reps):
        ctrl = fresh(compiled=False)
        wrap(ctrl, "_model_terms", "model")        # A, H, B, h_b and the observer's Jacobian row
        wrap(ctrl, "_qp_rows", "rows")              # the whole assembly of eq. (21): G, h
        wrap(ctrl.qp, "solve", "qp", capture=True)
        for t, q, qd, st in states:
            for k in acc:
                acc[k] = 0
            keep.clear()
            t0 = perf_counter_ns()
            ctrl.compute(t, q, qd, st)
            tot = perf_counter_ns() - t0
            tail = 0   # part of _qp_rows since the controller's steps were split
            for k in acc:
                piece[k].append(acc[k])
            piece["tail"].append(tail)
            piece["total_instr"].append(tot)
            piece["rest"].append(tot - sum(acc.values()))
            qp_called.append(keep["qp"].status in (1, 2))
    us = lambda a: np.asarray(a, dtype=float) / 1000.0  # noqa: E731
    qp_called = np.array(qp_called)
    assembly = us(piece["rows"]) + us(piece["tail"])
    st = np.array([d[2] for d in decisions])
    res = {
        "steps_recorded": len(states), "replays": reps, "steps_timed": len(total),
        "qp_status_counts": {"unconstrained": int(np.sum(st == 0)), "active": int(np.sum(st == 1)),
                             "infeasible": int(np.sum(st == 2)), "solver_error": int(np.sum(st == 3))},
        "pieces_us": {
            "model_terms": pct(us(piece["model"])),
            "constraint_assembly": pct(assembly),
            "constraint_rows_only": pct(us(piece["rows"])),
            "assembly_tail_G_h": pct(us(piece["tail"])),
            "qp_solve_all_steps": pct(us(piece["qp"])),
            "qp_solve_piqp_called": pct(us(piece["qp"])[qp_called]),
            "qp_solve_x_star_feasible": pct(us(piece["qp"])[~qp_called]),
            "observer_jacobian": pct(us(piece["observer"])),
            "rest_of_compute": pct(us(piece["rest"])),
            "total_instrumented": pct(us(piece["total_instr"])),
            "total": pct(us(total)),
            "total_reference_engine": pct(us(total_ref)),
        },
        "decisions": decisions,
    }
    return res
