"""Adaptation-QP benchmark: the early-out, the held PIQP path, the compiled exact solver and the
general-purpose solvers quadprog and DAQP, on the same instances, side by side in one run.

    python -m benchmarks.qp_bench OUT.json [--forces 250 600] [--modes both] [--repeats 30]
                                  [--instances FILE.npz] [--quick]

Instances are the controller's own QPs (``runner.run(keep_qp=True)``: 2 steps, a push of F N at
t = 0.2315 s for 25 ms, per force and mode), or those saved in ``--instances`` (written there
when the file does not exist). Every timing is the per-call time of a Python call measured with
``time.perf_counter_ns``; each instance is solved by every solver of a run in turn (round robin),
``repeats`` times, with the garbage collector off, so the figures of a run share the machine's
state of the moment. Reported: p50 / p99 / mean [us] and ratios to the fastest general-purpose
solver, p50 over p50 within one run. Runs:

* head to head: piqp_held, quadprog, daqp, exact_numba (the headline ratio);
* all solvers: every solver below (more code between two calls of one solver: colder caches,
  which costs PIQP's larger code more than DAQP's);
* early-out: early_out and early_out_numpy on the instances with x* feasible;
* profile: the steps of the held PIQP path timed one by one (see :func:`profile_held_path`).

Solvers (all on the instances where x* is infeasible, except ``early_out``):

* ``early_out``          AdaptationQP.solve (production object) on the instances with x* feasible.
* ``early_out_numpy``    exact.solve_exact on the same instances (numpy validation, G x* - h,
                         result): the cost of the early-out before the compiled kernel.
* ``piqp_held``          AdaptationQP(solver="piqp").solve, the controller's path.
* ``piqp_held_tight``    AdaptationQP(polish=False): PIQP to 1e-10 only, no screening/polish.
* ``piqp_core``          a held PIQP DenseSolver, update + solve only (tight settings), no wrapping.
* ``exact_numba``        AdaptationQP(solver="exact").solve.
* ``exact_numpy``        exact.solve_exact (the reference).
* ``quadprog`` / ``daqp``  the solvers' own Python calls with the QP built from (G, h, x*, W).
* ``quadprog_qpsolvers`` / ``daqp_qpsolvers``  through ``solver.solve_with_qpsolvers`` (as
                         benchmarks/run.py measures them).

Every answer is compared with exact's (|x - x_exact|_inf <= 1e-6 max(1, |x_exact|_inf)); a
solver's timings only count on the instances all solvers answered correctly (failures listed).
Top-level keys for scripts/bench: ``early_out_p50_us``, ``piqp_ratio_to_fastest`` (piqp_held p50 /
the faster of quadprog and daqp direct p50, head to head), ``piqp_ratio_to_fastest_qpsolvers`` and
``exact_numba_ratio_to_fastest``.
"""
from __future__ import annotations

import argparse
import gc
import json
import platform
import sys
import time
from pathlib import Path
from time import perf_counter_ns

import numpy as np

from benchmarks.common import pct

from biped_controller.studies import provenance

ROOT = Path(__file__).resolve().parents[1]
PUSH_START, PUSH_DURATION = 0.2315, 0.025
MATCH_TOL = 1e-6


