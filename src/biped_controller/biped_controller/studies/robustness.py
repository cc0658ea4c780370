"""Robustness table: undisturbed walking and the largest survivable push per adaptation mode,
observer on and off, for each perturbation of the plant (``biped_sim.plant.perturbation``).

Run through ``scripts/robustness [options]`` (``--help``), e.g. the priority part on two processes::

    scripts/robustness --workers 2 --modes both none --observer on

Pure Python (no ROS). The controller always keeps the nominal description; each *level* is a
``PlantPerturbation`` given to the simulator only (``trial.settings.RunSettings.perturbation`` ->
``runner.run`` -> ``Simulator``).

Per level:

* walk: ``runner.run(WALK_STEPS, mode)`` from the family's initial state without a push; it *survives*
  when ``WALK_STEPS`` impacts happen without a fall (the record gives the fall cause and time, the
  largest tracking error and |l|, and the observer's largest force estimate, which under model error
  is a fictitious force explaining the model's residual);
* max push: the capability map's search (``capability_map.run_maps``, one one-cell map per (level,
  mode, observer), all at once on the capability map's workers, after the walks: phase 0.5 of the
  first step = ``trial.runs.DEFAULT_START``, forward, 0.025 s; coarse scan then bisection, survival =
  ``trial.survival``) with a coarse, per-mode search (:data:`SEARCHES`): the boundary is known to
  within the resolution only, and islands above the lowest failing edge are listed.

Records: the walk records in ``<store>/walks.jsonl`` and the push simulations in ``<store>/push.jsonl``
(JSON Lines, resumable: a rerun skips every walk and simulation already stored; push records are keyed
by the capability map's fingerprint, which contains the perturbation through the run settings).
Noise is one realisation (seed 0): a boundary under noise is that realisation's. The early stop of
``trial.stop.EarlyStop`` shortens the nominal rows' survival trials only (it was measured on the nominal
plant); ``--full-trials`` turns it off there too.

``--profile NAME`` (config/profiles/) sets the controller's and the simulator's settings of every row (the
observer is the table's own column); a profile's own plant perturbation (the real-sensor profiles' sensor
noise) lies under every row: the row's fields replace the profile's, the others stay (so ``nominal`` under
``real-sensors`` is the nominal model with the design-point noise). ``--set`` adds simulator settings over it.

Over seeds (``--seeds N``, ``--survival-levels C,C``): every (row, mode, observer) whose plant draws noise
gets the max-push table over seeds at the push cell (``trial.seeded.seeded_table``, the row's own search
ranges): survival rates with Wilson 95 % intervals and the forces where survival crosses each level, with
intervals; printed as a second table and stored under ``seeded_pushes``. Rows without noise are exact (one
trial decides: survival 1 up to the boundary, 0 at the first failure). These searches are not resumable.
"""
from __future__ import annotations

import argparse
import re
import json
import math
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biped_sim.plant.perturbation import PerturbationError, PlantPerturbation

from biped_controller.studies import capability_map as cmap
from biped_controller.closed_loop.executor import make_executor
from biped_controller.studies.provenance import git_state
from biped_controller.studies.trial.survival import survival_rule
from biped_controller.studies.trial.args import (SETTINGS_ERRORS, StudyArgumentParser, add_modes_arg, add_robot_arg,
                                                 controller_arg, levels_arg, positive_int, profile_arg)
from biped_controller.studies.trial import seeded, uncertainty
from biped_controller.studies.trial.context import context, scaled_force
from biped_controller.studies.trial.record import faulted
from biped_controller.studies.trial.scan import no_fall_undefined
from biped_controller.studies.trial.controller import resolve
from biped_controller.studies.trial.settings import (DEFAULT_PROFILE, RunSettings, differences, parse_overrides,
                                                     print_settings)
from biped_controller.studies import provenance

WALK_STEPS = 20
PUSH_CELL = dict(direction="forward", phase=0.5, duration=0.025)
#: per-mode force search of the max-push cell (coarse step, largest force scanned, bisection resolution) [N]:
#: coarse steps of 20-40 N up to a force above the mode's nominal boundary, the lowest failing edge bisected to
#: half a coarse step, so every boundary of the table is known to within that resolution only
SEARCHES: dict[str, cmap.Search] = {
    "none": cmap.Search(coarse=20.0, fmax=200.0, resolution=10.0),
    "tau": cmap.Search(coarse=40.0, fmax=800.0, resolution=20.0),
    "p": cmap.Search(coarse=40.0, fmax=800.0, resolution=20.0),
    "both": cmap.Search(coarse=40.0, fmax=960.0, resolution=20.0),
    "wbc": cmap.Search(coarse=20.0, fmax=400.0, resolution=10.0),
    "hybrid": cmap.Search(coarse=40.0, fmax=1200.0, resolution=20.0),
    # the torso parameter's modes: searched like tau and hybrid
    "lambda": cmap.Search(coarse=40.0, fmax=800.0, resolution=20.0),
    "all": cmap.Search(coarse=40.0, fmax=1200.0, resolution=20.0),
}
#: the search of a plug-in controller's row (any registered controller, ``--controller``): coarse 40 N up to
#: 1200 N, bisected to 20 N (the widest of the built-in modes' searches)
PLUGIN_SEARCH = cmap.Search(coarse=40.0, fmax=1200.0, resolution=20.0)
ALL_INERTIAS = ("torso", "thigh", "shin", "foot")


