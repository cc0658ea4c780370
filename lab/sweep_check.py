"""Checks of the sweeps' speed-ups, run once and reported in docs/capability_map.md.

``python -m lab.sweep_check compare FAST_SUMMARY FULL_SUMMARY [--stores FAST FULL]``
    every cell of two capability-map summaries (``--json`` of ``scripts/capability_map``): boundary,
    first failure, cause, islands, no-fall edge, first fall and its cause, equal or not; with the stores, every (cell, force) simulated by
    both: survived and cause equal or not (the early-stopped trials of the fast map against the same
    trials run in full).

``python -m lab.sweep_check margins STORE [--sample N] [--seed S] [--workers W]``
    the early stop's argument measured: N early-stopped trials of a map's store (seeded sample) run
    again in full, recording at every check after an impact the plant's distance to the gait's fixed point and the
    controller's p, p', tau', force estimate; per trial the impact where ``EarlyStop.decided`` first
    holds, whether the full trial survives, and the largest distances at the later impacts and at the
    end, relative to the early-stop tolerances and to the survival rule's floors P_FLOOR and TAU_DOT_FLOOR (its band is never tighter).

``python -m lab.sweep_check orbit SUMMARY [--set K=V ...] [--durations D ...] [--fractions F ...]``
    the MuJoCo early stop's argument measured (``trial.stop.MujocoEarlyStop``): each mode's unpushed walk
    and pushed trials of a map's cells (forces: ``--fractions`` of each cell's boundary and its first
    failing force) run in full, recording at every check after an impact the quantities the criterion
    bounds (``MujocoEarlyStop.distances``); per trial the impact where the criterion first holds and the
    full trial's verdict, and over all trials: the unpushed walks' largest distances, the settled pushed
    walks' (the last ``--settled`` impacts of the survivors), whether every trial the criterion decides
    survives in full, and how close the failing trials came to being decided.

``python -m lab.sweep_check replay STORE [--set K=V ...] [--profile P] [--modes M ...]``
    a record is a function of its trial alone: every record of a map's store made with these settings (its
    fingerprint) simulated again, in the store's order, twice -- on new objects (a new loop pool per
    trial) and on one pool reused from trial to trial, as a map's worker runs them -- and compared field
    by field: the two replays with each other (any difference: the record depends on the trials run
    before it) and the new-object replay with the stored record (the records a change of the code
    changed, each field's old and new value and relative change). Records of another fingerprint are
    counted, not replayed.

``python -m lab.sweep_check bracket-replay FULL_STORE [--windows W ...] [--below B ...]``
    the bracketed search replayed, without a simulation, on the records of a full search (``--search
    full``: every coarse force of every cell and its bisection): for each island window W and bracket
    check B (``island_window``, ``bracket_check_below`` of config/studies.yaml), the simulations the
    bracketed search runs and the cells whose answer (boundary, first failure, islands, no-fall edge, first
    fall) differs from the full search's on the same records; a cell whose bracketed search needs a force
    the full search did not run (another bisection: another edge) is counted as differing.

Pure: no ROS import.
"""
from __future__ import annotations

import argparse
import json
import math
import random
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from biped_sim.plant.push import Push

from biped_controller.studies.trial import runs, stop, trials
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import RunSettings, differences, run_settings
from biped_controller.studies.trial.survival import P_FLOOR, TAU_DOT_FLOOR, survival_rule
from biped_controller.studies.capmap.search import Boundary, coarse_edge, plan_cell, plan_no_fall
from biped_controller.studies.capmap.spec import DEFAULT_COARSE, DEFAULT_MAX, DEFAULT_MAX_IMPULSE, DEFAULT_RESOLUTION, \
    DIRECTIONS, Cell, MapSpec, Search, SimSpec, onset_time
from biped_controller.studies.capmap.store import fingerprint as map_fingerprint
from biped_controller.studies.capmap.task import simulate
from biped_controller.studies.capmap.store import RecordStore
from biped_controller.closed_loop.executor import make_executor
from biped_controller.closed_loop import runner
from biped_controller.studies import provenance


def _cells(summary: dict) -> dict:
    return {(b["mode"], b["direction"], b["phase"], b["duration"]): b for b in summary["boundaries"]}


def compare(fast: dict, full: dict, fast_records: list[dict] | None = None,
            full_records: list[dict] | None = None) -> dict:
    """Cell by cell (and, with records, trial by trial) comparison of two map summaries."""
    a, b = _cells(fast), _cells(full)
    common = sorted(set(a) & set(b))
    diff = {k: [] for k in ("force", "first_failure", "cause", "islands", "no_fall_edge", "first_fall", "fall_cause")}
    for c in common:
        for k in diff:
            if a[c].get(k) != b[c].get(k):          # (a summary written before a key existed: None)
                diff[k].append({"cell": list(c), "fast": a[c].get(k), "full": b[c].get(k)})
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


