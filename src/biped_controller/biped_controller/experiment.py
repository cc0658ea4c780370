"""Experiments of the paper's section 6: undisturbed walking, a push, the largest survivable push.

Pure Python on top of the in-process closed loop (``runner.run``: Simulator + AdaptiveController in
lockstep, no ROS). Run through ``scripts/experiment SUBCOMMAND [options]``:

  walk      --steps 10 [--mode M]              tracking with the controller at the integration rate
                                               and at the control period (zero-order hold)
  push      --force 250 --duration 0.025 [--start 0.2315] [--mode both] [--figures DIR]
                                               one push (+ forward, on the back); figures like the
                                               paper's Figs. 3-7
  max-push  --mode M [--resolution 5] [--max 2000] [--coarse 50]
                                               largest survivable push force
  table     [--workers N]                      max-push for the four modes next to the paper's values

Every subcommand prints a table and, with ``--json FILE``, writes its numbers. Everything is
deterministic (the simulator and the controller are); the functions are importable (tests, benchmarks).

Survival (max-push): no fall until ``SURVIVAL_STEPS`` impacts after the end of the push, and at the end
of the run p within ``P_TOL`` of p_d and tau' within ``TAU_DOT_TOL`` of 1 (the robot is back on its
preferred gait). Survival need not be monotone in the force, so the search scans coarsely first, bisects
the lowest failing edge, and reports every survivable coarse force above that edge ("islands").
"""
from __future__ import annotations

import argparse
import functools
import json
import math
import multiprocessing as mp
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biped_sim.description import RobotDescription, load_description
from biped_sim.simulator import SimConfig, load_sim_config

from .controller import MODES, load_controller_config
from biped_sim.gait_family import GaitFamily
from .qp import STATUS_NAMES
from . import runner
from .runner import PushSpec, RunResult

#: The paper's largest survivable push [N] (250 N-class push on the back during 0.025 s at mid-step);
#: mode "none" (classical computed torque) has no number in the paper.
PAPER_MAX_PUSH: dict[str, float | None] = {"both": 650.0, "tau": 455.0, "p": 320.0, "none": None}
DEFAULT_START = 0.2315          # the middle of the first step (T / 2 = 0.2315 s)
DEFAULT_DURATION = 0.025        # paper: 0.025 s
SURVIVAL_STEPS = 10             # impacts that must follow the end of the push
P_TOL = 1e-3                    # |p - p_d| at the end of a survived run [m]
TAU_DOT_TOL = 1e-3              # |tau' - 1| at the end of a survived run [-]
ZOH_EXPLANATION = (
    "cause of the ZOH error: the torque is computed at each control instant and held for the period "
    "(1 ms) while the reference acceleration q_d'' (and the state) keep changing, an O(dt) acceleration "
    "error every period; and the touchdown falls between two control instants, so the torque held since "
    "the last instant acts up to the impact and the step starts from a slightly different post-impact "
    "state. The integration-rate controller (torque law evaluated at every RK4 stage) has neither error "
    "source except the last fraction of a period before each impact."
)


# ------------------------------------------------------------------------------------------ context
@dataclass(frozen=True)
class Context:
    """Everything a run needs that can be loaded once per process."""

    desc: RobotDescription
    family: GaitFamily
    sim_config: SimConfig


@functools.lru_cache(maxsize=1)
def context() -> Context:
    return Context(load_description(), GaitFamily.load(), load_sim_config())


def _run(steps: int, mode: str, pushes: tuple[PushSpec, ...] = (), *, integration_rate: bool = False,
         observer: bool | None = None, keep_qp: bool = False) -> RunResult:
    ctx = context()
    overrides = {"mode": mode, "period": ctx.sim_config.control_period}
    if observer is not None:
        overrides["disturbance_observer"] = observer
    ccfg = load_controller_config(**overrides)
    return runner.run(steps=steps, mode=mode, pushes=pushes, sim_config=ctx.sim_config, ctrl_config=ccfg,
                      family=ctx.family, desc=ctx.desc, integration_rate=integration_rate, keep_qp=keep_qp)


