"""What a controller knows of the robot, reachable from the plug-in package alone (``ControllerSetup.model``,
``ControllerSetup.gains``, ``ControllerSetup.reference``).

Coordinates and units (DESIGN.md): paper joint coordinates q1..q6 of the current stance (stance ankle,
stance knee, stance hip, swing hip, swing knee, swing ankle) [rad], rates [rad/s], accelerations [rad/s^2],
torques [N m]; the stance foot is flat on the ground and pinned (single support, the paper's eqs. 1-10);
positions relative to the stance ankle, x forward, y up [m].

* :class:`RobotModel`: the fixed-stance-foot model of the robot as the controller knows it (the nominal
  description, not a perturbed plant): the dynamics A(q) q'' + H(q, q') = Gamma (eq. 1) with the ground
  reaction rows [R_x, R_y, m_a] = B q'' + h_b, and the centre of mass x_G, its velocity J_G q' and its
  drift J_G' q' (eqs. 2-4);
* :class:`Gains`: the joint PD gains of the built-in controller's computed-torque law (eq. 16),
  ``config/controller.yaml``;
* :class:`Reference`: the gait family q_d(p, tau) (stride p [m], phase tau [s]): :meth:`Reference.at`
  gives q_d and its partial derivatives by name (:class:`ReferencePoint`), :meth:`ReferencePoint.motion`
  the reference motion along given p', tau', p'', tau'' (eq. 11: :class:`ReferenceMotion`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from biped_model.description import RobotDescription
from biped_model.fixed_foot import Dynamics, FixedFootModel
from biped_model.gait_family import GaitFamily, GaitSample, eq11

from biped_controller.core.control.config import load_controller_config

__all__ = ["ComState", "ComTerms", "Dynamics", "Gains", "Reference", "ReferenceMotion", "ReferencePoint",
           "RobotModel"]


@dataclass(frozen=True)
class Gains:
    """The joint PD gains of the computed-torque law w = q_d'' + Kv (q_d' - q') + Kp (q_d - q) (eq. 16):
    ``Kp`` [1/s^2], ``Kv`` [1/s]."""

    Kp: float
    Kv: float

    @classmethod
    def from_config(cls) -> "Gains":
        """The built-in controller's gains, ``config/controller.yaml``'s ``Kp`` and ``Kv``."""
        cfg = load_controller_config()
        return cls(Kp=float(cfg.Kp), Kv=float(cfg.Kv))


@dataclass(frozen=True)
class ComState:
    """The centre of mass relative to the stance ankle: ``position`` x_G = (x, height) [m] and
    ``velocity`` x_G' = J_G(q) q' [m/s], both (2,)."""

    position: np.ndarray
    velocity: np.ndarray


@dataclass(frozen=True)
class ComTerms:
    """Eqs. (2)-(4) at (q, q'): ``position`` x_G (2,) [m], ``jacobian`` J_G = dx_G/dq (2, 6) [m/rad],
    ``drift`` J_G'(q, q') q' (2,) [m/s^2] (the CoM's acceleration at q'' = 0), so that
    x_G'' = J_G q'' + drift."""

    position: np.ndarray
    jacobian: np.ndarray
    drift: np.ndarray


class RobotModel:
    """The controller-side model of ``desc`` (module docstring): Pinocchio on the fixed-stance-foot chain,
    with its own data (never the plant's). ``mass`` [kg] (both feet included), ``gravity`` [m/s^2],
    ``torque_min``, ``torque_max`` (6,) [N m] the joint torque limits in paper order."""

    def __init__(self, desc: RobotDescription):
        self.desc = desc
        self._m = FixedFootModel(desc)
        self.mass = self._m.mass
        self.gravity = float(desc.gravity)
        self.torque_min = self._m.torque_min.copy()
        self.torque_max = self._m.torque_max.copy()

    def dynamics(self, q: np.ndarray, qd: np.ndarray) -> Dynamics:
        """``A`` (6, 6) [kg m^2] the inertia matrix and ``H`` (6,) [N m] the Coriolis, centrifugal and gravity
        torques of A(q) q'' + H(q, q') = Gamma (eq. 1); ``B`` (3, 6) and ``h_b`` (3,) the ground's reaction
        [R_x, R_y, m_a] = B q'' + h_b [N, N, N m] on the stance foot."""
        return self._m.dynamics(np.asarray(q, dtype=float), np.asarray(qd, dtype=float))

    def com(self, q: np.ndarray) -> np.ndarray:
        """x_G (2,) [m]: the centre of mass (forward, height) relative to the stance ankle."""
        return self._m.com(np.asarray(q, dtype=float))

    def com_state(self, q: np.ndarray, qd: np.ndarray) -> ComState:
        """x_G [m] and x_G' = J_G q' [m/s] (cheaper than :meth:`com_terms`)."""
        c, v = self._m.com_velocity(np.asarray(q, dtype=float), np.asarray(qd, dtype=float))
        return ComState(c, v)

    def com_terms(self, q: np.ndarray, qd: np.ndarray) -> ComTerms:
        """x_G, J_G and the drift J_G' q' at (q, q') (eqs. 2-4)."""
        c, J, drift = self._m.com_terms(np.asarray(q, dtype=float), np.asarray(qd, dtype=float))
        return ComTerms(c, J, drift)


@dataclass(frozen=True)
class ReferenceMotion:
    """The reference motion at one instant: ``q`` = q_d [rad], ``qd`` = q_d' [rad/s], ``qdd`` = q_d''
    [rad/s^2], each (6,)."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


@dataclass(frozen=True)
class ReferencePoint:
    """q_d and its partial derivatives at stride ``p`` [m] and phase ``tau`` [s], each (6,): ``q`` [rad],
    ``dq_dp`` [rad/m], ``dq_dtau`` [rad/s], ``d2q_dp2`` [rad/m^2], ``d2q_dtau2`` [rad/s^2], ``d2q_dp_dtau``
    [rad/(m s)]."""

    p: float
    tau: float
    q: np.ndarray
    dq_dp: np.ndarray
    dq_dtau: np.ndarray
    d2q_dp2: np.ndarray
    d2q_dtau2: np.ndarray
    d2q_dp_dtau: np.ndarray

    def motion(self, p_dot: float, tau_dot: float, p_ddot: float = 0.0, tau_ddot: float = 0.0) -> ReferenceMotion:
        """Eq. (11) with p' [m/s], tau' [-], p'' [m/s^2], tau'' [1/s]:
        q_d' = dq/dp p' + dq/dtau tau',
        q_d'' = dq/dp p'' + dq/dtau tau'' + d2q/dp2 p'^2 + d2q/dtau2 tau'^2 + 2 d2q/dpdtau p' tau'."""
        g = GaitSample(self.q, self.dq_dp, self.dq_dtau, self.d2q_dp2, self.d2q_dtau2, self.d2q_dp_dtau)
        q, qd, qdd = eq11(g, float(p_dot), float(tau_dot), float(p_ddot), float(tau_ddot))
        return ReferenceMotion(q, qd, qdd)


class Reference:
    """The gait family as a controller reads it: q_d(p, tau) for p in [``p_min``, ``p_max``] [m] and tau in
    [0, ``T``] [s] (``T`` the preferred step's duration), ``p_d`` [m] the preferred stride."""

    def __init__(self, family: GaitFamily):
        self.family = family
        self.T, self.p_d, self.p_min, self.p_max = float(family.T), float(family.p_d), float(family.p_min), float(
            family.p_max)

    def at(self, p: float, tau: float) -> ReferencePoint:
        """q_d and its five partial derivatives at (p [m], tau [s])."""
        g = self.family.evaluate(float(p), float(tau))
        return ReferencePoint(float(p), float(tau), g.q, g.dq_dp, g.dq_dtau, g.d2q_dp2, g.d2q_dtau2, g.d2q_dp_dtau)

    def motion(self, p: float, tau: float, p_dot: float, tau_dot: float, p_ddot: float = 0.0,
               tau_ddot: float = 0.0) -> ReferenceMotion:
        """``at(p, tau).motion(p_dot, tau_dot, p_ddot, tau_ddot)`` (eq. 11)."""
        return self.at(p, tau).motion(p_dot, tau_dot, p_ddot, tau_ddot)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Where every run starts: (q_d(p_d, 0) [rad], dq_d/dtau(p_d, 0) [rad/s]) (tau' = 1)."""
        return self.family.initial_state()