#: the quantities ``MujocoEarlyStop`` bounds, and the tolerance each is held to (band: a fraction of the band)
ORBIT_KEYS = ("q", "q_in", "qd_in", "p", "tau_dot", "p_dot", "force", "lam", "lam_dot")


def orbit_tolerances(es: stop.MujocoEarlyStop, band: dict) -> dict:
    """The tolerance of each of :data:`ORBIT_KEYS` for a trial with ``band`` (``Band.as_dict``)."""
    return {"q": es.q, "q_in": es.q, "qd_in": es.qd, "p": es.band * band["p_tol"],
            "tau_dot": es.band * band["tau_dot_tol"], "p_dot": es.p_dot_rate * es.band * band["p_tol"],
            "force": es.force, "lam": es.lam, "lam_dot": es.lam_dot}


def _orbit_log(task: tuple) -> dict:
    """One trial (``force`` 0: the unpushed walk of ``steps`` impacts) run in full, with
    ``MujocoEarlyStop.distances`` at every check after an impact."""
    mode, direction, phase, duration, force, steps, settings = task
    fam = context().family
    dt = settings.sim_config().control_period
    start = onset_time(float(phase), fam.T)
    end = start + float(duration) if force else 0.0
    rows = []

    def log(sim, ctrl) -> bool:
        d = stop.MujocoEarlyStop.distances(sim, ctrl, end, fam, dt)
        rows.append({"impact": int(sim.impact_count), **d})
        return False
    push = Push(start, float(duration), DIRECTIONS[direction] * float(force), None)
    if force:
        res = runs.push_run(push, mode, settings=settings, keep_records=False, on_impact=log)
        band = trials.band(mode, push, settings)
        v = survival_rule().verdict(res, end, band)
        n = runs.trial_steps(push)
    else:
        res = runs.run(steps, mode, (), settings=settings, keep_records=False, on_impact=log)
        band = trials.walk_band(mode, settings, steps)
        v = survival_rule().verdict(res, 0.0, band)
        n = steps
    last = res.statuses[-1]
    return {"key": [mode, direction, float(phase), float(duration), float(force)], "steps": n,
            "survived_full": v.survived, "fell": v.fell, "reason_full": v.reason, "band": band.as_dict(),
            "end": {"p": abs(last.p - fam.p_d), "tau_dot": abs(last.tau_dot - 1.0)}, "impacts": rows}


def orbit_pushes(summary: dict, durations: tuple[float, ...], fractions: tuple[float, ...],
                 phases: tuple[float, ...] | None = None) -> list[tuple]:
    """(mode, direction, phase, duration, force) of the pushes to measure: per cell of ``summary`` (a map's
    ``--json``) with a duration in ``durations`` (and a phase in ``phases``, None: all), ``fractions`` of its
    boundary force and its first failing force (none when censored), each force once."""
    out = []
    for b in summary["boundaries"]:
        if not any(abs(b["duration"] - d) < 1e-12 for d in durations):
            continue
        if phases is not None and not any(abs(b["phase"] - ph) < 1e-12 for ph in phases):
            continue
        forces = sorted({round(f * b["force"], 6) for f in fractions if f * b["force"] > 0}
                        | ({b["first_failure"]} if b.get("first_failure") is not None else set()))
        out += [(b["mode"], b["direction"], b["phase"], b["duration"], f) for f in forces]
    return out


