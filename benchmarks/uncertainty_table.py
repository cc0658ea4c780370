"""Wall and CPU time of the answers over seeds beside their deterministic counterparts, in one run (issue 43).

``python -m benchmarks.uncertainty_table [--seeds 8] [--workers 2] [--modes both] [--profile real-sensors]
[--slice-phases 0] [--slice-seeds 16] [--slice-modes both,wbc] [--out results/uncertainty]`` runs, one after
the other, each as its own process (each records its own provenance beside its JSON; their printed tables
go to ``tables.txt``):

1. the max-push table at the paper's cell (the default push window) with the profile (``real-sensors``: the
   rigid plant, ``real-sensors-mujoco``: MuJoCo; both put the design-point sensor noise on the plant):
   deterministic, one trial per force with the noise's seed 0 (``deterministic.json``), then over seeds,
   ``--seeds N`` (``seeds_N.json``);
2. with ``--slice-phases P`` (> 0), the 25 ms slice of the capability map (forward, onset phases k / P): the
   deterministic map (``slice_deterministic.json``, its store in a fresh temporary directory) and the map
   over ``--slice-seeds`` seeds (``slice_seeds_N.json``, likewise).

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
                  profile: str) -> list[str]:
    """The capability map's command line of the 25 ms forward slice (deterministic, or over seeds)."""
    cmd = [sys.executable, "-m", "biped_controller.studies.capability_map", "--modes", modes, "--profile", profile,
           "--durations", "0.025", "--directions", "forward", "--phases", str(phases), "--workers", str(workers),
           "--no-progress", "--store", str(store), "--json", str(json_path)]
    return cmd + (["--seeds", str(seeds)] if seeds is not None else [])


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


def run_slice(json_path: Path, modes: str, workers: int, phases: int, seeds: int | None, profile: str, log) -> dict:
    """One slice, timed, from an empty store; its simulation count."""
    with tempfile.TemporaryDirectory() as tmp:
        out = timed(slice_command(json_path, Path(tmp) / "store.jsonl", modes, workers, phases, seeds, profile), log)
    data = json.loads(json_path.read_text(encoding="utf-8"))
    n = data["trials_run"] if seeds is not None else data["run"]["simulations_run"]
    return {**out, "json": json_path.name, "trials": n}


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
    ap.add_argument("--out", type=Path, default=Path("results/uncertainty"))
    args = ap.parse_args(argv)
    if min(args.seeds, args.workers, args.slice_seeds) < 1 or args.slice_phases < 0:
        ap.error("--seeds, --slice-seeds and --workers must be >= 1, --slice-phases >= 0")
    args.out.mkdir(parents=True, exist_ok=True)
    from biped_controller.studies import provenance
    timing_path = args.out / "timing.json"
    plant = "mujoco" if args.profile.endswith("mujoco") else "rigid"
    provenance.track(timing_path, args.out / "tables.txt", argv=argv, plant=plant, profile=args.profile)
    out = {"what": f"the max-push table at the paper's cell, profile {args.profile} (the design-point sensor noise on "
                   f"the plant): deterministic (one trial per force, seed 0) beside the table over seeds"
                   + (", and the 25 ms forward slice likewise" if args.slice_phases else ""),
           "cpu_count": os.cpu_count()}
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
            out["slice_seeded"] = run_slice(args.out / f"slice_seeds_{args.slice_seeds}.json", args.slice_modes,
                                            args.workers, args.slice_phases, args.slice_seeds, args.profile, log)
            out["slice_ratio_process_wall"] = (out["slice_seeded"]["process_wall_s"]
                                               / out["slice_deterministic"]["process_wall_s"])
            out["slice_ratio_cpu"] = out["slice_seeded"]["cpu_s"] / out["slice_deterministic"]["cpu_s"]
    timing_path.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
