"""The largest survivable push: a coarse scan of forces, then a bisection of the lowest failing edge, for
one push window (start, duration, height, direction) and one or more modes; the table of the results.

Survival need not be monotone in the force, so the search scans coarsely first, bisects the lowest
failing edge, and reports every survivable coarse force above that edge ("islands").
"""
from __future__ import annotations

import math
import sys

from biped_controller.studies.executor import CountingBar, ProgressBar, make_executor
from biped_controller.studies.trial import trials
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.runs import DEFAULT_DURATION, DEFAULT_START, paper_push
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings, check_settings, differences
from biped_controller.studies.trial.survival import noisy_sensing, rule_text

#: The paper's largest survivable push [N] (250 N-class push on the back during 0.025 s at mid-step);
#: mode "none" (classical computed torque) has no number in the paper.
PAPER_MAX_PUSH: dict[str, float | None] = {"both": 650.0, "tau": 455.0, "p": 320.0, "none": None}


def _trial(args: tuple) -> dict:
    push, mode, settings = args
    return trials.survives(push, mode, settings)


def coarse_forces(fmax: float, coarse: float) -> list[float]:
    """The coarse scan's forces [N]: coarse, 2 coarse, ... <= fmax."""
    n = int(math.floor(fmax / coarse + 1e-9))
    return [coarse * k for k in range(1, n + 1)]

def analyse_coarse(trials: list[dict]) -> tuple[float, float | None, list[float]]:
    """(last survivable force below the first failure (0 if the first fails), first failing force or None,
    survivable coarse forces above the first failure)."""
    trials = sorted(trials, key=lambda r: r["force"])
    lo, hi = 0.0, None
    for r in trials:
        if r["survived"]:
            lo = r["force"]
        else:
            hi = r["force"]
            break
    islands = [r["force"] for r in trials if hi is not None and r["force"] > hi and r["survived"]]
    return lo, hi, islands


def bisect_edge(mode: str, lo: float, hi: float, resolution: float, *, duration: float = DEFAULT_DURATION,
                start: float = DEFAULT_START, height: float | None = None, progress=None,
                sign: float = 1.0, settings: RunSettings = DEFAULT_SETTINGS) -> tuple[float, float, list[dict]]:
    """Bisect the force magnitudes [lo (survives), hi (fails)] [N] down to ``resolution`` [N] for pushes over
    [start, start + duration) [s] at ``height`` [m] (None: the simulator's), applied with ``sign`` (+1
    forward). Returns (lo, hi, trials)."""
    done = []
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        push = paper_push(sign * mid, start=start, duration=duration, height=height)
        r = dict(trials.survives(push, mode, settings), force=mid)
        done.append(r)
        if progress:
            progress()
        if r["survived"]:
            lo = mid
        else:
            hi = mid
    return lo, hi, done


def _bisect_task(args: tuple) -> tuple[str, float, float, list[dict]]:
    mode, lo, hi, resolution, duration, start, height, sign, settings = args
    a, b, tr = bisect_edge(mode, lo, hi, resolution, duration=duration, start=start, height=height, sign=sign,
                           settings=settings)
    return mode, a, b, tr


def _result_for(mode: str, coarse_trials: list[dict], lo: float, hi: float | None, bis: list[dict],
                islands: list[float], fmax: float, resolution: float, coarse: float) -> dict:
    trials = sorted(coarse_trials + bis, key=lambda r: r["force"])
    first_fail = next((r for r in trials if r["force"] == hi), None) if hi is not None else None
    return {
        "mode": mode, "max_force": lo, "first_failure": hi, "resolution": resolution, "coarse_step": coarse,
        "scan_max": fmax, "islands": islands, "paper": PAPER_MAX_PUSH.get(mode),
        "failure_cause": first_fail["reason"] if first_fail else None,
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
    bis_est = len(modes) * max(0, math.ceil(math.log2(max(coarse / resolution, 1.0))))
    bar = CountingBar(len(tasks) + bis_est, ProgressBar(sys.stderr if progress else None,
                                                        label="max-push " + ",".join(modes)))
    ex = make_executor(workers, initializer=context)
    try:
        coarse_res = ex.map(_trial, [(t,) for t in tasks], on_result=lambda r: bar())
        per_mode = {}
        bis_tasks = []
        for m in modes:
            tr = [dict(r, force=abs(r["force"])) for r in coarse_res if r["mode"] == m]
            lo, hi, isl = analyse_coarse(tr)
            per_mode[m] = (tr, lo, hi, isl)
            if hi is not None:
                bis_tasks.append((m, lo, hi, resolution, duration, start, height, sign, settings))
        bis_out = {}
        if workers > 1 and len(bis_tasks) > 1:
            for mode, lo, hi, tr in ex.map(_bisect_task, [(t,) for t in bis_tasks], on_result=lambda r: bar(len(r[3]))):
                bis_out[mode] = (lo, hi, tr)
        else:
            for (m, lo, hi, res_, d, s0, h, sg, st) in bis_tasks:
                bis_out[m] = bisect_edge(m, lo, hi, res_, duration=d, start=s0, height=h, progress=bar, sign=sg,
                                         settings=st)
    finally:
        ex.close()
    bar.close()
    results = {}
    for m in modes:
        tr, lo, hi, isl = per_mode[m]
        if m in bis_out:
            lo, hi, bt = bis_out[m]
        else:
            bt = []
        results[m] = _result_for(m, tr, lo, hi, bt, isl, fmax, resolution, coarse)
        results[m]["direction"] = "forward" if sign > 0 else "backward"
        results[m].update(duration=duration, start=start, height=height, settings=differences(settings),
                          push_height=settings.sim_config().push_height if height is None else height,
                          noisy_sensing=noisy_sensing(settings),
                          p_reference=trials.p_reference(m, paper_push(0.0, start=start, duration=duration,
                                                                       height=height), settings))
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
    """The table of :func:`max_push_modes`'s results, with the push, the search and the survival rule."""
    print(f"{'mode':<6} {'max force [N]':>13} {'first fail [N]':>14} {'paper [N]':>9} {'islands (coarse) [N]':<24} cause of the first failure")
    for m, r in results.items():
        paper = "-" if r["paper"] is None else f"{r['paper']:g}"
        ff = "none" if r["first_failure"] is None else f"{r['first_failure']:g}"
        isl = ", ".join(f"{x:g}" for x in r["islands"]) or "-"
        print(f"{m:<6} {r['max_force']:13g} {ff:>14} {paper:>9} {isl:<24} {r['failure_cause'] or '-'}")
    r0 = next(iter(results.values()))
    print(f"(push {r0['direction']} for {r0['duration']:g} s from t = {r0['start']:g} s at {r0['push_height']:g} m "
          f"above the hip; coarse step {r0['coarse_step']:g} N up to {r0['scan_max']:g} N, edge bisected to "
          f"{r0['resolution']:g} N; survival = {rule_text(bool(r0.get('noisy_sensing')), r0.get('p_reference'))})")


