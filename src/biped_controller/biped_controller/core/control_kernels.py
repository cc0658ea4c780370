"""Compiled (numba) control period of the adaptive controller, for the fast engine (issue 11).

Pure numerics, no ROS: the per-period work of :class:`controller.AdaptiveController` in one call,
with the same equations, units and row order as its reference (Python) steps, which stay the oracle
of the tests (``engine: reference``):

* reference, eqs. (11), (16), (17), (20): q_d(p, tau) and its partial derivatives from the gait
  family's pieces (a_ij(p) = sum_m coef[k, i, j, m] (p - centers[k])^m, piece k = bisect_right(inner,
  p)), w = D x + v, D = [dq_d/dp, dq_d/dtau], x* = (-k_v p' + k_p (p_d - p), k_v (1 - tau'));
* model terms, eq. (1): A, H, B, h_b on the controller's locked-root chain
  (``biped_sim.robot.planar_kernels.fixed_root_terms``' maths) and the torso point's Jacobian x row;
* disturbance observer: F = j6 . r / j6 . j6, r = A_prev ((q'_now - q'_prev) / dt - w_prev);
  h_b,c = h_b + B A^-1 j6 F - Jb F;
* rows, eq. (21): G x <= h (37 rows: the 17 constraints with and without the estimate, p range,
  tau' >= tau_dot_min), the early-out decision "x* feasible" evaluated on the adapted columns
  exactly as ``qp_fast.early_out`` does (same expression, bit for bit);
* when x* is feasible (or in mode none): w, the torque Gamma = A w + H (eq. 15), the margins of the
  17 true constraints, the predicted reaction R = B w + h_b,c and the ZMP l = Gamma_1 / R_y.

When x* is not feasible the caller solves the QP (PIQP or the exact solver) on G, h and calls
:func:`finish` with the answer. Any non-finite value sends the caller back to the reference path.

Array layouts (all float64, C order; offsets named below):
  par (PAR_SIZE,)   gains, margins, state, observer inputs (``P_*``)
  cons (CONS_SIZE,) margin (17) | row_scale (17) | torque_min (6) | torque_max (6) | the QP's contact
                    rows (5 x (C_x, C_y, e)) | the robot's contact rows (``model.contact_rows``)
  prev (8, 6)       observer memory: q'_prev, w_prev, A_prev (6 rows)
  work (WORK_ROWS, 6) outputs: torque, w, v, e, D^T (2 rows), A (6 rows), H, B (3 rows)
  res (RES_SIZE,)   outputs: x (2), x* (2), F, max |e|, l, tightest, R (2), h_b (3), h_b,c (3), margins (17)
"""
from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numba
import numpy as np

from biped_sim.robot import planar_kernels as pk
from biped_controller.core import qp_fast
from biped_controller.core.qp_fast import _rows_and_decision

# compiled against planar_kernels and qp_fast: a change there must recompile this module
pk.drop_stale_cache(__name__.rsplit(".", 1)[-1], [Path(m.__file__) for m in (pk, qp_fast)] + [Path(__file__)])

N_ROWS = 17
QP_ROWS = 2 * N_ROWS + 3

# par offsets
(P_KP, P_KV, P_KP2, P_KV2, P_PD, P_DT, P_PMIN, P_PMAX, P_TAUD_MIN, P_OBS_ON, P_OBS_H, P_P, P_PDOT, P_TAU,
 P_TAUDOT, P_OBS_MODE, P_OBS_DT, P_F_PREV, P_ADAPT_P, P_ADAPT_TAU) = range(20)
PAR_SIZE = 20
OBS_NONE, OBS_RESIDUAL, OBS_KEEP = 0, 1, 2      # P_OBS_MODE: no memory, residual of the last period, keep F
# cons: margin (17) | row_scale (17) | torque_min (6) | torque_max (6) | the 5 contact rows of the QP
# (controller's mu and foot range) | the robot's 5 contact rows; a contact row is (C_x, C_y, e) of
# ``model.contact_rows``: C (R_x, R_y) + e Gamma_1 < 0 (the rows are written once, there)
CONS_TMIN = 2 * N_ROWS
CONS_TMAX = CONS_TMIN + 6
CONS_QP_ROWS = CONS_TMAX + 6
CONS_TRUE_ROWS = CONS_QP_ROWS + 15
CONS_SIZE = CONS_TRUE_ROWS + 15
# work rows
W_TORQUE, W_W, W_V, W_E, W_DP, W_DTAU, W_A, W_H, W_B = 0, 1, 2, 3, 4, 5, 6, 12, 13
WORK_ROWS = 16
# res offsets
R_X, R_XS, R_F, R_MAXERR, R_ZMP, R_TIGHT, R_R, R_HB, R_HBC, R_MARGINS = 0, 2, 4, 5, 6, 7, 8, 10, 13, 16
RES_SIZE = R_MARGINS + N_ROWS
# return codes of ``step``
FEASIBLE, NEEDS_QP, NONFINITE = 0, 1, 2