def search_for(mode: str) -> cmap.Search:
    """The max-push search of a row: :data:`SEARCHES` for a built-in mode, :data:`PLUGIN_SEARCH` otherwise;
    for another robot than the default one each force scaled by its M sqrt(g L) / the default robot's
    (``trial.context.force_scale``; the default robot's: these, bit for bit)."""
    s = SEARCHES.get(mode, PLUGIN_SEARCH)
    if not ROBOT:
        return s
    return cmap.Search(scaled_force(s.coarse, ROBOT), scaled_force(s.fmax, ROBOT), scaled_force(s.resolution, ROBOT),
                       s.max_impulse if math.isinf(s.max_impulse) else scaled_force(s.max_impulse, ROBOT))


def single_observer(mode: str) -> bool:
    """The row runs once, observer off, when the observer setting does not change the controller's runs
    (``TrialController.uses_observer``): mode none (its torque never uses the estimate) and any plug-in
    controller (the observer setting is the adaptive controller's)."""
    return not resolve(mode).uses_observer


@dataclass(frozen=True)
class Level:
    """One row of the table: a name (the table's text), the group it belongs to, the perturbation, and the
    key that selects it on the command line (``--levels``: letters, digits and ``_ . + -`` only, so a
    shell needs no quoting and argparse's help formatter no escaping)."""

    name: str
    group: str
    perturbation: PlantPerturbation
    key: str


def _inertias(scale: float) -> PlantPerturbation:
    return PlantPerturbation(**{f"{k}_inertia_scale": scale for k in ALL_INERTIAS})


#: the table's rows, in order
LEVELS: tuple[Level, ...] = (
    Level("nominal", "nominal", PlantPerturbation(), "nominal"),
    Level("torso mass -20 %", "model", PlantPerturbation(torso_mass_scale=0.8), "torso_mass-20"),
    Level("torso mass -10 %", "model", PlantPerturbation(torso_mass_scale=0.9), "torso_mass-10"),
    Level("torso mass +10 %", "model", PlantPerturbation(torso_mass_scale=1.1), "torso_mass+10"),
    Level("torso mass +20 %", "model", PlantPerturbation(torso_mass_scale=1.2), "torso_mass+20"),
    Level("torso CoM -2 cm", "model", PlantPerturbation(torso_com_shift=-0.02), "torso_com-2cm"),
    Level("torso CoM +2 cm", "model", PlantPerturbation(torso_com_shift=0.02), "torso_com+2cm"),
    Level("inertias -30 %", "model", _inertias(0.7), "inertias-30"),
    Level("inertias +30 %", "model", _inertias(1.3), "inertias+30"),
    Level("noise 1e-4 rad, 1e-2 rad/s", "sensing", PlantPerturbation(noise_q=1e-4, noise_qd=1e-2), "noise1e-4"),
    Level("noise 5e-4 rad, 5e-2 rad/s", "sensing", PlantPerturbation(noise_q=5e-4, noise_qd=5e-2), "noise5e-4"),
    Level("noise 5e-4 rad, 5e-2 rad/s, 14 bits", "sensing",
          PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14), "noise5e-4_14bit"),
    Level("noise 1e-3 rad, 1e-1 rad/s", "sensing", PlantPerturbation(noise_q=1e-3, noise_qd=1e-1), "noise1e-3"),
    Level("delay 1 period", "sensing", PlantPerturbation(delay=1), "delay1"),
    Level("delay 2 periods", "sensing", PlantPerturbation(delay=2), "delay2"),
    Level("delay 1 period, touchdown at once", "sensing", PlantPerturbation(delay=1, touchdown_delayed=False), "delay1_touchdown_at_once"),
    Level("delay 2 periods, touchdown at once", "sensing", PlantPerturbation(delay=2, touchdown_delayed=False), "delay2_touchdown_at_once"),
    Level("mu 0.5", "friction", PlantPerturbation(mu=0.5), "mu0.5"),
    Level("mu 0.4", "friction", PlantPerturbation(mu=0.4), "mu0.4"),
)
LEVELS_BY_NAME = {lv.name: lv for lv in LEVELS}
LEVELS_BY_KEY = {lv.key: lv for lv in LEVELS}
assert len(LEVELS_BY_KEY) == len(LEVELS) and all(re.fullmatch(r"[A-Za-z0-9_.+-]+", k) for k in LEVELS_BY_KEY)


class RobustnessError(ValueError):
    """A bad level name, mode or option (the message names it)."""


