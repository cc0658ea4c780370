"""The adaptive controller's compiled period (fast engine): the kernels' module names and loaders
(``controller_kernels``, ``wbc_kernels``, through ``biped_model.numba_cache``) and :class:`CompiledPeriod`, which
runs ``controller_kernels.step`` on the controller's own arrays and returns the same ``ControlOutput`` as the
Python steps of ``controller.AdaptiveController`` (its oracle). Units and row orders are the layout's
(``controller_layout``).
"""
from __future__ import annotations

import numpy as np

from biped_model import numba_cache
from biped_model.fixed_foot import N_CONSTRAINTS
from biped_controller.core.control.controller_layout import MEMORY, QP_ROWS, RES, TORSO_QP_ROWS, WORK, R_, W_
from biped_controller.core.control.status import (MSG_FIXED_REFERENCE, MSG_X_STAR_FEASIBLE, NO_ADAPTATION,
                                                   ControlOutput)
from biped_controller.core.qp.problem import ACTIVE, INFEASIBLE_FALLBACK, UNCONSTRAINED
from biped_controller.core.qp.solver import SOLVER_ERROR

CONTROLLER_KERNELS = "biped_controller.core.control.controller_kernels"
# what the compiled period is compiled against besides its own source (kernels it calls, offsets it reads)
CONTROLLER_KERNELS_SOURCES = ("biped_model.planar_abi", "biped_model.planar_kernels", "biped_model.layout",
                           "biped_model.gait_family",
                           "biped_controller.core.control.controller_layout", "biped_controller.core.qp.problem",
                           "biped_controller.core.qp.exact_kernels")


WBC_KERNELS = "biped_controller.core.control.wbc_kernels"
WBC_KERNELS_SOURCES = CONTROLLER_KERNELS_SOURCES + (CONTROLLER_KERNELS,)


def load_wbc_kernels():
    """The compiled whole-body stage (``wbc_kernels``, modes wbc and hybrid) through ``numba_cache.load``."""
    load_controller_kernels()
    return numba_cache.load(WBC_KERNELS, sources=WBC_KERNELS_SOURCES)


def load_controller_kernels():
    """The compiled control period (``controller_kernels``), through ``numba_cache.load``: its ``begin`` and
    ``commit`` are the one home of the parameter advance, the observer's mode and the period's commit, for
    the compiled period and the Python steps alike."""
    return numba_cache.load(CONTROLLER_KERNELS, sources=CONTROLLER_KERNELS_SOURCES)

_SENS_RES = slice(RES.at.sens_dR, RES.at.sens_margin + RES.sizes["sens_margin"])


