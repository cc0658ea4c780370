"""Wall and CPU time of the answers over seeds beside their deterministic counterparts, in one run (issue 43).

``python -m benchmarks.uncertainty_table [--seeds 8] [--workers 2] [--modes both] [--profile real-sensors]
[--slice-phases 0] [--slice-seeds 16] [--slice-modes both,wbc] [--out results/uncertainty]`` runs, one after
the other, each as its own process (each records its own provenance beside its JSON; their printed tables
go to ``tables.txt``):

1. the max-push table at the paper's cell (the default push window) with the profile (``real-sensors``: the
   rigid plant, ``real-sensors-mujoco``: MuJoCo; both put the design-point sensor noise on the plant):
   deterministic, one trial per force with the noise's seed 0 (``deterministic.json``), then over seeds,
   ``--seeds N`` (``seeds_N.json``);
2. with ``--slice-phases P`` (> 0), the 25 ms slice of the capability map (forward, onset phases k / P; the map's
   search, or ``--slice-coarse``, ``--slice-resolution``): the deterministic map (``slice_deterministic.json``,
   its store in a fresh temporary directory) and the map over ``--slice-seeds`` seeds (``slice_seeds_N.json``,
   likewise); with ``--slice-full`` also the map over seeds with ``--full-trials`` (``slice_seeds_N_full.json``:
   every noisy trial run in full, as before the early stop under sensor noise), after it, and the ratio of
   the two, with the outcomes compared cell by cell (rates and crossings).

3. with ``--trial-reps K`` (> 0), one survival trial's cost on the two paths, in this process: K seeded trials
   (each mode of ``--trial-mode`` (a comma list), ``--trial-force`` at the paper's window, seeds 0..K-1, each
   its pushed run and its seed's unpushed walk, as the seeded table runs them) with the compiled closed loop
   (real sensing in the loop: ``loop_kernels.run_segment``'s ``sensing`` on the rigid plant,
   ``mujoco_loop_kernels.run_mujoco_segment``'s on MuJoCo) and with the objects (``compiled_loop=False``, the
   only path a MuJoCo real-sensor trial had before), alternating trial by trial so both see the same load; per
   path the median wall time and CPU time per trial, and the ratios; the two paths' outcomes are compared (they
   are equal record for record: tests). ``--no-tables``: item 3 alone.

``timing.json``: per run the benchmark's clock around the process, the process's own wall time, the CPU
seconds of the process and its workers (``resource.getrusage(RUSAGE_CHILDREN)`` before and after: on a
shared machine the CPU seconds compare where wall times do not), the trial count, the load average at each
end; and the ratios seeded / deterministic.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def command(json_path: Path, modes: str, workers: int, seeds: int | None, profile: str = "real-sensors") -> list[str]:
    """The experiment's command line of one of the two tables."""
    cmd = [sys.executable, "-m", "biped_controller.studies.experiment", "table", "--profile", profile,
           "--modes", modes, "--workers", str(workers), "--json", str(json_path)]
    return cmd + (["--seeds", str(seeds)] if seeds is not None else [])


def slice_command(json_path: Path, store: Path, modes: str, workers: int, phases: int, seeds: int | None,
                  profile: str, search: tuple[float | None, float | None] = (None, None),
                  full_trials: bool = False) -> list[str]:
    """The capability map's command line of the 25 ms forward slice (deterministic, or over seeds; ``search``:
    its coarse step and resolution [N], None: the map's; ``full_trials``: no early stop)."""
    cmd = [sys.executable, "-m", "biped_controller.studies.capability_map", "--modes", modes, "--profile", profile,
           "--durations", "0.025", "--directions", "forward", "--phases", str(phases), "--workers", str(workers),
           "--no-progress", "--store", str(store), "--json", str(json_path)]
    for flag, value in zip(("--coarse", "--resolution"), search):
        if value is not None:
            cmd += [flag, f"{value:g}"]
    return cmd + (["--seeds", str(seeds)] if seeds is not None else []) + (["--full-trials"] if full_trials else [])


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def timed(cmd: list[str], log) -> dict:
    """Run ``cmd``; its wall time on this clock, its CPU seconds (with its workers) and the load average."""
    load0, cpu0 = os.getloadavg(), _cpu_children()
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=log, stderr=subprocess.DEVNULL)
    return {"command": " ".join(cmd[1:]), "process_wall_s": time.perf_counter() - t0,
            "cpu_s": _cpu_children() - cpu0, "load_average_start": list(load0), "load_average_end": list(os.getloadavg())}


def run_table(json_path: Path, modes: str, workers: int, seeds: int | None, profile: str, log) -> dict:
    """One table, timed; its JSON's wall time and its trial count."""
    out = timed(command(json_path, modes, workers, seeds, profile), log)
    data = json.loads(json_path.read_text(encoding="utf-8"))
    return {**out, "json": json_path.name, "table_wall_time_s": data["wall_time"],
            "trials": sum(len(r["trials"]) for r in data["modes"].values())}


