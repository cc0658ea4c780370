"""Sweep speed: the capability map's default map (4 modes x 2 directions x 20 phases x 3
durations = 480 cells) with the early stop and the bracketed search, on os.cpu_count() worker processes,
from an empty store. Keys ``sweep.map_full_wall_s`` (wall time [s]) and ``sweep.sims_per_s``
(simulations per second of wall time); ``--quick``: a 2-phase, 1-mode map (no ``map_full_wall_s``).

    python -m benchmarks.sweep_bench [--quick] [--json results/benchmarks/results.json]
    python -m benchmarks.sweep_bench --from-summary SUMMARY.json [--worker-cpu-s S] [--load L1 L5 L15] [--note TEXT]

Standalone, the figures are merged into ``--json`` (section ``sweep`` and its ``keys``) without touching
the rest; ``benchmarks/run.py`` runs :func:`bench_sweep` as its section 6. The machine is shared: the
figures are this run's, on whatever load there was (``load_average`` is recorded beside them).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR



def bench_sweep(quick: bool) -> dict:
    from biped_controller.studies import capability_map as cm

    workers = max(2, os.cpu_count() or 2)
    spec = (cm.MapSpec(modes=("none",), directions=("forward",), phases=cm.phases_of(2), durations=(0.025,))
            if quick else cm.MapSpec())
    load0 = os.getloadavg()
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    with tempfile.TemporaryDirectory() as d:
        ex = cm.PoolExecutor(workers)
        try:
            t0 = time.perf_counter()
            run = cm.run_map(spec, ex, cm.RecordStore(Path(d) / "records.jsonl"))
            wall = time.perf_counter() - t0
        finally:
            ex.close()
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"available": True, "quick": quick, "cells": len(spec.cells()), "workers": workers,
            "search": "neighbours" if spec.neighbours else "full", "island_window": spec.island_window,
            "bracket_check_below": spec.bracket_check_below,
            "simulations": run.simulated, "wall_s": wall, "sims_per_s": run.simulated / wall,
            "worker_cpu_s": (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime),
            "load_average_before": list(load0), "load_average_after": list(os.getloadavg())}


def from_summary(path: Path, worker_cpu_s: float | None, load: list[float] | None, note: str) -> dict:
    """The same figures from a map already run by ``scripts/capability_map --json`` (its summary's run
    section): recorded, not re-measured (``source`` says where they come from)."""
    r = json.loads(path.read_text())["run"]
    cells = len(json.loads(path.read_text())["boundaries"])
    return {"available": True, "quick": cells < 480, "cells": cells, "workers": r.get("workers"),
            "search": "neighbours", "simulations": r["simulations_run"], "wall_s": r["wall_time"],
            "sims_per_s": r["simulations_run"] / r["wall_time"], "worker_cpu_s": worker_cpu_s,
            "load_average_before": load, "load_average_after": None,
            "source": f"{path.name}: scripts/capability_map {' '.join(r.get('argv', []))}; {note}"}


def keys(s: dict) -> dict:
    ok = bool(s.get("available"))
    return {"sweep.map_full_wall_s": s["wall_s"] if ok and not s["quick"] else None,
            "sweep.sims_per_s": s["sims_per_s"] if ok else None}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", type=Path, default=RESULTS_DIR / "results.json")
    ap.add_argument("--from-summary", type=Path, default=None,
                    help="record a map already run (its --json summary) instead of running one")
    ap.add_argument("--worker-cpu-s", type=float, default=None, help="with --from-summary: its CPU time [s]")
    ap.add_argument("--load", type=float, nargs=3, default=None, help="with --from-summary: load average at its start")
    ap.add_argument("--note", default="", help="with --from-summary: how it was run")
    a = ap.parse_args(argv)
    provenance.track(a.json, argv=argv)   # record of each file written (results/README.md)
    s = (from_summary(a.from_summary, a.worker_cpu_s, a.load, a.note) if a.from_summary is not None
         else bench_sweep(a.quick))
    print(json.dumps(s, indent=1))
    R = json.loads(a.json.read_text()) if a.json.exists() else {}
    R["sweep"] = s
    R.setdefault("keys", {}).update(keys(s))
    a.json.write_text(json.dumps(R, indent=1, default=float) + "\n", encoding="utf-8")
    print(f"wrote {a.json}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
