"""Checks of the sweeps' speed-ups, run once and reported in docs/capability_map.md.

``python -m biped_controller.studies.sweep_check compare FAST_SUMMARY FULL_SUMMARY [--stores FAST FULL]``
    every cell of two capability-map summaries (``--json`` of ``scripts/capability_map``): boundary,
    first failure, cause and islands, equal or not; with the stores, every (cell, force) simulated by
    both: survived and cause equal or not (the early-stopped trials of the fast map against the same
    trials run in full).

``python -m biped_controller.studies.sweep_check margins STORE [--sample N] [--seed S] [--workers W]``
    the early stop's argument measured: N early-stopped trials of a map's store (seeded sample) run
    again in full, recording at every check after an impact the plant's distance to the gait's fixed point and the
    controller's p, p', tau', force estimate; per trial the impact where ``EarlyStop.decided`` first
    holds, whether the full trial survives, and the largest distances at the later impacts and at the
    end, relative to the early-stop tolerances and to the survival rule's floors P_FLOOR and TAU_DOT_FLOOR (its band is never tighter).

Pure: no ROS import.
"""
from __future__ import annotations

import argparse
import json
import random
import sys
from pathlib import Path

import numpy as np

from biped_sim.plant.push import Push

from biped_controller.studies.trial import runs, stop, trials
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import RunSettings
from biped_controller.studies.trial.survival import P_FLOOR, TAU_DOT_FLOOR, survival_rule
from biped_controller.studies.capmap.spec import DIRECTIONS, onset_time
from biped_controller.studies.capmap.store import RecordStore
from biped_controller.studies.executor import make_executor
from biped_controller.studies import provenance


def _cells(summary: dict) -> dict:
    return {(b["mode"], b["direction"], b["phase"], b["duration"]): b for b in summary["boundaries"]}


def compare(fast: dict, full: dict, fast_records: list[dict] | None = None,
            full_records: list[dict] | None = None) -> dict:
    """Cell by cell (and, with records, trial by trial) comparison of two map summaries."""
    a, b = _cells(fast), _cells(full)
    common = sorted(set(a) & set(b))
    diff = {k: [] for k in ("force", "first_failure", "cause", "islands")}
    for c in common:
        for k in diff:
            if a[c][k] != b[c][k]:
                diff[k].append({"cell": list(c), "fast": a[c][k], "full": b[c][k]})
    out = {"cells_fast": len(a), "cells_full": len(b), "cells_compared": len(common),
           "differences": {k: len(v) for k, v in diff.items()}, "details": diff,
           "simulations_fast": fast["run"]["simulations_in_map"], "simulations_full": full["run"]["simulations_in_map"],
           "island_cells_fast": sum(1 for c in common if a[c]["islands"]),
           "island_cells_full": sum(1 for c in common if b[c]["islands"])}
    if fast_records is not None and full_records is not None:
        def key(r):
            return (r["mode"], r["direction"], float(r["phase"]), float(r["duration"]), float(r["force"]))
        fr = {key(r): r for r in full_records}
        both = [(r, fr[key(r)]) for r in fast_records if key(r) in fr]
        stopped = [(x, y) for x, y in both if x.get("decided_at_step") is not None]
        out["trials_in_both"] = len(both)
        out["trials_in_both_early_stopped"] = len(stopped)
        out["trial_outcome_differences"] = [
            {"key": list(key(x)), "fast": [x["survived"], x["cause"]], "full": [y["survived"], y["cause"]]}
            for x, y in both if (x["survived"], x["cause"]) != (y["survived"], y["cause"])]
    return out


