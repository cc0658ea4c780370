"""The teacher of the learned baseline: the product's mode ``none`` (classical computed torque on the fixed
reference, ``plugin.builtin.ModeNone``) as a function of the policy observation (``policy.spec``) alone.

With p = p_d, p' = 0, tau' = 1, tau'' = 0 (mode none's reference: no adaptation) the reference at the time in
stance s [s] is q_d = q_d(p_d, s), q_d' = dq_d/dtau, q_d'' = d2q_d/dtau2 (eq. 11), and the law is eqs.
(16)-(17): Gamma = A(q) (q_d'' + Kv (q_d' - q') + Kp (q_d - q)) + H(q, q') [N m], in paper order of the
observed stance, with the model, gains and family the controller is built with (``plugin.interface
.ControllerSetup``). The action is Gamma / tau_max clipped to [-1, 1] (the plant clips the torque to its
limits the same way). Mode none reads its phase from its own clock (tau restarts at the sensed touchdown);
the observation's ``time_in_stance`` is that clock, so on the plug-in loop at the plant's period this
function gives mode none's torques (lab/ppo_teacher.py compares them period by period).

Pure NumPy over the controller-side model (``plugin.model``), no learner: a teacher for imitation and the
probes of lab/ppo_teacher.py and lab/ppo_dagger_probe.py (docs/policies_training.md).
"""
from __future__ import annotations

import numpy as np

from biped_model.description import RobotDescription
from biped_model.gait_family import GaitFamily

from biped_controller.plugin.model import Gains, RobotModel
from biped_controller.policy.spec import OBS_SIZE, torque_limits


class TeacherPolicy:
    """``teacher(obs (22,)) -> action (6,)`` in [-1, 1] (module docstring); ``torque(obs)`` [N m] unclipped."""

    def __init__(self, desc: RobotDescription, family: GaitFamily, gains: Gains | None = None):
        self.model = RobotModel(desc)
        self.family = family
        self.gains = gains if gains is not None else Gains.from_config()
        self.limits = torque_limits(desc)
        self.p_d = float(family.p_d)

    def torque(self, obs: np.ndarray, offset: np.ndarray | None = None) -> np.ndarray:
        """Gamma [N m] (module docstring), unclipped; ``offset`` (6,) [rad], when given, is added to q_d (the
        residual action of ``policy.residual``: Kp (q_d + offset - q))."""
        o = np.asarray(obs, dtype=float).reshape(-1)
        if o.shape != (OBS_SIZE,):
            raise ValueError(f"teacher: observation of shape {o.shape}, expected ({OBS_SIZE},)")
        q, qd, s = o[0:6], o[6:12], float(o[15])
        g = self.family.evaluate(self.p_d, s)
        e = g.q - q if offset is None else (g.q + offset) - q
        w = g.d2q_dtau2 + self.gains.Kv * (g.dq_dtau - qd) + self.gains.Kp * e
        dyn = self.model.dynamics(q, qd)
        return dyn.A @ w + dyn.H

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.clip(self.torque(obs) / self.limits, -1.0, 1.0)

    def batch(self, obs: np.ndarray) -> np.ndarray:
        """Actions (n, 6) for observations (n, 22)."""
        return np.stack([self(o) for o in np.asarray(obs, dtype=float)])
