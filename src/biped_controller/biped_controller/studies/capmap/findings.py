"""What a finished map says: each boundary with its conversions, the findings over the boundaries, and
the summary JSON."""
from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path
from typing import Sequence

from biped_sim.plant.push import Push

from biped_controller.core.control.config import MODES
from biped_controller.studies.trial import stop, survival, trials
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.runs import DEFAULT_DURATION, trial_steps
from biped_controller.studies.trial.scan import no_fall_undefined
from biped_controller.studies.trial.search import PAPER_MAX_PUSH
from biped_controller.studies.trial.settings import differences
from biped_controller.studies.capmap.driver import MapRun
from biped_controller.studies.capmap.metrics import body_weight_fraction, com_velocity_change, impulse
from biped_controller.studies.capmap.search import island_ranges
from biped_controller.studies.capmap.spec import Cell, MapSpec, onset_time


def cell_summary(run: MapRun, cell: Cell) -> dict:
    """One boundary, JSON-ready, with its conversions, failure cause and islands, and the no-fall edge
    (``no_fall_edge``, ``first_fall``: None censored, and its cause) at the same resolution; where the
    lowest force that fell or faulted faulted (a plug-in controller's fault), the no-fall edge is undefined:
    ``no_fall_edge`` and ``first_fall`` None and ``no_fall_undefined`` says why."""
    ctx = context()
    M, g = ctx.desc.total_mass, ctx.desc.gravity
    b = run.boundaries[cell]
    d = cell.duration
    first = run.records[cell].get(b.hi) if b.hi is not None else None
    first_fall = run.records[cell].get(b.no_fall_hi) if b.no_fall_hi is not None else None
    return {
        "mode": cell.mode, "direction": cell.direction, "phase": cell.phase,
        "start": onset_time(cell.phase, ctx.family.T), "duration": d,
        "force": b.lo, "first_failure": b.hi, "censored": b.hi is None,
        "scan_max": run.spec.search.for_duration(d).fmax,
        "impulse": impulse(b.lo, d), "delta_v_com": com_velocity_change(b.lo, d, M),
        "body_weight_fraction": body_weight_fraction(b.lo, M, g),
        "cause": first["cause"] if first else None, "reason": first["reason"] if first else None,
        "fall_time": first["fall_time"] if first else None,
        "islands": list(b.islands), "islands_complete": b.full,
        "island_ranges": island_ranges(b.islands, run.spec.search.coarse),
        "island_impulses": [impulse(f, d) for f in b.islands],
        "no_fall_edge": b.no_fall_lo, "first_fall": b.no_fall_hi,
        "fall_cause": first_fall["cause"] if first_fall else None,
        **({} if b.no_fall_fault is None
           else {"no_fall_undefined": no_fall_undefined(run.records[cell][b.no_fall_fault])}),
        "simulations": len(run.records[cell]),
    }


def _fmt_phases(phases: Sequence[float]) -> str:
    return ", ".join(f"{p:g}" for p in phases) if phases else "none"


def no_fall_agreement(bs: Sequence[dict], resolution: float) -> dict:
    """Over cells ``bs``: the mean no-fall edge and the cells whose survival boundary is within one
    ``resolution`` [N] of the no-fall edge (a censored no-fall edge counts when the boundary is censored
    too), with the phases of the others; the cells whose no-fall edge is undefined (a controller fault
    before any fall: ``cell_summary``'s ``no_fall_undefined``) are left out of both and listed in
    ``phases_no_fall_undefined``, present only when there are some."""
    undefined = [b["phase"] for b in bs if b.get("no_fall_undefined")]
    extra = {"phases_no_fall_undefined": undefined} if undefined else {}
    nf = [b for b in bs if b.get("no_fall_edge") is not None]
    if not nf:
        return extra
    def close(b):
        if b["first_fall"] is None:
            return b["censored"]
        return b["no_fall_edge"] - b["force"] <= resolution
    return {"mean_no_fall_edge": sum(b["no_fall_edge"] for b in nf) / len(nf),
            "cells_with_no_fall_edge": len(nf),
            "cells_boundary_within_resolution_of_no_fall": sum(1 for b in nf if close(b)),
            "phases_boundary_below_no_fall": [b["phase"] for b in nf if not close(b)], **extra}


