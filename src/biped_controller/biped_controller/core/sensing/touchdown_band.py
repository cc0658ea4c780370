"""A predicted touchdown under an uncertain estimate: the k-sigma band of the swing sole's
predicted height and the torque admissible in both stances inside it. Pure NumPy + Pinocchio, no ROS.

With a known delay of d periods and the touchdown in the delayed sample (the plant's ``touchdown_delayed``),
the Smith predictor (``predictor``) decides the stance the controller acts in from the predicted swing sole
height. From an exact sample it meets the plant's impact to round-off; from a noisy estimate it misses by
the estimate's spread, and on the rigid plant one period in the wrong stance is a fall (the contact limits
of the foot really on the ground are not the ones the controller held). The decision here:

  height   z = z_s(q^-)   [m]: the lowest sole point of the swing foot above the stance sole line
           (``DelayPredictor.lowest_sole``) at the state q^- predicted to t_k from the sample *without* a
           touchdown (the foot may be below the ground: the old stance's hypothesis continued);
  spread   sigma_z^2 = g^T P_qq(t_k) g,  g = dz_s/dq at q^- (central differences, step ``FD_STEP`` rad),
           P_qq(t_k) = the position block of the estimator's covariance at the sample propagated over the
           sample's age Dt = t_k - t_j as one interval of the filter's own time update:
           P_qq + Dt (P_qv + P_vq) + Dt^2 P_vv + sigma_a^2 Dt^4 / 4 I  (``estimation`` module docstring);
  (a period with z > k R sqrt(6 trace P_qq) is outside the band without computing g: ``sigma_bound``, R the
  chain's longest lever, ``lever_bound``)
  band     |z| <= k sigma_z (k = ``touchdown_band_sigmas``) while the sole descends, z_s' = g q'^- < 0
           (a foot rising from the last touchdown is not landing): whether the foot is down at t_k is not
           known to the estimate's k-sigma level; outside it the predictor's own decision stands (z < 0:
           touched down, relabelled, the impact map; z > 0: the old stance).

Inside the band the stance the controller decides in is still the predictor's (its mean), but the torque
it sends must not break the contact of either hypothesis:

  old   (q^-, q'^-) in the sample's stance s (no touchdown yet), Gamma_old = Gamma_told (or relabelled);
  new   (q^+, q'^+) in the other stance: the predictor's touchdown state when it predicted one, otherwise
        the flat-foot impact map at (q^-, q'^-) (``predictor.flat_foot_impact``: touched down now).

For each hypothesis h the model's 17 rows (and for the new one two more: the foot the touchdown releases must
lift off, the vertical acceleration of its heel and toe >= 0, ``BothStancesTorque.liftoff_rows``; the rigid
plant ends a walk whose released foot sinks 1 mm, and the old stance's law, which holds that foot as its
stance, drives its ankle into the ground) (eq. 10, ``FixedFootModel.constraints`` with the controller's
tightened mu, heel and toe and its margins m) are linear in the torque: w_h = A_h^-1 (L_h Gamma - H_h),
L_h = I or the relabelling -flip, so A_q,h A_h^-1 L_h Gamma <= -m - b_q,h + A_q,h A_h^-1 H_h. If the
controller's torque Gamma* (in the told stance's paper order) satisfies the 36 rows (17 + 17 + 2) it is sent
unchanged; otherwise the torque sent is the least-violation answer ``solver.least_violation`` of the 36 rows with
x* = Gamma* and W = diag(1 / Gamma_max^2) (PIQP on the slack form: as its regularisation goes to 0, the
W-closest torque to Gamma* that holds both hypotheses' rows when they have a common point, else the one of
least summed squared violation; an active row is held to that regularisation, tested to 1e-4 m/s^2).
Reconciliation: the prediction is redone each period from the newest sample, so when the sensed stance
arrives the sample starts in it and there is no band (the estimate's impact map, ``pipeline``).

Without the estimator (perfect sensing, P = None) there is no band: the predictor is exact with an exact
model, and every run with perfect sensors is unchanged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from biped_model.fixed_foot import FixedFootModel

from biped_controller.core.qp.solver import least_violation

FD_STEP = 1e-7      # [rad] central-difference step of dz_s/dq (z_s is smooth away from a flat foot's kink)


@dataclass(frozen=True)
class TouchdownBand:
    """A period inside the band: z [m] and sigma_z [m] of the module docstring, and the two hypotheses'
    paper (q [rad], q' [rad/s], stance) at t_k."""

    z: float
    sigma_z: float
    q_old: np.ndarray
    qd_old: np.ndarray
    stance_old: int
    q_new: np.ndarray
    qd_new: np.ndarray
    stance_new: int


def propagated_position_cov(P: np.ndarray, dt: float, sigma_acc: float) -> np.ndarray:
    """P_qq(t_j + dt) of the module docstring from the (12, 12) covariance P of (q, q') at t_j."""
    P = np.asarray(P, dtype=float)
    Pqq, Pqv, Pvv = P[:6, :6], P[:6, 6:], P[6:, 6:]
    return Pqq + dt * (Pqv + Pqv.T) + dt * dt * Pvv + 0.25 * sigma_acc ** 2 * dt ** 4 * np.eye(6)


def sole_height_std(lowest_sole: Callable[[np.ndarray], float], q: np.ndarray, Pqq: np.ndarray) -> float:
    """sigma_z = sqrt(g^T P_qq g), g = dz_s/dq at q by central differences (``FD_STEP``)."""
    q = np.asarray(q, dtype=float)
    g = np.empty(6)
    for i in range(6):
        qp, qm = q.copy(), q.copy()
        qp[i] += FD_STEP
        qm[i] -= FD_STEP
        g[i] = (lowest_sole(qp) - lowest_sole(qm)) / (2.0 * FD_STEP)
    return float(math.sqrt(max(g @ Pqq @ g, 0.0)))


def sole_rate(lowest_sole: Callable[[np.ndarray], float], q: np.ndarray, qd: np.ndarray) -> float:
    """z_s' = (dz_s/dq) q' [m/s] by central differences along q' (step ``FD_STEP`` / |q'|)."""
    q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
    n = float(np.linalg.norm(qd))
    if n == 0.0:
        return 0.0
    h = FD_STEP / n
    return (lowest_sole(q + h * qd) - lowest_sole(q - h * qd)) / (2.0 * h)


def lever_bound(desc) -> float:
    """R [m]: no hinge is farther than this from a swing sole point along the chain (stance ankle, two legs,
    the swing foot to its heel or toe): 2 (thigh + shin) + max(-l_min, l_max). In the plane |dz_s/dq_i| <= R."""
    return 2.0 * desc.leg_length + max(-desc.foot.l_min, desc.foot.l_max)


def sigma_bound(R: float, Pqq: np.ndarray) -> float:
    """An upper bound of sigma_z without the gradient: g^T P g <= |g|^2 lambda_max(P) <= 6 R^2 trace(P)."""
    return float(R * math.sqrt(6.0 * max(float(np.trace(Pqq)), 0.0)))


def in_band(z: float, sigma_z: float, k: float) -> bool:
    """|z| <= k sigma_z with sigma_z > 0 (no band without a spread)."""
    return sigma_z > 0.0 and k > 0.0 and abs(z) <= k * sigma_z


class BothStancesTorque:
    """The torque admissible in both hypotheses of a band period (module docstring). ``margin`` (17,): the
    controller's margins in the row order of CONSTRAINT_NAMES; ``mu``, ``l_min``, ``l_max``: its tightened
    contact rows."""

    def __init__(self, model: FixedFootModel, margin: np.ndarray, mu: float, l_min: float, l_max: float):
        self.model = model
        self.margin = np.asarray(margin, dtype=float)
        self.mu, self.l_min, self.l_max = float(mu), float(l_min), float(l_max)
        self.W = 1.0 / np.asarray(model.torque_max, dtype=float) ** 2

    def rows(self, q: np.ndarray, qd: np.ndarray, relabelled: bool, released: bool = False
             ) -> tuple[np.ndarray, np.ndarray]:
        """(G, h) with G Gamma <= h the 17 rows of the hypothesis at (q, q') for the torque Gamma in the told
        stance's order (``relabelled``: the hypothesis is the other stance); ``released``: two more rows, the
        lift-off of the foot the touchdown released (module docstring, ``liftoff_rows``)."""
        dyn = self.model.dynamics(q, qd)
        cm = self.model.constraints(q, qd, dyn, mu=self.mu, l_min=self.l_min, l_max=self.l_max)
        Ainv = np.linalg.inv(dyn.A)
        A_q, b_q, m = cm.A_q, cm.b_q, self.margin
        if released:
            Jp, dp = self.liftoff_rows(q, qd)
            A_q, b_q, m = np.vstack([A_q, -Jp]), np.concatenate([b_q, -dp]), np.concatenate([m, [0.0, 0.0]])
        M = A_q @ Ainv                                    # rows per unit (Gamma_h - H_h)
        L = -np.fliplr(np.eye(6)) if relabelled else np.eye(6)
        return M @ L, -m - b_q + M @ dyn.H

    def liftoff_rows(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(J_p (2, 6), d_p (2,)) with the vertical acceleration of the swing foot's heel and toe
        a_p = J_p w + d_p [m/s^2]: z_p = z_a + l sin(theta), theta = sum q (stance foot flat), l = l_min, l_max
        (the foot's own, not the tightened ones), J_p = dz_a/dq + l cos(theta) 1^T, d_p = (dJ_z/dt) q' -
        l sin(theta) theta'^2 with (dJ_z/dt) q' by central differences of J_z along q' (step ``FD_STEP``/|q'|)."""
        q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        th, thd = float(np.sum(q)), float(np.sum(qd))
        Jz = self.model.swing_foot_jacobian(q)[1]
        n = float(np.linalg.norm(qd))
        if n > 0.0:
            h = FD_STEP / n
            drift = (self.model.swing_foot_jacobian(q + h * qd)[1] - self.model.swing_foot_jacobian(q - h * qd)[1]) \
                @ qd / (2.0 * h)
        else:
            drift = 0.0
        ls = (self.model.l_min, self.model.l_max)
        Jp = np.array([Jz + l * math.cos(th) for l in ls])
        dp = np.array([drift - l * math.sin(th) * thd * thd for l in ls])
        return Jp, dp

    def torque(self, band: TouchdownBand, torque: np.ndarray, told: int) -> tuple[np.ndarray, bool]:
        """(the torque to send, in the told stance's order; True when it differs from ``torque``)."""
        G1, h1 = self.rows(band.q_old, band.qd_old, band.stance_old != told)
        G2, h2 = self.rows(band.q_new, band.qd_new, band.stance_new != told, released=True)
        G, h = np.vstack([G1, G2]), np.concatenate([h1, h2])
        t0 = np.asarray(torque, dtype=float)
        if np.all(G @ t0 <= h):
            return t0, False
        res = least_violation(G, h, t0, self.W)
        x = np.asarray(res.x, dtype=float)
        if not np.all(np.isfinite(x)):
            return t0, False
        return x, True
