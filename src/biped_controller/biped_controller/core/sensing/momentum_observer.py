"""Generalized-momentum disturbance observer (De Luca & Mattone, 2003), on the controller's fixed-stance-foot
model. Pure NumPy + Pinocchio, no ROS.

Joint dynamics of the model in single support (paper joints q1..q6, stance foot fixed):
    A(q) q'' + C(q, q') q' + g(q) = Gamma + tau_d
where tau_d [N m] is everything the model does not contain: a push (J^T F), a model error (masses,
inertias), friction. With the generalized momentum p = A(q) q' and A' = C + C^T,
    p' = Gamma + C^T(q, q') q' - g(q) + tau_d,
so the first-order observer of gain K [1/s]
    r(t) = K ( p(t) - p(0) - int_0^t (Gamma + C^T q' - g + r) ds )
obeys r' = K (tau_d - r): r is tau_d through a first-order low-pass of bandwidth K, with no joint
acceleration needed. Discrete (the controller's samples t_k, the torque Gamma_{k-1} held over
[t_{k-1}, t_k)): I_k = I_{k-1} + (Gamma_{k-1} + r_{k-1}) dt - (beta_{k-1} + beta_k) dt / 2 with
beta = g - C^T q' (trapezoid), r_k = K (p_k - p_0 - I_k).

The torso wrench. r (6 joint torques) is read as an equivalent planar wrench W = (F_x, F_z, M_y) on the
torso at ``height`` above the hip (F in world axes [N], M_y counter-clockwise [N m]): r = J_j^T W with J
the (3, 9) Jacobian of the torso point's (x, z) velocity and the torso's pitch rate over the locked-root
chain, J_j its joint columns; the stance-leg rows give W by least squares (the swing-leg rows of J_j^T
are zero). A push on the torso is such a wrench; a torso mass error is, in a slow gait, one too (the
missing weight as a vertical force F_z at the torso). The wrench moves the ground reaction predicted by
the model, [R_x, R_y] = B w + h_b, by
    dR = (B A^-1 J_j^T - J_r^T) W  (first two rows: S W),  J_r the Jacobian's root columns
(the joint accelerations change by A^-1 J_j^T W, and the wrench goes to the ground through the stance
foot). Its covariance, from the velocity noise the observer passes straight through (r ~ K A dq' at
high frequency): Sigma_r = K^2 A Sigma_qd A, Sigma_W = J^+ Sigma_r J^+T, Sigma_dR = S Sigma_W S^T.

At a touchdown the model's joints change roles: the observer restarts (p(0) = p at the first sample of
the new stance) with r set to the previous wrench seen through the new stance's Jacobian, so the
estimate of a push that goes on is kept. That carried wrench is a guess (a model error read as a torso
wrench in one stance is not the same wrench in the other): its error is taken as large as itself, and
decays with the observer's convergence, Sigma_W += diag((W_restart e^{-K (t - t_restart)})^2). (Measured
with the inertias 30 % larger than modelled: without this term the first period after the touchdown that
follows an 80 N push predicts l = -0.095 m where the plant has -0.100 m, a fall over the heel; with it an
80 N and a 160 N push are survived.)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from biped_model.description import RobotDescription
from biped_model.fixed_foot import FixedFootModel
from biped_model.finite import finite_number


class MomentumObserverError(ValueError):
    """A setting of the momentum observer is invalid (the message names it)."""


@dataclass(frozen=True)
class Wrench:
    """An observer's output at one sample: r (6,) [N m], W = (F_x [N], F_z [N], M_y [N m]) on the torso,
    its covariance (3, 3), and the shift of the predicted ground force dR (2,) [N] with its covariance."""

    r: np.ndarray
    W: np.ndarray
    cov_W: np.ndarray
    dR: np.ndarray
    cov_dR: np.ndarray
    S: np.ndarray          # (2, 3): dR = S W


class MomentumTerms:
    """A(q), beta(q, q') = g(q) - C(q, q')^T q' and the torso wrench Jacobian of the fixed-foot model (own
    Pinocchio data; Pinocchio's Coriolis matrix satisfies A' = C + C^T)."""

    def __init__(self, desc: RobotDescription):
        self.ffm = FixedFootModel(desc)
        self.model = self.ffm.model
        self.data = self.model.createData()
        self._q = np.zeros(9)
        self._v = np.zeros(9)

    def mass_beta(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._q[3:] = q
        self._v[3:] = qd
        M = pin.crba(self.model, self.data, self._q).copy()
        M = np.triu(M) + np.triu(M, 1).T
        C = pin.computeCoriolisMatrix(self.model, self.data, self._q, self._v)
        g = pin.computeGeneralizedGravity(self.model, self.data, self._q)
        A = M[3:, 3:].copy()
        beta = g[3:] - C[3:, 3:].T @ np.asarray(qd, dtype=float)
        return A, beta

    def wrench_jacobian(self, q: np.ndarray, height: float) -> np.ndarray:
        """(3, 9): rows torso point x, z velocity at ``height`` above the hip, torso pitch rate."""
        J = np.zeros((3, 9))
        J[:2] = self.ffm.torso_point_jacobian(q, height)
        J[2, 2:6] = 1.0          # root pitch + q1 + q2 + q3 (all axes (0, -1, 0): counter-clockwise)
        return J

    def reaction_shift(self, q: np.ndarray, qd: np.ndarray, height: float) -> np.ndarray:
        """S (2, 3): the model's predicted (R_x, R_y) move by S W under a torso wrench W."""
        dyn = self.ffm.dynamics(q, qd)
        J = self.wrench_jacobian(q, height)
        Jj, Jr = J[:, 3:], J[:, :3]
        return (dyn.B @ np.linalg.solve(dyn.A, Jj.T) - Jr.T)[:2]


