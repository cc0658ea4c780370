"""Section 4 of ``scripts/bench``: the in-process closed loop's speed (simulated s / wall s and / CPU s) per
engine and plant, the variants interleaved in one run; ``--inprocess-only`` runs it alone
(:func:`inprocess_only`)."""
from __future__ import annotations

import gc
import json
import os
import platform
import time
from pathlib import Path

from benchmarks.common import ctrl_cfg, robot_files, sim_cfg


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

    desc, family = robot_files()
    configs = {(e, m): (sim_cfg(engine=e, plant="rigid"), ctrl_cfg(m, engine=e))
               for e in ("fast", "reference") for m in ("none", "both")}
    for m in ("none", "both"):   # the MuJoCo plant with the fast engine's controller (its compiled period)
        configs[("mujoco", m)] = (sim_cfg(engine="fast", plant="mujoco"), configs[("fast", m)][1])

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