# ------------------------------------------------------------------------------------------ summaries
def joint_errors(result: RunResult, family: GaitFamily | None = None) -> np.ndarray:
    """(N, 6) tracking errors q_d(p, tau) - q at every control instant [rad] (paper joint order)."""
    fam = family if family is not None else context().family
    return np.array([fam.evaluate(s.p, s.tau).q - r.q for s, r in zip(result.statuses, result.records)])


def summarize(result: RunResult, family: GaitFamily | None = None, push_end: float | None = None) -> dict:
    """Numbers of one run (plain floats/lists, JSON-ready)."""
    fam = family if family is not None else context().family
    st, rec = result.statuses, result.records
    p = np.array([s.p for s in st])
    tau = np.array([s.tau for s in st])
    taud = np.array([s.tau_dot for s in st])
    err = np.array([s.max_tracking_error for s in st])
    t = np.array([r.t for r in rec])
    cop = np.array([r.cop for r in rec])
    ok = np.isfinite(cop) & ~np.array([r.fallen for r in rec])
    impacts = [float(i.t) for i in result.impacts]
    first = impacts[0] if impacts else math.inf
    qp_counts: dict[str, int] = {}
    for s in st:
        name = STATUS_NAMES.get(s.qp_status, "NO_ADAPTATION" if s.qp_status == 4 else str(s.qp_status))
        qp_counts[name] = qp_counts.get(name, 0) + 1
    out = {
        "steps_walked": int(result.steps_walked),
        "fallen": bool(result.fallen),
        "fall_cause": result.fall_cause,
        "fall_detail": result.fall_detail,
        "fall_time": None if math.isnan(result.fall_time) else float(result.fall_time),
        "sim_time": float(t[-1] + context().sim_config.control_period) if len(t) else 0.0,
        "max_tracking_error": float(err.max()) if err.size else 0.0,
        "max_tracking_error_before_first_impact": float(err[t < first].max()) if np.any(t < first) else 0.0,
        "max_tracking_error_after_first_impact": float(err[t >= first].max()) if np.any(t >= first) else 0.0,
        "p_min": float(p.min()), "p_max": float(p.max()),
        "max_p_excursion": float(np.max(np.abs(p - fam.p_d))),
        "tau_max": float(tau.max()),
        "tau_dot_min": float(taud.min()), "tau_dot_max": float(taud.max()),
        "max_tau_dot_excursion": float(np.max(np.abs(taud - 1.0))),
        "max_abs_l": float(np.max(np.abs(cop[ok]))) if np.any(ok) else math.nan,
        "l_at_fall": float(rec[-1].cop) if result.fallen else None,
        "final_p": float(p[-1]), "final_tau_dot": float(taud[-1]),
        "impact_times": impacts,
        "step_durations": [float(b - a) for a, b in zip([0.0] + impacts[:-1], impacts)],
        "qp_status_counts": qp_counts,
    }
    if push_end is not None:
        out["impacts_after_push"] = int(sum(1 for x in impacts if x >= push_end))
    return out


# ------------------------------------------------------------------------------------------ walk
def walk(steps: int = 10, mode: str = "both") -> dict:
    """Undisturbed walking, controller at the integration rate and at the control period (ZOH)."""
    out = {"steps": steps, "mode": mode, "explanation": ZOH_EXPLANATION}
    for key, ir in (("integration_rate", True), ("zoh", False)):
        t0 = time.perf_counter()
        res = _run(steps, mode, integration_rate=ir)
        s = summarize(res)
        s["wall_time"] = time.perf_counter() - t0
        out[key] = s
    return out


def print_walk(r: dict) -> None:
    print(f"walk: {r['steps']} steps, mode {r['mode']}")
    print(f"{'controller':<18} {'steps':>5} {'fallen':>6} {'max err [rad]':>13} {'1st step':>10} {'after impact':>12} "
          f"{'p range [m]':>17} {'tau_dot range':>17} {'wall [s]':>8}")
    for key, label in (("integration_rate", "integration rate"), ("zoh", "ZOH 1 ms")):
        s = r[key]
        print(f"{label:<18} {s['steps_walked']:>5} {str(s['fallen']):>6} {s['max_tracking_error']:13.3e} "
              f"{s['max_tracking_error_before_first_impact']:10.2e} {s['max_tracking_error_after_first_impact']:12.2e} "
              f"{s['p_min']:8.5f}-{s['p_max']:8.5f} {s['tau_dot_min']:8.5f}-{s['tau_dot_max']:8.5f} {s['wall_time']:8.2f}")
    for key, label in (("integration_rate", "integration rate"), ("zoh", "ZOH 1 ms")):
        print(f"impact times ({label}): " + ", ".join(f"{x:.6f}" for x in r[key]["impact_times"]))
    print(r["explanation"])


