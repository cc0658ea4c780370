"""Wall time of the max-push table over seeds beside its deterministic counterpart, in one run (issue 43).

``python -m benchmarks.uncertainty_table [--seeds 8] [--workers 2] [--out results/uncertainty]`` runs, one
after the other, at the paper's cell (the default push window) on the rigid plant with the real-sensor
profile and the design-point sensor noise on the plant (``--perturb noise_q=5e-4 noise_qd=5e-2
encoder_bits=14``; the profile alone puts no noise on the plant):

1. the deterministic table: one trial per force with the noise's seed 0 (``deterministic.json``);
2. the table over seeds: ``--seeds N`` (``seeds_N.json``);

each as its own ``python -m biped_controller.studies.experiment table ...`` process (each records its own
provenance beside its JSON; their printed tables go to ``tables.txt``), and writes ``timing.json``: both wall times (the processes' own ``wall_time``
and the benchmark's clock around each process), the trial counts and the load average at each end.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

NOISE = ("--perturb", "noise_q=5e-4", "--perturb", "noise_qd=5e-2", "--perturb", "encoder_bits=14")


def command(json_path: Path, modes: str, workers: int, seeds: int | None) -> list[str]:
    """The experiment's command line of one of the two tables."""
    cmd = [sys.executable, "-m", "biped_controller.studies.experiment", "table", "--profile", "real-sensors",
           *NOISE, "--modes", modes, "--workers", str(workers), "--json", str(json_path)]
    return cmd + (["--seeds", str(seeds)] if seeds is not None else [])


def run_one(json_path: Path, modes: str, workers: int, seeds: int | None, log) -> dict:
    """Run one table and time it; its JSON's wall time and its trial count."""
    cmd = command(json_path, modes, workers, seeds)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=log, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    data = json.loads(json_path.read_text(encoding="utf-8"))
    n_trials = sum(len(r["trials"]) for r in data["modes"].values())
    return {"command": " ".join(cmd[1:]), "json": json_path.name, "process_wall_s": wall,
            "table_wall_time_s": data["wall_time"], "trials": n_trials, "load_average_start": list(load0),
            "load_average_end": list(os.getloadavg())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.uncertainty_table", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--modes", default="both")
    ap.add_argument("--out", type=Path, default=Path("results/uncertainty"))
    args = ap.parse_args(argv)
    if args.seeds < 1 or args.workers < 1:
        ap.error("--seeds and --workers must be >= 1")
    args.out.mkdir(parents=True, exist_ok=True)
    from biped_controller.studies import provenance
    timing_path = args.out / "timing.json"
    provenance.track(timing_path, args.out / "tables.txt", argv=argv, plant="rigid", profile="real-sensors")
    with open(args.out / "tables.txt", "w", encoding="utf-8") as log:
        det = run_one(args.out / "deterministic.json", args.modes, args.workers, None, log)
        log.flush()
        seeded = run_one(args.out / f"seeds_{args.seeds}.json", args.modes, args.workers, args.seeds, log)
    out = {"what": "the max-push table at the paper's cell, rigid plant, profile real-sensors with the design-point "
                   "sensor noise on the plant: deterministic (one trial per force, seed 0) beside the table over seeds",
           "cpu_count": os.cpu_count(), "deterministic": det, "seeded": seeded,
           "ratio_process_wall": seeded["process_wall_s"] / det["process_wall_s"]}
    timing_path.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
