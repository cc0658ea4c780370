"""The largest survivable push: a coarse scan of forces, then a bisection of the lowest failing edge, for
one push window (start, duration, height, direction) and one or more modes; the table of the results.

Survival need not be monotone in the force, so the search scans coarsely first, bisects the lowest
failing edge, and reports every survivable coarse force above that edge ("islands"). Two edges are
searched at the same resolution: the survival boundary (the survival rule, :mod:`.survival`) and the
no-fall edge (no fall, settled or not).
"""
from __future__ import annotations

import math
import sys

from biped_controller.closed_loop.executor import CountingBar, ProgressBar, make_executor
from biped_controller.studies.trial import trials
from biped_controller.studies.trial.scan import (analyse_coarse, coarse_forces, no_fall_undefined,  # noqa: F401
                                                outcome)  # (the search API)
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.runs import DEFAULT_DURATION, DEFAULT_START, paper_push
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings, check_settings, differences
from biped_controller.studies.trial.survival import survival_rule

#: The paper's largest survivable push [N] (250 N-class push on the back during 0.025 s at mid-step);
#: mode "none" (classical computed torque) has no number in the paper.
PAPER_MAX_PUSH: dict[str, float | None] = {"both": 650.0, "tau": 455.0, "p": 320.0, "none": None}


def _trial(args: tuple) -> dict:
    push, mode, settings = args
    settings.activate()
    return trials.survives(push, mode, settings)


def bisect_edge(mode: str, lo: float, hi: float, resolution: float, *, duration: float = DEFAULT_DURATION,
                start: float = DEFAULT_START, height: float | None = None, progress=None,
                sign: float = 1.0, settings: RunSettings = DEFAULT_SETTINGS, edge: str = "survival",
                known: dict[float, dict] | None = None) -> tuple[float, float, list[dict]]:
    """Bisect the force magnitudes [lo (passes), hi (fails)] [N] of ``edge`` (:func:`outcome`) down to
    ``resolution`` [N] for pushes over [start, start + duration) [s] at ``height`` [m] (None: the
    simulator's), applied with ``sign`` (+1 forward). ``known``: trials already simulated, by force
    magnitude (reused, and the new ones added). Returns (lo, hi, the trials simulated here)."""
    done = []
    known = {} if known is None else known
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        r = known.get(mid)
        if r is None:
            push = paper_push(sign * mid, start=start, duration=duration, height=height)
            r = known[mid] = dict(trials.survives(push, mode, settings), force=mid)
            done.append(r)
            if progress:
                progress()
        if outcome(r, edge):
            lo = mid
        else:
            hi = mid
    return lo, hi, done


def bisect_both(mode: str, coarse_trials: list[dict], resolution: float, *, duration: float = DEFAULT_DURATION,
                start: float = DEFAULT_START, height: float | None = None, progress=None, sign: float = 1.0,
                settings: RunSettings = DEFAULT_SETTINGS) -> dict:
    """Both edges of one mode from its coarse trials (force magnitudes), each bisected to ``resolution``
    [N]: the survival boundary and the no-fall edge (the bisections share their trials at equal forces).
    Returns {edge: (lo, hi or None, islands)} and "trials": every bisection trial."""
    known = {r["force"]: r for r in coarse_trials}
    out: dict = {"trials": []}
    for edge in ("survival", "no_fall"):
        lo, hi, isl = analyse_coarse(coarse_trials, edge)
        if hi is not None:
            lo, hi, tr = bisect_edge(mode, lo, hi, resolution, duration=duration, start=start, height=height,
                                     progress=progress, sign=sign, settings=settings, edge=edge, known=known)
            out["trials"] += tr
        out[edge] = (lo, hi, isl)
    return out


def _bisect_task(args: tuple) -> tuple[str, dict]:
    mode, coarse_trials, resolution, duration, start, height, sign, settings = args
    settings.activate()
    return mode, bisect_both(mode, coarse_trials, resolution, duration=duration, start=start, height=height,
                             sign=sign, settings=settings)