# ------------------------------------------------------------------------------------------ push
def push_step_index(start: float, duration: float, T: float) -> int:
    """Index of the (nominal) step during which the push ends (0 = first step)."""
    return int(math.floor((start + duration) / T))


def push_run(force: float, duration: float = DEFAULT_DURATION, start: float = DEFAULT_START, mode: str = "both",
             height: float | None = None, steps_after: int = SURVIVAL_STEPS, keep_qp: bool = False) -> RunResult:
    """One push (+ forward, i.e. on the back), then ``steps_after`` more steps."""
    T = context().family.T
    steps = push_step_index(start, duration, T) + 1 + steps_after
    return _run(steps, mode, (PushSpec(start, duration, float(force), height),), keep_qp=keep_qp)


def survival(result: RunResult, push_end: float, steps_after: int = SURVIVAL_STEPS) -> tuple[bool, str]:
    """(survived, reason) by the criterion of the module docstring."""
    fam = context().family
    if result.fallen:
        return False, f"fell: {result.fall_cause} at t = {result.fall_time:.4f} s"
    after = sum(1 for i in result.impacts if i.t >= push_end)
    if after < steps_after:
        return False, f"only {after} steps after the push (time limit)"
    last = result.statuses[-1]
    if abs(last.p - fam.p_d) > P_TOL:
        return False, f"p = {last.p:.5f} m not back to p_d (|p - p_d| > {P_TOL})"
    if abs(last.tau_dot - 1.0) > TAU_DOT_TOL:
        return False, f"tau' = {last.tau_dot:.5f} not back to 1 (> {TAU_DOT_TOL})"
    return True, "survived"


def push_experiment(force: float, duration: float = DEFAULT_DURATION, start: float = DEFAULT_START,
                    mode: str = "both", height: float | None = None, figures: str | Path | None = None) -> dict:
    res = push_run(force, duration, start, mode, height)
    ok, why = survival(res, start + duration)
    s = summarize(res, push_end=start + duration)
    out = {"force": force, "duration": duration, "start": start, "mode": mode, "height": height,
           "survived": ok, "reason": why, **s}
    if figures is not None:
        out["figures"] = [str(p) for p in push_figures(res, Path(figures), start, duration,
                                                       title=f"{force:g} N, {duration * 1e3:g} ms at t = {start:g} s, mode {mode}")]
    return out


def print_push(r: dict) -> None:
    print(f"push {r['force']:g} N for {r['duration']:g} s at t = {r['start']:g} s (+ forward, on the back), mode {r['mode']}")
    print(f"  result: {'SURVIVED' if r['survived'] else 'FAILED'} ({r['reason']})")
    if r["fallen"]:
        print(f"  fall: {r['fall_cause']} at t = {r['fall_time']:.4f} s: {r['fall_detail']}")
    print(f"  steps walked {r['steps_walked']} ({r.get('impacts_after_push', 0)} after the push)")
    print(f"  max |l| = {r['max_abs_l']:.4f} m (limits +-0.1 m)")
    print(f"  p in [{r['p_min']:.5f}, {r['p_max']:.5f}] m, max |p - p_d| = {r['max_p_excursion']:.5f} m, final p = {r['final_p']:.6f}")
    print(f"  tau' in [{r['tau_dot_min']:.5f}, {r['tau_dot_max']:.5f}], max |tau' - 1| = {r['max_tau_dot_excursion']:.5f}, "
          f"final tau' = {r['final_tau_dot']:.6f}")
    print(f"  max tracking error {r['max_tracking_error']:.4e} rad; QP statuses {r['qp_status_counts']}")
    for f in r.get("figures", []):
        print(f"  figure: {f}")


