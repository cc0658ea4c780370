"""Fast engine: the compiled planar kernels behind the simulator's and the controller's models.

Pure Python + NumPy around ``planar_kernels`` (numba), no ROS. The Pinocchio models
(``floating.FloatingModel``, ``biped_model.fixed_foot.FixedFootModel``) stay the reference engine and
the oracle of the tests; the classes here compute the same quantities from a ``PlanarTree`` built from
the ``RobotDescription`` (lengths, masses, centres of mass, inertias of ``robots/biped7/description.yaml``):

* ``FastFloatingModel``: a drop-in for ``FloatingModel`` (same methods, same frames, signs and
  orderings: ``x = [x_hip, z_hip, theta_torso, lh, lk, la, rh, rk, ra]``), plus the one-call
  integration ``rk4_step`` / ``rk4_steps`` and ``project``, ``swing_probe`` of ``Simulator``.
* ``FastFixedFootModel``: the controller's single-support terms ``A, H, B, h_b`` (as
  ``FixedFootModel.dynamics``) and the x row of ``torso_point_jacobian`` in one call.

The kernels are loaded when a model is built (``planar_kernels()``: ``numba_cache.load``, cache in
``<repo>/build/numba-cache``); the first run after a change of the kernels compiles them (~15-30 s) and
says so on stderr. Importing this module compiles nothing.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from biped_model import numba_cache
from biped_model import planar_abi as abi
from biped_model.description import RobotDescription, load_description
from biped_model.finite import finite_array, finite_number
from biped_model.floating import ContactSolution, FloatingModel, ImpactResult, SimulationError

PX, PZ, REV = abi.PX, abi.PZ, abi.REV
PLANAR_KERNELS = "biped_model.planar_kernels"


def planar_kernels():
    """The compiled planar kernels (``planar_kernels``), loaded through ``numba_cache.load`` (compiled on
    the first run after a change, then loaded from the cache)."""
    return numba_cache.load(PLANAR_KERNELS, sources=("biped_model.planar_abi",))
_NO_PUSH = np.empty(0)


class TreeError(ValueError):
    """A planar tree is inconsistent (message names the joint or body and what is wrong)."""


@dataclass(frozen=True)
class Joint:
    """One-DOF joint: ``kind`` PX / PZ (prism along the parent frame's x / z) or REV (hinge,
    counter-clockwise in the x-z view, i.e. about -y); ``offset`` (x, z) [m] of its frame origin in
    the parent's frame; ``parent`` a lower joint index, -1 for the world."""

    name: str
    parent: int
    kind: int
    offset: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class Body:
    """Rigid body fixed to the frame of ``joint``: mass [kg], centre of mass ``com`` (x, z) [m] in that
    frame, rotational inertia about the centre of mass and the plane's normal [kg m^2]."""

    name: str
    joint: int
    mass: float
    com: tuple[float, float]
    inertia: float


