"""``scripts/capability_map``: the command line of the map (``--help``)."""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import sys
from pathlib import Path
from typing import Sequence

from biped_controller.core.control.config import PAPER_MODES
from biped_controller.studies import capmap
from biped_controller.studies.capmap.driver import run_map
from biped_controller.studies.capmap.executors import DEFAULT_BATCH, SerialExecutor, make_executor
from biped_controller.studies.capmap.figures import figures
from biped_controller.studies.capmap.findings import findings_text, summary
from biped_controller.studies.capmap.spec import (DEFAULT_COARSE, DEFAULT_DURATIONS, DEFAULT_MAX, DEFAULT_MAX_IMPULSE,
                                                  DEFAULT_PHASES, DEFAULT_RESOLUTION, DIRECTIONS, Cell, MapError,
                                                  MapSpec, Search, phases_of)
from biped_controller.studies.capmap.store import RecordStore
from biped_controller.closed_loop.executor import ProgressBar
from biped_controller.studies.trial.args import (StudyArgumentParser, add_modes_arg, add_settings_args, controller_arg,
                                                 finite_float, levels_arg,
                                                 positive_float, positive_int, settings_from_args)
from biped_controller.studies.trial.context import scaled_force
from biped_controller.studies.trial.seeded import is_random
from biped_controller.studies.trial.uncertainty import DEFAULT_LEVELS
from biped_controller.studies.trial.settings import print_settings
from biped_controller.studies.provenance import git_state
from biped_controller.studies import provenance


def _split(values: Sequence[str]) -> list[str]:
    return [x for v in values for x in v.split(",") if x]


def _dump(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, allow_nan=False) + "\n", encoding="utf-8")


def _terminate(signum, frame):
    raise SystemExit(128 + signum)


def _seeded(args, spec: MapSpec, argv) -> int:
    """``--seeds N`` on noisy settings: :func:`capmap.seeded.seeded_map`, its table, figure and JSON."""
    from biped_controller.studies.capmap import seeded as sm
    if args.report_only and not args.store.exists():
        print(f"error: --report-only: no store {args.store}", file=sys.stderr)
        return 2
    print(f"scripts/capability_map {' '.join(sys.argv[1:] if argv is None else argv)}")
    print_settings(spec.settings)
    n = len(spec.directions) * len(spec.phases) * len(spec.durations)
    print(f"{n} cells over {args.seeds} seeds (modes {','.join(spec.modes)} on common seeds), levels "
          f"{','.join(f'{c:g}' for c in args.levels)}; store {args.store}")
    signal.signal(signal.SIGTERM, _terminate)
    res = sm.seeded_map(spec, args.seeds, args.levels, workers=args.workers, ray=args.ray, store=args.store,
                        simulate=not args.report_only)
    res["argv"] = list(sys.argv[1:] if argv is None else argv)
    res["workers"] = args.workers
    res["executor"] = "ray" if args.ray else ("pool" if args.workers > 1 else "in process")
    res["git"] = git_state()
    for line in sm.crossing_table(res):
        print(line)
    print(f"{res['trials_run']} trials run, {res['cells_resumed']} cells resumed from the store"
          + (f", {len(res['cells_missing'])} cells not in the store (--report-only)" if res["cells_missing"] else "")
          + f"; wall time {res['wall_time']:.1f} s")
    if not res["cells"]:
        return 0
    if args.out is not None:
        print(f"figure: {sm.band_figure(res, args.out / 'seeded_bands.png')}")
    if args.json is not None:
        _dump(args.json, res)
        print(f"summary: {args.json}")
    return 0


