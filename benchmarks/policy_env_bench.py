"""Speed of the Gymnasium environment (``BipedPush-v0``) beside the floor its plant's own step cost sets,
measured in one run.

``.venv/bin/python -m benchmarks.policy_env_bench [--plant mujoco] [--steps 3000] [--repeats 3] [--quick]
[--workers 2] [--per-worker 8] [--json results/benchmarks/policy_env.json]``

What is timed (the policy's own evaluation is not: only ``env.reset`` and ``env.step`` calls):

* ``single``: one environment in this process at the default policy period (config/policy_env.yaml), random
  pushes (``RandomPushes``, seeded) and a fixed seeded linear policy (tanh of a small linear map of the
  observation: it falls after a few hundred milliseconds, so resets are part of the figure, as in training);
  env steps per second;
* ``floor_single``: the same episodes replayed on a bare plant (``make_plant``; ``reset``, the pushes, then
  ``plant.step`` with the torques the environment applied, period by period; ``observe`` where the sensor
  model needs it): what the environment would reach if it cost nothing beyond its plant. The floor in env
  steps per second is the bare plant's periods per second over the environment's plant periods per env step;
* ``vector2``: ``gymnasium.vector.AsyncVectorEnv`` of two environments (two worker processes), the same
  policy on the batch; env steps per second summed over both (the autoreset calls not counted as steps);
* ``floor_vector2``: two bare-plant replays (``floor_single``'s episodes) at once in two processes, their
  periods per second summed, over the vector run's plant periods per env step;
* ``batch``: the product's vector form (``policy.vector.BatchVectorEnv``, next-step autoreset, all infos
  kept) of ``--workers`` processes (2) of ``--per-worker`` environments each (8), the same environments and
  policy; about as many env steps in all as ``vector2`` (``2 * --steps``), ``--repeats`` times alternating
  with ``floor_batch``: two bare-plant replays as ``floor_vector2``'s, over the batch run's plant periods per
  env step; both summed over the repeats.

Keys: ``policy_env.<plant>.single.env_steps_per_s``, ``...floor_single.env_steps_per_s``,
``...single.over_floor`` (target >= 0.7; ``...over_floor_cpu`` the same in CPU time: the vector run's CPU is
its workers' from after the first reset to the last step, read in each worker, plus this process's in
``step``; its floor's the two replays' own),
the same for ``vector2`` and ``batch``. A vector step waits for both workers, so on a loaded machine its wall-time rate
pays for the slower one each step, which the free-running replays do not: the CPU ratio separates that. The single-core run and its floor alternate ``--repeats`` times and are summed, as do the batch run and
its floor. The machine is shared: the ratios
compare figures of this one run; the target is printed, never asserted.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import time
from pathlib import Path

import numpy as np

from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR

TARGET = 0.7
RUNS = (("single", "floor_single"), ("vector2", "floor_vector2"), ("batch", "floor_batch"))
DIST = {"force_min": 0.0, "force_max": 150.0, "onset_min": 0.02, "onset_max": 0.2, "p_none": 0.3}


def policy(seed: int = 2, scale: float = 0.01):
    from biped_controller.policy.spec import OBS_SIZE
    rng = np.random.default_rng(seed)
    W, b = scale * rng.standard_normal((OBS_SIZE, 6)), scale * rng.standard_normal(6)
    return lambda obs: np.tanh(obs @ W + b)


def make_env(plant: str, keep_records: bool = False):
    import gymnasium as gym
    import biped_controller.policy  # noqa: F401
    from biped_controller.policy.env import make_random_push_env

    class CpuClock(gym.Wrapper):
        """``cpu_seconds()``: this process's CPU time (read in a vector env's worker through ``call``)."""

        def cpu_seconds(self) -> float:
            return time.process_time()
    return CpuClock(make_random_push_env(DIST, seed=0, plant=plant, keep_records=keep_records))


def run_single(plant: str, steps: int, record: bool) -> dict:
    """``steps`` env steps in episodes seeded 0, 1, ...; the time in reset and step; with ``record`` the
    episodes (initial state, pushes, applied torques per plant period) for the floor's replay."""
    env = make_env(plant, keep_records=record)
    u = env.unwrapped
    pol = policy()
    episodes, t_env, c_env, n, periods, ep = [], 0.0, 0.0, 0, 0, 0
    while n < steps:
        t0, c0 = time.perf_counter(), time.process_time()
        obs, info = env.reset(seed=ep)
        t_env += time.perf_counter() - t0
        c_env += time.process_time() - c0
        while n < steps:
            a = pol(obs)
            t0, c0 = time.perf_counter(), time.process_time()
            obs, r, term, trunc, info = env.step(a)
            t_env += time.perf_counter() - t0
            c_env += time.process_time() - c0
            n += 1
            if term or trunc:
                break
        periods += u.sim.step_index
        if record:
            episodes.append({"q0": u.initial_state[0], "qd0": u.initial_state[1],
                             "pushes": [(p.start, p.duration, p.force, p.height) for p in u._pushes],
                             "torques": np.array([rec.torque for rec in u.records])})
        ep += 1
    return {"env_steps": n, "episodes": ep, "plant_periods": periods, "seconds": t_env, "cpu_seconds": c_env,
            "env_steps_per_s": n / t_env, "env_steps_per_cpu_s": n / c_env, "periods_per_env_step": periods / n,
            "recorded": episodes}


