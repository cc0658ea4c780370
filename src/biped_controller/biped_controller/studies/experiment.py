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
  table     [--workers N] [--modes M,M,...]    max-push for the four modes (or the modes named, e.g.
                                               none,tau,p,both,wbc,hybrid) next to the paper's values
  probe     --force F [--mode M] [--start S]   one push, the controller's view period by period while
                                               it acts: true push vs the observer's estimate, predicted
                                               vs actual ground reaction and l, QP status, tightest row

Settings of every subcommand: ``--observer on|off`` (the controller's disturbance observer; default:
config/controller.yaml) and ``--set KEY=VALUE`` (repeatable) for any key of config/controller.yaml
(except ``mode``: the subcommand chooses it) or config/simulator.yaml, e.g. ``--set margin_zmp=0.0
--set Kp=900 --set push_height=0.0``. Values are parsed as YAML scalars (``0.0``, ``900``, ``false``,
``reference``); the config loaders check them (a bad value is an error naming the key).
The effective controller and simulator settings and the overrides are printed and stored in the JSON,
so every table says exactly what it ran.

Every subcommand prints a table and, with ``--json FILE``, writes its numbers. Everything is
deterministic (the simulator and the controller are); the functions are importable (tests, benchmarks).

Survival (max-push): no fall until ``SURVIVAL_STEPS`` impacts after the end of the push, and at the end
of the run p within ``P_TOL`` of p_d and tau' within ``TAU_DOT_TOL`` of 1 (the robot is back on its
preferred gait). With noisy sensors (a perturbation with ``noise_q``, ``noise_qd``, ``encoder_bits`` or
``noise_pitch``) tau' is compared with the band ``TAU_DOT_TOL_NOISE`` instead (p keeps ``P_TOL``): the
controller's tau' follows its estimate of the state, never settles exactly, and an undisturbed walk under
the design-point noise already leaves 1 by up to 0.018 (docs/robustness.md); a pushed robot is back
when it is as close to the gait as an unpushed one under the same noise. Under model error (a perturbation
whose plant differs from the description: ``PlantPerturbation.model_is_nominal`` False) the unpushed robot
itself need not settle at p_d (on MuJoCo with the inertias 30 % larger it walks with p 1.2-1.4 mm short of
p_d after 11 steps, the toe row active at every touchdown), so p is compared with the unpushed walk's p at
the same instant (same settings, same number of steps: :func:`reference_p`), within ``P_TOL``; without model
error the reference is p_d itself. Survival need not be monotone in the force, so the search scans coarsely first, bisects
the lowest failing edge, and reports every survivable coarse force above that edge ("islands").
"""
from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from biped_sim.robot.description import LEFT, RobotDescription, load_description
from biped_sim.robot.gait_family import GaitFamily
from biped_sim.robot.settings import default_config_dir, read_settings
from biped_sim.plant.perturbation import PerturbationError, PlantPerturbation
from biped_sim.plant.config import SimConfig, SimConfigError, load_sim_config
from biped_sim.plant.push import Push
from biped_sim.plant.protocol import make_plant

from biped_controller.studies import runner
from biped_controller.core.control.controller import (MODES, NO_ADAPTATION, TORSO_MODES, AdaptiveController, ControllerConfig, ControllerConfigError,
                         load_controller_config)
from biped_sim.robot.fixed_foot import CONSTRAINT_NAMES
from biped_controller.core.qp.solver import STATUS_NAMES
from biped_controller.core.control.controller_layout import M_
from biped_controller.studies.executor import CountingBar, ProgressBar, make_executor
from biped_controller.studies.runner import RunResult
from biped_controller.studies import provenance

#: The paper's largest survivable push [N] (250 N-class push on the back during 0.025 s at mid-step);
#: mode "none" (classical computed torque) has no number in the paper.
PAPER_MAX_PUSH: dict[str, float | None] = {"both": 650.0, "tau": 455.0, "p": 320.0, "none": None}
DEFAULT_START = 0.2315          # the middle of the first step (T / 2 = 0.2315 s)
DEFAULT_DURATION = 0.025        # paper: 0.025 s
SURVIVAL_STEPS = 10             # impacts that must follow the end of the push
P_TOL = 1e-3                    # |p - p_d| at the end of a survived run [m]
TAU_DOT_TOL = 1e-3              # |tau' - 1| at the end of a survived run [-]
TAU_DOT_TOL_NOISE = 0.02        # |tau' - 1| at the end of a survived run with noisy sensors [-] (module doc)
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


# ------------------------------------------------------------------------------------------ settings
class OverrideError(ValueError):
    """A ``--set``/``--observer`` override names an unknown key, is malformed, or contradicts another one
    (the message names the key)."""


#: keys ``--set`` may override: every ControllerConfig field but ``mode`` (chosen by the subcommand) and
#: ``period`` (it is the simulator's ``control_period``), and every SimConfig field
CONTROLLER_KEYS: tuple[str, ...] = tuple(k for k in ControllerConfig.__dataclass_fields__ if k not in ("mode", "period"))
SIMULATOR_KEYS: tuple[str, ...] = tuple(SimConfig.__dataclass_fields__)


@functools.lru_cache(maxsize=16)
def _sim_config(items: tuple[tuple[str, object], ...]) -> SimConfig:
    return context().sim_config if not items else load_sim_config(**dict(items))


@dataclass(frozen=True)
class RunSettings:
    """Overrides of config/controller.yaml and config/simulator.yaml for a run (hashable, picklable: it
    travels to the worker processes). Empty = the config files as they are. ``perturbation`` (issue 14):
    the plant's model error, friction and sensing, given to the simulator only (None: none).
    ``full_trials`` (issue 19): run every survival trial in full (no early stop); not part of
    :meth:`describe` (an early-stopped trial has the outcome of the full one: ``EarlyStop``)."""

    controller: tuple[tuple[str, object], ...] = ()
    simulator: tuple[tuple[str, object], ...] = ()
    perturbation: PlantPerturbation | None = None
    full_trials: bool = False    # True: no early stop (every survival trial runs in full), whatever config/studies.yaml says

    def sim_config(self) -> SimConfig:
        return _sim_config(self.simulator)

    def ctrl_config(self, mode: str) -> ControllerConfig:
        """The controller settings for ``mode``; the period is the simulator's control period. Read again
        whenever ``config/controller.yaml`` or ``config/simulator.yaml`` changed (their modification
        times key a per-process cache: a YAML parse costs more than a failing simulation)."""
        return _ctrl_config(mode, self.controller, self.simulator, _config_stamp())

    def describe(self) -> dict:
        """JSON-ready: the overrides and the effective settings (every key of both files)."""
        ctrl = asdict(self.ctrl_config(MODES[0]))
        del ctrl["mode"]
        sim = asdict(self.sim_config())
        if sim["plant"] == "rigid":   # the MuJoCo plant's keys do not act on the rigid one: left out, so the rigid
            sim = {k: v for k, v in sim.items() if k != "plant" and not k.startswith("mujoco_")}   # fingerprints stay
        out = {"overrides": {**dict(self.controller), **dict(self.simulator)},
               "controller": ctrl, "simulator": sim}
        if self.perturbation is not None and not self.perturbation.is_zero:   # (absent: nominal plant)
            out["perturbation"] = self.perturbation.as_dict()
        return out


def _config_stamp() -> tuple[int, int]:
    d = default_config_dir()
    return (os.stat(d / "controller.yaml").st_mtime_ns, os.stat(d / "simulator.yaml").st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _ctrl_config(mode: str, controller: tuple, simulator: tuple, stamp: tuple[int, int]) -> ControllerConfig:
    return load_controller_config(mode=mode, period=_sim_config(simulator).control_period, **dict(controller))


def _scalar(text: str) -> object:
    """A YAML scalar, with numbers such as ``5e-4`` that YAML 1.1 reads as words taken as numbers."""
    v = yaml.safe_load(text)
    if isinstance(v, str):
        for conv in (int, float):
            try:
                return conv(v)
            except ValueError:
                pass
    return v


def _parse_value(key: str, text: str) -> object:
    try:
        v = _scalar(text)
    except yaml.YAMLError as exc:
        raise OverrideError(f"--set {key}={text}: the value does not parse: {exc}") from exc
    if not isinstance(v, (bool, int, float, str)):
        raise OverrideError(f"--set {key}={text}: expected a number, true/false or a word, got {text!r}")
    return v


def parse_overrides(items: list[str] | tuple[str, ...] = (), observer: str | bool | None = None,
                    full_trials: bool = False) -> RunSettings:
    """``RunSettings`` from ``KEY=VALUE`` strings and the observer switch ("on"/"off"/bool/None = config
    file). Raises :class:`OverrideError` naming an unknown or repeated key or a malformed item; a value
    out of range raises the config's own error (ControllerConfigError / SimConfigError, naming the key)
    when :func:`check_settings` builds the configs."""
    ctrl: dict[str, object] = {}
    sim: dict[str, object] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise OverrideError(f"--set expects KEY=VALUE, got {item!r}")
        if key in ctrl or key in sim:
            raise OverrideError(f"--set {key}: given twice")
        if key in CONTROLLER_KEYS:
            ctrl[key] = _parse_value(key, text)
        elif key in SIMULATOR_KEYS:
            sim[key] = _parse_value(key, text)
        elif key in ("mode", "period"):
            raise OverrideError(f"--set {key}: not overridable here ("
                                + ("use the subcommand's --mode" if key == "mode" else "set control_period")
                                + ")")
        else:
            raise OverrideError(f"--set {key}: unknown setting {key!r}; controller keys: {', '.join(CONTROLLER_KEYS)}; "
                                f"simulator keys: {', '.join(SIMULATOR_KEYS)}")
    if observer is not None:
        on = observer if isinstance(observer, bool) else {"on": True, "off": False}.get(str(observer))
        if on is None:
            raise OverrideError(f"--observer must be on or off, got {observer!r}")
        if "disturbance_observer" in ctrl and ctrl["disturbance_observer"] != on:
            raise OverrideError("disturbance_observer: --observer and --set disagree")
        ctrl["disturbance_observer"] = on
    return RunSettings(tuple(sorted(ctrl.items())), tuple(sorted(sim.items())), full_trials=bool(full_trials))


def parse_perturbation(items: list[str] | tuple[str, ...] = ()) -> PlantPerturbation | None:
    """A ``PlantPerturbation`` from ``FIELD=VALUE`` strings (values parsed as YAML scalars; None when
    empty). Raises :class:`OverrideError` for a malformed or repeated item and ``PerturbationError``
    naming a bad field or value."""
    vals: dict[str, object] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise OverrideError(f"--perturb expects FIELD=VALUE, got {item!r}")
        if key in vals:
            raise OverrideError(f"--perturb {key}: given twice")
        try:
            v = _scalar(text)
        except yaml.YAMLError as exc:
            raise OverrideError(f"--perturb {key}={text}: the value does not parse: {exc}") from exc
        vals[key] = v
    return PlantPerturbation.from_dict(vals) if vals else None


def check_settings(settings: RunSettings) -> dict:
    """Build both configs once (a bad value raises the config's error naming the key); the description."""
    return settings.describe()


def print_settings(desc: dict) -> None:
    ov = desc["overrides"]
    print("overrides: " + (", ".join(f"{k}={v}" for k, v in ov.items()) if ov else "none (config files as they are)"))
    c = desc["controller"]
    print("controller: " + ", ".join(f"{k}={c[k]}" for k in c))
    s = desc["simulator"]
    print("simulator: " + ", ".join(f"{k}={s[k]}" for k in s))
    if "perturbation" in desc:
        print("plant perturbation: " + PlantPerturbation.from_dict(desc["perturbation"]).label())


DEFAULT_SETTINGS = RunSettings()


def _run(steps: int, mode: str, pushes: tuple[Push, ...] = (), *, integration_rate: bool = False,
         observer: bool | None = None, keep_qp: bool = False, settings: RunSettings = DEFAULT_SETTINGS,
         keep_records: bool = True, on_impact=None, pool: runner.LoopPool | None = None) -> RunResult:
    ctx = context()
    if observer is not None:
        settings = RunSettings(tuple(sorted({**dict(settings.controller), "disturbance_observer": observer}.items())),
                               settings.simulator, settings.perturbation, settings.full_trials)
    ccfg = settings.ctrl_config(mode)
    return runner.run(steps=steps, mode=mode, pushes=pushes, sim_config=settings.sim_config(), ctrl_config=ccfg,
                      family=ctx.family, desc=ctx.desc, integration_rate=integration_rate, keep_qp=keep_qp,
                      perturbation=settings.perturbation, keep_records=keep_records, on_impact=on_impact, pool=pool)


# ------------------------------------------------------------------------------------------ summaries
def joint_errors(result: RunResult, family: GaitFamily | None = None) -> np.ndarray:
    """(N, 6) tracking errors q_d(p, tau, lambda) - q at every control instant [rad] (paper joint order;
    lambda = 0 outside modes lambda and all)."""
    fam = family if family is not None else context().family
    return np.array([fam.evaluate_torso(s.p, s.tau, s.lam).q - r.q for s, r in zip(result.statuses, result.records)])


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
        "sim_time": float(rec[-1].t_end) if rec else 0.0,
        "max_tracking_error": float(err.max()) if err.size else 0.0,
        "max_tracking_error_before_first_impact": float(err[t < first].max()) if np.any(t < first) else 0.0,
        "max_tracking_error_after_first_impact": float(err[t >= first].max()) if np.any(t >= first) else 0.0,
        "p_min": float(p.min()), "p_max": float(p.max()),
        "max_p_excursion": float(np.max(np.abs(p - fam.p_d))),
        "tau_max": float(tau.max()),
        "tau_dot_min": float(taud.min()), "tau_dot_max": float(taud.max()),
        # the observer's |force estimate| over the run [N] (issue 22: without a push it is noise and model error)
        "force_estimate_abs_p50": float(np.percentile(np.abs([s.force_estimate for s in st]), 50)) if st else 0.0,
        "force_estimate_abs_p95": float(np.percentile(np.abs([s.force_estimate for s in st]), 95)) if st else 0.0,
        "force_estimate_abs_max": float(np.max(np.abs([s.force_estimate for s in st]))) if st else 0.0,
        "max_tau_dot_excursion": float(np.max(np.abs(taud - 1.0))),
        "max_abs_l": float(np.max(np.abs(cop[ok]))) if np.any(ok) else math.nan,
        "l_at_fall": float(rec[-1].cop) if result.fallen else None,
        "final_p": float(p[-1]), "final_tau_dot": float(taud[-1]),
        "max_abs_lambda": float(np.max(np.abs([s.lam for s in st]))) if st else 0.0,
        "final_lambda": float(st[-1].lam) if st else 0.0,
        "impact_times": impacts,
        "step_durations": [float(b - a) for a, b in zip([0.0] + impacts[:-1], impacts)],
        "qp_status_counts": qp_counts,
    }
    if push_end is not None:
        out["impacts_after_push"] = int(sum(1 for x in impacts if x >= push_end))
    return out