def _result_for(mode: str, coarse_trials: list[dict], edges: dict, fmax: float, resolution: float,
                coarse: float) -> dict:
    trials = sorted(coarse_trials + edges["trials"], key=lambda r: r["force"])
    lo, hi, islands = edges["survival"]
    nf_lo, nf_hi, nf_isl = edges["no_fall"]
    first_fail = next((r for r in trials if r["force"] == hi), None) if hi is not None else None
    first_fall = next((r for r in trials if r["force"] == nf_hi), None) if nf_hi is not None else None
    undefined = no_fall_undefined(first_fall)
    if undefined is not None:               # the lowest force that fell or faulted faulted: no edge is known
        nf_lo, nf_hi, nf_isl, first_fall = None, None, [], None
    return {
        "mode": mode, "max_force": lo, "first_failure": hi, "resolution": resolution, "coarse_step": coarse,
        "scan_max": fmax, "islands": islands, "paper": PAPER_MAX_PUSH.get(mode),
        "failure_cause": first_fail["reason"] if first_fail else None,
        "no_fall_edge": nf_lo, "first_fall": nf_hi, "no_fall_islands": nf_isl,
        "fall_cause": first_fall["reason"] if first_fall else None,
        **({} if undefined is None else {"no_fall_undefined": undefined}),
        "trials": trials,
    }


def max_push_modes(modes: tuple[str, ...], resolution: float = 5.0, fmax: float = 2000.0, coarse: float = 50.0, *,
                   duration: float = DEFAULT_DURATION, start: float = DEFAULT_START, height: float | None = None,
                   workers: int = 1, progress: bool = True, sign: float = 1.0,
                   settings: RunSettings = DEFAULT_SETTINGS) -> dict[str, dict]:
    """Largest survivable push for each mode: coarse scan (all modes' trials together, over the studies'
    executor with ``workers`` processes), then a bisection of each mode's lowest failing edge (modes in
    parallel). Forces [N], push window [start, start + duration) [s] at ``height`` [m] above the hip (None:
    the simulator's ``push_height``), ``sign`` +1 forward. Every result carries ``settings`` (the profile
    and the settings that differ from the configuration files: ``settings.differences``) and the effective
    ``push_height`` [m]."""
    check_settings(settings)   # a bad override fails here, before any worker starts
    forces = coarse_forces(fmax, coarse)
    tasks = [(paper_push(sign * f, start=start, duration=duration, height=height), m, settings)
             for m in modes for f in forces]
    # the most the search can need: every coarse force, then two bisections (survival boundary, no-fall edge)
    # per mode, each of one coarse step halved down to the resolution (trials shared at equal forces)
    bis_max = 2 * len(modes) * max(0, math.ceil(math.log2(max(coarse / resolution, 1.0))))
    bar = CountingBar(len(tasks) + bis_max, ProgressBar(sys.stderr if progress else None,
                                                        label="max-push " + ",".join(modes)),
                      f"{len(tasks)} coarse + {bis_max} bisection")
    ex = make_executor(workers, initializer=context)
    try:
        coarse_res = ex.map(_trial, [(t,) for t in tasks], on_result=lambda r: bar())
        per_mode = {m: [dict(r, force=abs(r["force"])) for r in coarse_res if r["mode"] == m] for m in modes}
        bis_tasks = [(m, per_mode[m], resolution, duration, start, height, sign, settings) for m in modes]
        if workers > 1 and len(bis_tasks) > 1:
            edges = dict(ex.map(_bisect_task, [(t,) for t in bis_tasks], on_result=lambda r: bar(len(r[1]["trials"]))))
        else:
            edges = {m: bisect_both(m, per_mode[m], resolution, duration=duration, start=start, height=height,
                                    progress=bar, sign=sign, settings=settings) for m in modes}
    finally:
        ex.close()
    bar.close()
    rule = survival_rule()
    results = {}
    for m in modes:
        results[m] = _result_for(m, per_mode[m], edges[m], fmax, resolution, coarse)
        results[m]["direction"] = "forward" if sign > 0 else "backward"
        band = trials.band(m, paper_push(0.0, start=start, duration=duration, height=height), settings)
        results[m].update(duration=duration, start=start, height=height, settings=differences(settings),
                          push_height=settings.sim_config().push_height if height is None else height,
                          band=band.as_dict(), survival=rule.text(band))
    return results