class MomentumObserver:
    """The observer of the module docstring (gain ``K`` [1/s], wrench point ``height`` [m] above the hip)."""

    def __init__(self, desc: RobotDescription, K: float, height: float):
        self.K = finite_number(K, "momentum_observer_gain", above=0, error=MomentumObserverError)
        self.height = float(height)
        self.terms = MomentumTerms(desc)
        self.reset()

    def reset(self) -> None:
        self._started = False
        self.r = np.zeros(6)
        self.W = np.zeros(3)
        self._I = np.zeros(6)
        self._p0 = np.zeros(6)
        self._beta = np.zeros(6)
        self._stance: int | None = None
        self._W_restart = np.zeros(3)
        self._since = 0.0

    def update(self, q: np.ndarray, qd: np.ndarray, stance: int, torque_prev: np.ndarray | None, dt: float,
               cov_qd: np.ndarray | None = None) -> Wrench:
        """One sample: (q, q') [rad, rad/s] of the current ``stance``, the torque held over the interval
        ``dt`` [s] that led here (paper order of this stance; None at the first sample), ``cov_qd`` (6, 6)
        the velocity's covariance [rad^2/s^2] (None: 0). Returns the wrench estimate."""
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        A, beta = self.terms.mass_beta(q, qd)
        p = A @ qd
        J = self.terms.wrench_jacobian(q, self.height)
        Jj = J[:, 3:]
        if not self._started or stance != self._stance or torque_prev is None:
            # (re)start: p(0) = p now, r set to the kept wrench seen through this stance's Jacobian
            r0 = Jj.T @ self.W if self._started else np.zeros(6)
            self._W_restart = self.W.copy() if self._started else np.zeros(3)
            self._since = 0.0
            self._p0 = p.copy()
            self._I = -r0 / self.K
            self.r = r0
            self._started = True
        else:
            self._I = self._I + (np.asarray(torque_prev, dtype=float) + self.r) * dt - 0.5 * (self._beta + beta) * dt
            self.r = self.K * (p - self._p0 - self._I)
            self._since += dt
        self._beta = beta
        self._stance = stance
        pinv = np.linalg.pinv(Jj.T)           # (3, 6)
        self.W = pinv @ self.r
        cov_r = (self.K ** 2) * (A @ cov_qd @ A) if cov_qd is not None else np.zeros((6, 6))
        cov_W = pinv @ cov_r @ pinv.T
        # after a restart the wrench carried over is a guess: its error is as large as itself, and the
        # observer's own convergence (e^{-K t}) removes it
        cov_W = cov_W + np.diag((self._W_restart * math.exp(-self.K * self._since)) ** 2)
        S = self.terms.reaction_shift(q, qd, self.height)
        return Wrench(r=self.r.copy(), W=self.W.copy(), cov_W=cov_W, dR=S @ self.W, cov_dR=S @ cov_W @ S.T, S=S)