def orbit_summary(logs: list[dict], es: stop.MujocoEarlyStop, settled: int) -> dict:
    """The figures of ``orbit`` (module docstring) from :func:`_orbit_log`'s logs, with the criterion ``es``."""
    walks = [lg for lg in logs if lg["key"][4] == 0]
    pushed = [lg for lg in logs if lg["key"][4] != 0]

    def worst(rows) -> dict:
        return {k: max((r[k] for r in rows), default=0.0) for k in ORBIT_KEYS + ("qd",)}
    unpushed = {lg["key"][0]: {"impacts": len(lg["impacts"]), "band": lg["band"],
                               "largest": worst(lg["impacts"][1:]), "first_impact": worst(lg["impacts"][:1])}
                for lg in walks}
    settled_rows = [r for lg in pushed if lg["survived_full"]
                    for r in [x for x in lg["impacts"] if x["after_push"]][-settled:]]
    trials_out, wrong, decided, saved, closest = [], [], 0, 0, []
    for lg in pushed:
        tol = orbit_tolerances(es, lg["band"])
        ratios = [max(r[k] / tol[k] for k in ORBIT_KEYS) if r["after_push"] else math.inf for r in lg["impacts"]]
        first = next((i for i, (r, x) in enumerate(zip(lg["impacts"], ratios)) if es.inside(r, _Band(lg["band"]))),
                      None)
        at = lg["impacts"][first]["impact"] if first is not None else None
        if at is not None:
            decided += 1
            saved += lg["steps"] - at
            if not lg["survived_full"]:
                wrong.append(lg["key"])
        if not lg["survived_full"]:
            closest.append(min(ratios, default=math.inf))
        trials_out.append({"key": lg["key"], "survived_full": lg["survived_full"], "fell": lg["fell"],
                           "decided_at": at, "steps": lg["steps"],
                           "closest_over_tolerance": _finite(min(ratios, default=math.inf))})
    fin = [c for c in closest if math.isfinite(c)]
    return {"criterion": asdict(es), "unpushed": unpushed,
            "settled": {"impacts": len(settled_rows), "last_impacts_per_trial": settled, "largest": worst(settled_rows)},
            "pushed_trials": len(pushed), "survived_in_full": sum(1 for lg in pushed if lg["survived_full"]),
            "decided": decided, "decided_but_not_survived_in_full": wrong,
            "impacts_saved": saved, "impacts_in_full": sum(lg["steps"] for lg in pushed),
            "failing_closest_over_tolerance": min(fin) if fin else None,
            "failing_never_after_the_push": len(closest) - len(fin),
            "trials": trials_out}


def _finite(x: float) -> float | None:
    """``x``, or None where it is not finite (JSON)."""
    return x if math.isfinite(x) else None


class _Band:
    """A ``Band.as_dict`` read back (what ``MujocoEarlyStop.inside`` reads of a band)."""

    def __init__(self, d: dict):
        self.p_tol, self.tau_dot_tol = d["p_tol"], d["tau_dot_tol"]


def orbit(summary: dict, settings: RunSettings, modes: tuple[str, ...], durations: tuple[float, ...],
          fractions: tuple[float, ...], phases: tuple[float, ...] | None, walk_steps: int, workers: int,
          settled: int) -> dict:
    """Run :func:`_orbit_log` on each mode's unpushed walk and on :func:`orbit_pushes`; :func:`orbit_summary`."""
    pushes = [p for p in orbit_pushes(summary, durations, fractions, phases) if p[0] in modes]
    tasks = [(m, "forward", 0.0, 0.0, 0.0, walk_steps, settings) for m in modes] + \
            [(*p, 0, settings) for p in pushes]
    with make_executor(workers, initializer=context) as ex:
        logs = ex.map(_orbit_log, [(t,) for t in tasks])
    es = stop.mujoco_early_stop()
    out = orbit_summary(logs, es, settled)
    out["settings"] = differences(settings)
    out["logs"] = logs
    return out


def _field_changes(old: dict, new: dict) -> dict:
    """{field: {old, new, relative}} of the fields of two records that differ (``relative``: |new - old| /
    max(|old|, |new|) for two numbers, None otherwise); the store's own ``fingerprint`` is left out."""
    out = {}
    for k in sorted(set(old) | set(new)):
        if k == "fingerprint":
            continue
        a, b = old.get(k), new.get(k)
        if a == b:
            continue
        num = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (a, b))
        rel = abs(b - a) / max(abs(a), abs(b)) if num and max(abs(a), abs(b)) > 0 else None
        out[k] = {"old": a, "new": b, "relative": rel}
    return out