_V = numba.types.Array(numba.types.float64, 1, "C")
_VI = numba.types.Array(numba.types.int64, 1, "C")
_M = numba.types.Array(numba.types.float64, 2, "C")
_C4 = numba.types.Array(numba.types.float64, 4, "C")
_I = numba.types.int64

_STAMP = os.path.join(os.environ.get("NUMBA_CACHE_DIR", ""), "control_kernels.stamp")
_KEY = pk.cache_key(Path(__file__))
pk.announce_compile(Path(_STAMP), _KEY, sys.stderr)


@numba.njit(cache=True)
def _family(coef, inner, centers, p, tau, out):
    """out (6, 6) <- rows q, dq/dp, dq/dtau, d2q/dp2, d2q/dtau2, d2q/dpdtau at (p, tau) (the pieces'
    polynomials in p times tau^j, as ``GaitFamily.evaluate``)."""
    k = 0
    while k < inner.shape[0] and inner[k] <= p:
        k += 1
    u = p - centers[k]
    K = coef.shape[3]
    for i in range(6):
        for r in range(6):
            out[r, i] = 0.0
    for j in range(5):
        tj = tau ** j
        dtj = j * tau ** (j - 1) if j >= 1 else 0.0
        d2tj = j * (j - 1) * tau ** (j - 2) if j >= 2 else 0.0
        for i in range(6):
            a = 0.0
            da = 0.0
            d2a = 0.0
            pw = 1.0
            for m in range(K):
                c = coef[k, i, j, m]
                a += c * pw
                if m + 1 < K:
                    da += coef[k, i, j, m + 1] * (m + 1) * pw
                if m + 2 < K:
                    d2a += coef[k, i, j, m + 2] * (m + 2) * (m + 1) * pw
                pw *= u
            out[0, i] += a * tj
            out[1, i] += da * tj
            out[2, i] += a * dtj
            out[3, i] += d2a * tj
            out[4, i] += a * d2tj
            out[5, i] += da * dtj


@numba.njit(cache=True)
def _contact(cons, off, r, rx, ry, g1):
    """Contact row r of the block at ``off`` of ``cons``: C_r (R_x, R_y) + e_r Gamma_1 (``model.contact_rows``)."""
    k = off + 3 * r
    return cons[k] * rx + cons[k + 1] * ry + cons[k + 2] * g1


@numba.njit(cache=True)
def _finish(par, cons, work, res):
    """From x = res[R_X:R_X+2]: w = D x + v (eq. 17), Gamma = A w + H (eq. 15), the 17 margins (positive =
    satisfied, the robot's own mu and foot, no controller margin), R = B w + h_b,c, l, the tightest row."""
    x0 = res[R_X]
    x1 = res[R_X + 1]
    for i in range(6):
        work[W_W, i] = work[W_DP, i] * x0 + work[W_DTAU, i] * x1 + work[W_V, i]
    for i in range(6):
        s = work[W_H, i]
        for k in range(6):
            s += work[W_A + i, k] * work[W_W, k]
        work[W_TORQUE, i] = s
    rx = res[R_HBC]
    ry = res[R_HBC + 1]
    for k in range(6):
        rx += work[W_B, k] * work[W_W, k]
        ry += work[W_B + 1, k] * work[W_W, k]
    res[R_R] = rx
    res[R_R + 1] = ry
    g1 = work[W_TORQUE, 0]
    mg = res[R_MARGINS:]
    for r in range(5):
        mg[r] = -_contact(cons, CONS_TRUE_ROWS, r, rx, ry, g1)
    for i in range(6):
        mg[5 + i] = cons[CONS_TMAX + i] - work[W_TORQUE, i]
        mg[11 + i] = work[W_TORQUE, i] - cons[CONS_TMIN + i]
    best = 0
    bv = mg[0] / cons[N_ROWS]
    for i in range(1, N_ROWS):
        val = mg[i] / cons[N_ROWS + i]
        if val < bv:
            bv = val
            best = i
    res[R_TIGHT] = best
    res[R_ZMP] = g1 / ry if ry != 0.0 else math.nan