# ------------------------------------------------------------------------------------------ walk
def walk(steps: int = 10, mode: str = "both", settings: RunSettings = DEFAULT_SETTINGS) -> dict:
    """Undisturbed walking, controller at the integration rate and at the control period (ZOH)."""
    out = {"steps": steps, "mode": mode, "explanation": ZOH_EXPLANATION}
    pert = settings.perturbation
    for key, ir in (("integration_rate", True), ("zoh", False)):
        if ir and pert is not None and not pert.sensing_is_perfect:
            out[key] = None      # a torque function sees the true state at every RK4 stage: no sensor model
            continue
        t0 = time.perf_counter()
        res = _run(steps, mode, integration_rate=ir, settings=settings)
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
        if s is None:
            print(f"{label:<18} (not run: the sensor model needs held torques)")
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
        print(f"force estimate |F| ({label}): p50 {s['force_estimate_abs_p50']:.1f} N, p95 "
              f"{s['force_estimate_abs_p95']:.1f} N, max {s['force_estimate_abs_max']:.1f} N")
    print(r["explanation"])


# ------------------------------------------------------------------------------------------ push
def push_step_index(start: float, duration: float, T: float) -> int:
    """Index of the (nominal) step during which the push ends (0 = first step)."""
    return int(math.floor((start + duration) / T))


