"""Hand the in-process closed loop's quiet periods to the compiled loop (``loop_kernels.run_segment``).

Pure Python + NumPy, no ROS. A :class:`Segment` binds one :class:`rigid.Simulator` and one
:class:`controller.AdaptiveController` (both on the fast engine; the simulator's sensors ideal, or real
sensing without a delay on the controller's compiled sensing pipeline, ``Segment.sensing_eligible``): each
:meth:`Segment.run` hands the objects' own state arrays (the controller's ``memory``, the simulator's
``sim_state``; nothing is packed or unpacked) to the kernel, which runs periods until one needs Python
(the QP, an impact, a fall, ...) and leaves both arrays at the state after the last period it committed;
it returns the periods' ``StepRecord`` and ``ControllerStatusData``, identical to what ``ctrl.compute`` +
``sim.step`` return one period at a time. The objects then take the next period themselves.

:class:`MujocoSegment` is the same for the MuJoCo plant (``mujoco_loop_kernels.run_mujoco_segment``): the
controller's arrays and the plant's (``MujocoPlant.compiled_plant()``: MuJoCo's ``mjData`` and the plant's
bookkeeping arrays, its public description of what a compiled loop needs) go to the kernel; a period that
ends in a touchdown or a fall is run there and finished by the plant's Python. Real sensing without a delay
runs in both loops (the plant's sensors' sample, ``biped_sim.plant.sensor_kernels``, and the controller's
compiled sensing pipeline).
"""
from __future__ import annotations

import numpy as np

from biped_model import numba_cache
from biped_model.floating import PAPER_FROM_URDF
from biped_sim.plant.records import StepRecord
from biped_sim.plant.rigid import Simulator

from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.control.controller_compiled import (CONTROLLER_KERNELS, CONTROLLER_KERNELS_SOURCES,
                                                               WBC_KERNELS, WBC_KERNELS_SOURCES)
from biped_controller.core.control.status import (MSG_FIXED_REFERENCE, MSG_X_STAR_FEASIBLE, NO_ADAPTATION,
                                                  ControllerStatusData, status_records)
from biped_controller.core.control.controller_layout import RES, WORK
from biped_controller.core.qp.problem import UNCONSTRAINED
from biped_controller.core.sensing.pipeline_compiled import (PIPELINE_KERNELS, PIPELINE_KERNELS_SOURCES,
                                                             CompiledSensing, load_pipeline_kernels)

_PERM = np.ascontiguousarray(np.array(PAPER_FROM_URDF, dtype=float))

LOOP_KERNELS = "biped_controller.closed_loop.loop_kernels"
# what the compiled loop is compiled against besides its own source
PERIOD_GRID_KERNELS = "biped_sim.plant.period_grid_kernels"
SENSOR_KERNELS = "biped_sim.plant.sensor_kernels"
# one period of real sensing, shared by both compiled loops, and what it is compiled against
SENSING_STEP_KERNELS = "biped_controller.closed_loop.sensing_step_kernels"
SENSING_STEP_SOURCES = (SENSOR_KERNELS, PIPELINE_KERNELS, "biped_controller.core.control.controller_layout") + \
    PIPELINE_KERNELS_SOURCES
LOOP_KERNELS_SOURCES = CONTROLLER_KERNELS_SOURCES + (CONTROLLER_KERNELS, WBC_KERNELS, PERIOD_GRID_KERNELS,
                                                     "biped_sim.plant.rigid_layout", SENSOR_KERNELS) + (
                                                     PIPELINE_KERNELS,) + PIPELINE_KERNELS_SOURCES + (
                                                     SENSING_STEP_KERNELS,)


def load_loop_kernels():
    """The compiled closed loop (``loop_kernels``) through ``numba_cache.load`` (cache kept with its
    dependencies: the planar kernels, the compiled period, the layouts)."""
    numba_cache.load(CONTROLLER_KERNELS, sources=CONTROLLER_KERNELS_SOURCES)
    numba_cache.load(WBC_KERNELS, sources=WBC_KERNELS_SOURCES)
    numba_cache.load(PERIOD_GRID_KERNELS)
    numba_cache.load(SENSOR_KERNELS)
    load_pipeline_kernels()
    numba_cache.load(SENSING_STEP_KERNELS, sources=SENSING_STEP_SOURCES)
    return numba_cache.load(LOOP_KERNELS, sources=LOOP_KERNELS_SOURCES)