def combos(modes, observers) -> list[tuple[str, bool]]:
    """(mode, observer) pairs to run: every adaptive mode with each observer setting, then ``none`` once
    with the observer off (no QP: its torque never uses the estimate, so the observer changes nothing)."""
    return ([(m, obs) for obs in observers for m in modes if not single_observer(m)]
            + [(m, False) for m in modes if single_observer(m)])


#: simulator overrides of the profile and ``--set KEY=VALUE`` (e.g. ``--set plant=mujoco``); set by :func:`main`,
#: passed explicitly to every walk task and carried by every push spec's settings; part of every settings
#: fingerprint, so stored records of another plant are never reused
SIMULATOR_OVERRIDES: tuple[tuple[str, object], ...] = ()
#: controller overrides of the profile (the observer excepted: the table's column), set by :func:`main` like
#: :data:`SIMULATOR_OVERRIDES`
CONTROLLER_OVERRIDES: tuple[tuple[str, object], ...] = ()
#: the profile's name (recorded in the settings; its entries are the overrides above)
PROFILE: str = DEFAULT_PROFILE
#: the robot (``--robot``; "" the default), set by :func:`main` like :data:`SIMULATOR_OVERRIDES`: passed
#: explicitly to every walk task and carried by every push spec's settings
ROBOT: str = ""


def settings_for(perturbation: PlantPerturbation, observer: bool, full_trials: bool = False,
                 simulator: tuple[tuple[str, object], ...] | None = None,
                 controller: tuple[tuple[str, object], ...] | None = None, robot: str | None = None) -> RunSettings:
    """Run settings: the config files, the profile's controller overrides (``controller``, None:
    :data:`CONTROLLER_OVERRIDES`) with the observer switch, the plant's perturbation, ``simulator`` overrides
    (None: :data:`SIMULATOR_OVERRIDES`), the robot (None: :data:`ROBOT`)."""
    sim = SIMULATOR_OVERRIDES if simulator is None else tuple(simulator)
    ctrl = dict(CONTROLLER_OVERRIDES if controller is None else controller)
    ctrl["disturbance_observer"] = bool(observer)
    return RunSettings(controller=tuple(sorted(ctrl.items())), simulator=sim,
                       perturbation=perturbation, full_trials=full_trials, profile=PROFILE,
                       robot=ROBOT if robot is None else robot)


# ------------------------------------------------------------------------------------------ walk
def walk_record(perturbation: PlantPerturbation, mode: str, observer: bool, steps: int = WALK_STEPS,
                simulator: tuple[tuple[str, object], ...] | None = None,
                controller: tuple[tuple[str, object], ...] | None = None, robot: str | None = None) -> dict:
    """One undisturbed walk of ``steps`` impacts by the controller ``mode`` (``TrialController.walk``; the
    pure task of a worker: ``simulator`` and ``controller`` overrides passed with it, never read from a global
    in a spawned worker; ``robot`` likewise); JSON-ready record. The tracking error [rad], p [m], tau' [-] and the force estimate
    [N] come from the status keys ``max_tracking_error``, ``p``, ``tau_dot``, ``force_estimate`` (None where
    the controller does not report them); a controller fault is a failed walk whose cause is the fault."""
    st = settings_for(perturbation, observer, simulator=simulator, controller=controller, robot=robot).activate()
    t0 = time.perf_counter()
    ctl = resolve(mode)
    res = ctl.walk(steps, st)
    fault = res.fault

    def top(key):
        v = [abs(float(x)) for x in res.series(key) if not math.isnan(x)] if res.statuses else []
        return float(max(v)) if v else None

    def final(key):
        v = res.series(key)[-1:] if res.statuses else ()
        return float(v[0]) if len(v) and not math.isnan(v[0]) else None
    cop = [abs(r.cop) for r in res.records if math.isfinite(r.cop) and not r.fallen]
    cause = res.fall_cause or (f"controller fault: {fault.kind}" if fault is not None else None)
    return {
        "kind": "walk", "perturbation": perturbation.as_dict(), "mode": mode,
        "observer": bool(observer) and ctl.uses_observer,
        "steps": steps, "fingerprint": walk_fingerprint(perturbation, observer, simulator, controller, robot),
        "survived": (not res.fallen) and fault is None and res.steps_walked >= steps,
        "steps_walked": int(res.steps_walked), "fall_cause": cause,
        "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
        "fall_detail": res.fall_detail or (str(fault) if fault is not None else None),
        "max_tracking_error": top("max_tracking_error"), "max_abs_l": float(max(cop)) if cop else None,
        "max_force_estimate": top("force_estimate"),
        "final_p": final("p"), "final_tau_dot": final("tau_dot"),
        "wall_time": time.perf_counter() - t0,
    }


def walk_fingerprint(perturbation: PlantPerturbation, observer: bool,
                     simulator: tuple[tuple[str, object], ...] | None = None,
                     controller: tuple[tuple[str, object], ...] | None = None, robot: str | None = None) -> str:
    """The capability map's fingerprint of the walk's settings (controller and simulator settings with the
    perturbation, robot description, gait family file): a walk record is reused only while it matches."""
    st = settings_for(perturbation, observer, simulator=simulator, controller=controller, robot=robot).activate()
    return cmap.fingerprint(cmap.MapSpec(settings=st))