class CompiledPeriod:
    """The compiled period of an :class:`AdaptiveController` (fast engine): ``controller_kernels.step`` on the
    controller's own arrays (gains, cons, memory), the QP when x* is not feasible, the same
    ``ControlOutput`` as the Python steps."""

    def __init__(self, ctrl):
        self.ck = ctrl.ck
        self.ctrl = ctrl
        self.coef, self.inner, self.centers = ctrl.family.piece_arrays()
        self.ti, self.tf = ctrl._fast.ti, ctrl._fast.tf
        # the rows G x <= h of the period (modes lambda, all: the four torso rows and the column of lambda'')
        self.nx = 3 if ctrl.torso else 2
        self.G = np.zeros((TORSO_QP_ROWS, 3) if ctrl.torso else (QP_ROWS, 2))
        self.h = np.zeros(self.G.shape[0])
        # modes wbc, hybrid: the compiled whole-body stage (wbc_kernels) with PIQP when it does not settle;
        # ``python_stage`` True runs the Python stage (wbc.WholeBodyStage, the tests' oracle) instead
        self.wk = load_wbc_kernels() if ctrl.whole_body is not None else None
        self.python_stage = False
        self.stage_counts = {"solved": 0, "piqp": 0}   # periods the compiled stage changed w / handed to PIQP
        self.Gw = np.zeros((2 * N_CONSTRAINTS, 6))
        self.hw = np.zeros(2 * N_CONSTRAINTS)

    def compute(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int) -> ControlOutput | None:
        ck, ctrl = self.ck, self.ctrl
        if q.dtype != np.float64 or not q.flags.c_contiguous:
            q = np.ascontiguousarray(q, dtype=float)
        if qd.dtype != np.float64 or not qd.flags.c_contiguous:
            qd = np.ascontiguousarray(qd, dtype=float)
        work = np.empty((WORK.size, 6))
        res = np.empty(RES.size)
        if ctrl._compiled_sensing:              # the momentum observer's inputs to the period
            ctrl._sensing.into_res(res[_SENS_RES])
        G, h = self.G, self.h
        t, stance = float(t), int(stance)
        code = ck.step(self.coef, self.inner, self.centers, self.ti, self.tf, q, qd, t, stance, ctrl.gains,
                       ctrl.cons, ctrl.memory, G, h, work, res)
        if code == ck.NONFINITE:
            return None
        Gr = hr = xs = None
        if not ctrl.adapted:
            status, msg = NO_ADAPTATION, MSG_FIXED_REFERENCE[ctrl.cfg.mode]
        elif code == ck.FEASIBLE:
            if ctrl.keep_qp:                  # the instance is only handed out when kept
                Gr, hr, xs = self.reduced(G, h, res)
            status, msg = UNCONSTRAINED, MSG_X_STAR_FEASIBLE
        else:
            answer = self.solve_qp(G, h, res)
            if answer is None:
                return None
            x, status, msg, Gr, hr, xs = answer
            res[R_.x:R_.x + x.size] = x
            ck.finish(ctrl.cons, ctrl.memory, work, res, qd, t, stance)
        torque, wb = work[W_.torque].copy(), None
        if ctrl.whole_body is not None:       # modes wbc, hybrid: the whole-body stage
            if self.python_stage:
                torque, wb = self._whole_body(work, res, torque, status)
            else:
                torque, wb = self._whole_body_compiled(work, res, status, t)
        return ctrl._output(res, torque, t, stance, status, msg,
                            Gr.copy() if Gr is not None else None, hr, xs.copy() if xs is not None else None, wb)

    def _whole_body_compiled(self, work: np.ndarray, res: np.ndarray, status: int, t: float):
        """The compiled whole-body stage (``wbc_kernels.stage``) after the compiled period (which has
        committed its w to ``memory``): it writes the stage's status fields into ``res`` and, when it changes
        w, the torque, outputs and the memory's w; when its active-set iteration does not settle, the held
        PIQP of the Python stage answers (least violation when no w holds every row) and ``wbc_kernels.apply``
        takes that w. Returns (torque, False: the status fields are in ``res``)."""
        ctrl, wk = self.ctrl, self.wk
        run = ctrl.whole_body.mode == "wbc" or status in (INFEASIBLE_FALLBACK, SOLVER_ERROR)
        code = wk.stage(ctrl.wbc, ctrl.cons, ctrl.memory, work, res, self.Gw, self.hw, bool(run))
        if code == wk.SOLVED:
            self.stage_counts["solved"] += 1
        elif code == wk.NEEDS_PIQP:
            self.stage_counts["piqp"] += 1
            w_star = work[W_.w].copy()
            wb = ctrl.whole_body.qp.solve(self.Gw, self.hw, w_star)
            wk.apply(ctrl.cons, ctrl.memory, work, res, self.Gw, self.hw, w_star,
                     np.ascontiguousarray(wb.w, dtype=float), int(wb.status))
        elif code == wk.NONFINITE:      # non-finite rows: w* is kept (the Python stage's SOLVER_ERROR)
            res[R_.wbc_status] = SOLVER_ERROR
        return work[W_.torque].copy(), False

    def reduced(self, G: np.ndarray, h: np.ndarray, res: np.ndarray):
        """The QP over the adapted parameters of the rows G x <= h (x = (p'', tau''), modes lambda and all
        (p'', tau'', lambda'')) and x* of ``res``: a parameter that is not adapted stays at x* and moves to the
        right-hand side. Returns (G_r, h_r, x*_r)."""
        ctrl = self.ctrl
        xs_full = res[R_.x_star:R_.x_star + self.nx]
        idx, fixed = ctrl._adapted_idx, ctrl._fixed_idx
        Gr, xs = G[:, idx], xs_full[idx]
        hr = h - G[:, fixed] @ xs_full[fixed] if fixed else h.copy()
        return Gr, hr, xs

    def solve_qp(self, G: np.ndarray, h: np.ndarray, res: np.ndarray):
        """The period's decision when x* is not feasible (``controller_kernels.step`` returned NEEDS_QP with G,
        h and ``res``): the controller's QP on the adapted parameters. Returns (x (2,), status, message, G_r,
        h_r, x*_r), or None when the answer is not finite (the caller takes the reference path). Also the
        compiled loop's QP periods (``segment``): one home of the decision. Modes lambda and all: x (3,), and
        lambda'' held to the torso's range after an answer that does not hold the rows (as the Python steps)."""
        Gr, hr, xs = self.reduced(G, h, res)
        qres = self.ctrl.qp.solve(Gr, hr, xs)
        x = res[R_.x_star:R_.x_star + self.nx].copy()
        x[self.ctrl._adapted_idx] = qres.x
        if not np.all(np.isfinite(x)):
            return None
        msg = qres.message
        if qres.status not in (UNCONSTRAINED, ACTIVE):
            msg += self.ctrl._hold_ranges(x, res, (float(res[R_.lam]), float(res[R_.lam + 1]))
                                          if self.nx == 3 else None)
        return x, qres.status, msg, Gr, hr, xs

    def _whole_body(self, work: np.ndarray, res: np.ndarray, torque: np.ndarray, status: int):
        """The whole-body stage after the compiled period (which has committed its w to ``memory``): when it
        changes w, the torque, the reported margins, reaction, l and tightest row follow the new w, and the
        memory's w (the observer's next residual) is the new w. Returns (torque, WBCResult or None)."""
        ctrl = self.ctrl
        A, H, B = work[W_.A:W_.A + 6], work[W_.H], work[W_.B:W_.B + 3]
        hbc = res[R_.h_b_c:R_.h_b_c + 3]
        wb = ctrl.whole_body.decide(work[W_.w].copy(), status, A, H, B, res[R_.h_b:R_.h_b + 3], hbc)
        if wb is None or wb.status == UNCONSTRAINED:
            return torque, wb
        torque, R, margins, tightest, zmp = ctrl.whole_body.outputs(wb.w, A, H, B, hbc)
        res[RES.slice("margins")] = margins
        res[RES.slice("reaction")] = R
        res[R_.tightest], res[R_.zmp] = tightest, zmp
        ctrl.memory[MEMORY.slice("prev_w")] = wb.w
        return torque, wb
