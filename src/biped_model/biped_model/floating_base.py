"""The simulator's floating-base model, typed: one Protocol both engines satisfy.

Pure Python, no ROS. ``floating.FloatingModel`` (Pinocchio, the reference engine and the tests' oracle)
and ``fast_engine.FastFloatingModel`` (the compiled planar kernels) compute the same quantities with the
same arguments, frames, signs and orderings (``x = [x_hip, z_hip, theta_torso, lh, lk, la, rh, rk, ra]``,
``v = dx/dt``; feet 0 left, 1 right; see ``floating``); :class:`FloatingBaseModel` states that contract,
:class:`CompiledFloatingModel` adds what only the compiled engine has (the one-call integration and the
kernels' arrays), and :func:`make_floating_model` is the one place the engine is chosen.
tests/test_fast_kernels.py checks both classes against the Protocols, signature by signature.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, Sequence, runtime_checkable

import numpy as np

from biped_model.description import RobotDescription

if TYPE_CHECKING:   # pragma: no cover - types only
    from types import ModuleType

    from biped_model.floating import ContactSolution, ImpactResult

ENGINE_NAMES = ("fast", "reference")


@runtime_checkable
class FloatingBaseModel(Protocol):
    """Kinematics and dynamics of the floating-base biped (SI units, world x forward, z up, angles about -y)."""

    desc: RobotDescription
    mass: float                      # [kg]
    joint_names: tuple[str, ...]     # the six URDF joints, in x[3:] order

    def foot_pose(self, x: np.ndarray, foot: int) -> np.ndarray:
        """(x, z, pitch) of the foot's ankle frame [m, m, rad]."""

    def sole_points(self, x: np.ndarray, foot: int) -> np.ndarray:
        """(2, 2): heel and toe (x, z) [m]."""

    def contact_jacobian(self, x: np.ndarray, foot: int) -> np.ndarray:
        """(3, 9): rows x, z, pitch of the foot's frame."""

    def foot_velocity(self, x: np.ndarray, v: np.ndarray, foot: int) -> np.ndarray:
        """(3,): d/dt (x, z, pitch) of the foot's frame."""

    def contact_drift(self, x: np.ndarray, v: np.ndarray, foot: int) -> np.ndarray:
        """(3,): Jdot v of the foot's frame."""

    def push_jacobian(self, x: np.ndarray, height: float) -> np.ndarray:
        """(2, 9): world (x, z) rows of the torso point ``height`` [m] above the hip."""

    def state_from_paper(self, q: np.ndarray, qd: np.ndarray, stance: int, ankle_x: float = 0.0,
                         foot_pitch: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Floating (x, v) from paper (q, q') with the stance foot at (ankle_x, 0, foot_pitch), at rest."""

    @staticmethod
    def paper_from_state(x: np.ndarray, v: np.ndarray, stance: int) -> tuple[np.ndarray, np.ndarray]:
        """Paper (q, q') of the stance's labelling."""

    def mass_matrix(self, x: np.ndarray) -> np.ndarray:
        """(9, 9) M(x)."""

    def inverse_mass_matrix(self, x: np.ndarray) -> np.ndarray:
        """(9, 9) M(x)^-1."""

    def contact_dynamics(self, x: np.ndarray, v: np.ndarray, tau: np.ndarray, foot: int) -> "ContactSolution":
        """Acceleration and contact wrench with ``foot`` held (tau: generalized force, (9,))."""

    def free_dynamics(self, x: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Acceleration without contact."""

    def impact(self, x: np.ndarray, v: np.ndarray, new_stance: int) -> "ImpactResult":
        """Inelastic impact of the foot ``new_stance``."""

    def kinetic_energy(self, x: np.ndarray, v: np.ndarray) -> float:
        """[J]"""

    def potential_energy(self, x: np.ndarray) -> float:
        """[J]"""

    def com(self, x: np.ndarray) -> np.ndarray:
        """Centre of mass [m], world."""


@runtime_checkable
class CompiledFloatingModel(FloatingBaseModel, Protocol):
    """The compiled engine's additions: the kernels (``pk``), their parameter arrays (``ti``, ``tf``), the
    one-call RK4 step with the stance foot held at ``anchor`` and the projection onto the contact."""

    ti: np.ndarray
    tf: np.ndarray
    pk: "ModuleType"

    def rk4_step(self, x: np.ndarray, v: np.ndarray, tau_j: np.ndarray, pushes: Sequence[tuple[float, float]],
                 foot: int, anchor: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, v, wrench) after one RK4 step of h [s] with held joint torques and pushes (force, height)."""

    def project(self, x: np.ndarray, v: np.ndarray, foot: int, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The foot put on its anchor, the velocity normal to the contact removed."""


def make_floating_model(desc: RobotDescription, engine: str) -> FloatingBaseModel:
    """The simulator's model for ``engine``: "fast" (compiled kernels, a :class:`CompiledFloatingModel`) or
    "reference" (Pinocchio). Raises ValueError naming the engine otherwise."""
    if engine == "fast":
        from biped_model.fast_engine import FastFloatingModel   # loads the compiled kernels only when used
        return FastFloatingModel(desc)
    if engine == "reference":
        from biped_model.floating import FloatingModel
        return FloatingModel(desc)
    raise ValueError(f"engine must be one of {ENGINE_NAMES}, got {engine!r}")