def _walk_key(perturbation: PlantPerturbation | dict, mode: str, observer: bool, steps: int,
              fingerprint: str | None) -> str:
    # normalised through the dataclass: a record stored before a field was added keys as its default
    p = (perturbation if isinstance(perturbation, PlantPerturbation) else PlantPerturbation.from_dict(perturbation)).as_dict()
    return json.dumps([p, mode, bool(observer), int(steps), fingerprint], sort_keys=True)


def _record_key(r: dict) -> str:
    return _walk_key(r["perturbation"], r["mode"], r["observer"], r["steps"], r.get("fingerprint"))


def run_walks(levels, modes, observers, store: cmap.RecordStore, workers, log=print,
              simulate: bool = True) -> dict[str, dict]:
    """Every (level, mode, observer) walk not yet in ``store``, on ``workers`` (an executor of
    ``closed_loop.executor``, or a number of processes); returns the records by key. Mode ``none`` ignores the observer (no QP: the estimate is never used), so it runs once,
    with the observer as configured off. ``simulate`` False: only the stored records."""
    done = {_record_key(r): r for r in store.load() if r.get("kind") == "walk"}
    if not simulate:
        return done
    tasks = []
    for lv in levels:
        for m in modes:
            for obs in ((False,) if single_observer(m) else observers):
                k = _walk_key(lv.perturbation, m, obs, WALK_STEPS, walk_fingerprint(lv.perturbation, obs))
                if k not in done:
                    tasks.append((lv.perturbation, m, obs, WALK_STEPS, SIMULATOR_OVERRIDES, CONTROLLER_OVERRIDES, ROBOT))
    log(f"walks: {len(tasks)} to run, {len(done)} stored")

    def keep(r: dict) -> None:
        store.append([r])
        done[_record_key(r)] = r
        log(f"  walk {PlantPerturbation.from_dict(r['perturbation']).label()} {r['mode']} "
            f"observer {'on' if r['observer'] else 'off'}: {'survived' if r['survived'] else 'FELL'} "
            f"{r['steps_walked']} steps {r['fall_cause'] or ''} ({r['wall_time']:.0f} s)")
    if tasks:
        if isinstance(workers, int):
            with make_executor(workers, initializer=context) as ex:
                ex.map(walk_record, tasks, on_result=keep)
        else:
            workers.map(walk_record, tasks, on_result=keep)
    return done


# ------------------------------------------------------------------------------------------ max push
def push_spec(perturbation: PlantPerturbation, mode: str, observer: bool, full_trials: bool = False) -> cmap.MapSpec:
    """The capability map of one mode on the max-push cell, with the level's perturbation (one cell: the
    full search, no neighbour)."""
    return cmap.MapSpec(modes=(mode,), directions=(PUSH_CELL["direction"],), phases=(PUSH_CELL["phase"],),
                        durations=(PUSH_CELL["duration"],), search=search_for(mode),
                        settings=settings_for(perturbation, observer, full_trials))


def max_push_record(run: cmap.MapRun) -> dict:
    """The boundary of the one cell of ``run`` (JSON-ready): force, first failure, cause, islands."""
    (cell,) = run.spec.cells()
    b = cmap.cell_summary(run, cell)
    return {"max_force": b["force"], "max_force_no_fall": b["no_fall_edge"], "first_fall": b["first_fall"], "first_failure": b["first_failure"], "censored": b["censored"],
            "cause": b["cause"], "reason": b["reason"], "islands": b["islands"], "simulations": b["simulations"],
            "resolution": run.spec.search.resolution, "coarse": run.spec.search.coarse, "scan_max": run.spec.search.fmax,
            **({k: b[k] for k in ("no_fall_undefined",) if k in b})}


def stored_max_push(spec: cmap.MapSpec, records: list[dict]) -> dict | None:
    """The max-push record of ``spec``'s one cell from stored simulation records alone (the search of
    ``capability_map.plan_cell`` replayed), or None when the store does not finish the search."""
    (cell,) = spec.cells()
    fp = cmap.fingerprint(spec)
    key = (cell.mode, cell.direction, cell.phase, cell.duration)
    recs = {float(r["force"]): r for r in records
            if r.get("fingerprint") == fp and cmap.record_key(r)[:4] == key}
    forces, b = cmap.plan_cell(spec.search, {f: bool(r["survived"]) for f, r in recs.items()})
    if b is None:
        return None
    forces, b = cmap.plan_no_fall(spec.search, {f: cmap.record_ends_no_fall(r) for f, r in recs.items()}, b,
                                  {f: faulted(r) for f, r in recs.items()})
    if b is None:
        return None
    first = recs.get(b.hi) if b.hi is not None else None
    return {"max_force": b.lo, "max_force_no_fall": b.no_fall_lo, "first_fall": b.no_fall_hi, "first_failure": b.hi, "censored": b.hi is None,
            "cause": first["cause"] if first else None, "reason": first["reason"] if first else None,
            "islands": list(b.islands), "simulations": len(recs), "resolution": spec.search.resolution,
            "coarse": spec.search.coarse, "scan_max": spec.search.fmax,
            **({} if b.no_fall_fault is None else {"no_fall_undefined": no_fall_undefined(recs[b.no_fall_fault])})}


