"""A closed loop (simulator + controller, the order of ``runner.run``) that also keeps, per period, the true
state, the controller's estimate and its momentum observer's output: the tests compare them."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from biped_model.description import LEFT, load_description
from biped_model.gait_family import GaitFamily
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.rigid import Simulator

from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController


@dataclass
class Trace:
    t: list = field(default_factory=list)
    stance: list = field(default_factory=list)         # true stance at the period start
    told: list = field(default_factory=list)           # stance the sensors reported
    q: list = field(default_factory=list)              # true q, q' at the period start
    qd: list = field(default_factory=list)
    torque: list = field(default_factory=list)         # applied (record, true stance order)
    est: list = field(default_factory=list)            # (q, qd, P) of the estimator or None
    r: list = field(default_factory=list)              # momentum observer's r or None
    W: list = field(default_factory=list)
    obs: list = field(default_factory=list)            # what the controller was given: (t, q, qd, stance, pitch)
    sent: list = field(default_factory=list)           # the torque it returned (paper order of the told stance)
    wrench: list = field(default_factory=list)         # its momentum observer's Wrench or None
    band: list = field(default_factory=list)           # the period's TouchdownBand (touchdown_band.py) or None
    records: list = field(default_factory=list)
    statuses: list = field(default_factory=list)
    fall: object = None


def closed_loop(t_end: float, perturbation: PlantPerturbation | None = None, pushes=(), steps: int | None = None,
                python_sensing: bool = True, **overrides) -> Trace:
    """``python_sensing``: the Python cores (the oracle) or, False, the compiled pipeline (fast engine)."""
    fam = GaitFamily.load()
    desc = load_description()
    sim = Simulator(desc, perturbation=perturbation)
    ctrl = AdaptiveController(load_controller_config(mode="both", **overrides), fam, desc,
                              python_sensing=python_sensing)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    for p in pushes:
        sim.schedule_push(*p)
    tr = Trace()
    tr.ctrl = ctrl
    while sim.t < t_end and sim.fall is None and (steps is None or sim.impact_count < steps):
        q, qd = sim.fm.paper_from_state(sim.x, sim.v, sim.stance)
        tr.t.append(sim.t)
        tr.stance.append(sim.stance)
        tr.q.append(q)
        tr.qd.append(qd)
        obs = sim.observe()
        tr.told.append(obs.stance)
        out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch, obs.pitch_rate)
        tr.obs.append((obs.t, np.array(obs.q), np.array(obs.qd), obs.stance, obs.pitch, obs.pitch_rate))
        tr.sent.append(np.array(out.torque))
        tr.wrench.append(ctrl.wrench)
        sp = ctrl._sensing
        if sp is not None and getattr(sp, "est", None) is not None:
            e = sp.est.estimate()
            tr.est.append((e.q, e.qd, e.P))
        elif sp is not None and getattr(sp, "estimator", False):      # the compiled pipeline
            x, P = sp.state[:12].copy(), sp.P
            tr.est.append((x[:6], x[6:], P))
        else:
            tr.est.append(None)
        tr.band.append(getattr(sp, "band", None))
        tr.r.append(None if ctrl.wrench is None else ctrl.wrench.r)
        tr.W.append(None if ctrl.wrench is None else ctrl.wrench.W)
        rec = sim.step(out.torque)
        tr.torque.append(rec.torque)
        tr.records.append(rec)
        tr.statuses.append(out.status)
    tr.fall = sim.fall
    return tr