def main(argv: list[str] | None = None) -> int:
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    ap = StudyArgumentParser(prog="scripts/capability_map", description=capmap.__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_modes_arg(ap, None, f"the paper's {','.join(PAPER_MODES)} without --controller; with --controller, only the "
                            f"controllers given")
    ap.add_argument("--controller", type=controller_arg, action="append", default=[], metavar="NAME",
                    help="a registered controller to map (repeatable; python -m biped_controller.studies.controllers list), "
                         "beside the --modes given")
    ap.add_argument("--directions", nargs="+", default=list(DIRECTIONS), help="forward backward (default both)")
    ap.add_argument("--phases", type=positive_int, default=DEFAULT_PHASES, help="onsets k/N of the first step, k < N")
    ap.add_argument("--only-phases", type=finite_float, nargs="+", default=None, metavar="PHASE",
                    help="map only these of the --phases onsets (each must be one of k/N): a part of a map, whose "
                         "cells the whole map's store then resumes")
    ap.add_argument("--durations", nargs="+", type=positive_float, default=list(DEFAULT_DURATIONS), help="push durations [s]")
    ap.add_argument("--resolution", type=positive_float, default=None,
                    help=f"bisection resolution [N] (default {DEFAULT_RESOLUTION:g} N; another robot: x its M sqrt(g L) / biped7's)")
    ap.add_argument("--coarse", type=positive_float, default=None,
                    help=f"coarse scan step [N] (default {DEFAULT_COARSE:g} N, scaled likewise)")
    ap.add_argument("--max", type=positive_float, default=None,
                    help=f"largest force scanned [N] (default {DEFAULT_MAX:g} N, scaled likewise)")
    ap.add_argument("--max-impulse", type=float, default=None,
                    help=f"largest impulse scanned [N s] (inf: none): long pushes scan up to this / duration (default "
                         f"{DEFAULT_MAX_IMPULSE:g} N s, scaled likewise)")
    ap.add_argument("--search", choices=("neighbours", "full"), default=None,
                    help="neighbours: bracket each cell's edge from its lower-phase neighbour's (bracket_check_below "
                         "coarse steps checked under it, islands within island_window coarse steps above the edge); "
                         "full: every coarse force of every cell "
                         "(default: config/studies.yaml search_from_neighbours)")
    ap.add_argument("--height", type=finite_float, default=None,
                    help="push point above the hip [m] (default: push_height of config/simulator.yaml)")
    ap.add_argument("--workers", type=positive_int, default=cores, help=f"processes (default: all cores, {cores}); 1 = in process")
    ap.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                    help="run on Ray: a local instance (num_cpus = --workers) or the cluster at ADDRESS")
    ap.add_argument("--batch", type=positive_int, default=None, help="simulations per task (default 1, 4 on Ray)")
    ap.add_argument("--store", type=Path, default=Path("build/capability_map/records.jsonl"),
                    help="per-simulation records (JSON Lines), resumed by a rerun")
    ap.add_argument("--out", type=Path, default=None, help="directory for the PNG figures")
    ap.add_argument("--json", type=Path, default=None, help="summary JSON")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--report-only", action="store_true",
                    help="run nothing: summary and figures from the store (incomplete cells are left out)")
    ap.add_argument("--seeds", type=positive_int, default=None,
                    help="seeds per force where the settings draw noise (e.g. --profile real-sensors-mujoco): per cell "
                         "the survival rates with Wilson 95 %% intervals, the crossings of --levels and the modes "
                         "compared on common seeds (capmap.seeded; --store: finished cells, resumed); settings "
                         "without noise: the map as without it")
    ap.add_argument("--levels", type=levels_arg, default=DEFAULT_LEVELS, metavar="C,C,...",
                    help="with --seeds: survival levels whose crossing forces are searched, each in (0, 1) (default "
                         "0.9,0.5)")
    add_settings_args(ap)
    args = ap.parse_args(argv)
    provenance.track(args.json, args.out, args.store, args=args, argv=argv)   # record of each file written (results/README.md)
    settings = settings_from_args(ap, args)
    for name, default in (("resolution", DEFAULT_RESOLUTION), ("coarse", DEFAULT_COARSE), ("max", DEFAULT_MAX),
                          ("max_impulse", DEFAULT_MAX_IMPULSE)):
        if getattr(args, name) is None:     # the search ranges scale with the robot (biped7: the defaults)
            setattr(args, name, scaled_force(default, settings.robot))
    try:
        names = list(args.modes) if args.modes is not None else ([] if args.controller else list(PAPER_MODES))
        spec = MapSpec(tuple(dict.fromkeys(names + list(args.controller))), tuple(_split(args.directions)), phases_of(args.phases),
                       tuple(float(d) for d in args.durations), Search(args.coarse, args.max, args.resolution, args.max_impulse),
                       args.height, settings, None if args.search is None else args.search == "neighbours")
        if args.only_phases is not None:
            wrong = [p for p in args.only_phases if p not in spec.phases]
            if wrong:
                raise MapError(f"--only-phases {' '.join(f'{p:g}' for p in wrong)}: not among the {len(spec.phases)} "
                               f"phases k/{len(spec.phases)}")
            spec = dataclasses.replace(spec, phases=tuple(p for p in spec.phases if p in args.only_phases))
    except MapError as exc:
        ap.error(str(exc))
    if args.seeds is not None and is_random(settings):
        return _seeded(args, spec, argv)
    if args.seeds is not None:
        print(f"--seeds {args.seeds}: these settings draw nothing random (no sensor noise on the plant), one trial "
              f"per force decides: the map as without --seeds")
    batch = args.batch if args.batch is not None else DEFAULT_BATCH["ray" if args.ray else "pool"]
    print(f"scripts/capability_map {' '.join(sys.argv[1:] if argv is None else argv)}")
    print_settings(settings)
    print(f"{len(spec.cells())} cells: modes {','.join(spec.modes)} x directions {','.join(spec.directions)} x "
          f"{len(spec.phases)} phases x durations {','.join(f'{d:g}' for d in spec.durations)} s; coarse "
          f"{spec.search.coarse:g} N to " + ", ".join(f"{spec.search.for_duration(d).fmax:g} N ({d:g} s)" for d in spec.durations)
          + f", bisection to {spec.search.resolution:g} N; store {args.store}")
    ex = SerialExecutor() if args.report_only else make_executor(args.workers, args.ray)
    # a kill (SIGTERM) unwinds like Ctrl-C: the executor is closed (no orphaned workers) and every record
    # stored so far stays for the next run
    signal.signal(signal.SIGTERM, _terminate)
    try:
        run = run_map(spec, ex, RecordStore(args.store), batch, None if args.no_progress else ProgressBar(),
                      simulate=not args.report_only)
    finally:
        ex.close()
    figs = figures(run, args.out) if args.out is not None else []
    summ = summary(run, figs)
    summ["run"]["argv"] = list(sys.argv[1:] if argv is None else argv)
    summ["run"]["workers"] = args.workers
    summ["run"]["batch"] = batch
    summ["run"]["store"] = str(args.store)
    summ["run"]["git"] = git_state()
    r = summ["run"]
    print(f"{r['simulations_in_map']} simulations in the map: {r['simulations_run']} run now, "
          f"{r['simulations_resumed']} resumed from the store ({r['store_records_ignored']} store records of "
          f"other settings/code/cells ignored); wall time {r['wall_time']:.1f} s, "
          + (f"{r['rate']:.3f} sims/s ({r['executor']}, {args.workers} workers, batch {batch})" if r["rate"] else "nothing run"))
    print(f"{'mode':<5} {'dir':<8} {'dur':>5} " + " ".join(f"{p:>8g}" for p in spec.phases))
    for m in spec.modes:
        for dr in spec.directions:
            for du in spec.durations:
                row = []
                for ph in spec.phases:
                    b = run.boundaries.get(Cell(m, dr, ph, du))
                    if b is None:
                        row.append(f"{'?':>8}")
                        continue
                    row.append(f"{b.lo:>7.2f}{'+' if b.hi is None else ('*' if b.islands else ' ')}")
                print(f"{m:<5} {dr:<8} {du:>5g} " + " ".join(row))
    print("(boundary force [N] per onset phase; * = islands above the edge, + = censored: survived up to the scan's max"
          + (f"; ? = search incomplete: {len(run.missing)} cells)" if run.missing else ")"))
    for line in findings_text(summ["findings"]):
        print(line)
    pr = summ["parameter_range"]
    if pr["max_abs_p_minus_pd"] is not None:
        print(f"parameters: max |p - p_d| = {pr['max_abs_p_minus_pd']:.4f} m (range [{pr['p_min']:g}, {pr['p_max']:g}] m), "
              f"tau' in [{pr['min_tau_dot']:.4f}, {pr['max_tau_dot']:.4f}] (range [{pr['tau_dot_min']:g}, {pr.get('tau_dot_max', float('inf')):g}]); "
              f"{len(pr['trials_out_of_range'])} trials out of range, {pr['trials_not_recorded']} without the record")
    for p in figs:
        print(f"figure: {p}")
    if args.json is not None:
        _dump(args.json, summ)
        print(f"summary: {args.json}")
    return 0