def run_pushes(levels, modes, observers, store: cmap.RecordStore, executor, log=print,
               full_trials: bool = False) -> dict[tuple, dict]:
    """Max push of every (level, mode, observer), all at once through ``capability_map.run_maps`` (one
    one-cell map per row: every worker stays busy; resumable from ``store``); returns {(level name, mode,
    observer): record}. Mode ``none`` runs with the observer off only (its torque never uses the
    estimate). ``executor`` None: only what the store holds (no simulation). ``full_trials``: no early
    stop (it applies to the nominal plant only in any case: ``trial.stop.EarlyStop``)."""
    out = {}
    keys = [(lv, m, obs) for m, obs in combos(modes, observers) for lv in levels]
    specs = [push_spec(lv.perturbation, m, obs, full_trials) for lv, m, obs in keys]
    if executor is None:
        stored = store.load()
        for (lv, m, obs), spec in zip(keys, specs):
            r = stored_max_push(spec, stored)
            if r is not None:
                out[(lv.name, m, obs)] = dict(r, level=lv.name, mode=m, observer=obs,
                                              perturbation=lv.perturbation.as_dict())
        return out
    t0 = time.perf_counter()
    runs = cmap.run_maps(specs, executor, store, batch=1)
    for (lv, m, obs), run in zip(keys, runs):
        r = max_push_record(run)
        r.update(level=lv.name, mode=m, observer=obs, perturbation=lv.perturbation.as_dict(),
                 simulated_now=run.simulated)
        out[(lv.name, m, obs)] = r
        log(f"  max push {lv.name:<28} {m:<4} observer {'on ' if obs else 'off'}: {r['max_force']:g} N "
            f"(first failure {r['first_failure']}, {r['cause']}; {run.simulated} run now, {run.resumed} resumed)")
    log(f"max push: {sum(r.simulated for r in runs)} simulations run, {sum(r.resumed for r in runs)} resumed, "
        f"{time.perf_counter() - t0:.0f} s")
    return out


def under_profile(levels, base: PlantPerturbation | None) -> tuple[Level, ...]:
    """``levels`` with the profile's plant perturbation ``base`` under each (the row's non-default fields
    replace base's); ``levels`` unchanged when ``base`` is None."""
    if base is None:
        return tuple(levels)
    zero = PlantPerturbation().as_dict()
    return tuple(Level(lv.name, lv.group, PlantPerturbation.from_dict(
        {**base.as_dict(), **{k: v for k, v in lv.perturbation.as_dict().items() if v != zero[k]}}), lv.key)
        for lv in levels)


def _seeded_key(lv, mode: str, observer: bool, seeds: int, survival_levels, full_trials: bool) -> str:
    """What a seeded row's answer depends on: the row's perturbation (its seed included), the mode, the
    observer, the seed count, the survival levels, the row's search and the settings' fingerprint (plant,
    profile, overrides, robot, gait family)."""
    sr = search_for(mode)
    st = settings_for(lv.perturbation, observer, full_trials).activate()
    return json.dumps([lv.perturbation.as_dict(), mode, bool(observer), int(seeds), [float(c) for c in survival_levels],
                       [sr.resolution, sr.fmax, sr.coarse], bool(full_trials), cmap.fingerprint(cmap.MapSpec(settings=st))],
                      sort_keys=True)


