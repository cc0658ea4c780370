"""Does the MuJoCo early stop (``trial.stop.MujocoEarlyStop``) hold under sensor noise? Trials of a seeded-map
store (``scripts/capability_map --seeds N --store F``, run in full: a noisy profile's trials are never stopped
early today) run again in full, each with its own seed, recording at every check after a touchdown the
quantities the criterion bounds (``MujocoEarlyStop.distances``), with the tolerances of the trial's own band
(its seed's unpushed walk).

    .venv/bin/python -m lab.noisy_early_stop STORE.jsonl [--cells D:PHASE ...] [--batches mixed|all]
        [--per-cell N] [--seed S] [--workers W] --json F

Per trial: whether the run in full reproduces the stored record (verdict, reason, fall time, impacts walked,
parameter excursion: the check that logging at the touchdowns changes nothing), the first check where the
criterion holds (the touchdown where the early stop would end it) and the full verdict. Over all trials:
the survivors decided and the impacts that saves, every decided trial that did not survive in full (the
criterion's error: must be none), and how close the failing trials came to being decided (their smallest
largest-distance-over-tolerance after the push). ``--batches mixed``: per cell and mode the stored force
batches whose survival rate lies strictly between 0 and 1 (the trials the crossings rest on), ``all``:
every batch; ``--per-cell N``: at most N trials per cell, a seeded sample. Pure: no ROS import.
"""
from __future__ import annotations

import argparse
import json
import math
import random
import time
from pathlib import Path

from biped_controller.closed_loop.executor import make_executor
from biped_controller.studies import provenance
from biped_controller.studies.capmap.spec import DIRECTIONS, onset_time
from biped_controller.studies.trial import runs, seeded, stop, trials
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.controller import parameter_excursion
from biped_controller.studies.trial.runs import paper_push
from biped_controller.studies.trial.settings import differences, run_settings
from biped_controller.studies.trial.survival import survival_rule
from lab.sweep_check import ORBIT_KEYS, _Band, _finite, orbit_tolerances

#: the record's fields a full re-run must reproduce to the last bit
SAME = ("survived", "fell", "reason", "fall_cause", "fall_time", "steps_walked", "max_abs_p_minus_pd", "min_p",
        "max_p", "min_tau_dot", "max_tau_dot")


def _log(task: tuple) -> dict:
    """One stored trial again in full with the criterion's distances at every check after a touchdown."""
    rec, direction, phase, duration, profile = task
    settings = seeded.seeded_settings(run_settings(profile), rec["seed"])
    fam = context().family
    dt = settings.sim_config().control_period
    start = onset_time(float(phase), fam.T)
    push = paper_push(DIRECTIONS[direction] * float(rec["force"]), start=start, duration=float(duration))
    end = start + float(duration)
    rows = []

    def log(sim, ctrl) -> bool:
        rows.append({"impact": int(sim.impact_count), **stop.MujocoEarlyStop.distances(sim, ctrl, end, fam, dt)})
        return False
    res = runs.push_run(push, rec["mode"], settings=settings, keep_records=False, on_impact=log)
    band = trials.band(rec["mode"], push, settings)
    v = survival_rule().verdict(res, end, band)
    # the record's fields from this run (the same as trials.survives's without an early stop)
    again = {"survived": bool(v.survived), "fell": bool(v.fell), "reason": v.reason, "fall_cause": res.fall_cause,
             "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
             "steps_walked": int(res.steps_walked), **parameter_excursion(res)}
    return {"key": [rec["mode"], direction, float(phase), float(rec["force"]), int(rec["seed_index"])],
            "survived_full": bool(v.survived), "reason_full": v.reason, "band": band.as_dict(),
            "steps": runs.trial_steps(push), "impacts": rows,
            "reproduced": {k: again.get(k) == rec.get(k) for k in SAME},
            "full_equals_record": bool(v.survived) == bool(rec["survived"]) and v.reason == rec["reason"]}


