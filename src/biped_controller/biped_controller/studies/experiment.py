"""Experiments of the paper's section 6: undisturbed walking, a push, the largest survivable push.

Pure Python on top of the in-process closed loop (``runner.run``: plant + AdaptiveController in lockstep,
no ROS). Run through ``scripts/experiment SUBCOMMAND [options]``:

  walk      --steps 10 [--mode M | --controller NAME]
                                               tracking with the controller at the integration rate
                                               and at the control period (zero-order hold)
  push      --force 250 --duration 0.025 [--start 0.2315] [--mode both | --controller NAME] [--figures DIR]
                                               one push (+ forward, on the back); figures like the
                                               paper's Figs. 3-7
  max-push  --mode M | --controller NAME [--resolution 5] [--max 2000] [--coarse 50]
                                               largest survivable push force (of a mode or of any
                                               registered controller: docs/controllers.md)
  table     [--workers N] [--modes M,M,...] [--controller NAME ...]
                                               max-push for the four modes (or the modes named, e.g.
                                               none,tau,p,both,wbc,hybrid, and the controllers named)
                                               next to the paper's values
            [--seeds N [--levels 0.9,0.5] [--ray [ADDRESS]]]
                                               (table, max-push) where the plant draws sensor noise:
                                               N seeds per force, survival rates with Wilson 95 %
                                               intervals and the forces where survival crosses each
                                               level (trial.seeded; docs/experiments.md)
  band      [--mode M] [--duration D] [--start S]
                                               the survival rule's band: the unpushed walk of a trial's
                                               impacts, its excursions step by step, the band
  probe     --force F [--mode M | --controller NAME] [--start S]
                                               one push, the controller's view period by period while
                                               it acts: true push vs the observer's estimate, predicted
                                               vs actual ground reaction and l, QP status, tightest row
                                               (a plug-in: the actual reaction and l beside the status
                                               it reports)

``--controller NAME`` (walk, push, probe, max-push, table): a built-in mode, a registered controller
(``python -m biped_controller.studies.controllers list``) or ``module:Class``, run through the studies' one
resolution step (``trial.controller.resolve``: built-in modes on the compiled path, any other controller
through the generic loop; docs/controllers.md). An unknown name is an error naming it, before any run.

Settings of every subcommand: ``--profile NAME`` (config/profiles/: paper, default, real-sensors, ...),
``--observer on|off`` (the controller's disturbance observer) and ``--set KEY=VALUE`` (repeatable) for any
key of config/controller.yaml (except ``mode``: the subcommand chooses it) or config/simulator.yaml, e.g.
``--set margin_zmp=0.0 --set Kp=900 --set push_height=0.0``, over the profile. Values are parsed as YAML
scalars (``0.0``, ``900``, ``false``, ``reference``); the config loaders check them (a bad value is an
error naming the key). Every run prints and stores the profile and the settings that differ from the
configuration files.

Every subcommand prints a table and, with ``--json FILE``, writes its numbers. Everything is
deterministic (the simulator and the controller are). The pieces are importable from
``biped_controller.studies.trial`` (settings, survival, trials, the max-push search) and
``biped_controller.studies.single_runs`` (walk, push, probe).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from biped_controller.core.control.config import MODES
from biped_controller.studies import single_runs
from biped_controller.studies.trial.args import (StudyArgumentParser, add_modes_arg, add_settings_args, controller_arg,
                                                 levels_arg,
                                                 finite_float, nonnegative_float, positive_float, positive_int, settings_from_args)
from biped_controller.studies.trial.context import scaled_force
from biped_controller.studies.trial.runs import DEFAULT_DURATION, DEFAULT_START, paper_push
from biped_controller.studies.trial.seeded import is_random, print_seeded, seeded_table
from biped_controller.studies.trial.uncertainty import DEFAULT_LEVELS
from biped_controller.studies.trial.search import max_push_modes, ordering_finding, print_max_push
from biped_controller.studies.trial.settings import differences, print_settings
from biped_controller.studies import provenance

#: the modes of ``table`` by default: the paper's four
TABLE_MODES: tuple[str, ...] = ("none", "tau", "p", "both")


def _dump(path: Path | None, data: dict) -> None:
    if path is None:
        return

    def conv(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, (np.floating, np.integer)):
            return o.item()
        if isinstance(o, float) and not math.isfinite(o):
            return None
        raise TypeError(type(o))
    def finite(o):              # json writes a float NaN as NaN (not JSON): null, as conv does for NumPy's
        if isinstance(o, float) and not math.isfinite(o):
            return None
        if isinstance(o, dict):
            return {k: finite(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [finite(v) for v in o]
        return o
    path.write_text(json.dumps(finite(data), indent=1, default=conv) + "\n", encoding="utf-8")


def _push_window_args(a, with_force: bool) -> None:
    if with_force:
        a.add_argument("--force", type=finite_float, default=250.0, help="[N], + forward (on the back)")
    a.add_argument("--duration", type=positive_float, default=DEFAULT_DURATION, help="[s]")
    a.add_argument("--start", type=nonnegative_float, default=DEFAULT_START, help="[s]")
    a.add_argument("--height", type=nonnegative_float, default=None,
                   help="above the hip [m] (default: push_height of config/simulator.yaml)")


def _controller_arg(a: argparse.ArgumentParser) -> None:
    a.add_argument("--controller", type=controller_arg, default=None, metavar="NAME",
                   help="any registered controller (python -m biped_controller.studies.controllers list) in place "
                        "of --mode")


#: the push searches' defaults [N] for the default robot (scaled for another: ``trial.context.scaled_force``)
SEARCH_DEFAULTS = {"resolution": 5.0, "max": 2000.0, "coarse": 50.0}


def parser() -> StudyArgumentParser:
    """The command line of ``scripts/experiment``."""
    ap = StudyArgumentParser(prog="scripts/experiment", description=__doc__,
                             formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("walk", help="undisturbed walk: integration-rate vs ZOH controller")
    a.add_argument("--steps", type=positive_int, default=10)
    a.add_argument("--mode", choices=MODES, default="both")
    _controller_arg(a)
    a.add_argument("--json", type=Path)
    add_settings_args(a)
    for name, hlp in (("push", "one push, with figures like the paper's Figs. 3-7"),
                      ("probe", "one push: the controller's view period by period while it acts")):
        a = sub.add_parser(name, help=hlp)
        _push_window_args(a, with_force=True)
        a.add_argument("--mode", choices=MODES, default="both")
        _controller_arg(a)
        if name == "push":
            a.add_argument("--figures", type=Path, help="directory for the PNG figures")
        else:
            a.add_argument("--after", type=nonnegative_float, default=0.010,
                           help="print this long after the push end [s]")
        a.add_argument("--json", type=Path)
        add_settings_args(a)
    a = sub.add_parser("band", help="the survival rule's band: the unpushed walk's excursions step by step")
    _push_window_args(a, with_force=False)
    a.add_argument("--mode", choices=MODES, default="both")
    _controller_arg(a)
    a.add_argument("--json", type=Path)
    add_settings_args(a, full_trials=False)
    for name, hlp in (("max-push", "largest survivable push for one mode"),
                      ("table", "max-push for the four modes, or for --modes")):
        a = sub.add_parser(name, help=hlp)
        if name == "max-push":
            a.add_argument("--mode", choices=MODES, default="both")
            _controller_arg(a)
        else:
            add_modes_arg(a, TABLE_MODES, f"the paper's {','.join(TABLE_MODES)}")
            a.add_argument("--controller", type=controller_arg, action="append", default=[], metavar="NAME",
                           help="a registered controller added to the table (repeatable)")
        a.add_argument("--resolution", type=positive_float, default=None,
                       help=f"bisection resolution [N] (default {SEARCH_DEFAULTS['resolution']:g} N; another robot: "
                            "x its M sqrt(g L) / biped7's, docs/robots.md)")
        a.add_argument("--max", type=positive_float, default=None,
                       help=f"largest force scanned [N] (default {SEARCH_DEFAULTS['max']:g} N, scaled likewise)")
        a.add_argument("--coarse", type=positive_float, default=None,
                       help=f"coarse scan step [N] (default {SEARCH_DEFAULTS['coarse']:g} N, scaled likewise)")
        _push_window_args(a, with_force=False)
        a.add_argument("--backward", action="store_true", help="push backwards (on the chest) instead")
        a.add_argument("--workers", type=positive_int, default=1, help="processes (each builds its own models)")
        a.add_argument("--seeds", type=positive_int, default=None,
                       help="seeds per force where the settings draw noise (sensor noise): survival rates with "
                            "Wilson 95 %% intervals and the crossing forces of --levels (trial.seeded); a profile "
                            "without randomness runs one trial per force as without it")
        a.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                       help="with --seeds on noisy settings: run the trials on Ray, a local instance (num_cpus = "
                            "--workers) or the cluster at ADDRESS (the same answer: decisions on complete batches)")
        a.add_argument("--levels", type=levels_arg, default=DEFAULT_LEVELS, metavar="C,C,...",
                       help="with --seeds: the survival levels whose crossing forces are searched, each in (0, 1) "
                            "(default 0.9,0.5)")
        a.add_argument("--json", type=Path)
        add_settings_args(a)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    out = getattr(args, "json", None)
    if out is not None and not Path(out).parent.is_dir():
        ap.error(f"--json {out}: its directory {Path(out).parent} does not exist (nothing was run)")
    provenance.track(getattr(args, "json", None), getattr(args, "figures", None), args=args, argv=argv)   # record of each file written (results/README.md)
    settings = settings_from_args(ap, args)
    for name, default in SEARCH_DEFAULTS.items():
        if hasattr(args, name) and getattr(args, name) is None:    # scaled with the robot (biped7: the defaults)
            setattr(args, name, scaled_force(default, settings.robot))
    given = list(sys.argv[1:] if argv is None else argv)
    print(f"scripts/experiment {' '.join(given)}")
    print_settings(settings)
    if args.cmd == "walk":
        r = single_runs.walk(args.steps, args.controller or args.mode, settings)
        single_runs.print_walk(r)
    elif args.cmd == "push":
        push = paper_push(args.force, start=args.start, duration=args.duration, height=args.height)
        r = single_runs.push_experiment(push, args.controller or args.mode, args.figures, settings)
        single_runs.print_push(r)
    elif args.cmd == "band":
        push = paper_push(0.0, start=args.start, duration=args.duration, height=args.height)
        r = single_runs.band_walk(push, args.controller or args.mode, settings)
        single_runs.print_band_walk(r)
    elif args.cmd == "probe":
        push = paper_push(args.force, start=args.start, duration=args.duration, height=args.height)
        r = single_runs.probe(push, args.controller or args.mode, settings, after=args.after)
        single_runs.print_probe(r)
    else:
        if args.cmd == "max-push":
            modes = (args.controller or args.mode,)
        else:
            modes = tuple(dict.fromkeys(tuple(args.modes) + tuple(args.controller)))
        seeded = args.seeds is not None and is_random(settings)
        if args.ray is not None and not seeded:
            ap.error("argument --ray: only with --seeds on settings that draw noise (the seeded table)")
        t0 = time.perf_counter()
        if seeded:
            res = seeded_table(modes, args.seeds, args.resolution, args.max, args.coarse, levels=args.levels,
                               duration=args.duration, start=args.start, height=args.height, workers=args.workers,
                               ray=args.ray, sign=-1.0 if args.backward else 1.0, settings=settings)
            print_seeded(res)
            r = {"modes": res, "seeds": args.seeds, "wall_time": time.perf_counter() - t0}
            print(f"wall time {r['wall_time']:.1f} s")
            r["settings"] = differences(settings)
            r["argv"] = given
            _dump(args.json, r)
            return 0
        if args.seeds is not None:
            print(f"--seeds {args.seeds}: these settings draw nothing random (no sensor noise on the plant), "
                  "so every seed gives the same trial: one trial per force")
        res = max_push_modes(modes, args.resolution, args.max, args.coarse, duration=args.duration, start=args.start,
                             height=args.height, workers=args.workers, sign=-1.0 if args.backward else 1.0,
                             settings=settings)
        print_max_push(res)
        r = {"modes": res, "wall_time": time.perf_counter() - t0}
        if args.cmd == "table":
            r["ordering"] = ordering_finding(res)
            print(r["ordering"])
        print(f"wall time {r['wall_time']:.1f} s")
    r["settings"] = differences(settings)
    r["argv"] = given
    _dump(args.json, r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