def log(msg: str) -> None:
    print(f"qp_bench: {msg}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------------------
# instances
# ------------------------------------------------------------------------------------------------


def generate_instances(forces, modes, steps: int = 2) -> list[dict]:
    """The controller's QP instances (G, h, x*) of short pushed runs; W from the controller config."""
    from biped_controller.closed_loop.runner import run
    from biped_sim.plant.push import Push

    out = []
    for mode in modes:
        for F in forces:
            t0 = time.perf_counter()
            r = run(steps=steps, mode=mode, pushes=(Push(PUSH_START, PUSH_DURATION, float(F)),), keep_qp=True)
            for G, h, xs, status in r.qp_instances:
                out.append({"mode": mode, "force": float(F), "G": np.array(G, dtype=float),
                            "h": np.array(h, dtype=float), "x_star": np.array(xs, dtype=float),
                            "status": int(status)})
            log(f"{mode} {F:g} N: {len(r.qp_instances)} instances ({time.perf_counter() - t0:.1f} s)")
    return out


def save_instances(path: Path, inst: list[dict]) -> None:
    arrays = {}
    for k, d in enumerate(inst):
        for key in ("G", "h", "x_star"):
            arrays[f"{k}_{key}"] = d[key]
    meta = [{"mode": d["mode"], "force": d["force"], "status": d["status"]} for d in inst]
    np.savez_compressed(path, meta=json.dumps(meta), **arrays)


def load_instances(path: Path) -> list[dict]:
    with np.load(path) as f:
        meta = json.loads(str(f["meta"]))
        return [{**m, "G": f[f"{k}_G"], "h": f[f"{k}_h"], "x_star": f[f"{k}_x_star"]} for k, m in enumerate(meta)]


def controller_weights(mode: str) -> np.ndarray:
    """W of the controller's QP in this mode (config/controller.yaml weights of the adapted parameters)."""
    from biped_controller.core.control.config import load_controller_config

    cfg = load_controller_config()
    idx = {"tau": [1], "p": [0], "both": [0, 1]}[mode]
    return np.array([cfg.weight_p, cfg.weight_tau], dtype=float)[idx]


# ------------------------------------------------------------------------------------------------
# solvers
# ------------------------------------------------------------------------------------------------


def make_solvers(n: int, m: int, W: np.ndarray) -> dict:
    """name -> f(G, h, x*) returning x (n,) or None (no answer)."""
    import daqp
    import piqp
    import quadprog

    from biped_controller.core.qp.solver import AdaptationQP, solve_with_qpsolvers
    from biped_controller.core.qp.exact import solve_exact
    from biped_controller.core.qp.solver import configure_piqp

    held = AdaptationQP(n, m, W)
    tight = AdaptationQP(n, m, W, polish=False)
    exact = AdaptationQP(n, m, W, solver="exact")
    H = np.diag(W)
    core = piqp.DenseSolver()
    configure_piqp(core.settings, 1e-10, 1e-11, 250)
    Pf, cf, Gf, hf = np.asfortranarray(H), np.zeros(n), np.asfortranarray(np.zeros((m, n))), np.ones(m)
    core.setup(Pf, cf, None, None, Gf, None, hf, None, None)

    def piqp_core(G, h, xs):
        cf[:] = -W * xs
        Gf[:, :] = G
        core.update(c=cf, G=Gf, h_u=h)
        core.solve()
        return np.array(core.result.x)

    def quadprog_direct(G, h, xs):
        # quadprog: min 1/2 x'Hx - a'x  s.t.  C'x >= b
        return quadprog.solve_qp(H, W * xs, -G.T, -h, 0)[0]

    def daqp_direct(G, h, xs):
        x, _f, flag, _info = daqp.solve(H, -W * xs, G, h)
        return x if flag > 0 else None

    return {
        "piqp_held": lambda G, h, xs: held.solve(G, h, xs).x,
        "piqp_held_tight": lambda G, h, xs: tight.solve(G, h, xs).x,
        "piqp_core": piqp_core,
        "exact_numba": lambda G, h, xs: exact.solve(G, h, xs).x,
        "exact_numpy": lambda G, h, xs: solve_exact(G, h, xs, W).x,
        "quadprog": quadprog_direct,
        "daqp": daqp_direct,
        "quadprog_qpsolvers": lambda G, h, xs: solve_with_qpsolvers(G, h, xs, W, "quadprog").x,
        "daqp_qpsolvers": lambda G, h, xs: solve_with_qpsolvers(G, h, xs, W, "daqp").x,
    }, held


GENERAL = ("quadprog", "daqp")
GENERAL_QPSOLVERS = ("quadprog_qpsolvers", "daqp_qpsolvers")
#: timed side by side for the headline ratio: the production path, the general-purpose solvers'
#: own calls and the compiled exact solver (the floor)
HEAD_TO_HEAD = ("piqp_held", "quadprog", "daqp", "exact_numba")


def _round_robin(names, fns, instances, repeats) -> dict:
    """{name: per-call times [ns]}: every instance solved by every named function in turn."""
    times = {k: [] for k in names}
    gc.collect()
    gc.disable()
    try:
        for _ in range(repeats):
            for d in instances:
                G, h, xs = d["G"], d["h"], d["x_star"]
                for k in names:
                    f = fns[k]
                    t0 = perf_counter_ns()
                    f(G, h, xs)
                    times[k].append(perf_counter_ns() - t0)
    finally:
        gc.enable()
    return times


def profile_held_path(held, instances, repeats) -> dict:
    """Where the time of AdaptationQP.solve goes on instances with x* infeasible: the same steps
    as the PIQP path of ``AdaptationQP._piqp_solve`` (screening solve accepted by the polish),
    each timed; a DAQP call in between every instance keeps the caches as cold as in the
    head-to-head run. Reads the solver's internals (a profiling tool, not an API)."""
    import daqp

    from biped_controller.core.qp.problem import ACTIVE, DEFAULT_FEAS_RTOL, make_result

    k_mod, W, m, n = held._k, held.W, held.m, held.n
    H = np.diag(W)
    steps = ("type checks + early_out kernel", "load_piqp kernel (presolve)", "PIQP setup", "PIQP solve",
             "result + iteration count", "polish kernel (+ outputs)", "QPResult")
    t = {s_: [] for s_ in steps}
    iters, rows = [], []
    gc.collect()
    gc.disable()
    try:
        for _ in range(repeats):
            for d in instances:
                G, h, xs = d["G"], d["h"], d["x_star"]
                c0 = perf_counter_ns()
                active = np.empty(m, dtype=bool)
                code = k_mod.early_out(G, h, xs, held.active_tol, active)
                c1 = perf_counter_ns()
                k = k_mod.load_piqp(G, h, xs, W, held._g_buf, held._h_buf, held._c, held._rows)
                e = held._held.get(k) or held._held_for(k)
                c2 = perf_counter_ns()
                e.screen.setup(held._P, held._c, None, None, e.G, None, e.h, None, None)
                c3 = perf_counter_ns()
                e.screen.solve()
                c4 = perf_counter_ns()
                res = e.screen.result
                it = int(res.info.iter)
                c5 = perf_counter_ns()
                x, z, act = np.empty(n), np.empty(m), np.empty(m, dtype=bool)
                mv = k_mod.polish(G, h, xs, W, res.z_u, held._rows, res.x, DEFAULT_FEAS_RTOL, held.active_tol,
                                  x, z, act)
                c6 = perf_counter_ns()
                make_result(x, ACTIVE, "solved (PIQP, polished)", mv, act, it, z)
                c7 = perf_counter_ns()
                for s_, a_, b_ in zip(steps, (c0, c1, c2, c3, c4, c5, c6), (c1, c2, c3, c4, c5, c6, c7)):
                    t[s_].append(b_ - a_)
                iters.append(it)
                rows.append(k)
                assert code == 1 and mv == mv, "profile assumes x* infeasible and the polish accepted"
                daqp.solve(H, -W * xs, G, h)
    finally:
        gc.enable()
    out = {s_: pct(np.asarray(v) / 1000.0) for s_, v in t.items()}
    return {"steps_us": out, "sum_of_p50_us": float(sum(v["p50"] for v in out.values())),
            "screening_iterations_mean": float(np.mean(iters)), "screening_iterations_max": int(np.max(iters)),
            "rows_seen_by_piqp": sorted(set(int(r) for r in rows)), "rows_of_the_problem": m}


def bench_group(inst: list[dict], W: np.ndarray, repeats: int) -> dict:
    """All solvers on one group of instances of equal (m, n)."""
    from biped_controller.core.qp.exact import solve_exact
    from biped_controller.core.qp.problem import constraint_values

    n = inst[0]["G"].shape[1]
    m = inst[0]["G"].shape[0]
    solvers, held = make_solvers(n, m, W)
    names = list(solvers)
    feas = [d for d in inst if np.all(constraint_values(d["G"], d["x_star"], d["h"]) <= 0.0)]
    cons = [d for d in inst if not np.all(constraint_values(d["G"], d["x_star"], d["h"]) <= 0.0)]
    # correctness first (also warms every solver up)
    failures = {k: [] for k in names}
    usable = []
    n_infeasible = 0
    for d in cons:
        ex = solve_exact(d["G"], d["h"], d["x_star"], W)
        if ex.status != 1:           # infeasible: the general solvers have no least-violation answer
            n_infeasible += 1
            continue
        scale = max(1.0, float(np.max(np.abs(ex.x))))
        ok = True
        for k in names:
            try:
                x = solvers[k](d["G"], d["h"], d["x_star"])
                err = float(np.max(np.abs(np.asarray(x) - ex.x))) if x is not None else float("inf")
            except (ValueError, ArithmeticError) as exc:  # quadprog raises ValueError when it fails
                err, x = float("inf"), f"{type(exc).__name__}: {exc}"
            if not err <= MATCH_TOL * scale:
                ok = False
                if len(failures[k]) < 5:
                    failures[k].append(f"force {d['force']:g}: |dx| = {err:.3g}")
        if ok:
            usable.append(d)
    held.calls = held.tight_calls = 0
    early_fn = {"early_out": lambda G, h, xs: held.solve(G, h, xs),
                "early_out_numpy": lambda G, h, xs: solve_exact(G, h, xs, W)}
    head = _round_robin(HEAD_TO_HEAD, solvers, usable, repeats)
    calls, tight = held.calls, held.tight_calls
    full = _round_robin(names, solvers, usable, max(1, repeats // 2))
    early = _round_robin(tuple(early_fn), early_fn, feas, repeats)
    profile = profile_held_path(held, usable, max(1, repeats // 2))

    def table(times):
        return {k: {**pct(np.asarray(v) / 1000.0), "failures": len(failures[k]), "failure_examples": failures[k]}
                for k, v in times.items()}

    return {"n": n, "m": m, "W": W.tolist(), "instances": len(inst), "x_star_feasible": len(feas),
            "constrained": len(cons), "infeasible": n_infeasible, "timed_constrained": len(usable),
            "repeats": repeats, "head_to_head_us": table(head), "all_solvers_us": table(full),
            "early_out_us": {k: pct(np.asarray(v) / 1000.0) for k, v in early.items()},
            "piqp_held_calls": calls, "piqp_held_tight_resolves": tight, "piqp_held_profile": profile}


def ratios(group: dict) -> dict:
    """p50 ratios, each within one round-robin run."""
    head, full = group["head_to_head_us"], group["all_solvers_us"]

    def fastest(t, names):
        return min(names, key=lambda k: t[k]["p50"])

    f_head = fastest(head, GENERAL)
    f_full = fastest(full, GENERAL)
    f_q = fastest(full, GENERAL_QPSOLVERS)
    return {
        "fastest_general": f_head,
        "piqp_ratio_to_fastest": head["piqp_held"]["p50"] / head[f_head]["p50"],
        "exact_numba_ratio_to_fastest": head["exact_numba"]["p50"] / head[f_head]["p50"],
        "all_solvers_run": {
            "fastest_general": f_full,
            "piqp_ratio_to_fastest": full["piqp_held"]["p50"] / full[f_full]["p50"],
            "piqp_tight_ratio_to_fastest": full["piqp_held_tight"]["p50"] / full[f_full]["p50"],
            "piqp_core_ratio_to_fastest": full["piqp_core"]["p50"] / full[f_full]["p50"],
            "fastest_general_qpsolvers": f_q,
            "piqp_ratio_to_fastest_qpsolvers": full["piqp_held"]["p50"] / full[f_q]["p50"],
        },
    }


def run_bench(forces=(250.0, 600.0), modes=("both",), repeats: int = 30, instances: Path | None = None) -> dict:
    from biped_controller.core.qp.solver import load_exact_kernels
    load_exact_kernels()   # compiles or loads the kernels before any timing
    if instances is not None and Path(instances).exists():
        inst = load_instances(Path(instances))
        log(f"loaded {len(inst)} instances from {instances}")
    else:
        inst = generate_instances(forces, modes)
        if instances is not None:
            save_instances(Path(instances), inst)
    out = {"machine": {"python": platform.python_version(), "processor": platform.processor(),
                       "node": platform.node()},
           "match_tol": MATCH_TOL, "groups": {}}
    for mode in sorted({d["mode"] for d in inst}):
        group = [d for d in inst if d["mode"] == mode]
        W = controller_weights(mode)
        log(f"mode {mode}: {len(group)} instances, {repeats} repeats ...")
        g = bench_group(group, W, repeats)
        g["ratios"] = ratios(g)
        out["groups"][mode] = g
    main = out["groups"].get("both") or next(iter(out["groups"].values()))
    out["early_out_p50_us"] = main["early_out_us"]["early_out"]["p50"]
    out["early_out_numpy_p50_us"] = main["early_out_us"]["early_out_numpy"]["p50"]
    out["piqp_ratio_to_fastest"] = main["ratios"]["piqp_ratio_to_fastest"]
    out["piqp_ratio_to_fastest_qpsolvers"] = main["ratios"]["all_solvers_run"]["piqp_ratio_to_fastest_qpsolvers"]
    out["exact_numba_ratio_to_fastest"] = main["ratios"]["exact_numba_ratio_to_fastest"]
    return out


def report(res: dict) -> str:
    lines = []
    for mode, g in res["groups"].items():
        r = g["ratios"]
        lines.append(f"mode {mode}: n={g['n']} m={g['m']}; {g['timed_constrained']} constrained instances timed "
                     f"x {g['repeats']}, {g['x_star_feasible']} with x* feasible, {g['infeasible']} infeasible; "
                     f"PIQP tight re-solves {g['piqp_held_tight_resolves']} of {g['piqp_held_calls']} PIQP calls")
        for title, key in (("head to head", "head_to_head_us"), ("all solvers", "all_solvers_us")):
            lines.append(f"  {title}: {'solver':20s} {'p50 us':>9s} {'p99 us':>9s} {'fail':>5s}")
            for k, v in sorted(g[key].items(), key=lambda kv: kv[1]["p50"] or 1e99):
                lines.append(f"  {'':14s}{k:20s} {v['p50']:9.2f} {v['p99']:9.2f} {v['failures']:5d}")
        lines.append("  early-out (x* feasible):")
        for k, v in g["early_out_us"].items():
            lines.append(f"  {'':14s}{k:20s} {v['p50']:9.2f} {v['p99']:9.2f}")
        p = g["piqp_held_profile"]
        lines.append(f"  held PIQP path, step by step (p50 us; screening iterations {p['screening_iterations_mean']:.2f}"
                     f" mean, rows seen by PIQP {p['rows_seen_by_piqp']} of {p['rows_of_the_problem']}):")
        for k, v in p["steps_us"].items():
            lines.append(f"  {'':14s}{k:34s} {v['p50']:7.2f}")
        a = r["all_solvers_run"]
        lines.append(f"  piqp_held / {r['fastest_general']} = {r['piqp_ratio_to_fastest']:.2f} (head to head), "
                     f"{a['piqp_ratio_to_fastest']:.2f} (all solvers run; piqp_core {a['piqp_core_ratio_to_fastest']:.2f},"
                     f" tight {a['piqp_tight_ratio_to_fastest']:.2f}); exact_numba / it = "
                     f"{r['exact_numba_ratio_to_fastest']:.2f}; piqp_held / {a['fastest_general_qpsolvers']} = "
                     f"{a['piqp_ratio_to_fastest_qpsolvers']:.2f}")
    lines.append(f"early-out p50 {res['early_out_p50_us']:.2f} us (numpy path {res['early_out_numpy_p50_us']:.2f} us); "
                 f"PIQP held / fastest general {res['piqp_ratio_to_fastest']:.2f}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="JSON file to write")
    ap.add_argument("--forces", type=float, nargs="+", default=[250.0, 600.0], help="push forces [N]")
    ap.add_argument("--modes", nargs="+", default=["both"], choices=["both", "p", "tau"])
    ap.add_argument("--repeats", type=int, default=30, help="round-robin passes over the instances")
    ap.add_argument("--instances", type=Path, default=None, help="npz cache of the instances (read, or written)")
    ap.add_argument("--quick", action="store_true", help="one force, 5 repeats")
    a = ap.parse_args(argv)
    provenance.track(a.out, argv=argv)   # record of each file written (results/README.md)
    if a.quick:
        a.forces, a.repeats = a.forces[:1], 5
    res = run_bench(tuple(a.forces), tuple(a.modes), a.repeats, a.instances)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1))
    print(report(res))
    log(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