def max_push(mode: str, resolution: float = 5.0, fmax: float = 2000.0, coarse: float = 50.0, **kw) -> dict:
    """:func:`max_push_modes` for one mode (keywords as there)."""
    return max_push_modes((mode,), resolution, fmax, coarse, **kw)[mode]


def ordering_finding(results: dict[str, dict]) -> str:
    """Whether the measured max pushes keep the paper's ordering both > tau > p > none, in words."""
    order = ("both", "tau", "p", "none")
    vals = [results[m]["max_force"] for m in order if m in results]
    if len(vals) < len(order):
        return "ordering: not all four modes were run"
    holds = all(a > b for a, b in zip(vals[:-1], vals[1:]))
    txt = " > ".join(f"{m} ({results[m]['max_force']:g} N)" for m in order)
    if holds:
        return f"finding: the paper's ordering both > tau > p > none HOLDS: {txt}"
    ranked = sorted(order, key=lambda m: -results[m]["max_force"])
    return ("finding: the paper's ordering both > tau > p > none does NOT hold; measured ranking "
            + " >= ".join(f"{m} ({results[m]['max_force']:g} N)" for m in ranked))


def print_max_push(results: dict[str, dict]) -> None:
    """The table of :func:`max_push_modes`'s results: per mode the survival boundary and the no-fall edge
    (both bisected to the same resolution), with the push, the search and the survival rule's band."""
    print(f"{'mode':<6} {'max force [N]':>13} {'first fail [N]':>14} {'no-fall edge [N]':>16} {'first fall [N]':>14} "
          f"{'paper [N]':>9} {'islands (coarse) [N]':<22} cause of the first failure")
    for m, r in results.items():
        paper = "-" if r["paper"] is None else f"{r['paper']:g}"
        ff = "none" if r["first_failure"] is None else f"{r['first_failure']:g}"
        fl = "none" if r["first_fall"] is None else f"{r['first_fall']:g}"
        isl = ", ".join(f"{x:g}" for x in r["islands"]) or "-"
        nf = "undefined" if r["no_fall_edge"] is None else f"{r['no_fall_edge']:g}"
        fl = "-" if r["no_fall_edge"] is None else fl
        print(f"{m:<6} {r['max_force']:13g} {ff:>14} {nf:>16} {fl:>14} {paper:>9} {isl:<22} "
              f"{r['failure_cause'] or '-'}")
    r0 = next(iter(results.values()))
    # the bracket each bisection ended with (coarse step halved until it is at most the resolution asked)
    brackets = sorted({r["first_failure"] - r["max_force"] for r in results.values() if r["first_failure"] is not None})
    got = " / ".join(f"{b:g}" for b in brackets) or "none"
    print(f"(push {r0['direction']} for {r0['duration']:g} s from t = {r0['start']:g} s at {r0['push_height']:g} m "
          f"above the hip; coarse step {r0['coarse_step']:g} N up to {r0['scan_max']:g} N, both edges bisected to a "
          f"bracket of at most {r0['resolution']:g} N: {got} N)")
    for m, r in results.items():
        if r.get("no_fall_undefined"):
            print(f"no-fall edge, {m}: {r['no_fall_undefined']}")
    for m, r in results.items():
        print(f"survival, {m}: {r['survival']}")
