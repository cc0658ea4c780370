"""Hand the in-process closed loop's quiet periods to the compiled loop (``loop_kernels.run_segment``).

Pure Python + NumPy, no ROS. A :class:`Segment` binds one :class:`simulator.Simulator` and one
:class:`controller.AdaptiveController` (both on the fast engine, the simulator's sensors ideal): each
:meth:`Segment.run` packs their states into the kernel's arrays, runs periods until one needs Python
(the QP, an impact, a fall, ...), unpacks the states back into the objects, and returns the periods'
``StepRecord`` and ``ControllerStatusData``, identical to what ``ctrl.compute`` + ``sim.step`` return
one period at a time. The objects then take the next period themselves.
"""
from __future__ import annotations

import numpy as np

from biped_sim.robot.floating import PAPER_FROM_URDF
from biped_sim.plant.records import StepRecord
from biped_sim.plant.rigid import Simulator

from biped_controller.studies import loop_kernels as lk
from biped_controller.core.controller import NO_ADAPTATION, AdaptiveController, ControllerStatusData, ParamState, _Previous
from biped_controller.core.qp_types import UNCONSTRAINED

_PERM = np.ascontiguousarray(np.array(PAPER_FROM_URDF, dtype=float))


class Segment:
    """The compiled loop for one (simulator, controller) pair. ``keep_records`` False: only the last
    period of each segment is returned (enough for a run's outcome, ~2x cheaper than building every
    record); ``capacity`` rows are recorded per call."""

    def __init__(self, sim: Simulator, ctrl: AdaptiveController, keep_records: bool = True, capacity: int = 8192):
        if not self.eligible(sim, ctrl):
            raise ValueError("Segment needs the fast engine on both sides and ideal sensors")
        self.sim, self.ctrl, self.fp = sim, ctrl, ctrl._kernel
        self.keep = keep_records
        d, c = sim.desc, sim.cfg
        lo, hi = d.torque_limits()
        self.slim = np.array([d.mu, d.foot.l_min, d.foot.l_max, c.touchdown_tolerance, c.clearance_before_touchdown,
                              c.liftoff_penetration, c.control_period, float(c.substeps), *lo, *hi], dtype=float)
        assert self.slim.size == lk.SLIM_SIZE
        self.cst = np.zeros(lk.CST_SIZE)
        self.sst = np.zeros(lk.SST_SIZE)
        self.rec = np.empty((capacity, lk.REC_COLS))
        self.sta = np.empty((capacity, lk.STA_COLS))
        self.out = np.zeros(1)
        self.ended = ""

    @staticmethod
    def eligible(sim: Simulator, ctrl: AdaptiveController) -> bool:
        # mode wbc checks its rows every period in Python (wbc.py); hybrid only after a p/tau QP, which the
        # compiled loop hands to the objects anyway
        return bool(sim._fast and getattr(ctrl, "_kernel", None) is not None and sim.sensor.identity
                    and ctrl.cfg.mode != "wbc")

    def _pack(self) -> None:
        ctrl, sim, cst, fp = self.ctrl, self.sim, self.cst, self.fp
        s = ctrl.state
        cst[lk.C_P], cst[lk.C_PDOT], cst[lk.C_TAU], cst[lk.C_TAUDOT] = s.p, s.p_dot, s.tau, s.tau_dot
        cst[lk.C_PDD], cst[lk.C_TDD] = ctrl._decision
        cst[lk.C_HAS_TLAST] = 0.0 if ctrl._t_last is None else 1.0
        cst[lk.C_TLAST] = 0.0 if ctrl._t_last is None else ctrl._t_last
        cst[lk.C_STANCE] = -1.0 if ctrl.stance is None else ctrl.stance
        prev = ctrl._prev
        cst[lk.C_PREV_OK] = 0.0 if prev is None else 1.0
        if prev is not None:
            cst[lk.C_PREV_STANCE], cst[lk.C_PREV_T] = prev.stance, prev.t
            fp.prev[0], fp.prev[1], fp.prev[2:] = prev.qd, prev.w, prev.A
        cst[lk.C_F] = ctrl.force_estimate
        cst[lk.C_STEP] = ctrl.step_index
        sst = self.sst
        sst[lk.S_T], sst[lk.S_STEP], sst[lk.S_STANCE] = sim.t, sim.step_index, sim.stance
        sst[lk.S_CLEARED] = float(sim.cleared)
        sst[lk.S_ANCHOR:lk.S_ANCHOR + 3] = sim.anchor
        ps = sim.book.pushes
        self.pushes = np.array([[p.start, p.end, p.force, p.height] for p in ps], dtype=float).reshape(len(ps), 4)

    def _unpack(self, n: int, x: np.ndarray, v: np.ndarray) -> None:
        ctrl, sim, cst, sst = self.ctrl, self.sim, self.cst, self.sst
        ctrl.state = ParamState(float(cst[lk.C_P]), float(cst[lk.C_PDOT]), float(cst[lk.C_TAU]), float(cst[lk.C_TAUDOT]))
        ctrl._decision = (float(cst[lk.C_PDD]), float(cst[lk.C_TDD]))
        ctrl._t_last = float(cst[lk.C_TLAST])
        ctrl.stance = int(cst[lk.C_STANCE])
        P = self.fp.prev
        ctrl._prev = _Previous(qd=P[0].copy(), w=P[1].copy(), A=P[2:].copy(), stance=int(cst[lk.C_PREV_STANCE]),
                               t=float(cst[lk.C_PREV_T]))
        ctrl.force_estimate = float(cst[lk.C_F])
        ctrl.step_index = int(cst[lk.C_STEP])
        s = ctrl.state
        ctrl._period_start = ParamState(s.p, s.p_dot, s.tau, s.tau_dot)
        sim.x, sim.v = x, v
        sim.t = float(sst[lk.S_T])
        sim.step_index = int(sst[lk.S_STEP])
        sim.cleared = bool(sst[lk.S_CLEARED])

    def run(self, t_stop: float, max_periods: int = 1 << 40) -> tuple[list[StepRecord], list[ControllerStatusData]]:
        """Periods until one needs Python, ``t_stop`` [s] is reached (the period reaching it included) or
        ``max_periods``; returns their records and statuses (all, or the last one, see ``keep_records``)."""
        self._pack()
        sim, ctrl, fp = self.sim, self.ctrl, self.fp
        step0, cstep0, stance = sim.step_index, ctrl.step_index, sim.stance
        x = sim.x.copy()
        v = sim.v.copy()
        par = fp.par.copy()   # the kernel writes the period's state into par; the objects keep theirs
        n = lk.run_segment(fp.coef, fp.inner, fp.centers, fp.ti, fp.tf, par, fp.cons, self.cst, fp.prev,
                           sim.fm.ti, sim.fm.tf, x, v, self.sst, self.slim, self.pushes, _PERM,
                           float(t_stop), int(max_periods), not self.keep, self.rec, self.sta, self.out)
        self.ended = lk.END_NAMES[int(self.out[0])]
        if n == 0:
            return [], []
        self._unpack(n, x, v)
        cap = self.rec.shape[0]
        idx = range(n) if self.keep else [n - 1]
        return self._records(idx, cap, step0, cstep0, stance)

    def _records(self, idx, cap: int, step0: int, cstep0: int, stance: int):
        """The rows as ``StepRecord`` / ``ControllerStatusData``, field for field what the objects build.
        Built column-wise, then each instance's ``__dict__`` filled at once (the frozen dataclasses'
        ``__init__`` costs ~4 us per object, as much as a compiled period); every field is set here, and
        the tests compare every field (``dataclasses.fields``) with the objects' records."""
        rec, sta = self.rec, self.sta
        impacts = self.sim.impact_count
        mode = self.ctrl.cfg.mode
        status, msg = ((NO_ADAPTATION, "mode none: classical computed torque") if not self.ctrl.adapted
                       else (UNCONSTRAINED, "x* feasible"))
        sel = [k % cap for k in idx]
        rows = rec[sel]
        srows = sta[sel]
        col = lambda a, i: a[:, i].tolist()   # noqa: E731  exact Python floats of a column
        T, TE, PF, IMP = col(rows, lk.REC_T), col(rows, lk.REC_TEND), col(rows, lk.REC_PF), col(rows, lk.REC_IMP)
        COP = (rows[:, lk.REC_W + 2] / rows[:, lk.REC_W + 1]).tolist()
        X, V = rows[:, lk.REC_X:lk.REC_X + 9], rows[:, lk.REC_V:lk.REC_V + 9]
        BASE, BASED = X[:, :3].copy(), V[:, :3].copy()
        Q, QD = rows[:, lk.REC_Q:lk.REC_Q + 6], rows[:, lk.REC_QD:lk.REC_QD + 6]
        TQ, W = rows[:, lk.REC_TORQUE:lk.REC_TORQUE + 6], rows[:, lk.REC_W:lk.REC_W + 3]
        P, PD, TA, TAD = (col(srows, c) for c in (lk.STA_P, lk.STA_PDOT, lk.STA_TAU, lk.STA_TAUDOT))
        PDD, TDD, PDDS, TDDS = (col(srows, c) for c in (lk.STA_PDD, lk.STA_TDD, lk.STA_PDDS, lk.STA_TDDS))
        TIGHT = [int(v) for v in col(srows, lk.STA_TIGHT)]
        ZMP, ERR, F = col(srows, lk.STA_ZMP), col(srows, lk.STA_MAXERR), col(srows, lk.STA_F)
        MG, R = srows[:, lk.STA_MARGINS:lk.STA_MARGINS + 17], srows[:, lk.STA_R:lk.STA_R + 2]
        new = object.__new__
        records, statuses = [], []
        for j, k in enumerate(idx):
            r = new(StepRecord)
            r.__dict__.update(
                step=step0 + k, t=T[j], stance=stance, q=Q[j], qd=QD[j], base=BASE[j], base_dot=BASED[j], x=X[j],
                v=V[j], torque=TQ[j], wrench=W[j], cop=COP[j], push_force=PF[j], impacts=impacts, fallen=False,
                fall_cause="", fall_detail="", t_end=TE[j], push_impulse=IMP[j])
            records.append(r)
            c = new(ControllerStatusData)
            c.__dict__.update(
                step=cstep0 + k, t=T[j], mode=mode, p=P[j], p_dot=PD[j], tau=TA[j], tau_dot=TAD[j], p_ddot=PDD[j],
                tau_ddot=TDD[j], p_ddot_star=PDDS[j], tau_ddot_star=TDDS[j], qp_status=status, qp_message=msg,
                margins=MG[j], tightest=TIGHT[j], zmp=ZMP[j], stance=stance, max_tracking_error=ERR[j],
                predicted_reaction=R[j], force_estimate=F[j])
            statuses.append(c)
        return records, statuses