def _impact_log(rec: dict, settings: RunSettings) -> dict:
    """One record's trial again in full, with the early-stop quantities at every impact."""
    ctx = context()
    fam, es = ctx.family, stop.early_stop()
    start = onset_time(float(rec["phase"]), fam.T)
    end = start + float(rec["duration"])
    rows = []

    def log(sim, ctrl) -> bool:
        imp = sim.impact_log[-1]
        q, qd = sim.fm.paper_from_state(sim.x, sim.v, sim.stance)
        g = fam.evaluate(fam.p_d, sim.t - imp.t)
        s = ctrl.state
        rows.append({"impact": int(sim.impact_count), "t": float(sim.t), "t_impact": float(imp.t),
                     "after_push": bool(imp.t >= end),
                     "decided": es.decided(sim, ctrl, end, fam),
                     "q": float(np.max(np.abs(q - g.q))), "qd": float(np.max(np.abs(qd - g.dq_dtau))),
                     "p": abs(s.p - fam.p_d), "p_dot": abs(s.p_dot), "tau_dot": abs(s.tau_dot - 1.0),
                     "force": abs(ctrl.force_estimate)})
        return False
    signed = DIRECTIONS[rec["direction"]] * float(rec["force"])
    push = Push(start, float(rec["duration"]), float(signed), rec.get("height"))
    res = runs.push_run(push, rec["mode"], settings=settings, keep_records=False, on_impact=log)
    v = survival_rule().verdict(res, end, trials.band(rec["mode"], push, settings))
    ok, why = v.survived, v.reason
    last = res.statuses[-1]
    return {"key": [rec["mode"], rec["direction"], rec["phase"], rec["duration"], rec["force"]],
            "survived_full": ok, "reason_full": why, "impacts": rows,
            "end": {"p": abs(last.p - fam.p_d), "tau_dot": abs(last.tau_dot - 1.0)}}


def margins(records: list[dict], sample: int, seed: int, workers: int) -> dict:
    """The early-stopped trials of ``records`` (a seeded sample of ``sample``) run in full: see the module."""
    stopped = [r for r in records if r.get("decided_at_step") is not None]
    rng = random.Random(seed)
    pick = rng.sample(stopped, min(sample, len(stopped)))
    settings = RunSettings(full_trials=True)
    with make_executor(workers, initializer=context) as ex:
        logs = ex.map(_impact_log, [(r, settings) for r in pick])
    es = stop.early_stop()
    tol = {"q": es.q, "qd": es.qd, "p": es.p, "p_dot": es.p_dot, "tau_dot": es.tau_dot, "force": es.force}
    worst = {k: 0.0 for k in tol}
    worst_end = {"p": 0.0, "tau_dot": 0.0}
    all_later_inside = True
    decided_where_stopped = 0
    for lg, r in zip(logs, pick):
        # on_impact runs once or twice per impact (one period after it, and at the next compiled segment's end)
        k = next(i for i, row in enumerate(lg["impacts"]) if row["decided"])
        decided_where_stopped += lg["impacts"][k]["impact"] == r["decided_at_step"]
        for row in lg["impacts"][k + 1:]:
            for name in tol:
                worst[name] = max(worst[name], row[name] / tol[name])
            all_later_inside &= row["decided"]
        worst_end["p"] = max(worst_end["p"], lg["end"]["p"] / P_FLOOR)
        worst_end["tau_dot"] = max(worst_end["tau_dot"], lg["end"]["tau_dot"] / TAU_DOT_FLOOR)
    return {"early_stopped_in_store": len(stopped), "sample": len(pick), "seed": seed,
            "survived_in_full": sum(1 for lg in logs if lg["survived_full"]),
            "decided_at_the_same_impact": decided_where_stopped,
            "every_later_impact_inside_the_tolerances": bool(all_later_inside),
            "largest_later_distance_over_tolerance": worst,
            "largest_end_distance_over_survival_tolerance": worst_end,
            "tolerances": tol, "trials": logs}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="sweep_check", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("compare")
    a.add_argument("fast", type=Path)
    a.add_argument("full", type=Path)
    a.add_argument("--stores", nargs=2, type=Path, default=None, metavar=("FAST", "FULL"))
    a.add_argument("--json", type=Path, default=None)
    m = sub.add_parser("margins")
    m.add_argument("store", type=Path)
    m.add_argument("--sample", type=int, default=100)
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--workers", type=int, default=2)
    m.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    provenance.track(args.json, args=args, argv=argv)   # record of each file written (results/README.md)
    if args.cmd == "compare":
        fast, full = (json.loads(p.read_text()) for p in (args.fast, args.full))
        recs = [RecordStore(p).load() for p in args.stores] if args.stores else [None, None]
        out = compare(fast, full, *recs)
        brief = {k: v for k, v in out.items() if k != "details"}
        print(json.dumps(brief, indent=1))
        for k, v in out["details"].items():
            for d in v[:10]:
                print(f"{k}: {d}")
    else:
        out = margins(RecordStore(args.store).load(), args.sample, args.seed, args.workers)
        print(json.dumps({k: v for k, v in out.items() if k != "trials"}, indent=1))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1, allow_nan=False, default=float) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
