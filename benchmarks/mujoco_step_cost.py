"""What one MuJoCo step costs, where it goes, and what real-time factor the MuJoCo closed loop can reach.

``.venv/bin/python -m benchmarks.mujoco_step_cost [--steps 5] [--repeats 3] [--json results/benchmarks/mujoco_step_cost.json]``

1. **States.** The walk of ``scripts/bench``'s in-process section (unpushed, mode both, ``--steps`` steps, the
   fast engine) on the MuJoCo plant of the configuration files, its Python step path (``compiled_steps``
   False), with every MuJoCo
   integration state (``mj_getState``, ``mjSTATE_INTEGRATION``) and step length saved before each ``mj_step``.
2. **One step, replayed.** Each saved state is restored (``mj_setState``) into a fresh ``MjData`` and one
   ``mj_step`` taken, timed with ``time.perf_counter_ns`` around the call (the least over ``--repeats``
   passes of each state's time, then the mean and quantiles over the states); the steps are split into
   those with contacts (``ncon`` > 0 after the step) and without. MuJoCo's own timers (``mjData.timer``:
   collision, constraint assembly and solve, kinematics, ...) give the split of the mean step [us].
3. **The bound.** A control period of ``period`` [s] takes ``period / mujoco_timestep`` MuJoCo steps, so the
   real-time factor of the closed loop is at most ``period / (n_steps * mean step cost)`` even with a
   controller and bookkeeping that cost nothing; the figure is given for the configured step and twice it.
4. **Closed loops side by side.** As ``scripts/bench``'s in-process section times them (``runner.run``, the
   fast engine, the compiled closed loop, every record kept), the same walk, interleaved ``--repeats`` times
   after a warm-up: MuJoCo at the
   configured step, MuJoCo at twice that step (a different simulation: its foot figures are
   ``results/mujoco_foot/tail/``), and the rigid plant. Real-time factor = simulated s / wall s.

Every figure depends on the machine's load (recorded before and after); compare the rows of one run.
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import time

import numpy as np

from benchmarks import RESULTS_DIR
from biped_controller.studies import provenance

TIMERS = ("mjTIMER_STEP", "mjTIMER_FORWARD", "mjTIMER_POSITION", "mjTIMER_POS_KINEMATICS", "mjTIMER_POS_INERTIA",
          "mjTIMER_POS_COLLISION", "mjTIMER_COL_BROAD", "mjTIMER_COL_NARROW", "mjTIMER_POS_MAKE",
          "mjTIMER_POS_PROJECT", "mjTIMER_VELOCITY", "mjTIMER_ACTUATION", "mjTIMER_CONSTRAINT", "mjTIMER_ADVANCE")


def capture_states(loop, steps: int) -> list[tuple[np.ndarray, float]]:
    """Every MuJoCo integration state of one run of ``loop`` (Python step path), with the step length [s]."""
    import mujoco
    m = loop.sim.model
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    size = mujoco.mj_stateSize(m, spec)
    states: list[tuple[np.ndarray, float]] = []
    step = mujoco.mj_step

    def saving(model, data):
        s = np.empty(size)
        mujoco.mj_getState(model, data, s, spec)
        states.append((s, float(model.opt.timestep)))
        step(model, data)

    loop.sim.compiled_steps = False
    mujoco.mj_step = saving
    try:
        loop.reset()
        loop.run(steps, (), limit=10.0, compiled_loop=False)
    finally:
        mujoco.mj_step = step
        loop.sim.compiled_steps = True
    return states


def replay(model, states, repeats: int) -> dict:
    """Time one ``mj_step`` from each saved state (module docstring, 2.)."""
    import mujoco
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    data = mujoco.MjData(model)
    h0 = model.opt.timestep
    ns = np.empty((repeats, len(states)))
    ncon = np.empty(len(states), dtype=np.int64)
    for r in range(repeats):
        for i, (s, h) in enumerate(states):
            mujoco.mj_setState(model, data, s, spec)
            model.opt.timestep = h
            t0 = time.perf_counter_ns()
            mujoco.mj_step(model, data)
            ns[r, i] = time.perf_counter_ns() - t0
            ncon[i] = data.ncon
    # MuJoCo's timers over one more pass (their sums over the pass / the steps)
    mujoco.mj_resetData(model, data)
    for s, h in states:
        mujoco.mj_setState(model, data, s, spec)
        model.opt.timestep = h
        mujoco.mj_step(model, data)
    model.opt.timestep = h0
    timers = {}
    for name in TIMERS:
        t = data.timer[int(getattr(mujoco.mjtTimer, name))]
        timers[name[len("mjTIMER_"):].lower()] = float(t.duration) / max(int(t.number), 1) * 1e6   # s -> us
    us = ns.min(axis=0) / 1e3           # the least disturbed of the repeats (the machine is shared)
    contact = ncon > 0
    return {"states": len(states), "mean_us": float(us.mean()), "p50_us": float(np.percentile(us, 50)),
            "p90_us": float(np.percentile(us, 90)), "with_contact": int(contact.sum()),
            "mean_us_with_contact": float(us[contact].mean()) if contact.any() else None,
            "mean_us_without_contact": float(us[~contact].mean()) if (~contact).any() else None,
            "mean_contacts": float(ncon.mean()), "mujoco_timers_us_per_step": timers}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=str(RESULTS_DIR / "mujoco_step_cost.json"))
    a = ap.parse_args(argv)
    if a.steps < 1 or a.repeats < 1:
        ap.error("--steps and --repeats must be >= 1")
    provenance.track(a.json, argv=argv, plant="mujoco")

    from biped_controller.core.control.config import load_controller_config
    from biped_controller.closed_loop import runner
    from biped_sim.plant.config import load_sim_config
    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily

    family, desc = GaitFamily.load(), load_description()
    ccfg = load_controller_config(mode="both", engine="fast")
    configs = {"mujoco": load_sim_config(plant="mujoco", engine="fast")}
    h, period = configs["mujoco"].mujoco_timestep, configs["mujoco"].control_period
    configs = {f"mujoco_{h * 1e3:g}ms": configs["mujoco"],
               f"mujoco_{2 * h * 1e3:g}ms": load_sim_config(plant="mujoco", engine="fast", mujoco_timestep=2 * h),
               "rigid": load_sim_config(plant="rigid", engine="fast")}

    load0 = os.getloadavg()[0]
    date = time.strftime("%Y-%m-%d %H:%M:%S")
    loop = runner.ClosedLoop(configs[f"mujoco_{h * 1e3:g}ms"], ccfg, family, desc)
    states = capture_states(loop, a.steps)
    step = replay(loop.sim.model, states, a.repeats)
    bound = {f"{k:g}_ms": period / (round(period / (k * 1e-3)) * step["mean_us"] * 1e-6)
             for k in (h * 1e3, 2 * h * 1e3)}

    acc = {k: [0.0, 0.0, 0] for k in configs}
    for rep in range(a.repeats + 1):
        for k, scfg in configs.items():
            gc.collect()
            t0 = time.perf_counter()
            r = runner.run(steps=a.steps, mode="both", sim_config=scfg, ctrl_config=ccfg, desc=desc, family=family)
            wall = time.perf_counter() - t0
            if rep:                 # the first pass warms up (kernels loaded, buffers allocated)
                acc[k][0] += r.records[-1].t_end
                acc[k][1] += wall
                acc[k][2] += len(r.records)
    closed = {k: {"sim_s": s, "wall_s": w, "periods": n, "realtime_factor": s / w, "us_per_period": w / n * 1e6}
              for k, (s, w, n) in acc.items()}
    load1 = os.getloadavg()[0]
    out = {"meta": {"date": date, "steps": a.steps, "repeats": a.repeats, "mode": "both", "push": None,
                    "control_period": period,
                    "mujoco_timestep": h, "cpus": os.cpu_count(), "machine": platform.processor() or platform.machine(),
                    "python": platform.python_version(), "loadavg_1min_before": load0, "loadavg_1min_after": load1},
           "mj_step": step, "realtime_bound_zero_cost_controller": bound, "closed_loop": closed}
    os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
    with open(a.json, "w", encoding="utf-8") as f:
        f.write(json.dumps(out, indent=1) + "\n")
    print(f"one mj_step, {step['states']} states of an unpushed walk, {date}, load {load0:.2f} -> {load1:.2f}")
    print(f"  mean {step['mean_us']:.2f} us (with contact {step['mean_us_with_contact']:.2f}, without "
          f"{step['mean_us_without_contact']}), {step['mean_contacts']:.2f} contacts a step")
    print("  MuJoCo timers [us/step]: " + ", ".join(f"{k} {v:.2f}" for k, v in step["mujoco_timers_us_per_step"].items()))
    print("  real-time bound with a free controller: " + ", ".join(f"{k} {v:.1f}x" for k, v in bound.items()))
    for k, c in closed.items():
        print(f"  closed loop {k}: {c['realtime_factor']:.2f}x ({c['us_per_period']:.1f} us a period)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