_NO_NOISE = np.zeros((0, 14))


def _sensing_arguments(sim, ctrl: AdaptiveController) -> tuple[bool, tuple, np.ndarray]:
    """What a compiled loop's ``sensing`` arguments are for this pair: (on, the pipeline's arrays (tree ti, tf,
    conf, state, a backup of the state, the estimate q, q'), the noise's sizes). On with real sensing
    (``Segment.sensing_eligible``): the controller's compiled pipeline's own arrays, so the objects go on from
    the state the kernel leaves; off: placeholders the kernel does not read."""
    if not sim.sensor.identity:
        sp = ctrl._sensing
        return True, (sp.ti, sp.tf, sp.conf, sp.state, np.empty_like(sp.state), sp._q, sp._qd), sim.sensor.compiled_noise
    e = np.zeros(1)
    return False, (np.zeros(1, dtype=np.int64), e, e, e, e, e, e), np.zeros(5)


def _decision_buffers(fp):
    """The buffers of a QP period handed back by a compiled loop, shaped as the compiled period ``fp``'s:
    G and h (its rows), the RES row, the work rows and the decision x (p'', tau'' [, lambda''])."""
    return (np.zeros_like(fp.G), np.zeros_like(fp.h), np.zeros(RES.size), np.zeros((WORK.size, 6)),
            np.zeros(fp.nx))