def push_figures(result: RunResult, outdir: Path, start: float, duration: float, joint: int | None = None,
                 title: str = "") -> list[Path]:
    """PNG figures like the paper's Figs. 3-7. ``joint`` (0-based) for Figs. 6-7; default: the joint
    with the largest tracking error."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fam = context().family
    desc = context().desc
    outdir.mkdir(parents=True, exist_ok=True)
    t = np.array([r.t for r in result.records])
    st = result.statuses
    E = joint_errors(result, fam)
    j = int(np.argmax(np.max(np.abs(E), axis=0))) if joint is None else joint
    impacts = [i.t for i in result.impacts]
    paths = []

    def decorate(ax):
        ax.axvspan(start, start + duration, color="tab:red", alpha=0.15, label="push")
        for x in impacts:
            ax.axvline(x, color="0.6", lw=0.6, ls=":")
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3)

    def save(fig, name):
        p = outdir / name
        fig.tight_layout()
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)

    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.plot(t, [r.cop for r in result.records], lw=1.0, label="l (simulator)")
    ax.plot(t, [s.zmp for s in st], lw=0.8, ls="--", label="l (controller prediction)")
    ax.axhline(desc.foot.l_max, color="k", ls="--", lw=0.8)
    ax.axhline(desc.foot.l_min, color="k", ls="--", lw=0.8, label="limits")
    ax.set_ylim(1.3 * desc.foot.l_min, 1.3 * desc.foot.l_max)
    ax.set_ylabel("l [m]")
    ax.set_title(f"Fig. 3: centre of pressure l(t). {title}", fontsize=9)
    decorate(ax)
    ax.legend(fontsize=8, loc="lower right")
    save(fig, "fig3_l.png")

    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(t, [s.p for s in st], lw=1.0)
    ax.axhline(fam.p_d, color="k", ls="--", lw=0.8, label="p_d")
    ax.set_ylabel("p [m]")
    ax.set_title(f"Fig. 4: stride parameter p(t). {title}", fontsize=9)
    decorate(ax)
    ax.legend(fontsize=8)
    save(fig, "fig4_p.png")

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    a1.plot(t, [s.tau for s in st], lw=1.0)
    a1.set_ylabel("tau [s]")
    a1.set_title(f"Fig. 5: phase tau(t) and its rate tau'(t). {title}", fontsize=9)
    decorate(a1)
    a1.set_xlabel("")
    a2.plot(t, [s.tau_dot for s in st], lw=1.0)
    a2.axhline(1.0, color="k", ls="--", lw=0.8)
    a2.set_ylabel("tau' [-]")
    decorate(a2)
    save(fig, "fig5_tau.png")

    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(t, E[:, j], lw=1.0)
    ax.set_ylabel(f"q{j + 1}_d - q{j + 1} [rad]")
    ax.set_title(f"Fig. 6: tracking error of q{j + 1}. {title}", fontsize=9)
    decorate(ax)
    save(fig, "fig6_tracking_error.png")

    q = np.array([r.q[j] for r in result.records])
    qd = np.array([r.qd[j] for r in result.records])
    stance = np.array([r.stance for r in result.records])
    brk = np.flatnonzero(np.diff(stance) != 0) + 1   # do not join the points across an impact
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    ax.plot(np.insert(q, brk, np.nan), np.insert(qd, brk, np.nan), lw=0.8, label="measured")
    ref = [fam.reference(fam.p_d, 0.0, x, 1.0) for x in np.linspace(0, fam.T, 200)]
    ax.plot([r[0][j] for r in ref], [r[1][j] for r in ref], "k--", lw=0.8, label="preferred gait")
    during = (t >= start) & (t < start + duration)
    ax.plot(q[during], qd[during], color="tab:red", lw=2, label="during the push")
    ax.set_xlabel(f"q{j + 1} [rad]")
    ax.set_ylabel(f"q{j + 1}' [rad/s]")
    ax.set_title(f"Fig. 7: q{j + 1} in its phase plane", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save(fig, "fig7_phase_plane.png")
    return paths


# ------------------------------------------------------------------------------------------ max push
def survives(force: float, mode: str, duration: float = DEFAULT_DURATION, start: float = DEFAULT_START,
             height: float | None = None) -> dict:
    """One survival trial (JSON-ready): force, survived, reason, and a few numbers."""
    res = push_run(force, duration, start, mode, height)
    ok, why = survival(res, start + duration)
    return {"force": float(force), "mode": mode, "survived": ok, "reason": why,
            "fall_cause": res.fall_cause, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
            "steps_walked": int(res.steps_walked)}


def _trial(args: tuple) -> dict:
    return survives(*args)


def coarse_forces(fmax: float, coarse: float) -> list[float]:
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


def bisect_edge(mode: str, lo: float, hi: float, resolution: float, duration: float = DEFAULT_DURATION,
                start: float = DEFAULT_START, height: float | None = None, progress=None,
                sign: float = 1.0) -> tuple[float, float, list[dict]]:
    """Bisect the force magnitudes [lo (survives), hi (fails)] down to ``resolution`` [N]; the push is
    applied with ``sign`` (+1 forward). Returns (lo, hi, trials)."""
    trials = []
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        r = dict(survives(sign * mid, mode, duration, start, height), force=mid)
        trials.append(r)
        if progress:
            progress()
        if r["survived"]:
            lo = mid
        else:
            hi = mid
    return lo, hi, trials


def _bisect_task(args: tuple) -> tuple[str, float, float, list[dict]]:
    mode, lo, hi, resolution, duration, start, height, sign = args
    a, b, tr = bisect_edge(mode, lo, hi, resolution, duration, start, height, sign=sign)
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


class Progress:
    def __init__(self, total: int, label: str, enabled: bool = True):
        self.total, self.done, self.label, self.enabled = total, 0, label, enabled
        self.t0 = time.perf_counter()

    def __call__(self, n: int = 1, total: int | None = None) -> None:
        self.done += n
        if total is not None:
            self.total = total
        if not self.enabled:
            return
        w = 30
        k = int(w * min(self.done, self.total) / max(self.total, 1))
        sys.stderr.write(f"\r{self.label} [{'#' * k}{'.' * (w - k)}] {self.done}/{self.total} runs "
                         f"{time.perf_counter() - self.t0:6.1f} s")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def _pool(workers: int):
    return mp.get_context("spawn").Pool(workers, initializer=_worker_init)


def _worker_init() -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    context()  # each worker loads its own description, family and settings (and builds its own models per run)


def max_push_modes(modes: tuple[str, ...], resolution: float = 5.0, fmax: float = 2000.0, coarse: float = 50.0,
                   duration: float = DEFAULT_DURATION, start: float = DEFAULT_START, height: float | None = None,
                   workers: int = 1, progress: bool = True, sign: float = 1.0) -> dict[str, dict]:
    """Largest survivable push for each mode: coarse scan (all modes' trials together, over a pool of
    ``workers`` processes), then a bisection of each mode's lowest failing edge (modes in parallel)."""
    forces = coarse_forces(fmax, coarse)
    tasks = [(sign * f, m, duration, start, height) for m in modes for f in forces]
    bis_est = len(modes) * max(0, math.ceil(math.log2(max(coarse / resolution, 1.0))))
    bar = Progress(len(tasks) + bis_est, "max-push " + ",".join(modes), progress)
    coarse_res: list[dict] = []
    pool = _pool(workers) if workers > 1 else None
    try:
        it = pool.imap(_trial, tasks) if pool else map(_trial, tasks)
        for r in it:
            coarse_res.append(r)
            bar()
        per_mode = {}
        bis_tasks = []
        for m in modes:
            tr = [dict(r, force=abs(r["force"])) for r in coarse_res if r["mode"] == m]
            lo, hi, isl = analyse_coarse(tr)
            per_mode[m] = (tr, lo, hi, isl)
            if hi is not None:
                bis_tasks.append((m, lo, hi, resolution, duration, start, height, sign))
        bis_out = {}
        if pool and len(bis_tasks) > 1:
            for mode, lo, hi, tr in pool.imap(_bisect_task, bis_tasks):
                bis_out[mode] = (lo, hi, tr)
                bar(len(tr))
        else:
            for (m, lo, hi, res_, d, s0, h, sg) in bis_tasks:
                bis_out[m] = bisect_edge(m, lo, hi, res_, d, s0, h, progress=bar, sign=sg)
    finally:
        if pool:
            pool.close()
            pool.join()
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
    return results


