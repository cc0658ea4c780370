"""Whole-body QP (the field's standard baseline): choose the joint accelerations themselves.

Pure numerics, no ROS. Kuindersma, Permenter & Tedrake (2014), TSID and mc_rtc control a legged robot
this way: keep the reference, and each period pick the joint accelerations w closest to the tracking
law's w*, subject to the contact and actuator constraints. Here, over w in R^6 (rad/s^2, paper joints
q1..q6 of the stance-foot-fixed chain)::

    minimise    1/2 (w - w*)^T M (w - w*)
    subject to  G w <= h          (m = 34 rows: WBC_ROWS)

* The rows are the 17 of eq. (10), ``A_q w + b_q < 0`` (``biped_model.fixed_foot``, row order
  ``CONSTRAINT_NAMES``), with the controller's margins, exactly as the p/tau QP states them (eq. 21
  with w = D x + v): rows 0-16 with the disturbance observer's shifted reaction drift h_b,c, rows 17-33
  the same without it (robust to a push that ends during the coming period; identical rows when the
  estimate is 0). The contact rows are ``C R + e Gamma_1 + margin < 0`` with R = B w + h_b and
  Gamma_1 = A[0] w + H[0]; the torque rows ``Gamma - (Gamma_max - margin_torque)`` and
  ``(Gamma_min + margin_torque) - Gamma``. So G = [A_q; A_q] and h = -(b_q + margin) per block. Units
  of row i: N (take_off, slides), N m (zmp rows, torques).
* M = weight_joint I_6 + weight_torso s s^T, s = (1, 1, 1, 0, 0, 0): s . w is the torso's pitch
  acceleration (its absolute angle is q1 + q2 + q3 with the stance foot flat), so the second term is a
  torso-pitch task weight. Units 1/(rad/s^2)^2 times a cost unit; only the ratio matters.
* Multipliers z >= 0 with W (w - w*) + G^T z = 0 (the sign convention of :mod:`problem`).

Solver: the PIQP-held :class:`solver.AdaptationQP` (n = 6, any n works with PIQP; its objects held, each
solve set up from its instance alone; duplicated rows dropped; polished and KKT-checked), on the variable y = L^T w with M = L L^T
(Cholesky), which turns the weight into the identity that solver takes (its weight is diagonal):
1/2 |y - y*|^2 = 1/2 (w - w*)^T M (w - w*), G w = (G L^-T) y. Statuses are those of :mod:`problem`:
UNCONSTRAINED (G w* <= h with zero tolerance, evaluated on w itself; w = w* bit for bit, no solver),
ACTIVE, INFEASIBLE_FALLBACK (no w holds every row: the least-violation answer
``argmin sum_i max(G w - h, 0)_i^2 + eps (w - w*)^T M (w - w*)``, the p/tau QP's own definition, which
is invariant under the change of variable), SOLVER_ERROR (non-finite data; w = w*).

This module is the Python stage and the oracle; :mod:`wbc_kernels` is its compiled twin (the controller's
compiled period and the compiled loop run it; the rows there are these rows to the bit, the early-out the
same expression, and its active-set answer this QP's optimum to round-off; this held PIQP answers when
the compiled iteration does not settle).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from biped_model.fixed_foot import N_CONSTRAINTS
from biped_model.finite import finite_number
from biped_controller.core.control.controller_layout import WBC_MODE_HYBRID, WBC_MODE_WBC
from biped_controller.core.qp.solver import AdaptationQP
from biped_controller.core.qp.problem import (
    DEFAULT_ACTIVE_TOL,
    INFEASIBLE_FALLBACK,
    SOLVER_ERROR,
    UNCONSTRAINED,
    QPResult,
    QPShapeError,
    constraint_values,
)

N_JOINTS = 6
#: rows of the whole-body QP: the 17 constraints with the estimated push force, the same without it
WBC_ROWS = 2 * N_CONSTRAINTS
#: s . w = torso pitch acceleration [rad/s^2] (absolute torso angle q1 + q2 + q3, stance foot flat)
TORSO_PITCH_ROW = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])


class WBCError(ValueError):
    """A whole-body QP setting is out of range (message names it)."""


def weight_matrix(weight_joint: float, weight_torso: float) -> np.ndarray:
    """M = weight_joint I_6 + weight_torso s s^T (symmetric positive definite for weight_joint > 0 and
    weight_torso >= 0). Raises :class:`WBCError` naming the bad weight."""
    for name, v, lo_ok in (("wbc_weight_joint", weight_joint, False), ("wbc_weight_torso", weight_torso, True)):
        finite_number(v, name, **({"at_least": 0} if lo_ok else {"above": 0}), error=WBCError)
    return float(weight_joint) * np.eye(N_JOINTS) + float(weight_torso) * np.outer(TORSO_PITCH_ROW, TORSO_PITCH_ROW)


def rows_on_w(A: np.ndarray, H: np.ndarray, B: np.ndarray, h_b: np.ndarray, h_b_c: np.ndarray,
              C: np.ndarray, e: np.ndarray, margin: np.ndarray, torque_min: np.ndarray,
              torque_max: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 34 rows G w <= h of the whole-body QP (module docstring).

    A (6, 6) and H (6,) of eq. (1) [N m per rad/s^2, N m]; B (3, 6), h_b (3,) the reaction rows
    (R = B[:2] w + h_b[:2], [N]); h_b_c (3,) the same drift with the observer's estimated force (h_b when
    off); C (5, 2), e (5,) the controller's contact rows (``contact_rows`` with its tighter mu and foot
    range); margin (17,) subtracted from the right-hand side; torque limits (6,) [N m]."""
    # element by element, (C_r0 x_0 + C_r1 x_1) + e_r y: no BLAS, the same bits as wbc_kernels.rows
    A_q = np.empty((N_CONSTRAINTS, N_JOINTS))
    A_q[:5] = (C[:, :1] * B[0] + C[:, 1:2] * B[1]) + e[:, None] * A[0]
    A_q[5:11] = A
    A_q[11:17] = -A
    b_c = np.empty(N_CONSTRAINTS)
    b_c[:5] = (C[:, 0] * h_b_c[0] + C[:, 1] * h_b_c[1]) + e * H[0]
    b_c[5:11] = H - torque_max
    b_c[11:17] = torque_min - H
    b_0 = b_c.copy()
    b_0[:5] = (C[:, 0] * h_b[0] + C[:, 1] * h_b[1]) + e * H[0]
    G = np.vstack([A_q, A_q])
    h = np.concatenate([-(b_c + margin), -(b_0 + margin)])
    return G, h