def findings(boundaries: Sequence[dict], resolution: float) -> dict:
    """What the map shows, computed from the boundaries: per (mode, direction, duration) the weakest and
    strongest phases; per (direction, duration) where p beats tau and the reverse (a difference larger
    than the bisection resolution); per (mode, duration) backward vs forward; islands and causes per
    mode. Also the cross-check cell (phase 0.5, forward, 0.025 s) against the paper's numbers."""
    def key(b):
        return (b["mode"], b["direction"], b["duration"])
    groups: dict[tuple, list[dict]] = {}
    for b in boundaries:
        groups.setdefault(key(b), []).append(b)
    out: dict = {"weakest": [], "p_vs_tau": [], "backward_vs_forward": [], "islands": {}, "causes": {},
                 "paper_cell": []}
    for (m, dr, du), bs in sorted(groups.items()):
        bs = sorted(bs, key=lambda b: b["phase"])
        fs = [b["force"] for b in bs]
        lo, hi = min(fs), max(fs)
        out["weakest"].append({
            "mode": m, "direction": dr, "duration": du, "min_force": lo, "mean_force": sum(fs) / len(fs),
            "max_force": hi, "weakest_phases": [b["phase"] for b in bs if b["force"] == lo],
            "strongest_phases": [b["phase"] for b in bs if b["force"] == hi],
            "censored_phases": [b["phase"] for b in bs if b["censored"]],
            "min_impulse": impulse(lo, du), "min_delta_v_com": bs[fs.index(lo)]["delta_v_com"],
            **no_fall_agreement(bs, resolution)})
    dirs = sorted({b["direction"] for b in boundaries})
    durs = sorted({b["duration"] for b in boundaries})
    modes = [m for m in MODES if any(b["mode"] == m for b in boundaries)]
    modes += sorted({b["mode"] for b in boundaries} - set(MODES))     # plug-in controllers, after the modes
    if "p" in modes and "tau" in modes:
        for dr in dirs:
            for du in durs:
                p = {b["phase"]: b["force"] for b in groups.get(("p", dr, du), [])}
                t = {b["phase"]: b["force"] for b in groups.get(("tau", dr, du), [])}
                common = sorted(set(p) & set(t))
                out["p_vs_tau"].append({
                    "direction": dr, "duration": du,
                    "p_better": [ph for ph in common if p[ph] - t[ph] > resolution],
                    "tau_better": [ph for ph in common if t[ph] - p[ph] > resolution],
                    "tied": [ph for ph in common if abs(p[ph] - t[ph]) <= resolution],
                    "mean_p": sum(p[x] for x in common) / len(common) if common else None,
                    "mean_tau": sum(t[x] for x in common) / len(common) if common else None})
    if set(dirs) == {"forward", "backward"}:
        for m in modes:
            for du in durs:
                f = {b["phase"]: b["force"] for b in groups.get((m, "forward", du), [])}
                bw = {b["phase"]: b["force"] for b in groups.get((m, "backward", du), [])}
                common = sorted(set(f) & set(bw))
                if not common:
                    continue
                mf = sum(f[x] for x in common) / len(common)
                mb = sum(bw[x] for x in common) / len(common)
                out["backward_vs_forward"].append({
                    "mode": m, "duration": du, "mean_forward": mf, "mean_backward": mb,
                    "ratio_backward_forward": mb / mf if mf > 0 else None,
                    "backward_weaker_phases": [x for x in common if f[x] - bw[x] > resolution],
                    "backward_stronger_phases": [x for x in common if bw[x] - f[x] > resolution]})
    for m in modes:
        mine = [b for b in boundaries if b["mode"] == m]
        out["islands"][m] = [{"direction": b["direction"], "phase": b["phase"], "duration": b["duration"],
                              "edge": b["first_failure"], "islands": b["island_ranges"]}
                             for b in mine if b["islands"]]
        causes: dict[str, int] = {}
        for b in mine:
            k = b["cause"] or "censored"
            causes[k] = causes.get(k, 0) + 1
        out["causes"][m] = causes
    for b in boundaries:
        if b["phase"] == 0.5 and b["direction"] == "forward" and b["duration"] == DEFAULT_DURATION:
            out["paper_cell"].append({"mode": b["mode"], "force": b["force"],
                                      "paper": PAPER_MAX_PUSH.get(b["mode"])})
    return out


