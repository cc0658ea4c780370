"""Compiled closed loop (numba): many control periods of controller + simulator in one call (issue 11).

Pure numerics, no ROS. The in-process runner (``runner.run``) hands a *segment* of periods to
:func:`run_segment` while nothing in them needs Python: each period is exactly what the objects do
one call at a time, in the same order and with the same kernels --

  1. the sensors: paper (q, q') of the stance from the floating state (``paper_from_urdf``);
  2. the controller: parameter advance over the elapsed integer nanoseconds (tau = 0 when the stance
     changed), the observer mode, ``control_kernels.step`` (x* must be feasible: a period that needs
     the QP ends the segment before it);
  3. the torque: clipped to the limits, mapped to the URDF joints of the stance;
  4. the simulator: the period's intervals (RK4 substeps, split at push starts and ends, as
     ``Simulator.step``) and ``planar_kernels.period`` (an event -- touchdown candidate, failed wrench
     check, sinking foot, singular state -- ends the segment before the period);
  5. the period is recorded (row k of ``rec`` and ``sta``) and both states are committed.

A segment also ends after the period whose end reaches ``t_stop`` and when the record arrays are full
(``ring`` False) or after ``max_periods``. Whatever ended it, the states passed in hold the state after
the last committed period, so the caller goes on with the objects (the QP, the impact, the fall) for
the next period, then hands the next segment over. Records are bit-identical to the objects' (tested).

Layouts (float64, C order):
  cst  controller state (C_*): p, p', tau, tau', p'', tau'' of the last decision, t of the last decision,
       has a last decision, stance of the last decision (-1 none), observer memory valid, its stance,
       its t, force estimate F, period index
  prev (8, 6)  observer memory: q'_prev, w_prev, A_prev
  sst  simulator state (S_*): t, period index, stance, cleared, anchor (3)
  slim simulator limits (L_*): mu, l_min, l_max, touchdown tolerance, clearance, liftoff penetration,
       control period, substeps, torque min (6), torque max (6)
  pushes (n, 4): start, end, force, height of every scheduled push
  perm (2, 6, 6): PAPER_FROM_URDF of each stance
  rec (cap, REC_COLS), sta (cap, STA_COLS): one row a period (columns REC_* / STA_*)
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numba
import numpy as np

from biped_sim.robot import planar_kernels as pk
from biped_controller.core import control_kernels as ck
from biped_controller.core import qp_fast

# compiled against planar_kernels, qp_fast and control_kernels: a change there must recompile this module
pk.drop_stale_cache(__name__.rsplit(".", 1)[-1], [Path(m.__file__) for m in (pk, qp_fast, ck)] + [Path(__file__)])

# controller state
(C_P, C_PDOT, C_TAU, C_TAUDOT, C_PDD, C_TDD, C_TLAST, C_HAS_TLAST, C_STANCE, C_PREV_OK, C_PREV_STANCE,
 C_PREV_T, C_F, C_STEP) = range(14)
CST_SIZE = 14
# simulator state
S_T, S_STEP, S_STANCE, S_CLEARED, S_ANCHOR = 0, 1, 2, 3, 4
SST_SIZE = 7
# simulator limits
L_MU, L_LMIN, L_LMAX, L_TD_TOL, L_CLEAR, L_PEN, L_DT, L_SUB, L_TQ_MIN, L_TQ_MAX = 0, 1, 2, 3, 4, 5, 6, 7, 8, 14
SLIM_SIZE = 20
# record columns: the simulator's StepRecord of the period
REC_T, REC_TEND, REC_X, REC_V, REC_Q, REC_QD, REC_TORQUE, REC_W, REC_PF, REC_IMP = 0, 1, 2, 11, 20, 26, 32, 38, 41, 42
REC_COLS = 43
# status columns: the controller's ControllerStatusData of the period
(STA_P, STA_PDOT, STA_TAU, STA_TAUDOT, STA_PDD, STA_TDD, STA_PDDS, STA_TDDS) = range(8)
STA_MARGINS, STA_TIGHT, STA_ZMP, STA_MAXERR, STA_R, STA_F = 8, 25, 26, 27, 28, 30
STA_COLS = 31
# why a segment ended
(END_LIMIT, END_FULL, END_QP, END_SIM_EVENT, END_NONFINITE, END_PUSHES, END_MAX) = range(7)
END_NAMES = ("t_stop reached", "record arrays full", "QP needed", "simulator event", "non-finite controller value",
             "two pushes in one interval", "max_periods")

_V = numba.types.Array(numba.types.float64, 1, "C")
_VI = numba.types.Array(numba.types.int64, 1, "C")
_M = numba.types.Array(numba.types.float64, 2, "C")
_C3 = numba.types.Array(numba.types.float64, 3, "C")
_C4 = numba.types.Array(numba.types.float64, 4, "C")
_I = numba.types.int64
_F = numba.types.float64
_B = numba.types.boolean

_STAMP = Path(numba.config.CACHE_DIR or ".") / "loop_kernels.stamp"
_KEY = pk.cache_key(Path(__file__))
pk.announce_compile(_STAMP, _KEY, sys.stderr)


@numba.njit(cache=True)
def _knots(t_start, dt_nom, substeps, pushes, knots):
    """The period's integration intervals as ``Simulator.step`` builds them; returns (count of knots,
    t at the period's grid end)."""
    t_grid_end = (math.floor(t_start / dt_nom + 1e-6) + 1) * dt_nom
    dt = t_grid_end - t_start
    n_sub = max(1, int(math.ceil(substeps * dt / dt_nom - 1e-9)))
    h = dt / n_sub
    n = 0
    for i in range(n_sub):
        knots[n] = t_start + i * h
        n += 1
    knots[n] = t_grid_end
    n += 1
    for k in range(pushes.shape[0]):
        for c in (pushes[k, 0], pushes[k, 1]):
            if t_start < c < t_grid_end:
                if n >= knots.shape[0]:
                    return -1, t_grid_end
                knots[n] = c
                n += 1
    ks = np.sort(knots[:n])
    m = 0
    for i in range(n):   # set() then sorted(): exact duplicates once
        if m == 0 or ks[i] != knots[m - 1]:
            knots[m] = ks[i]
            m += 1
    return m, t_grid_end


