"""Cost of the IMU in the DDS lockstep: the simulator node publishes ``/imu`` with every state and
the controller node answers a state only once it holds the ``/imu`` of its stamp (``use_imu: true``, the
default) or ignores the IMU (``use_imu: false``). Runs ``lockstep.measure`` (simulator + controller, no
recorder, isolated domain) alternately with the two settings, ``--pairs`` times, and writes the rates with
the machine's load average to ``results/benchmarks/imu_lockstep.json``. Nothing is asserted.

    .venv/bin/python -m benchmarks.imu_lockstep [--pairs 3] [--seconds 2.0]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

from benchmarks.lockstep import measure
from benchmarks.domain import Domain
from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR

OUT = RESULTS_DIR / "imu_lockstep.json"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=3, help="alternated (with, without) pairs of runs")
    ap.add_argument("--seconds", type=float, default=2.0, help="sim seconds per run")
    ap.add_argument("--json", type=Path, default=OUT)
    args = ap.parse_args(argv)
    provenance.track(args.json, argv=argv)   # record of each file written (results/README.md)
    runs = {"use_imu_true": [], "use_imu_false": []}
    load = [os.getloadavg()[0]]
    for _ in range(args.pairs):
        for key, value in (("use_imu_true", "true"), ("use_imu_false", "false")):
            r = measure(args.seconds, Domain, ctrl_params=(f"use_imu:={value}",))
            if not r.get("available"):
                raise SystemExit(f"{key}: {r.get('reason')}")
            runs[key].append(round(r["steps_per_s"], 1))
            load.append(os.getloadavg()[0])
            print(f"{key:14s} {r['steps_per_s']:7.1f} steps/s (load {load[-1]:.1f})", flush=True)
    med = {k: statistics.median(v) for k, v in runs.items()}
    doc = {"when": time.strftime("%Y-%m-%d %H:%M:%S"), "cpus": os.cpu_count(), "machine": platform.machine(),
           "sim_seconds": args.seconds, "pairs": args.pairs, "steps_per_s": runs, "median_steps_per_s": med,
           "ratio_with_to_without": med["use_imu_true"] / med["use_imu_false"],
           "load_average_1min": [round(x, 2) for x in load],
           "command": " ".join([".venv/bin/python -m benchmarks.imu_lockstep"] + list(sys.argv[1:] if argv is None else argv))}
    args.json.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    print(f"median with /imu paired {med['use_imu_true']:.1f}, without {med['use_imu_false']:.1f} steps/s "
          f"(ratio {doc['ratio_with_to_without']:.2f}); written to {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