def findings_text(f: dict) -> list[str]:
    lines = ["weakest / strongest onset phases (boundary force [N]):"]
    for w in f["weakest"]:
        cens = f", censored (>= max) at {_fmt_phases(w['censored_phases'])}" if w["censored_phases"] else ""
        lines.append(f"  {w['mode']:<4} {w['direction']:<8} {w['duration']:g} s: min {w['min_force']:g} N at phase "
                     f"{_fmt_phases(w['weakest_phases'])} ({w['min_impulse']:.3g} N s, dv_com {w['min_delta_v_com']:.3g} m/s), "
                     f"mean {w['mean_force']:.1f}, max {w['max_force']:g} at {_fmt_phases(w['strongest_phases'])}{cens}")
        if "mean_no_fall_edge" in w:
            lines.append(f"       no-fall edge: mean {w['mean_no_fall_edge']:.1f} N; boundary within one resolution step "
                         f"of it in {w['cells_boundary_within_resolution_of_no_fall']} of {w['cells_with_no_fall_edge']} "
                         f"cells (below it at {_fmt_phases(w['phases_boundary_below_no_fall'])})")
        if w.get("phases_no_fall_undefined"):
            lines.append(f"       no-fall edge: undefined at phase {_fmt_phases(w['phases_no_fall_undefined'])} (the "
                         f"controller faulted before any fall: a faulted trial is neither a survival nor a fall)")
    if f["p_vs_tau"]:
        lines.append("p vs tau (difference > resolution):")
        for x in f["p_vs_tau"]:
            lines.append(f"  {x['direction']:<8} {x['duration']:g} s: p beats tau at {_fmt_phases(x['p_better'])}; "
                         f"tau beats p at {_fmt_phases(x['tau_better'])}; tied at {_fmt_phases(x['tied'])} "
                         + ("" if x["mean_p"] is None else f"(means p {x['mean_p']:.1f} N, tau {x['mean_tau']:.1f} N)"))
    if f["backward_vs_forward"]:
        lines.append("backward vs forward (mean boundary over the phases):")
        for x in f["backward_vs_forward"]:
            r = "-" if x["ratio_backward_forward"] is None else f"{x['ratio_backward_forward']:.2f}"
            lines.append(f"  {x['mode']:<4} {x['duration']:g} s: forward {x['mean_forward']:.1f} N, backward "
                         f"{x['mean_backward']:.1f} N (ratio {r}); backward weaker at "
                         f"{_fmt_phases(x['backward_weaker_phases'])}, stronger at {_fmt_phases(x['backward_stronger_phases'])}")
    lines.append("islands (survivable coarse forces above the lowest failing edge):")
    for m, isl in f["islands"].items():
        lines.append(f"  {m:<4} {len(isl)} cells" + ("" if not isl else ": " + "; ".join(
            f"{x['direction']} {x['duration']:g} s phase {x['phase']:g}: edge {x['edge']:g} N, islands "
            + ", ".join(f"{a:g}-{b:g}" if a != b else f"{a:g}" for a, b in x["islands"]) for x in isl[:6])
            + (" ..." if len(isl) > 6 else "")))
    lines.append("causes of the first failure: " + "; ".join(
        f"{m}: " + ", ".join(f"{k} {v}" for k, v in sorted(c.items())) for m, c in f["causes"].items()))
    for x in f["paper_cell"]:
        paper = "-" if x["paper"] is None else f"{x['paper']:g} N"
        lines.append(f"cross-check (phase 0.5, forward, 0.025 s = experiment's max-push cell): {x['mode']} "
                     f"{x['force']:g} N (paper {paper})")
    return lines


def parameter_range(run: MapRun) -> dict:
    """The map's trials against the parameters' valid range (``trials.out_of_range``: p in the family's
    [p_min, p_max] [m], tau' in [tau_dot_min, tau_dot_max]): the range, the largest |p - p_d| [m] and the extremes of tau' [-]
    over the recorded trials, the trials that leave the range (key and what leaves) and how many records
    carry no excursion (stored before it was recorded)."""
    fam, cc = context().family, run.spec.settings.ctrl_config(MODES[0])    # settings of every mode
    tdm, tdx = cc.tau_dot_min, cc.tau_dot_max
    recs = [r for by_force in run.records.values() for r in by_force.values()]
    known = [r for r in recs if all(r.get(k) is not None for k in ("max_abs_p_minus_pd", "min_tau_dot", "max_tau_dot"))]
    out = []
    for r in recs:
        why = trials.out_of_range(r, fam.p_min, fam.p_max, tdm, tdx)
        if why and r in known:
            out.append({k: r[k] for k in ("mode", "direction", "phase", "duration", "force")} | {"why": why})
    return {"p_min": fam.p_min, "p_max": fam.p_max, "p_d": fam.p_d, "tau_dot_min": tdm, "tau_dot_max": tdx,
            "max_abs_p_minus_pd": max((r["max_abs_p_minus_pd"] for r in known), default=None),
            "min_tau_dot": min((r["min_tau_dot"] for r in known), default=None),
            "max_tau_dot": max((r["max_tau_dot"] for r in known), default=None),
            "trials_out_of_range": out, "trials_not_recorded": len(recs) - len(known)}


