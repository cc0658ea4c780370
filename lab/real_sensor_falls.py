"""Why do modes none and p fall unpushed on every seed under the real-sensors profile on the rigid plant?

``python -m lab.real_sensor_falls [--seeds 16] [--steps 2] [--json F]`` (issue 43). Each row is one variant of
the real-sensors settings (the profile's controller settings, the plant's noise ``perturbation``), run unpushed
for ``--steps`` impacts on seeds 0..S-1 per mode (``runner.run``, records kept). Per (variant, mode): how many
seeds fell, their causes and fall times, and the centre of pressure l = m / F_z [m] of the first period (the
plant's wrench check at t = 0: heel l_min = -0.1 m, toe l_max = 0.1 m), its mean and spread over the seeds, and
per seed the smallest distance of l to the foot's edges over the run (the margin; negative: the fall).

Variants (what each isolates):

* ``ideal``: no sensor model, the profile's estimator and observer off (the paper's setting): the nominal
  margin of the gait at t = 0;
* ``controller-only``: the profile's controller settings, the plant's noise off (``--perturb none``): the
  estimator and the observer on a true sample (a bias of theirs shows here);
* ``design``: the profile as committed (noise_q 5e-4 rad, noise_q' 5e-2 rad/s, 14-bit encoders);
* ``q-only``, ``qd-only``, ``encoder-only``: one source of the design point at a time;
* ``scale-0.1``, ``scale-0.25``, ``scale-0.5``: the design point's noise scaled (the encoders kept);
* ``no-estimator``: the design point with the estimator off (the raw sample acts);
* ``exact-first``: the design point, but the first period's draws are zero (the first sample is the true
  state, quantised): the estimator then starts from the truth (its start transient isolated; a lab-only
  patch of ``SensorModel.noise_rows``, nothing of the product changed);
* ``exact-first-10``: the same for the first 10 periods.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import statistics
import sys
from dataclasses import replace
from pathlib import Path

from biped_sim.plant.perturbation import SensorModel

from biped_controller.closed_loop import runner
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import run_settings

L_MIN, L_MAX = -0.1, 0.1

VARIANTS: dict[str, tuple[str | None, tuple[str, ...], tuple[str, ...]]] = {
    # name: (profile, controller overrides, plant perturbation)
    "ideal": (None, (), ()),
    "controller-only": ("real-sensors", (), ("none",)),
    "design": ("real-sensors", (), ()),
    "q-only": ("real-sensors", (), ("none", "noise_q=5e-4")),
    "qd-only": ("real-sensors", (), ("none", "noise_qd=5e-2")),
    "encoder-only": ("real-sensors", (), ("none", "encoder_bits=14")),
    "scale-0.1": ("real-sensors", (), ("none", "noise_q=5e-5", "noise_qd=5e-3", "encoder_bits=14")),
    "scale-0.25": ("real-sensors", (), ("none", "noise_q=1.25e-4", "noise_qd=1.25e-2", "encoder_bits=14")),
    "scale-0.5": ("real-sensors", (), ("none", "noise_q=2.5e-4", "noise_qd=2.5e-2", "encoder_bits=14")),
    "no-estimator": ("real-sensors", ("state_estimator=false",), ()),
    "exact-first": ("real-sensors", (), ()),
    "exact-first-10": ("real-sensors", (), ()),
}
#: variants whose first k periods draw no noise (``exact_first``)
EXACT_FIRST = {"exact-first": 1, "exact-first-10": 10}


@contextlib.contextmanager
def exact_first(k: int):
    """``SensorModel.noise_rows`` with the rows of the first ``k`` sampled periods zeroed (lab-only patch)."""
    orig = SensorModel.noise_rows

    def patched(self, n):
        fresh = self._first is None and self._zpos == 0 and not getattr(self, "_lab_zeroed", False)
        rows = orig(self, max(n, k))
        if fresh:
            rows[:k] = 0.0
            self._lab_zeroed = True
        return rows
    SensorModel.noise_rows = patched
    try:
        yield
    finally:
        SensorModel.noise_rows = orig


def settings_of(variant: str, seed: int):
    profile, overrides, perturb = VARIANTS[variant]
    s = run_settings(profile, list(overrides), perturb=list(perturb))
    if s.perturbation is None:          # nothing random: every seed is the same run
        return s
    return replace(s, perturbation=replace(s.perturbation, seed=int(seed)))


def deterministic(variant: str) -> bool:
    """The variant draws no noise (one run stands for every seed)."""
    p = settings_of(variant, 0).perturbation
    return p is None or p.sensing_is_perfect


def walk(variant: str, mode: str, seed: int, steps: int) -> dict:
    """One unpushed walk: fell, cause, time, the first period's l [m] and the run's smallest edge margin [m]."""
    ctx = context()
    s = settings_of(variant, seed)
    with exact_first(EXACT_FIRST.get(variant, 0)) if variant in EXACT_FIRST else contextlib.nullcontext():
        res = runner.run(steps, mode, (), sim_config=s.sim_config(), ctrl_config=s.ctrl_config(mode),
                         family=ctx.family, desc=ctx.desc, perturbation=s.perturbation, keep_records=True)
    ls = [r.cop for r in res.records if math.isfinite(r.cop)]
    l0 = res.records[0].cop if res.records else math.nan
    return {"seed": seed, "fell": bool(res.fallen), "cause": res.fall_cause,
            "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time), "steps": int(res.steps_walked),
            "l0": float(l0), "min_margin": float(min(min(l - L_MIN, L_MAX - l) for l in ls)) if ls else math.nan,
            "noise": s.perturbation.as_dict() if s.perturbation is not None else None}


def summarize(rows: list[dict]) -> dict:
    l0 = [r["l0"] for r in rows if math.isfinite(r["l0"])]
    causes: dict[str, int] = {}
    for r in rows:
        if r["fell"]:
            causes[r["cause"]] = causes.get(r["cause"], 0) + 1
    times = [r["fall_time"] for r in rows if r["fell"] and r["fall_time"] is not None]
    return {"seeds": len(rows), "fell": sum(r["fell"] for r in rows), "causes": causes,
            "fall_time_median": statistics.median(times) if times else None,
            "l0_mean": statistics.fmean(l0) if l0 else None,
            "l0_std": statistics.pstdev(l0) if len(l0) > 1 else 0.0,
            "l0_min": min(l0) if l0 else None, "l0_max": max(l0) if l0 else None,
            "min_margin_median": statistics.median(r["min_margin"] for r in rows)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.real_sensor_falls", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--steps", type=int, default=2)
    ap.add_argument("--modes", default="none,p,tau,both")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    if args.seeds < 1 or args.steps < 1:
        ap.error("--seeds and --steps must be >= 1")
    variants = args.variants.split(",")
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        ap.error(f"unknown variant {bad[0]!r} (one of {', '.join(VARIANTS)})")
    if args.json is not None:
        from biped_controller.studies import provenance
        provenance.track(args.json, argv=argv, plant="rigid", profile="real-sensors")
    out = {"what": __doc__.split("\n\n")[0], "seeds": args.seeds, "steps": args.steps, "l_min": L_MIN, "l_max": L_MAX,
           "variants": {}}
    print(f"{'variant':16s} {'mode':5s} fell  l0 mean   l0 std   l0 min   l0 max  margin p50  causes")
    for v in variants:
        out["variants"][v] = {}
        for m in args.modes.split(","):
            seeds = range(1) if deterministic(v) else range(args.seeds)
            rows = [walk(v, m, i, args.steps) for i in seeds]
            s = summarize(rows)
            out["variants"][v][m] = {"summary": s, "runs": rows}
            f = lambda x: f"{x:8.4f}" if x is not None else "       -"   # noqa: E731
            print(f"{v:16s} {m:5s} {s['fell']:2d}/{s['seeds']:<2d} {f(s['l0_mean'])} {f(s['l0_std'])} "
                  f"{f(s['l0_min'])} {f(s['l0_max'])} {f(s['min_margin_median'])}   {s['causes']}", flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
