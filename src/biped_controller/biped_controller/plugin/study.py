"""The largest survivable push of any interface controller, by the studies' search and survival rule.

A trial: the push (``Push(start, duration, force)``, + forward, on the back) then ``SURVIVAL_STEPS``
touchdowns after its end (``experiment.push_step_index`` + 1 + SURVIVAL_STEPS steps in all, time limit
(steps + 3) 3 T), run in full (no early stop: the studies' early stop reads the adaptive controller's
parameters). Survived: no fall, no controller fault, SURVIVAL_STEPS touchdowns at or after the push's
end, and, where the controller's last status reports them, |p - p_d| <= P_TOL [m] and
|tau_dot - 1| <= TAU_DOT_TOL (the return to the preferred gait of ``experiment.survival``; a controller
without a stride or a time scaling is judged by the fall and the step count alone).

The search (``experiment.max_push_modes``'s): forces ``coarse, 2 coarse, ..., fmax`` [N]; the last
survivable force below the first failure, then the edge bisected to ``resolution`` [N]; survivable
coarse forces above the first failure are reported as islands, and beside this strict boundary the no-fall
edge (the largest force tried below the lowest one that fell, ``first_fall``: the plant comparison's second
figure). One process.
"""
from __future__ import annotations

import math
from typing import Mapping

from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.push import Push
from biped_sim.robot.description import RobotDescription, load_description
from biped_sim.robot.gait_family import GaitFamily

from biped_controller.plugin.loop import PluginLoop, PluginRunResult
from biped_controller.studies.experiment import (DEFAULT_DURATION, DEFAULT_START, P_TOL, SURVIVAL_STEPS, TAU_DOT_TOL,
                                                 analyse_coarse, coarse_forces, push_step_index)


def survival(result: PluginRunResult, push_end: float, p_d: float, steps_after: int = SURVIVAL_STEPS
             ) -> tuple[bool, str]:
    """(survived, reason) by the rule of the module docstring."""
    if result.fault is not None:
        return False, f"controller fault: {result.fault}"
    if result.fallen:
        return False, f"fell: {result.fall_cause} at t = {result.fall_time:.4f} s"
    after = sum(1 for i in result.impacts if i.t >= push_end)
    if after < steps_after:
        return False, f"only {after} steps after the push (time limit)"
    last = result.last_status
    if "p" in last and not abs(float(last["p"]) - p_d) <= P_TOL:
        return False, f"p = {float(last['p']):.5f} m not back to p_d (|p - p_d| > {P_TOL})"
    if "tau_dot" in last and not abs(float(last["tau_dot"]) - 1.0) <= TAU_DOT_TOL:
        return False, f"tau' = {float(last['tau_dot']):.5f} not back to 1 (> {TAU_DOT_TOL})"
    return True, "survived"


class PushTrials:
    """Survival trials of one controller on one plant (one :class:`PluginLoop`, reused)."""

    def __init__(self, controller: str | object, *, sim_config: SimConfig | None = None,
                 family: GaitFamily | None = None, desc: RobotDescription | None = None,
                 perturbation: PlantPerturbation | None = None, options: Mapping[str, object] | None = None):
        self.family = family if family is not None else GaitFamily.load()
        self.loop = PluginLoop(controller, sim_config=sim_config if sim_config is not None else load_sim_config(),
                               family=self.family, desc=desc if desc is not None else load_description(),
                               perturbation=perturbation, options=options)
        self.trials = 0

    def survives(self, force: float, duration: float = DEFAULT_DURATION, start: float = DEFAULT_START,
                 height: float | None = None) -> dict:
        """One trial (JSON-ready): force [N], survived, reason, fall cause and time, steps walked, fault."""
        steps = push_step_index(start, duration, self.family.T) + 1 + SURVIVAL_STEPS
        res = self.loop.run(steps, (Push(start, duration, float(force), height),), keep_records=False)
        self.trials += 1
        ok, why = survival(res, start + duration, self.family.p_d)
        return {"force": float(force), "controller": self.loop.name, "survived": ok, "reason": why,
                "fall_cause": res.fall_cause, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
                "steps_walked": int(res.steps_walked),
                "fault": None if res.fault is None else res.fault.kind}

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
        fell = [r["force"] for r in trials if r["fall_cause"]]
        first_fall = min(fell) if fell else None
        below = [r["force"] for r in trials if first_fall is None or r["force"] < first_fall]
        return {"controller": self.loop.name, "plant": self.loop.scfg.plant, "max_force": lo, "first_failure": hi,
                "failure_cause": first["reason"] if first else None, "islands": islands,
                "first_fall": first_fall, "no_fall_edge": max(below) if below else 0.0, "resolution": resolution,
                "coarse_step": coarse, "scan_max": fmax, "duration": duration, "start": start, "height": height,
                "direction": "forward" if sign > 0 else "backward", "trials": trials}
