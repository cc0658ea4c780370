"""The largest survivable push of any interface controller, by the studies' search and survival rule.

A trial: the push (``Push(start, duration, force)``, + forward, on the back) then ``SURVIVAL_STEPS``
touchdowns after its end (``trial.runs.push_step_index`` + 1 + SURVIVAL_STEPS steps in all, time limit
(steps + 3) 3 T), run in full (no early stop: the studies' early stop reads the adaptive controller's
parameters). Survived: no fall, no controller fault, SURVIVAL_STEPS touchdowns at or after the push's
end, and, where the controller's last status reports them, p and tau_dot back within the band of the
one survival rule (``trial.survival``: the floors 1 mm / 1e-3 or k times the controller's own unpushed
walk's excursion); a controller without a stride or a time scaling is judged by the fall and the step
count alone.

The search (``trial.search.max_push_modes``'s): forces ``coarse, 2 coarse, ..., fmax`` [N]; the last
survivable force below the first failure, then the edge bisected to ``resolution`` [N]; survivable
coarse forces above the first failure are reported as islands, and beside this strict boundary the no-fall
edge (the largest force tried below the lowest one that fell, ``first_fall``: the plant comparison's second
figure; undefined, None with ``no_fall_undefined`` saying why, when the lowest force that fell or faulted
faulted: a faulted trial is neither a survival nor a fall). One process.
"""
from __future__ import annotations

import functools
from dataclasses import replace
import math
from typing import Mapping

from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.push import Push
from biped_model.description import RobotDescription, load_description
from biped_model.gait_family import GaitFamily

from biped_controller.plugin.loop import PluginLoop
from biped_controller.plugin.result import RunResult
from biped_controller.studies.trial import record
from biped_controller.studies.trial.runs import DEFAULT_DURATION, DEFAULT_START, push_step_index
from biped_controller.studies.trial.record import faulted
from biped_controller.studies.trial.scan import analyse_coarse, coarse_forces, no_fall_undefined
from biped_controller.studies.trial.settings import RunSettings
from biped_controller.studies.trial.survival import FLOOR_BAND, SURVIVAL_STEPS, Band, SurvivalRule, survival_rule


def plugin_band(controller: str, settings: RunSettings, steps: int) -> Band:
    """The survival rule's band (``trial.survival``) for a plug-in's trial of ``steps`` touchdowns with
    ``settings``: its own unpushed walk's excursion of the ``p`` and ``tau_dot`` it reports (none reported:
    the floors), run once per process."""
    return _plugin_band(controller, settings, int(steps), survival_rule())


@functools.lru_cache(maxsize=64)
def _plugin_band(controller: str, settings: RunSettings, steps: int, rule: SurvivalRule) -> Band:
    return walk_band(trials_for(controller, settings).loop, steps, rule)


def walk_band(loop: PluginLoop, steps: int, rule: SurvivalRule) -> Band:
    """The band of ``loop``'s controller from its unpushed walk of ``steps`` touchdowns (the floors when it
    falls or faults), with which of p and tau' it reports (``Band.checks_p``, ``Band.checks_tau_dot``)."""
    res = loop.run(steps, (), keep_records=True)
    # what the controller reports, from every status of its walk (none before a fault at its first period)
    checks = {"checks_p": any("p" in st for st in res.statuses),
              "checks_tau_dot": any("tau_dot" in st for st in res.statuses)}
    if res.fault is not None:
        return replace(FLOOR_BAND, unpushed_fault=str(res.fault), **checks)
    if res.fallen:
        return replace(FLOOR_BAND, unpushed_fall=f"{res.fall_cause} at t = {res.fall_time:.4f} s", **checks)
    t0 = rule.window_start(res.impacts)
    win = [st for rec, st in zip(res.records, res.statuses) if rec.t >= t0]
    band = rule.band_from_series([float(st["p"]) for st in win if "p" in st],
                                 [float(st["tau_dot"]) for st in win if "tau_dot" in st])
    return replace(band, **checks)


def survival(result: RunResult, push_end: float, band: Band = FLOOR_BAND) -> tuple[bool, bool, str]:
    """(survived, fell, reason): the one survival rule (``trial.survival.SurvivalRule.judge``) on a plug-in's
    run, its last status's ``p`` and ``tau_dot`` checked where it reports them; a controller fault is a
    failure that is not a fall."""
    if result.fault is not None:
        return False, False, f"controller fault: {result.fault}"
    last = result.last_status
    v = survival_rule().judge(result.fallen, f"{result.fall_cause} at t = {result.fall_time:.4f} s", result.impacts,
                              push_end, float(last["p"]) if "p" in last else None,
                              float(last["tau_dot"]) if "tau_dot" in last else None, band)
    return v.survived, v.fell, v.reason