def push_run(force: float, duration: float = DEFAULT_DURATION, start: float = DEFAULT_START, mode: str = "both",
             height: float | None = None, steps_after: int = SURVIVAL_STEPS, keep_qp: bool = False,
             settings: RunSettings = DEFAULT_SETTINGS, keep_records: bool = True, on_impact=None,
             pool: runner.LoopPool | None = None) -> RunResult:
    """One push (+ forward, i.e. on the back), then ``steps_after`` more steps. ``keep_records`` False: the
    outcome only (``runner.run``), as a survival trial needs; ``on_impact``: ``runner.run``'s early stop;
    ``pool``: ``runner.run``'s reuse of the loop and of the walk up to the push."""
    T = context().family.T
    steps = push_step_index(start, duration, T) + 1 + steps_after
    return _run(steps, mode, (Push(start, duration, float(force), height),), keep_qp=keep_qp, settings=settings,
                keep_records=keep_records, on_impact=on_impact, pool=pool)


def noisy_sensing(settings: RunSettings) -> bool:
    """The run's sensors are noisy or quantised (survival then uses the noise band for tau')."""
    p = settings.perturbation
    return p is not None and bool(p.noise_q or p.noise_qd or p.encoder_bits or p.noise_pitch)


def model_error(settings: RunSettings) -> bool:
    """The run's plant differs from the controller's description in its masses, centres of mass or inertias
    (friction, sensing and delay are not model error here)."""
    p = settings.perturbation
    return p is not None and not replace(p, mu=None).model_is_nominal