def replay(records: list[dict], settings: RunSettings, modes: tuple[str, ...] | None = None) -> dict:
    """``replay`` (module docstring) of ``records`` with ``settings`` (the settings the map ran with):
    only the records whose fingerprint is that of ``settings`` (and of their push height), of ``modes``
    when given. Returns the counts, the records whose two replays differ (``history_dependent``), and those
    whose replay on new objects differs from the stored record (``changed``, by field)."""
    fps: dict = {}
    shared = runner.LoopPool()
    out = {"records_in_store": len(records), "other_fingerprint": 0, "other_mode": 0, "replayed": 0,
           "history_dependent": [], "changed": [], "outcome_changed": 0}
    for rec in records:
        if modes is not None and rec["mode"] not in modes:
            out["other_mode"] += 1
            continue
        height = rec.get("height")
        key = (rec["mode"], height)
        if key not in fps:
            fps[key] = map_fingerprint(MapSpec(modes=(rec["mode"],), height=height, settings=settings,
                                               neighbours=False, island_window=0))
        if rec.get("fingerprint") != fps[key]:
            out["other_fingerprint"] += 1
            continue
        spec = SimSpec(Cell(rec["mode"], rec["direction"], float(rec["phase"]), float(rec["duration"])),
                       float(rec["force"]))
        alone = simulate(spec, settings, height, pool=runner.LoopPool())
        reused = simulate(spec, settings, height, pool=shared)
        out["replayed"] += 1
        tag = [rec["mode"], rec["direction"], rec["phase"], rec["duration"], rec["force"]]
        if reused != alone:
            out["history_dependent"].append({"key": tag, "fields": _field_changes(alone, reused)})
        ch = _field_changes(rec, alone)
        if ch:
            out["changed"].append({"key": tag, "fields": ch})
            out["outcome_changed"] += int(any(k in ch for k in ("survived", "cause", "fall_time", "steps_walked",
                                                                 "decided_at_step")))
    fields: dict = {}
    for c in out["changed"]:
        for k, v in c["fields"].items():
            f = fields.setdefault(k, {"records": 0, "max_relative": 0.0})
            f["records"] += 1
            if v["relative"] is not None:
                f["max_relative"] = max(f["max_relative"], v["relative"])
    out["changed_fields"] = fields
    out["settings"] = differences(settings)
    return out


def _replay_cell(search: Search, surv: dict, fell: dict, hint: float | None, window: int, below: int):
    """One cell's search (``plan_cell`` then ``plan_no_fall``) on the records ``surv``, ``fell`` (force [N]
    -> bool): (Boundary or None when a force it needs is not recorded, the forces it simulated)."""
    used: set[float] = set()
    view: dict[float, bool] = {}
    while True:
        forces, b = plan_cell(search, view, hint, window, below)
        if b is not None:
            break
        if any(f not in surv for f in forces):
            return None, used
        for f in forces:
            view[f] = surv[f]
            used.add(f)
    fv = {f: fell[f] for f in used}
    while True:
        forces, b2 = plan_no_fall(search, fv, b)
        if b2 is not None:
            return b2, used
        if any(f not in fell for f in forces):
            return None, used
        for f in forces:
            fv[f] = fell[f]
            used.add(f)


def _answer(b: Boundary) -> tuple:
    return (b.lo, b.hi, tuple(b.islands), b.no_fall_lo, b.no_fall_hi)