@dataclass(frozen=True)
class WBCResult:
    """Answer of the whole-body QP.

    w : (6,) chosen joint accelerations [rad/s^2].
    status : UNCONSTRAINED, ACTIVE, INFEASIBLE_FALLBACK or SOLVER_ERROR (:mod:`problem`).
    message : detail (solver, violated rows).
    active : (17,) bool, constraint i active (G w - h >= -active_tol) in either block (with or without
        the estimated force), in the order of ``CONSTRAINT_NAMES``.
    deviation : |w - w*|_2 [rad/s^2] (0 when UNCONSTRAINED).
    max_violation : max(G w - h, 0) in the units of the worst row (0 when the rows hold).
    qp : the underlying solver's answer in y = L^T w (None when no solver ran).
    """

    w: np.ndarray
    status: int
    message: str
    active: np.ndarray
    deviation: float
    max_violation: float
    qp: QPResult | None = None

    @property
    def active_mask(self) -> int:
        """The active rows as a bit mask (bit i = CONSTRAINT_NAMES[i])."""
        return int(sum(1 << i for i in np.flatnonzero(self.active)))


def rows_hold(G: np.ndarray, h: np.ndarray, w: np.ndarray) -> bool:
    """G w <= h with zero tolerance (the early-out expression of the p/tau QP, :func:`constraint_values`)."""
    return bool(np.all(constraint_values(G, w, h) <= 0.0))


