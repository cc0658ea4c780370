"""Where does one seeded MuJoCo real-sensor trial spend its time? cProfile of ``trial.seeded.seeded_trial`` (the
pushed run with the early stop, and its seed's unpushed walk, the band), as the probabilistic 25 ms slice runs it
(profile ``real-sensors-mujoco``, issue 43), in this process.

    .venv/bin/python -m lab.mujoco_trial_profile [--mode both] [--phase 0.5] [--direction backward]
        [--force 400] [--seeds 0 1] [--objects] --json results/uncertainty/mujoco_trial_profile/F.json

``--objects`` runs the trials with ``compiled_loop=False`` (every period on the objects: ``observe``,
``AdaptiveController.compute``, ``MujocoPlant.step``), for the side by side. One warm-up trial (seed 10000) loads
and compiles the kernels outside the profile. The JSON holds the seconds, the control periods simulated, the
functions with the most own time and the most cumulative time (seconds under the profiler, which inflates
Python-heavy code more than the kernels; the profiler's clock is this process's CPU time, since the machine
is shared), and the load average.
"""
from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import time
from pathlib import Path


def _rows(stats: pstats.Stats, key: str, n: int) -> list[dict]:
    """The ``n`` functions with the largest ``key`` (``tottime`` or ``cumtime``): name, calls, own and
    cumulative seconds."""
    idx = 2 if key == "tottime" else 3
    items = sorted(stats.stats.items(), key=lambda kv: kv[1][idx], reverse=True)[:n]
    out = []
    for (file, line, name), (_cc, nc, tt, ct, _callers) in items:
        short = file.split("site-packages/")[-1].split("/src/")[-1]
        out.append({"function": f"{short}:{line}({name})", "calls": nc, "own_s": round(tt, 4), "cum_s": round(ct, 4)})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mode", default="both")
    ap.add_argument("--profile", default="real-sensors-mujoco")
    ap.add_argument("--phase", type=float, default=0.5, help="onset phase of the first step")
    ap.add_argument("--direction", choices=("forward", "backward"), default="backward")
    ap.add_argument("--duration", type=float, default=0.025, help="[s]")
    ap.add_argument("--force", type=float, default=400.0, help="[N] magnitude")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--objects", action="store_true", help="compiled_loop=False: every period on the objects")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args(argv)

    from biped_controller.closed_loop import runner
    from biped_controller.studies import provenance
    from biped_controller.studies.capmap.spec import onset_time
    from biped_controller.studies.trial import seeded
    from biped_controller.studies.trial.context import context
    from biped_controller.studies.trial.runs import paper_push
    from biped_controller.studies.trial.settings import run_settings

    provenance.track(args.json, argv=argv, plant="mujoco" if "mujoco" in args.profile else "rigid",
                     profile=args.profile)
    base = run_settings(args.profile)
    base.activate()
    T = context().family.T
    sign = 1.0 if args.direction == "forward" else -1.0
    push = paper_push(sign * args.force, start=onset_time(args.phase, T), duration=args.duration)
    if args.objects:                     # every period on the objects
        orig = runner.ClosedLoop._segment
        runner.ClosedLoop._segment = lambda self, *a, **k: None
    periods = [0]
    orig_run = runner.ClosedLoop.run

    def counting(self, *a, **k):
        out = orig_run(self, *a, **k)
        periods[0] += self.sim.step_index
        return out
    runner.ClosedLoop.run = counting
    seeded.seeded_trial(push, args.mode, seeded.seeded_settings(base, 10_000))     # warm-up, outside the profile
    periods[0] = 0
    prof = cProfile.Profile(time.process_time)     # CPU seconds: the machine is shared
    load0 = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    recs = []
    prof.enable()
    for s in args.seeds:
        recs.append(seeded.seeded_trial(push, args.mode, seeded.seeded_settings(base, s)))
    prof.disable()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if args.objects:
        runner.ClosedLoop._segment = orig
    st = pstats.Stats(prof)
    out = {"mode": args.mode, "profile": args.profile, "push": {"start": push.start, "duration": push.duration,
                                                                 "force": push.force},
           "seeds": args.seeds, "objects": args.objects, "wall_s_profiled": wall, "cpu_s_profiled": cpu,
           "control_periods": periods[0], "cpu_us_per_period_profiled": 1e6 * cpu / max(periods[0], 1),
           "outcomes": [{k: r.get(k) for k in ("seed", "survived", "reason", "steps_walked", "unpushed_fall")}
                        for r in recs],
           "top_own": _rows(st, "tottime", args.top), "top_cumulative": _rows(st, "cumtime", args.top),
           "load_average_start": list(load0), "load_average_end": list(os.getloadavg())}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(f"{len(args.seeds)} trials, {periods[0]} control periods, {wall:.2f} s wall ({cpu:.2f} CPU s) under the "
          f"profiler; {out['cpu_us_per_period_profiled']:.0f} CPU us a period")
    for r in out["top_own"][:15]:
        print(f"  own {r['own_s']:7.3f} s  cum {r['cum_s']:7.3f} s  {r['calls']:8d}  {r['function']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