def pick(store: Path, cells: list[str] | None, batches: str, per_cell: int | None, seed: int) -> tuple[list, str]:
    """The (record, direction, phase, duration, profile) tasks: see the module docstring."""
    rng = random.Random(seed)
    tasks, profile = [], None
    for line in store.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        cell = json.loads(line)
        key = cell["key"]
        tag = f"{key['direction']}:{key['phase']:g}"
        if cells is not None and tag not in cells:
            continue
        prof = key["settings"]["profile"]
        if profile is None:
            profile = prof
            if json.loads(json.dumps(differences(run_settings(prof)))) != key["settings"]:
                raise SystemExit(f"{store}: the store's settings are not profile {prof!r}'s with today's config")
        elif prof != profile:
            raise SystemExit(f"{store}: more than one profile ({profile}, {prof})")
        chosen = []
        for res in cell["result"].values():
            keep = {row["force"] for row in res["rates"]
                    if batches == "all" or (row["counted"] and 0 < row["survived"] < row["counted"])}
            chosen += [r for r in res["trials"] if r["force"] in keep]
        if per_cell is not None and len(chosen) > per_cell:
            chosen = rng.sample(chosen, per_cell)
        tasks += [(r, key["direction"], key["phase"], key["duration"], prof) for r in chosen]
    return tasks, profile


def summarize(logs: list[dict], es: stop.MujocoEarlyStop) -> dict:
    """The figures of the module docstring from :func:`_log`'s logs, with the criterion ``es``."""
    out_trials, wrong, closest, decided, saved, in_full = [], [], [], 0, 0, 0
    for lg in logs:
        tol = orbit_tolerances(es, lg["band"])
        ratios = [max(r[k] / tol[k] for k in ORBIT_KEYS) if r["after_push"] else math.inf for r in lg["impacts"]]
        first = next((i for i, r in enumerate(lg["impacts"]) if es.inside(r, _Band(lg["band"]))), None)
        at = lg["impacts"][first]["impact"] if first is not None else None
        if lg["survived_full"]:
            in_full += lg["steps"]
        if at is not None:
            decided += 1
            saved += lg["steps"] - at
            if not lg["survived_full"]:
                wrong.append(lg["key"])
        else:
            closest.append(min(ratios, default=math.inf)) if not lg["survived_full"] else None
        worst = ({k: max(r[k] / tol[k] for r in lg["impacts"][first:]) for k in ORBIT_KEYS}
                 if first is not None else None)
        out_trials.append({"key": lg["key"], "survived_full": lg["survived_full"], "decided_at": at,
                           "steps": lg["steps"], "closest_over_tolerance": _finite(min(ratios, default=math.inf)),
                           "later_worst_over_tolerance": worst,
                           "reproduced": all(lg["reproduced"].values()) and lg["full_equals_record"]})
    survivors = [t for t in out_trials if t["survived_full"]]
    fin = [c for c in closest if math.isfinite(c)]
    return {"criterion": es.identity(), "trials": len(logs),
            "reproduced": sum(1 for t in out_trials if t["reproduced"]),
            "survived_in_full": len(survivors), "survivors_decided": sum(1 for t in survivors if t["decided_at"]),
            "decided": decided, "decided_but_not_survived_in_full": wrong,
            "impacts_saved": saved, "survivor_impacts_in_full": in_full,
            "failing_closest_over_tolerance": min(fin) if fin else None,
            "failing_never_checked_after_the_push": len(closest) - len(fin),
            "per_trial": out_trials}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="noisy_early_stop", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("store", type=Path)
    ap.add_argument("--cells", nargs="+", default=None, metavar="DIRECTION:PHASE")
    ap.add_argument("--batches", choices=("mixed", "all"), default="mixed")
    ap.add_argument("--per-cell", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args(argv)
    provenance.track(args.json, argv=argv)
    tasks, profile = pick(args.store, args.cells, args.batches, args.per_cell, args.seed)
    t0 = time.perf_counter()
    with make_executor(args.workers, initializer=context) as ex:
        logs = ex.map(_log, [(t,) for t in tasks])
    out = summarize(logs, stop.mujoco_early_stop())
    out.update({"store": str(args.store), "profile": profile, "cells": args.cells, "batches": args.batches,
                "per_cell": args.per_cell, "seed": args.seed, "wall_s": time.perf_counter() - t0, "logs": logs})
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    print(f"{out['trials']} trials ({out['reproduced']} reproduce their records); {out['survived_in_full']} survive in "
          f"full, {out['survivors_decided']} of them decided, saving {out['impacts_saved']} of "
          f"{out['survivor_impacts_in_full']} impacts; decided but not surviving: {len(out['decided_but_not_survived_in_full'])}; "
          f"failing trials' closest: {out['failing_closest_over_tolerance']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
