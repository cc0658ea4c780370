"""The report of ``scripts/bench``: the Markdown tables of one run (:func:`markdown`), the stable dotted keys
of its sections (:func:`stable_keys`) and the merger of the sub-benchmarks' own files into them
(:func:`merge_sub_benchmarks`)."""
from __future__ import annotations

import json
from pathlib import Path

from benchmarks.common import MATCH_TOL, PUSH_DURATION, PUSH_START, TARGETS


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


SUB_BENCHMARKS = ("wbc_step.json", "model_error.json", "estimation.json", "torso_step.json", "plugin.json",
                  "policy_env.json")


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