def run_slice(json_path: Path, modes: str, workers: int, phases: int, seeds: int | None, profile: str, log,
              search: tuple[float | None, float | None] = (None, None), full_trials: bool = False) -> dict:
    """One slice, timed, from an empty store; its simulation count."""
    with tempfile.TemporaryDirectory() as tmp:
        out = timed(slice_command(json_path, Path(tmp) / "store.jsonl", modes, workers, phases, seeds, profile, search,
                                  full_trials), log)
    data = json.loads(json_path.read_text(encoding="utf-8"))
    n = data["trials_run"] if seeds is not None else data["run"]["simulations_run"]
    return {**out, "json": json_path.name, "trials": n}


def trial_cost(reps: int, profile: str, mode: str, force: float) -> dict:
    """Item 3 of the module docstring: the median wall time of one seeded trial (its pushed run and its
    unpushed walk, records as the seeded table keeps them) on the compiled loop and on the objects."""
    import statistics
    from dataclasses import replace

    from biped_controller.closed_loop import runner
    from biped_controller.studies.trial import runs
    from biped_controller.studies.trial.context import context
    from biped_controller.studies.trial.settings import run_settings
    from biped_controller.studies.trial.survival import survival_rule

    ctx = context()
    base = run_settings(profile)
    push = runs.paper_push(force)
    steps = runs.trial_steps(push)
    rule = survival_rule()

    def one(seed: int, compiled: bool) -> tuple[float, float, int, tuple]:
        s = replace(base, perturbation=replace(base.perturbation, seed=seed))
        kw = dict(sim_config=s.sim_config(), ctrl_config=s.ctrl_config(mode), family=ctx.family, desc=ctx.desc,
                  perturbation=s.perturbation, compiled_loop=compiled)
        t0, c0 = time.perf_counter(), time.process_time()
        pushed = runner.run(steps, mode, (push,), keep_records=False, **kw)
        walk = runner.run(steps, mode, (), keep_records=True, **kw)
        band = rule.band_from_walk(walk)
        verdict = rule.verdict(pushed, push.start + push.duration, band)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        periods = int(walk.records[-1].step) + 1
        return dt, dc, periods, (verdict.survived, verdict.reason, pushed.steps_walked, pushed.fall_cause)

    one(10_000, True)           # the kernels loaded (and compiled, on a first run) outside the timing
    one(10_000, False)
    times: dict[bool, list[float]] = {True: [], False: []}
    cpus: dict[bool, list[float]] = {True: [], False: []}
    periods: dict[bool, list[int]] = {True: [], False: []}
    same = True
    load0 = os.getloadavg()
    for seed in range(reps):
        outcome = {}
        for compiled in ((True, False) if seed % 2 == 0 else (False, True)):
            dt, dc, n, outcome[compiled] = one(seed, compiled)
            times[compiled].append(dt)
            cpus[compiled].append(dc)
            periods[compiled].append(n)
        same = same and outcome[True] == outcome[False]
    med = {k: statistics.median(v) for k, v in times.items()}
    cmed = {k: statistics.median(v) for k, v in cpus.items()}
    return {"mode": mode, "force": force, "profile": profile, "reps": reps, "seeds": list(range(reps)),
            "compiled_s_per_trial": med[True], "objects_s_per_trial": med[False],
            "ratio_objects_over_compiled": med[False] / med[True],
            "compiled_cpu_s_per_trial": cmed[True], "objects_cpu_s_per_trial": cmed[False],
            "ratio_cpu_objects_over_compiled": cmed[False] / cmed[True],
            "walk_periods_median": statistics.median(periods[True]),
            "same_outcomes": same, "times_s": {"compiled": times[True], "objects": times[False]},
            "cpu_s": {"compiled": cpus[True], "objects": cpus[False]},
            "load_average_start": list(load0), "load_average_end": list(os.getloadavg())}


