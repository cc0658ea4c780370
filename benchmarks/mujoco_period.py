"""Where a MuJoCo control period's time goes, and the MuJoCo closed loop's paths side by side, in one run.

``.venv/bin/python -m benchmarks.mujoco_period [--steps 3] [--repeats 3] [--json results/benchmarks/mujoco_period.json]``

The in-process closed loop (``runner.ClosedLoop``) on the MuJoCo plant (``plant: mujoco``, the configuration
files' settings: 0.125 ms MuJoCo step), mode both, a pushed walk (300 N for 25 ms from t = 0.2315 s, inside a
control period) of ``--steps`` steps, every record kept. Three paths, interleaved ``--repeats`` times, each
timed wall (``time.perf_counter``) and CPU (``time.process_time``, this process's user + system):

* ``python_steps``: the plant's Python loop, one iteration per MuJoCo step (``MujocoPlant.compiled_steps``
  False: ``mj_step``, ``mj_rnePostConstraint``, the compiled bookkeeping through the bindings), the controller
  object every period;
* ``compiled_steps``: a period's MuJoCo steps in one compiled call (``mujoco_kernels.substeps``), the
  controller object every period;
* ``compiled_loop``: the compiled closed loop (``runner``'s ``MujocoSegment``: controller period and MuJoCo
  steps in one call per run of periods), when the runner has it for this plant.

Every path's records are compared field for field with ``python_steps``' (``records_equal``). Then
instrumented runs of each path (``--repeats`` each, interleaved; the median of each figure) split a period: the
controller's ``compute``, the plant's ``observe`` and ``step`` and, inside ``step``, the calls to
``mujoco.mj_step``, ``mujoco.mj_rnePostConstraint`` and the compiled bookkeeping (``python_steps``) or to the
compiled steps (``compiled_steps``); on the compiled loop its kernel (controller periods and MuJoCo steps) and
the Python around it (records, statuses, the QP decisions, the touchdowns' impact records). Each call is timed
with ``time.perf_counter_ns`` (the timer's own cost per call, measured around an empty call, subtracted). The
instrumented runs are slower than the timed ones by that timing; their split is the figure, the timed runs
the speed.
"""
from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import os
import platform
import time
from pathlib import Path
from time import perf_counter_ns

import numpy as np

from benchmarks import RESULTS_DIR
from biped_controller.studies import provenance

PUSH = (0.2315, 0.025, 300.0)     # start [s], duration [s], force [N]


def records_equal(a, b) -> bool:
    """Every field of every record equal (arrays bit for bit, NaN equal to NaN)."""
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        for f in dataclasses.fields(x):
            u, v = getattr(x, f.name), getattr(y, f.name)
            if isinstance(u, np.ndarray) or isinstance(v, np.ndarray):
                if not np.array_equal(np.asarray(u), np.asarray(v), equal_nan=True):
                    return False
            elif u != v and not (isinstance(u, float) and isinstance(v, float) and u != u and v != v):
                return False
    return True


class Timed:
    """A callable wrapped with a per-call timer (ns summed in ``ns``, calls in ``n``)."""

    def __init__(self, fn):
        self.fn, self.ns, self.n = fn, 0, 0

    def __call__(self, *a, **k):
        t0 = perf_counter_ns()
        r = self.fn(*a, **k)
        self.ns += perf_counter_ns() - t0
        self.n += 1
        return r


