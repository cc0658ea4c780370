"""The residual action's inner loop: a policy that moves the targets of the product's computed-torque law
instead of commanding torques (``action_mode: residual`` of ``config/policy_env.yaml``; docs/policies.md).

The action a in [-1, 1]^6 of a policy period is the offset delta = a * s [rad] (s the ``residual_scale``, one
per joint)
on the gait family's preferred reference; at every plant control period beneath the policy period the torque
is mode ``none``'s law (``policy.teacher``, eqs. (16)-(17)) on the offset reference,

    Gamma = A(q) (q_d'' + Kv (q_d' - q') + Kp (q_d + delta - q)) + H(q, q'),    clipped to [-tau_max, tau_max],

with q_d = q_d(p_d, s), q_d' = dq_d/dtau, q_d'' = d2q_d/dtau2 at the time in stance s, (q, q') the sensed
joint state of that period (the observation vector of ``policy.spec``), in paper order of the sensed stance.
So delta = 0 is mode ``none``, and a policy changes the commanded acceleration by Kp delta [rad/s^2]: the
torque it can add at a joint scales with the inertia that joint drives (A Kp delta), where a torque action
gives the light swing foot the same range as the hip (docs/policies_training.md says why that mattered).

The environment (``policy.env``) and the policy controller (``policy.controller``) both call
:meth:`ResidualLaw.torque` on the same vector each period, so the two give the same torques bit for bit.
Pure NumPy over the controller-side model, no ROS.
"""
from __future__ import annotations

import numpy as np

from biped_model.description import RobotDescription
from biped_model.gait_family import GaitFamily

from biped_controller.plugin.model import Gains
from biped_controller.policy.spec import torque_limits
from biped_controller.policy.teacher import TeacherPolicy


def config_gains() -> dict[str, float]:
    """The law's gains as a policy file records them: ``{"Kp": [1/s^2], "Kv": [1/s]}`` of
    ``config/controller.yaml`` (what the environment's law uses)."""
    g = Gains.from_config()
    return {"Kp": g.Kp, "Kv": g.Kv}


class ResidualLaw:
    """``torque(obs (22,), delta (6,) [rad]) -> (6,) [N m]`` (module docstring); ``scale`` [rad] is s, a number
    or six (paper joint order)."""

    def __init__(self, desc: RobotDescription, family: GaitFamily, scale, gains: Gains | None = None):
        self.scale = self.check_scale(scale)
        self.teacher = TeacherPolicy(desc, family, gains)
        self.gains = self.teacher.gains
        self.limits = torque_limits(desc)

    @staticmethod
    def check_scale(scale) -> np.ndarray:
        """s as a (6,) array [rad] from a number or six; ``ValueError`` naming it unless all are finite > 0."""
        try:
            s = np.broadcast_to(np.asarray(scale, dtype=float), (6,)).copy()
        except (TypeError, ValueError):
            raise ValueError(f"residual_scale must be a number > 0 [rad] or six of them, got {scale!r}") from None
        if not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ValueError(f"residual_scale must be finite numbers > 0 [rad], got {scale!r}")
        return s

    def offset(self, action: np.ndarray) -> np.ndarray:
        """delta = clip(a, -1, 1) * s [rad] (a NaN stays NaN: the loop's guard records it as a fault)."""
        return np.clip(np.asarray(action, dtype=float), -1.0, 1.0) * self.scale

    def torque(self, obs: np.ndarray, delta: np.ndarray) -> np.ndarray:
        return np.clip(self.teacher.torque(obs, delta), -self.limits, self.limits)