class WholeBodyQP:
    """The held whole-body QP solver: one :class:`solver.AdaptationQP` made at construction, whose PIQP
    objects are set up from each call's instance (an answer depends on that instance alone).

    Parameters: M (6, 6) symmetric positive definite weight (:func:`weight_matrix`); ``m`` rows
    (default WBC_ROWS); ``active_tol`` (row units) for the ``active`` mask."""

    def __init__(self, M: np.ndarray, m: int = WBC_ROWS, active_tol: float = DEFAULT_ACTIVE_TOL):
        M = np.asarray(M, dtype=float)
        if M.shape != (N_JOINTS, N_JOINTS):
            raise QPShapeError(f"M has shape {M.shape}, expected (6, 6)")
        if not np.all(np.isfinite(M)) or not np.allclose(M, M.T, rtol=0.0, atol=1e-12 * np.abs(M).max()):
            raise WBCError("M must be finite and symmetric")
        try:
            L = np.linalg.cholesky(M)
        except np.linalg.LinAlgError as exc:
            raise WBCError(f"M must be positive definite: {exc}") from exc
        self.M = M.copy()
        self.m = int(m)
        self._LT = L.T.copy()                        # y = L^T w
        self._LinvT = np.linalg.inv(L).T.copy()      # w = L^-T y
        self.active_tol = float(active_tol)
        self.qp = AdaptationQP(N_JOINTS, self.m, np.ones(N_JOINTS), solver="piqp", fallback="piqp",
                               active_tol=self.active_tol)

    def _fold(self, active_rows: np.ndarray) -> np.ndarray:
        a = np.asarray(active_rows, dtype=bool)
        return a[:N_CONSTRAINTS] | a[N_CONSTRAINTS:2 * N_CONSTRAINTS] if a.size >= 2 * N_CONSTRAINTS \
            else a[:N_CONSTRAINTS].copy()

    def solve(self, G: np.ndarray, h: np.ndarray, w_star: np.ndarray) -> WBCResult:
        """The QP of the module docstring for this period's rows and target. Raises only
        :class:`QPShapeError` (shapes); everything else is a status."""
        G = np.asarray(G, dtype=float)
        h = np.asarray(h, dtype=float)
        w_star = np.asarray(w_star, dtype=float)
        if G.shape != (self.m, N_JOINTS) or h.shape != (self.m,) or w_star.shape != (N_JOINTS,):
            raise QPShapeError(f"G {G.shape}, h {h.shape}, w_star {w_star.shape}: expected ({self.m}, 6), "
                               f"({self.m},), (6,)")
        if not (np.all(np.isfinite(G)) and np.all(np.isfinite(h)) and np.all(np.isfinite(w_star))):
            v = constraint_values(G, w_star, h)
            return WBCResult(w=w_star.copy(), status=SOLVER_ERROR, message="non-finite G, h or w*",
                             active=np.zeros(N_CONSTRAINTS, bool), deviation=0.0,
                             max_violation=float(np.nanmax(np.maximum(v, 0.0))) if np.any(np.isfinite(v)) else math.inf)
        v = constraint_values(G, w_star, h)
        if np.all(v <= 0.0):
            return WBCResult(w=w_star.copy(), status=UNCONSTRAINED, message="w* holds every row",
                             active=self._fold(v >= -self.active_tol), deviation=0.0, max_violation=0.0)
        res = self.qp.solve(G @ self._LinvT, h, self._LT @ w_star)
        w = self._LinvT @ res.x
        if res.status == SOLVER_ERROR or not np.all(np.isfinite(w)):
            w = w_star.copy()
        v = constraint_values(G, w, h)
        return WBCResult(w=w, status=int(res.status), message=res.message,
                         active=self._fold(v >= -self.active_tol),
                         deviation=float(np.linalg.norm(w - w_star)),
                         max_violation=float(max(np.max(v), 0.0)), qp=res)


#: status of a whole-body stage that did not run (the ControllerStatus constant NO_ADAPTATION)
NOT_RUN = 4
#: the modes with a whole-body stage, and their code in the compiled stage's constants (controller_layout.WBC)
WBC_MODES = {"wbc": WBC_MODE_WBC, "hybrid": WBC_MODE_HYBRID}


