"""Where one real-sensor survival trial's time goes (issue 43): cProfile of one seeded trial.

``python -m lab.benchmarks.real_sensor_trial_profile [--path compiled|objects] [--mode both] [--force 300]
[--seed 999] [--top 25]`` runs one seeded trial of the paper's window with ``--profile real-sensors`` on the
rigid plant (``trial.seeded.seeded_trial``: the pushed run and its seed's unpushed walk, the records the seeded
table keeps) once to load the kernels (seed + 1), then once under cProfile, and prints the functions by
cumulative and by own time. ``--path objects`` keeps the compiled closed loop out (``ClosedLoop._segment``
answers None: every period on the objects, the path before real sensing ran in the compiled loop). Prints only.
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.benchmarks.real_sensor_trial_profile", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--path", choices=("compiled", "objects"), default="compiled")
    ap.add_argument("--mode", default="both")
    ap.add_argument("--force", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=999)
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args(argv)
    from biped_controller.closed_loop import runner
    from biped_controller.studies.trial import runs, seeded
    from biped_controller.studies.trial.context import context
    from biped_controller.studies.trial.settings import run_settings

    if args.path == "objects":
        runner.ClosedLoop._segment = lambda self, *a, **k: None
    context()
    settings = run_settings("real-sensors")
    push = runs.paper_push(args.force)
    seeded.seeded_trial(push, args.mode, seeded.seeded_settings(settings, args.seed + 1))
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    rec = seeded.seeded_trial(push, args.mode, seeded.seeded_settings(settings, args.seed))
    prof.disable()
    print(f"{args.path}: one trial {time.perf_counter() - t0:.3f} s (under cProfile), survived {rec['survived']} "
          f"({rec['reason']})")
    pstats.Stats(prof).sort_stats("cumulative").print_stats(args.top)
    pstats.Stats(prof).sort_stats("tottime").print_stats(args.top)
    return 0


if __name__ == "__main__":
    sys.exit(main())