@functools.lru_cache(maxsize=32)
def reference_p(mode: str, steps: int, settings: RunSettings) -> float:
    """p [m] at the end of the unpushed walk of ``steps`` impacts with ``settings`` (the survival criterion's
    reference under model error, module docstring); NaN when that walk falls."""
    res = _run(steps, mode, (), settings=settings, keep_records=False)
    return math.nan if res.fallen else float(res.statuses[-1].p)


def survival(result: RunResult, push_end: float, steps_after: int = SURVIVAL_STEPS, noisy: bool = False,
             p_ref: float | None = None) -> tuple[bool, str]:
    """(survived, reason) by the criterion of the module docstring (``noisy``: the band for noisy sensors;
    ``p_ref``: the unpushed walk's p under model error, None: p_d)."""
    fam = context().family
    tau_tol = TAU_DOT_TOL_NOISE if noisy else TAU_DOT_TOL
    if result.fallen:
        return False, f"fell: {result.fall_cause} at t = {result.fall_time:.4f} s"
    after = sum(1 for i in result.impacts if i.t >= push_end)
    if after < steps_after:
        return False, f"only {after} steps after the push (time limit)"
    last = result.statuses[-1]
    if p_ref is not None:
        if not abs(last.p - p_ref) <= P_TOL:
            return False, f"p = {last.p:.5f} m not back to the unpushed walk's {p_ref:.5f} m (> {P_TOL})"
    elif abs(last.p - fam.p_d) > P_TOL:
        return False, f"p = {last.p:.5f} m not back to p_d (|p - p_d| > {P_TOL})"
    if abs(last.tau_dot - 1.0) > tau_tol:
        return False, f"tau' = {last.tau_dot:.5f} not back to 1 (> {tau_tol})"
    return True, "survived"


def push_experiment(force: float, duration: float = DEFAULT_DURATION, start: float = DEFAULT_START,
                    mode: str = "both", height: float | None = None, figures: str | Path | None = None,
                    settings: RunSettings = DEFAULT_SETTINGS) -> dict:
    res = push_run(force, duration, start, mode, height, settings=settings)
    ok, why = survival(res, start + duration, noisy=noisy_sensing(settings), p_ref=_p_ref(mode, start, duration, settings))
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
    if r["mode"] in TORSO_MODES:
        print(f"  max |lambda| = {r['max_abs_lambda']:.5f} rad, final lambda = {r['final_lambda']:.6f} rad")
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

    if result.statuses and result.statuses[0].mode in TORSO_MODES:      # the torso parameter (issue 21)
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


