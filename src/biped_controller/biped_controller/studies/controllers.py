"""Controllers behind the controller interface, from the command line:

  python -m biped_controller.studies.controllers list                 the registered controllers, one a line (name, where
                                                          it comes from, module:Class, what it does)
  python -m biped_controller.studies.controllers check NAME [--time T] [--option KEY=VALUE ...]
                                                          load one, check it against the interface, then
                                                          build it and run one control period on a
                                                          synthetic observation (one_period): a fault
                                                          there fails the check (exit 1)
  python -m biped_controller.studies.controllers max-push NAME [--plant rigid|mujoco] [--option KEY=VALUE ...]
        [--resolution 5] [--max 2000] [--coarse 50] [--start S] [--duration D] [--backward]
        [--perturb FIELD=VALUE ...] [--json FILE]
                                                          its largest survivable push at the paper's cell
                                                          (25 ms on the back at t = 0.2315 s; trial.plugin_trials)
                                                          or at the onset, duration and direction given, on
                                                          the plant perturbed as given
  python -m biped_controller.studies.controllers slices MAP.json [MAP.json ...] [--duration 0.025] [--tie 0]
        [--json FILE] [--markdown FILE]
                                                          capability-map slices (scripts/capability_map --json)
                                                          side by side per plant and controller: mean and
                                                          weakest boundary per direction, phases led, pairwise
                                                          comparison, agreement with the no-fall edge
                                                          (capmap.compare)
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from biped_controller.plugin.interface import ControllerFault, ControlResult, InterfaceError
from biped_controller.plugin.registry import (ControllerLoadError, UnknownControllerError, load_controller,
                                              load_registration, registered, summary)


def _option(text: str) -> tuple[str, float | str]:
    """KEY=VALUE: the value a number where it reads as one, else the word or path as given (e.g.
    ``file=policies/x/policy.onnx``)."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"--option takes KEY=VALUE, got {text!r}")
    try:
        return key, float(value)
    except ValueError:
        if not value:
            raise argparse.ArgumentTypeError(f"--option {key}: the value is empty") from None
        return key, value


#: what ``check`` can and cannot tell, printed with a passed check
CHECK_SCOPE = ("the check runs reset and one compute at one time on one state: a fault that shows only later in a run "
               "(another time, state or stance, a touchdown) is not caught here; a run or a sweep records it as the "
               "trial's controller fault (reason 'controller fault: ...', cause controller_fault)")


def one_period(name: str, t: float = 0.0, options: dict | None = None) -> ControlResult:
    """One control period of the controller ``name`` on a synthetic observation, through the same guard as
    every run (``interface.GuardedController``): the controller built from the setup of the studies'
    default robot (description, gait family, control period [s] of config/simulator.yaml; ``options``),
    ``reset(t, LEFT)``, then ``compute`` of the observation at ``t`` [s] (stamped as a run's, step 0, left
    stance) of the gait family's initial state q, q' [rad, rad/s], no IMU reading (NaN) and a zero last
    torque. Returns the checked result; raises ``interface.ControllerFault`` (wrong type, shape, a
    non-finite torque, a malformed status, an exception, the constructor's included) naming the controller."""
    from biped_model.description import LEFT
    from biped_controller.plugin.interface import FAULT_KINDS, ControllerSetup, Observation, stamp_time
    from biped_controller.plugin.registry import make_controller
    from biped_controller.studies.trial.context import context
    ctx = context()
    setup = ControllerSetup(ctx.desc, ctx.family, ctx.sim_config.control_period, dict(options or {}))
    try:
        ctrl = make_controller(name, setup)
    except Exception as exc:        # the controller's own constructor failed: its fault, named as the runs name it
        raise ControllerFault(name, t, FAULT_KINDS[4], f"the constructor raised {type(exc).__name__}: {exc}") from exc
    q0, qd0 = ctx.family.initial_state()
    ts = stamp_time(t)
    ctrl.reset(ts, LEFT)
    return ctrl.compute(Observation.frozen(ts, 0, LEFT, q0, qd0, math.nan, math.nan, np.zeros(6), LEFT))