def max_push(mode: str, resolution: float = 5.0, fmax: float = 2000.0, coarse: float = 50.0, **kw) -> dict:
    return max_push_modes((mode,), resolution, fmax, coarse, **kw)[mode]


def ordering_finding(results: dict[str, dict]) -> str:
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
    print(f"{'mode':<6} {'max force [N]':>13} {'first fail [N]':>14} {'paper [N]':>9} {'islands (coarse) [N]':<24} cause of the first failure")
    for m, r in results.items():
        paper = "-" if r["paper"] is None else f"{r['paper']:g}"
        ff = "none" if r["first_failure"] is None else f"{r['first_failure']:g}"
        isl = ", ".join(f"{x:g}" for x in r["islands"]) or "-"
        print(f"{m:<6} {r['max_force']:13g} {ff:>14} {paper:>9} {isl:<24} {r['failure_cause'] or '-'}")
    r0 = next(iter(results.values()))
    print(f"(push {r0['direction']} for {DEFAULT_DURATION if 'duration' not in r0 else r0['duration']:g} s; "
          f"coarse step {r0['coarse_step']:g} N up to {r0['scan_max']:g} N, edge bisected to {r0['resolution']:g} N; "
          f"survival = no fall for {SURVIVAL_STEPS} steps after the push, |p - p_d| <= {P_TOL} m and "
          f"|tau' - 1| <= {TAU_DOT_TOL} at the end)")


