"""Single closed-loop runs of the paper's section 6 and what they print: an undisturbed walk (controller at
the integration rate and at the control period), one push with figures like the paper's Figs. 3-7, and the
probe of one push (the controller's view period by period while it acts)."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from biped_sim.plant.protocol import make_plant
from biped_sim.plant.push import Push
from biped_model.description import LEFT
from biped_model.fixed_foot import CONSTRAINT_NAMES

from biped_controller.core.control.config import TORSO_MODES
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.control.status import NO_ADAPTATION
from biped_controller.core.qp.solver import STATUS_NAMES
from biped_controller.closed_loop.runner import RunResult
from biped_controller.studies.trial import runs
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings, differences
from biped_controller.studies.trial.summary import joint_errors
from biped_controller.studies.trial.survival import survival_rule
from biped_controller.studies.trial.controller import resolve
from biped_controller.studies.trial.trials import band as trial_band

ZOH_EXPLANATION = (
    "cause of the ZOH error: the torque is computed at each control instant and held for the period "
    "(1 ms) while the reference acceleration q_d'' (and the state) keep changing, an O(dt) acceleration "
    "error every period; and the touchdown falls between two control instants, so the torque held since "
    "the last instant acts up to the impact and the step starts from a slightly different post-impact "
    "state. The integration-rate controller (torque law evaluated at every RK4 stage) has neither error "
    "source except the last fraction of a period before each impact."
)


def walk(steps: int = 10, mode: str = "both", settings: RunSettings = DEFAULT_SETTINGS) -> dict:
    """Undisturbed walking for ``steps`` impacts by the controller ``mode`` (a built-in mode or any registered
    controller, ``trial.controller.resolve``), at the control period (ZOH) and, for the adaptive controller
    with ideal sensors, also at the integration rate (a torque function sees the true state; a plug-in's
    torque is held over the period): ``integration_rate`` None otherwise, ``not_run`` says why."""
    ctl = resolve(mode)
    out = {"steps": steps, "mode": mode, "explanation": ZOH_EXPLANATION if ctl.adaptive else "", "not_run": None}
    pert = settings.perturbation
    for key, ir in (("integration_rate", True), ("zoh", False)):
        if ir and not ctl.adaptive:
            out[key] = None
            out["not_run"] = "a plug-in's torque is held over the control period"
            continue
        if ir and pert is not None and not pert.sensing_is_perfect:
            out[key] = None      # a torque function sees the true state at every RK4 stage: no sensor model
            out["not_run"] = "the sensor model needs held torques"
            continue
        t0 = time.perf_counter()
        res = ctl.walk(steps, settings, integration_rate=ir)
        s = ctl.summary(res)
        s["wall_time"] = time.perf_counter() - t0
        out[key] = s
    return out


def print_walk(r: dict) -> None:
    print(f"walk: {r['steps']} steps, mode {r['mode']}")
    print(f"{'controller':<18} {'steps':>5} {'fallen':>6} {'max err [rad]':>13} {'1st step':>10} {'after impact':>12} "
          f"{'p range [m]':>17} {'tau_dot range':>17} {'wall [s]':>8}")
    for key, label in (("integration_rate", "integration rate"), ("zoh", "ZOH 1 ms")):
        s = r[key]
        if s is None:
            print(f"{label:<18} (not run: {r.get('not_run') or 'the sensor model needs held torques'})")
            continue
        if s["fallen"]:
            print(f"{label:<18} fall: {s['fall_cause']} at t = {s['fall_time']:.4f} s: {s['fall_detail']}")
        print(f"{label:<18} {s['steps_walked']:>5} {str(s['fallen']):>6} {s['max_tracking_error']:13.3e} "
              f"{s['max_tracking_error_before_first_impact']:10.2e} {s['max_tracking_error_after_first_impact']:12.2e} "
              f"{s['p_min']:8.5f}-{s['p_max']:8.5f} {s['tau_dot_min']:8.5f}-{s['tau_dot_max']:8.5f} {s['wall_time']:8.2f}")
    for key, label in (("integration_rate", "integration rate"), ("zoh", "ZOH 1 ms")):
        if r[key] is None:
            continue
        print(f"impact times ({label}): " + ", ".join(f"{x:.6f}" for x in r[key]["impact_times"]))
        s = r[key]
        if s.get("fault"):
            print(f"controller fault ({label}): {s['fault']}")
        if math.isfinite(s["force_estimate_abs_max"]):      # NaN: the controller reports no force estimate
            print(f"force estimate |F| ({label}): p50 {s['force_estimate_abs_p50']:.1f} N, p95 "
                  f"{s['force_estimate_abs_p95']:.1f} N, max {s['force_estimate_abs_max']:.1f} N")
    if r["explanation"]:
        print(r["explanation"])


def push_experiment(push: Push, mode: str = "both", figures: str | Path | None = None,
                    settings: RunSettings = DEFAULT_SETTINGS) -> dict:
    """One ``push`` and ``SURVIVAL_STEPS`` steps after it: the survival verdict and the run's summary;
    with ``figures`` a directory, the paper-like PNG figures written there."""
    force, duration, start, height = push.force, push.duration, push.start, push.height
    ctl = resolve(mode)
    steps = runs.trial_steps(push)
    res = ctl.walk(steps, settings, (push,))
    rule, band = survival_rule(), ctl.band(settings, steps)
    v = ctl.verdict(res, push.end, band)
    s = ctl.summary(res, push_end=push.end)
    out = {"force": force, "duration": duration, "start": start, "mode": mode, "height": height,
           "survived": v.survived, "reason": v.reason, "band": band.as_dict(), "survival": rule.text(band), **s}
    if figures is not None:
        title = f"{force:g} N, {duration * 1e3:g} ms at t = {start:g} s, {'mode' if ctl.adaptive else 'controller'} {mode}"
        draw = push_figures if ctl.adaptive else reported_figures
        out["figures"] = [str(p) for p in draw(res, Path(figures), push, title=title)]
    return out


def band_walk(push: Push, mode: str = "both", settings: RunSettings = DEFAULT_SETTINGS) -> dict:
    """The survival rule's band for trials of ``push``'s window (its force is not used) of the controller
    ``mode`` (a built-in mode or any registered controller, ``trial.controller.resolve``): its unpushed walk
    of the trial's impacts (``runs.trial_steps``), per step its largest |p - p_d| [m] and |tau' - 1| [-] (a
    controller that does not report ``p`` or ``tau_dot`` has None there, and the rule's floors for it), the
    largest of each over every window of ``band_window`` consecutive steps, and the band (the one its
    trials are judged with: ``TrialController.band``)."""
    rule = survival_rule()
    ctl = resolve(mode)
    steps = runs.trial_steps(push)
    res = ctl.walk(steps, settings, (), keep_records=True)
    p_d = context().family.p_d
    if ctl.adaptive:
        t = np.array([s.t for s in res.statuses])
    else:                                   # a plug-in's status has no time: its period's record has
        t = np.array([r.t for r in res.records])
    p = res.series("p") - p_d if _reports(res, "p") else None
    td = res.series("tau_dot") - 1.0 if _reports(res, "tau_dot") else None
    bounds = [0.0] + [float(i.t) for i in res.impacts]
    per_step = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        w = (t >= a) & (t < b)
        if w.any():
            per_step.append({"p": float(np.abs(p[w]).max()) if p is not None else None,
                             "tau_dot": float(np.abs(td[w]).max()) if td is not None else None})

    def largest(xs):
        xs = [x for x in xs if x is not None]
        return max(xs) if xs else None
    W = rule.band_window
    windows = [{"steps": [k + 1, k + W], "p": largest(x["p"] for x in per_step[k:k + W]),
                "tau_dot": largest(x["tau_dot"] for x in per_step[k:k + W])} for k in range(len(per_step) - W + 1)]
    band = ctl.band(settings, steps)
    fault = getattr(res, "fault", None)         # a plug-in's controller fault (the adaptive controller has none)
    return {"mode": mode, "steps": steps, "fallen": bool(res.fallen), "fall_cause": res.fall_cause or None,
            "fault": None if fault is None else str(fault),
            "settings": differences(settings), "rule": rule.identity(), "per_step": per_step, "windows": windows,
            "end": {"p": float(p[-1]) if p is not None else None, "tau_dot": float(td[-1]) if td is not None else None},
            "band": band.as_dict(), "survival": rule.text(band)}


def _reports(res: RunResult, key: str) -> bool:
    """Whether every status of the run reports ``key`` (the adaptive controller's always do)."""
    if not res.statuses:
        return False
    return all(key in s for s in res.statuses) if isinstance(res.statuses[0], Mapping) else True


def print_band_walk(r: dict) -> None:
    def e(x, w):
        return f"{x:{w}.3e}" if x is not None else f"{'not reported':>{w}}"
    end = (f": CONTROLLER FAULT ({r['fault']})" if r.get("fault") else f": FELL ({r['fall_cause']})" if r["fallen"]
           else "")
    print(f"unpushed walk, controller {r['mode']}, {r['steps']} impacts" + end)
    print("step  max|p - p_d| [m]  max|tau' - 1|")
    for k, x in enumerate(r["per_step"], 1):
        print(f"{k:4d}  {e(x['p'], 16)}  {e(x['tau_dot'], 13)}")
    ws = r["windows"]
    for key, label, unit in (("p", "max|p - p_d|", " m"), ("tau_dot", "max|tau' - 1|", "")):
        xs = [w[key] for w in ws if w[key] is not None]
        if xs:
            print(f"windows of {r['rule']['band_window']} steps: {label} {min(xs):.3e} .. {max(xs):.3e}{unit}")
    print(f"end: p - p_d {e(r['end']['p'], 0).strip()} m, tau' - 1 {e(r['end']['tau_dot'], 0).strip()}")
    print(f"survival: {r['survival']}")


def _verdict_word(r: dict) -> str:
    """A single run's headline word: a controller fault (no torque from then on: neither a survival nor a
    fall) is named before the fall and the survival rule."""
    if r.get("fault"):
        return "CONTROLLER FAULT"
    return "SURVIVED" if r["survived"] else "FELL" if r["fallen"] else \
        "FAILED (no fall, not back on the gait)"


def _verdict_line(r: dict) -> str:
    """``WORD (reason)``: the fault's message in place of the reason's "controller fault: " prefix."""
    reason = r["reason"].removeprefix("controller fault: ") if r.get("fault") else r["reason"]
    return f"{_verdict_word(r)} ({reason})"


def print_push(r: dict) -> None:
    print(f"push {r['force']:g} N for {r['duration']:g} s at t = {r['start']:g} s (+ forward, on the back), mode {r['mode']}")
    print(f"  result: {_verdict_line(r)}")
    print(f"  survival: {r['survival']}")
    if r["fallen"]:
        print(f"  fall: {r['fall_cause']} at t = {r['fall_time']:.4f} s: {r['fall_detail']}")
    print(f"  steps walked {r['steps_walked']} ({r.get('impacts_after_push', 0)} after the push)")
    print(f"  max |l| = {r['max_abs_l']:.4f} m (limits +-0.1 m)")
    print(f"  p in [{r['p_min']:.5f}, {r['p_max']:.5f}] m, max |p - p_d| = {r['max_p_excursion']:.5f} m, final p = {r['final_p']:.6f}")
    print(f"  tau' in [{r['tau_dot_min']:.5f}, {r['tau_dot_max']:.5f}], max |tau' - 1| = {r['max_tau_dot_excursion']:.5f}, "
          f"final tau' = {r['final_tau_dot']:.6f}")
    if r["mode"] in TORSO_MODES:
        print(f"  max |lambda| = {r['max_abs_lambda']:.5f} rad, final lambda = {r['final_lambda']:.6f} rad")
    print(f"  max tracking error {r['max_tracking_error']:.4e} rad; QP statuses {r['qp_status_counts']}")
    if r.get("fault"):
        print(f"  controller fault: {r['fault']}")
    for f in r.get("figures", []):
        print(f"  figure: {f}")


def push_figures(result: RunResult, outdir: Path, push: Push, joint: int | None = None,
                 title: str = "") -> list[Path]:
    """PNG figures like the paper's Figs. 3-7 of a run with ``push``. ``joint`` (0-based) for Figs. 6-7;
    default: the joint with the largest tracking error."""
    start, duration = push.start, push.duration
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

    if result.statuses and result.statuses[0].mode in TORSO_MODES:      # the torso parameter
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
        a1.plot(t, [s.lam for s in st], lw=1.0)
        a1.axhline(0.0, color="k", ls="--", lw=0.8)
        a1.set_ylabel("lambda [rad]")
        a1.set_title(f"torso offset lambda(t) (+ leans back) and lambda'(t). {title}", fontsize=9)
        decorate(a1)
        a1.set_xlabel("")
        a2.plot(t, [s.lam_dot for s in st], lw=1.0)
        a2.set_ylabel("lambda' [rad/s]")
        decorate(a2)
        save(fig, "fig5b_lambda.png")

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


def reported_figures(result, outdir: Path, push: Push, title: str = "") -> list[Path]:
    """The PNG figures of :func:`push_figures` that a run of any interface controller
    (``plugin.result.RunResult``) has the data for: Fig. 3, the centre of pressure l(t) [m] (and the
    controller's prediction where it reports ``zmp``), Fig. 4, p(t) [m], and Fig. 5, tau'(t) [-], where it
    reports ``p`` and ``tau_dot``; the tracking error needs q_d(p, tau), the adaptive controller's."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fam, desc = context().family, context().desc
    outdir.mkdir(parents=True, exist_ok=True)
    t = np.array([r.t for r in result.records])
    impacts = [i.t for i in result.impacts]
    paths = []

    def figure(name: str, ylabel: str, text: str, curves: list[tuple[np.ndarray, str]], lines: list[tuple[float, str]]):
        fig, ax = plt.subplots(figsize=(7, 3.4))
        for y, label in curves:
            ax.plot(t, y, lw=1.0, label=label)
        for y, label in lines:
            ax.axhline(y, color="k", ls="--", lw=0.8, label=label)
        ax.axvspan(push.start, push.end, color="tab:red", alpha=0.15, label="push")
        for x in impacts:
            ax.axvline(x, color="0.6", lw=0.6, ls=":")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(ylabel)
        ax.set_title(f"{text}. {title}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(outdir / name, dpi=110)
        plt.close(fig)
        paths.append(outdir / name)

    def reported(key: str) -> bool:
        return any(key in st for st in result.statuses)
    curves = [(np.array([r.cop for r in result.records]), "l (simulator)")]
    if reported("zmp"):
        curves.append((result.series("zmp"), "l (controller prediction)"))
    figure("fig3_l.png", "l [m]", "Fig. 3: centre of pressure l(t)", curves,
           [(desc.foot.l_max, "limits"), (desc.foot.l_min, "")])
    if reported("p"):
        figure("fig4_p.png", "p [m]", "Fig. 4: stride parameter p(t)", [(result.series("p"), "p")], [(fam.p_d, "p_d")])
    if reported("tau_dot"):
        figure("fig5_tau.png", "tau' [-]", "Fig. 5: phase rate tau'(t)", [(result.series("tau_dot"), "tau'")],
               [(1.0, "1")])
    return paths


@dataclass(frozen=True)
class ProbeResult:
    """A closed-loop run plus what ``runner.run`` does not return: the controller's force estimate."""

    result: RunResult
    force_estimate: np.ndarray    # (N,) the observer's horizontal torso force at each period [N] (0 when off)


def probe_run(push: Push, mode: str = "both", settings: RunSettings = DEFAULT_SETTINGS,
              until: float | None = None, steps: int | None = None) -> ProbeResult:
    """The closed loop of ``runner.run`` (same order of calls, so bit-identical records; tested) with one
    push, also recording ``AdaptiveController.force_estimate`` after each decision. Stops at a fall, after
    ``steps`` impacts (default: as ``push_run``), or once the simulated time reaches ``until`` [s]."""
    ctx = context()
    scfg = settings.sim_config()
    ccfg = settings.ctrl_config(mode)
    n_steps = steps if steps is not None else runs.trial_steps(push)
    sim = make_plant(scfg.plant, ctx.desc, scfg, settings.perturbation)   # rigid or MuJoCo (--set plant=...)
    ctrl = AdaptiveController(ccfg, ctx.family, ctx.desc)
    q0, qd0 = ctx.family.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    sim.schedule_push(push.start, push.duration, float(push.force), push.height)
    limit = until if until is not None else (n_steps + 3) * ctx.family.T * 3
    records, statuses, est = [], [], []
    while True:
        obs = sim.observe()
        out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch, obs.pitch_rate)
        statuses.append(out.status)
        est.append(ctrl.force_estimate)
        rec = sim.step(out.torque)
        records.append(rec)
        if rec.fallen or sim.fall is not None or sim.impact_count >= n_steps or sim.t >= limit:
            break
    fall = sim.fall
    res = RunResult(records=records, statuses=statuses, steps_walked=sim.impact_count, fallen=fall is not None,
                    fall_cause=fall.cause if fall else "", fall_detail=fall.detail if fall else "",
                    fall_time=fall.t if fall else math.nan, impacts=list(sim.impact_log))
    return ProbeResult(res, np.array(est))


def _status_name(code: int) -> str:
    return STATUS_NAMES.get(code, "NO_ADAPTATION" if code == NO_ADAPTATION else str(code))


def probe(push: Push, mode: str = "both", settings: RunSettings = DEFAULT_SETTINGS, before: float = 0.002,
          after: float = 0.010) -> dict:
    """One push seen from the controller, period by period over [start - before, end + after] (or to the
    fall). Per period (values at its start t): the true push and the observer's estimate [N]; the QP
    status; the tightest of the 17 true rows (margins scaled by the model's row scales, evaluated with the
    controller's predicted reaction) and its margin; the predicted ground reaction R (the controller's
    B w + h_b, with the estimate when the observer is on) against the simulator's actual wrench (F_x, F_z)
    under the same torque and push [N]; l predicted (Gamma_1 / R_y predicted) and actual (m / F_z) [m];
    p'' [m/s^2] and tau'' [1/s]. Plus the survival verdict of the full run (up to SURVIVAL_STEPS after)."""
    ctl = resolve(mode)
    if not ctl.adaptive:
        return _probe_reported(ctl, push, settings, before, after)
    pr = probe_run(push, mode, settings)
    res = pr.result
    force, duration, start, height = push.force, push.duration, push.start, push.height
    end = push.end
    v = survival_rule().verdict(res, end, trial_band(mode, push, settings))
    ok, why = v.survived, v.reason
    rows = []
    for k, (rec, st) in enumerate(zip(res.records, res.statuses)):
        if rec.t < start - before - 1e-12 or rec.t > end + after + 1e-12:
            continue
        i = int(st.tightest)
        rows.append({
            "t": float(rec.t), "stance": int(rec.stance), "impacts": int(rec.impacts), "push": float(rec.push_force),
            "estimate": float(pr.force_estimate[k]),
            "qp_status": _status_name(st.qp_status), "tightest": CONSTRAINT_NAMES[i],
            "tightest_margin": float(st.margins[i]),
            "R_pred": [float(st.predicted_reaction[0]), float(st.predicted_reaction[1])],
            "R_act": [float(rec.wrench[0]), float(rec.wrench[1])],
            "l_pred": float(st.zmp), "l_act": float(rec.cop),
            "p_ddot": float(st.p_ddot), "tau_ddot": float(st.tau_ddot), "p": float(st.p), "tau_dot": float(st.tau_dot),
        })
    during = [r for r in rows if start <= r["t"] < end]
    return {
        "force": float(force), "mode": mode, "duration": duration, "start": start, "height": height,
        "settings": differences(settings), "survived": ok, "reason": why,
        "fall_cause": res.fall_cause or None, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
        "fall_detail": res.fall_detail or None,
        "max_l_error_during_push": max((abs(r["l_act"] - r["l_pred"]) for r in during), default=None),
        "periods": rows,
    }


def _probe_reported(ctl, push: Push, settings: RunSettings, before: float, after: float) -> dict:
    """:func:`probe` of any interface controller: per period the true push [N], the simulator's wrench
    (F_x, F_z) [N] and centre of pressure l [m], and the controller's status as it reports it (``status``:
    name -> value); ``max_l_error_during_push`` [m] where it reports its predicted l as ``zmp``."""
    steps = runs.trial_steps(push)
    res = ctl.walk(steps, settings, (push,))
    v = ctl.verdict(res, push.end, ctl.band(settings, steps))
    rows = []
    for rec, st in zip(res.records, res.statuses):
        if rec.t < push.start - before - 1e-12 or rec.t > push.end + after + 1e-12:
            continue
        rows.append({"t": float(rec.t), "stance": int(rec.stance), "impacts": int(rec.impacts),
                     "push": float(rec.push_force), "R_act": [float(rec.wrench[0]), float(rec.wrench[1])],
                     "l_act": float(rec.cop), "status": dict(st)})
    during = [r for r in rows if push.start <= r["t"] < push.end and "zmp" in r["status"]]
    return {
        "force": float(push.force), "mode": ctl.name, "duration": push.duration, "start": push.start,
        "height": push.height, "settings": differences(settings), "survived": v.survived, "reason": v.reason,
        "fall_cause": res.fall_cause or None, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
        "fall_detail": res.fall_detail or None, "fault": None if res.fault is None else str(res.fault),
        "max_l_error_during_push": max((abs(r["l_act"] - float(r["status"]["zmp"])) for r in during), default=None),
        "periods": rows,
    }


def _print_probe_reported(r: dict) -> None:
    keys = sorted({k for x in r["periods"] for k in x["status"]})
    print(f"{'t [s]':>7} {'imp':>3} {'push':>6} {'Rx act':>8} {'Ry act':>8} {'l act':>7} " + " ".join(f"{k:>10}" for k in keys))
    for x in r["periods"]:
        vals = " ".join(f"{float(x['status'][k]):10.4g}" if k in x["status"] else f"{'-':>10}" for k in keys)
        print(f"{x['t']:7.4f} {x['impacts']:3d} {x['push']:6.1f} {x['R_act'][0]:8.1f} {x['R_act'][1]:8.1f} "
              f"{x['l_act']:7.4f} {vals}")
    if r.get("fault"):
        print(f"  controller fault: {r['fault']}")


def print_probe(r: dict) -> None:
    print(f"probe: {r['force']:g} N for {r['duration']:g} s at t = {r['start']:g} s, mode {r['mode']}: "
          + (f"{_verdict_line(r)}" if r.get("fault") else f"{'SURVIVED' if r['survived'] else 'FAILED'} ({r['reason']})"))
    if r["fall_detail"]:
        print(f"  fall: {r['fall_detail']}")
    if r["periods"] and "qp_status" not in r["periods"][0]:
        _print_probe_reported(r)
        return
    print(f"{'t [s]':>7} {'imp':>3} {'push':>6} {'F_est':>7} {'QP':>13} {'tightest':>15} {'margin':>8} {'Rx pred':>8} {'Rx act':>8} "
          f"{'Ry pred':>8} {'Ry act':>8} {'l pred':>7} {'l act':>7} {'p_dd':>8} {'tau_dd':>8} {'p':>7} {'tau_d':>6}")
    for x in r["periods"]:
        print(f"{x['t']:7.4f} {x['impacts']:3d} {x['push']:6.1f} {x['estimate']:7.1f} {x['qp_status']:>13} {x['tightest']:>15} "
              f"{x['tightest_margin']:8.2f} {x['R_pred'][0]:8.1f} {x['R_act'][0]:8.1f} {x['R_pred'][1]:8.1f} "
              f"{x['R_act'][1]:8.1f} {x['l_pred']:7.4f} {x['l_act']:7.4f} {x['p_ddot']:8.3f} {x['tau_ddot']:8.3f} "
              f"{x['p']:7.4f} {x['tau_dot']:6.3f}")
    if r["max_l_error_during_push"] is not None:
        print(f"max |l act - l pred| during the push: {r['max_l_error_during_push']:.4f} m")


