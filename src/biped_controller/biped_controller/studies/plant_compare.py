"""Rigid vs MuJoCo plant side by side: the tables of ``docs/mujoco_plant.md`` that no other study
prints. Pure Python on ``runner.run`` (no ROS). The one-off comparisons that once lived here (``falls``, the
measurement behind the MuJoCo fall thresholds; ``cmap`` and ``robustness``, two plants' maps and robustness rows
side by side) are ``python -m lab.plant_compare`` (``lab/README.md``). Usage::

    python -m biped_controller.studies.plant_compare walk  [--steps 20] [--modes both tau p none] [--controller NAME]
                                                        [--profile P] [--json F]
    python -m biped_controller.studies.plant_compare pushes [--dir results/mujoco_plant] [--reuse] [--profile P]
                                                        [--controller NAME ...]
    python -m biped_controller.studies.plant_compare push --force 600 [--mode both | --controller NAME]
                                                       [--observer on|off] [--profile P]
    python -m biped_controller.studies.plant_compare fingerprint

``fingerprint``: one sha256 over everything the MuJoCo plant records in a fixed set of runs (walks, pushes in
three modes, a backward push, a fall, the classical controller's fall, sensor noise and delay, a torque law
evaluated at every MuJoCo step): every field of every ``StepRecord``, ``ImpactRecord`` and controller status
(hashed as ``studies.fingerprint`` hashes the rigid plant's), the outcome, and the plant's contact diagnostics
(each counter and the touchdown forces). A change to the plant that must not change behaviour (a speed-up)
prints the same last line before and after, on the same machine. Each run but the integration-rate one is
also made through the controller interface (the mode's built-in class on the generic loop): its records,
impacts and outcome must equal the compiled path's bit for bit (compared, not hashed; exit 1 otherwise).

``push``: one push (25 ms at t = 0.2315 s or ``--start``, 5 steps after it) on both plants: the outcome, and on MuJoCo the
contact diagnostics over the run: what the rigid plant would have declared a fall (the friction cone, the
centre of pressure at an edge, an unloaded stance foot) and how far the foot rolled and slid.

``pushes``: the four-mode max-push table (``scripts/experiment table``: forward, 25 ms at t = 0.2315 s) for
both plants, observer on and off, side by side: the survival boundary (``trial.survival``: no fall for 10
steps, then p and tau' within the band of the unpushed walk) and the *no-fall edge* (the largest force below
the lowest one that fell; the first falling force and its cause), both bisected to the table's resolution. Runs
``scripts/experiment table --workers 2 --observer O --set plant=P --json DIR/table_P_observer_O.json`` for
each (P, O), or with ``--reuse`` reads those files.

``walk``, ``push`` and ``pushes`` take ``--profile NAME`` (config/profiles/); the plant (and in ``push`` and
``pushes`` the observer) is set over it.

``walk``: per plant and mode, an undisturbed walk of ``--steps`` steps: outcome, max tracking error [rad],
step times [s] (mean, min, max over the steps walked), energy per step: the motors' absolute work
sum_k sum_i |Gamma_i q'_i| dt [J] and the paper's criterion C = (1/p) int Gamma^T Gamma dt [N^2 m^2 s / m] per
step (p = the step length the impacts give), final tau'; on MuJoCo the contact diagnostics (time the stance
foot was unloaded, its centre of pressure within 1 mm of heel or toe, on the friction cone, pitched beyond
1 mrad, its largest pitch and slip).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from biped_sim.plant.config import load_sim_config
from biped_sim.plant.push import Push
from biped_controller.core.control.config import MODES
from biped_controller.closed_loop import runner
from biped_controller.studies.trial.args import (SETTINGS_ERRORS, StudyArgumentParser, add_modes_arg, add_robot_arg, controller_arg, finite_float,
                                                 nonnegative_float, positive_int, profile_arg)
from biped_controller.studies.trial.controller import resolve
from biped_controller.studies.trial.settings import DEFAULT_PROFILE, RunSettings, parse_overrides
from biped_controller.studies import provenance

PLANTS = ("rigid", "mujoco")


def _stance_pitch(records) -> np.ndarray:
    X = np.array([r.x for r in records])
    st = np.array([r.stance for r in records])
    return np.where(st == 0, X[:, 2] + X[:, 3:6].sum(1), X[:, 2] + X[:, 6:9].sum(1))


def _with_plant(settings: RunSettings, plant: str) -> RunSettings:
    """``settings`` with the simulator setting ``plant`` (rigid or mujoco)."""
    return replace(settings, simulator=tuple(sorted({**dict(settings.simulator), "plant": plant}.items())))


def walk_row(plant: str, mode: str, steps: int, settings: RunSettings | None = None) -> dict:
    """One undisturbed walk of the controller ``mode`` on ``plant`` with ``settings`` (None: the configuration
    files; ``TrialController.walk``; JSON-ready row, see the module docstring). The tracking error [rad] and
    the final p [m] and tau' [-] are the status keys ``max_tracking_error``, ``p``, ``tau_dot`` (None where
    the controller does not report them)."""
    on_plant = _with_plant(settings if settings is not None else RunSettings(), plant)
    from biped_sim.plant import mujoco as pm
    plants = []
    orig = pm.MujocoPlant.reset

    def grab(self, *a, **k):       # the plant object, for its contact diagnostics
        plants.append(self)
        return orig(self, *a, **k)
    pm.MujocoPlant.reset = grab
    try:
        r = resolve(mode).walk(steps, on_plant)
    finally:
        pm.MujocoPlant.reset = orig
    track = [abs(float(x)) for x in r.series("max_tracking_error") if not math.isnan(x)]
    tracking = float(max(track)) if track else None
    final = {k: (float(r.series(k)[-1]) if r.statuses and not math.isnan(r.series(k)[-1]) else None)
             for k in ("tau_dot", "p")}
    ti = [0.0] + [i.t for i in r.impacts]
    st = np.diff(ti)
    work, crit = [], []
    for a, b in zip(ti[:-1], ti[1:]):
        recs = [x for x in r.records if a <= x.t < b]
        work.append(sum(float(np.sum(np.abs(x.torque * x.qd))) * (x.t_end - x.t) for x in recs))
        crit.append(sum(float(x.torque @ x.torque) * (x.t_end - x.t) for x in recs))
    lengths = [abs(i.ankle_x - j.ankle_x) for i, j in zip(r.impacts[1:], r.impacts[:-1])]
    p = float(np.mean(lengths)) if lengths else math.nan
    row = {"plant": plant, "mode": mode, "steps_walked": r.steps_walked, "fallen": r.fallen,
           "fall_cause": r.fall_cause, "fall_time": None if math.isnan(r.fall_time) else r.fall_time,
           "max_tracking_error": tracking,
           "step_time_mean": float(np.mean(st)) if len(st) else None,
           "step_time_min": float(np.min(st)) if len(st) else None, "step_time_max": float(np.max(st)) if len(st) else None,
           "step_length_mean": p, "work_per_step": float(np.mean(work)) if work else None,
           "criterion_per_step": float(np.mean(crit) / p) if crit and p == p else None,
           "final_tau_dot": final["tau_dot"], "final_p": final["p"],
           "max_stance_pitch": float(np.max(np.abs(_stance_pitch(r.records))))}
    if plants:
        row["contact"] = plants[-1].diagnostics.as_dict()
    return row


def walk_table(rows: list[dict]) -> str:
    L = ["| plant | mode | steps | fall | max tracking error [rad] | step time mean (min-max) [s] | "
         "motor work / step [J] | C / step [N^2 m^2 s/m] | final tau' | max stance-foot pitch [rad] |",
         "| --- | --- | ---: | --- | ---: | --- | ---: | ---: | ---: | ---: |"]
    for r in rows:
        f = lambda v, d: "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{d}f}"   # noqa: E731
        L.append(f"| {r['plant']} | {r['mode']} | {r['steps_walked']} | {r['fall_cause'] or '-'} | "
                 f"{f(r['max_tracking_error'], 4)} | {f(r['step_time_mean'], 4)} ({f(r['step_time_min'], 4)}-"
                 f"{f(r['step_time_max'], 4)}) | {f(r['work_per_step'], 1)} | {f(r['criterion_per_step'], 0)} | "
                 f"{f(r['final_tau_dot'], 5)} | {f(r['max_stance_pitch'], 4)} |")
    c = [r for r in rows if "contact" in r]
    if c:
        L += ["", "| MuJoCo mode | MuJoCo steps | stance foot unloaded | CoP within 1 mm of an edge | on the friction cone | "
              "pitched > 1 mrad | max pitch [rad] | max CoP [m] | max slip [m] |", "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for r in c:
            d = r["contact"]
            pc = lambda k: f"{100 * d[k] / d['time']:.1f} %" if d["time"] else "-"   # noqa: E731
            L.append(f"| {r['mode']} | {d['steps']} | {pc('unloaded_time')} | {pc('edge_time')} | {pc('cone_time')} | "
                     f"{pc('tilt_time')} | {d['max_tilt']:.4f} | {d['max_cop']:.4f} | {d['max_slip']:.2e} |")
    return "\n".join(L)


def no_fall_edge(trials: list[dict]) -> tuple[float, float | None, str]:
    """(largest tried force below the lowest one that fell, that force or None, its fall cause)."""
    lo, hi, cause = 0.0, None, ""
    for t in sorted(trials, key=lambda t: t["force"]):
        if t["fall_cause"]:
            return lo, t["force"], t["fall_cause"]
        lo = t["force"]
    return lo, hi, cause


def pushes_table(directory: Path, reuse: bool, profile: str = DEFAULT_PROFILE,
                 controllers: tuple[str, ...] = (), robot: str | None = None) -> tuple[str, dict]:
    """The max-push table of the four modes and of the ``controllers`` named (registered controllers'
    names, ``trial.controller.resolve``) on both plants, observer on and off (module docstring, ``pushes``).
    ``reuse``: a table file that holds every row asked for is read, not run again. ``robot``: ``--robot``
    (None: the default robot)."""
    from biped_controller.studies import experiment
    names = tuple(dict.fromkeys(("none", "tau", "p", "both") + tuple(controllers)))
    data = {}
    for obs in ("on", "off"):
        for plant in PLANTS:
            f = directory / f"table_{plant}_observer_{obs}.json"
            if not (reuse and f.is_file() and set(names) <= set(json.loads(f.read_text(encoding="utf-8"))["modes"])):
                experiment.main(["table", "--workers", "2", "--profile", profile, "--observer", obs,
                                 "--set", f"plant={plant}", "--json", str(f)]
                                + [x for c in controllers for x in ("--controller", c)]
                                + (["--robot", robot] if robot else []))
            data[(plant, obs)] = json.loads(f.read_text(encoding="utf-8"))["modes"]
    L = ["| observer | mode | paper [N] | rigid: max push [N] (first failure) | MuJoCo: max push [N] (first failure) | "
         "rigid: no-fall edge [N], first fall | MuJoCo: no-fall edge [N], first fall |",
         "| --- | --- | ---: | --- | --- | --- | --- |"]
    out = {}
    for obs in ("on", "off"):
        for mode in names:
            cells = []
            for plant in PLANTS:
                m = data[(plant, obs)][mode]
                lo, hi, cause = ((m["no_fall_edge"], m["first_fall"], m["fall_cause"] or "") if "no_fall_edge" in m
                                 else no_fall_edge(m["trials"]))     # a table of the coarse-only search
                out[f"{plant}/{obs}/{mode}"] = dict(max_force=m["max_force"], failure=m["failure_cause"], no_fall=lo,
                                                    first_fall=hi, fall_cause=cause, islands=m["islands"])
                cells.append((f"{m['max_force']:g} ({m['failure_cause']})", "undefined (controller fault)" if lo is None
                              else f"{lo:g}, {hi:g} N {cause}" if hi else f"> {lo:g}"))
            paper = data[("rigid", obs)][mode]["paper"]
            L.append(f"| {obs} | {mode} | {paper if paper else '-'} | {cells[0][0]} | {cells[1][0]} | {cells[0][1]} | {cells[1][1]} |")
    return "\n".join(L), out


def push_pair(push: Push, mode: str, observer: bool | None = None, profile: str = DEFAULT_PROFILE,
              robot: str | None = None) -> list[dict]:
    """``push`` and 5 steps after it by the controller ``mode`` (a built-in mode or a registered controller,
    ``TrialController.walk``) on both plants (the profile's settings, the observer on or off, None: the
    profile's; the observer is the adaptive controller's): the outcome and on MuJoCo the contact diagnostics
    (module docstring). ``final_p`` [m] and ``final_tau_dot`` [-] are None for a controller that does not
    report them."""
    from biped_sim.plant import mujoco as pm
    ctl = resolve(mode)
    st = parse_overrides((), observer, profile=profile, robot=robot).activate()
    observer = st.ctrl_config(mode).disturbance_observer if ctl.adaptive else False
    force, start = push.force, push.start
    out = []
    for plant in PLANTS:
        plants = []
        orig = pm.MujocoPlant.reset

        def grab(self, *a, **k):
            plants.append(self)
            return orig(self, *a, **k)
        pm.MujocoPlant.reset = grab
        try:
            r = ctl.walk(6, _with_plant(st, plant), (push,))
        finally:
            pm.MujocoPlant.reset = orig
        final = {k: (float(r.series(k)[-1]) if r.statuses and not math.isnan(r.series(k)[-1]) else None)
                 for k in ("tau_dot", "p")}
        row = dict(plant=plant, mode=mode, observer=observer, force=force, start=start, steps_walked=r.steps_walked,
                   fall=r.fall_cause or None, fall_time=None if math.isnan(r.fall_time) else r.fall_time,
                   detail=r.fall_detail or None, final_p=final["p"], final_tau_dot=final["tau_dot"])
        if r.fault is not None:
            row["fault"] = str(r.fault)
        if plants:
            row["contact"] = plants[-1].diagnostics.as_dict()
        out.append(row)
        print(json.dumps(row), flush=True)
    return out


# (name, steps, mode, pushes, perturbation keywords, runner keywords)
FINGERPRINT_RUNS = (
    ("walk-both", 4, "both", (), {}, {}),
    ("walk-none", 3, "none", (), {}, {}),
    ("push-both", 4, "both", (Push(0.9, 0.025, 300.0),), {}, {}),
    ("push-tau", 4, "tau", (Push(0.9, 0.025, 200.0),), {}, {}),
    ("push-p", 4, "p", (Push(0.9, 0.025, 150.0),), {}, {}),
    ("back-both", 4, "both", (Push(1.2, 0.025, -150.0),), {}, {}),
    ("fall-both", 4, "both", (Push(0.2315, 0.025, 1500.0),), {}, {}),
    ("noise-both", 3, "both", (), {"noise_q": 1e-4, "noise_qd": 1e-2, "seed": 3}, {}),
    ("delay-both", 3, "both", (), {"delay": 1}, {}),
    ("rate-both", 2, "both", (Push(0.3, 0.025, 200.0),), {}, {"integration_rate": True}),
)


def run_digest(run_spec: tuple, scfg=None) -> tuple[str, "runner.RunResult"]:
    """sha256 of one of ``FINGERPRINT_RUNS`` on the MuJoCo plant (module docstring, ``fingerprint``) and its
    result."""
    import dataclasses
    import hashlib

    from biped_sim.plant import mujoco as pm
    from biped_sim.plant.perturbation import PlantPerturbation
    from biped_controller.studies.fingerprint import digest, feed

    name, steps, mode, pushes, pert, kw = run_spec
    scfg = scfg if scfg is not None else load_sim_config(plant="mujoco")
    orig = pm.MujocoPlant.reset
    plants: list = []

    def grab(self, *a, **k):
        plants.append(self)
        return orig(self, *a, **k)
    pm.MujocoPlant.reset = grab
    try:
        r = runner.run(steps, mode, pushes, sim_config=scfg,
                       perturbation=PlantPerturbation(**pert) if pert else None, **kw)
    finally:
        pm.MujocoPlant.reset = orig
    h = hashlib.sha256(digest(r, ()).encode())
    dg = plants[-1].diagnostics
    for f in dataclasses.fields(dg):
        feed(h, np.asarray(getattr(dg, f.name), dtype=float) if f.name == "touchdown_forces" else getattr(dg, f.name))
    return h.hexdigest(), r


def interface_agrees(run_spec: tuple, result: "runner.RunResult", scfg) -> bool | None:
    """Whether the run ``run_spec`` made through the controller interface (the mode's built-in class on the
    generic loop, ``plugin.loop``) has the records, impacts and outcome of ``result`` (the studies' compiled
    path), bit for bit; None for a run the interface does not make (the torque law at the integration rate:
    an interface controller's torque is held over the period)."""
    from biped_sim.plant.perturbation import PlantPerturbation
    from biped_controller.plugin import loop as plugin_loop
    from biped_controller.studies.fingerprint import digest

    name, steps, mode, pushes, pert, kw = run_spec
    if kw:
        return None
    iface = plugin_loop.run(mode, steps, pushes, sim_config=scfg,
                            perturbation=PlantPerturbation(**pert) if pert else None)
    return iface.fault is None and digest(iface, (), statuses=False) == digest(result, (), statuses=False)


def mujoco_fingerprint(out=print, disagree: list | None = None) -> str:
    """The hash of ``FINGERPRINT_RUNS`` on the MuJoCo plant (module docstring, ``fingerprint``); prints one
    line per run and the total. Each run is also made through the controller interface
    (:func:`interface_agrees`: compared, not hashed); the names of the runs where it differs are appended to
    ``disagree``."""
    import hashlib

    scfg = load_sim_config(plant="mujoco")
    total = hashlib.sha256()
    for spec in FINGERPRINT_RUNS:
        digest, r = run_digest(spec, scfg)
        total.update(digest.encode())
        same = interface_agrees(spec, r, scfg)
        out(f"{spec[0]:12s} steps={r.steps_walked} fallen={r.fallen} {r.fall_cause or '-':13s} "
            f"periods={len(r.records)} {digest[:16]} interface: "
            f"{'-' if same is None else 'same records' if same else 'DIFFERENT records'}")
        if same is False and disagree is not None:
            disagree.append(spec[0])
    out(f"mujoco fingerprint {total.hexdigest()}")
    return total.hexdigest()


def main(argv: list[str] | None = None) -> int:
    ap = StudyArgumentParser(prog="python -m biped_controller.studies.plant_compare", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("walk")
    w.add_argument("--steps", type=positive_int, default=20)
    add_modes_arg(w, None, "both,tau,p,none without --controller; with --controller, only the controllers given")
    w.add_argument("--controller", type=controller_arg, action="append", default=[], metavar="NAME",
                   help="a registered controller's walk on both plants (repeatable), beside the --modes given")
    w.add_argument("--json", type=Path, default=None)
    pu = sub.add_parser("pushes")
    pu.add_argument("--dir", type=Path, default=Path("results/mujoco_plant"))
    pu.add_argument("--reuse", action="store_true")
    pu.add_argument("--controller", type=controller_arg, action="append", default=[], metavar="NAME",
                    help="a registered controller's rows beside the four modes (repeatable)")
    for p_ in (w, pu):
        p_.add_argument("--profile", type=profile_arg, default=DEFAULT_PROFILE, help="config/profiles/ NAME")
        add_robot_arg(p_)
    pu.add_argument("--json", type=Path, default=None)
    po = sub.add_parser("push")
    po.add_argument("--force", type=finite_float, required=True)
    po.add_argument("--mode", choices=MODES, default="both")
    po.add_argument("--controller", type=controller_arg, default=None, metavar="NAME",
                    help="any registered controller (python -m biped_controller.studies.controllers list) in place of --mode")
    po.add_argument("--profile", type=profile_arg, default=DEFAULT_PROFILE, help="config/profiles/ NAME")
    po.add_argument("--observer", choices=("on", "off"), default=None,
                    help="the disturbance observer (default: the profile's; on in the default profile)")
    po.add_argument("--start", type=nonnegative_float, default=0.2315, help="push onset [s] (default 0.2315 s, phase 0.5; "
                    "onset phase k/20 of the capability map: k/20 x 0.463 s; negative --force: backward)")
    po.add_argument("--json", type=Path, default=None)
    add_robot_arg(po)
    sub.add_parser("fingerprint")
    a = ap.parse_args(argv)
    provenance.track(getattr(a, "json", None), getattr(a, "dir", None) if a.cmd == "pushes" else None, argv=argv,
                     plant=None if a.cmd in ("fingerprint",) else "rigid,mujoco", robot=getattr(a, "robot", None))   # record of each file written (results/README.md)
    if a.cmd == "fingerprint":
        disagree: list = []
        mujoco_fingerprint(disagree=disagree)
        if disagree:
            print(f"the controller interface and the compiled path disagree: {', '.join(disagree)}", file=sys.stderr)
            return 1
        return 0
    if getattr(a, "robot", None) is not None:
        try:
            parse_overrides((), profile=a.profile, robot=a.robot)       # the robot checked: one line, exit 2
        except SETTINGS_ERRORS as exc:
            ap.error(str(exc))
    if a.cmd == "push":
        rows = push_pair(Push(a.start, 0.025, float(a.force)), a.controller or a.mode,
                         None if a.observer is None else a.observer == "on", a.profile, a.robot)
    elif a.cmd == "pushes":
        table, rows = pushes_table(a.dir, a.reuse, a.profile, tuple(a.controller), a.robot)
        print(table)
    elif a.cmd == "walk":
        try:
            settings = parse_overrides((), profile=a.profile, robot=a.robot).activate()
        except SETTINGS_ERRORS as exc:
            ap.error(str(exc))
        modes = list(dict.fromkeys((list(a.modes) if a.modes is not None else ([] if a.controller else
                                                                          ["both", "tau", "p", "none"]))
                                   + list(a.controller)))
        rows = [walk_row(pl, m, a.steps, settings) for m in modes for pl in PLANTS]
        print(walk_table(rows))
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(rows, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