def run_seeded_pushes(levels, modes, observers, seeds: int, survival_levels, workers: int, full_trials: bool,
                      log=print, store: cmap.RecordStore | None = None, simulate: bool = True) -> list[dict]:
    """The max push over ``seeds`` seeds (``trial.seeded.seeded_table`` at :data:`PUSH_CELL`, the row's
    search of :func:`search_for`) of every (level, mode, observer) whose plant draws noise; one record
    each (the seeded table's result without its trial records). ``store``: each row's record is appended as
    it finishes (key :func:`_seeded_key`) and a rerun takes the rows stored (resumable); ``simulate`` False:
    only the stored rows."""
    from biped_controller.closed_loop.executor import make_executor
    from biped_controller.studies.trial.record import seed_of
    out = []
    rows = [(lv, m, obs) for m, obs in combos(modes, observers) for lv in levels if seed_of(lv.perturbation) is not None]
    if not rows:
        log("--seeds: no row draws noise: every row is exact (one trial decides)")
        return out
    done = {r["key"]: r for r in (store.load() if store is not None else []) if r.get("kind") == "seeded"}
    T = context(ROBOT or None).family.T
    keys = {(lv.name, m, obs): _seeded_key(lv, m, obs, seeds, survival_levels, full_trials) for lv, m, obs in rows}
    todo = [row for row in rows if keys[(row[0].name, row[1], row[2])] not in done]
    log(f"seeded rows: {len(todo)} to run, {len(rows) - len(todo)} stored")
    with make_executor(workers if (todo and simulate) else 1, initializer=context) as ex:
        for lv, m, obs in rows:
            key = keys[(lv.name, m, obs)]
            if key in done:
                out.append(done[key]["row"])
                continue
            if not simulate:
                continue
            sr = search_for(m)
            t0 = time.perf_counter()
            r = seeded.seeded_table((m,), seeds, sr.resolution, sr.fmax, sr.coarse, levels=survival_levels,
                                    duration=PUSH_CELL["duration"], start=PUSH_CELL["phase"] * T, progress=False,
                                    settings=settings_for(lv.perturbation, obs, full_trials), executor=ex)[m]
            rec = {k: v for k, v in r.items() if k != "trials"}
            rec.update(level=lv.name, observer=obs, trials=len(r["trials"]))
            if store is not None:
                store.append([{"kind": "seeded", "key": key, "row": rec}])
            out.append(rec)
            log(f"  seeded max push {lv.name:<28} {m:<4} observer {'on ' if obs else 'off'}: " + ", ".join(
                f"{100 * c['level']:g} % {c['estimate']} N {c['interval']}" for c in r["crossings"])
                + f" ({len(r['trials'])} trials, {time.perf_counter() - t0:.0f} s)")
    return out


def seeded_markdown(records: list[dict], seeds: int) -> list[str]:
    """The table of :func:`run_seeded_pushes`: per noisy row, mode and observer, the crossing forces with
    their intervals and the seeds counted apart at the largest force tried."""
    levels = records[0]["levels"]
    out = [f"Max push over {seeds} seeds (rows whose plant draws noise; the others are exact): the force [N] at "
           f"which survival crosses each level, its interval in brackets (Wilson 95 %; 0 / unbounded: no force "
           f"tried excludes the level on that side)", "",
           "| perturbation | mode | observer | " + " | ".join(f"{100 * c:g} % crossing [N]" for c in levels)
           + " | seeds apart (unpushed fall / fault) |", "|" + " --- |" * (4 + len(levels))]
    for r in records:
        cells = []
        for c in r["crossings"]:
            lo, hi = c["interval"]
            cells.append("-" if c["estimate"] is None else
                         f"{c['estimate']:g} [{'0' if lo is None else format(lo, 'g')}, "
                         f"{'unbounded' if hi is None else format(hi, 'g')}]")
        last = r["rates"][-1] if r["rates"] else {"unpushed_falls": 0, "faults": 0}
        out.append(f"| {r['level']} | {r['mode']} | {'on' if r['observer'] else 'off'} | " + " | ".join(cells)
                   + f" | {last['unpushed_falls']} / {last['faults']} |")
    return out


# ------------------------------------------------------------------------------------------ table
def _walk_cell(r: dict | None) -> str:
    if r is None:
        return "-"
    if r["survived"]:
        return "yes"
    return f"no: {r['fall_cause']} (step {r['steps_walked'] + 1}, t = {r['fall_time']:.3f} s)"


def _push_cell(r: dict | None) -> str:
    if r is None:
        return "-"
    s = f"{r['max_force']:g}" if not r["censored"] else f">= {r['max_force']:g}"
    if r["islands"]:
        s += " (isl. " + ", ".join(f"{x:g}" for x in r["islands"]) + ")"
    nf = r.get("max_force_no_fall")
    if r.get("no_fall_undefined"):
        s += " [no-fall edge undefined: controller fault]"
    elif nf is not None:
        s += f" [no fall to {nf:g}]" if r.get("first_fall") is None else f" [no-fall edge {nf:g}]"
    return s


