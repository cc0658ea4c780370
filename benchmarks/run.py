"""Benchmarks of the controller, the adaptation QP, the DDS lockstep and the in-process loop.

    python -m benchmarks.run [--quick] [--json FILE] [--md FILE]

Writes results/benchmarks/results.json (or --json) and results/benchmarks/results.md (or beside --json),
each with its provenance record (results/README.md). ``keys`` holds the stable dotted keys of this run's
sections and, merged from the sub-benchmarks' own files (:data:`SUB_BENCHMARKS`, read from
``--sub-results``), the keys those separate runs produced; ``merged`` names each such file with its date.
Every timing is a median (p50) and a
99th percentile (p99) of per-call times measured with time.perf_counter_ns; the ratios compare
figures measured side by side in this one run (the machine is shared and noisy). Targets are
printed beside the results, never asserted. ``--quick``: a few hundred steps / instances (tests).
"""
from __future__ import annotations

import argparse
import gc
import importlib.util
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from time import perf_counter_ns

import numpy as np

from biped_controller.core.control.controller_layout import QP_ROWS
from biped_controller.studies import provenance
from biped_controller.studies.trial.args import controller_arg

ROOT = Path(__file__).resolve().parents[1]

#: The run's named profile (``--profile``), as the studies' settings: its controller and simulator settings
#: apply to every controller and plant the bench builds (sections 0, 1, 2 and 4); the bench's own variants (the
#: engine, ``plant: mujoco`` for the MuJoCo rows) are set over it. None until :func:`main` parses it.
_SETTINGS = None


def _ctrl_cfg(mode: str, **kw):
    """``load_controller_config`` with the profile's controller settings, then ``kw``."""
    from biped_controller.core.control.config import load_controller_config
    base = dict(_SETTINGS.controller) if _SETTINGS is not None else {}
    return load_controller_config(**{**base, "mode": mode, **kw})


def _sim_cfg(**kw):
    """``load_sim_config`` with the profile's simulator settings (its ``plant`` too, unless ``kw`` names one)."""
    from biped_sim.plant.config import load_sim_config
    base = dict(_SETTINGS.simulator) if _SETTINGS is not None else {}
    return load_sim_config(**{**base, **kw})
if str(ROOT) not in sys.path:  # `python benchmarks/run.py`
    sys.path.insert(0, str(ROOT))
from benchmarks import RESULTS_DIR  # noqa: E402  (after the path above)

PUSH_START, PUSH_DURATION = 0.2315, 0.025
MATCH_TOL = 1e-6
TARGETS = {
    "controller_step_p50_us": 30.0,
    "production_qp_vs_fastest_ratio": 1.5,
    "lockstep_vs_pingpong_fraction": 0.90,
    "lockstep_rate_hz": 1000.0,
    "inprocess_realtime_factor": 50.0,
    "max_push_table_s": 30.0,
    "sweep_map_full_wall_s": 60.0,
}


def log(msg: str) -> None:
    print(f"bench: {msg}", file=sys.stderr, flush=True)


def pct(a) -> dict:
    a = np.asarray(a, dtype=float)
    if a.size == 0:
        return {"n": 0, "p50": None, "p99": None, "mean": None}
    return {"n": int(a.size), "p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
            "mean": float(a.mean())}


# ------------------------------------------------------------------------------------------------
# 0. the recorded hard run
# ------------------------------------------------------------------------------------------------

def _push_run(force: float, steps: int, mode: str = "both", keep_qp: bool = True):
    from biped_controller.closed_loop.runner import run
    from biped_sim.plant.push import Push
    scfg = _sim_cfg()
    return run(steps=steps, mode=mode, pushes=(Push(PUSH_START, PUSH_DURATION, force),), keep_qp=keep_qp,
               sim_config=scfg, ctrl_config=_ctrl_cfg(mode, period=scfg.control_period))


def _qp_counts(res) -> dict:
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
        r = _push_run(F, st)
        info = {"force": F, "steps": st, "survived": not r.fallen, "fall_cause": r.fall_cause,
                "periods": len(r.records), "wall_s": time.perf_counter() - t0, **_qp_counts(r)}
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


# ------------------------------------------------------------------------------------------------
# 1. controller step split
# ------------------------------------------------------------------------------------------------

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
    from biped_model.gait_family import GaitFamily
    from biped_model.description import LEFT, load_description

    desc, family, scfg = load_description(), GaitFamily.load(), _sim_cfg()
    ccfg = _ctrl_cfg(mode, period=scfg.control_period)
    states = [(r.t, np.array(r.q), np.array(r.qd), r.stance) for r in records]
    reps = max(1, math.ceil(min_steps / len(states)))

    ccfg_ref = _ctrl_cfg(mode, period=scfg.control_period, engine="reference")

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


