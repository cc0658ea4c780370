"""Speed of plug-in controllers in process, beside the built-in modes, in one run.

``.venv/bin/python -m benchmarks.plugin_bench [--controller NAME ...] [--steps 5] [--repeats 2]
[--json results/benchmarks/plugin.json]``

Each variant walks ``--steps`` touchdowns on the rigid plant without a push (the same walk for all), its
sim time over its wall time (the real-time factor) and over its CPU time, the variants interleaved
repeat by repeat (the machine is shared: compare figures of the same run):

* ``builtin_<mode>_compiled``: ``runner.run`` of mode none / both, the compiled loop (the studies' path);
* ``builtin_<mode>_objects``: ``runner.run`` with the compiled period but a Python object per period;
* ``adapter_none``: mode none through the plug-in loop (``plugin.loop``: the built-in adapter);
* ``plugin_<name>``: each ``--controller`` through the plug-in loop (default the example
  ``capture_point``, pure Python; a built-in mode's name times its adapter there, its compiled path being
  ``builtin_<mode>_compiled``). ``scripts/bench --controller NAME`` runs this bench.

The plug-in loop's time is split (one extra instrumented run per plug-in, not the timed one) into the
controller's ``compute`` (guard included), the plant's ``step`` and ``observe``, and the rest of the loop
(the observation's copies, the bookkeeping), in microseconds per period. Keys:
``plugin.<name>.realtime_factor``, ``plugin.<name>.realtime_factor_cpu``,
``plugin.<name>.over_builtin_none_objects`` (ratio of real-time factors in this run). The issue's target
(a pure-Python plug-in at least 5x real time) is printed beside the figure, never asserted.
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

from biped_controller.studies import provenance
from biped_controller.studies.trial.args import controller_arg
from benchmarks import RESULTS_DIR

TARGET_REALTIME = 5.0


def _split(name: str, steps: int) -> dict:
    """One instrumented run of plug-in ``name``: us per period in compute, plant step, observe, the rest."""
    from biped_controller.plugin.loop import PluginLoop
    loop = PluginLoop(name)
    acc = {"compute": 0, "step": 0, "observe": 0}

    def timed(obj, attr, key):
        f = getattr(obj, attr)

        def w(*a, **k):
            t0 = perf_counter_ns()
            r = f(*a, **k)
            acc[key] += perf_counter_ns() - t0
            return r
        setattr(obj, attr, w)
    timed(loop.ctrl, "compute", "compute")
    timed(loop.sim, "step", "step")
    timed(loop.sim, "observe", "observe")
    t0 = perf_counter_ns()
    r = loop.run(steps, keep_records=False)
    total = perf_counter_ns() - t0
    n = max(r.periods, 1)
    out = {k: v / n / 1e3 for k, v in acc.items()}
    out["loop_rest"] = (total - sum(acc.values())) / n / 1e3
    out["total"] = total / n / 1e3
    out["periods"] = r.periods
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--controller", type=controller_arg, action="append", default=None, metavar="NAME",
                    help="controllers to time through the plug-in loop (repeatable; default capture_point; an "
                         "unknown name is an error naming it, before any run)")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", type=Path, default=RESULTS_DIR / "plugin.json")
    a = ap.parse_args(argv)
    if a.steps < 1 or a.repeats < 1:
        ap.error("--steps and --repeats must be >= 1")
    provenance.track(a.json, argv=argv, plant="rigid")
    from biped_controller.plugin.loop import PluginLoop
    from biped_controller.closed_loop.runner import run
    from biped_sim.plant.config import load_sim_config
    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily
    from biped_controller.core.control.config import load_controller_config

    names = list(dict.fromkeys(a.controller or ["capture_point"]))
    desc, family, scfg = load_description(), GaitFamily.load(), load_sim_config()
    ccfg = {m: load_controller_config(mode=m) for m in ("none", "both")}
    loops = {"adapter_none": PluginLoop("none", sim_config=scfg, family=family, desc=desc)}
    for n in names:
        loops[f"plugin_{n}"] = PluginLoop(n, sim_config=scfg, family=family, desc=desc)

    def one(variant: str) -> tuple[float, float, float, int]:
        gc.collect()
        c0, t0 = time.process_time(), time.perf_counter()
        if variant.startswith("builtin_"):
            _, mode, kind = variant.split("_")
            r = run(steps=a.steps, mode=mode, sim_config=scfg, ctrl_config=ccfg[mode], desc=desc, family=family,
                    compiled_loop=(kind == "compiled"), keep_records=True)
            sim_t, walked = r.records[-1].t_end, r.steps_walked
        else:
            r = loops[variant].run(a.steps, keep_records=True)
            sim_t, walked = r.records[-1].t_end, r.steps_walked
        return sim_t, time.perf_counter() - t0, time.process_time() - c0, walked

    variants = [f"builtin_{m}_{k}" for m in ("none", "both") for k in ("compiled", "objects")] + list(loops)
    for v in variants:               # warm-up: kernels loaded, caches filled; not timed
        one(v)
    load0 = os.getloadavg()[0]
    acc = {v: [0.0, 0.0, 0.0, 0] for v in variants}
    for _ in range(a.repeats):
        for v in variants:
            s, w, c, walked = one(v)
            acc[v][0] += s
            acc[v][1] += w
            acc[v][2] += c
            acc[v][3] = walked
    res = {v: {"sim_s": s, "wall_s": w, "cpu_s": c, "steps_walked": k, "realtime_factor": s / w,
               "realtime_factor_cpu": s / c, "us_per_period": w / (s / scfg.control_period) * 1e6}
           for v, (s, w, c, k) in acc.items()}
    split = {n: _split(n, a.steps) for n in names}
    meta = {"date": time.strftime("%Y-%m-%d %H:%M:%S"), "steps": a.steps, "repeats": a.repeats,
            "cpus": os.cpu_count(), "machine": platform.processor() or platform.machine(),
            "python": platform.python_version(), "loadavg_1min_before": load0,
            "loadavg_1min_after": os.getloadavg()[0]}
    keys = {}
    base = res["builtin_none_objects"]["realtime_factor"]
    for n in names:
        r = res[f"plugin_{n}"]
        keys[f"plugin.{n}.realtime_factor"] = r["realtime_factor"]
        keys[f"plugin.{n}.realtime_factor_cpu"] = r["realtime_factor_cpu"]
        keys[f"plugin.{n}.over_builtin_none_objects"] = r["realtime_factor"] / base
    keys["plugin.adapter_none.realtime_factor"] = res["adapter_none"]["realtime_factor"]
    for v in variants:
        if v.startswith("builtin_"):
            keys[f"plugin_bench.{v}.realtime_factor"] = res[v]["realtime_factor"]
    out = {"meta": meta, "target_realtime_factor": TARGET_REALTIME, "variants": res, "split_us_per_period": split,
           "keys": keys}
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(f"in process, rigid plant, {a.steps} steps x {a.repeats}, load average {load0:.1f} -> "
          f"{meta['loadavg_1min_after']:.1f} on {meta['cpus']} CPUs")
    print("| variant | sim s / wall s | sim s / CPU s | us per period (wall) |")
    print("| --- | ---: | ---: | ---: |")
    for v in variants:
        r = res[v]
        print(f"| {v} | {r['realtime_factor']:.2f} | {r['realtime_factor_cpu']:.2f} | {r['us_per_period']:.0f} |")
    for n, s in split.items():
        print(f"{n}: us per period: compute {s['compute']:.1f}, plant step {s['step']:.1f}, observe "
              f"{s['observe']:.1f}, rest of the loop {s['loop_rest']:.1f} (total {s['total']:.1f}); target "
              f">= {TARGET_REALTIME:g}x real time: {res[f'plugin_{n}']['realtime_factor']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
