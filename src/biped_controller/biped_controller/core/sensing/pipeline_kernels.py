"""Compiled (numba) sensing pipeline of one control period: the Kalman joint-state estimator and the
generalized-momentum observer, for the controller's compiled period.

Pure numerics, no ROS, no side effects on import (load it through ``numba_cache.load``, as
``pipeline_compiled`` does). The same equations, units and order as the Python cores, which stay the
oracle of the tests (``pipeline.SensingPipeline`` on ``estimation.JointStateEstimator`` and
``momentum_observer.MomentumObserver``, Pinocchio):

* estimator time update over dt [s] with a = A(x_q)^-1 (Gamma - H(x_q, x_q') + r) (the model's
  acceleration under the torque applied, Gamma = the sent torque clipped to the limits, relabelled
  -Gamma[::-1] if it was sent for the other stance; r the observer's last disturbance):
  x_q += x_q' dt + a dt^2 / 2, x_q' += a dt, P <- F P F^T + Q (``estimation`` module docstring);
* measurement update with z = (q_enc, q'_rate [, pitch] [, pitch rate]), H = [[I, 0], [0, I] [, [1 1 1 0..]]
  [, [0.. | 1 1 1 0..]]], R = diag(var_q, var_qd [, var_pitch] [, var_pitch_rate]):
  K = P H^T S^-1 (S = H P H^T + R, Cholesky),
  x += K (z - H x), P <- (I - K H) P (I - K H)^T + K R K^T (Joseph form, the Python core); here as
  sequential scalar updates, one measurement at a time (R diagonal: the same estimate and covariance,
  round-off apart), k = P h^T / (h P h^T + r), x += k (z - h x), P -= k (P h^T)^T;
* a sensed touchdown between the two (the sample's stance differs from the estimate's) returns
  NEEDS_IMPACT after the time update: the caller applies the model's flat-foot impact map
  (``predictor.flat_foot_impact``, Python: once per step) and calls :func:`sense_finish`;
* momentum observer (De Luca & Mattone): p = A q', beta = g(q) - C(q, q')^T q',
  I += (Gamma + r) dt - (beta_prev + beta) dt / 2, r = K (p - p(0) - I); restart (p(0) = p, r = J_j^T W of
  the previous wrench) at the first sample, at a stance change or without a previous torque. Here
  C^T q' is the gradient of the kinetic energy T = q'^T A(q) q' / 2 at fixed q' (the identity
  (C^T q')_i = q'^T (dA/dq_i) q' / 2 holds for every C with A' = C + C^T), in closed form on the planar
  chain: for hinge i with origin velocity u_i and the bodies b of its subtree (mass m_b, centre-of-mass
  velocity v_b), dT/dq_i = sum_b m_b v_b . perp(v_b - u_i) = sum_b m_b (v_bx u_iz - v_bz u_ix),
  perp(x, z) = (-z, x) (a body's angular velocity does not depend on q in the plane). g = H(q, 0);
* the torso wrench W = (J_j J_j^T)^-1 J_j r (the least-squares solution of J_j^T W = r, J_j (3 x 6) of
  full row rank: Pinocchio's pseudo-inverse in the oracle), cov_W = J^+ (K^2 A cov_q' A) J^+T +
  diag((W_restart e^{-K (t - t_restart)})^2), S = (B A^-1 J_j^T - J_r^T)[:2], dR = S W, cov_dR = S cov_W S^T,
  and the QP's contact rows widened by k sqrt(C_r cov_dR C_r^T) (``controller._observe_momentum``);
* with the legs' model-error estimator on (``SCONF.me``), right after the observer on the same sample and
  the observer's A, B, H and J_j: ``model_error_kernels.update`` (``model_error.LegModelError.update``'s
  maths, its regressor in closed form), with the inputs ``pipeline_compiled`` gave the Python estimator:
  restarted = (the time since the observer's restart is 0), the torque applied and the interval only when
  not restarted, not the first sample and a decision recorded (else none and 0), no update within the
  settling time after the observer's restart (``model_error_settle``); its torso wrench, dR,
  cov_dR and the rows' widening k sqrt(C_r cov_dR C_r^T) replace the observer's in what the QP reads
  (``into_res``) once it has taken a sample.

Arrays (float64, C order): ``conf`` (``pipeline_layout.SCONF``), ``s`` (``SENS``), ``ti``/``tf`` the
fixed-foot tree (``fast_engine.fixed_foot_tree``).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_model import numba_cache
from biped_model import planar_kernels as pk
from biped_controller.core.sensing import model_error_kernels as mek
from biped_controller.core.sensing.pipeline_layout import N_LEG_PARAMETERS, N_TREE_BODIES, S_, SC_

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

# return codes of ``sense``
DONE, NEEDS_IMPACT, SINGULAR = 0, 1, 2
N = 6
NX = 12

_V = numba.types.Array(numba.types.float64, 1, "C")
_VI = numba.types.Array(numba.types.int64, 1, "C")
_F = numba.types.float64
_I = numba.types.int64


# ------------------------------------------------------------------------------------------ model terms
@numba.njit(cache=True)
def _terms(ti, tf, q, qd, A, H):
    """A (6, 6), H (6,) of the locked-root chain at (q, q') (``planar_kernels.fixed_root_terms``' maths)."""
    B = np.empty((3, 6))
    hb = np.empty(3)
    jp = np.empty(9)
    pk.fixed_root_terms(ti, tf, q, qd, 0.0, A, H, B, hb, jp)


@numba.njit(cache=True)
def momentum_terms(ti, tf, q, qd, height, A, B, beta, J, H):
    """The observer's model terms at (q, q') from one kinematics pass: A (6, 6), B (3, 6) (root rows of the
    mass matrix), H (6,) = h(q, q') (so A, H also serve the estimator's next time update at this state),
    beta (6,) = g(q) - C(q, q')^T q' (module docstring; g_i = g0 sum_b m_b (x_b - x_i) over the bodies of
    hinge i's subtree, x_i its origin, g0 gravity along -z), J (3, 9) rows x, z velocity of the torso point
    ``height`` [m] above the hip and the torso's pitch rate (all 9 coordinates of the locked-root chain)."""
    n = ti[0]
    K, M, L, R, U, Cm = pk.workspace(n)
    qf = np.zeros(n)
    vf = np.zeros(n)
    for i in range(N):
        qf[3 + i] = q[i]
        vf[3 + i] = qd[i]
    h = U[0]
    pk.kinematics(ti, tf, qf, vf, K)
    pk.composite_mass_bias(ti, tf, K, M, h, Cm)            # M(q), h(q, q')
    for i in range(N):
        H[i] = h[3 + i]
        for k in range(N):
            A[i, k] = M[3 + i, 3 + k]
    for r in range(3):
        for k in range(N):
            B[r, k] = M[r, 3 + k]
    Jt = R[7:10]
    pk.point_jacobian(ti, K, ti[2], 0.0, height, Jt)
    for r in range(3):
        for k in range(n):
            J[r, k] = Jt[r, k]
    # g(q) and C^T q' = dT/dq (module docstring), both over each hinge's subtree
    g0 = tf[0]
    nb = ti[1]
    ob = pk.HEADER_F + 2 * n
    ctq = np.zeros(n)
    grav = np.zeros(n)
    for b in range(nb):
        j = ti[pk.HEADER_I + 2 * n + b]
        m = tf[ob + b]
        px, _, rx, rz = pk.frame_point(K, j, tf[ob + nb + b], tf[ob + 2 * nb + b])
        om = K[pk.K_OM, j]
        vx = K[pk.K_VX, j] - om * rz
        vz = K[pk.K_VZ, j] + om * rx
        i = j
        while i >= 0:                            # every hinge whose subtree holds body b
            if pk.joint_type(ti, i) == pk.REV:
                ctq[i] += m * (vx * K[pk.K_VZ, i] - vz * K[pk.K_VX, i])
                grav[i] += m * (px - K[pk.K_PX, i])
            i = pk.parent(ti, i)
    for i in range(N):
        beta[i] = g0 * grav[3 + i] - ctq[3 + i]


# ------------------------------------------------------------------------------------------ the estimator
@numba.njit(cache=True)
def _est_reset(conf, s, q, qd):
    """x = (q, q' from the rate sensor, or 0 with variance 1e2 without one), P diagonal."""
    vq = conf[SC_.var_q]
    use_qd = conf[SC_.var_qd] >= 0.0
    vqd = max(conf[SC_.var_qd], 1e-30) if use_qd else 1e2
    for i in range(NX * NX):
        s[S_.P + i] = 0.0
    for i in range(N):
        s[S_.x + i] = q[i]
        s[S_.x + N + i] = qd[i] if use_qd else 0.0
        s[S_.P + i * NX + i] = vq
        s[S_.P + (N + i) * NX + N + i] = vqd


@numba.njit(cache=True)
def _est_predict(conf, s, dt, a):
    """Time update over dt [s] with the acceleration a held (module docstring)."""
    for i in range(N):
        q = s[S_.x + i]
        qd = s[S_.x + N + i]
        s[S_.x + i] = q + qd * dt + 0.5 * a[i] * dt * dt
        s[S_.x + N + i] = qd + a[i] * dt
    P = s[S_.P:S_.P + NX * NX].reshape((NX, NX))
    # F P F^T with F = [[I, dt I], [0, I]]: rows then columns i <- i + dt (i + 6) for i < 6
    T = P.copy()
    for i in range(N):
        for c in range(NX):
            T[i, c] = P[i, c] + dt * P[N + i, c]
    for r in range(NX):
        for i in range(N):
            P[r, i] = T[r, i] + dt * T[r, N + i]
        for i in range(N, NX):
            P[r, i] = T[r, i]
    s2 = conf[SC_.sigma_acc] ** 2
    q11 = 0.25 * dt ** 4 * s2
    q12 = 0.5 * dt ** 3 * s2
    q22 = dt * dt * s2
    for i in range(N):
        P[i, i] += q11
        P[i, N + i] += q12
        P[N + i, i] += q12
        P[N + i, N + i] += q22


@numba.njit(cache=True)
def _scalar_update(P, x, c, z, rv, ph):
    """One scalar measurement z = h x + noise (variance rv), h = e_c (c >= 0), e_0 + e_1 + e_2 (c = -1: the
    torso pitch) or e_6 + e_7 + e_8 (c = -2: its rate): k = P h^T / (h P h^T + rv), x += k (z - h x),
    P <- P - k (P h^T)^T (symmetric by construction). False if h P h^T + rv is not > 0."""
    o = 0 if c == -1 else N
    for r in range(NX):
        ph[r] = P[r, c] if c >= 0 else P[r, o] + P[r, o + 1] + P[r, o + 2]
    sv = (ph[c] if c >= 0 else ph[o] + ph[o + 1] + ph[o + 2]) + rv
    if not sv > 0.0:
        return False
    inv = 1.0 / sv
    inn = z - (x[c] if c >= 0 else x[o] + x[o + 1] + x[o + 2])
    for r in range(NX):
        x[r] += ph[r] * inv * inn
    for r in range(NX):
        kr = ph[r] * inv
        for cc in range(r, NX):
            v = P[r, cc] - kr * ph[cc]
            P[r, cc] = v
            P[cc, r] = v
    return True


@numba.njit(cache=True)
def _est_update(conf, s, q, qd, pitch, pitch_rate):
    """Measurement update (module docstring), as sequential scalar updates (R is diagonal, so this is the
    batch update K = P H^T S^-1 of the Python core, round-off apart): encoders, rates, pitch, pitch rate.
    False if a variance is not positive."""
    P = s[S_.P:S_.P + NX * NX].reshape((NX, NX))
    x = s[S_.x:S_.x + NX]
    ph = np.empty(NX)
    for i in range(N):
        if not _scalar_update(P, x, i, q[i], conf[SC_.var_q], ph):
            return False
    if conf[SC_.var_qd] >= 0.0:
        for i in range(N):
            if not _scalar_update(P, x, N + i, qd[i], max(conf[SC_.var_qd], 1e-30), ph):
                return False
    if conf[SC_.var_pitch] >= 0.0 and math.isfinite(pitch):
        if not _scalar_update(P, x, -1, pitch, max(conf[SC_.var_pitch], 1e-30), ph):
            return False
    if conf[SC_.var_pitch_rate] >= 0.0 and math.isfinite(pitch_rate):
        if not _scalar_update(P, x, -2, pitch_rate, max(conf[SC_.var_pitch_rate], 1e-30), ph):
            return False
    return True


# ------------------------------------------------------------------------------------------ the observer
@numba.njit(cache=True)
def _observer(ti, tf, conf, s, q, qd, stance, restart, applied, dt, cov_qd, A, B, J):
    """One sample of the momentum observer (module docstring); outputs into s (W, cov_W, dR, cov_dR, S,
    extra), and the model terms it used into A (6, 6), B (3, 6), J (3, 9) (``momentum_terms``; H into
    s's H_est). False on a singular model."""
    Kg = conf[SC_.K]
    beta = np.empty(N)
    H = s[S_.H_est:S_.H_est + N]
    momentum_terms(ti, tf, q, qd, conf[SC_.height], A, B, beta, J, H)
    for i in range(N):
        for k in range(N):
            s[S_.A_est + N * i + k] = A[i, k]
    p = np.empty(N)
    for i in range(N):
        v = 0.0
        for k in range(N):
            v += A[i, k] * qd[k]
        p[i] = v
    Jj = np.empty((3, N))
    for a in range(3):
        for k in range(N):
            Jj[a, k] = J[a, 3 + k]
    if restart:
        started = s[S_.mo_started] != 0.0
        for i in range(N):
            r0 = 0.0
            if started:
                for a in range(3):
                    r0 += Jj[a, i] * s[S_.W + a]
            s[S_.p0 + i] = p[i]
            s[S_.I + i] = -r0 / Kg
            s[S_.r + i] = r0
        for a in range(3):
            s[S_.W_restart + a] = s[S_.W + a] if started else 0.0
        s[S_.since] = 0.0
        s[S_.mo_started] = 1.0
    else:
        for i in range(N):
            s[S_.I + i] = (s[S_.I + i] + (applied[i] + s[S_.r + i]) * dt) - 0.5 * (s[S_.beta + i] + beta[i]) * dt
        for i in range(N):
            s[S_.r + i] = Kg * (p[i] - s[S_.p0 + i] - s[S_.I + i])
        s[S_.since] += dt
    for i in range(N):
        s[S_.beta + i] = beta[i]
    s[S_.mo_stance] = stance
    # W = (Jj Jj^T)^-1 Jj r: the pseudo-inverse of Jj^T (full column rank)
    G = np.empty((3, 3))
    for a in range(3):
        for c in range(3):
            v = 0.0
            for k in range(N):
                v += Jj[a, k] * Jj[c, k]
            G[a, c] = v
    Lg = np.empty((3, 3))
    if not pk.cholesky(G, Lg):
        return False
    pinvT = np.empty((N, 3))                          # rows: columns of Jj, solved
    for k in range(N):
        for a in range(3):
            pinvT[k, a] = Jj[a, k]
    pk.chol_solve_rows(Lg, pinvT)                     # pinv[a, k] = pinvT[k, a]
    W = np.zeros(3)
    for a in range(3):
        for k in range(N):
            W[a] += pinvT[k, a] * s[S_.r + k]
        s[S_.W + a] = W[a]
    # cov_r = K^2 A cov A, cov_W = pinv cov_r pinv^T (+ the carried wrench's decaying square)
    T1 = np.empty((N, N))
    for i in range(N):
        for k in range(N):
            v = 0.0
            for j in range(N):
                v += A[i, j] * cov_qd[j, k]
            T1[i, k] = v
    covr = np.empty((N, N))
    k2 = Kg * Kg
    for i in range(N):
        for k in range(N):
            v = 0.0
            for j in range(N):
                v += T1[i, j] * A[j, k]
            covr[i, k] = k2 * v
    T2 = np.empty((3, N))
    for a in range(3):
        for k in range(N):
            v = 0.0
            for j in range(N):
                v += pinvT[j, a] * covr[j, k]
            T2[a, k] = v
    covW = np.empty((3, 3))
    for a in range(3):
        for c in range(3):
            v = 0.0
            for k in range(N):
                v += T2[a, k] * pinvT[k, c]
            covW[a, c] = v
    dec = math.exp(-Kg * s[S_.since])
    for a in range(3):
        wr = s[S_.W_restart + a] * dec
        covW[a, a] += wr * wr
    # S = (B A^-1 Jj^T - Jr^T)[:2]
    La = np.empty((N, N))
    if not pk.cholesky(A, La):
        return False
    Y = Jj.copy()                                     # rows: A^-1 Jj[a]
    pk.chol_solve_rows(La, Y)
    Sm = np.empty((2, 3))
    for a in range(2):
        for c in range(3):
            v = 0.0
            for k in range(N):
                v += B[a, k] * Y[c, k]
            Sm[a, c] = v - J[c, a]
    dR = np.zeros(2)
    covdR = np.zeros((2, 2))
    for a in range(2):
        for c in range(3):
            dR[a] += Sm[a, c] * W[c]
    for a in range(2):
        for b in range(2):
            v = 0.0
            for c in range(3):
                for e in range(3):
                    v += Sm[a, c] * covW[c, e] * Sm[b, e]
            covdR[a, b] = v
    for a in range(3):
        for c in range(3):
            s[S_.cov_W + 3 * a + c] = covW[a, c]
    for a in range(2):
        s[S_.dR + a] = dR[a]
        for c in range(2):
            s[S_.cov_dR + 2 * a + c] = covdR[a, c]
        for c in range(3):
            s[S_.S + 3 * a + c] = Sm[a, c]
    for row in range(5):
        cx = conf[SC_.qp_rows + 2 * row]
        cy = conf[SC_.qp_rows + 2 * row + 1]
        var = cx * (covdR[0, 0] * cx + covdR[0, 1] * cy) + cy * (covdR[1, 0] * cx + covdR[1, 1] * cy)
        s[S_.extra + row] = conf[SC_.confidence] * math.sqrt(max(var, 0.0))
    return True


# ------------------------------------------------------------------------------------------ the legs' error
@numba.njit(cache=True)
def _model_error(ti, tf, conf, s, q, qd, A, B, J, cov_qd, has_applied, applied, dt):
    """The legs' model-error estimator on the observer's sample (module docstring): its state and outputs
    are s's ``me_*`` fields. False if A is not positive definite."""
    npar = N_LEG_PARAMETERS
    Jj = np.empty((3, N))
    for a in range(3):
        for k in range(N):
            Jj[a, k] = J[a, 3 + k]
    Rres = np.zeros((3, 3))
    Rhold = np.zeros((3, 3))
    for a in range(3):
        Rres[a, a] = conf[SC_.me_var_res]
        Rhold[a, a] = conf[SC_.me_var_hold]
    D = conf[SC_.me_D:SC_.me_D + 2 * N_TREE_BODIES * npar].reshape((2 * N_TREE_BODIES, npar))
    ok = mek.update(ti, tf, D, q, qd, A, B, s[S_.H_est:S_.H_est + N], Jj, s[S_.r:S_.r + N],
                    s[S_.S:S_.S + 6].reshape((2, 3)), s[S_.cov_W:S_.cov_W + 9].reshape((3, 3)),
                    s[S_.W_restart:S_.W_restart + 3], s[S_.since], cov_qd, conf[SC_.K], dt, s[S_.since] == 0.0,
                    has_applied, applied, Rres, Rhold, conf[SC_.me_settle], s[S_.me_theta:S_.me_theta + npar],
                    s[S_.me_P:S_.me_P + npar * npar].reshape((npar, npar)),
                    s[S_.me_Yf:S_.me_Yf + npar * npar].reshape((npar, npar)),
                    s[S_.me_Yprev:S_.me_Yprev + npar * npar].reshape((npar, npar)),
                    s[S_.me_W_restart:S_.me_W_restart + 3], s[S_.me_last_torque:S_.me_last_torque + N],
                    s[S_.me_flags:S_.me_flags + 3], s[S_.me_W:S_.me_W + 3],
                    s[S_.me_cov_W:S_.me_cov_W + 9].reshape((3, 3)), s[S_.me_dR:S_.me_dR + 2],
                    s[S_.me_cov_dR:S_.me_cov_dR + 4].reshape((2, 2)))
    if not ok:
        return False
    c00, c01 = s[S_.me_cov_dR], s[S_.me_cov_dR + 1]
    c10, c11 = s[S_.me_cov_dR + 2], s[S_.me_cov_dR + 3]
    for row in range(5):
        cx = conf[SC_.qp_rows + 2 * row]
        cy = conf[SC_.qp_rows + 2 * row + 1]
        var = cx * (c00 * cx + c01 * cy) + cy * (c10 * cx + c11 * cy)
        s[S_.me_extra + row] = conf[SC_.confidence] * math.sqrt(max(var, 0.0))
    return True


# ------------------------------------------------------------------------------------------ one period
@numba.njit(cache=True)
def _elapsed_applied(conf, s, t, stance, applied):
    """dt [s] from integer nanoseconds since the last decision, and the torque it applied (clipped,
    relabelled when it was sent for the other stance than the state's at the last sample)."""
    dt = (round(t * 1e9) - round(s[S_.t_prev] * 1e9)) * 1e-9
    same = int(s[S_.told_prev]) == int(s[S_.stance])
    for i in range(N):
        j = i if same else N - 1 - i
        g = min(max(s[S_.torque_prev + j], conf[SC_.torque_min + j]), conf[SC_.torque_max + j])
        applied[i] = g if same else -g
    return dt


@numba.njit(_I(_VI, _V, _V, _V, _F, _V, _V, _I, _F, _F, _V, _V), cache=True)
def sense_finish(ti, tf, conf, s, t, q, qd, stance, pitch, pitch_rate, q_out, qd_out):
    """The rest of :func:`sense` after the time update (and the touchdown's impact map)."""
    first = s[S_.started] == 0.0
    est = conf[SC_.estimator] != 0.0
    if est:
        if first:
            _est_reset(conf, s, q, qd)
        elif not _est_update(conf, s, q, qd, pitch, pitch_rate):
            return SINGULAR
        for i in range(N):
            q_out[i] = s[S_.x + i]
            qd_out[i] = s[S_.x + N + i]
    else:
        for i in range(N):
            q_out[i] = q[i]
            qd_out[i] = qd[i]
    if conf[SC_.observer] != 0.0:
        cov = np.empty((N, N))
        if est:
            for i in range(N):
                for k in range(N):
                    cov[i, k] = s[S_.P + (N + i) * NX + N + k]
        else:
            cov[:, :] = 0.0
            v = conf[SC_.noise_qd] ** 2
            for i in range(N):
                cov[i, i] = v
        applied = np.zeros(N)
        dt = 0.0
        restart = first or s[S_.decided] == 0.0 or stance != int(s[S_.stance]) or s[S_.mo_started] == 0.0
        if not first and s[S_.decided] != 0.0:
            dt = _elapsed_applied(conf, s, t, stance, applied)
        if restart:
            dt = 0.0
        A = np.empty((N, N))
        B = np.empty((3, N))
        J = np.empty((3, 9))
        if not _observer(ti, tf, conf, s, q_out, qd_out, stance, restart, applied, dt, cov, A, B, J):
            return SINGULAR
        if conf[SC_.me] != 0.0:
            has_applied = s[S_.since] != 0.0 and not first and s[S_.decided] != 0.0
            if not _model_error(ti, tf, conf, s, q_out, qd_out, A, B, J, cov, has_applied, applied,
                                dt if has_applied else 0.0):
                return SINGULAR
    s[S_.started] = 1.0
    s[S_.stance] = stance
    return DONE


@numba.njit(_I(_VI, _V, _V, _V, _F, _V, _V, _I, _F, _F, _V, _V), cache=True)
def sense(ti, tf, conf, s, t, q, qd, stance, pitch, pitch_rate, q_out, qd_out):
    """The pipeline for the sample (q, q', stance, pitch [rad], pitch_rate [rad/s]; NaN: none) at t [s]
    (delay 0: the sample is the present):
    the estimator's time update, then, unless the stance changed (NEEDS_IMPACT: the caller applies the
    impact to x and P and calls :func:`sense_finish`), the measurement update and the observer. q_out,
    q_out' <- the state the controller acts on. SINGULAR: a model matrix was not positive definite."""
    if s[S_.started] != 0.0 and conf[SC_.estimator] != 0.0:
        applied = np.empty(N)
        dt = _elapsed_applied(conf, s, t, stance, applied)
        A = np.empty((N, N))
        H = np.empty(N)
        if conf[SC_.observer] != 0.0:            # the observer computed them at this estimate last period
            for i in range(N):
                H[i] = s[S_.H_est + i]
                for k in range(N):
                    A[i, k] = s[S_.A_est + N * i + k]
        else:
            xq = s[S_.x:S_.x + N].copy()
            xv = s[S_.x + N:S_.x + NX].copy()
            _terms(ti, tf, xq, xv, A, H)
        L = np.empty((N, N))
        if not pk.cholesky(A, L):
            return SINGULAR
        a = np.empty((1, N))
        for i in range(N):
            rr = s[S_.r + i] if conf[SC_.observer] != 0.0 else 0.0
            a[0, i] = applied[i] - H[i] + rr
        pk.chol_solve_rows(L, a)
        _est_predict(conf, s, dt, a[0])
        if stance != int(s[S_.stance]):
            return NEEDS_IMPACT
    return sense_finish(ti, tf, conf, s, t, q, qd, stance, pitch, pitch_rate, q_out, qd_out)


@numba.njit(_I(_V, _V, _V), cache=True)
def into_res(s, conf, out):
    """out (8,) <- [dR (2) [N], F_x = W[0] [N], the five rows' widening [N]] (the controller's RES fields):
    the observer's, or with the legs' model-error estimator once it has taken a sample its combined ones."""
    observer = conf[SC_.observer] != 0.0
    if observer and conf[SC_.me] != 0.0 and s[S_.me_flags] != 0.0:
        out[0] = s[S_.me_dR]
        out[1] = s[S_.me_dR + 1]
        out[2] = s[S_.me_W]
        for r in range(5):
            out[3 + r] = s[S_.me_extra + r]
        return 0
    out[0] = s[S_.dR] if observer else 0.0
    out[1] = s[S_.dR + 1] if observer else 0.0
    out[2] = s[S_.W] if observer else 0.0
    for r in range(5):
        out[3 + r] = s[S_.extra + r] if observer else 0.0
    return 0


# ------------------------------------------------------------------------------------------ the predictor
@numba.njit(cache=True)
def _accel(ti, tf, q, qd, tau, a):
    """a <- A(q)^-1 (tau - H(q, q')) on the locked-root chain (single support, stance foot fixed). False if
    A is not positive definite."""
    A = np.empty((N, N))
    H = np.empty(N)
    _terms(ti, tf, q, qd, A, H)
    L = np.empty((N, N))
    if not pk.cholesky(A, L):
        return False
    b = np.empty((1, N))
    for i in range(N):
        b[0, i] = tau[i] - H[i]
    pk.chol_solve_rows(L, b)
    for i in range(N):
        a[i] = b[0, i]
    return True


@numba.njit(cache=True)
def _rk4(ti, tf, q, qd, tau, h, q_out, qd_out):
    """One classical RK4 step of length h [s] of A q'' + H = tau from (q, q') (``DelayPredictor._rk4``)."""
    k1v = np.empty(N)
    k2v = np.empty(N)
    k3v = np.empty(N)
    k4v = np.empty(N)
    qs = np.empty(N)
    vs = np.empty(N)
    ok = _accel(ti, tf, q, qd, tau, k1v)
    for i in range(N):
        qs[i] = q[i] + 0.5 * h * qd[i]
        vs[i] = qd[i] + 0.5 * h * k1v[i]
    k2q = vs.copy()
    ok = ok and _accel(ti, tf, qs, vs, tau, k2v)
    for i in range(N):
        qs[i] = q[i] + 0.5 * h * k2q[i]
        vs[i] = qd[i] + 0.5 * h * k2v[i]
    k3q = vs.copy()
    ok = ok and _accel(ti, tf, qs, vs, tau, k3v)
    for i in range(N):
        qs[i] = q[i] + h * k3q[i]
        vs[i] = qd[i] + h * k3v[i]
    k4q = vs.copy()
    ok = ok and _accel(ti, tf, qs, vs, tau, k4v)
    for i in range(N):
        q_out[i] = q[i] + (h / 6.0) * (qd[i] + 2 * k2q[i] + 2 * k3q[i] + k4q[i])
        qd_out[i] = qd[i] + (h / 6.0) * (k1v[i] + 2 * k2v[i] + 2 * k3v[i] + k4v[i])
    return ok


@numba.njit(cache=True)
def lowest_sole(ti, tf, q):
    """Height [m] of the swing foot's lowest sole point (heel l_min or toe l_max along its frame) above the
    stance sole line, stance foot flat (``DelayPredictor.lowest_sole``)."""
    n = ti[0]
    K = np.empty((10, n))
    qf = np.zeros(n)
    for i in range(N):
        qf[3 + i] = q[i]
    pk.kinematics(ti, tf, qf, qf, K)
    fj = ti[4]
    th = K[pk.K_TH, fj]
    z = K[pk.K_PZ, fj]
    return z + min(tf[1] * math.sin(th), tf[2] * math.sin(th))


@numba.njit(cache=True)
def flat_foot_impact(ti, tf, q, qd, q_out, qd_out):
    """The flat-foot touchdown (``predictor.flat_foot_impact``) on the fixed-foot tree, whose root is a free
    planar joint at the stance ankle: the landing foot laid flat by its ankle (q6 -= sum q), the inelastic
    impact of the tree's foot 1 with the stance foot at rest (``planar_kernels.impact``: the same map as the
    floating model's, another choice of root), then the legs relabelled: q -> -q[::-1]. False if singular."""
    n = ti[0]
    qf = np.zeros(n)
    vf = np.zeros(n)
    s = 0.0
    for i in range(N):
        s += q[i]
    for i in range(N):
        qf[3 + i] = q[i]
        vf[3 + i] = qd[i]
    qf[3 + N - 1] -= s
    vp = np.empty(n)
    out = np.empty(7)
    if pk.impact(ti, tf, qf, vf, 1, vp, out) != pk.STATUS_OK:
        return False
    for i in range(N):
        q_out[i] = -qf[3 + N - 1 - i]
        qd_out[i] = -vp[3 + N - 1 - i]
    return True


@numba.njit(_I(_VI, _V, _V, _V, numba.types.Array(numba.types.float64, 2, "C"), _I, _F, _V, _V, _I, _V, _V, _V),
            cache=True)
def predict(ti, tf, conf, s, hist, n_hist, t_now, q, qd, stance, q_out, qd_out, out):
    """The Smith predictor (``predictor.DelayPredictor.predict``, its module docstring): from the sample (q,
    q', stance) taken at hist[0, 0] through the decisions hist[:n_hist] (rows [t [s], told stance, torque
    sent (6) [N m]]) to t_now [s]: RK4 with SCONF.pred_substeps steps per period, the torque clipped and
    relabelled when it was sent for the other stance than the predicted one, a touchdown (swing sole at
    or below the ground once it cleared) through the flat-foot impact map. q_out, qd_out <- the predicted
    present state; out <- [its stance, touchdowns predicted]. Returns 0, or SINGULAR."""
    if stance != int(s[S_.pred_sample_stance]):
        s[S_.pred_cleared] = 0.0
        s[S_.pred_sample_stance] = stance
    if lowest_sole(ti, tf, q) > conf[SC_.pred_clearance]:
        s[S_.pred_cleared] = 1.0
    cleared = s[S_.pred_cleared] != 0.0
    clr, tdh, ttol = conf[SC_.pred_clearance], conf[SC_.pred_td_height], conf[SC_.pred_t_tol]
    per, sub = conf[SC_.period], conf[SC_.pred_substeps]
    qc = q.copy()
    vc = qd.copy()
    qn = np.empty(N)
    vn = np.empty(N)
    qe = np.empty(N)
    ve = np.empty(N)
    tau_told = np.empty(N)
    tau = np.empty(N)
    st = stance
    n_td = 0
    for i in range(n_hist):
        t0 = hist[i, 0]
        t1 = hist[i + 1, 0] if i + 1 < n_hist else t_now
        dt = t1 - t0
        if dt <= 0:
            continue
        n = max(1, int(math.ceil(sub * dt / per - 1e-9)))
        h = dt / n
        told = int(hist[i, 1])
        for k in range(N):
            tau_told[k] = min(max(hist[i, 2 + k], conf[SC_.torque_min + k]), conf[SC_.torque_max + k])
        for j in range(n):
            for k in range(N):
                tau[k] = tau_told[k] if told == st else -tau_told[N - 1 - k]
            if not _rk4(ti, tf, qc, vc, tau, h, qn, vn):
                return SINGULAR
            z = lowest_sole(ti, tf, qn)
            if cleared and z < -tdh:
                lo_ = 0.0
                hi_ = h
                while hi_ - lo_ > ttol:
                    mid = 0.5 * (lo_ + hi_)
                    _rk4(ti, tf, qc, vc, tau, mid, qe, ve)
                    if lowest_sole(ti, tf, qe) > 0.0:
                        lo_ = mid
                    else:
                        hi_ = mid
                _rk4(ti, tf, qc, vc, tau, hi_, qe, ve)
                if not flat_foot_impact(ti, tf, qe, ve, qc, vc):
                    return SINGULAR
                st = 1 - st
                cleared = False
                n_td += 1
                rest = h - hi_
                if rest > 0:
                    for k in range(N):
                        tau[k] = tau_told[k] if told == st else -tau_told[N - 1 - k]
                    _rk4(ti, tf, qc, vc, tau, rest, qn, vn)
                    qc[:] = qn
                    vc[:] = vn
                continue
            qc[:] = qn
            vc[:] = vn
            if z > clr:
                cleared = True
            if cleared and j == n - 1 and z <= tdh:
                if not flat_foot_impact(ti, tf, qc, vc, qe, ve):
                    return SINGULAR
                qc[:] = qe
                vc[:] = ve
                st = 1 - st
                cleared = False
                n_td += 1
    q_out[:] = qc
    qd_out[:] = vc
    out[0] = st
    out[1] = n_td
    return DONE