def bracket_replay(records: list[dict], windows: tuple[int, ...], belows: tuple[int, ...], search: Search) -> dict:
    """The bracketed search on a full search's records, for each island window and bracket check (the
    module's ``replay``). Rows (mode, direction, duration) are searched phase by phase as the driver does:
    the first phase in full, every other from its lower neighbour's coarse edge (``coarse_edge`` on the
    recorded coarse forces, which a full search holds all of)."""
    surv: dict[tuple, dict[float, bool]] = {}
    fell: dict[tuple, dict[float, bool]] = {}
    for r in records:
        k = (r["mode"], r["direction"], float(r["duration"]), float(r["phase"]))
        surv.setdefault(k, {})[float(r["force"])] = bool(r["survived"])
        fell.setdefault(k, {})[float(r["force"])] = r.get("fall_time") is not None
    rows: dict[tuple, list[float]] = {}
    for k in surv:
        rows.setdefault(k[:3], []).append(k[3])
    full = {}
    for k in surv:
        s = search.for_duration(k[2])
        b, used = _replay_cell(s, surv[k], fell[k], None, 0, 1)
        if b is None:
            raise ValueError(f"the records of cell {k} are not a full search's: force(s) missing")
        full[k] = (b, len(used))
    out = {"cells": len(full), "simulations_full": sum(n for _, n in full.values()), "runs": []}
    for window in windows:
        for below in belows:
            sims, differ = 0, []
            for row, phases in sorted(rows.items()):
                hint = None
                for ph in sorted(phases):
                    k = row + (ph,)
                    s = search.for_duration(row[2])
                    b, used = _replay_cell(s, surv[k], fell[k], hint, window, below)
                    sims += len(used)
                    if b is None or _answer(b) != _answer(full[k][0]):
                        differ.append({"cell": list(k), "full": list(_answer(full[k][0])),
                                       "bracketed": list(_answer(b)) if b is not None else "needs a force the full search did not run"})
                    coarse = {f: v for f, v in surv[k].items() if f in s.coarse_forces()}
                    hint = coarse_edge(s, coarse, hint, window, below)
            out["runs"].append({"island_window": window, "bracket_check_below": below, "simulations": sims,
                                "cells_differing": len(differ), "differing": differ})
    return out


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
    o = sub.add_parser("orbit")
    o.add_argument("summary", type=Path, help="a capability map's --json (its cells' boundaries choose the forces)")
    o.add_argument("--set", dest="overrides", action="append", default=None, metavar="KEY=VALUE",
                   help="settings overrides (default: plant=mujoco)")
    o.add_argument("--profile", default=None)
    o.add_argument("--modes", default="both,tau,p,none")
    o.add_argument("--durations", type=float, nargs="+", default=[0.025])
    o.add_argument("--phases", type=float, nargs="+", default=None)
    o.add_argument("--fractions", type=float, nargs="+", default=[0.5, 0.9, 1.0])
    o.add_argument("--walk-steps", type=int, default=20)
    o.add_argument("--settled", type=int, default=5, help="last impacts of each survivor counted as settled")
    o.add_argument("--workers", type=int, default=2)
    o.add_argument("--json", type=Path, default=None)
    r = sub.add_parser("replay")
    r.add_argument("store", type=Path, help="a capability map's record store (JSON Lines)")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="the settings the map ran with (its --set)")
    r.add_argument("--profile", default=None)
    r.add_argument("--modes", nargs="+", default=None)
    r.add_argument("--json", type=Path, default=None)
    b = sub.add_parser("bracket-replay")
    b.add_argument("store", type=Path, help="the records of a full search (--search full)")
    b.add_argument("--windows", type=int, nargs="+", default=[2])
    b.add_argument("--below", type=int, nargs="+", default=[1, 2])
    b.add_argument("--coarse", type=float, default=DEFAULT_COARSE)
    b.add_argument("--max", type=float, default=DEFAULT_MAX)
    b.add_argument("--resolution", type=float, default=DEFAULT_RESOLUTION)
    b.add_argument("--max-impulse", type=float, default=DEFAULT_MAX_IMPULSE)
    b.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    plant = "mujoco" if args.cmd == "orbit" and args.overrides is None else None     # orbit's default settings
    provenance.track(args.json, args=args, argv=argv, plant=plant)   # record of each file written (results/README.md)
    if args.cmd == "compare":
        fast, full = (json.loads(p.read_text()) for p in (args.fast, args.full))
        recs = [RecordStore(p).load() for p in args.stores] if args.stores else [None, None]
        out = compare(fast, full, *recs)
        brief = {k: v for k, v in out.items() if k != "details"}
        print(json.dumps(brief, indent=1))
        for k, v in out["details"].items():
            for d in v[:10]:
                print(f"{k}: {d}")
    elif args.cmd == "bracket-replay":
        out = bracket_replay(RecordStore(args.store).load(), tuple(args.windows), tuple(args.below),
                     Search(args.coarse, args.max, args.resolution, args.max_impulse))
        for run in out["runs"]:
            print(f"island_window {run['island_window']}, bracket_check_below {run['bracket_check_below']}: "
                  f"{run['simulations']} simulations (full search {out['simulations_full']}), "
                  f"{run['cells_differing']} of {out['cells']} cells differ"
                  + "".join(f"\n  {d['cell']}: full {d['full']}, bracketed {d['bracketed']}" for d in run["differing"]))
    elif args.cmd == "orbit":
        settings = run_settings(args.profile, args.overrides if args.overrides is not None else ["plant=mujoco"],
                                full_trials=True)
        out = orbit(json.loads(args.summary.read_text()), settings, tuple(args.modes.split(",")),
                    tuple(args.durations), tuple(args.fractions),
                    tuple(args.phases) if args.phases is not None else None, args.walk_steps, args.workers,
                    args.settled)
        print(json.dumps({k: v for k, v in out.items() if k not in ("trials", "logs")}, indent=1))
    elif args.cmd == "replay":
        out = replay(RecordStore(args.store).load(), run_settings(args.profile, args.overrides),
                     tuple(args.modes) if args.modes else None)
        print(json.dumps({k: (len(v) if k in ("history_dependent", "changed") else v) for k, v in out.items()},
                         indent=1))
        for c in out["changed"][:10]:
            print(f"changed: {c['key']}: " + ", ".join(f"{k} {v['old']!r} -> {v['new']!r}" for k, v in c["fields"].items()))
    else:
        out = margins(RecordStore(args.store).load(), args.sample, args.seed, args.workers)
        print(json.dumps({k: v for k, v in out.items() if k != "trials"}, indent=1))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1, allow_nan=False, default=float) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