# ------------------------------------------------------------------------------------------ max push
class StudySettingsError(ValueError):
    """``config/studies.yaml`` holds a value out of range (the message names the key)."""


@dataclass(frozen=True)
class EarlyStop:
    """When a survival trial's outcome is decided (issue 19; ``config/studies.yaml``).

    Once a control period after an impact at or after the end of the push has completed without a fall
    (``runner.run``'s ``on_impact``: the controller's own post-impact torque has acted and passed the
    plant's checks), the trial is *decided* (survived) when the walk is back on the preferred gait: the
    plant's state (q, q') at that instant t within ``q`` [rad] and ``qd`` [rad/s] (max norm) of the
    gait's orbit at the same time into the step, q_d(p_d, t - t_impact) and dq_d/dtau(p_d, t - t_impact)
    (``GaitFamily.evaluate``; the same in either stance), and the controller's parameters as last decided
    within ``p`` [m] of p_d, ``p_dot`` [m/s] of 0, ``tau_dot`` of 1, its observer's force estimate within
    ``force`` [N] of 0, and its torso offset (issue 21, modes lambda and all; 0 in the others) within ``lam``
    [rad] and ``lam_dot`` [rad/s] of 0: the offset's profile phi vanishes at the impact, so q and q' do not
    show lambda there, and in mode lambda p and tau' never leave the gait's. The rest of the trial would be the undisturbed walk from such a state, which walks
    on and ends with p, tau' inside :data:`P_TOL`, :data:`TAU_DOT_TOL` (measured: docs/capability_map.md,
    "Early stop"). Applied to the nominal plant with ideal sensors only (the measurement's plant): a
    perturbed plant's trial runs in full."""

    enabled: bool
    q: float
    qd: float
    p: float
    p_dot: float
    tau_dot: float
    force: float
    lam: float
    lam_dot: float

    KEYS = ("early_stop", "early_stop_q", "early_stop_qd", "early_stop_p", "early_stop_p_dot",
            "early_stop_tau_dot", "early_stop_force", "early_stop_lambda", "early_stop_lambda_dot")

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> "EarlyStop":
        p = Path(path) if path is not None else default_config_dir() / "studies.yaml"
        v = read_settings(p, cls.KEYS)
        if not isinstance(v["early_stop"], bool):
            raise StudySettingsError(f"{p}: 'early_stop' must be true or false, got {v['early_stop']!r}")
        for k in cls.KEYS[1:]:
            x = v[k]
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not (math.isfinite(x) and x > 0):
                raise StudySettingsError(f"{p}: '{k}' must be a finite number > 0, got {x!r}")
        return cls(v["early_stop"], *(float(v[k]) for k in cls.KEYS[1:]))

    def decided(self, sim, ctrl, push_end: float, family: GaitFamily) -> bool:
        """The criterion above, on the latest impact of ``sim``, its state now and the state of ``ctrl``."""
        imp = sim.impact_log[-1]
        if imp.t < push_end:
            return False
        s = ctrl.state
        if not (abs(s.p - family.p_d) <= self.p and abs(s.p_dot) <= self.p_dot and abs(s.tau_dot - 1.0) <= self.tau_dot
                and abs(ctrl.force_estimate) <= self.force):
            return False
        mem = ctrl.memory       # the torso offset lambda, lambda' at the last decision (issue 21; 0 outside its modes)
        if not (abs(mem[M_.lam]) <= self.lam and abs(mem[M_.lam_dot]) <= self.lam_dot):
            return False
        q, qd = sim.fm.paper_from_state(sim.x, sim.v, sim.stance)
        g = family.evaluate(family.p_d, sim.t - imp.t)
        return bool(np.max(np.abs(q - g.q)) <= self.q and np.max(np.abs(qd - g.dq_dtau)) <= self.qd)


@functools.lru_cache(maxsize=4)
def _early_stop(stamp: int) -> EarlyStop:
    return EarlyStop.load()


def early_stop() -> EarlyStop:
    """``config/studies.yaml``'s early stop, read again whenever the file changed."""
    return _early_stop(os.stat(default_config_dir() / "studies.yaml").st_mtime_ns)


@functools.lru_cache(maxsize=1)
def loop_pool() -> runner.LoopPool:
    """This process's :class:`runner.LoopPool` (the survival trials' plants, controllers and walks to the
    push onsets, reused: bit-identical outcomes, tested)."""
    return runner.LoopPool()


