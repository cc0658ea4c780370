"""The controller's model of the biped in single support (stance foot fixed), eqs. (1)-(10).

Pure Python + Pinocchio, no ROS. The kinematic chain starts at the stance foot and ends at the swing
foot, with the paper's joints q1..q6 (stance ankle, stance knee, stance hip, swing hip, swing knee,
swing ankle; see DESIGN.md for signs). The same chain serves for both legs through the relabelling
``relabel(q) = -q[::-1]`` (the legs are identical).

The chain is rooted on three *locked* planar joints (x, z translation and pitch about -y) at the stance
ankle, on the sole line. Evaluating inverse dynamics with those joints at rest turns their generalized
forces into the ground reaction on the stance foot:

    tau_full = M_full(q) [0; w] + h_full(q, q')       (Pinocchio CRBA + non-linear effects)
    [R_x, R_y, m_a] = tau_full[0:3],   Gamma = tau_full[3:9] = A(q) w + H(q, q')

where R is the ground's force on the stance foot [N] (R_y vertical, up positive) and m_a the ground's
moment about the ankle [N m] (counter-clockwise positive). Because the ankle lies on the sole line and
the foot's centre of mass is on the ankle's vertical, m_a = Gamma_1 and the centre of pressure is
l = Gamma_1 / R_y (eq. 7). The same reaction follows from Newton's law for the centre of mass,
R = M (J_G w + J_G' q') + [0, M g] (eqs. 3-4); the tests check one against the other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from biped_model.description import RobotDescription, load_description

AXIS = np.array([0.0, -1.0, 0.0])
N_CONSTRAINTS = 17
CONSTRAINT_NAMES: tuple[str, ...] = (
    "take_off",           # -R_y < 0
    "slide_backward",     # -mu R_y - R_x < 0   (R_x >= -mu R_y)
    "slide_forward",      # -mu R_y + R_x < 0   (R_x <= mu R_y)
    "zmp_heel",           # l_m R_y - Gamma_1 < 0
    "zmp_toe",            # Gamma_1 - l_M R_y < 0
    "torque_max_1", "torque_max_2", "torque_max_3", "torque_max_4", "torque_max_5", "torque_max_6",
    "torque_min_1", "torque_min_2", "torque_min_3", "torque_min_4", "torque_min_5", "torque_min_6",
)


def contact_rows(mu: float, l_min: float, l_max: float) -> tuple[np.ndarray, np.ndarray]:
    """The five contact constraints of eqs. (5)-(8), written once, as functions of the ground force
    R = (R_x, R_y) [N] and the stance ankle torque Gamma_1 [N m]:  C R + e Gamma_1 < 0, rows in the order
    take_off, slide_backward, slide_forward, zmp_heel, zmp_toe. Returns (C (5, 2), e (5,))."""
    C = np.array([[0.0, -1.0], [-1.0, -mu], [1.0, -mu], [0.0, l_min], [0.0, -l_max]])
    e = np.array([0.0, 0.0, 0.0, -1.0, 1.0])
    return C, e


def relabel(q: np.ndarray) -> np.ndarray:
    """Exchange the roles of the legs: q' = -q[::-1] (also for velocities). An involution."""
    return -np.asarray(q, dtype=float)[::-1].copy()


def _inertia(mass: float, com_z: float, iyy: float) -> pin.Inertia:
    return pin.Inertia(mass, np.array([0.0, 0.0, com_z]), np.diag([iyy, iyy, iyy]))


def build_fixed_foot_model(desc: RobotDescription) -> pin.Model:
    """Pinocchio model: 3 locked root joints (PX, PZ, pitch) + q1..q6, frames ``stance_sole``/``swing_sole``."""
    m = pin.Model()
    m.name = "biped_fixed_stance_foot"
    m.gravity = pin.Motion(np.array([0.0, 0.0, -desc.gravity]), np.zeros(3))
    eye = pin.SE3.Identity()
    jx = m.addJoint(0, pin.JointModelPX(), eye, "root_x")
    jz = m.addJoint(jx, pin.JointModelPZ(), eye, "root_z")
    jp = m.addJoint(jz, pin.JointModelRevoluteUnaligned(AXIS), eye, "root_pitch")
    ft, sh, th, to = desc.foot, desc.shin, desc.thigh, desc.torso
    # stance foot (motionless in single support, but part of M and x_G)
    m.appendBodyToJoint(jp, pin.Inertia(ft.mass, np.array([ft.com_forward, 0.0, 0.0]), np.diag([ft.inertia] * 3)), eye)
    up = lambda z: pin.SE3(np.eye(3), np.array([0.0, 0.0, z]))  # noqa: E731
    j1 = m.addJoint(jp, pin.JointModelRevoluteUnaligned(AXIS), eye, "q1_stance_ankle")
    m.appendBodyToJoint(j1, _inertia(sh.mass, sh.length - sh.com, sh.inertia), eye)  # shin, ankle -> knee
    j2 = m.addJoint(j1, pin.JointModelRevoluteUnaligned(AXIS), up(sh.length), "q2_stance_knee")
    m.appendBodyToJoint(j2, _inertia(th.mass, th.length - th.com, th.inertia), eye)  # thigh, knee -> hip
    j3 = m.addJoint(j2, pin.JointModelRevoluteUnaligned(AXIS), up(th.length), "q3_stance_hip")
    m.appendBodyToJoint(j3, _inertia(to.mass, to.com, to.inertia), eye)  # torso, above the hip
    j4 = m.addJoint(j3, pin.JointModelRevoluteUnaligned(AXIS), eye, "q4_swing_hip")
    m.appendBodyToJoint(j4, _inertia(th.mass, -th.com, th.inertia), eye)
    j5 = m.addJoint(j4, pin.JointModelRevoluteUnaligned(AXIS), up(-th.length), "q5_swing_knee")
    m.appendBodyToJoint(j5, _inertia(sh.mass, -sh.com, sh.inertia), eye)
    j6 = m.addJoint(j5, pin.JointModelRevoluteUnaligned(AXIS), up(-sh.length), "q6_swing_ankle")
    m.appendBodyToJoint(j6, pin.Inertia(ft.mass, np.array([ft.com_forward, 0.0, 0.0]), np.diag([ft.inertia] * 3)), eye)
    m.addFrame(pin.Frame("stance_sole", jp, eye, pin.FrameType.OP_FRAME))
    m.addFrame(pin.Frame("hip", j3, eye, pin.FrameType.OP_FRAME))
    m.addFrame(pin.Frame("swing_sole", j6, eye, pin.FrameType.OP_FRAME))
    return m