def replay(plant: str, episodes: list[dict]) -> dict:
    """The bare plant over ``episodes`` (module docstring): periods and seconds."""
    from biped_sim.plant.protocol import make_plant
    from biped_controller.studies.trial.settings import run_settings
    from biped_controller.studies.trial.context import context
    s = run_settings(None, [f"plant={plant}"])
    ctx = context(s.robot)
    sim = make_plant(s.sim_config().plant, ctx.desc, s.sim_config(), s.perturbation)
    identity = sim.sensor.identity
    n, t_all, c_all = 0, 0.0, 0.0
    for e in episodes:
        t0, c0 = time.perf_counter(), time.process_time()
        sim.reset(e["q0"], e["qd0"], 0)
        for p in e["pushes"]:
            sim.schedule_push(*p)
        for tq in e["torques"]:
            if not identity:
                sim.observe()
            sim.step(tq)
            n += 1
            if sim.fall is not None:
                break
        t_all += time.perf_counter() - t0
        c_all += time.process_time() - c0
    return {"plant_periods": n, "seconds": t_all, "cpu_seconds": c_all, "periods_per_s": n / t_all,
            "periods_per_cpu_s": n / c_all}


def _replay_worker(args):
    plant, episodes = args
    return replay(plant, episodes)


def run_vector(plant: str, steps: int) -> dict:
    """``steps`` env steps per environment on an AsyncVectorEnv of two (module docstring)."""
    import gymnasium as gym
    vec = gym.vector.AsyncVectorEnv([lambda: make_env(plant) for _ in range(2)], context="fork")
    pol = policy()
    try:
        t0 = time.perf_counter()
        obs, info = vec.reset(seed=[0, 1000])
        t_env = time.perf_counter() - t0
        w0 = np.array(vec.call("cpu_seconds"))
        n, dt, c_main, periods = _drive(vec, pol, obs, 2, 2 * steps)
        t_env += dt
        w1 = np.array(vec.call("cpu_seconds"))
    finally:
        vec.close()
    cpu = float((w1 - w0).sum()) + c_main     # the workers' CPU over the steps and this process's in step
    return {"env_steps": n, "seconds": t_env, "env_steps_per_s": n / t_env, "plant_periods": periods,
            "periods_per_env_step": periods / n, "cpu_seconds": cpu, "env_steps_per_cpu_s": n / cpu}


def _drive(vec, pol, obs, n_env: int, steps: int) -> tuple[int, float, float, int]:
    """Step ``vec`` (``n_env`` environments, next-step autoreset) with ``pol`` from ``obs`` until ``steps`` env
    steps (autoreset calls not counted): (env steps, wall seconds in ``step``, this process's CPU seconds in
    ``step``, plant periods)."""
    n, t_env, c_main, periods = 0, 0.0, 0.0, 0
    autoreset = np.zeros(n_env, dtype=bool)
    prev = np.zeros(n_env)
    while n < steps:
        a = pol(obs)
        t0, c0 = time.perf_counter(), time.process_time()
        obs, r, term, trunc, info = vec.step(a)
        t_env += time.perf_counter() - t0
        c_main += time.process_time() - c0
        n += int((~autoreset).sum())
        # plant periods of this step: the plant's period count since its reset, minus the count before
        k = np.asarray(info["plant_periods"], dtype=float)
        periods += int(np.where(autoreset, 0.0, k - prev).sum())
        prev = k
        autoreset = np.logical_or(term, trunc)
    return n, t_env, c_main, periods