@dataclass(frozen=True)
class PlanarTree:
    """Kinematic tree + inertias + contact/push geometry, the kernels' whole input.

    ``feet``: the joints whose frame origins are the two contact points (ankles on the sole line);
    ``sole`` = (l_min, l_max) [m] along a foot frame's x; ``push_joint``: the frame carrying pushes at
    (0, height); ``gravity`` [m/s^2] along -z."""

    joints: tuple[Joint, ...]
    bodies: tuple[Body, ...]
    gravity: float
    push_joint: int
    feet: tuple[int, int]
    sole: tuple[float, float]

    def validate(self, floating_root: bool = True) -> "PlanarTree":
        nj = len(self.joints)
        for k, j in enumerate(self.joints):
            if j.kind not in (PX, PZ, REV):
                raise TreeError(f"joint {k} '{j.name}': kind must be PX, PZ or REV, got {j.kind!r}")
            if not -1 <= j.parent < k:
                raise TreeError(f"joint {k} '{j.name}': parent must be in [-1, {k - 1}], got {j.parent}")
            message = f"joint {k} '{j.name}': offset must be two finite numbers, got {j.offset!r}"
            if len(j.offset) != 2:
                raise TreeError(message)
            finite_array(j.offset, "offset", error=TreeError, message=message)
        if not self.bodies:
            raise TreeError("tree has no body")
        for b in self.bodies:
            if not 0 <= b.joint < nj:
                raise TreeError(f"body '{b.name}': joint must be in [0, {nj - 1}], got {b.joint}")
            finite_number(b.mass, "mass", above=0, error=TreeError,
                          message=f"body '{b.name}': mass must be > 0 kg, got {b.mass}")
            finite_number(b.inertia, "inertia", at_least=0, error=TreeError,
                          message=f"body '{b.name}': inertia must be >= 0 kg m^2, got {b.inertia}")
            message = f"body '{b.name}': com must be two finite numbers, got {b.com!r}"
            if len(b.com) != 2:
                raise TreeError(message)
            finite_array(b.com, "com", error=TreeError, message=message)
        for what, k in (("push_joint", self.push_joint), ("feet[0]", self.feet[0]), ("feet[1]", self.feet[1])):
            if not 0 <= k < nj:
                raise TreeError(f"{what} must be a joint index in [0, {nj - 1}], got {k}")
        finite_number(self.gravity, "gravity", above=0, error=TreeError,
                      message=f"gravity must be > 0 m/s^2, got {self.gravity}")
        if not self.sole[0] < self.sole[1]:
            raise TreeError(f"sole must satisfy l_min < l_max, got {self.sole}")
        if floating_root:
            want = ((-1, PX), (0, PZ), (1, REV))
            got = tuple((j.parent, j.kind) for j in self.joints[:3])
            if nj < 3 or got != want or any(j.offset != (0.0, 0.0) for j in self.joints[:3]):
                raise TreeError("floating root: joints 0, 1, 2 must be PX from the world, PZ, REV at zero offsets")
        return self

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(ti int64, tf float64) in the layout of ``planar_kernels``."""
        nj, nb = len(self.joints), len(self.bodies)
        ti = np.array([nj, nb, self.push_joint, self.feet[0], self.feet[1]]
                      + [j.parent for j in self.joints] + [j.kind for j in self.joints]
                      + [b.joint for b in self.bodies], dtype=np.int64)
        tf = np.array([self.gravity, self.sole[0], self.sole[1]]
                      + [j.offset[0] for j in self.joints] + [j.offset[1] for j in self.joints]
                      + [b.mass for b in self.bodies] + [b.com[0] for b in self.bodies]
                      + [b.com[1] for b in self.bodies] + [b.inertia for b in self.bodies], dtype=np.float64)
        assert ti.size == abi.HEADER_I + 2 * nj + nb and tf.size == abi.HEADER_F + 2 * nj + 4 * nb
        return ti, tf


def _planar_root(name: str) -> list[Joint]:
    return [Joint(f"{name}_x", -1, PX), Joint(f"{name}_z", 0, PZ), Joint(f"{name}_pitch", 1, REV)]


def floating_tree(desc: RobotDescription) -> PlanarTree:
    """The simulator's tree, as ``make_urdf`` + the planar root of ``FloatingModel``: joints in the
    order of x (root x, z, torso pitch, left hip, knee, ankle, right hip, knee, ankle); the torso frame
    origin is the hip, legs hang along -z, ankle frames on the sole line."""
    t, th, sh, ft = desc.torso, desc.thigh, desc.shin, desc.foot
    joints = _planar_root("root")
    bodies = [Body("torso", 2, t.mass, (0.0, t.com), t.inertia)]
    for side in ("left", "right"):
        hip = len(joints)
        joints += [Joint(f"{side}_hip", 2, REV), Joint(f"{side}_knee", hip, REV, (0.0, -th.length)),
                   Joint(f"{side}_ankle", hip + 1, REV, (0.0, -sh.length))]
        bodies += [Body(f"{side}_thigh", hip, th.mass, (0.0, -th.com), th.inertia),
                   Body(f"{side}_shin", hip + 1, sh.mass, (0.0, -sh.com), sh.inertia),
                   Body(f"{side}_foot", hip + 2, ft.mass, (ft.com_forward, 0.0), ft.inertia)]
    return PlanarTree(tuple(joints), tuple(bodies), desc.gravity, push_joint=2, feet=(5, 8),
                      sole=(ft.l_min, ft.l_max)).validate()


def fixed_foot_tree(desc: RobotDescription) -> PlanarTree:
    """The controller's chain (``biped_model.fixed_foot.build_fixed_foot_model``): planar root at the
    stance ankle carrying the stance foot, then the paper's q1..q6 (stance ankle, knee, hip, swing hip,
    knee, ankle). Push frame = q3's (the torso, origin at the hip); feet = (root pitch, q6)."""
    t, th, sh, ft = desc.torso, desc.thigh, desc.shin, desc.foot
    joints = _planar_root("stance") + [
        Joint("q1_stance_ankle", 2, REV), Joint("q2_stance_knee", 3, REV, (0.0, sh.length)),
        Joint("q3_stance_hip", 4, REV, (0.0, th.length)), Joint("q4_swing_hip", 5, REV),
        Joint("q5_swing_knee", 6, REV, (0.0, -th.length)), Joint("q6_swing_ankle", 7, REV, (0.0, -sh.length)),
    ]
    bodies = [
        Body("stance_foot", 2, ft.mass, (ft.com_forward, 0.0), ft.inertia),
        Body("stance_shin", 3, sh.mass, (0.0, sh.length - sh.com), sh.inertia),
        Body("stance_thigh", 4, th.mass, (0.0, th.length - th.com), th.inertia),
        Body("torso", 5, t.mass, (0.0, t.com), t.inertia),
        Body("swing_thigh", 6, th.mass, (0.0, -th.com), th.inertia),
        Body("swing_shin", 7, sh.mass, (0.0, -sh.com), sh.inertia),
        Body("swing_foot", 8, ft.mass, (ft.com_forward, 0.0), ft.inertia),
    ]
    return PlanarTree(tuple(joints), tuple(bodies), desc.gravity, push_joint=5, feet=(2, 8),
                      sole=(ft.l_min, ft.l_max)).validate()