@numba.njit(numba.types.int64(
    _C4, _V, _V, _VI, _V, _V, _V, _V, _M,                       # controller: family, tree, par, cons, cst, prev
    _VI, _V, _V, _V, _V, _V, _M, _C3,                           # simulator: tree, x, v, sst, slim, pushes, perm
    _F, _I, _B, _M, _M, _V), cache=True)                        # t_stop, max_periods, ring, rec, sta, out
def run_segment(coef, inner, centers, cti, ctf, par, cons, cst, prev,
                sti, stf, x, v, sst, slim, pushes, perm,
                t_stop, max_periods, ring, rec, sta, out):
    """Run periods while nothing needs Python (module docstring). Returns the number of periods done;
    out[0] = why the segment ended (END_*)."""
    cap = rec.shape[0]
    q = np.empty(6)
    qd = np.empty(6)
    G = np.empty((ck.QP_ROWS, 2))
    h = np.empty(ck.QP_ROWS)
    work = np.empty((ck.WORK_ROWS, 6))
    res = np.empty(ck.RES_SIZE)
    applied = np.empty(6)
    tj = np.empty(6)
    knots = np.empty(64)
    lim = np.empty(pk.PERIOD_LIMITS_SIZE)
    xo = np.empty(x.shape[0])
    vo = np.empty(x.shape[0])
    w0 = np.empty(3)
    pout = np.empty(pk.PERIOD_OUT_SIZE)
    anchor = sst[S_ANCHOR:S_ANCHOR + 3].copy()
    n_done = 0
    out[0] = END_MAX
    while n_done < max_periods:
        if not ring and n_done >= cap:
            out[0] = END_FULL
            return n_done
        t = sst[S_T]
        stance = int(sst[S_STANCE])
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
        # 2. controller: advance (on copies until the period is committed), observer mode, step
        p, p_dot, tau, tau_dot = cst[C_P], cst[C_PDOT], cst[C_TAU], cst[C_TAUDOT]
        if cst[C_HAS_TLAST] != 0.0:
            h_el = (round(t * 1e9) - round(cst[C_TLAST] * 1e9)) * 1e-9
            p_dd0 = cst[C_PDD]
            t_dd0 = cst[C_TDD]
            p += p_dot * h_el + 0.5 * p_dd0 * h_el * h_el
            p_dot += p_dd0 * h_el
            tau += tau_dot * h_el + 0.5 * t_dd0 * h_el * h_el
            tau_dot += t_dd0 * h_el
        if cst[C_STANCE] >= 0.0 and stance != int(cst[C_STANCE]):
            tau = 0.0
        par[ck.P_P] = p
        par[ck.P_PDOT] = p_dot
        par[ck.P_TAU] = tau
        par[ck.P_TAUDOT] = tau_dot
        if cst[C_PREV_OK] == 0.0:
            par[ck.P_OBS_MODE] = ck.OBS_NONE
        elif int(cst[C_PREV_STANCE]) != stance:
            par[ck.P_OBS_MODE] = ck.OBS_KEEP
            par[ck.P_F_PREV] = cst[C_F]
        else:
            par[ck.P_OBS_MODE] = ck.OBS_RESIDUAL
            par[ck.P_OBS_DT] = (round(t * 1e9) - round(cst[C_PREV_T] * 1e9)) * 1e-9
        code = ck.step(coef, inner, centers, cti, ctf, q, qd, par, cons, prev, G, h, work, res)
        if code == ck.NEEDS_QP:
            out[0] = END_QP
            return n_done
        if code != ck.FEASIBLE:
            out[0] = END_NONFINITE
            return n_done
        # 3. torque: clipped, to the URDF joints
        for i in range(6):
            applied[i] = min(max(work[ck.W_TORQUE, i], slim[L_TQ_MIN + i]), slim[L_TQ_MAX + i])
        for j in range(6):
            s = 0.0
            for i in range(6):
                s += P[i, j] * applied[i]
            tj[j] = s
        # 4. simulator period
        nk, t_end = _knots(t, slim[L_DT], slim[L_SUB], pushes, knots)
        if nk < 0:
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
                        out[0] = END_PUSHES
                        return n_done
                    forces[i] = pushes[k, 2]
                    heights[i] = pushes[k, 3]
        lim[0] = slim[L_MU]
        lim[1] = slim[L_LMIN]
        lim[2] = slim[L_LMAX]
        lim[3] = slim[L_TD_TOL]
        lim[4] = slim[L_CLEAR]
        lim[5] = slim[L_PEN]
        lim[6] = sst[S_CLEARED]
        st = pk.period(sti, stf, x, v, tj, knots[:nk].copy(), forces, heights, stance, anchor, lim, xo, vo, w0, pout)
        if st != pk.PERIOD_DONE:
            out[0] = END_SIM_EVENT
            return n_done
        # 5. record and commit
        row = n_done % cap
        r = rec[row]
        r[REC_T] = t
        r[REC_TEND] = t_end
        for k in range(9):
            r[REC_X + k] = x[k]
            r[REC_V + k] = v[k]
        for i in range(6):
            r[REC_Q + i] = q[i]
            r[REC_QD + i] = qd[i]
            r[REC_TORQUE + i] = applied[i]
        for k in range(3):
            r[REC_W + k] = w0[k]
        r[REC_PF] = forces[0] if not math.isnan(heights[0]) else 0.0
        r[REC_IMP] = pout[2]
        s_ = sta[row]
        s_[STA_P] = p
        s_[STA_PDOT] = p_dot
        s_[STA_TAU] = tau
        s_[STA_TAUDOT] = tau_dot
        s_[STA_PDD] = res[ck.R_X]
        s_[STA_TDD] = res[ck.R_X + 1]
        s_[STA_PDDS] = res[ck.R_XS]
        s_[STA_TDDS] = res[ck.R_XS + 1]
        for k in range(17):
            s_[STA_MARGINS + k] = res[ck.R_MARGINS + k]
        s_[STA_TIGHT] = res[ck.R_TIGHT]
        s_[STA_ZMP] = res[ck.R_ZMP]
        s_[STA_MAXERR] = res[ck.R_MAXERR]
        s_[STA_R] = res[ck.R_R]
        s_[STA_R + 1] = res[ck.R_R + 1]
        s_[STA_F] = res[ck.R_F]
        cst[C_P] = p
        cst[C_PDOT] = p_dot
        cst[C_TAU] = tau
        cst[C_TAUDOT] = tau_dot
        cst[C_PDD] = res[ck.R_X]
        cst[C_TDD] = res[ck.R_X + 1]
        cst[C_TLAST] = t
        cst[C_HAS_TLAST] = 1.0
        cst[C_STANCE] = stance
        cst[C_PREV_OK] = 1.0
        cst[C_PREV_STANCE] = stance
        cst[C_PREV_T] = t
        cst[C_F] = res[ck.R_F]
        cst[C_STEP] += 1.0
        for i in range(6):
            prev[0, i] = qd[i]
            prev[1, i] = work[ck.W_W, i]
            for k in range(6):
                prev[2 + i, k] = work[ck.W_A + i, k]
        x[:] = xo
        v[:] = vo
        sst[S_T] = t_end
        sst[S_STEP] += 1.0
        sst[S_CLEARED] = pout[1]
        n_done += 1
        if t_end >= t_stop:
            out[0] = END_LIMIT
            return n_done
    return n_done


pk.write_stamp(_STAMP, _KEY)