@dataclass(frozen=True)
class Dynamics:
    """Single-support terms at (q, q'): Gamma = A w + H; [R_x, R_y, m_a] = B w + h_b."""

    A: np.ndarray      # (6, 6) inertia matrix [kg m^2]
    H: np.ndarray      # (6,) Coriolis, centrifugal and gravity torques [N m]
    B: np.ndarray      # (3, 6) reaction rows: ground force/moment per unit joint acceleration
    h_b: np.ndarray    # (3,) ground reaction at w = 0 [N, N, N m]


@dataclass(frozen=True)
class ConstraintMatrices:
    """The 17 constraints of eq. (10): A_q w + b_q < 0 (row order = CONSTRAINT_NAMES)."""

    A_q: np.ndarray    # (17, 6)
    b_q: np.ndarray    # (17,)


class FixedFootModel:
    """Controller-side model. Owns its own Pinocchio ``Data`` (never shared with the simulator)."""

    def __init__(self, desc: RobotDescription | None = None):
        self.desc = desc if desc is not None else load_description()
        self.model = build_fixed_foot_model(self.desc)
        self.data = self.model.createData()
        self.mass = float(sum(i.mass for i in self.model.inertias))
        self._q = np.zeros(9)
        self._v = np.zeros(9)
        self._lower = np.tril_indices(9, -1)
        self.swing_frame = self.model.getFrameId("swing_sole")
        self.hip_frame = self.model.getFrameId("hip")
        lo, hi = self.desc.torque_limits()
        self.torque_min = np.array(lo)
        self.torque_max = np.array(hi)
        self.l_min = self.desc.foot.l_min
        self.l_max = self.desc.foot.l_max
        self.mu = self.desc.mu
        # Scale of each constraint row, to compare margins of different units (N, N m).
        mg = self.mass * self.desc.gravity
        self.row_scale = np.concatenate(
            [[mg, mg, mg, 0.1 * mg, 0.1 * mg], self.torque_max, self.torque_max]
        )

    def _full(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        self._q[3:] = q
        if qd is not None:
            self._v[3:] = qd

    def dynamics(self, q: np.ndarray, qd: np.ndarray) -> Dynamics:
        """A(q), H(q, q') of eq. (1) and the reaction rows (CRBA + non-linear effects, Pinocchio)."""
        self._full(q, qd)
        M = pin.crba(self.model, self.data, self._q).copy()
        M[self._lower] = M.T[self._lower]  # CRBA fills the upper triangle
        h = pin.nonLinearEffects(self.model, self.data, self._q, self._v)
        return Dynamics(A=M[3:, 3:].copy(), H=h[3:].copy(), B=M[0:3, 3:].copy(), h_b=h[0:3].copy())

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Gamma [N m] (6,), [R_x, R_y, m_a]) for joint accelerations w, by RNEA on the locked-root chain."""
        self._full(q, qd)
        a = np.zeros(9)
        a[3:] = w
        tau = pin.rnea(self.model, self.data, self._q, self._v, a)
        return tau[3:].copy(), tau[0:3].copy()

    def com(self, q: np.ndarray) -> np.ndarray:
        """(x_G, y_G) [m] relative to the stance ankle (y_G = height; whole robot incl. both feet)."""
        self._full(q)
        c = pin.centerOfMass(self.model, self.data, self._q)
        return np.array([c[0], c[2]])

    def com_velocity(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x_G, x_G') [m, m/s]: the CoM (x, height) relative to the stance ankle and its velocity J_G q'
        (eqs. (2)-(3)), without the Jacobian and the drift of :meth:`com_terms` (a third of its cost)."""
        self._full(q, qd)
        pin.centerOfMass(self.model, self.data, self._q, self._v)
        c, v = self.data.com[0], self.data.vcom[0]
        return np.array([c[0], c[2]]), np.array([v[0], v[2]])

    def com_terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x_G, J_G (2x6), J_G' q' (2,)): eqs. (2)-(4); the drift is the CoM acceleration at w = 0."""
        self._full(q, qd)
        J = pin.jacobianCenterOfMass(self.model, self.data, self._q)
        pin.centerOfMass(self.model, self.data, self._q, self._v, np.zeros(9))
        c = self.data.com[0]
        ac = self.data.acom[0]
        return np.array([c[0], c[2]]), J[[0, 2], 3:].copy(), np.array([ac[0], ac[2]])

    def constraints(self, q: np.ndarray, qd: np.ndarray, dyn: Dynamics | None = None, *,
                    mu: float | None = None, l_min: float | None = None, l_max: float | None = None
                    ) -> ConstraintMatrices:
        """Eq. (10): rows of A_q w + b_q < 0, in the order of CONSTRAINT_NAMES. With R = B w + h_b and
        Gamma = A w + H, the contact rows are C R + e Gamma_1 (``contact_rows``), the torque rows
        Gamma - Gamma_max and Gamma_min - Gamma. ``mu``, ``l_min``, ``l_max`` default to the robot's (a
        controller may pass tighter ones)."""
        d = dyn if dyn is not None else self.dynamics(q, qd)
        C, e = contact_rows(self.mu if mu is None else mu, self.l_min if l_min is None else l_min,
                            self.l_max if l_max is None else l_max)
        A_q = np.empty((N_CONSTRAINTS, 6))
        b_q = np.empty(N_CONSTRAINTS)
        A_q[:5] = C @ d.B[:2] + np.outer(e, d.A[0])
        b_q[:5] = C @ d.h_b[:2] + e * d.H[0]
        A_q[5:11], b_q[5:11] = d.A, d.H - self.torque_max
        A_q[11:17], b_q[11:17] = -d.A, self.torque_min - d.H
        return ConstraintMatrices(A_q, b_q)

    def margins_direct(self, q: np.ndarray, qd: np.ndarray, w: np.ndarray) -> np.ndarray:
        """-(constraint values) evaluated from inverse dynamics (RNEA) directly (positive = satisfied)."""
        gam, r = self.inverse_dynamics(q, qd, w)
        C, e = contact_rows(self.mu, self.l_min, self.l_max)
        vals = np.concatenate([C @ r[:2] + e * gam[0], gam - self.torque_max, self.torque_min - gam])
        return -vals

    def swing_foot(self, q: np.ndarray, qd: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """Swing sole (ankle) pose (x, z, angle) relative to the stance ankle, and its velocity if qd given."""
        self._full(q, qd)
        pin.forwardKinematics(self.model, self.data, self._q, self._v)
        pin.updateFramePlacement(self.model, self.data, self.swing_frame)
        oMf = self.data.oMf[self.swing_frame]
        angle = float(np.sum(q))  # sum of relative angles = absolute foot angle (stance foot flat)
        pose = np.array([oMf.translation[0], oMf.translation[2], angle])
        if qd is None:
            return pose, None
        v = pin.getFrameVelocity(self.model, self.data, self.swing_frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        vel = np.array([v.linear[0], v.linear[2], float(np.sum(qd))])
        return pose, vel

    def swing_foot_jacobian(self, q: np.ndarray) -> np.ndarray:
        """(3, 6) Jacobian of (x, z, angle) of the swing sole w.r.t. q."""
        self._full(q)
        pin.computeJointJacobians(self.model, self.data, self._q)
        pin.updateFramePlacements(self.model, self.data)
        J = pin.getFrameJacobian(self.model, self.data, self.swing_frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        out = np.empty((3, 6))
        out[0] = J[0, 3:]
        out[1] = J[2, 3:]
        out[2] = 1.0
        return out

    def torso_point_jacobian(self, q: np.ndarray, height: float) -> np.ndarray:
        """(2, 9) Jacobian of the world (x, z) velocity of the torso point ``height`` [m] above the hip,
        w.r.t. the 9 coordinates of the locked-root chain (3 root + q1..q6)."""
        self._full(q)
        pin.computeJointJacobians(self.model, self.data, self._q)
        jid = self.model.frames[self.hip_frame].parentJoint
        J = pin.getJointJacobian(self.model, self.data, jid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        th = float(q[0] + q[1] + q[2])
        r = np.array([-height * np.sin(th), 0.0, height * np.cos(th)])
        lin = J[:3] - pin.skew(r) @ J[3:]
        return lin[[0, 2]]

    def kinetic_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        self._full(q, qd)
        return float(pin.computeKineticEnergy(self.model, self.data, self._q, self._v))

    def potential_energy(self, q: np.ndarray) -> float:
        self._full(q)
        return float(pin.computePotentialEnergy(self.model, self.data, self._q))