class PushTrials:
    """Survival trials of one controller on one plant (one :class:`PluginLoop`, reused)."""

    def __init__(self, controller: str | object, *, sim_config: SimConfig | None = None,
                 family: GaitFamily | None = None, desc: RobotDescription | None = None,
                 perturbation: PlantPerturbation | None = None, options: Mapping[str, object] | None = None):
        self.family = family if family is not None else GaitFamily.load()
        self.loop = PluginLoop(controller, sim_config=sim_config if sim_config is not None else load_sim_config(),
                               family=self.family, desc=desc if desc is not None else load_description(),
                               perturbation=perturbation, options=options)
        self.perturbation = perturbation
        self.trials = 0
        self._bands: dict[tuple[int, SurvivalRule], Band] = {}

    def _band(self, steps: int) -> Band:
        """The survival band of a trial of ``steps`` touchdowns: this controller's unpushed walk, once."""
        rule = survival_rule()
        if (steps, rule) not in self._bands:
            self._bands[(steps, rule)] = walk_band(self.loop, steps, rule)
        return self._bands[(steps, rule)]

    def survives(self, force: float, duration: float = DEFAULT_DURATION, start: float = DEFAULT_START,
                 height: float | None = None) -> dict:
        """One trial (JSON-ready): force [N], survived, fell, reason, fall cause and time, steps walked,
        ``fault`` (the fault's kind, None without one) and the trial record's ``seed`` and ``fault_kind``
        (``trial.record``)."""
        steps = push_step_index(Push(start, duration, 0.0), self.family.T) + 1 + SURVIVAL_STEPS
        res = self.loop.run(steps, (Push(start, duration, float(force), height),), keep_records=False)
        self.trials += 1
        ok, fell, why = survival(res, start + duration, self._band(steps))
        return {"force": float(force), "controller": self.loop.name, "survived": ok, "fell": fell, "reason": why,
                "fall_cause": res.fall_cause, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
                "steps_walked": int(res.steps_walked),
                "fault": None if res.fault is None else res.fault.kind,
                "seed": record.seed_of(self.perturbation), "fault_kind": record.fault_kind_of(res.fault)}

    def max_push(self, resolution: float = 5.0, fmax: float = 2000.0, coarse: float = 50.0,
                 duration: float = DEFAULT_DURATION, start: float = DEFAULT_START, height: float | None = None,
                 sign: float = 1.0) -> dict:
        """The largest survivable push [N] (module docstring): ``max_force``, ``first_failure``, the
        ``islands`` and every trial."""
        trials = []
        for f in coarse_forces(fmax, coarse):
            trials.append(dict(self.survives(sign * f, duration, start, height), force=f))
        lo, hi, islands = analyse_coarse(trials)
        while hi is not None and hi - lo > resolution:
            mid = 0.5 * (lo + hi)
            r = dict(self.survives(sign * mid, duration, start, height), force=mid)
            trials.append(r)
            if r["survived"]:
                lo = mid
            else:
                hi = mid
        trials.sort(key=lambda r: r["force"])
        first = next((r for r in trials if r["force"] == hi), None) if hi is not None else None
        ended = [r for r in trials if r["fall_cause"] or faulted(r)]     # fell, or faulted: its fall unknown
        first_end = min(ended, key=lambda r: r["force"]) if ended else None
        undefined = no_fall_undefined(first_end)
        first_fall = first_end["force"] if first_end is not None and undefined is None else None
        below = [r["force"] for r in trials if first_end is None or r["force"] < first_end["force"]]
        no_fall_edge = None if undefined is not None else max(below) if below else 0.0
        return {"controller": self.loop.name, "plant": self.loop.scfg.plant, "max_force": lo, "first_failure": hi,
                "failure_cause": first["reason"] if first else None, "islands": islands,
                "first_fall": first_fall, "no_fall_edge": no_fall_edge,
                **({} if undefined is None else {"no_fall_undefined": undefined}), "resolution": resolution,
                "coarse_step": coarse, "scan_max": fmax, "duration": duration, "start": start, "height": height,
                "direction": "forward" if sign > 0 else "backward", "trials": trials}


@functools.lru_cache(maxsize=8)
def trials_for(controller: str, settings: RunSettings) -> PushTrials:
    """This process's :class:`PushTrials` of ``controller`` (a registered name, resolved here: in a sweep's
    worker process or Ray task) on the plant of ``settings`` (its simulator settings and perturbation)."""
    from biped_controller.studies.trial.context import context
    ctx = context(settings.activate().robot)
    return PushTrials(controller, sim_config=settings.sim_config(), family=ctx.family, desc=ctx.desc,
                      perturbation=settings.perturbation)


def survives_push(push: Push, controller: str, settings: RunSettings) -> dict:
    """One survival trial of a plug-in controller in the shape of ``trial.trials.survives``'s record
    (force, mode = the controller's name, survived, reason, fall cause and time, steps walked,
    ``decided_at_step`` None: run in full) plus ``fault`` (the fault's kind, None without one). The
    rule is :func:`survival` with the band of the controller's own unpushed walk (:func:`plugin_band`)."""
    settings.activate()
    tr = trials_for(controller, settings)
    steps = push_step_index(push, tr.family.T) + 1 + SURVIVAL_STEPS
    res = tr.loop.run(steps, (push,), keep_records=False)
    tr.trials += 1
    ok, fell, why = survival(res, push.start + push.duration, plugin_band(controller, settings, steps))
    return {"force": float(push.force), "mode": controller, "survived": ok, "fell": fell, "reason": why,
            "fall_cause": res.fall_cause, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
            "steps_walked": int(res.steps_walked), "decided_at_step": None,
            "fault": None if res.fault is None else res.fault.kind}