@numba.njit(numba.types.int64(_C4, _V, _V, _VI, _V, _V, _V, _V, _V, _M, _M, _V, _M, _V), cache=True)
def step(coef, inner, centers, ti, tf, q, qd, par, cons, prev, G, h, work, res):
    """One control period up to the QP decision (see the module docstring). Returns FEASIBLE (x = x*
    and every output computed), NEEDS_QP (G, h filled; solve, put x in res, call ``finish``) or NONFINITE
    (use the reference path). G (QP_ROWS, 2), h (QP_ROWS,) are filled whenever a parameter is adapted."""
    fam = np.empty((6, 6))
    _family(coef, inner, centers, par[P_P], par[P_TAU], fam)
    p_dot = par[P_PDOT]
    tau_dot = par[P_TAUDOT]
    kp_, kv_ = par[P_KP], par[P_KV]
    maxerr = 0.0
    for i in range(6):
        qd_d = fam[1, i] * p_dot + fam[2, i] * tau_dot
        drift = fam[3, i] * p_dot ** 2 + fam[4, i] * tau_dot ** 2 + 2.0 * fam[5, i] * p_dot * tau_dot
        e = fam[0, i] - q[i]
        work[W_E, i] = e
        work[W_V, i] = drift + kv_ * (qd_d - qd[i]) + kp_ * e
        work[W_DP, i] = fam[1, i]
        work[W_DTAU, i] = fam[2, i]
        if abs(e) > maxerr or e != e:
            maxerr = abs(e)
    res[R_MAXERR] = maxerr
    xs0 = -par[P_KV2] * p_dot + par[P_KP2] * (par[P_PD] - par[P_P])
    xs1 = par[P_KV2] * (1.0 - tau_dot)
    res[R_XS] = xs0
    res[R_XS + 1] = xs1
    res[R_X] = xs0
    res[R_X + 1] = xs1
    # eq. (1) and the reaction rows: the locked-root chain (joints 0-2 at rest), q1..q6
    A = np.empty((6, 6))
    H = np.empty(6)
    B = np.empty((3, 6))
    hb = np.empty(3)
    jp = np.empty(9)
    pk.fixed_root_terms(ti, tf, q, qd, par[P_OBS_H], A, H, B, hb, jp)
    work[W_A:W_A + 6] = A
    work[W_H] = H
    work[W_B:W_B + 3] = B
    res[R_HB:R_HB + 3] = hb
    hbc = np.empty(3)
    hbc[:] = hb
    F = 0.0
    if par[P_OBS_ON] != 0.0:
        mode = par[P_OBS_MODE]
        if mode == OBS_KEEP:
            F = par[P_F_PREV]
        elif mode == OBS_RESIDUAL:
            dt = par[P_OBS_DT]
            num = 0.0
            nrm = 0.0
            for i in range(6):
                r = 0.0
                for k in range(6):
                    r += prev[2 + i, k] * ((qd[k] - prev[0, k]) / dt - prev[1, k])
                num += jp[3 + i] * r
                nrm += jp[3 + i] * jp[3 + i]
            F = num / nrm if nrm > 1e-12 else 0.0
        # h_b,c = h_b + B A^-1 j6 F - Jb F
        L = np.empty((6, 6))
        y = np.empty((1, 6))
        if not pk._cholesky(A, L):
            return NONFINITE
        for k in range(6):
            y[0, k] = jp[3 + k] * F
        pk._chol_solve_rows(L, y)
        for r in range(3):
            s = 0.0
            for k in range(6):
                s += B[r, k] * y[0, k]
            hbc[r] = hb[r] + (s - jp[r] * F)
    res[R_HBC:R_HBC + 3] = hbc
    res[R_F] = F
    for i in range(6):
        if not (math.isfinite(work[W_V, i]) and math.isfinite(work[W_DP, i]) and math.isfinite(work[W_DTAU, i])):
            return NONFINITE
    for r in range(3):
        if not math.isfinite(hbc[r]):
            return NONFINITE
    ap = par[P_ADAPT_P] != 0.0
    at = par[P_ADAPT_TAU] != 0.0
    if not (ap or at):
        _finish(par, cons, work, res)
        return FEASIBLE
    # eq. (21): the 17 rows with the controller's margins, with (rows 0-16) and without (17-33) the estimate
    Aq = np.empty((N_ROWS, 6))
    bq = np.empty(N_ROWS)
    b0 = np.empty(5)
    for r in range(5):
        for k in range(6):
            Aq[r, k] = _contact(cons, CONS_QP_ROWS, r, B[0, k], B[1, k], A[0, k])
        bq[r] = _contact(cons, CONS_QP_ROWS, r, hbc[0], hbc[1], H[0]) + cons[r]
        b0[r] = _contact(cons, CONS_QP_ROWS, r, hb[0], hb[1], H[0]) + cons[r]
    for i in range(6):
        for k in range(6):
            Aq[5 + i, k] = A[i, k]
            Aq[11 + i, k] = -A[i, k]
        bq[5 + i] = (H[i] - cons[CONS_TMAX + i]) + cons[5 + i]
        bq[11 + i] = (cons[CONS_TMIN + i] - H[i]) + cons[11 + i]
    for r in range(N_ROWS):
        ad0 = 0.0
        ad1 = 0.0
        av = 0.0
        for k in range(6):
            ad0 += Aq[r, k] * work[W_DP, k]
            ad1 += Aq[r, k] * work[W_DTAU, k]
            av += Aq[r, k] * work[W_V, k]
        G[r, 0] = ad0
        G[r, 1] = ad1
        G[N_ROWS + r, 0] = ad0
        G[N_ROWS + r, 1] = ad1
        h[r] = -(av + bq[r])
        h[N_ROWS + r] = -(av + (b0[r] if r < 5 else bq[r]))
    dt = par[P_DT]
    p, p_dot_ = par[P_P], par[P_PDOT]
    G[2 * N_ROWS, 0] = 0.5 * dt * dt
    G[2 * N_ROWS, 1] = 0.0
    G[2 * N_ROWS + 1, 0] = -0.5 * dt * dt
    G[2 * N_ROWS + 1, 1] = 0.0
    G[2 * N_ROWS + 2, 0] = 0.0
    G[2 * N_ROWS + 2, 1] = -dt
    h[2 * N_ROWS] = par[P_PMAX] - p - p_dot_ * dt
    h[2 * N_ROWS + 1] = p + p_dot_ * dt - par[P_PMIN]
    h[2 * N_ROWS + 2] = tau_dot - par[P_TAUD_MIN]
    for r in range(QP_ROWS):
        if not (math.isfinite(G[r, 0]) and math.isfinite(G[r, 1]) and math.isfinite(h[r])):
            return NONFINITE
    # x* feasible on the adapted columns? (qp_fast.early_out's expression; a fixed parameter stays at x*
    # and moves to the right-hand side)
    v = np.empty(QP_ROWS)
    if ap and at:
        feasible = _rows_and_decision(G, h, res[R_XS:R_XS + 2], v)
    else:
        col = 0 if ap else 1
        fixed = 1 - col
        Gr = np.empty((QP_ROWS, 1))
        hr = np.empty(QP_ROWS)
        xr = np.empty(1)
        xr[0] = res[R_XS + col]
        for r in range(QP_ROWS):
            Gr[r, 0] = G[r, col]
            hr[r] = h[r] - G[r, fixed] * res[R_XS + fixed]
        feasible = _rows_and_decision(Gr, hr, xr, v)
    if not feasible:
        return NEEDS_QP
    _finish(par, cons, work, res)
    return FEASIBLE


@numba.njit(numba.types.int64(_V, _V, _M, _V), cache=True)
def finish(par, cons, work, res):
    """After a QP: w, torque, margins, reaction, l and the tightest row for x = res[R_X:R_X+2]."""
    _finish(par, cons, work, res)
    return 0


pk.write_stamp(Path(_STAMP), _KEY)