def survives(force: float, mode: str, duration: float = DEFAULT_DURATION, start: float = DEFAULT_START,
             height: float | None = None, settings: RunSettings = DEFAULT_SETTINGS,
             pool: runner.LoopPool | None | bool = True) -> dict:
    """One survival trial (JSON-ready): force, survived, reason, and a few numbers. With the early stop
    (``config/studies.yaml``, unless ``settings.full_trials`` or a perturbed plant) the trial ends at the
    first impact where its outcome is decided (:class:`EarlyStop`): survived, ``decided_at_step`` = the
    impacts walked by then; otherwise ``decided_at_step`` is None (the trial ran in full). Under sensor noise
    survival uses the noise band (``survival(noisy=True)``). ``pool`` True: this process's
    :func:`loop_pool` (the loop and the walk up to the push reused, the outcome bit-identical); a
    ``runner.LoopPool``; None or False: a new plant and controller, walked from t = 0."""
    end = start + duration
    if pool is True:
        pool = loop_pool()
    elif pool is False:
        pool = None
    on_impact = None
    fired: list[int] = []
    es = None if settings.full_trials else early_stop()
    if es is not None and es.enabled and (settings.perturbation is None or settings.perturbation.is_zero):
        fam = context().family

        def stop_if_decided(sim, ctrl) -> bool:
            if es.decided(sim, ctrl, end, fam):
                fired.append(sim.impact_count)
                return True
            return False
        on_impact = stop_if_decided
    res = push_run(force, duration, start, mode, height, settings=settings, keep_records=False, on_impact=on_impact,
                   pool=pool)
    decided = bool(fired) and not res.fallen
    if decided:
        ok, why = True, "survived"
    else:
        ok, why = survival(res, end, noisy=noisy_sensing(settings), p_ref=_p_ref(mode, start, duration, settings))
    return {"force": float(force), "mode": mode, "survived": ok, "reason": why,
            "fall_cause": res.fall_cause, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
            "steps_walked": int(res.steps_walked), "decided_at_step": int(res.steps_walked) if decided else None}


def _p_ref(mode: str, start: float, duration: float, settings: RunSettings) -> float | None:
    """The survival criterion's p reference: the unpushed walk's (:func:`reference_p`) under model error,
    None (p_d) otherwise."""
    if not model_error(settings):
        return None
    steps = push_step_index(start, duration, context().family.T) + 1 + SURVIVAL_STEPS
    return reference_p(mode, steps, settings)


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
                sign: float = 1.0, settings: RunSettings = DEFAULT_SETTINGS) -> tuple[float, float, list[dict]]:
    """Bisect the force magnitudes [lo (survives), hi (fails)] down to ``resolution`` [N]; the push is
    applied with ``sign`` (+1 forward). Returns (lo, hi, trials)."""
    trials = []
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        r = dict(survives(sign * mid, mode, duration, start, height, settings), force=mid)
        trials.append(r)
        if progress:
            progress()
        if r["survived"]:
            lo = mid
        else:
            hi = mid
    return lo, hi, trials


def _bisect_task(args: tuple) -> tuple[str, float, float, list[dict]]:
    mode, lo, hi, resolution, duration, start, height, sign, settings = args
    a, b, tr = bisect_edge(mode, lo, hi, resolution, duration, start, height, sign=sign, settings=settings)
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


def max_push_modes(modes: tuple[str, ...], resolution: float = 5.0, fmax: float = 2000.0, coarse: float = 50.0,
                   duration: float = DEFAULT_DURATION, start: float = DEFAULT_START, height: float | None = None,
                   workers: int = 1, progress: bool = True, sign: float = 1.0,
                   settings: RunSettings = DEFAULT_SETTINGS) -> dict[str, dict]:
    """Largest survivable push for each mode: coarse scan (all modes' trials together, over the studies'
    executor with ``workers`` processes), then a bisection of each mode's lowest failing edge (modes in
    parallel). Every result carries ``settings`` (the overrides and the effective controller/simulator
    settings)."""
    described = check_settings(settings)   # a bad override fails here, before any worker starts
    forces = coarse_forces(fmax, coarse)
    tasks = [(sign * f, m, duration, start, height, settings) for m in modes for f in forces]
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
                bis_out[m] = bisect_edge(m, lo, hi, res_, d, s0, h, progress=bar, sign=sg, settings=st)
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
        results[m].update(duration=duration, start=start, height=height, settings=described,
                          noisy_sensing=noisy_sensing(settings),
                          p_reference=_p_ref(m, start, duration, settings))
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
    h = r0["settings"]["simulator"]["push_height"] if r0["height"] is None else r0["height"]
    print(f"(push {r0['direction']} for {r0['duration']:g} s from t = {r0['start']:g} s at {h:g} m above the hip; "
          f"coarse step {r0['coarse_step']:g} N up to {r0['scan_max']:g} N, edge bisected to {r0['resolution']:g} N; "
          f"survival = no fall for {SURVIVAL_STEPS} steps after the push, "
          + (f"|p - p_d| <= {P_TOL} m" if r0.get("p_reference") is None
             else f"|p - p_ref| <= {P_TOL} m (p_ref = {r0['p_reference']:.5f} m: the unpushed walk's, model error)")
          + " and "
          f"|tau' - 1| <= {TAU_DOT_TOL_NOISE if r0.get('noisy_sensing') else TAU_DOT_TOL} at the end"
          + (", the band for noisy sensors)" if r0.get("noisy_sensing") else ")"))