def run_batch(plant: str, steps: int, workers: int, per_worker: int) -> dict:
    """About ``2 * steps`` env steps in all (the vector2 run's) on a ``BatchVectorEnv`` of ``workers`` processes
    of ``per_worker`` environments each, all infos kept (module docstring)."""
    from biped_controller.policy.vector import BatchVectorEnv
    n_env = workers * per_worker
    vec = BatchVectorEnv([lambda: make_env(plant) for _ in range(n_env)], workers=workers, context="fork")
    pol = policy()
    first = [s.start for s in vec.worker_slices]
    try:
        t0 = time.perf_counter()
        obs, info = vec.reset(seed=[1000 * j for j in range(n_env)])
        t_env = time.perf_counter() - t0
        w0 = np.array(vec.call("cpu_seconds"))[first]
        n, dt, c_main, periods = _drive(vec, pol, obs, n_env, 2 * steps)
        t_env += dt
        w1 = np.array(vec.call("cpu_seconds"))[first]
    finally:
        vec.close()
    cpu = float((w1 - w0).sum()) + c_main
    return {"env_steps": n, "seconds": t_env, "plant_periods": periods, "cpu_seconds": cpu}


def replay_pair(plant: str, episodes: list[dict]) -> dict:
    """Two bare-plant replays of ``episodes`` at once in two processes: periods, wall and CPU seconds."""
    with mp.get_context("fork").Pool(2) as pool:
        t0 = time.perf_counter()
        both = pool.map(_replay_worker, [(plant, episodes)] * 2)
        wall = time.perf_counter() - t0
    return {"plant_periods": sum(b["plant_periods"] for b in both), "wall_seconds": wall,
            "cpu_seconds": sum(b["cpu_seconds"] for b in both)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plant", choices=("mujoco", "rigid"), default="mujoco")
    ap.add_argument("--steps", type=int, default=3000, help="env steps (per environment in the vector run)")
    ap.add_argument("--repeats", type=int, default=3, help="single-core runs, each beside its floor (default 3)")
    ap.add_argument("--quick", action="store_true", help="300 env steps")
    ap.add_argument("--workers", type=int, default=2, help="BatchVectorEnv worker processes (default 2)")
    ap.add_argument("--per-worker", type=int, default=8, help="BatchVectorEnv environments per worker (default 8)")
    ap.add_argument("--json", type=Path, default=RESULTS_DIR / "policy_env.json")
    a = ap.parse_args(argv)
    steps = 300 if a.quick else a.steps
    if steps < 1:
        ap.error("--steps must be >= 1")
    if a.workers < 1 or a.per_worker < 1 or a.repeats < 1:
        ap.error("--workers, --per-worker and --repeats must be >= 1")
    provenance.track(a.json, argv=argv, plant=a.plant)
    from biped_controller.policy.env import load_env_config
    from biped_sim.plant.config import load_sim_config
    period = load_env_config().policy_period
    control = load_sim_config().control_period
    load0 = os.getloadavg()[0]
    run_single(a.plant, min(steps, 200), record=False)             # warm-up: kernels and caches loaded
    rec = run_single(a.plant, steps, record=True)                  # the episodes, recorded
    episodes = rec.pop("recorded")
    replay(a.plant, episodes[:3])                                  # warm-up
    # the environment and its floor interleaved, repeat by repeat (the machine is shared), summed
    acc_env, acc_floor = [], []
    for _ in range(a.repeats):
        r = run_single(a.plant, steps, record=False)
        r.pop("recorded")
        acc_env.append(r)
        acc_floor.append(replay(a.plant, episodes))
    single = {k: sum(r[k] for r in acc_env) for k in ("env_steps", "plant_periods", "seconds", "cpu_seconds")}
    single.update(env_steps_per_s=single["env_steps"] / single["seconds"],
                  env_steps_per_cpu_s=single["env_steps"] / single["cpu_seconds"],
                  periods_per_env_step=single["plant_periods"] / single["env_steps"], repeats=a.repeats,
                  over_floor_each_repeat=[e["seconds"] and (f["seconds"] / e["seconds"]) * (e["plant_periods"] / f["plant_periods"])
                                          for e, f in zip(acc_env, acc_floor)])
    floor = {k: sum(r[k] for r in acc_floor) for k in ("plant_periods", "seconds", "cpu_seconds")}
    floor.update(periods_per_s=floor["plant_periods"] / floor["seconds"],
                 periods_per_cpu_s=floor["plant_periods"] / floor["cpu_seconds"])
    vector = run_vector(a.plant, steps)
    with mp.get_context("fork").Pool(2) as pool:
        t0 = time.perf_counter()
        both = pool.map(_replay_worker, [(a.plant, episodes)] * 2)
        wall2 = time.perf_counter() - t0
    # the batched vector form and two bare replays interleaved, repeat by repeat, summed
    acc_b, acc_bf = [], []
    for _ in range(a.repeats):
        acc_b.append(run_batch(a.plant, steps, a.workers, a.per_worker))
        acc_bf.append(replay_pair(a.plant, episodes))
    batch = {k: sum(r[k] for r in acc_b) for k in ("env_steps", "plant_periods", "seconds", "cpu_seconds")}
    batch.update(workers=a.workers, envs_per_worker=a.per_worker, repeats=a.repeats,
                 env_steps_per_s=batch["env_steps"] / batch["seconds"],
                 env_steps_per_cpu_s=batch["env_steps"] / batch["cpu_seconds"],
                 periods_per_env_step=batch["plant_periods"] / batch["env_steps"],
                 over_floor_each_repeat=[(f["wall_seconds"] / e["seconds"]) * (e["plant_periods"] / f["plant_periods"])
                                         for e, f in zip(acc_b, acc_bf)])
    bfloor = {k: sum(r[k] for r in acc_bf) for k in ("plant_periods", "wall_seconds", "cpu_seconds")}
    bfloor.update(periods_per_s=bfloor["plant_periods"] / bfloor["wall_seconds"],
                  env_steps_per_s=bfloor["plant_periods"] / bfloor["wall_seconds"] / batch["periods_per_env_step"],
                  env_steps_per_cpu_s=bfloor["plant_periods"] / bfloor["cpu_seconds"] / batch["periods_per_env_step"])
    cpu2 = sum(b["cpu_seconds"] for b in both)
    floor2_pps = sum(b["plant_periods"] for b in both) / wall2
    res = {
        "single": single,
        "floor_single": {**floor, "env_steps_per_s": floor["periods_per_s"] / single["periods_per_env_step"],
                         "env_steps_per_cpu_s": floor["periods_per_cpu_s"] / single["periods_per_env_step"]},
        "vector2": vector,
        "floor_vector2": {"plant_periods": sum(b["plant_periods"] for b in both), "wall_seconds": wall2,
                          "periods_per_s": floor2_pps, "cpu_seconds": cpu2,
                          "env_steps_per_s": floor2_pps / vector["periods_per_env_step"],
                          "env_steps_per_cpu_s": sum(b["plant_periods"] for b in both) / cpu2
                          / vector["periods_per_env_step"]},
        "batch": batch,
        "floor_batch": bfloor,
    }
    res["single"]["over_floor"] = res["single"]["env_steps_per_s"] / res["floor_single"]["env_steps_per_s"]
    for k, f in RUNS:
        res[k]["over_floor_cpu"] = res[k]["env_steps_per_cpu_s"] / res[f]["env_steps_per_cpu_s"]
    for k, f in RUNS[1:]:
        res[k]["over_floor"] = res[k]["env_steps_per_s"] / res[f]["env_steps_per_s"]
    meta = {"date": time.strftime("%Y-%m-%d %H:%M:%S"), "plant": a.plant, "steps": steps,
            "policy_period": period, "control_period": control, "cpus": os.cpu_count(),
            "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
            "loadavg_1min_before": load0, "loadavg_1min_after": os.getloadavg()[0],
            "episodes_single": rec["episodes"], "random_pushes": DIST}
    keys = {}
    for k in ("single", "floor_single", "vector2", "floor_vector2", "batch", "floor_batch"):
        keys[f"policy_env.{a.plant}.{k}.env_steps_per_s"] = res[k]["env_steps_per_s"]
    for k in ("single", "vector2", "batch"):
        keys[f"policy_env.{a.plant}.{k}.over_floor"] = res[k]["over_floor"]
        keys[f"policy_env.{a.plant}.{k}.over_floor_cpu"] = res[k]["over_floor_cpu"]
    out = {"meta": meta, "target_over_floor": TARGET, "results": res, "keys": keys}
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(f"BipedPush-v0 on {a.plant}, policy period {period * 1e3:g} ms over a {control * 1e3:g} ms plant period, "
          f"{steps} env steps, load average {load0:.1f} -> {meta['loadavg_1min_after']:.1f} on {meta['cpus']} CPUs")
    print("| run | env steps/s | plant periods per env step | floor env steps/s | over floor (target >= 0.7) |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for k, f in RUNS:
        r = res[k]
        print(f"| {k} | {r['env_steps_per_s']:.0f} | {r['periods_per_env_step']:.2f} | "
              f"{res[f]['env_steps_per_s']:.0f} | {r['over_floor']:.2f} |")
    for k, f in RUNS:
        print(f"{k}, in CPU time: {res[k]['env_steps_per_cpu_s']:.0f} env steps per CPU s beside a floor of "
              f"{res[f]['env_steps_per_cpu_s']:.0f}: {res[k]['over_floor_cpu']:.2f}")
    print(f"single, wall-time ratio of each repeat: "
          f"{', '.join(f'{x:.2f}' for x in res['single']['over_floor_each_repeat'])}")
    print(f"batch ({a.workers} workers x {a.per_worker} environments), wall-time ratio of each repeat: "
          f"{', '.join(f'{x:.2f}' for x in res['batch']['over_floor_each_repeat'])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
