"""Compiled closed loop on the MuJoCo plant (numba): many control periods of controller + MuJoCo in one call.

Pure numerics and MuJoCo's C API, no ROS, no side effects on import (load it with
``segment.load_mujoco_loop_kernels``, which loads the plant's kernels and MuJoCo's library first). The MuJoCo
twin of ``loop_kernels.run_segment``: the in-process runner (``runner.run``) hands a *segment* of periods to
:func:`run_mujoco_segment`, each period exactly what the objects do one call at a time (the controller's
``compute`` and ``MujocoPlant.step`` with held torques), in the same order and with the same kernels --

  1. the sensors: ``MujocoPlant.observe`` with ideal sensors, ``mujoco_kernels.measure`` (q1 against the ground);
     with real sensing (``sensing``, no delay) then the plant's sensors' sample (``sensor_kernels.sample``) and the
     controller's compiled sensing pipeline (``pipeline_kernels.sense``), as ``loop_kernels.run_segment``'s
     step 1b;
  2. the controller: ``controller_kernels.period_start`` and ``period_step`` (a period that needs the QP ends
     the segment before it, its rows handed back; the next call takes it with the caller's decision,
     ``controller_kernels.period_outputs``) and, modes wbc and hybrid, the whole-body stage
     (``wbc_kernels.run_stage``), as ``loop_kernels.run_segment``;
  3. the plant: the period's grid end and integration knots (``biped_sim.plant.period_grid``: ``n_sub`` equal
     MuJoCo steps of at most ``mujoco_timestep``, split at push starts and ends), ``mujoco_kernels.begin_period``
     (the clipped torque to ``ctrl``), ``mujoco_kernels.substeps`` (the MuJoCo steps), then, for a period with
     no event, ``mujoco_kernels.end_period``;
  4. the controller's commit (``controller_kernels.period_commit``) and the period's record (row k of ``rec``:
     the plant's row, ``mujoco_kernels.R_*``, then t, t_end, the push force at t and the push impulse; row k of
     ``sta``: the controller's ``RES`` row).

A period whose MuJoCo steps end in a touchdown or a possible fall (``substeps`` returns ``TOUCHDOWN`` or
``MAYBE_FALL``), or whose end state is not finite or raised a MuJoCo warning (bad qacc, qpos, qvel), is run and
committed on the controller's side but not finished: the segment ends with ``END_PLANT_EVENT``, the period's row
(its state at the start, torque, sums so far) in ``rec``'s next row and in ``out`` what the plant's Python needs
to finish it (``MujocoPlant.finish_compiled_period``: the impact record, the fall's name, the numerical check). A segment
also ends after the period whose end reaches ``t_stop``, when the record arrays are full (``ring`` False) or
after ``max_periods``. The plant's time and period index are in ``clock`` (t, step), the rest of its state in
MuJoCo's ``mjData`` and the plant's arrays (``acc``, ``ip``, ``fp``), which the objects read afterwards.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_sim.plant import mujoco_kernels as mk
from biped_sim.plant import period_grid_kernels as pg
from biped_model import numba_cache
from biped_controller.core.control import controller_kernels as ck
from biped_controller.core.control import wbc_kernels as wk
from biped_controller.core.control.controller_layout import R_, W_, WB_, WBC_MODE_OFF, WBC_MODE_WBC
from biped_controller.closed_loop import sensing_step_kernels as sp

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

# record columns after the plant's row (mujoco_kernels.R_*)
C_T, C_T_END, C_PUSH_FORCE, C_PUSH_IMPULSE = mk.ROW_SIZE, mk.ROW_SIZE + 1, mk.ROW_SIZE + 2, mk.ROW_SIZE + 3
REC_SIZE = mk.ROW_SIZE + 4
# why a segment ended
(END_LIMIT, END_FULL, END_QP, END_PLANT_EVENT, END_NONFINITE, END_MAX, END_KNOTS, END_SENSE,
 END_NOISE) = range(9)
END_NAMES = ("t_stop reached", "record arrays full", "QP needed", "plant event", "non-finite controller value",
             "max_periods", "too many knots in a period", "sensing needs Python (a sensed touchdown, a singular "
             "matrix)", "noise rows used up")
# the sensing pipeline's fields of RES (``pipeline_kernels.into_res``'s 8 values)
_SENS_RES0 = R_.sens_dR
# out: why the segment ended, then for END_PLANT_EVENT: substeps' code, the intervals done, the knots' count, the
# period's start and grid end [s], the pushes' impulse so far [N s], the record row of the period; the knots
O_END, O_CODE, O_DONE, O_NK, O_T_START, O_T_GRID_END, O_IMPULSE, O_ROW = range(8)
O_KNOTS = 8
MAX_KNOTS = 64
OUT_SIZE = O_KNOTS + MAX_KNOTS
# clock: the plant's time [s] and period index
K_T, K_STEP = 0, 1


@numba.njit(cache=True, nogil=True)
def period_knots(t_start, dt_nom, h_mj, pushes, knots):
    """The period's grid end and its integration knots (``period_grid_kernels``, the compiled twin of
    ``biped_sim.plant.period_grid``) with the MuJoCo plant's step count max(1, ceil((t_end - t_start) / h_mj
    - 1e-9)), the push starts and ends of ``pushes`` strictly inside as cuts, into ``knots``: returns (count
    of knots, the grid end), count -1 when ``knots`` is too short (tested equal through the records)."""
    t_grid_end = pg.grid_end(t_start, dt_nom)
    n_sub = max(1, int(math.ceil((t_grid_end - t_start) / h_mj - 1e-9)))
    return pg.knots(t_start, t_grid_end, n_sub, pushes, knots), t_grid_end


_V, _VI, _M, _C4, _I, _F = ck.T_VEC, ck.T_IVEC, ck.T_MAT, ck.T_ARR4, ck.T_INT, ck.T_FLOAT
_C3 = numba.types.Array(numba.types.float64, 3, "C")
_B = numba.types.boolean
_WARN = numba.types.Array(numba.types.int32, 1, "A")     # MjData.warning.number: a strided view


@numba.njit(_I(_C4, _V, _V, _VI, _V, _V, _V, _V,                      # controller: family, tree, gains, cons, mem
               _I, _I, _V, _M, _M, _M, _V, _V, _M, _V, _V, _VI, _V,   # MuJoCo: model, data, timestep, arrays
               _WARN, _VI, _V, _V, _C3, _M, _F, _F, _F, _V,           # warnings, limits, perm, pushes, clock
               _F, _I, _B, _M, _M, _V, _V,                            # t_stop, max_periods, ring, rec, sta, out, wbc
               _M, _V, _V, _M, _V, _B,                                # QP: G, h, res, work, x, x given
               _B, _VI, _V, _V, _V, _V, _V, _V, _M, _V), cache=True, nogil=True)   # sensing (loop_kernels')
def run_mujoco_segment(coef, inner, centers, cti, ctf, gains, cons, mem,
                       model, data, timestep, cfrc, xpos, scom, qpos, qvel, xfrc, ctrl, acc, ip, fp, warn, bad_warn,
                       lo, hi, perm, pushes, torso_com, h_mj, dt_nom, clock,
                       t_stop, max_periods, ring, rec, sta, out, wbc,
                       G, h, res, work, qp_x, qp_given,
                       sensing, s_ti, s_tf, sconf, sstate, sback, qe, qde, noise, nconf):  # pragma: no cover (compiled)
    """Run periods while nothing needs Python (module docstring). Returns the number of periods committed on
    both sides; out[O_END] = why the segment ended (END_*). ``model``, ``data``: the ``mjModel*``, ``mjData*``
    addresses; ``timestep`` the view of ``opt.timestep``; ``warn`` MuJoCo's warning counters, ``bad_warn`` the
    indices that make a numerical fall; ``lo``, ``hi`` the torque limits (paper order); ``perm`` (2, 6, 6)
    PAPER_FROM_URDF per stance; ``pushes`` (n, 4) the scheduled pushes (start, end, force, height);
    ``h_mj`` the MuJoCo step, ``dt_nom`` the control period [s]. The QP hand-back is ``loop_kernels.run_segment``'s
    (``G``, ``h``, ``res``, ``work``; ``qp_x``, ``qp_given``).

    ``sensing`` True (real sensing, no delay; ``segment.MujocoSegment``): ``loop_kernels.run_segment``'s sensing
    on this plant -- the sample of the measured (q, q') and of the IMU's torso pitch qpos[2] and its rate
    qvel[2] with row k of ``noise`` (``sensor_kernels.sample``, ``nconf`` the noise's sizes), the pipeline
    (``s_ti``, ``s_tf``, ``sconf``, ``sstate``) into the estimate (``qe``, ``qde``) the controller acts on and
    into the period's RES row; the record keeps the measured (q, q'); the committed period records the torque
    sent in the pipeline's state. A period handed back before its commit (the QP, a non-finite value, the
    knots) leaves the pipeline's state as before it (``sback``) and uses no noise row; END_SENSE when the
    pipeline needs Python (a sensed touchdown with the estimator), END_NOISE when ``noise`` has no row left. A
    period ending in a plant event is committed on both sides (its noise row used): the rows used are the
    periods returned plus that one."""
    cap = rec.shape[0]
    q = np.empty(6)
    qd = np.empty(6)
    meas = np.empty(12)
    qs = np.empty(6)
    qds = np.empty(6)
    sens = np.empty(8)
    torque = np.empty(6)
    knots = out[O_KNOTS:O_KNOTS + MAX_KNOTS]
    sub_out = np.zeros(mk.OUT_SIZE)
    Gw = np.empty((wk.WBC_ROWS, 6))
    hw = np.empty(wk.WBC_ROWS)
    wmode = wbc[WB_.mode]
    n_push = pushes.shape[0]
    n_done = 0
    out[O_END] = END_MAX
    while n_done < max_periods:
        if not ring and n_done >= cap:
            out[O_END] = END_FULL
            return n_done
        t = clock[K_T]
        stance = ip[mk.I_STANCE]
        P = perm[stance]
        # 1. sensors (observe: ideal, q1 against the ground)
        mk.measure(qpos, qvel, P, 3 if stance == 0 else 6, meas)
        for i in range(6):
            q[i] = meas[i]
            qd[i] = meas[6 + i]
        qc = q
        qdc = qd
        if sensing:         # 1b. the plant's sensors and the controller's sensing pipeline (docstring)
            if n_done >= noise.shape[0]:
                out[O_END] = END_NOISE
                return n_done
            if not sp.sense_period(q, qd, qpos[2], qvel[2], noise[n_done], nconf, qs, qds, sens, sback, s_ti, s_tf, sconf,
                                   sstate, t, stance, qe, qde, res, _SENS_RES0):
                out[O_END] = END_SENSE
                return n_done
            qc = qe
            qdc = qde
        # 2. controller
        code = ck.loop_period(qp_given and n_done == 0, qp_x, coef, inner, centers, cti, ctf, qc, qdc, t, stance,
                              gains, cons, mem, G, h, work, res)
        if code == ck.NEEDS_QP:
            if sensing:
                sstate[:] = sback
            out[O_END] = END_QP
            return n_done
        if code != ck.FEASIBLE:
            if sensing:
                sstate[:] = sback
            out[O_END] = END_NONFINITE
            return n_done
        if wmode != WBC_MODE_OFF:
            wcode = wk.run_stage(wbc, cons, mem, work, res, Gw, hw, wmode == WBC_MODE_WBC, False)
            if wcode == wk.NEEDS_PIQP:
                if sensing:
                    sstate[:] = sback
                out[O_END] = END_QP
                return n_done
            if wcode == wk.NONFINITE:
                if sensing:
                    sstate[:] = sback
                out[O_END] = END_NONFINITE
                return n_done
        # 3. plant: knots, the period's start, the MuJoCo steps
        nk, t_grid_end = period_knots(t, dt_nom, h_mj, pushes, knots)
        if nk < 0:
            if sensing:
                sstate[:] = sback
            out[O_END] = END_KNOTS
            return n_done
        row_i = n_done % cap
        r = rec[row_i]
        row = r[:mk.ROW_SIZE]
        for i in range(6):
            torque[i] = work[W_.torque, i]
        mk.begin_period(torque, lo, hi, P, P, False, qpos, qvel, ctrl, acc, row)
        push_force = 0.0
        if n_push > 0:
            tm = 0.5 * (knots[0] + knots[1])
            for k in range(n_push):
                if pushes[k, 0] <= tm < pushes[k, 1]:
                    push_force += pushes[k, 2]
        sub_out[mk.O_DONE] = 0.0
        sub_out[mk.O_IMPULSE] = 0.0
        scode = mk.substeps(model, data, timestep, knots[:nk], 0, pushes, torso_com, cfrc, xpos, scom, qpos, qvel,
                            xfrc, ctrl, acc, ip, fp, sub_out)
        # 4. the controller's commit (the objects commit before the plant's period: nothing reads it in between)
        ck.period_commit(mem, res, work, qdc, t, stance)
        if sensing:         # the decision, in the pipeline (CompiledSensing.record: the torque sent, told stance)
            sp.record_decision(sstate, t, work, stance)
        sta[row_i, :] = res
        r[C_T] = t
        r[C_PUSH_FORCE] = push_force
        r[C_PUSH_IMPULSE] = sub_out[mk.O_IMPULSE]
        numerical = not math.isfinite(acc[mk.A_STATE_SUM])
        for b in range(bad_warn.shape[0]):
            if warn[bad_warn[b]] != 0:
                numerical = True
        if scode != mk.CONTINUE or numerical:
            out[O_END] = END_PLANT_EVENT
            out[O_CODE] = scode
            out[O_DONE] = sub_out[mk.O_DONE]
            out[O_NK] = nk
            out[O_T_START] = t
            out[O_T_GRID_END] = t_grid_end
            out[O_IMPULSE] = sub_out[mk.O_IMPULSE]
            out[O_ROW] = row_i
            return n_done
        mk.end_period(acc, row, stance, False, t_grid_end - t)
        r[C_T_END] = t_grid_end
        clock[K_T] = t_grid_end
        clock[K_STEP] += 1.0
        n_done += 1
        if t_grid_end >= t_stop:
            out[O_END] = END_LIMIT
            return n_done
    return n_done