# ------------------------------------------------------------------------------------------ probe
@dataclass(frozen=True)
class ProbeResult:
    """A closed-loop run plus what ``runner.run`` does not return: the controller's force estimate."""

    result: RunResult
    force_estimate: np.ndarray    # (N,) the observer's horizontal torso force at each period [N] (0 when off)


def probe_run(force: float, mode: str = "both", duration: float = DEFAULT_DURATION, start: float = DEFAULT_START,
              height: float | None = None, settings: RunSettings = DEFAULT_SETTINGS,
              until: float | None = None, steps: int | None = None) -> ProbeResult:
    """The closed loop of ``runner.run`` (same order of calls, so bit-identical records; tested) with one
    push, also recording ``AdaptiveController.force_estimate`` after each decision. Stops at a fall, after
    ``steps`` impacts (default: as ``push_run``), or once the simulated time reaches ``until`` [s]."""
    ctx = context()
    scfg = settings.sim_config()
    ccfg = settings.ctrl_config(mode)
    n_steps = steps if steps is not None else push_step_index(start, duration, ctx.family.T) + 1 + SURVIVAL_STEPS
    sim = make_plant(scfg.plant, ctx.desc, scfg, settings.perturbation)   # rigid or MuJoCo (--set plant=...)
    ctrl = AdaptiveController(ccfg, ctx.family, ctx.desc)
    q0, qd0 = ctx.family.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    sim.schedule_push(start, duration, float(force), height)
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


def probe(force: float, mode: str = "both", duration: float = DEFAULT_DURATION, start: float = DEFAULT_START,
          height: float | None = None, settings: RunSettings = DEFAULT_SETTINGS, before: float = 0.002,
          after: float = 0.010) -> dict:
    """One push seen from the controller, period by period over [start - before, end + after] (or to the
    fall). Per period (values at its start t): the true push and the observer's estimate [N]; the QP
    status; the tightest of the 17 true rows (margins scaled by the model's row scales, evaluated with the
    controller's predicted reaction) and its margin; the predicted ground reaction R (the controller's
    B w + h_b, with the estimate when the observer is on) against the simulator's actual wrench (F_x, F_z)
    under the same torque and push [N]; l predicted (Gamma_1 / R_y predicted) and actual (m / F_z) [m];
    p'' [m/s^2] and tau'' [1/s]. Plus the survival verdict of the full run (up to SURVIVAL_STEPS after)."""
    pr = probe_run(force, mode, duration, start, height, settings)
    res = pr.result
    end = start + duration
    ok, why = survival(res, end)
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
        "settings": check_settings(settings), "survived": ok, "reason": why,
        "fall_cause": res.fall_cause or None, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
        "fall_detail": res.fall_detail or None,
        "max_l_error_during_push": max((abs(r["l_act"] - r["l_pred"]) for r in during), default=None),
        "periods": rows,
    }


def print_probe(r: dict) -> None:
    print(f"probe: {r['force']:g} N for {r['duration']:g} s at t = {r['start']:g} s, mode {r['mode']}: "
          f"{'SURVIVED' if r['survived'] else 'FAILED'} ({r['reason']})")
    if r["fall_detail"]:
        print(f"  fall: {r['fall_detail']}")
    print(f"{'t [s]':>7} {'imp':>3} {'push':>6} {'F_est':>7} {'QP':>13} {'tightest':>15} {'margin':>8} {'Rx pred':>8} {'Rx act':>8} "
          f"{'Ry pred':>8} {'Ry act':>8} {'l pred':>7} {'l act':>7} {'p_dd':>8} {'tau_dd':>8} {'p':>7} {'tau_d':>6}")
    for x in r["periods"]:
        print(f"{x['t']:7.4f} {x['impacts']:3d} {x['push']:6.1f} {x['estimate']:7.1f} {x['qp_status']:>13} {x['tightest']:>15} "
              f"{x['tightest_margin']:8.2f} {x['R_pred'][0]:8.1f} {x['R_act'][0]:8.1f} {x['R_pred'][1]:8.1f} "
              f"{x['R_act'][1]:8.1f} {x['l_pred']:7.4f} {x['l_act']:7.4f} {x['p_ddot']:8.3f} {x['tau_ddot']:8.3f} "
              f"{x['p']:7.4f} {x['tau_dot']:6.3f}")
    if r["max_l_error_during_push"] is not None:
        print(f"max |l act - l pred| during the push: {r['max_l_error_during_push']:.4f} m")


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


def _add_settings_args(a: argparse.ArgumentParser) -> None:
    a.add_argument("--observer", choices=("on", "off"), default=None,
                   help="the controller's disturbance observer (default: config/controller.yaml); "
                        "off = the paper's controller as published")
    a.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of config/controller.yaml or config/simulator.yaml (repeatable)")
    a.add_argument("--full-trials", action="store_true",
                   help="run every survival trial in full (no early stop: config/studies.yaml early_stop)")
    a.add_argument("--perturb", dest="perturb", action="append", default=[], metavar="FIELD=VALUE",
                   help="a field of the plant's PlantPerturbation, e.g. torso_mass_scale=0.8, noise_q=5e-4, "
                        "encoder_bits=14, delay=2 (repeatable; biped_sim.plant.perturbation)")


