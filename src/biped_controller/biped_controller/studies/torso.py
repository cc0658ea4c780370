"""The torso parameter's results: cost in tracking and energy, and the p / tau / lambda figure.

    python -m biped_controller.studies.torso cost [--force 500] [--start 0.2315] [--duration 0.025]
        [--modes both,lambda,all] [--backward] [--steps 12] [--robot NAME|PATH] [--json FILE]
    python -m biped_controller.studies.torso figure --force F [--start S] [--duration D] [--backward]
        [--modes both,all] [--robot NAME|PATH] --out FILE.png [--json FILE]

``cost``: one push (or none, ``--force 0``) per mode, the in-process closed loop on the rigid plant
(``trial.runs.run``, ``steps`` impacts, on the ``--robot``), and per mode: survival (``trial.survival``), the largest and the
rms tracking error max_i |q_d,i - q_i| [rad] over the run (q_d = q_d(p, tau, lambda), the controller's own
reference), the actuators' absolute work sum_k sum_i |Gamma_i q'_i| dt_k [J] and the torque-squared
integral sum_k |Gamma|^2 dt_k [N^2 m^2 s] (a Joule-loss proxy), both over the same time span for every
mode (the first ``horizon`` seconds: the shortest run's, so a fall does not shorten one mode's sum only),
and the largest |lambda| [rad].

``figure``: the same push in each mode, p [m], tau' [-] and lambda [rad] against t [s] in one figure
(three panels, the paper's Figs. 4-5 style), the push shaded, each mode's fall marked.

A capability map's modes against a base per duration and direction, once ``compare`` here, is
``python -m lab.torso_compare`` (``lab/README.md``).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from biped_sim.plant.push import Push
from biped_controller.studies.trial.args import (StudyArgumentParser, add_modes_arg, add_robot_arg,
                                                 nonnegative_float, positive_float, positive_int, settings_from_args)
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.runs import DEFAULT_DURATION, DEFAULT_START, run
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings
from biped_controller.studies.trial import trials
from biped_controller.studies.trial.survival import FLOOR_BAND, survival_rule
from biped_controller.closed_loop.runner import RunResult
from biped_controller.studies import provenance


def push_runs(push: Push, modes, steps: int, settings: RunSettings = DEFAULT_SETTINGS) -> dict[str, RunResult]:
    """One run of ``steps`` impacts per mode with ``push`` (a zero force: no push), on the robot and the
    plant of ``settings``."""
    pushes = (push,) if push.force != 0 else ()
    return {m: run(steps, m, pushes, settings=settings) for m in modes}


def costs(runs: dict[str, RunResult], push_end: float, settings: RunSettings = DEFAULT_SETTINGS) -> dict:
    """Per mode: survival, tracking error (max, rms) [rad], absolute work [J], torque-squared integral
    [N^2 m^2 s] over the common horizon [s] (the shortest run's end), largest |lambda| [rad]."""
    horizon = min(r.records[-1].t_end for r in runs.values())
    out = {"horizon_s": horizon, "modes": {}}
    for m, r in runs.items():
        band = FLOOR_BAND if r.fallen else trials.walk_band(m, settings, r.steps_walked)
        v = survival_rule().verdict(r, push_end, band)
        ok, why = v.survived, v.reason
        keep = [k for k, rec in enumerate(r.records) if rec.t < horizon]
        dt = np.array([min(r.records[k].t_end, horizon) - r.records[k].t for k in keep])
        tq = np.array([r.records[k].torque for k in keep])
        qd = np.array([r.records[k].qd for k in keep])
        err = np.array([r.statuses[k].max_tracking_error for k in keep])
        out["modes"][m] = {
            "survived": bool(ok), "reason": why, "steps_walked": int(r.steps_walked),
            "max_tracking_error_rad": float(err.max()), "rms_tracking_error_rad": float(np.sqrt(np.mean(err**2))),
            "abs_work_J": float(np.sum(np.abs(tq * qd).sum(axis=1) * dt)),
            "torque_sq_integral": float(np.sum((tq**2).sum(axis=1) * dt)),
            "max_abs_lambda_rad": float(max(abs(s.lam) for s in r.statuses)),
        }
    return out


def figure(runs: dict[str, RunResult], push: Push, title: str, path: Path) -> Path:
    """p, tau' and lambda against t for each mode's run (three panels)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fam = context().family
    fig, ax = plt.subplots(3, 1, figsize=(7.5, 7.5), sharex=True)
    for m, r in runs.items():
        t = np.array([s.t for s in r.statuses])
        label = f"{m}: " + ("fell (" + r.fall_cause + ")" if r.fallen else "no fall")
        for a, name in zip(ax, ("p", "tau_dot", "lam")):
            line, = a.plot(t, [getattr(s, name) for s in r.statuses], lw=1.0, label=label)
            if r.fallen:
                a.axvline(r.fall_time, color=line.get_color(), ls="--", lw=0.8)
    ax[0].axhline(fam.p_d, color="k", ls=":", lw=0.8)
    ax[1].axhline(1.0, color="k", ls=":", lw=0.8)
    ax[2].axhline(0.0, color="k", ls=":", lw=0.8)
    for a, lab in zip(ax, ("p [m]", "tau' [-]", "lambda [rad] (+ leans back)")):
        a.axvspan(push.start, push.end, color="tab:red", alpha=0.15)
        a.set_ylabel(lab)
        a.grid(alpha=0.3)
    ax[0].set_title(title, fontsize=9)
    ax[0].legend(fontsize=8)
    ax[2].set_xlabel("t [s]")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = StudyArgumentParser(prog="python -m biped_controller.studies.torso", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("cost", "figure"):
        a = sub.add_parser(name)
        a.add_argument("--force", type=nonnegative_float, default=500.0, required=name == "figure", help="[N], + forward")
        a.add_argument("--start", type=nonnegative_float, default=DEFAULT_START, help="[s]")
        a.add_argument("--duration", type=positive_float, default=DEFAULT_DURATION, help="[s]")
        a.add_argument("--backward", action="store_true", help="push on the chest (negative force)")
        add_modes_arg(a, ("both", "lambda", "all") if name == "cost" else ("both", "all"),
                      "both,lambda,all" if name == "cost" else "both,all", controller=False)
        a.add_argument("--steps", type=positive_int, default=12, help="impacts to walk")
        add_robot_arg(a)
        a.add_argument("--json", type=Path)
        if name == "figure":
            a.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    settings = settings_from_args(ap, args)
    provenance.track(getattr(args, "json", None), getattr(args, "out", None), args=args, argv=argv)   # record of each file written (results/README.md)
    if not (math.isfinite(args.force) and args.force >= 0):
        ap.error(f"--force must be a finite number >= 0 (use --backward for the sign), got {args.force}")
    force = -args.force if args.backward else args.force
    push = Push(args.start, args.duration, force)
    runs = push_runs(push, args.modes, args.steps, settings)
    push_end = args.start + args.duration
    res = {"argv": list(sys.argv[1:] if argv is None else argv), "force": force, "start": args.start,
           "duration": args.duration, **costs(runs, push_end, settings)}
    print(f"push {force:g} N for {args.duration:g} s at t = {args.start:g} s; sums over the first {res['horizon_s']:.3f} s")
    print(f"{'mode':<7} {'survived':<9} {'max err':>9} {'rms err':>9} {'|work| J':>9} {'int G^2':>10} {'max|lam|':>9}")
    for m, c in res["modes"].items():
        print(f"{m:<7} {str(c['survived']):<9} {c['max_tracking_error_rad']:9.4f} {c['rms_tracking_error_rad']:9.4f} "
              f"{c['abs_work_J']:9.2f} {c['torque_sq_integral']:10.1f} {c['max_abs_lambda_rad']:9.4f}  {c['reason']}")
    if args.cmd == "figure":
        title = f"{force:g} N, {args.duration * 1e3:g} ms at t = {args.start:g} s"
        res["figure"] = str(figure(runs, push, title, args.out))
        print(f"figure: {res['figure']}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
