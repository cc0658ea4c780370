"""In-process closed loop (no ROS, no DDS): Simulator + AdaptiveController, lockstep per control period.

The node graph does exactly this over DDS; ``run`` is the reference the DDS run is compared with.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from biped_sim.robot.description import LEFT, RobotDescription, load_description
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.push import Push
from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.records import ImpactRecord, StepRecord
from biped_sim.plant.rigid import Simulator

from biped_controller.core.controller import AdaptiveController, ControllerConfig, ControllerStatusData, load_controller_config
from biped_controller.studies.segment import Segment
from biped_sim.robot.gait_family import GaitFamily


@dataclass
class RunResult:
    records: list[StepRecord]
    statuses: list[ControllerStatusData]
    steps_walked: int
    fallen: bool
    fall_cause: str
    fall_detail: str
    fall_time: float
    impacts: list[ImpactRecord]
    # with keep_qp: (G, h, x*, qp_status) of every period that built a QP instance
    qp_instances: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] = field(default_factory=list)

    def series(self, name: str) -> np.ndarray:
        return np.array([getattr(s, name) for s in self.statuses])


def run(steps: int = 10, mode: str = "both", pushes: tuple[Push, ...] = (), *,
        sim_config: SimConfig | None = None, ctrl_config: ControllerConfig | None = None,
        family: GaitFamily | None = None, desc: RobotDescription | None = None,
        integration_rate: bool = False, keep_qp: bool = False, max_time: float | None = None,
        extra_time_after_steps: float = 0.0, perturbation: PlantPerturbation | None = None,
        compiled_loop: bool = True, keep_records: bool = True) -> RunResult:
    """Walk ``steps`` steps (impacts) or until a fall. ``integration_rate``: the controller's torque law is
    evaluated at every RK4 stage (no QP re-solve inside a period). ``perturbation`` (issue 14) goes to the
    simulator only: the plant and the sensors differ, the controller keeps ``desc``.

    ``compiled_loop`` (fast engine, ideal sensors, held torques, no ``keep_qp``): the periods where nothing
    needs Python run in the compiled loop (``segment.Segment``), with records identical to the objects'
    period by period (tested); the objects take every period with a QP, an impact or a fall.
    ``keep_records`` False (with the compiled loop): ``records``/``statuses`` keep only the periods the
    objects ran and the last period of each compiled segment -- the run's outcome (fall, impacts, the last
    status) is the same, the time series is not there."""
    desc = desc if desc is not None else load_description()
    family = family if family is not None else GaitFamily.load()
    scfg = sim_config if sim_config is not None else load_sim_config()
    ccfg = ctrl_config if ctrl_config is not None else load_controller_config(mode=mode, period=scfg.control_period)
    if ccfg.period != scfg.control_period:
        ccfg = ControllerConfig(**{**ccfg.__dict__, "period": scfg.control_period})
    sim = Simulator(desc, scfg, perturbation=perturbation)
    ctrl = AdaptiveController(ccfg, family, desc, keep_qp=keep_qp)
    q0, qd0 = family.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    for p in pushes:
        sim.schedule_push(p.start, p.duration, p.force, p.height)
    limit = max_time if max_time is not None else (steps + 3) * family.T * 3
    records, statuses, qps = [], [], []
    seg = None
    if compiled_loop and not integration_rate and not keep_qp and Segment.eligible(sim, ctrl):
        seg = Segment(sim, ctrl, keep_records=keep_records)
    while True:
        if seg is not None:
            t_stop = limit
            if sim.impact_count >= steps and extra_time_after_steps > 0:
                t_stop = min(limit, sim.impact_log[steps - 1].t + extra_time_after_steps)
            recs, stats = seg.run(t_stop)
            records += recs
            statuses += stats
            if recs and sim.t >= t_stop:
                break
        obs = sim.observe()
        out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance)
        statuses.append(out.status)
        if keep_qp and out.G is not None:
            qps.append((out.G, out.h, out.x_star, out.status.qp_status))
        if integration_rate:
            rec = sim.step(lambda s, q, qd, st: ctrl.torque_within_period(s, q, qd, st))
        else:
            rec = sim.step(out.torque)
        records.append(rec)
        if rec.fallen or sim.fall is not None:
            break
        if sim.impact_count >= steps:
            if extra_time_after_steps <= 0 or sim.t >= sim.impact_log[steps - 1].t + extra_time_after_steps:
                break
        if sim.t >= limit:
            break
    fall = sim.fall
    return RunResult(records=records, statuses=statuses, steps_walked=sim.impact_count,
                     fallen=fall is not None, fall_cause=fall.cause if fall else "",
                     fall_detail=fall.detail if fall else "", fall_time=fall.t if fall else math.nan,
                     impacts=list(sim.impact_log), qp_instances=qps)


def tracking_error(result: RunResult) -> float:
    return float(max(s.max_tracking_error for s in result.statuses))