#: the modes of ``table`` by default: the paper's four
TABLE_MODES: tuple[str, ...] = ("none", "tau", "p", "both")


def _modes_arg(text: str) -> tuple[str, ...]:
    """``--modes none,wbc,...``: known modes, each once, at least one (argparse names the option)."""
    modes = tuple(m.strip() for m in text.split(",") if m.strip())
    bad = [m for m in modes if m not in MODES]
    if not modes or bad or len(set(modes)) != len(modes):
        raise argparse.ArgumentTypeError(f"expected distinct modes out of {','.join(MODES)}, got {text!r}")
    return modes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/experiment", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("walk", help="undisturbed walk: integration-rate vs ZOH controller")
    a.add_argument("--steps", type=int, default=10)
    a.add_argument("--mode", choices=MODES, default="both")
    a.add_argument("--json", type=Path)
    _add_settings_args(a)
    for name, hlp in (("push", "one push, with figures like the paper's Figs. 3-7"),
                      ("probe", "one push: the controller's view period by period while it acts")):
        a = sub.add_parser(name, help=hlp)
        a.add_argument("--force", type=float, default=250.0, help="[N], + forward (on the back)")
        a.add_argument("--duration", type=float, default=DEFAULT_DURATION)
        a.add_argument("--start", type=float, default=DEFAULT_START)
        a.add_argument("--height", type=float, default=None,
                       help="above the hip [m] (default: push_height of config/simulator.yaml)")
        a.add_argument("--mode", choices=MODES, default="both")
        if name == "push":
            a.add_argument("--figures", type=Path, help="directory for the PNG figures")
        else:
            a.add_argument("--after", type=float, default=0.010, help="print this long after the push end [s]")
        a.add_argument("--json", type=Path)
        _add_settings_args(a)
    for name, hlp in (("max-push", "largest survivable push for one mode"),
                      ("table", "max-push for the four modes, or for --modes")):
        a = sub.add_parser(name, help=hlp)
        if name == "max-push":
            a.add_argument("--mode", choices=MODES, default="both")
        else:
            a.add_argument("--modes", type=_modes_arg, default=TABLE_MODES,
                           help=f"comma-separated modes (default {','.join(TABLE_MODES)}; any of {','.join(MODES)})")
        a.add_argument("--resolution", type=float, default=5.0, help="bisection resolution [N]")
        a.add_argument("--max", type=float, default=2000.0, help="largest force scanned [N]")
        a.add_argument("--coarse", type=float, default=50.0, help="coarse scan step [N]")
        a.add_argument("--duration", type=float, default=DEFAULT_DURATION)
        a.add_argument("--start", type=float, default=DEFAULT_START)
        a.add_argument("--height", type=float, default=None,
                       help="above the hip [m] (default: push_height of config/simulator.yaml)")
        a.add_argument("--backward", action="store_true", help="push backwards (on the chest) instead")
        a.add_argument("--workers", type=int, default=1, help="processes (each builds its own models)")
        a.add_argument("--json", type=Path)
        _add_settings_args(a)
    args = ap.parse_args(argv)
    provenance.track(getattr(args, "json", None), getattr(args, "figures", None), args=args, argv=argv)   # record of each file written (results/README.md)
    try:
        settings = parse_overrides(args.overrides, args.observer, args.full_trials)
        pert = parse_perturbation(args.perturb)
        if pert is not None:
            settings = replace(settings, perturbation=pert)
        described = check_settings(settings)
    except (OverrideError, ControllerConfigError, SimConfigError, PerturbationError) as exc:
        ap.error(str(exc))
    print(f"scripts/experiment {' '.join(sys.argv[1:] if argv is None else argv)}")
    print_settings(described)
    if args.cmd == "walk":
        r = walk(args.steps, args.mode, settings)
        print_walk(r)
    elif args.cmd == "push":
        r = push_experiment(args.force, args.duration, args.start, args.mode, args.height, args.figures, settings)
        print_push(r)
    elif args.cmd == "probe":
        r = probe(args.force, args.mode, args.duration, args.start, args.height, settings, after=args.after)
        print_probe(r)
    else:
        modes = (args.mode,) if args.cmd == "max-push" else args.modes
        t0 = time.perf_counter()
        res = max_push_modes(modes, args.resolution, args.max, args.coarse, args.duration, args.start,
                             height=args.height, workers=max(1, args.workers),
                             sign=-1.0 if args.backward else 1.0, settings=settings)
        print_max_push(res)
        r = {"modes": res, "wall_time": time.perf_counter() - t0}
        if args.cmd == "table":
            r["ordering"] = ordering_finding(res)
            print(r["ordering"])
        print(f"wall time {r['wall_time']:.1f} s")
    if isinstance(r, dict):
        r["settings"] = described
        r["argv"] = list(sys.argv[1:] if argv is None else argv)
    _dump(args.json, r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
