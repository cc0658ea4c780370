"""Compiled (numba) control period of the adaptive controller, for the fast engine.

Pure numerics, no ROS, no side effects on import (load it through ``numba_cache.load``, as
``controller`` does, so its cache is kept with its dependencies). The per-period work of
:class:`controller.AdaptiveController` in one call, with the same equations, units and row order as its
reference (Python) steps, which stay the oracle of the tests (``engine: reference``):

* the period's start (:func:`begin`, also called by the Python steps): the parameters advance over the
  elapsed time since the last decision, from integer nanoseconds (exact integration with the held
  p'', tau''): p += p' h + p'' h^2 / 2, p' += p'' h (tau likewise), then p held to [p_min, p_max] with the
  outward part of p' removed at a bound (:func:`limited`: an integrator with limits, for a full period or one
  cut short by an impact), tau = 0 when the stance changed (an impact); the observer's mode: no memory, the
  residual of the last period, or keep F (the last period ended with an impact);
* reference, eqs. (11), (16), (17), (20): q_d(p, tau) and its partial derivatives from the gait
  family's pieces (a_ij(p) = sum_m coef[k, i, j, m] (p - centers[k])^m, piece k = bisect_right(inner,
  p)), w = D x + v, D = [dq_d/dp, dq_d/dtau], x* = (-k_v p' + k_p (p_d - p), k_v (1 - tau'));
* model terms, eq. (1): A, H, B, h_b on the controller's locked-root chain
  (``biped_model.planar_kernels.fixed_root_terms``' maths) and the torso point's Jacobian x row;
* disturbance observer: F = j6 . r / j6 . j6, r = A_prev ((q'_now - q'_prev) / dt - w_prev);
  h_b,c = h_b + B A^-1 j6 F - Jb F; or, with the momentum observer (GAINS.momentum), the
  compiled sensing pipeline's (``pipeline_kernels``) h_b,c = h_b + (dR, 0), F = F_x, and the five
  contact rows stated with the estimate widened by its spread (RES.sens_*, written before the period);
* rows, eq. (21): G x <= h (37 rows: the 17 constraints with and without the estimate, p range,
  tau' >= tau_dot_min), the early-out decision "x* feasible" evaluated on the adapted columns
  exactly as ``exact_kernels.early_out`` does (same expression, bit for bit);
* modes lambda and all (GAINS.torso): the torso offset of ``gait_family.with_torso`` in the
  reference (q_d += lambda phi(tau/T) e, its lambda terms in dq/dtau, d2q/dtau2 and eq. (11)), a third
  column dq/dlambda (WORK.dq_dlam) and x = (p'', tau'', lambda''), lambda''* = -kv_lambda lambda' - kp_lambda
  lambda, four more rows (lambda, lambda' after one period within +-lambda_max, +-lambda_dot_max; G is then
  (TORSO_QP_ROWS, 3)); lambda, lambda' advance (held to +-lambda_max as p to its range) and commit with p, p'
  (``period_start``, ``period_commit``),
  0 in the other modes, whose arithmetic is unchanged bit for bit;
* when x* is feasible (or in mode none): w, the torque Gamma = A w + H (eq. 15), the margins of the
  17 true constraints, the predicted reaction R = B w + h_b,c and the ZMP l = Gamma_1 / R_y;
* the period's end (:func:`commit`, also called by the Python steps): the memory takes the period's
  parameters, its decision, t, the stance, F, q', w and A.

When x* is not feasible the caller solves the QP (PIQP or the exact solver) on G, h and calls
:func:`finish` with the answer (modes lambda and all: lambda'' held to the torso's range first when the
answer does not hold the rows, ``controller_compiled.CompiledPeriod.solve_qp``). Any non-finite value sends the caller back to the reference path
(memory unchanged).

Arrays (float64, C order; fields and offsets declared once in ``controller_layout``): ``gains`` (GAINS),
``cons`` (CONS), ``mem`` (MEMORY: the controller's own state), ``res`` (RES), ``work`` (WORK rows x 6).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_model import numba_cache
from biped_model import planar_kernels as pk
from biped_model.gait_family import TORSO_DIRECTION
from biped_controller.core.control.controller_layout import (
    C_, G_, M_, OBS_KEEP, OBS_NONE, OBS_RESIDUAL, QP_ROWS, R_, TORSO_ROWS, W_, CONS, RES, WORK, N_JOINTS)
from biped_controller.core.qp.exact_kernels import rows_and_decision

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

N_ROWS = CONS.sizes["margin"]
WORK_ROWS = WORK.size
RES_SIZE = RES.size
# return codes of ``step``
FEASIBLE, NEEDS_QP, NONFINITE = 0, 1, 2

# numba types of the kernels' arguments (explicit signatures; also the compiled loop's)
T_VEC = numba.types.Array(numba.types.float64, 1, "C")
T_IVEC = numba.types.Array(numba.types.int64, 1, "C")
T_MAT = numba.types.Array(numba.types.float64, 2, "C")
T_ARR4 = numba.types.Array(numba.types.float64, 4, "C")
T_INT = numba.types.int64
T_FLOAT = numba.types.float64
_V, _VI, _M, _C4, _I, _F = T_VEC, T_IVEC, T_MAT, T_ARR4, T_INT, T_FLOAT


@numba.njit(cache=True)
def advanced(p, p_dot, tau, tau_dot, p_ddot, tau_ddot, h):
    """(p, p', tau, tau') after h [s] with constant p'' [m/s^2], tau'' [1/s] (exact integration):
    p + (p' h + p'' h^2 / 2), p' + p'' h, likewise for tau."""
    return (p + (p_dot * h + 0.5 * p_ddot * h * h), p_dot + p_ddot * h,
            tau + (tau_dot * h + 0.5 * tau_ddot * h * h), tau_dot + tau_ddot * h)


@numba.njit(numba.types.UniTuple(_F, 4)(_F, _F, _F, _F, _F, _F, _F), cache=True)
def advance(p, p_dot, tau, tau_dot, p_ddot, tau_ddot, h):
    """:func:`advanced` from Python: the free integration, without the range's limit (the hold's and the
    tests' arithmetic of one period)."""
    return advanced(p, p_dot, tau, tau_dot, p_ddot, tau_ddot, h)


@numba.njit(cache=True)
def limited(v, v_dot, lo, hi):
    """A double integrator's state (v, v') held to its range [lo, hi] (an integrator with limits and
    anti-windup): at or past a bound, v is put on it and the outward part of v' is removed,

      v >= hi:  (hi, min(v', 0));    v <= lo:  (lo, max(v', 0));    otherwise (v, v') unchanged (bit for bit).

    Units are v's (p: [m], [m/s]; lambda: [rad], [rad/s]). Why: the range rows of the QP and the hold
    (``controller._hold_ranges``) put v inside [lo, hi] at the end of a full period, v + v' dt + v'' dt^2 / 2,
    but the quadratic v(h) = v + v' h + v'' h^2 / 2 peaks inside the period when v' and v'' have opposite
    signs and v' / |v''| < dt, v'^2 / (2 |v''|) beyond its start value; a period cut short by an impact
    (h < dt) can end near that peak, outside the range.
    Keeping v(h) itself below the bound for every h in (0, dt] would need v'' <= -v'^2 / (2 (hi - v)) (from
    v = 0.64996 m at v' = 1.92 m/s: -4.6e4 m/s^2), so the decision cannot be what holds it: the integration
    does. A v on the bound with v' <= 0 (inward) is unchanged; a v' pointing out of the range at the bound
    would carry v out at once, so it is removed (the state's velocity does not wind up against the limit)."""
    if v >= hi:
        return hi, min(v_dot, 0.0)
    if v <= lo:
        return lo, max(v_dot, 0.0)
    return v, v_dot


@numba.njit(numba.types.UniTuple(_F, 2)(_F, _F, _F, _F), cache=True)
def limit(v, v_dot, lo, hi):
    """:func:`limited` from Python (lambda within a period, the tests)."""
    return limited(v, v_dot, lo, hi)


@numba.njit(cache=True)
def advanced_in_range(p, p_dot, tau, tau_dot, p_ddot, tau_ddot, h, p_min, p_max):
    """(p, p', tau, tau') after h [s] with the held p'', tau'' (:func:`advanced`), p and p' then held to
    [p_min, p_max] [m] (:func:`limited`): the controller's parameter advance, wherever it is evaluated (the
    period's start, the reference within a period, the reference at a sample's instant). tau' is linear in h,
    so between two in-range ends it needs no limit."""
    p, p_dot, tau, tau_dot = advanced(p, p_dot, tau, tau_dot, p_ddot, tau_ddot, h)
    p, p_dot = limited(p, p_dot, p_min, p_max)
    return p, p_dot, tau, tau_dot


@numba.njit(numba.types.UniTuple(_F, 4)(_F, _F, _F, _F, _F, _F, _F, _F, _F), cache=True)
def advance_in_range(p, p_dot, tau, tau_dot, p_ddot, tau_ddot, h, p_min, p_max):
    """:func:`advanced_in_range` from Python (the torque law within a period, ``reference_at``)."""
    return advanced_in_range(p, p_dot, tau, tau_dot, p_ddot, tau_ddot, h, p_min, p_max)


@numba.njit(cache=True)
def period_start(mem, gains, t, stance, res):
    """The period's parameters into res (p, p', tau, tau', and lambda, lambda' in the torso modes), advanced from the
    memory over the elapsed integer nanoseconds with the held decision, p and p' held to the family's range
    [p_min, p_max] (:func:`advanced_in_range`; lambda, lambda' to [-lambda_max, lambda_max] in the torso modes,
    :func:`limited`), whether the period ran in full or was cut short by an impact; tau = 0 when the stance
    changed; the observer's mode and elapsed time (RES.obs_mode, obs_dt); lambda'' = lambda''* = 0 (res x[2],
    x_star[2]) until a torso mode decides them. The memory is not changed."""
    p, p_dot, tau, tau_dot = mem[M_.p], mem[M_.p_dot], mem[M_.tau], mem[M_.tau_dot]
    decided = mem[M_.decided] != 0.0
    dt_ns = 0.0
    if decided:
        dt_ns = (round(t * 1e9) - round(mem[M_.t_last] * 1e9)) * 1e-9
        p, p_dot, tau, tau_dot = advanced_in_range(p, p_dot, tau, tau_dot, mem[M_.p_ddot], mem[M_.tau_ddot], dt_ns,
                                                   gains[G_.p_min], gains[G_.p_max])
    last = mem[M_.stance]
    if last >= 0.0 and stance != int(last):
        tau = 0.0
    res[R_.p] = p
    res[R_.p_dot] = p_dot
    res[R_.tau] = tau
    res[R_.tau_dot] = tau_dot
    # torso modes: lambda, lambda' advanced likewise with the held lambda'' (carried over an impact: phi(0) = 0);
    # 0 outside modes lambda and all. The period's lambda'' and lambda''* start at 0 (the torso modes decide them).
    lam, lam_dot = mem[M_.lam], mem[M_.lam_dot]
    if decided:
        lam_ddot = mem[M_.lam_ddot]
        lam, lam_dot = lam + (lam_dot * dt_ns + 0.5 * lam_ddot * dt_ns * dt_ns), lam_dot + lam_ddot * dt_ns
        if gains[G_.torso] != 0.0:
            lam, lam_dot = limited(lam, lam_dot, -gains[G_.lam_max], gains[G_.lam_max])
    res[R_.lam] = lam
    res[R_.lam + 1] = lam_dot
    res[R_.x + 2] = 0.0
    res[R_.x_star + 2] = 0.0
    if not decided:
        res[R_.obs_mode] = OBS_NONE
    elif int(last) != stance:
        res[R_.obs_mode] = OBS_KEEP
    else:
        res[R_.obs_mode] = OBS_RESIDUAL
    res[R_.obs_dt] = dt_ns


@numba.njit(cache=True)
def _extremes(mem, v, lo, first):
    """mem[lo], mem[lo + 1] <- the smallest and largest committed value of a parameter: ``v`` alone at the first
    commit since the reset (``first``), else widened by ``v``; a NaN, once there, stays (the run's range is then
    unknown, not silently the finite part)."""
    if first or v != v:
        mem[lo] = v
        mem[lo + 1] = v
        return
    if mem[lo] == mem[lo] and v < mem[lo]:
        mem[lo] = v
    if mem[lo + 1] == mem[lo + 1] and v > mem[lo + 1]:
        mem[lo + 1] = v


@numba.njit(cache=True)
def period_commit(mem, res, work, qd, t, stance):
    """The period is applied: the memory takes its parameters, decision, time, stance, F, q', w, A (and lambda,
    lambda', lambda'': 0 outside the torso modes), and the extremes of p and tau' since the reset (:func:`_extremes`)."""
    first = mem[M_.decided] == 0.0
    _extremes(mem, res[R_.p], M_.p_lo, first)
    _extremes(mem, res[R_.tau_dot], M_.tau_dot_lo, first)
    mem[M_.p] = res[R_.p]
    mem[M_.p_dot] = res[R_.p_dot]
    mem[M_.tau] = res[R_.tau]
    mem[M_.tau_dot] = res[R_.tau_dot]
    mem[M_.p_ddot] = res[R_.x]
    mem[M_.tau_ddot] = res[R_.x + 1]
    mem[M_.lam] = res[R_.lam]
    mem[M_.lam_dot] = res[R_.lam + 1]
    mem[M_.lam_ddot] = res[R_.x + 2]
    mem[M_.decided] = 1.0
    mem[M_.t_last] = t
    mem[M_.stance] = stance
    mem[M_.force] = res[R_.force]
    mem[M_.step] += 1.0
    for i in range(N_JOINTS):
        mem[M_.prev_qd + i] = qd[i]
        mem[M_.prev_w + i] = work[W_.w, i]
        for k in range(N_JOINTS):
            mem[M_.prev_A + N_JOINTS * i + k] = work[W_.A + i, k]


@numba.njit(numba.types.int64(_V, _V, _F, _I, _V), cache=True)
def begin(mem, gains, t, stance, res):
    """:func:`period_start` from Python (the controller's Python steps)."""
    period_start(mem, gains, t, stance, res)
    return 0


@numba.njit(numba.types.int64(_V, _V, _M, _V, _F, _I), cache=True)
def commit(mem, res, work, qd, t, stance):
    """:func:`period_commit` from Python (the controller's Python steps)."""
    period_commit(mem, res, work, qd, t, stance)
    return 0


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
def torso_profile(s):
    """(phi, dphi/ds, d2phi/ds2) of the torso offset's profile, s = tau / T: phi(s) = 16 s^2 (1 - s)^2 on (0, 1),
    0 outside (the compiled twin of ``gait_family.torso_profile``, tested against it)."""
    if s <= 0.0 or s >= 1.0:
        return 0.0, 0.0, 0.0
    u = 1.0 - s
    return 16.0 * s * s * u * u, 32.0 * s * u * (u - s), 32.0 * (u * u - 4.0 * s * u + s * s)


#: the offset's direction e (``gait_family.TORSO_DIRECTION``: q3 += lambda phi, q4 -= lambda phi; a compile-time
#: constant)
_TORSO_E = TORSO_DIRECTION.copy()


@numba.njit(cache=True)
def _contact(cons, off, r, rx, ry, g1):
    """Contact row r of the block at ``off`` of ``cons``: C_r (R_x, R_y) + e_r Gamma_1 (``fixed_foot.contact_rows``)."""
    k = off + 3 * r
    return cons[k] * rx + cons[k + 1] * ry + cons[k + 2] * g1


@numba.njit(cache=True)
def _finish(cons, work, res):
    """From x = res[x]: w = D x + v (eq. 17; D = [dq/dp, dq/dtau, dq/dlambda], x = (p'', tau'', lambda'')), Gamma = A w + H (eq. 15), the 17 margins (positive =
    satisfied, the robot's own mu and foot, no controller margin), R = B w + h_b,c, l, the tightest row."""
    x0 = res[R_.x]
    x1 = res[R_.x + 1]
    for i in range(6):
        work[W_.w, i] = work[W_.dq_dp, i] * x0 + work[W_.dq_dtau, i] * x1 + work[W_.v, i]
    x2 = res[R_.x + 2]
    if x2 != 0.0:       # torso modes: + dq/dlambda lambda'' (x2 is 0 outside the torso modes: w as before, bit for bit)
        for i in range(6):
            work[W_.w, i] += work[W_.dq_dlam, i] * x2
    _outputs(cons, work, res)


@numba.njit(cache=True)
def _outputs(cons, work, res):
    """From w = work[w]: Gamma = A w + H (eq. 15), the 17 margins, R, l, the tightest row (of :func:`_finish`;
    also the whole-body stage's, ``wbc_kernels``)."""
    for i in range(6):
        s = work[W_.H, i]
        for k in range(6):
            s += work[W_.A + i, k] * work[W_.w, k]
        work[W_.torque, i] = s
    rx = res[R_.h_b_c]
    ry = res[R_.h_b_c + 1]
    for k in range(6):
        rx += work[W_.B, k] * work[W_.w, k]
        ry += work[W_.B + 1, k] * work[W_.w, k]
    res[R_.reaction] = rx
    res[R_.reaction + 1] = ry
    g1 = work[W_.torque, 0]
    mg = res[R_.margins:R_.margins + N_ROWS]
    for r in range(5):
        mg[r] = -_contact(cons, C_.true_rows, r, rx, ry, g1)
    for i in range(6):
        mg[5 + i] = cons[C_.torque_max + i] - work[W_.torque, i]
        mg[11 + i] = work[W_.torque, i] - cons[C_.torque_min + i]
    best = 0
    bv = mg[0] / cons[C_.row_scale]
    for i in range(1, N_ROWS):
        val = mg[i] / cons[C_.row_scale + i]
        if val < bv:
            bv = val
            best = i
    res[R_.tightest] = best
    res[R_.zmp] = g1 / ry if ry != 0.0 else math.nan


@numba.njit(cache=True)
def period_step(coef, inner, centers, ti, tf, q, qd, gains, cons, mem, G, h, work, res):
    """The period up to the QP decision from the period's start in res (:func:`period_start`); the memory is
    read (observer), not changed. Returns FEASIBLE, NEEDS_QP or NONFINITE (see :func:`step`)."""
    fam = np.empty((6, 6))
    _family(coef, inner, centers, res[R_.p], res[R_.tau], fam)
    p_dot = res[R_.p_dot]
    tau_dot = res[R_.tau_dot]
    kp_, kv_ = gains[G_.Kp], gains[G_.Kv]
    torso = gains[G_.torso] != 0.0
    maxerr = 0.0
    if torso:
        # torso modes (gait_family.with_torso, eq11_torso): q_d += lambda phi e, dq/dtau += lambda phi'/T e,
        # d2q/dtau2 += lambda phi''/T^2 e, dq/dlambda = phi e, d2q/dtau dlambda = phi'/T e; eq. (11) gains
        # dq/dlambda lambda' in q_d' and 2 d2q/dtau dlambda tau' lambda' in the drift
        T = gains[G_.T]
        lam, lam_dot = res[R_.lam], res[R_.lam + 1]
        phi, dphi, d2phi = torso_profile(res[R_.tau] / T)
        for i in range(6):
            ei = _TORSO_E[i]
            dq_dtau = fam[2, i] + (lam * dphi / T) * ei
            dq_dlam = phi * ei
            qd_d = fam[1, i] * p_dot + dq_dtau * tau_dot + dq_dlam * lam_dot
            drift = (fam[3, i] * p_dot ** 2 + (fam[4, i] + (lam * d2phi / (T * T)) * ei) * tau_dot ** 2
                     + 2.0 * fam[5, i] * p_dot * tau_dot + 2.0 * ((dphi / T) * ei) * tau_dot * lam_dot)
            e = (fam[0, i] + (lam * phi) * ei) - q[i]
            work[W_.e, i] = e
            work[W_.v, i] = drift + kv_ * (qd_d - qd[i]) + kp_ * e
            work[W_.dq_dp, i] = fam[1, i]
            work[W_.dq_dtau, i] = dq_dtau
            work[W_.dq_dlam, i] = dq_dlam
            if abs(e) > maxerr or e != e:
                maxerr = abs(e)
        xs2 = -gains[G_.kv_lam] * lam_dot - gains[G_.kp_lam] * lam
        res[R_.x_star + 2] = xs2
        res[R_.x + 2] = xs2
    else:
        for i in range(6):
            qd_d = fam[1, i] * p_dot + fam[2, i] * tau_dot
            drift = fam[3, i] * p_dot ** 2 + fam[4, i] * tau_dot ** 2 + 2.0 * fam[5, i] * p_dot * tau_dot
            e = fam[0, i] - q[i]
            work[W_.e, i] = e
            work[W_.v, i] = drift + kv_ * (qd_d - qd[i]) + kp_ * e
            work[W_.dq_dp, i] = fam[1, i]
            work[W_.dq_dtau, i] = fam[2, i]
            if abs(e) > maxerr or e != e:
                maxerr = abs(e)
    res[R_.max_error] = maxerr
    xs0 = -gains[G_.kv] * p_dot + gains[G_.kp] * (gains[G_.p_d] - res[R_.p])
    xs1 = gains[G_.kv] * (1.0 - tau_dot)
    res[R_.x_star] = xs0
    res[R_.x_star + 1] = xs1
    res[R_.x] = xs0
    res[R_.x + 1] = xs1
    # eq. (1) and the reaction rows: the locked-root chain (joints 0-2 at rest), q1..q6
    A = np.empty((6, 6))
    H = np.empty(6)
    B = np.empty((3, 6))
    hb = np.empty(3)
    jp = np.empty(9)
    pk.fixed_root_terms(ti, tf, q, qd, gains[G_.observer_height], A, H, B, hb, jp)
    work[W_.A:W_.A + 6] = A
    work[W_.H] = H
    work[W_.B:W_.B + 3] = B
    res[R_.h_b:R_.h_b + 3] = hb
    hbc = np.empty(3)
    hbc[:] = hb
    F = 0.0
    if gains[G_.momentum] != 0.0:
        # the momentum observer's shift of (R_x, R_y), from the compiled sensing pipeline
        # (pipeline_kernels; written into res before the period)
        F = res[R_.sens_force]
        hbc[0] = hb[0] + res[R_.sens_dR]
        hbc[1] = hb[1] + res[R_.sens_dR + 1]
    elif gains[G_.observer] != 0.0:
        mode = res[R_.obs_mode]
        if mode == OBS_KEEP:
            F = mem[M_.force]
        elif mode == OBS_RESIDUAL:
            dt = res[R_.obs_dt]
            num = 0.0
            nrm = 0.0
            for i in range(6):
                r = 0.0
                for k in range(6):
                    r += mem[M_.prev_A + 6 * i + k] * ((qd[k] - mem[M_.prev_qd + k]) / dt - mem[M_.prev_w + k])
                num += jp[3 + i] * r
                nrm += jp[3 + i] * jp[3 + i]
            F = num / nrm if nrm > 1e-12 else 0.0
        # h_b,c = h_b + B A^-1 j6 F - Jb F
        L = np.empty((6, 6))
        y = np.empty((1, 6))
        if not pk.cholesky(A, L):
            return NONFINITE
        for k in range(6):
            y[0, k] = jp[3 + k] * F
        pk.chol_solve_rows(L, y)
        for r in range(3):
            s = 0.0
            for k in range(6):
                s += B[r, k] * y[0, k]
            hbc[r] = hb[r] + (s - jp[r] * F)
    res[R_.h_b_c:R_.h_b_c + 3] = hbc
    res[R_.force] = F
    for i in range(6):
        if not (math.isfinite(work[W_.v, i]) and math.isfinite(work[W_.dq_dp, i])
                and math.isfinite(work[W_.dq_dtau, i])):
            return NONFINITE
        if torso and not math.isfinite(work[W_.dq_dlam, i]):
            return NONFINITE
    if torso and not math.isfinite(res[R_.x_star + 2]):
        return NONFINITE
    for r in range(3):
        if not math.isfinite(hbc[r]):
            return NONFINITE
    ap = gains[G_.adapt_p] != 0.0
    at = gains[G_.adapt_tau] != 0.0
    al = gains[G_.adapt_lam] != 0.0
    if not (ap or at or al):
        _finish(cons, work, res)
        return FEASIBLE
    # eq. (21): the 17 rows with the controller's margins, with (rows 0-16) and without (17-33) the estimate
    Aq = np.empty((N_ROWS, 6))
    bq = np.empty(N_ROWS)
    b0 = np.empty(5)
    for r in range(5):
        for k in range(6):
            Aq[r, k] = _contact(cons, C_.qp_rows, r, B[0, k], B[1, k], A[0, k])
        bq[r] = _contact(cons, C_.qp_rows, r, hbc[0], hbc[1], H[0]) + cons[C_.margin + r]
        if gains[G_.momentum] != 0.0:
            bq[r] += res[R_.sens_margin + r]     # the estimate's spread, its rows only
        b0[r] = _contact(cons, C_.qp_rows, r, hb[0], hb[1], H[0]) + cons[C_.margin + r]
    for i in range(6):
        for k in range(6):
            Aq[5 + i, k] = A[i, k]
            Aq[11 + i, k] = -A[i, k]
        bq[5 + i] = (H[i] - cons[C_.torque_max + i]) + cons[C_.margin + 5 + i]
        bq[11 + i] = (cons[C_.torque_min + i] - H[i]) + cons[C_.margin + 11 + i]
    for r in range(N_ROWS):
        ad0 = 0.0
        ad1 = 0.0
        av = 0.0
        for k in range(6):
            ad0 += Aq[r, k] * work[W_.dq_dp, k]
            ad1 += Aq[r, k] * work[W_.dq_dtau, k]
            av += Aq[r, k] * work[W_.v, k]
        G[r, 0] = ad0
        G[r, 1] = ad1
        G[N_ROWS + r, 0] = ad0
        G[N_ROWS + r, 1] = ad1
        if torso:               # the third column: A_q dq/dlambda
            ad2 = 0.0
            for k in range(6):
                ad2 += Aq[r, k] * work[W_.dq_dlam, k]
            G[r, 2] = ad2
            G[N_ROWS + r, 2] = ad2
        h[r] = -(av + bq[r])
        h[N_ROWS + r] = -(av + (b0[r] if r < 5 else bq[r]))
    dt = gains[G_.dt]
    p, p_dot_ = res[R_.p], res[R_.p_dot]
    G[2 * N_ROWS, 0] = 0.5 * dt * dt
    G[2 * N_ROWS, 1] = 0.0
    G[2 * N_ROWS + 1, 0] = -0.5 * dt * dt
    G[2 * N_ROWS + 1, 1] = 0.0
    G[2 * N_ROWS + 2, 0] = 0.0
    G[2 * N_ROWS + 2, 1] = -dt
    h[2 * N_ROWS] = gains[G_.p_max] - p - p_dot_ * dt
    h[2 * N_ROWS + 1] = p + p_dot_ * dt - gains[G_.p_min]
    h[2 * N_ROWS + 2] = tau_dot - gains[G_.tau_dot_min]
    if torso:
        return _torso_rows_and_decision(gains, cons, work, res, G, h, ap, at, al)
    for r in range(QP_ROWS):
        if not (math.isfinite(G[r, 0]) and math.isfinite(G[r, 1]) and math.isfinite(h[r])):
            return NONFINITE
    # x* feasible on the adapted columns? (exact_kernels.early_out's expression; a fixed parameter stays at x*
    # and moves to the right-hand side)
    v = np.empty(QP_ROWS)
    if ap and at:
        feasible = rows_and_decision(G, h, res[R_.x_star:R_.x_star + 2], v)
    else:
        col = 0 if ap else 1
        fixed = 1 - col
        Gr = np.empty((QP_ROWS, 1))
        hr = np.empty(QP_ROWS)
        xr = np.empty(1)
        xr[0] = res[R_.x_star + col]
        for r in range(QP_ROWS):
            Gr[r, 0] = G[r, col]
            hr[r] = h[r] - G[r, fixed] * res[R_.x_star + fixed]
        feasible = rows_and_decision(Gr, hr, xr, v)
    if not feasible:
        return NEEDS_QP
    _finish(cons, work, res)
    return FEASIBLE


@numba.njit(cache=True)
def _torso_rows_and_decision(gains, cons, work, res, G, h, ap, at, al):
    """Modes lambda and all, after the 37 rows of :func:`period_step` (their third column written):
    the third column of the three range rows (0) and the four torso rows, lambda + lambda' dt + lambda'' dt^2/2
    within +-lambda_max and lambda' + lambda'' dt within +-lambda_dot_max (``controller._qp_rows``' order), then
    the early-out on the adapted columns (a fixed parameter stays at x* and moves to the right-hand side,
    h - (G_0 x*_0 + G_1 x*_1) in mode lambda). G (TORSO_QP_ROWS, 3). Returns FEASIBLE (outputs done), NEEDS_QP
    or NONFINITE."""
    dt = gains[G_.dt]
    hh = 0.5 * dt * dt
    lam, lam_dot = res[R_.lam], res[R_.lam + 1]
    b = 2 * N_ROWS
    for r in range(3):
        G[b + r, 2] = 0.0
    for r in range(3, 3 + TORSO_ROWS):
        G[b + r, 0] = 0.0
        G[b + r, 1] = 0.0
    G[b + 3, 2] = hh
    G[b + 4, 2] = -hh
    G[b + 5, 2] = dt
    G[b + 6, 2] = -dt
    h[b + 3] = gains[G_.lam_max] - lam - lam_dot * dt
    h[b + 4] = lam + lam_dot * dt + gains[G_.lam_max]
    h[b + 5] = gains[G_.lam_dot_max] - lam_dot
    h[b + 6] = lam_dot + gains[G_.lam_dot_max]
    m = G.shape[0]
    for r in range(m):
        if not (math.isfinite(G[r, 0]) and math.isfinite(G[r, 1]) and math.isfinite(G[r, 2])
                and math.isfinite(h[r])):
            return NONFINITE
    v = np.empty(m)
    xs = res[R_.x_star:R_.x_star + 3]
    if ap and at and al:
        feasible = rows_and_decision(G, h, xs, v)
    else:
        na = int(ap) + int(at) + int(al)
        cols = np.empty(na, dtype=np.int64)
        fixed = np.empty(3 - na, dtype=np.int64)
        ia = 0
        jf = 0
        for c in range(3):
            if (ap, at, al)[c]:
                cols[ia] = c
                ia += 1
            else:
                fixed[jf] = c
                jf += 1
        Gr = np.empty((m, na))
        hr = np.empty(m)
        xr = np.empty(na)
        for j in range(na):
            xr[j] = xs[cols[j]]
        for r in range(m):
            for j in range(na):
                Gr[r, j] = G[r, cols[j]]
            s = G[r, fixed[0]] * xs[fixed[0]]
            for j in range(1, 3 - na):
                s += G[r, fixed[j]] * xs[fixed[j]]
            hr[r] = h[r] - s
        feasible = rows_and_decision(Gr, hr, xr, v)
    if not feasible:
        return NEEDS_QP
    _finish(cons, work, res)
    return FEASIBLE


@numba.njit(numba.types.int64(_C4, _V, _V, _VI, _V, _V, _V, _F, _I, _V, _V, _V, _M, _V, _M, _V), cache=True)
def step(coef, inner, centers, ti, tf, q, qd, t, stance, gains, cons, mem, G, h, work, res):
    """One control period at time t [s] in ``stance`` up to the QP decision (module docstring). Returns
    FEASIBLE (x = x*, every output computed, the memory committed), NEEDS_QP (G, h filled; solve, put x
    in res, call :func:`finish`) or NONFINITE (use the reference path; the memory is unchanged).
    G (QP_ROWS, 2), h (QP_ROWS,) are filled whenever a parameter is adapted; in modes lambda and all
    G (TORSO_QP_ROWS, 3), h (TORSO_QP_ROWS,): x = (p'', tau'', lambda'')."""
    period_start(mem, gains, t, stance, res)
    code = period_step(coef, inner, centers, ti, tf, q, qd, gains, cons, mem, G, h, work, res)
    if code == FEASIBLE:
        period_commit(mem, res, work, qd, t, stance)
    return code


#: the outputs of a period for the decision x = res[x] (w, torque, margins, reaction, l, tightest row), the
#: memory untouched: the compiled loop's QP periods, committed with the period
period_outputs = _finish


@numba.njit(numba.types.int64(_V, _V, _M, _V, _V, _F, _I), cache=True)
def finish(cons, mem, work, res, qd, t, stance):
    """After a QP: w, torque, margins, reaction, l and the tightest row for x = res[x]; the memory is
    committed."""
    _finish(cons, work, res)
    period_commit(mem, res, work, qd, t, stance)
    return 0


@numba.njit(cache=True, nogil=True)
def loop_period(qp_given, qp_x, coef, inner, centers, ti, tf, q, qd, t, stance, gains, cons, mem, G, h, work,
                res):
    """A compiled closed loop's controller for one period (``loop_kernels``, ``mujoco_loop_kernels``): with
    ``qp_given`` the QP period the last call handed back (its ``res`` and ``work`` as they were left) takes the
    decision ``qp_x`` (p'', tau''; modes lambda and all: and lambda'') and its outputs, FEASIBLE; otherwise
    the period's start and step (:func:`period_step`'s code: FEASIBLE, NEEDS_QP with G, h filled, ...). The
    memory is committed by the caller with the period."""
    if qp_given:
        for k in range(qp_x.shape[0]):
            res[R_.x + k] = qp_x[k]
        _finish(cons, work, res)
        return FEASIBLE
    period_start(mem, gains, t, stance, res)
    return period_step(coef, inner, centers, ti, tf, q, qd, gains, cons, mem, G, h, work, res)