class Segment:
    """The compiled loop for one (simulator, controller) pair. ``keep_records`` False: only the last
    period of each segment is returned (enough for a run's outcome, ~2x cheaper than building every
    record); ``capacity`` rows are recorded per call."""

    def __init__(self, sim: Simulator, ctrl: AdaptiveController, keep_records: bool = True, capacity: int = 8192):
        if not self.eligible(sim, ctrl):
            raise ValueError("Segment needs the fast engine on both sides and ideal sensors, or real sensing "
                             "without a delay on the compiled sensing pipeline")
        self.lk = load_loop_kernels()
        self.sim, self.ctrl, self.fp = sim, ctrl, ctrl.compiled_period
        self.keep = keep_records
        self.rec = np.empty((capacity, self.lk.REC.size))
        self.sta = np.empty((capacity, RES.size))
        self.out = np.zeros(1)
        self.ended = ""
        self.n = 0
        self._last = None
        # the QP period handed back (END_QP): its rows and RES row; the decision given with the next call
        # (modes lambda and all: the torso rows and the column of lambda'', as the compiled period's)
        self.G, self.h, self.res, self.work, self.qp_x = _decision_buffers(self.fp)
        # the compiled loop takes the QP periods too, with the controller's decision (not in modes whose
        # whole-body stage follows a QP: hybrid)
        self.takes_qp = ctrl.whole_body is None and bool(ctrl.adapted)
        self.sensing, self._sens, self.nconf = _sensing_arguments(sim, ctrl)

    @staticmethod
    def sensing_eligible(sim: Simulator, ctrl: AdaptiveController) -> bool:
        """Real sensing the compiled loop runs (``loop_kernels.run_segment``'s ``sensing``): the plant's sensor
        model without a delay (``SensorModel.compiled_noise``), the controller's compiled sensing pipeline
        without a delay compensation, its legs' model-error estimator (if on) in the kernel."""
        sp = getattr(ctrl, "_sensing", None)
        return bool(isinstance(sp, CompiledSensing) and sp.d == 0 and not sp._me_python
                    and ctrl._ref_log is None and sim.sensor.compiled_noise is not None)

    @staticmethod
    def eligible(sim: Simulator, ctrl: AdaptiveController) -> bool:
        # modes wbc, hybrid: the compiled whole-body stage runs in the loop (wbc_kernels); a period where it
        # needs PIQP, or where hybrid's p/tau QP runs, goes to the objects; the Python stage (the tests'
        # oracle, ``python_stage``) never runs in the loop
        # (modes lambda and all: the compiled period takes lambda, the QP periods are decided as the others')
        # real sensing without a delay: the compiled sensing pipeline runs in the loop (sensing_eligible)
        fp = getattr(ctrl, "compiled_period", None)
        if not (sim.compiled and fp is not None and not fp.python_stage):
            return False
        if sim.sensor.identity and not ctrl.cfg.real_sensing:
            return True
        return Segment.sensing_eligible(sim, ctrl)

    def run(self, t_stop: float, max_periods: int = 1 << 40, decision: tuple | None = None, build: bool = True
            ) -> tuple[list[StepRecord], list[ControllerStatusData]]:
        """Periods until one needs Python, ``t_stop`` [s] is reached (the period reaching it included) or
        ``max_periods``; returns their records and statuses (all, or the last one, see ``keep_records``;
        ``self.n`` the periods done). ``decision``: :meth:`decide`'s answer for the QP period the last call
        handed back, which this call then takes first. ``build`` False (``keep_records`` False only): nothing
        is built, :meth:`last` builds the last period's record when it is wanted (a run's last period)."""
        sim, ctrl, fp, lk = self.sim, self.ctrl, self.fp, self.lk
        pushes = sim.push_rows()        # (start, end, force, height) of each push (the plant's, ScheduledPushes)
        step0, cstep0, stance = sim.step_index, ctrl.step_index, sim.stance
        if decision is not None:
            self.qp_x[:] = decision[0]
        # the noise of the periods to come (1024 at most: a segment needing more ends there, END_NOISE)
        noise = sim.sensor.noise_rows(min(int(max_periods), 1024)) if self.sensing else _NO_NOISE
        self.n = n = lk.run_segment(fp.coef, fp.inner, fp.centers, fp.ti, fp.tf, ctrl.gains, ctrl.cons, ctrl.memory,
                           sim.fm.ti, sim.fm.tf, sim.sim_state, sim.limits, pushes, _PERM,
                           float(t_stop), int(max_periods), not self.keep, self.rec, self.sta, self.out, ctrl.wbc,
                           self.G, self.h, self.res, self.work, self.qp_x, decision is not None,
                           self.sensing, *self._sens, noise, self.nconf)
        if self.sensing and n > 0:
            sim.sensor.taken(n, step0 + n - 1, stance)
        self.ended = lk.END_NAMES[int(self.out[0])]
        if n == 0:
            return [], []
        first = decision[1:3] if decision is not None else None
        if not self.keep and not build:
            self._last = (n - 1, step0, cstep0, stance, first)
            return [], []
        self._last = None
        cap = self.rec.shape[0]
        idx = range(n) if self.keep else [n - 1]
        return self._records(idx, cap, step0, cstep0, stance, first)

    def last(self) -> tuple[list[StepRecord], list[ControllerStatusData]]:
        """The record and status of the last period of the last call made with ``build`` False (``keep_records``
        False), built now; ([], []) when that call built them or ran no period."""
        if self._last is None:
            return [], []
        k, step0, cstep0, stance, first = self._last
        self._last = None
        return self._records([k], self.rec.shape[0], step0, cstep0, stance, first)

    @property
    def needs_qp(self) -> bool:
        """The last call ended at a period that needs the QP (its rows in ``G``, ``h``, ``res``)."""
        return int(self.out[0]) == self.lk.END_QP

    def decide(self) -> tuple | None:
        """The controller's decision for the QP period the last call handed back (``CompiledPeriod.solve_qp``:
        the controller's own solver, as its compiled period decides): (x, status, message, ...), or None
        where the compiled loop does not take it (hybrid's whole-body stage, a non-finite answer): the objects
        take that period."""
        if not (self.takes_qp and self.needs_qp):
            return None
        return self.fp.solve_qp(self.G, self.h, self.res)

    def _records(self, idx, cap: int, step0: int, cstep0: int, stance: int, first: tuple | None = None):
        """The rows as ``StepRecord`` / ``ControllerStatusData``, field for field what the objects build.
        Built column-wise, then each record's ``__dict__`` filled at once (the frozen dataclasses'
        ``__init__`` costs ~4 us per object, as much as a compiled period); every field is set here, and
        the tests compare every field (``dataclasses.fields``) with the objects' records. The statuses come
        from the controller's one builder (``status_records``)."""
        R = self.lk.REC.at
        impacts = self.sim.impact_count
        status, msg = ((NO_ADAPTATION, MSG_FIXED_REFERENCE[self.ctrl.cfg.mode]) if not self.ctrl.adapted
                       else (UNCONSTRAINED, MSG_X_STAR_FEASIBLE))
        sel = [k % cap for k in idx]
        rows = self.rec[sel]
        col = lambda a, i: a[:, i].tolist()   # noqa: E731  exact Python floats of a column
        T, TE, PF, IMP = col(rows, R.t), col(rows, R.t_end), col(rows, R.push_force), col(rows, R.push_impulse)
        COP = (rows[:, R.wrench + 2] / rows[:, R.wrench + 1]).tolist()
        X, V = rows[:, R.x:R.x + 9], rows[:, R.v:R.v + 9]
        BASE, BASED = X[:, :3].copy(), V[:, :3].copy()
        Q, QD = rows[:, R.q:R.q + 6], rows[:, R.qd:R.qd + 6]
        TQ, W = rows[:, R.torque:R.torque + 6], rows[:, R.wrench:R.wrench + 3]
        new = object.__new__
        records = []
        for j, k in enumerate(idx):
            r = new(StepRecord)
            r.__dict__.update(
                step=step0 + k, t=T[j], stance=stance, q=Q[j], qd=QD[j], base=BASE[j], base_dot=BASED[j], x=X[j],
                v=V[j], torque=TQ[j], wrench=W[j], cop=COP[j], push_force=PF[j], impacts=impacts, fallen=False,
                fall_cause="", fall_detail="", t_end=TE[j], push_impulse=IMP[j])
            records.append(r)
        statuses = status_records(self.sta[sel], [cstep0 + k for k in idx], T, self.ctrl.cfg.mode, stance,
                                  status, msg)
        if first is not None and idx[0] == 0:       # the first period took the QP's decision: its status
            statuses[0] = status_records(self.sta[sel[:1]], [cstep0], T[:1], self.ctrl.cfg.mode, stance,
                                         int(first[0]), first[1])[0]
        return records, statuses


