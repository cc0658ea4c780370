"""In-process closed loop (no ROS, no DDS) of any interface controller with the rigid or the MuJoCo plant.

The loop of ``closed_loop.runner.ClosedLoop.run`` (its Python-object path) with the controller interface in
place of ``AdaptiveController.compute``: each period the plant's ``observe()`` (its sensor model
applied) becomes an :class:`~biped_controller.plugin.interface.Observation` (with the torque the plant
applied over the previous period), ``on_touchdown`` is called when the sensed stance changed, the
controller's checked torque is held over the period by ``plant.step`` and the period's ``StepRecord``
and status mapping are kept. The run ends at ``steps`` touchdowns (plus ``extra_time_after_steps`` [s]),
a fall, ``limit`` [s], or a controller fault (``interface.ControllerFault``: recorded in the result,
not raised, so a sweep records the trial and goes on).

The controller never gets the plant: only observations.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.protocol import make_plant
from biped_sim.plant.push import Push
from biped_model.description import LEFT, RobotDescription, load_description
from biped_model.gait_family import GaitFamily

from biped_controller.plugin.interface import (ControllerFault, ControllerSetup, GuardedController, Observation,
                                               stamp_time)
from biped_controller.plugin.registry import make_controller
from biped_controller.plugin.result import RunResult


class PluginLoop:
    """One plant and one interface controller, built once and reusable across runs (:meth:`run` resets
    both). ``controller``: a registered name (``registry.load_controller``) or an already built controller
    (then ``name`` labels it); ``options`` go to the controller's :class:`ControllerSetup`."""

    def __init__(self, controller: str | object, *, sim_config: SimConfig | None = None,
                 family: GaitFamily | None = None, desc: RobotDescription | None = None,
                 perturbation: PlantPerturbation | None = None, options: Mapping[str, object] | None = None,
                 name: str | None = None):
        self.scfg = sim_config if sim_config is not None else load_sim_config()
        self.family = family if family is not None else GaitFamily.load()
        self.desc = desc if desc is not None else load_description()
        self.setup = ControllerSetup(self.desc, self.family, self.scfg.control_period, dict(options or {}))
        if isinstance(controller, str):
            self.ctrl = make_controller(controller, self.setup)
            self.name = controller
        else:
            self.name = name if name is not None else type(controller).__name__
            self.ctrl = controller if isinstance(controller, GuardedController) else GuardedController(controller,
                                                                                                        self.name)
        self.sim = make_plant(self.scfg.plant, self.desc, self.scfg, perturbation)

    def run(self, steps: int, pushes: tuple[Push, ...] = (), *, limit: float | None = None,
            extra_time_after_steps: float = 0.0, keep_records: bool = True) -> RunResult:
        """Reset plant and controller to the family's initial state (LEFT stance, t = 0), schedule
        ``pushes`` and walk (module docstring). ``limit`` [s] defaults to ``runner.run``'s,
        (steps + 3) 3 T. ``keep_records`` False: the outcome and the last status only."""
        sim, ctrl, fam = self.sim, self.ctrl, self.family
        limit = limit if limit is not None else (steps + 3) * fam.T * 3
        q0, qd0 = fam.initial_state()
        sim.reset(q0, qd0, LEFT)
        for p in pushes:
            sim.schedule_push(p.start, p.duration, p.force, p.height)
        records, statuses = [], []
        fault = None
        last_torque, last_stance, prev = np.zeros(6), None, None
        status: Mapping = {}
        n = 0
        try:
            ctrl.reset(sim.t, LEFT)
        except ControllerFault as exc:
            fault = exc
        while fault is None:
            raw = sim.observe()
            t = stamp_time(raw.t)
            obs = Observation.frozen(t, raw.step, raw.stance, raw.q, raw.qd, raw.pitch, raw.pitch_rate,
                                     last_torque, raw.stance if last_stance is None else last_stance)
            try:
                if prev is not None and raw.stance != prev:
                    ctrl.on_touchdown(t, raw.stance)
                out = ctrl.compute(obs)
            except ControllerFault as exc:
                fault = exc
                break
            prev = raw.stance
            status = out.status
            rec = sim.step(out.torque)
            n += 1
            if keep_records:
                records.append(rec)
                statuses.append(status)
            last_torque, last_stance = rec.torque, rec.stance
            if rec.fallen or sim.fall is not None:
                break
            if sim.impact_count >= steps:
                if extra_time_after_steps <= 0 or sim.t >= sim.impact_log[steps - 1].t + extra_time_after_steps:
                    break
            if sim.t >= limit:
                break
        fall = sim.fall
        return RunResult(controller=self.name, records=records, statuses=statuses,
                               steps_walked=sim.impact_count, fallen=fall is not None,
                               fall_cause=fall.cause if fall else "", fall_detail=fall.detail if fall else "",
                               fall_time=fall.t if fall else math.nan, impacts=list(sim.impact_log), fault=fault,
                               periods=n, last_status=dict(status))


def run(controller: str | object, steps: int = 10, pushes: tuple[Push, ...] = (), *,
        sim_config: SimConfig | None = None, family: GaitFamily | None = None, desc: RobotDescription | None = None,
        perturbation: PlantPerturbation | None = None, options: Mapping[str, object] | None = None,
        limit: float | None = None, extra_time_after_steps: float = 0.0, keep_records: bool = True
        ) -> RunResult:
    """One run of ``controller`` (a registered name or a built controller) on the plant of ``sim_config``
    (``plant: rigid`` or ``mujoco``): :class:`PluginLoop` built for it, then :meth:`PluginLoop.run`."""
    return PluginLoop(controller, sim_config=sim_config, family=family, desc=desc, perturbation=perturbation,
                      options=options).run(steps, pushes, limit=limit, extra_time_after_steps=extra_time_after_steps,
                                           keep_records=keep_records)