def survival_bands(spec: MapSpec) -> dict:
    """{mode: {trial impacts: the survival rule's band}} of the map's cells (``trial.survival``)."""
    T = context().family.T
    steps = sorted({trial_steps(Push(onset_time(c.phase, T), c.duration, 0.0)) for c in spec.cells()})
    return {m: {str(n): trials.walk_band(m, spec.settings, n).as_dict() for n in steps} for m in spec.modes}


def partial_rules(spec: MapSpec) -> dict:
    """{mode: the survival rule in words with its band} for the modes whose rule is not the definition's
    (``rule_text()``): a controller that does not report both p and tau' (``Band.checks_p``,
    ``Band.checks_tau_dot``) is not held to the return to the gait it does not report. Empty for the
    built-in modes (they report both)."""
    T = context().family.T
    n = min(trial_steps(Push(onset_time(c.phase, T), c.duration, 0.0)) for c in spec.cells())
    out = {}
    for m in spec.modes:
        band = trials.walk_band(m, spec.settings, n)
        if not (band.checks_p and band.checks_tau_dot):
            out[m] = survival.rule_text(band)
    return out


def summary(run: MapRun, figures: Sequence[Path] = ()) -> dict:
    """The summary JSON: the map, the robot's mass and weight, what the run did, every boundary, the
    findings and the figures. ``map.survival`` is the rule's definition; ``map.survival_by_mode``, present
    only when some mode's rule differs from it, gives that mode's rule (:func:`partial_rules`)."""
    ctx = context()
    M, g = ctx.desc.total_mass, ctx.desc.gravity
    s = run.spec
    bs = [cell_summary(run, c) for c in s.cells() if c in run.boundaries]
    total = sum(len(v) for v in run.records.values())
    return {
        "map": {"modes": list(s.modes), "directions": list(s.directions), "phases": list(s.phases),
                "durations": list(s.durations), "coarse": s.search.coarse, "max": s.search.fmax,
                "max_impulse": s.search.max_impulse if math.isfinite(s.search.max_impulse) else None,
                "scan_max_per_duration": {f"{d:g}": s.search.for_duration(d).fmax for d in s.durations},
                "resolution": s.search.resolution, "height": s.height,
                "search": "neighbours" if s.neighbours else "full", "island_window": s.island_window,
                "bracket_check_below": s.bracket_check_below,
                "early_stop": (not s.settings.full_trials) and stop.enabled(s.settings),
                "onset": f"start = phase * T of the first step, T = {ctx.family.T:g} s (walk starts at t = 0)",
                "direction_sign": "forward = + force (on the back), backward = - force",
                "survival": survival.rule_text(),
                **({"survival_by_mode": rules} if (rules := partial_rules(s)) else {}),
                "survival_bands": survival_bands(s)},
        "fingerprint": run.fingerprint,
        "settings": differences(s.settings),
        "robot": {"mass": M, "gravity": g, "weight": M * g},
        "units": {"force": "N", "impulse": "N s", "delta_v_com": "m/s", "body_weight_fraction": "-",
                  "phase": "fraction of the step", "start": "s", "duration": "s"},
        "run": {"executor": run.executor, "wall_time": run.wall_time, "simulations_run": run.simulated,
                "simulations_resumed": run.resumed, "simulations_in_map": total,
                "store_records_ignored": run.ignored,
                "settings_changed_during_run": run.fingerprint_at_end != run.fingerprint,
                "rate": run.simulated / run.wall_time if run.wall_time > 0 else None},
        "incomplete_cells": [asdict(c) for c in run.missing],
        "boundaries": bs,
        "findings": findings(bs, s.search.resolution),
        "parameter_range": parameter_range(run),
        "figures": [str(p) for p in figures],
    }