def _numbers(x) -> str:
    """An array as plain numbers (no NumPy reprs)."""
    return "[" + ", ".join(f"{float(v):.6g}" for v in x) + "]"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m biped_controller.studies.controllers",
                                 description="Controllers behind the controller interface.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="the registered controllers, one a line")
    chk = sub.add_parser("check", help="load one controller, check it against the interface and run one period "
                                        "on a synthetic observation")
    chk.add_argument("name")
    chk.add_argument("--time", type=float, default=0.0,
                     help="the synthetic observation's time t [s] (default 0: a run's first period)")
    chk.add_argument("--option", type=_option, action="append", default=[], help="controller option KEY=VALUE")
    mp = sub.add_parser("max-push", help="largest survivable push at the paper's cell")
    mp.add_argument("name")
    mp.add_argument("--plant", choices=("rigid", "mujoco"), default="rigid")
    mp.add_argument("--option", type=_option, action="append", default=[], help="controller option KEY=VALUE")
    mp.add_argument("--resolution", type=float, default=5.0, help="bisection resolution [N]")
    mp.add_argument("--max", type=float, default=2000.0, help="largest force scanned [N]")
    mp.add_argument("--coarse", type=float, default=50.0, help="coarse scan step [N]")
    mp.add_argument("--start", type=float, default=None, help="push onset [s] (default the paper's, 0.2315 s)")
    mp.add_argument("--duration", type=float, default=None, help="push duration [s] (default the paper's, 0.025 s)")
    mp.add_argument("--backward", action="store_true", help="push backwards (on the chest) instead")
    mp.add_argument("--perturb", action="append", default=[], metavar="FIELD=VALUE",
                    help="a field of the plant's PlantPerturbation, e.g. noise_q=1e-4 (repeatable; "
                         "biped_sim.plant.perturbation)")
    mp.add_argument("--json", type=Path)
    sl = sub.add_parser("slices", help="capability-map slices side by side (capmap.compare)")
    sl.add_argument("maps", nargs="+", type=Path, help="summary JSON files of scripts/capability_map --json")
    sl.add_argument("--duration", type=float, default=0.025, help="push duration of the slice [s]")
    sl.add_argument("--tie", type=float, default=0.0, help="boundaries within this of the largest share the lead [N]")
    sl.add_argument("--json", type=Path, help="write the comparison here")
    sl.add_argument("--markdown", type=Path, help="write the markdown tables here")
    args = ap.parse_args(argv)
    if args.cmd == "slices":
        return _slices(args, argv)
    if args.cmd == "list":
        for r in registered():
            try:
                text = summary(load_registration(r))
            except (ControllerLoadError, InterfaceError) as exc:
                text = f"BROKEN: {exc}"
            print(f"{r.name:<16} {r.source:<24} {r.target:<56} {text}")
        return 0
    try:
        cls = load_controller(args.name)
    except (UnknownControllerError, ControllerLoadError, InterfaceError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.cmd == "check":
        print(f"{args.name}: {cls.__module__}.{cls.__qualname__} satisfies the interface: {summary(cls)}")
        if not (math.isfinite(args.time) and args.time >= 0.0):
            print(f"error: --time must be a finite time >= 0 s, got {args.time!r}", file=sys.stderr)
            return 2
        try:
            out = one_period(args.name, args.time, dict(args.option))
        except ControllerFault as exc:
            print(f"{args.name}: FAILED: one period on a synthetic observation at t = {args.time:g} s: {exc}")
            return 1
        keys = ", ".join(sorted(out.status)) or "none"
        print(f"{args.name}: one period at t = {args.time:g} s on a synthetic observation (the gait family's initial "
              f"state, left stance): six finite torques {_numbers(out.torque)} N m, status keys: {keys}")
        print(f"{args.name}: {CHECK_SCOPE}")
        return 0
    from biped_controller.studies.trial.runs import DEFAULT_DURATION, DEFAULT_START
    start = DEFAULT_START if args.start is None else args.start
    duration = DEFAULT_DURATION if args.duration is None else args.duration
    if not (start >= 0 and duration > 0):
        print(f"error: --start must be >= 0 s and --duration > 0 s, got {start!r}, {duration!r}", file=sys.stderr)
        return 2
    from biped_sim.plant.perturbation import PerturbationError
    from biped_controller.studies.trial.settings import OverrideError, parse_perturbation
    try:
        perturbation = parse_perturbation(args.perturb)
    except (OverrideError, PerturbationError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from biped_sim.plant.config import load_sim_config      # the plant and the studies only for a run
    from biped_controller.studies import provenance
    from biped_controller.studies.trial.plugin_trials import PushTrials
    provenance.track(args.json, plant=args.plant, argv=argv)   # record of the file written (results/README.md)
    trials = PushTrials(args.name, sim_config=load_sim_config(plant=args.plant), options=dict(args.option),
                        perturbation=perturbation)
    r = trials.max_push(args.resolution, args.max, args.coarse, duration=duration, start=start,
                        sign=-1.0 if args.backward else 1.0)
    ff = "none" if r["first_failure"] is None else f"{r['first_failure']:g} N"
    print(f"{args.name} on {args.plant}: max push {r['max_force']:g} N (first failure {ff}: "
          f"{r['failure_cause'] or '-'}; islands {r['islands'] or '-'}; "
          + (f"no-fall edge {r['no_fall_undefined']}" if r.get("no_fall_undefined") else
             f"no-fall edge {r['no_fall_edge']:g} N, "
             f"first fall {'none' if r['first_fall'] is None else format(r['first_fall'], 'g') + ' N'}")
          + f"; {trials.trials} trials)")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({**r, "options": dict(args.option),
                                         "perturbation": None if perturbation is None else perturbation.as_dict()},
                                        indent=1))
    return 0


def _slices(args, argv: list[str] | None) -> int:
    from biped_controller.studies import provenance
    from biped_controller.studies.capmap.compare import CompareError, compare, markdown
    run = provenance.track(args.json, args.markdown, argv=argv)
    summaries = []
    for path in args.maps:
        try:
            summaries.append((str(path), json.loads(path.read_text(encoding="utf-8"))))
        except (OSError, ValueError) as exc:
            print(f"error: {path}: {exc}", file=sys.stderr)
            return 2
    try:
        cmp = compare(summaries, args.duration, provenance.default_plant(), args.tie)
    except KeyError as exc:
        print(f"error: a map summary lacks the field {exc}", file=sys.stderr)
        return 2
    except (CompareError, TypeError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    cmp["maps"] = [str(p) for p in args.maps]
    run.plant = ",".join(cmp["plants"])     # the plants the maps were run on (results/README.md: a comparison)
    text = markdown(cmp)
    print(text)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(cmp, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