def table_markdown(levels, modes, observers, walks: dict, pushes: dict) -> str:
    """The robustness table (markdown): per level, the 20-step walk (the (mode, observer) pairs that have
    walk records) and the max push [N] per mode and observer setting; a max push of 0 where that walk
    already fails is marked "(no walk)"."""
    def walk(lv, m, obs):
        return walks.get(_walk_key(lv.perturbation, m, obs, WALK_STEPS, walk_fingerprint(lv.perturbation, obs)))
    pairs = combos(modes, observers)
    walk_cols = [(m, obs) for m, obs in pairs if any(walk(lv, m, obs) is not None for lv in levels)]
    cols = ["perturbation"] + [f"walk {m}" + ("" if single_observer(m) else f" obs {'on' if obs else 'off'}")
                               for m, obs in walk_cols]
    cols += [f"max push {m}" + ("" if single_observer(m) else f" obs {'on' if obs else 'off'}") + " [N]" for m, obs in pairs]
    lines = ["| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols)]
    for lv in levels:
        row = [lv.name] + [_walk_cell(walk(lv, m, obs)) for m, obs in walk_cols]
        for m, obs in pairs:
            r = pushes.get((lv.name, m, obs))
            w = walk(lv, m, obs)
            cell = _push_cell(r)
            if r is not None and r["max_force"] == 0 and w is not None and not w["survived"]:
                cell += " (no walk)"
            row.append(cell)
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def figure(levels, modes, observers, pushes: dict, out: Path) -> Path:
    """Bar chart: the max push [N] per level (rows) for each mode and observer setting."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = [(m, obs) for m, obs in combos(modes, observers) if any((lv.name, m, obs) in pushes for lv in levels)]
    colors = {"none": "0.45", "tau": "tab:blue", "p": "tab:orange", "both": "tab:green", "wbc": "tab:purple",
              "hybrid": "tab:red", "lambda": "tab:brown", "all": "tab:cyan"}
    fig, ax = plt.subplots(figsize=(8.5, 0.42 * len(levels) + 1.6))
    y = np.arange(len(levels))
    hgt = 0.8 / max(len(series), 1)
    for i, (m, obs) in enumerate(series):
        vals = [pushes[(lv.name, m, obs)]["max_force"] if (lv.name, m, obs) in pushes else np.nan for lv in levels]
        ax.barh(y - 0.4 + (i + 0.5) * hgt, vals, height=hgt, color=colors[m], alpha=1.0 if obs else 0.45,
                hatch=None if obs else "//", label=f"{m}, observer {'on' if obs else 'off'}")
        # the no-fall edge where it lies above the survival boundary
        nf = [(pushes[(lv.name, m, obs)]["max_force_no_fall"], k) for k, lv in enumerate(levels)
              if (lv.name, m, obs) in pushes
              and pushes[(lv.name, m, obs)].get("max_force_no_fall", 0.0) > pushes[(lv.name, m, obs)]["max_force"]]
        if nf:
            ax.plot([f for f, _ in nf], [k - 0.4 + (i + 0.5) * hgt for _, k in nf], "|", ms=9, mew=2,
                    color=colors[m], label=f"{m}, observer {'on' if obs else 'off'}: no fall up to")
    ax.set_yticks(y)
    ax.set_yticklabels([lv.name for lv in levels], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("largest survivable back push, 0.025 s at mid first step [N]")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize=7, loc="center right", bbox_to_anchor=(1.0, 0.36))   # over the empty noise and delay rows
    ax.set_title("push recovery under plant perturbations (controller keeps the nominal model)", fontsize=9)
    out.mkdir(parents=True, exist_ok=True)
    p = out / "max_push.png"
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


# ------------------------------------------------------------------------------------------ CLI
def _levels(names: list[str] | None) -> tuple[Level, ...]:
    if not names:
        return LEVELS
    out = []
    for n in names:
        lv = LEVELS_BY_KEY.get(n) or LEVELS_BY_NAME.get(n)     # a key, or the table's text (quoted)
        if lv is None:
            raise RobustnessError(f"--levels: unknown level {n!r}; known keys: {' '.join(LEVELS_BY_KEY)}")
        out.append(lv)
    return tuple(out)


def _terminate(signum, frame):
    raise SystemExit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    ap = StudyArgumentParser(prog="scripts/robustness", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--levels", nargs="+", default=None, metavar="KEY",
                    help="level keys (default all): " + " ".join(LEVELS_BY_KEY))
    add_modes_arg(ap, None, "both,none without --controller; with --controller, only the controllers given")
    ap.add_argument("--controller", type=controller_arg, action="append", default=[], metavar="NAME",
                    help="a registered controller's rows (repeatable; observer off: it is the adaptive "
                         "controller's), beside the --modes given")
    ap.add_argument("--observer", nargs="+", choices=("on", "off"), default=["on", "off"])
    ap.add_argument("--what", choices=("walk", "push", "both"), default="both")
    ap.add_argument("--workers", type=positive_int, default=2)
    ap.add_argument("--store", type=Path, default=Path("build/robustness"), help="directory of the records")
    ap.add_argument("--json", type=Path, default=None, help="summary JSON")
    ap.add_argument("--table", type=Path, default=None, help="write the markdown table here")
    ap.add_argument("--figures", type=Path, default=None, help="directory for max_push.png")
    ap.add_argument("--full-trials", action="store_true",
                    help="run every survival trial in full (no early stop; it applies to the nominal plant only)")
    ap.add_argument("--report-only", action="store_true",
                    help="no simulation: the table, figure and JSON of what the store holds")
    ap.add_argument("--seeds", type=positive_int, default=None,
                    help="seeds per force for the rows whose plant draws noise: the max push as survival "
                         "probabilities over seeds (Wilson 95 %% intervals, crossing forces of --survival-levels)")
    ap.add_argument("--survival-levels", type=levels_arg, default=uncertainty.DEFAULT_LEVELS, metavar="C,C,...",
                    help="with --seeds: survival levels whose crossing forces are searched, each in (0, 1) "
                         "(default 0.9,0.5)")
    add_robot_arg(ap)
    ap.add_argument("--profile", type=profile_arg, default=DEFAULT_PROFILE,
                    help="config/profiles/ NAME: the controller and simulator settings of every row (the observer "
                         "is the table's column)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="a config/simulator.yaml setting for every run, e.g. --set plant=mujoco (repeatable)")
    args = ap.parse_args(argv)
    provenance.track(args.json, args.table, args.figures, args=args, argv=argv)   # record of each file written (results/README.md)
    global SIMULATOR_OVERRIDES, CONTROLLER_OVERRIDES, PROFILE, ROBOT
    try:
        given = parse_overrides(args.overrides)
        if given.controller:
            raise RobustnessError("--set: only config/simulator.yaml keys here (the table sets the controller's "
                                  f"observer itself), got {', '.join(k for k, _ in given.controller)}")
        st = parse_overrides(args.overrides, profile=args.profile, robot=args.robot)
        SIMULATOR_OVERRIDES = st.simulator
        CONTROLLER_OVERRIDES = tuple((k, v) for k, v in st.controller if k != "disturbance_observer")
        PROFILE = args.profile
        ROBOT = st.activate().robot
        survival_rule()          # config/studies.yaml's rule settings, checked before any simulation
        print_settings(st)
    except (*SETTINGS_ERRORS, RobustnessError) as exc:
        ap.error(str(exc))
    try:
        levels = under_profile(_levels(args.levels), st.perturbation)
    except (RobustnessError, PerturbationError) as exc:
        ap.error(str(exc))
    if st.perturbation is not None:
        print("the profile's plant perturbation lies under every row (a row's fields replace it): "
              + ", ".join(f"{k}={v}" for k, v in st.perturbation.as_dict().items()
                          if v != PlantPerturbation().as_dict()[k]))
    modes = tuple(dict.fromkeys((list(args.modes) if args.modes is not None else ([] if args.controller else ["both", "none"]))
                                + list(args.controller)))
    observers = tuple(o == "on" for o in args.observer)
    signal.signal(signal.SIGTERM, _terminate)
    walks_store = cmap.RecordStore(args.store / "walks.jsonl")
    push_store = cmap.RecordStore(args.store / "push.jsonl")
    t0 = time.perf_counter()
    log = _log
    walks = {}
    pushes = {}
    # one executor (the capability map's workers) for the walks and the push searches
    ex = None if args.report_only else cmap.make_executor(args.workers, None)
    try:
        if args.what in ("walk", "both"):
            walks = run_walks(levels, modes, observers, walks_store, ex if ex is not None else 1, log,
                              simulate=not args.report_only)
        if args.what in ("push", "both"):
            pushes = run_pushes(levels, modes, observers, push_store, ex, log, args.full_trials)
    finally:
        if ex is not None:
            ex.close()
    seeded_pushes = []
    if args.seeds is not None:
        seeded_pushes = run_seeded_pushes(levels, modes, observers, args.seeds, args.survival_levels, args.workers,
                                          args.full_trials, log, store=cmap.RecordStore(args.store / "seeded.jsonl"),
                                          simulate=not args.report_only)
    wall = time.perf_counter() - t0
    log(f"wall time {wall:.1f} s ({args.workers} workers)")
    table = table_markdown(levels, modes, observers, walks, pushes)
    if seeded_pushes:
        table += "\n" + "\n".join(seeded_markdown(seeded_pushes, args.seeds)) + "\n"
    print(table)
    if args.table is not None:
        args.table.parent.mkdir(parents=True, exist_ok=True)
        args.table.write_text(table, encoding="utf-8")
    figs = [str(figure(levels, modes, observers, pushes, args.figures))] if args.figures and pushes else []
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({
            "levels": [{"name": lv.name, "group": lv.group, "perturbation": lv.perturbation.as_dict()} for lv in levels],
            "walks": [walks[k] for k in sorted(walks)],
            "pushes": [dict(v, key=list(map(str, k))) for k, v in sorted(pushes.items(), key=str)],
            "searches": {m: {"coarse": s.coarse, "max": s.fmax, "resolution": s.resolution}
                         for m, s in {**SEARCHES, **{m: search_for(m) for m in modes}}.items()},
            "push_cell": PUSH_CELL, "walk_steps": WALK_STEPS, "figures": figs,
            "git": git_state(), "wall_time": wall, "workers": args.workers,
            "full_trials": args.full_trials,
            **({"seeded_pushes": seeded_pushes, "seeds": args.seeds} if seeded_pushes else {}),
            # the profile and what differs from the configuration files in every row (the observer: per row)
            "settings": differences(RunSettings(CONTROLLER_OVERRIDES, SIMULATOR_OVERRIDES, profile=PROFILE, robot=ROBOT))},
            indent=1), encoding="utf-8")
    return 0


def _log(msg: str) -> None:
    print(msg, flush=True)


if __name__ == "__main__":
    sys.exit(main())
