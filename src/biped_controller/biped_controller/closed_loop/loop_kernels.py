"""Compiled closed loop (numba): many control periods of controller + simulator in one call.

Pure numerics, no ROS, no side effects on import (load it with ``segment.load_loop_kernels``). The
in-process runner (``runner.run``) hands a *segment* of periods to :func:`run_segment` while nothing in
them needs Python: each period is exactly what the objects do one call at a time, in the same order and
with the same kernels --

  1. the sensors: paper (q, q') of the stance from the floating state (``paper_from_urdf``);
  2. the controller: ``controller_kernels.period_start`` (the parameter advance and the observer's mode, the one
     home of both) and ``controller_kernels.period_step``; a period that needs the QP ends the segment before it
     (its rows handed back), and the next call takes it with the caller's decision
     (``controller_kernels.period_outputs``, the controller's ``finish`` without the commit of step 5);
  3. the torque: clipped to the limits, mapped to the URDF joints of the stance;
  4. the simulator: the period's intervals (RK4 substeps, split at push starts and ends, as
     ``Simulator.step``) and ``planar_kernels.period`` (an event -- touchdown candidate, failed wrench
     check, sinking foot, singular state -- ends the segment before the period);
  5. the period is recorded (row k of ``rec`` and ``sta``) and both states are committed
     (``controller_kernels.period_commit`` for the controller).

A segment also ends after the period whose end reaches ``t_stop`` and when the record arrays are full
(``ring`` False) or after ``max_periods``. Whatever ended it, the state arrays passed in hold the state
after the last committed period: they are the objects' own arrays (the controller's ``memory``, the
simulator's ``sim_state``), so the objects go on from there (the QP, the impact, the fall) for the next
period. Records are bit-identical to the objects' (tested).

Arrays (float64, C order; fields declared once): ``gains``, ``cons``, ``mem`` (``controller_layout`` GAINS,
CONS, MEMORY), ``sst`` and ``slim`` (``biped_sim.plant.rigid_layout`` SIM_STATE, SIM_LIMITS),
pushes (n, 4): start, end, force, height of every scheduled push, perm (2, 6, 6): PAPER_FROM_URDF of each
stance, rec (cap, REC.size): the simulator's StepRecord of a period (``REC`` below), sta (cap, RES.size):
the controller's ``RES`` row of a period (its status).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_model import numba_cache
from biped_model import planar_kernels as pk
from biped_model.layout import Layout
from biped_sim.plant import period_grid_kernels as pg
from biped_sim.plant.rigid_layout import L_, S_
from biped_controller.core.control import controller_kernels as ck
from biped_controller.core.control import wbc_kernels as wk
from biped_controller.core.control.controller_layout import R_, RES, W_, WB_, WORK, WBC_MODE_OFF, WBC_MODE_WBC
from biped_controller.closed_loop import sensing_step_kernels as sp

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

# record columns: the simulator's StepRecord of the period
REC = Layout("rec", [("t", 1), ("t_end", 1), ("x", 9), ("v", 9), ("q", 6), ("qd", 6), ("torque", 6), ("wrench", 3),
                     ("push_force", 1), ("push_impulse", 1)])
REC_ = REC.at
WORK_ROWS = WORK.size
RES_SIZE = RES.size
# why a segment ended
(END_LIMIT, END_FULL, END_QP, END_SIM_EVENT, END_NONFINITE, END_PUSHES, END_MAX, END_SENSE, END_NOISE) = range(9)
END_NAMES = ("t_stop reached", "record arrays full", "QP needed", "simulator event", "non-finite controller value",
             "two pushes in one interval", "max_periods", "sensing needs Python (a sensed touchdown, a singular "
             "matrix)", "noise rows used up")
# the sensing pipeline's fields of RES (``pipeline_kernels.into_res``'s 8 values)
_SENS_RES0 = R_.sens_dR

_V, _VI, _M, _C4, _I, _F = ck.T_VEC, ck.T_IVEC, ck.T_MAT, ck.T_ARR4, ck.T_INT, ck.T_FLOAT
_C3 = numba.types.Array(numba.types.float64, 3, "C")
_B = numba.types.boolean


@numba.njit(cache=True)
def _knots(t_start, dt_nom, substeps, pushes, knots):
    """The period's grid end and its integration knots (``period_grid_kernels``, the compiled twin of
    ``biped_sim.plant.period_grid``) with the rigid plant's substep count ceil(substeps dt / dt_nom), the push
    starts and ends of ``pushes`` (rows: start, end, ...) as cuts, into ``knots``; returns (count of knots,
    the grid end), count -1 when ``knots`` is too short (tested equal to the Python home)."""
    t_grid_end = pg.grid_end(t_start, dt_nom)
    dt = t_grid_end - t_start
    n_sub = max(1, int(math.ceil(substeps * dt / dt_nom - 1e-9)))
    return pg.knots(t_start, t_grid_end, n_sub, pushes, knots), t_grid_end


@numba.njit(numba.types.int64(
    _C4, _V, _V, _VI, _V, _V, _V, _V,                           # controller: family, tree, gains, cons, mem
    _VI, _V, _V, _V, _M, _C3,                                   # simulator: tree, sst, slim, pushes, perm
    _F, _I, _B, _M, _M, _V,                                     # t_stop, max_periods, ring, rec, sta, out
    _V,                                                         # wbc: the whole-body stage's constants
    _M, _V, _V, _M, _V, _B,                                     # QP: G, h, res, work, x, x given for the 1st period
    _B, _VI, _V, _V, _V, _V, _V, _V, _M, _V), cache=True)       # sensing: on, tree, conf, state, backup, estimate, noise
def run_segment(coef, inner, centers, cti, ctf, gains, cons, mem,
                sti, stf, sst, slim, pushes, perm,
                t_stop, max_periods, ring, rec, sta, out, wbc,
                G, h, res, work, qp_x, qp_given,
                sensing, s_ti, s_tf, sconf, sstate, sback, qe, qde, noise, nconf):
    """Run periods while nothing needs Python (module docstring). Returns the number of periods done;
    out[0] = why the segment ended (END_*). A period that needs the QP ends the segment with its rows in
    ``G`` (QP_ROWS, 2; modes lambda and all: TORSO_QP_ROWS, 3), ``h``, its ``res`` row (x*, the parameters) and ``work`` (WORK rows); the caller
    solves it and calls again, those arrays untouched, with the decision in ``qp_x`` and ``qp_given`` True:
    the first period (the same one: the state has not moved) then takes x = qp_x
    (``controller_kernels.period_outputs``, as the controller's ``finish`` does) and the segment goes on.

    ``sensing`` True (real sensing, no delay; ``segment.Segment``): step 1 is the plant's sensors and the
    controller's sensing pipeline -- the sample q_s = q + noise_q z_q quantised to the encoder step
    (step round(q_s / step), half to even), q_s' = q' + noise_q' z_q', the IMU's pitch x[2] + noise_pitch z_p and
    rate v[2] + noise_pitch_rate z_r (row k of ``noise``: the k-th period's standard normal draws, as
    ``SensorModel.sample`` takes them; ``nconf`` the noise's sizes, ``sensor_kernels.NZ_*``;
    ``sensor_kernels.sample``), then ``pipeline_kernels.sense`` on
    (``s_ti``, ``s_tf``, ``sconf``, ``sstate``) into the estimate (``qe``, ``qde``) and ``into_res`` into
    the period's RES row -- as ``pipeline_compiled.CompiledSensing.sense`` and ``CompiledPeriod.compute``;
    the controller then acts on the estimate, the record keeps the true (q, q'), and the committed period
    records the torque sent in the pipeline's state (``CompiledSensing.record``). A period handed back for
    any reason leaves the pipeline's state as it was before it (``sback``: its copy) and uses no noise row,
    so that whoever takes that period (the next call, or the objects) samples and senses it from the same
    state with the same draws; END_SENSE when the pipeline needs Python (a sensed touchdown with the
    estimator: the impact map), END_NOISE when ``noise`` has no row left. The period count is the count of
    noise rows used."""
    cap = rec.shape[0]
    q = np.empty(6)
    qd = np.empty(6)
    applied = np.empty(6)
    tj = np.empty(6)
    knots = np.empty(64)
    lim = np.empty(pk.PERIOD_LIMITS_SIZE)
    xo = np.empty(9)
    vo = np.empty(9)
    w0 = np.empty(3)
    pout = np.empty(pk.PERIOD_OUT_SIZE)
    qs = np.empty(6)
    qds = np.empty(6)
    sens = np.empty(8)
    Gw = np.empty((wk.WBC_ROWS, 6))
    hw = np.empty(wk.WBC_ROWS)
    wmode = wbc[WB_.mode]
    x = sst[S_.x:S_.x + 9]
    v = sst[S_.v:S_.v + 9]
    anchor = sst[S_.anchor:S_.anchor + 3].copy()
    n_done = 0
    out[0] = END_MAX
    while n_done < max_periods:
        if not ring and n_done >= cap:
            out[0] = END_FULL
            return n_done
        t = sst[S_.t]
        stance = int(sst[S_.stance])
        P = perm[stance]
        # 1. sensors
        for i in range(6):
            sq = 0.0
            sv = 0.0
            for j in range(6):
                sq += P[i, j] * x[3 + j]
                sv += P[i, j] * v[3 + j]
            q[i] = sq
            qd[i] = sv
        qc = q
        qdc = qd
        if sensing:         # 1b. the plant's sensors and the controller's sensing pipeline (docstring)
            if n_done >= noise.shape[0]:
                out[0] = END_NOISE
                return n_done
            if not sp.sense_period(q, qd, x[2], v[2], noise[n_done], nconf, qs, qds, sens, sback, s_ti, s_tf, sconf,
                                   sstate, t, stance, qe, qde, res, _SENS_RES0):
                out[0] = END_SENSE
                return n_done
            qc = qe
            qdc = qde
        # 2. controller: the period's start and step (advance, observer mode; the memory is committed with the
        # period), or the QP period handed back by the last call takes its decision (ck.loop_period)
        code = ck.loop_period(qp_given and n_done == 0, qp_x, coef, inner, centers, cti, ctf, qc, qdc, t, stance,
                              gains, cons, mem, G, h, work, res)
        if code == ck.NEEDS_QP:
            if sensing:
                sstate[:] = sback
            out[0] = END_QP
            return n_done
        if code != ck.FEASIBLE:
            if sensing:
                sstate[:] = sback
            out[0] = END_NONFINITE
            return n_done
        # 2b. modes wbc, hybrid: the whole-body stage (hybrid: not run, the p/tau answer x* holds its rows)
        if wmode != WBC_MODE_OFF:
            wcode = wk.run_stage(wbc, cons, mem, work, res, Gw, hw, wmode == WBC_MODE_WBC, False)
            if wcode == wk.NEEDS_PIQP:
                if sensing:
                    sstate[:] = sback
                out[0] = END_QP
                return n_done
            if wcode == wk.NONFINITE:
                if sensing:
                    sstate[:] = sback
                out[0] = END_NONFINITE
                return n_done
        # 3. torque: clipped, to the URDF joints
        for i in range(6):
            applied[i] = min(max(work[W_.torque, i], slim[L_.torque_min + i]), slim[L_.torque_max + i])
        for j in range(6):
            s = 0.0
            for i in range(6):
                s += P[i, j] * applied[i]
            tj[j] = s
        # 4. simulator period
        nk, t_end = _knots(t, slim[L_.dt], slim[L_.substeps], pushes, knots)
        if nk < 0:
            if sensing:
                sstate[:] = sback
            out[0] = END_PUSHES
            return n_done
        ni = nk - 1
        forces = np.zeros(ni)
        heights = np.full(ni, np.nan)
        for i in range(ni):
            tm = 0.5 * (knots[i] + knots[i + 1])
            for k in range(pushes.shape[0]):
                if pushes[k, 0] <= tm < pushes[k, 1]:
                    if not math.isnan(heights[i]):
                        if sensing:
                            sstate[:] = sback
                        out[0] = END_PUSHES
                        return n_done
                    forces[i] = pushes[k, 2]
                    heights[i] = pushes[k, 3]
        lim[0] = slim[L_.mu]
        lim[1] = slim[L_.l_min]
        lim[2] = slim[L_.l_max]
        lim[3] = slim[L_.touchdown_tolerance]
        lim[4] = slim[L_.clearance]
        lim[5] = slim[L_.liftoff_penetration]
        lim[6] = sst[S_.cleared]
        st = pk.period(sti, stf, x, v, tj, knots[:nk].copy(), forces, heights, stance, anchor, lim, xo, vo, w0, pout)
        if st != pk.PERIOD_DONE:
            if sensing:
                sstate[:] = sback
            out[0] = END_SIM_EVENT
            return n_done
        # 5. record and commit
        row = n_done % cap
        r = rec[row]
        r[REC_.t] = t
        r[REC_.t_end] = t_end
        for k in range(9):
            r[REC_.x + k] = x[k]
            r[REC_.v + k] = v[k]
        for i in range(6):
            r[REC_.q + i] = q[i]
            r[REC_.qd + i] = qd[i]
            r[REC_.torque + i] = applied[i]
        for k in range(3):
            r[REC_.wrench + k] = w0[k]
        r[REC_.push_force] = forces[0] if not math.isnan(heights[0]) else 0.0
        r[REC_.push_impulse] = pout[2]
        sta[row, :] = res
        ck.period_commit(mem, res, work, qdc, t, stance)
        if sensing:         # the decision, in the pipeline (CompiledSensing.record: the torque sent, told stance)
            sp.record_decision(sstate, t, work, stance)
        x[:] = xo
        v[:] = vo
        sst[S_.t] = t_end
        sst[S_.step] += 1.0
        sst[S_.cleared] = pout[1]
        n_done += 1
        if t_end >= t_stop:
            out[0] = END_LIMIT
            return n_done
    return n_done