# ------------------------------------------------------------------------------------------ CLI
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
    path.write_text(json.dumps(data, indent=1, default=conv) + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/experiment", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("walk", help="undisturbed walk: integration-rate vs ZOH controller")
    a.add_argument("--steps", type=int, default=10)
    a.add_argument("--mode", choices=MODES, default="both")
    a.add_argument("--json", type=Path)
    a = sub.add_parser("push", help="one push, with figures like the paper's Figs. 3-7")
    a.add_argument("--force", type=float, default=250.0, help="[N], + forward (on the back)")
    a.add_argument("--duration", type=float, default=DEFAULT_DURATION)
    a.add_argument("--start", type=float, default=DEFAULT_START)
    a.add_argument("--height", type=float, default=None, help="above the hip [m] (default: config/simulator.yaml)")
    a.add_argument("--mode", choices=MODES, default="both")
    a.add_argument("--figures", type=Path, help="directory for the PNG figures")
    a.add_argument("--json", type=Path)
    for name, hlp in (("max-push", "largest survivable push for one mode"), ("table", "max-push for all four modes")):
        a = sub.add_parser(name, help=hlp)
        if name == "max-push":
            a.add_argument("--mode", choices=MODES, default="both")
        a.add_argument("--resolution", type=float, default=5.0, help="bisection resolution [N]")
        a.add_argument("--max", type=float, default=2000.0, help="largest force scanned [N]")
        a.add_argument("--coarse", type=float, default=50.0, help="coarse scan step [N]")
        a.add_argument("--duration", type=float, default=DEFAULT_DURATION)
        a.add_argument("--start", type=float, default=DEFAULT_START)
        a.add_argument("--backward", action="store_true", help="push backwards (on the chest) instead")
        a.add_argument("--workers", type=int, default=1, help="processes (each builds its own models)")
        a.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    if args.cmd == "walk":
        r = walk(args.steps, args.mode)
        print_walk(r)
    elif args.cmd == "push":
        r = push_experiment(args.force, args.duration, args.start, args.mode, args.height, args.figures)
        print_push(r)
    else:
        modes = (args.mode,) if args.cmd == "max-push" else ("none", "tau", "p", "both")
        t0 = time.perf_counter()
        res = max_push_modes(modes, args.resolution, args.max, args.coarse, args.duration, args.start,
                             workers=max(1, args.workers), sign=-1.0 if args.backward else 1.0)
        for v in res.values():
            v["duration"] = args.duration
        print_max_push(res)
        r = {"modes": res, "wall_time": time.perf_counter() - t0}
        if args.cmd == "table":
            r["ordering"] = ordering_finding(res)
            print(r["ordering"])
        print(f"wall time {r['wall_time']:.1f} s")
    _dump(args.json, r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