def timer_overhead_ns(n: int = 20000) -> float:
    """The cost [ns] a :class:`Timed` wrapper adds to a call: the wrapped empty function minus the bare one."""
    def f(*a):
        return None
    w = Timed(f)
    t0 = perf_counter_ns()
    for _ in range(n):
        f(1, 2)
    bare = perf_counter_ns() - t0
    t0 = perf_counter_ns()
    for _ in range(n):
        w(1, 2)
    return max(0.0, (perf_counter_ns() - t0 - bare) / n)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path, default=RESULTS_DIR / "mujoco_period.json")
    a = ap.parse_args(argv)
    provenance.track(a.json, argv=argv, plant="mujoco")
    import mujoco

    from biped_controller.core.control.config import load_controller_config
    from biped_controller.closed_loop import runner, segment
    from biped_sim.plant.config import load_sim_config
    from biped_sim.plant.push import Push
    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily

    scfg = load_sim_config(plant="mujoco")
    ccfg = load_controller_config(mode="both", period=scfg.control_period)
    family, desc = GaitFamily.load(), load_description()
    loop = runner.ClosedLoop(scfg, ccfg, family, desc)
    push = (Push(*PUSH),)
    has_compiled_loop = hasattr(runner, "MujocoSegment")
    paths = ("python_steps", "compiled_steps") + (("compiled_loop",) if has_compiled_loop else ())

    def one(path: str):
        loop.sim.compiled_steps = path != "python_steps"
        loop.reset()
        gc.collect()
        c0, t0 = time.process_time(), time.perf_counter()
        r = loop.run(a.steps, push, limit=10.0, compiled_loop=path == "compiled_loop")
        return r, time.perf_counter() - t0, time.process_time() - c0

    for p in paths:          # warm-up: the kernels loaded, the buffers allocated
        one(p)
    load0 = os.getloadavg()[0]
    date = time.strftime("%Y-%m-%d %H:%M:%S")
    acc = {p: [0.0, 0.0, 0.0, 0] for p in paths}
    ref = None
    equal = {}
    for _ in range(a.repeats):
        for p in paths:
            r, wall, cpu = one(p)
            sim_t = r.records[-1].t_end
            acc[p][0] += sim_t
            acc[p][1] += wall
            acc[p][2] += cpu
            acc[p][3] += len(r.records)
            if p == "python_steps":
                ref = r
            else:
                equal[p] = equal.get(p, True) and records_equal(ref.records, r.records)
            del r
    timed = {}
    for p, (sim_t, wall, cpu, n) in acc.items():
        timed[p] = {"periods": n, "sim_s": sim_t, "wall_s": wall, "cpu_s": cpu, "realtime_factor": sim_t / wall,
                    "realtime_factor_cpu": sim_t / cpu, "us_per_period": wall / n * 1e6,
                    "us_per_period_cpu": cpu / n * 1e6,
                    "records_equal_to_python_steps": equal.get(p, True)}
    load1 = os.getloadavg()[0]

    # the instrumented runs: where a period goes (each path --repeats times, interleaved; the median per figure)
    over = timer_overhead_ns()

    def split_once(p: str) -> dict:
        sim, ctrl = loop.sim, loop.ctrl
        sim.compiled_steps = p != "python_steps"
        loop.reset()
        w = {}
        if p != "compiled_loop":
            w = {"controller_compute": Timed(ctrl.compute), "plant_observe": Timed(sim.observe),
                 "plant_step": Timed(sim.step)}
        saved_mj = (mujoco.mj_step, mujoco.mj_rnePostConstraint)
        mlk = segment.load_mujoco_loop_kernels() if has_compiled_loop else None
        saved_seg = mlk.run_mujoco_segment if mlk is not None else None
        if p == "python_steps":
            inner = {"mj_step": Timed(mujoco.mj_step), "mj_rnePostConstraint": Timed(mujoco.mj_rnePostConstraint),
                     "after_step_kernel": Timed(sim._after_step)}
            mujoco.mj_step, mujoco.mj_rnePostConstraint = inner["mj_step"], inner["mj_rnePostConstraint"]
            sim._after_step = inner["after_step_kernel"]
        elif p == "compiled_steps":
            inner = {"substeps_kernel": Timed(sim._substeps)}
            sim._substeps = inner["substeps_kernel"]
        else:
            inner = {"segment_kernel": Timed(saved_seg)}
            mlk.run_mujoco_segment = inner["segment_kernel"]
        if w:
            ctrl.compute, sim.observe, sim.step = w["controller_compute"], w["plant_observe"], w["plant_step"]
        gc.collect()
        t0 = perf_counter_ns()
        try:
            r = loop.run(a.steps, push, limit=10.0, compiled_loop=p == "compiled_loop")
        finally:
            wall = perf_counter_ns() - t0
            mujoco.mj_step, mujoco.mj_rnePostConstraint = saved_mj
            for o, names in ((ctrl, ("compute",)), (sim, ("observe", "step"))):
                for name in names:
                    o.__dict__.pop(name, None)
            sim._after_step = sim._k.after_step
            sim._substeps = sim._k.substeps
            if mlk is not None:
                mlk.run_mujoco_segment = saved_seg
        n = len(r.records)
        per = {}
        for name, t in {**w, **inner}.items():
            per[name] = (t.ns - over * t.n) / n / 1e3
            per[name + "_calls_per_period"] = t.n / n
        total = wall / n / 1e3 - over * sum(t.n for t in (*w.values(), *inner.values())) / n / 1e3
        if w:
            # the inner calls' timers ran inside the plant's step: their cost is not the step's
            per["plant_step"] -= over * sum(t.n for t in inner.values()) / n / 1e3
            per["plant_step_rest"] = per["plant_step"] - sum(per[k] for k in inner)
            per["loop_rest"] = total - sum(per[k] for k in w)
        else:
            per["python_rest"] = total - per["segment_kernel"]
        per["total"] = total
        return per

    runs: dict = {p: [] for p in paths}
    for _ in range(a.repeats):
        for p in paths:
            runs[p].append(split_once(p))
    split = {p: {k: float(np.median([r[k] for r in rs])) for k in rs[0]} for p, rs in runs.items()}
    load2 = os.getloadavg()[0]
    out = {"meta": {"date": date, "steps": a.steps, "repeats": a.repeats, "push": dict(zip(("start", "duration",
                                                                                           "force"), PUSH)),
                    "mode": "both", "mujoco_timestep": scfg.mujoco_timestep, "cpus": os.cpu_count(),
                    "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
                    "loadavg_1min_before": load0, "loadavg_1min_after": load1, "loadavg_1min_after_split": load2,
                    "timer_overhead_ns_per_call": over},
           "timed": timed, "split": split}
    base = timed["python_steps"]["realtime_factor"]
    out["speedup_over_python_steps"] = {p: timed[p]["realtime_factor"] / base for p in paths}
    out["keys"] = {f"mujoco_period.{p}.realtime_factor": timed[p]["realtime_factor"] for p in paths}
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(f"MuJoCo closed loop, mode both, {a.steps} steps x {a.repeats}, {date}, load {load0:.2f} -> {load1:.2f}")
    print("| path | sim s / wall s | us per period (wall) | sim s / CPU s | us per period (CPU) | records equal |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    for p in paths:
        t = timed[p]
        print(f"| {p} | {t['realtime_factor']:.2f} | {t['us_per_period']:.1f} | {t['realtime_factor_cpu']:.2f} | "
              f"{t['us_per_period_cpu']:.1f} | {t['records_equal_to_python_steps']} |")
    print("where a period goes (instrumented runs, median of the repeats, us per period):")
    for p, per in split.items():
        print(f"{p}: " + ", ".join(f"{k} {v:.1f}" for k, v in per.items() if not k.endswith("_calls_per_period")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