MUJOCO_LOOP_KERNELS = "biped_controller.closed_loop.mujoco_loop_kernels"
MUJOCO_LOOP_KERNELS_SOURCES = CONTROLLER_KERNELS_SOURCES + (CONTROLLER_KERNELS, WBC_KERNELS, PERIOD_GRID_KERNELS,
                                                            "biped_sim.plant.mujoco_kernels", SENSOR_KERNELS) + (
                                                            PIPELINE_KERNELS,) + PIPELINE_KERNELS_SOURCES + (
                                                            SENSING_STEP_KERNELS,)


def load_mujoco_loop_kernels():
    """The compiled closed loop on the MuJoCo plant (``mujoco_loop_kernels``) through ``numba_cache.load``,
    after the plant's kernels (``biped_sim.plant.mujoco.load_kernels``: MuJoCo's library loaded for numba) and
    the controller's."""
    from biped_sim.plant.mujoco import load_kernels as load_mujoco_kernels

    load_mujoco_kernels()
    numba_cache.load(CONTROLLER_KERNELS, sources=CONTROLLER_KERNELS_SOURCES)
    numba_cache.load(WBC_KERNELS, sources=WBC_KERNELS_SOURCES)
    numba_cache.load(PERIOD_GRID_KERNELS)
    numba_cache.load(SENSOR_KERNELS)
    load_pipeline_kernels()
    numba_cache.load(SENSING_STEP_KERNELS, sources=SENSING_STEP_SOURCES)
    return numba_cache.load(MUJOCO_LOOP_KERNELS, sources=MUJOCO_LOOP_KERNELS_SOURCES)