# ------------------------------------------------------------------------------------------------
# 2. small-QP solvers side by side
# ------------------------------------------------------------------------------------------------

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


# ------------------------------------------------------------------------------------------------
# 3. DDS: bare ping-pong and the node lockstep
# ------------------------------------------------------------------------------------------------

class Domain:
    """A free ROS_DOMAIN_ID from domain_coordinator (port lock) for the duration of the block."""

    def __enter__(self):
        self._cm = None
        try:
            from domain_coordinator import domain_id
            self._cm = domain_id()
            did = self._cm.__enter__()
        except Exception:  # noqa: BLE001
            did = 101 + os.getpid() % 100
        env = dict(os.environ)
        env.update(ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        env.pop("ROS_STATIC_PEERS", None)
        env.pop("ROS_LOCALHOST_ONLY", None)
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        self.env, self.id = env, did
        return self

    def __exit__(self, *exc):
        if self._cm is not None:
            self._cm.__exit__(*exc)


def bench_pingpong(count: int) -> dict:
    with Domain() as dom:
        pong = subprocess.Popen([sys.executable, "-m", "benchmarks.pingpong", "pong", "--timeout", "10"],
                                cwd=ROOT, env=dom.env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            p = subprocess.run([sys.executable, "-m", "benchmarks.pingpong", "ping", "--count", str(count),
                                "--warmup", "200"], cwd=ROOT, env=dom.env, capture_output=True, text=True,
                               timeout=120 + count / 100)
        finally:
            pong.terminate()
            try:
                pong.wait(5)
            except subprocess.TimeoutExpired:
                pong.kill()
                pong.wait()
        lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
        if p.returncode != 0 or not lines:
            return {"available": False, "error": (p.stdout + p.stderr)[-500:], "domain_id": dom.id}
        out = json.loads(lines[-1])
        out.update(available=True, domain_id=dom.id)
        return out


def bench_lockstep(seconds: float, pingpong: dict | None) -> dict:
    mods = ("biped_sim.graph.simulator_node", "biped_controller.graph.controller_node")
    missing = [m for m in mods if importlib.util.find_spec(m) is None]
    if missing:
        return {"available": False, "reason": f"not available: {', '.join(missing)} not written yet"}
    from benchmarks.lockstep import measure
    try:
        res = measure(seconds, Domain)
    except Exception as exc:  # noqa: BLE001
        return {"available": False, "reason": f"not available: {type(exc).__name__}: {exc}"}
    if res.get("available") and pingpong and pingpong.get("available"):
        res["fraction_of_pingpong"] = res["steps_per_s"] / pingpong["rate_hz"]
    from benchmarks.lockstep import measure_with_recorder
    try:
        res["with_recorder"] = measure_with_recorder(seconds, Domain)
    except Exception as exc:  # noqa: BLE001
        res["with_recorder"] = {"available": False, "reason": f"not available: {type(exc).__name__}: {exc}"}
    return res


# ------------------------------------------------------------------------------------------------
# 4. in-process simulation speed
# ------------------------------------------------------------------------------------------------

def bench_inprocess(steps: int, repeats: int = 2) -> dict:
    """In-process closed loop (runner.run), sim time / wall time, per engine and mode, the engines
    interleaved in the same run (the machine's speed varies: compare ratios). The first fast run of a
    process loads the compiled kernels: a warm-up run of each engine comes first and is not timed."""
    from biped_controller.closed_loop.runner import run

    variants = {   # name: (engine, runner.run keywords)
        "fast": ("fast", {}),                                       # compiled loop, every record kept
        "fast_outcome_only": ("fast", {"keep_records": False}),     # compiled loop, outcome only (the sweeps)
        "fast_objects": ("fast", {"compiled_loop": False}),         # compiled kernels, objects every period
        "reference": ("reference", {}),                             # Pinocchio, Python
        "mujoco": ("mujoco", {}),                                   # the MuJoCo plant, its compiled loop
        "mujoco_objects": ("mujoco", {"compiled_loop": False}),     # the MuJoCo plant, objects every period
    }

    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily
    desc, family = load_description(), GaitFamily.load()
    configs = {(e, m): (_sim_cfg(engine=e, plant="rigid"), _ctrl_cfg(m, engine=e))
               for e in ("fast", "reference") for m in ("none", "both")}
    for m in ("none", "both"):   # the MuJoCo plant with the fast engine's controller (its compiled period)
        configs[("mujoco", m)] = (_sim_cfg(engine="fast", plant="mujoco"), configs[("fast", m)][1])

    def one(variant, mode, n):
        """The closed loop only: the robot, the family and the settings are read before the clock starts
        (reading the YAML files costs ~10 ms, a tenth of a 5-step run on the fast engine)."""
        engine, kw = variants[variant]
        scfg, ccfg = configs[(engine, mode)]
        gc.collect()    # the previous runs' records are garbage: their collection is not this run's time
        c0, t0 = time.process_time(), time.perf_counter()
        r = run(steps=n, mode=mode, sim_config=scfg, ctrl_config=ccfg, desc=desc, family=family, **kw)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        sim_t = r.records[-1].t_end
        return r, sim_t, wall, cpu

    for v in variants:
        one(v, "both", 1)
    out: dict = {v: {} for v in variants}
    for mode in ("none", "both"):
        acc = {e: [0.0, 0.0, None, 0.0] for e in out}
        for _ in range(repeats):
            for engine in out:
                r, sim_t, wall, cpu = one(engine, mode, steps)
                acc[engine][0] += sim_t
                acc[engine][1] += wall
                acc[engine][2] = (r.steps_walked, r.fallen)   # not the records: they would stay alive
                acc[engine][3] += cpu
                del r
        for engine, (sim_t, wall, (walked, fallen), cpu) in acc.items():
            periods = round(sim_t / repeats / 1e-3)   # 1 ms periods (the outcome-only run keeps few records)
            # CPU time of this process beside the wall time: on a machine shared with other jobs the wall time
            # counts their time slices too, the CPU time (user + system) only this loop's
            out[engine][mode] = {"steps_walked": walked, "fallen": fallen, "periods": periods,
                                 "sim_s": sim_t, "wall_s": wall, "realtime_factor": sim_t / wall,
                                 "us_per_period": wall / (periods * repeats) * 1e6,
                                 "cpu_s": cpu, "realtime_factor_cpu": sim_t / cpu}
    for engine in out:
        out[engine]["realtime_factor"] = out[engine]["both"]["realtime_factor"]
    out["fast_over_reference"] = out["fast"]["realtime_factor"] / out["reference"]["realtime_factor"]
    out["mujoco_over_fast_objects"] = out["mujoco"]["realtime_factor"] / out["fast_objects"]["realtime_factor"]
    out["mujoco_over_mujoco_objects"] = out["mujoco"]["realtime_factor"] / out["mujoco_objects"]["realtime_factor"]
    out["mujoco_over_fast_objects_cpu"] = (out["mujoco"]["both"]["realtime_factor_cpu"]
                                           / out["fast_objects"]["both"]["realtime_factor_cpu"])
    # legacy layout (mode -> figures) for the README table: the default engine
    out["none"], out["both"] = out["fast"]["none"], out["fast"]["both"]
    return out


# ------------------------------------------------------------------------------------------------
# 5. max-push table
# ------------------------------------------------------------------------------------------------

def bench_experiment(quick: bool) -> dict:
    if importlib.util.find_spec("biped_controller.studies.experiment") is None:
        return {"available": False, "reason": "not available: biped_controller.studies.experiment not written yet"}
    from benchmarks.experiment_bench import time_table
    if quick:   # the table takes minutes even with coarse settings: only check the API is there
        import inspect
        from biped_controller.studies.trial import search
        sig = inspect.signature(search.max_push_modes)
        missing = [k for k in ("resolution", "fmax", "coarse", "workers", "progress") if k not in sig.parameters]
        return {"available": False, "reason": "skipped in --quick" + (f" (API changed: {missing})" if missing else "")}
    try:
        return time_table(quick)
    except Exception as exc:  # noqa: BLE001
        return {"available": False, "reason": f"not available: {type(exc).__name__}: {exc}"}


# ------------------------------------------------------------------------------------------------
# report
# ------------------------------------------------------------------------------------------------

def _f(x, nd=1):
    return "n/a" if x is None else (f"{x:.{nd}f}" if isinstance(x, (int, float)) else str(x))


def markdown(R: dict) -> str:
    L = []
    meta = R["meta"]
    L.append(f"Run {meta['date']} on {meta['cpus']} CPUs ({meta['machine']}), "
             f"{'quick' if meta['quick'] else 'full'} mode, {meta['wall_s']:.0f} s. "
             "p50/p99 of per-call times (time.perf_counter_ns); ratios are side by side in this run. "
             "Targets are printed, never asserted.")
    L.append("")
    c = R["controller"]
    hr = R["hard_run"]
    L.append(f"**1. Controller step** (mode `both`), replay of the hard run: push {hr['force']:.2f} N at "
             f"t = {PUSH_START} s for {PUSH_DURATION * 1000:.0f} ms (largest survived; bracket "
             f"{hr['bracket'][0]:.2f}-{hr['bracket'][1]:.2f} N), {c['steps_recorded']} periods x "
             f"{c['replays']} replays = {c['steps_timed']} steps; QP status over the run: "
             + ", ".join(f"{k} {v}" for k, v in c["qp_status_counts"].items()) + ".")
    L.append("")
    L.append("The pieces are the controller's Python steps on the compiled model terms (the compiled period "
             "replaced by them, timers around each); the production path is the compiled period (last rows).")
    L.append("")
    L.append("| piece | p50 [us] | p99 [us] | steps |")
    L.append("| --- | ---: | ---: | ---: |")
    labels = [("model_terms", "model terms (FixedFootModel.dynamics: A, H, reaction rows)"),
              ("constraint_assembly", "constraint assembly (eq. 21: _constraint_rows + G = A D, h)"),
              ("constraint_rows_only", "  of which _constraint_rows"),
              ("assembly_tail_G_h", "  of which G = A D, h, range rows"),
              ("qp_solve_all_steps", "QP solve (AdaptationQP.solve), all steps"),
              ("qp_solve_piqp_called", "  steps where PIQP ran"),
              ("qp_solve_x_star_feasible", "  steps with x* feasible (no solver call)"),
              ("observer_jacobian", "disturbance-observer jacobian"),
              ("rest_of_compute", "rest of compute (reference, status, margins, ...)"),
              ("total_instrumented", "  total of these Python steps (timers in place)"),
              ("total", f"**total AdaptiveController.compute, fast engine: compiled period** (target p50 <= "
                        f"{TARGETS['controller_step_p50_us']:.0f})"),
              ("total_reference_engine", "total AdaptiveController.compute, reference engine (Pinocchio)")]
    for k, lab in labels:
        p = c["pieces_us"][k]
        L.append(f"| {lab} | {_f(p['p50'])} | {_f(p['p99'])} | {p['n']} |")
    L.append("")
    s = R["solvers"]
    L.append(f"**2. Small-QP solvers** on the QPs recorded from the push probes "
             f"({s['instances_total']} instances: {s['instances_constrained']} constrained, of which "
             f"{s['instances_infeasible']} infeasible, from forces {', '.join(f'{x:g}' for x in s['forces_contributing'])} N; "
             f"{s['instances_unconstrained']} with x* feasible are skipped — they never call a solver: "
             f"AdaptationQP early-out p50 {_f(s['unconstrained_early_out_us']['p50'], 2)} us). "
             f"Each answer checked against the exact solver (|dx| <= {MATCH_TOL:g} max(1, |x|)) before "
             f"timing; {s['repeats_per_instance']} timed calls per instance, round-robin.")
    L.append("")
    L.append("| solver | p50 [us] | p99 [us] | ratio to fastest correct | failures | calls timed |")
    L.append("| --- | ---: | ---: | ---: | ---: | ---: |")
    for n, row in sorted(s["table_us"].items(), key=lambda kv: (kv[1]["p50"] is None, kv[1]["p50"] or 0)):
        L.append(f"| {n} | {_f(row['p50'])} | {_f(row['p99'])} | {_f(row['ratio_to_fastest'], 2)} | "
                 f"{row['failures']} | {row['n']} |")
    prod = s["table_us"].get("PIQP held (AdaptationQP)", {})
    L.append("")
    L.append(f"Production QP (PIQP held) p50 is {_f(prod.get('ratio_to_fastest'), 2)}x the fastest correct "
             f"({s['fastest_correct']}); target <= {TARGETS['production_qp_vs_fastest_ratio']}x.")
    L.append("")
    d = R["dds"]
    pp, ls = d["pingpong"], d["lockstep"]
    L.append("**3. DDS lockstep** (1 kHz control period, isolated ROS_DOMAIN_ID, LOCALHOST discovery)")
    L.append("")
    L.append("| loop | rate [steps/s] | real-time factor | round trip p50 [us] | p99 [us] |")
    L.append("| --- | ---: | ---: | ---: | ---: |")
    if pp.get("available"):
        L.append(f"| bare rclpy ping-pong (SimState -> JointState, 2 processes) | {_f(pp['rate_hz'], 0)} | "
                 f"{_f(pp['rate_hz'] / 1000.0, 2)} | {_f(pp['rtt_p50_us'])} | {_f(pp['rtt_p99_us'])} |")
    else:
        L.append(f"| bare rclpy ping-pong | failed: {pp.get('error', '')[:80]} | | | |")
    if ls.get("available"):
        L.append(f"| simulator_node + controller_node | {_f(ls['steps_per_s'], 0)} | "
                 f"{_f(ls['realtime_factor'], 2)} | {_f(ls.get('period_p50_us'))} | {_f(ls.get('period_p99_us'))} |")
        wr = ls.get("with_recorder") or {}
        if wr.get("available"):
            L.append(f"| the whole recorded graph (launch: + recorder, disturbance) | {_f(wr['steps_per_s'], 0)} | "
                     f"{_f(wr['realtime_factor'], 2)} | n/a | n/a |")
        else:
            L.append(f"| the whole recorded graph | {wr.get('reason', 'not measured')[:80]} | | | |")
        L.append("")
        L.append(f"Lockstep / ping-pong = {_f(ls.get('fraction_of_pingpong'), 2)} (target >= "
                 f"{TARGETS['lockstep_vs_pingpong_fraction']:.2f}, and >= 1 kHz).")
    else:
        L.append(f"| simulator_node + controller_node | {ls.get('reason', 'not available')} | | | |")
        L.append("")
        L.append(f"Targets: lockstep >= {TARGETS['lockstep_vs_pingpong_fraction']:.0%} of the ping-pong and >= 1 kHz.")
    L.append("")
    ip = R["inprocess"]
    L.append(f"**4. In-process loop** (runner.run, no push, engines interleaved in the same run; target >= "
             f"{TARGETS['inprocess_realtime_factor']:.0f}x real time): fast / reference = "
             f"{_f(ip.get('fast_over_reference'), 2)}")
    L.append("")
    L.append("Variants: `fast` = compiled loop (loop_kernels: many periods per call, the QP periods decided "
             "between two calls; the objects take the impacts, the falls and hybrid's QP periods), every record "
             "kept (runner.run's default); "
             "`fast_outcome_only` = the same with keep_records=False (what survival sweeps run); `fast_objects` = "
             "compiled kernels, the Python objects every period (compiled_loop=False); `reference` = Pinocchio; "
             "`mujoco` = the MuJoCo plant (`plant: mujoco`; target >= 20x in mode both) on its compiled loop "
             "(mujoco_loop_kernels: the controller's compiled period and the MuJoCo steps, many periods per call; "
             "the plant's Python finishes the touchdowns and falls), every record kept; `mujoco_objects` = the same "
             "plant with the objects every period (its MuJoCo steps one compiled call per period): "
             f"mujoco / fast_objects = {_f(ip.get('mujoco_over_fast_objects'), 2)} "
             f"(by CPU time {_f(ip.get('mujoco_over_fast_objects_cpu'), 2)}). CPU s: this process's user + system "
             "time, which on a shared machine leaves out the other jobs' time slices that the wall time counts.")
    L.append("")
    L.append("| variant | mode | simulated s | wall s | sim s / wall s | us per 1 ms period | CPU s | sim s / CPU s |")
    L.append("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for engine in ("fast", "fast_outcome_only", "fast_objects", "reference", "mujoco", "mujoco_objects"):
        if engine not in ip:
            continue
        for mode in ("none", "both"):
            v = ip[engine][mode]
            L.append(f"| {engine} | {mode} | {_f(v['sim_s'], 3)} | {_f(v['wall_s'], 2)} | "
                     f"{_f(v['realtime_factor'], 2)} | {_f(v['us_per_period'], 0)} | {_f(v.get('cpu_s'), 2)} | "
                     f"{_f(v.get('realtime_factor_cpu'), 2)} |")
    L.append("")
    e = R["experiment"]
    L.append(f"**5. Four-mode max-push table** (target <= {TARGETS['max_push_table_s']:.0f} s on 2 cores): "
             + (f"serial {_f(e['serial_s'])} s, parallel ({e['workers']} processes) {_f(e['parallel_s'])} s."
                if e.get("available") else e.get("reason", "not available") + "."))
    sw = R.get("sweep") or {}
    if sw.get("available"):
        L.append("")
        L.append(f"**6. Sweep**: {'a 2-phase map' if sw['quick'] else 'the default capability map'} "
                 f"({sw['cells']} cells, {sw['workers']} processes, early stop + bracketed search): "
                 f"{sw['simulations']} simulations in {_f(sw['wall_s'])} s = {_f(sw['sims_per_s'], 1)} sims/s "
                 f"(target <= {TARGETS['sweep_map_full_wall_s']:.0f} s for the full map; load average "
                 f"{sw['load_average_before'][0]:.1f} at the start).")
    return "\n".join(L) + "\n"


SUB_BENCHMARKS = ("wbc_step.json", "model_error.json", "estimation.json", "torso_step.json", "plugin.json")


def merge_sub_benchmarks(R: dict, directory: Path) -> dict:
    """Merge into ``R["keys"]`` the ``keys`` of each sub-benchmark file of :data:`SUB_BENCHMARKS` found in
    ``directory`` (separate runs: benchmarks/wbc_step.py, model_error_bench.py, estimation_bench.py,
    torso_step.py); a key this run produced itself is never replaced. Returns ``R["merged"]``: file name ->
    its path, date and the keys taken from it."""
    merged = {}
    keys = R.setdefault("keys", {})
    for name in SUB_BENCHMARKS:
        p = Path(directory) / name
        if not p.is_file():
            continue
        sub = json.loads(p.read_text(encoding="utf-8"))
        taken = {k: v for k, v in (sub.get("keys") or {}).items() if k not in keys}
        keys.update(taken)
        meta = sub.get("meta") if isinstance(sub.get("meta"), dict) else {}
        merged[name] = {"path": str(p), "date": meta.get("date") or sub.get("when") or sub.get("date"),
                        "keys": sorted(taken)}
    R["merged"] = merged
    return merged


def stable_keys(R: dict) -> dict:
    """The figures of issues 11 and 19 under stable dotted keys (None when a part was not available)."""
    from benchmarks.sweep_bench import keys as sweep_keys
    def get(*path):
        node = R
        for k in path:
            if not isinstance(node, dict) or k not in node:
                return None
            node = node[k]
        return node
    ls, pp, e = get("dds", "lockstep") or {}, get("dds", "pingpong") or {}, R.get("experiment") or {}
    return {
        "inprocess.fast.realtime_factor": get("inprocess", "fast", "realtime_factor"),
        "inprocess.reference.realtime_factor": get("inprocess", "reference", "realtime_factor"),
        "inprocess.fast_outcome_only.realtime_factor": get("inprocess", "fast_outcome_only", "realtime_factor"),
        "inprocess.mujoco.realtime_factor": get("inprocess", "mujoco", "realtime_factor"),
        "inprocess.mujoco.realtime_factor_cpu": get("inprocess", "mujoco", "both", "realtime_factor_cpu"),
        "inprocess.mujoco_over_fast_objects": get("inprocess", "mujoco_over_fast_objects"),
        "inprocess.mujoco_over_fast_objects_cpu": get("inprocess", "mujoco_over_fast_objects_cpu"),
        "controller.step_p50_us_reference_engine": get("controller", "pieces_us", "total_reference_engine", "p50"),
        "controller.step_p50_us": get("controller", "pieces_us", "total", "p50"),
        "qp.early_out_p50_us": get("qp_bench", "early_out_p50_us"),
        "qp.piqp_ratio_to_fastest": get("qp_bench", "piqp_ratio_to_fastest"),
        "dds.lockstep_steps_per_s": ls.get("steps_per_s") if ls.get("available") else None,
        "dds.pingpong_steps_per_s": pp.get("rate_hz") if pp.get("available") else None,
        "dds.lockstep_with_recorder_steps_per_s": (ls.get("with_recorder") or {}).get("steps_per_s"),
        "table.parallel_wall_s": e.get("parallel_s") if e.get("available") else None,
        **sweep_keys(R.get("sweep") or {"available": False}),
    }


def inprocess_only(json_path: Path, steps: int = 5, repeats: int = 3) -> int:
    """Section 4 alone, merged into ``json_path`` (``--inprocess-only``): every variant interleaved in one run,
    the load average (1 min) before and after it recorded beside the figures."""
    load0 = os.getloadavg()[0]
    date = time.strftime("%Y-%m-%d %H:%M:%S")
    t0 = time.perf_counter()
    ip = bench_inprocess(steps, repeats)
    meta = {"date": date, "steps": steps, "repeats": repeats, "cpus": os.cpu_count(),
            "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
            "loadavg_1min_before": load0, "loadavg_1min_after": os.getloadavg()[0],
            "wall_s": time.perf_counter() - t0}
    R = json.loads(json_path.read_text(encoding="utf-8")) if json_path.exists() else {}
    R["inprocess_side_by_side"] = {"meta": meta, **{k: v for k, v in ip.items() if k not in ("none", "both")}}
    keys = R.setdefault("keys", {})
    for v in ("fast", "fast_objects", "mujoco", "mujoco_objects"):
        keys[f"inprocess_side_by_side.{v}.realtime_factor"] = ip[v]["realtime_factor"]
        keys[f"inprocess_side_by_side.{v}.realtime_factor_cpu"] = ip[v]["both"]["realtime_factor_cpu"]
    keys["inprocess.mujoco.realtime_factor"] = ip["mujoco"]["realtime_factor"]
    keys["inprocess.mujoco.realtime_factor_cpu"] = ip["mujoco"]["both"]["realtime_factor_cpu"]
    keys["inprocess.mujoco_over_fast_objects"] = ip["mujoco_over_fast_objects"]
    keys["inprocess.mujoco_over_mujoco_objects"] = ip["mujoco_over_mujoco_objects"]
    keys["inprocess.mujoco_over_fast_objects_cpu"] = ip["mujoco_over_fast_objects_cpu"]
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(R, indent=1, default=float) + "\n", encoding="utf-8")
    print(f"in-process loop, mode both, {date}, load average {load0:.1f} -> {meta['loadavg_1min_after']:.1f} "
          f"on {meta['cpus']} CPUs:")
    print("| variant | sim s / wall s | us per period (wall) | sim s / CPU s | us per period (CPU) |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for v in ("fast", "fast_outcome_only", "fast_objects", "reference", "mujoco", "mujoco_objects"):
        b = ip[v]["both"]
        print(f"| {v} | {b['realtime_factor']:.2f} | {b['us_per_period']:.0f} | {b['realtime_factor_cpu']:.2f} | "
              f"{b['cpu_s'] / (b['periods'] * repeats) * 1e6:.0f} |")
    print(f"mujoco / fast_objects: wall {ip['mujoco_over_fast_objects']:.3f}, CPU {ip['mujoco_over_fast_objects_cpu']:.3f}")
    print(f"mujoco / mujoco_objects: wall {ip['mujoco_over_mujoco_objects']:.3f}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="biped benchmarks")
    ap.add_argument("--quick", action="store_true", help="a few hundred steps / instances")
    ap.add_argument("--json", default=None,
                    help="default results/benchmarks/results.json (with --controller: results/benchmarks/plugin.json)")
    ap.add_argument("--md", default=None, help="Markdown table (default: results.md beside the JSON)")
    ap.add_argument("--sub-results", type=Path, default=RESULTS_DIR,
                    help="directory of the sub-benchmarks' files whose keys are merged (default: %(default)s)")
    ap.add_argument("--inprocess-only", action="store_true",
                    help="section 4 alone (the MuJoCo plant beside the rigid one): merged into the JSON as "
                         "'inprocess_side_by_side' with its own date and load average, with the keys "
                         "inprocess.mujoco.*; the rest of the JSON is left as it is")
    ap.add_argument("--profile", default=None, metavar="NAME",
                    help="a named profile of config/profiles/ for every controller and plant the bench builds "
                         "(default: the configuration files); a profile with a plant perturbation is refused")
    ap.add_argument("--controller", type=controller_arg, action="append", default=[], metavar="NAME",
                    help="instead of the bench's sections: the in-process speed of the named controller "
                         "(repeatable; a built-in mode, a registered controller or module:Class) walking on the "
                         "rigid plant beside the built-in modes (benchmarks/plugin_bench.py; --quick: 1 step, "
                         "1 repeat)")
    a = ap.parse_args(argv)
    if a.controller:
        if a.profile is not None or a.inprocess_only:
            ap.error("--controller times the configuration files' settings alone (no --profile, "
                     "no --inprocess-only)")
        from benchmarks import plugin_bench
        return plugin_bench.main(["--json", a.json or str(RESULTS_DIR / "plugin.json")]
                                 + [x for n in a.controller for x in ("--controller", n)]
                                 + (["--steps", "1", "--repeats", "1"] if a.quick else []))
    if a.json is None:
        a.json = str(RESULTS_DIR / "results.json")
    global _SETTINGS
    from biped_controller.studies.trial.settings import OverrideError, differences, run_settings
    try:
        _SETTINGS = run_settings(profile=a.profile)
    except (OverrideError, ValueError) as exc:
        ap.error(f"--profile {a.profile}: {exc}")
    if _SETTINGS.perturbation is not None and not _SETTINGS.perturbation.is_zero:
        ap.error(f"--profile {a.profile}: sets a plant perturbation; the bench times unperturbed plants")
    json_path = Path(a.json)
    md_path = Path(a.md) if a.md else json_path.with_suffix(".md")
    provenance.track(json_path, None if a.inprocess_only else md_path, argv=argv, plant="rigid,mujoco")
    if a.inprocess_only:
        return inprocess_only(json_path)
    T0 = time.perf_counter()
    quick = a.quick
    R = {"meta": {"date": time.strftime("%Y-%m-%d %H:%M:%S"), "quick": quick, "cpus": os.cpu_count(),
                  "settings": differences(_SETTINGS),
                  "machine": platform.processor() or platform.machine(), "python": platform.python_version()},
         "targets": TARGETS}
    log("0. searching the hard run (largest surviving push, mode both)")
    hard = find_hard_run(quick)
    steps = 1 if quick else 22
    t0 = time.perf_counter()
    rec = _push_run(hard["force"], steps)
    log(f"recorded F={hard['force']:.2f} N: {len(rec.records)} periods, fallen={rec.fallen} "
        f"[{time.perf_counter() - t0:.1f} s]")
    instances = [(hard["force"], q) for q in rec.qp_instances] + hard["instances"]
    R["hard_run"] = {"force": hard["force"], "bracket": hard["bracket"], "probes": hard["probes"],
                     "recorded": {"steps": steps, "periods": len(rec.records), "fallen": rec.fallen,
                                  "steps_walked": rec.steps_walked, **_qp_counts(rec)}}
    log("1. controller step split")
    records = rec.records[:300] if quick else rec.records
    c = bench_controller(records, 300 if quick else 10_000)
    rec_dec = [(s.p_ddot, s.tau_ddot) for s in rec.statuses[:len(records)]]
    c["replay_matches_run"] = bool(np.allclose([d[:2] for d in c.pop("decisions")], rec_dec, rtol=1e-9, atol=1e-9))
    R["controller"] = c
    log(f"   total p50 {c['pieces_us']['total']['p50']:.1f} us; replay matches run: {c['replay_matches_run']}")
    log("2. QP solvers")
    cfg = _ctrl_cfg("both")
    W = np.array([cfg.weight_p, cfg.weight_tau])
    if quick:   # every constrained instance (a few hundred at most) and 200 with x* feasible
        con = [i for i in instances if not np.all(i[1][0] @ i[1][2] - i[1][1] <= 0.0)]
        unc = [i for i in instances if np.all(i[1][0] @ i[1][2] - i[1][1] <= 0.0)]
        instances = con[:300] + unc[:200]
    R["solvers"] = bench_solvers(instances, W, 200 if quick else 10_000, 20 if quick else 500)
    log(f"   fastest correct: {R['solvers']['fastest_correct']}")
    log("2b. QP path head to head (benchmarks/qp_bench.py: early-out, held PIQP, exact-numba, direct DAQP/quadprog)")
    from benchmarks.qp_bench import run_bench
    qb = run_bench((250.0,) if quick else (250.0, 600.0), ("both",), 5 if quick else 30)
    R["qp_bench"] = {k: qb.get(k) for k in ("early_out_p50_us", "piqp_ratio_to_fastest",
                                             "piqp_ratio_to_fastest_qpsolvers", "exact_numba_ratio_to_fastest")}
    log(f"   early-out p50 {R['qp_bench']['early_out_p50_us']} us; PIQP path / fastest direct "
        f"{R['qp_bench']['piqp_ratio_to_fastest']}")
    log("3. DDS ping-pong and lockstep")
    pp = bench_pingpong(300 if quick else 5000)
    R["dds"] = {"pingpong": pp, "lockstep": bench_lockstep(0.5 if quick else 5.0, pp)}
    log(f"   ping-pong {pp.get('rate_hz', 'failed')}; lockstep {R['dds']['lockstep'].get('steps_per_s', R['dds']['lockstep'].get('reason'))}")
    log("4. in-process speed")
    R["inprocess"] = bench_inprocess(1 if quick else 5)
    log("5. max-push table")
    R["experiment"] = bench_experiment(quick)
    log("6. sweep: the default capability map (early stop, bracketed search)")
    from benchmarks.sweep_bench import bench_sweep
    R["sweep"] = bench_sweep(quick)
    R["meta"]["wall_s"] = time.perf_counter() - T0
    R["keys"] = stable_keys(R)
    merge_sub_benchmarks(R, a.sub_results)
    p50 = c["pieces_us"]["total"]["p50"]
    prod = R["solvers"]["table_us"]["PIQP held (AdaptationQP)"]["ratio_to_fastest"]
    ls = R["dds"]["lockstep"]
    e = R["experiment"]
    R["target_check"] = {
        "controller_step_p50_us": {"value": p50, "target": "<= 30", "met": p50 <= 30},
        "production_qp_vs_fastest_ratio": {"value": prod, "target": "<= 1.5", "met": prod is not None and prod <= 1.5},
        "lockstep_vs_pingpong_fraction": {"value": ls.get("fraction_of_pingpong"), "target": ">= 0.90",
                                          "met": None if not ls.get("available") else ls.get("fraction_of_pingpong", 0) >= 0.9},
        "lockstep_rate_hz": {"value": ls.get("steps_per_s"), "target": ">= 1000",
                             "met": None if not ls.get("available") else ls["steps_per_s"] >= 1000},
        "inprocess_realtime_factor": {"value": R["inprocess"]["both"]["realtime_factor"], "target": ">= 50",
                                      "met": R["inprocess"]["both"]["realtime_factor"] >= 50},
        "max_push_table_s": {"value": e.get("parallel_s"), "target": "<= 30",
                             "met": None if not e.get("available") else e["parallel_s"] <= 30},
    }
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(R, indent=1, default=float) + "\n", encoding="utf-8")
    md = markdown(R)
    md_path.write_text(md, encoding="utf-8")
    print(md)
    log(f"wrote {json_path} and {md_path} [{R['meta']['wall_s']:.0f} s]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