class WholeBodyStage:
    """The whole-body stage of the controller's modes ``wbc`` and ``hybrid`` (after the p/tau decision).

    ``wbc``: every period, w* = the tracking law's w on the fixed reference (x = x*, as mode none); the
    whole-body QP relaxes it when it violates a row (UNCONSTRAINED, w unchanged, when it does not).
    ``hybrid``: the p/tau QP decides exactly as in mode ``both``; only when it did not hold its rows
    (status INFEASIBLE_FALLBACK or SOLVER_ERROR) the whole-body QP relaxes the adapted w around itself. A
    feasible p/tau answer holds the 17 rows (twice) that the whole-body QP checks, so the stage is not run
    then, and ``hybrid`` equals ``both`` bit for bit in those periods. Why this order and this target:
    the adaptation changes the reference (the robot's future: the stride and the timing of the next
    touchdown), the whole-body QP only the present acceleration (the reference stays where it was, and
    the tracking law pulls back towards it next period); so the adaptation goes first and does what it
    can, and the whole-body QP only takes the remaining violation, as close as M allows to what the
    adaptation chose (w* = the adapted w, same M as mode ``wbc``: one weight to argue, not two).

    The rows use the controller's margins and contact rows (``contact_rows`` with its mu and foot range)
    and the observer's shifted drift h_b,c, exactly as the p/tau QP's; the reported margins, reaction and
    ZMP are the robot's own rows with h_b,c (as the controller reports them)."""

    def __init__(self, mode: str, M: np.ndarray, C: np.ndarray, e: np.ndarray, margin: np.ndarray,
                 torque_min: np.ndarray, torque_max: np.ndarray, true_C: np.ndarray, true_e: np.ndarray,
                 row_scale: np.ndarray):
        if mode not in ("wbc", "hybrid"):
            raise WBCError(f"mode must be 'wbc' or 'hybrid' for a whole-body stage, got {mode!r}")
        self.mode = mode
        self.qp = WholeBodyQP(M)
        self.C, self.e, self.margin = np.asarray(C, float), np.asarray(e, float), np.asarray(margin, float)
        self.torque_min, self.torque_max = np.asarray(torque_min, float), np.asarray(torque_max, float)
        self.true_C, self.true_e = np.asarray(true_C, float), np.asarray(true_e, float)
        self.row_scale = np.asarray(row_scale, float)

    @classmethod
    def for_controller(cls, cfg, model) -> "WholeBodyStage":
        """From a ``ControllerConfig`` (mode, margins, wbc weights) and the controller's FixedFootModel."""
        from biped_model.fixed_foot import contact_rows
        C, e = contact_rows(cfg.margin_friction * model.mu, model.l_min + cfg.margin_zmp, model.l_max - cfg.margin_zmp)
        tC, te = contact_rows(model.mu, model.l_min, model.l_max)
        margin = np.concatenate([[cfg.margin_normal_force, 0.0, 0.0, 0.0, 0.0], np.full(12, cfg.margin_torque)])
        return cls(cfg.mode, weight_matrix(cfg.wbc_weight_joint, cfg.wbc_weight_torso), C, e, margin,
                   model.torque_min, model.torque_max, tC, te, model.row_scale)

    def decide(self, w: np.ndarray, qp_status: int, A, H, B, h_b, h_b_c) -> WBCResult | None:
        """The whole-body answer around ``w`` (the period's w after the p/tau decision), or None when the
        stage does not run (``hybrid`` with a p/tau answer that holds its rows)."""
        if self.mode == "hybrid" and qp_status not in (INFEASIBLE_FALLBACK, SOLVER_ERROR):
            return None
        G, h = rows_on_w(A, H, B, h_b, h_b_c, self.C, self.e, self.margin, self.torque_min, self.torque_max)
        return self.qp.solve(G, h, w)

    def outputs(self, w, A, H, B, h_b_c):
        """(torque (6,) = A w + H [N m], R (2,) = B[:2] w + h_b,c [N], margins (17,) of the robot's own rows
        (positive = satisfied), tightest row (scaled by row_scale), l = Gamma_1 / R_y [m]) for w."""
        torque = A @ w + H
        R = B[:2] @ w + h_b_c[:2]
        margins = np.empty(N_CONSTRAINTS)
        margins[:5] = -(self.true_C @ R + self.true_e * torque[0])
        margins[5:11] = self.torque_max - torque
        margins[11:17] = torque - self.torque_min
        tightest = int(np.argmin(margins / self.row_scale))
        zmp = float(torque[0] / R[1]) if R[1] != 0 else math.nan
        return torque, R, margins, tightest, zmp

    @staticmethod
    def status_fields(wb: WBCResult | None) -> dict:
        """The ControllerStatusData fields of the stage: wbc_status, wbc_active (bit mask), wbc_deviation."""
        if wb is None:
            return {"wbc_status": NOT_RUN, "wbc_active": 0, "wbc_deviation": 0.0}
        return {"wbc_status": int(wb.status), "wbc_active": wb.active_mask, "wbc_deviation": float(wb.deviation)}