def push_arrays(pushes: Sequence[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """(forces [N], heights [m]) arrays of a sequence of (force, height) pushes (``Simulator.interval_pushes``)."""
    if not pushes:
        return _NO_PUSH, _NO_PUSH
    return (np.array([float(f) for f, _ in pushes]), np.array([float(h) for _, h in pushes]))


@dataclass(frozen=True)
class StepBatch:
    """``FastFloatingModel.rk4_steps``: ``X[i], V[i]`` the state after step i; ``wrench[i]`` lambda =
    [F_x, F_z, m] at the start of step i; ``probe[i]`` the other foot after step i: [lowest sole z [m],
    ankle z rate [m/s], z rate of that sole point [m/s]]; ``completed`` steps (< n if one was singular)."""

    X: np.ndarray
    V: np.ndarray
    wrench: np.ndarray
    probe: np.ndarray
    completed: int


def _check(status: int, what: str) -> None:
    if status != abi.STATUS_OK:
        raise SimulationError(f"fast engine: {what}: singular contact system or non-finite state")


class FastFloatingModel:
    """Simulator-side model on the compiled kernels: the methods of ``FloatingModel`` (same arguments,
    results, frames and signs) plus the one-call integration of ``Simulator``.

    ``ti``, ``tf``: the kernel parameter arrays (never modify them); hot loops may call ``planar_kernels``
    directly with them and preallocated outputs."""

    def __init__(self, desc: RobotDescription | None = None):
        self.desc = desc if desc is not None else load_description()
        self.tree = floating_tree(self.desc)
        self.ti, self.tf = self.tree.arrays()
        self.pk = planar_kernels()
        self.mass = float(sum(b.mass for b in self.tree.bodies))
        self.joint_names = tuple(j.name for j in self.tree.joints[3:])
        self.nv = len(self.tree.joints)
        self._zero = np.zeros(self.nv)

    # ---------------------------------------------------------------- kinematics
    def _point(self, x: np.ndarray, v: np.ndarray, joint: int, lx: float, lz: float) -> tuple[np.ndarray, np.ndarray]:
        J = np.empty((3, self.nv))
        out = np.empty(abi.POINT_SIZE)
        self.pk.point_state(self.ti, self.tf, x, v, joint, lx, lz, J, out)
        return J, out

    def foot_pose(self, x: np.ndarray, foot: int) -> np.ndarray:
        """(x, z, pitch) of a foot's ankle point in the world; pitch = absolute foot angle (ccw)."""
        return self._point(x, self._zero, self.tree.feet[foot], 0.0, 0.0)[1][:3].copy()

    def sole_points(self, x: np.ndarray, foot: int) -> np.ndarray:
        """World (x, z) of the heel and the toe of a foot, shape (2, 2)."""
        px, pz, th = self.foot_pose(x, foot)
        out = np.empty((2, 2))
        for i, l in enumerate(self.tree.sole):
            out[i] = (px + l * np.cos(th), pz + l * np.sin(th))
        return out

    def contact_jacobian(self, x: np.ndarray, foot: int) -> np.ndarray:
        """(3, 9) rows of the foot's (x, z, pitch) velocity."""
        return self._point(x, self._zero, self.tree.feet[foot], 0.0, 0.0)[0]

    def foot_velocity(self, x: np.ndarray, v: np.ndarray, foot: int) -> np.ndarray:
        return self._point(x, v, self.tree.feet[foot], 0.0, 0.0)[1][3:6].copy()

    def contact_drift(self, x: np.ndarray, v: np.ndarray, foot: int) -> np.ndarray:
        """J_c' v: the foot's (x, z, pitch) acceleration when a = 0."""
        out = self._point(x, v, self.tree.feet[foot], 0.0, 0.0)[1]
        return np.array([out[6], out[7], 0.0])

    def push_jacobian(self, x: np.ndarray, height: float) -> np.ndarray:
        """(2, 9) Jacobian of the world (x, z) velocity of the torso point at ``height`` [m] above the hip."""
        return self._point(x, self._zero, self.tree.push_joint, 0.0, float(height))[0][:2].copy()

    def swing_probe(self, x: np.ndarray, v: np.ndarray, foot: int) -> np.ndarray:
        """[lowest sole z [m], ankle z rate [m/s], z rate of that sole point [m/s]] of ``foot``."""
        out = np.empty(abi.PROBE_SIZE)
        self.pk.swing_probe(self.ti, self.tf, x, v, int(foot), out)
        return out

    # ---------------------------------------------------------------- paper <-> floating state
    # the reference model's maths, written once (``FloatingModel``), on this engine's foot pose and Jacobian
    state_from_paper = FloatingModel.state_from_paper
    paper_from_state = staticmethod(FloatingModel.paper_from_state)

    # ---------------------------------------------------------------- dynamics
    def mass_bias(self, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M(x) (9, 9), h(x, v) (9,)): M a + h = tau (h: Coriolis, centrifugal, gravity)."""
        M = np.empty((self.nv, self.nv))
        h = np.empty(self.nv)
        self.pk.mass_bias(self.ti, self.tf, x, v, M, h)
        return M, h

    def mass_matrix(self, x: np.ndarray) -> np.ndarray:
        return self.mass_bias(x, self._zero)[0]

    def inverse_mass_matrix(self, x: np.ndarray) -> np.ndarray:
        return np.linalg.inv(self.mass_matrix(x))

    def contact_dynamics(self, x: np.ndarray, v: np.ndarray, tau: np.ndarray, foot: int) -> ContactSolution:
        """Solve M a + h = tau + J_c^T lambda, J_c a + J_c' v = 0 (Schur complement on the 3 contact rows)."""
        a = np.empty(self.nv)
        lam = np.empty(3)
        _check(self.pk.contact_dynamics(self.ti, self.tf, x, v, tau, int(foot), a, lam), "contact dynamics")
        return ContactSolution(a=a, wrench=lam)

    def free_dynamics(self, x: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Acceleration with no contact (flight): M^-1 (tau - h)."""
        a = np.empty(self.nv)
        _check(self.pk.free_dynamics(self.ti, self.tf, x, v, tau, a), "free dynamics")
        return a

    def impact(self, x: np.ndarray, v: np.ndarray, new_stance: int) -> ImpactResult:
        """Instantaneous inelastic impact of foot ``new_stance`` (Schur complement form):
        Lambda = -(J M^-1 J^T)^-1 J v-,  v+ = v- + M^-1 J^T Lambda; the other foot is released."""
        v_plus = np.empty(self.nv)
        out = np.empty(abi.IMPACT_SIZE)
        _check(self.pk.impact(self.ti, self.tf, x, v, int(new_stance), v_plus, out), "impact")
        return ImpactResult(v_plus=v_plus, impulse=out[0:3].copy(), old_foot_velocity=out[3:6].copy(),
                            energy_loss=float(out[6]))

    def _energy(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        out = np.empty(5)
        self.pk.energy(self.ti, self.tf, x, v, out)
        return out

    def kinetic_energy(self, x: np.ndarray, v: np.ndarray) -> float:
        return float(self._energy(x, v)[0])

    def potential_energy(self, x: np.ndarray) -> float:
        """sum m g z_com [J] (zero at z = 0)."""
        return float(self._energy(x, self._zero)[1])

    def com(self, x: np.ndarray) -> np.ndarray:
        return self._energy(x, self._zero)[2:4].copy()

    # ---------------------------------------------------------------- integration (Simulator)
    def project(self, x: np.ndarray, v: np.ndarray, foot: int, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``Simulator._project``: the foot's frame put exactly on anchor = (x, z, pitch) (pitch through
        x[2] first, then x[0], x[1]); v <- v - M^-1 J^T (J M^-1 J^T)^-1 J v at the corrected x."""
        xo = np.empty(self.nv)
        vo = np.empty(self.nv)
        _check(self.pk.project(self.ti, self.tf, x, v, int(foot), anchor, xo, vo), "projection")
        return xo, vo

    def rk4_step(self, x: np.ndarray, v: np.ndarray, tau_j: np.ndarray, pushes: Sequence[tuple[float, float]],
                 foot: int, anchor: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One RK4 step of length h [s] with foot ``foot`` held, URDF joint torques ``tau_j`` (6,) [N m]
        and the ``pushes`` ((force [N], height [m]) pairs, horizontal, on the torso) constant over the
        step, then ``project`` onto ``anchor``. Returns (x, v) after the step and the contact wrench
        lambda = [F_x, F_z, m] at the step start (the value ``Simulator`` checks)."""
        xo = np.empty(self.nv)
        vo = np.empty(self.nv)
        w = np.empty(3)
        fs, hs = push_arrays(pushes)
        _check(self.pk.rk4_step(self.ti, self.tf, x, v, tau_j, fs, hs, int(foot), anchor, float(h), xo, vo, w), "RK4 step")
        return xo, vo, w

    def rk4_steps(self, x: np.ndarray, v: np.ndarray, tau_j: np.ndarray, pushes: Sequence[tuple[float, float]],
                  foot: int, anchor: np.ndarray, h: float, n: int) -> StepBatch:
        """``n`` consecutive ``rk4_step``s in one call (e.g. the substeps of a control period), with the
        wrench at every step start and the swing probe (``swing_probe`` of foot 1 - foot) after every
        step. Stops early (``completed`` < n) at a singular step; nothing is raised."""
        X = np.empty((n, self.nv))
        V = np.empty((n, self.nv))
        W = np.empty((n, 3))
        P = np.empty((n, abi.PROBE_SIZE))
        fs, hs = push_arrays(pushes)
        done = self.pk.rk4_steps(self.ti, self.tf, x, v, tau_j, fs, hs, int(foot), anchor, float(h), X, V, W, P)
        return StepBatch(X, V, W, P, int(done))


class FastFixedFootModel:
    """Controller-side single-support terms on the compiled kernels (``FixedFootModel`` is the reference).

    Paper coordinates q1..q6 (stance ankle first); the stance foot is the locked planar root."""

    def __init__(self, desc: RobotDescription | None = None):
        self.desc = desc if desc is not None else load_description()
        self.tree = fixed_foot_tree(self.desc)
        self.ti, self.tf = self.tree.arrays()
        self.pk = planar_kernels()
        self.mass = float(sum(b.mass for b in self.tree.bodies))

    def terms(self, q: np.ndarray, qd: np.ndarray, height: float = 0.0
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A (6, 6), H (6,), B (3, 6), h_b (3,), jp (9,)) at (q, q'): Gamma = A w + H and the ground's
        action on the stance foot [R_x, R_y, m_a] = B w + h_b (as ``FixedFootModel.dynamics``); jp = the
        x row of ``torso_point_jacobian(q, height)`` (3 root coordinates then q1..q6)."""
        A = np.empty((6, 6))
        H = np.empty(6)
        B = np.empty((3, 6))
        hb = np.empty(3)
        jp = np.empty(9)
        self.pk.fixed_root_terms(self.ti, self.tf, q, qd, float(height), A, H, B, hb, jp)
        return A, H, B, hb, jp

    def terms_into(self, q: np.ndarray, qd: np.ndarray, height: float, A: np.ndarray, H: np.ndarray,
                   B: np.ndarray, hb: np.ndarray, jp: np.ndarray) -> None:
        """``terms`` into caller-owned arrays (float64, C order, shapes as ``terms`` returns): no allocation."""
        self.pk.fixed_root_terms(self.ti, self.tf, q, qd, height, A, H, B, hb, jp)

    def _energy(self, q: np.ndarray, qd: np.ndarray | None) -> np.ndarray:
        qf = np.zeros(9)
        vf = np.zeros(9)
        qf[3:] = q
        if qd is not None:
            vf[3:] = qd
        out = np.empty(5)
        self.pk.energy(self.ti, self.tf, qf, vf, out)
        return out

    def com(self, q: np.ndarray) -> np.ndarray:
        """(x_G, y_G) [m] relative to the stance ankle (whole robot incl. both feet)."""
        return self._energy(q, None)[2:4].copy()

    def kinetic_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        return float(self._energy(q, qd)[0])

    def potential_energy(self, q: np.ndarray) -> float:
        return float(self._energy(q, None)[1])