class MujocoSegment:
    """The compiled loop (``mujoco_loop_kernels.run_mujoco_segment``) for one (MuJoCo plant, controller) pair,
    with :class:`Segment`'s interface (``run``, ``last``, ``decide``, ``needs_qp``, ``n``, ``ended``). A period
    whose MuJoCo steps end in a touchdown, a possible fall or a numerical problem is finished by the plant's
    Python (``MujocoPlant.finish_compiled_period``) inside :meth:`run` and ends the call; it is counted in
    ``n`` and its record and status are returned with the others. Real sensing without a delay
    (``Segment.sensing_eligible``) runs in the loop as on the rigid plant (``mujoco_loop_kernels``' ``sensing``)."""

    def __init__(self, sim, ctrl: AdaptiveController, keep_records: bool = True, capacity: int = 8192):
        if not self.eligible(sim, ctrl):
            raise ValueError("MujocoSegment needs the compiled period, ideal sensors or real sensing without a "
                             "delay on the compiled sensing pipeline, and the plant's compiled steps")
        self.mk = load_mujoco_loop_kernels()
        self.plant = sim.compiled_plant()       # the plant's arrays the compiled steps take (biped_sim's CompiledPlant)
        self.pk = self.plant.kernels
        self.sim, self.ctrl, self.fp = sim, ctrl, ctrl.compiled_period
        self.keep = keep_records
        self.rec = np.empty((capacity, self.mk.REC_SIZE))
        self.sta = np.empty((capacity, RES.size))
        self.out = np.zeros(self.mk.OUT_SIZE)
        self.clock = np.zeros(2)
        self.ended = ""
        self.n = 0
        self._last = None
        self.G, self.h, self.res, self.work, self.qp_x = _decision_buffers(self.fp)
        self.takes_qp = ctrl.whole_body is None and bool(ctrl.adapted)
        self.sensing, self._sens, self.nconf = _sensing_arguments(sim, ctrl)

    @staticmethod
    def eligible(sim, ctrl: AdaptiveController) -> bool:
        """The compiled period on the controller's side (no Python whole-body stage), ideal sensors and no
        real sensing, or real sensing without a delay on the compiled sensing pipeline
        (``Segment.sensing_eligible``), held torques on the plant's compiled steps (no probe, no trace)."""
        fp = getattr(ctrl, "compiled_period", None)
        if not (getattr(sim, "name", "") == "mujoco" and getattr(sim, "compiled_steps", False)
                and fp is not None and not fp.python_stage and sim.probe is None and sim.trace is None):
            return False
        if sim.sensor.identity and not ctrl.cfg.real_sensing:
            return True
        return Segment.sensing_eligible(sim, ctrl)

    @property
    def needs_qp(self) -> bool:
        """The last call ended at a period that needs the QP (its rows in ``G``, ``h``, ``res``)."""
        return int(self.out[self.mk.O_END]) == self.mk.END_QP

    def decide(self) -> tuple | None:
        """As :meth:`Segment.decide`: the controller's decision for the QP period handed back, or None."""
        if not (self.takes_qp and self.needs_qp):
            return None
        return self.fp.solve_qp(self.G, self.h, self.res)

    def run(self, t_stop: float, max_periods: int = 1 << 40, decision: tuple | None = None, build: bool = True
            ) -> tuple[list[StepRecord], list[ControllerStatusData]]:
        """As :meth:`Segment.run`, on the MuJoCo plant (class docstring)."""
        sim, ctrl, fp, mk = self.sim, self.ctrl, self.fp, self.mk
        if sim.fall is not None:
            raise RuntimeError("the robot has fallen; reset() the plant")
        if decision is not None:
            self.qp_x[:] = decision[0]
        step0, cstep0, stance, impacts = sim.step_index, ctrl.step_index, sim.stance, sim.impact_count
        clock, out = self.clock, self.out
        clock[0], clock[1] = sim.t, sim.step_index
        d = sim.data
        plant = self.plant
        # the noise of the periods to come (1024 at most: a segment needing more ends there, END_NOISE)
        noise = sim.sensor.noise_rows(min(int(max_periods), 1024)) if self.sensing else _NO_NOISE
        n = mk.run_mujoco_segment(fp.coef, fp.inner, fp.centers, fp.ti, fp.tf, ctrl.gains, ctrl.cons, ctrl.memory,
                                  *plant.step_arguments(), _PERM, sim.push_rows(), plant.torso_com,
                                  plant.mujoco_step, sim.cfg.control_period, clock, float(t_stop),
                                  int(max_periods), not self.keep, self.rec, self.sta, out, ctrl.wbc, self.G, self.h,
                                  self.res, self.work, self.qp_x, decision is not None,
                                  self.sensing, *self._sens, noise, self.nconf)
        end = int(out[mk.O_END])
        # the noise rows used: the periods committed, and a period ending in a plant event (committed on the
        # controller's side, finished below)
        used = n + (end == mk.END_PLANT_EVENT)
        if self.sensing and used > 0:
            sim.sensor.taken(used, step0 + used - 1, stance)
        self.ended = mk.END_NAMES[end]
        if n > 0:
            sim.t, sim.step_index = float(clock[0]), int(clock[1])
            sim.x, sim.v = d.qpos.copy(), d.qvel.copy()
        event = None
        if end == mk.END_PLANT_EVENT:
            k = int(out[mk.O_ROW])
            nk = int(out[mk.O_NK])
            knots = out[mk.O_KNOTS:mk.O_KNOTS + nk].tolist()
            row = self.rec[k, :self.pk.ROW_SIZE].copy()
            event = sim.finish_compiled_period(int(out[mk.O_CODE]), int(out[mk.O_DONE]), knots,
                                               float(out[mk.O_T_START]), float(out[mk.O_T_GRID_END]),
                                               float(out[mk.O_IMPULSE]), row, float(self.rec[k, mk.C_PUSH_FORCE]))
        self.n = n + (event is not None)
        if self.n == 0:
            return [], []
        first = decision[1:3] if decision is not None else None
        info = (n, step0, cstep0, stance, impacts, first, event)
        if not self.keep and not build:
            self._last = info
            return [], []
        self._last = None
        return self._records(info, self.keep)

    def last(self) -> tuple[list[StepRecord], list[ControllerStatusData]]:
        """As :meth:`Segment.last`."""
        if self._last is None:
            return [], []
        info, self._last = self._last, None
        return self._records(info, False)

    def _records(self, info: tuple, every: bool):
        """The periods' ``StepRecord`` (the plant's fields from the rows, as ``MujocoPlant.step`` builds them;
        the handed-back period's from the plant) and ``ControllerStatusData`` (``status_records``); all of them
        (``every``) or the last one."""
        n, step0, cstep0, stance, impacts, first, event = info
        mk, pk = self.mk, self.pk
        cap = self.rec.shape[0]
        total = n + (event is not None)
        idx = list(range(total)) if every else [total - 1]
        sel = [j % cap for j in idx]
        records = []
        plain = [j for j in idx if j < n]
        if plain:
            rows = self.rec[[j % cap for j in plain]]
            T, TE = rows[:, mk.C_T].tolist(), rows[:, mk.C_T_END].tolist()
            PF, IMP, COP = rows[:, mk.C_PUSH_FORCE].tolist(), rows[:, mk.C_PUSH_IMPULSE].tolist(), rows[:, pk.R_COP].tolist()
            new = object.__new__
            for i, j in enumerate(plain):
                r = rows[i]
                rec = new(StepRecord)
                rec.__dict__.update(
                    step=step0 + j, t=T[i], stance=stance, q=r[pk.R_Q:pk.R_Q + 6], qd=r[pk.R_QD:pk.R_QD + 6],
                    base=r[pk.R_BASE:pk.R_BASE + 3], base_dot=r[pk.R_BASE_DOT:pk.R_BASE_DOT + 3],
                    x=r[pk.R_X:pk.R_X + 9], v=r[pk.R_V:pk.R_V + 9], torque=r[pk.R_TORQUE:pk.R_TORQUE + 6],
                    wrench=r[pk.R_WRENCH:pk.R_WRENCH + 3], cop=COP[i], push_force=PF[i], impacts=impacts,
                    fallen=False, fall_cause="", fall_detail="", t_end=TE[i], push_impulse=IMP[i])
                records.append(rec)
        if event is not None and idx[-1] == n:
            records.append(event)
        status, msg = ((NO_ADAPTATION, MSG_FIXED_REFERENCE[self.ctrl.cfg.mode]) if not self.ctrl.adapted
                       else (UNCONSTRAINED, MSG_X_STAR_FEASIBLE))
        times = self.rec[sel, mk.C_T].tolist()
        statuses = status_records(self.sta[sel], [cstep0 + j for j in idx], times, self.ctrl.cfg.mode, stance,
                                  status, msg)
        if first is not None and idx[0] == 0:
            statuses[0] = status_records(self.sta[sel[:1]], [cstep0], times[:1], self.ctrl.cfg.mode, stance,
                                         int(first[0]), first[1])[0]
        return records, statuses