def run_tables(args, out: dict) -> None:
    """Items 1 and 2 of the module docstring into ``out`` (their printed tables to ``tables.txt``)."""
    with open(args.out / "tables.txt", "w", encoding="utf-8") as log:
        out["deterministic"] = run_table(args.out / "deterministic.json", args.modes, args.workers, None,
                                         args.profile, log)
        log.flush()
        out["seeded"] = run_table(args.out / f"seeds_{args.seeds}.json", args.modes, args.workers, args.seeds,
                                  args.profile, log)
        out["ratio_process_wall"] = out["seeded"]["process_wall_s"] / out["deterministic"]["process_wall_s"]
        out["ratio_cpu"] = out["seeded"]["cpu_s"] / out["deterministic"]["cpu_s"]
        if args.slice_phases:
            log.flush()
            out["slice_deterministic"] = run_slice(args.out / "slice_deterministic.json", args.slice_modes,
                                                   args.workers, args.slice_phases, None, args.profile, log)
            log.flush()
            search = (args.slice_coarse, args.slice_resolution)
            name = f"slice_seeds_{args.slice_seeds}"
            out["slice_seeded"] = run_slice(args.out / f"{name}.json", args.slice_modes, args.workers, args.slice_phases,
                                            args.slice_seeds, args.profile, log, search)
            out["slice_ratio_process_wall"] = (out["slice_seeded"]["process_wall_s"]
                                               / out["slice_deterministic"]["process_wall_s"])
            out["slice_ratio_cpu"] = out["slice_seeded"]["cpu_s"] / out["slice_deterministic"]["cpu_s"]
            if args.slice_full:
                log.flush()
                out["slice_seeded_full"] = run_slice(args.out / f"{name}_full.json", args.slice_modes, args.workers,
                                                     args.slice_phases, args.slice_seeds, args.profile, log, search,
                                                     full_trials=True)
                out["slice_full_over_stopped_process_wall"] = (out["slice_seeded_full"]["process_wall_s"]
                                                               / out["slice_seeded"]["process_wall_s"])
                out["slice_full_over_stopped_cpu"] = out["slice_seeded_full"]["cpu_s"] / out["slice_seeded"]["cpu_s"]
                out["slice_full_vs_stopped_answers"] = same_answers(args.out / f"{name}.json",
                                                                    args.out / f"{name}_full.json")


def same_answers(a: Path, b: Path) -> dict:
    """Two seeded slices' summaries cell by cell: the cells whose rates or crossings differ (each mode)."""
    ca, cb = (json.loads(p.read_text(encoding="utf-8"))["cells"] for p in (a, b))
    key = lambda c: (c["direction"], c["phase"], c["duration"])         # noqa: E731
    other = {key(c): c for c in cb}
    diff = []
    for c in ca:
        d = other.get(key(c))
        for m, r in c["modes"].items():
            rd = None if d is None else d["modes"].get(m)
            for f in ("rates", "crossings"):
                if rd is None or r[f] != rd[f]:
                    diff.append({"cell": list(key(c)), "mode": m, "field": f})
    return {"cells": len(ca), "differing": diff}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.uncertainty_table", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--modes", default="both")
    ap.add_argument("--profile", default="real-sensors", choices=("real-sensors", "real-sensors-mujoco"))
    ap.add_argument("--slice-phases", type=int, default=0, help="onset phases of the timed slice (0: no slice)")
    ap.add_argument("--slice-seeds", type=int, default=16)
    ap.add_argument("--slice-modes", default="both,wbc")
    ap.add_argument("--slice-coarse", type=float, default=None, help="[N] the slice's coarse step (default the map's)")
    ap.add_argument("--slice-resolution", type=float, default=None, help="[N] the slice's resolution (default the map's)")
    ap.add_argument("--slice-full", action="store_true",
                    help="also the slice over seeds with --full-trials (no early stop under noise), and the ratio")
    ap.add_argument("--trial-reps", type=int, default=0, help="seeded trials per path for the trial's cost "
                    "(compiled loop against the objects; 0: not timed)")
    ap.add_argument("--trial-mode", default="both", help="mode(s) of the timed trials, a comma list")
    ap.add_argument("--no-tables", action="store_true", help="only the trial's cost (item 3)")
    ap.add_argument("--trial-force", type=float, default=300.0, help="[N] the timed trials' push (paper's window)")
    ap.add_argument("--out", type=Path, default=Path("results/uncertainty"))
    args = ap.parse_args(argv)
    if min(args.seeds, args.workers, args.slice_seeds) < 1 or args.slice_phases < 0 or args.trial_reps < 0:
        ap.error("--seeds, --slice-seeds and --workers must be >= 1, --slice-phases and --trial-reps >= 0")
    args.out.mkdir(parents=True, exist_ok=True)
    from biped_controller.studies import provenance
    timing_path = args.out / "timing.json"
    plant = "mujoco" if args.profile.endswith("mujoco") else "rigid"
    provenance.track(timing_path, args.out / "tables.txt", argv=argv, plant=plant, profile=args.profile)
    what = (f"one seeded survival trial's cost, profile {args.profile}: the compiled closed loop against the "
            f"objects" if args.no_tables else
            f"the max-push table at the paper's cell, profile {args.profile} (the design-point sensor noise on "
            f"the plant): deterministic (one trial per force, seed 0) beside the table over seeds"
            + (", and the 25 ms forward slice likewise" if args.slice_phases else ""))
    out = {"what": what, "cpu_count": os.cpu_count()}
    if not args.no_tables:
        run_tables(args, out)
    if args.trial_reps:
        modes = [m for m in args.trial_mode.split(",") if m]
        out["trial_costs"] = {m: trial_cost(args.trial_reps, args.profile, m, args.trial_force) for m in modes}
        out["trial_cost"] = out["trial_costs"][modes[0]]
    timing_path.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
