"""The legs' model-error estimator's kernels (``model_error``): its algebra after the regressor, in
NumPy (``combine``, the oracle) and compiled by Numba as loops (``combine_kernel``, checked against it); the
six-column leg regressor Y(q, q', q'') in closed form on the planar fixed-foot tree (``leg_regressor``,
Pinocchio's joint torque regressor its oracle); and the estimator's whole sample compiled (``update``: the
maths of ``LegModelError.update`` after the model terms, run by the compiled sensing pipeline inside
``pipeline_kernels.sense_finish``). A kernel module: import it with ``model_error.load_model_error_kernels``
(``biped_model.numba_cache.load``), never directly. The maths, units and conventions: ``model_error``'s
module docstring, ``combine``'s, ``regressor_into``'s and ``update``'s."""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_model.numba_cache import require_configured

require_configured(__name__)

from biped_model import planar_kernels as pk   # noqa: E402  (a kernel module: after the check)

_V = numba.types.Array(numba.types.float64, 1, "C")
_VI = numba.types.Array(numba.types.int64, 1, "C")
_M = numba.types.Array(numba.types.float64, 2, "C")
_FAST = {"reassoc", "contract"}


# ------------------------------------------------------------------------------------------ the regressor
@numba.njit(cache=True)
def regressor_into(ti, tf, D, q, qd, a, Y):
    """Y (nj, np) <- the generalized force on every coordinate of the locked-root chain (joints 0-2 of the
    planar tree ``ti``/``tf``, ``planar_kernels``' layout, at rest at zero: root x [N], z [N], pitch [N m];
    then the actuated joints 3..nj-1 at (q, q', q'' = a) [rad, rad/s, rad/s^2], [N m]) of a unit change of
    each parameter, Y = F D with D (2 nb, np) the combination of the bodies' columns and F (nj, 2 nb):

    * column b (unit mass of body b, its centre of mass P_b and its inertia about it fixed: a point mass at
      P_b): F[k, b] = J_b,k . (a_b + g e_z), J_b,k the (x, z) column of P_b's Jacobian for coordinate k
      (``planar_kernels.jacobian_column``: perp(P_b - p_k) for a hinge, the prism's axis), a_b = P_b'' the centre of
      mass's acceleration, g e_z gravity's (z up); 0 where k is not an ancestor of b's joint;
    * column nb + b (unit rotational inertia of body b about its centre of mass and the plane's normal):
      F[k, nb + b] = w_b,k alpha_b, w_b,k = 1 for a hinge ancestor (0 for a prism), alpha_b the body's
      angular acceleration.

    Both are the Newton-Euler equations of that unit body (the inertial + weight wrench m (a + g e_z),
    I alpha mapped to the coordinates by the transposed Jacobian), so Y is exact: the inverse dynamics are
    linear in the inertial parameters. Accelerations by one forward recursion over the frames: origin
    acceleration = the drift of ``planar_kernels.kinematics`` (the part at q'' = 0) + the part linear in
    q'': l_k = l_par + alpha_par perp(r_k) (+ e_k q''_k for a prism), alpha_k = alpha_par (+ q''_k for a
    hinge), r_k the origin's offset from its parent's, perp(x, z) = (-z, x); a point r from the origin of
    frame j: a_j + alpha_j perp(r) - omega_j^2 r. Signs as ``planar_kernels``: angles counter-clockwise in
    the sagittal view (about -y), moments counter-clockwise."""
    n = ti[0]
    nb = ti[1]
    npar = D.shape[1]
    g = tf[0]
    K = np.empty((16, n))      # one scratch: rows 0-9 the kinematics (planar_kernels' K), 10-15 q, v, q'', alpha, l
    qf = K[10]
    vf = K[11]
    m = n - q.shape[0]
    for i in range(n):
        qf[i] = q[i - m] if i >= m else 0.0
        vf[i] = qd[i - m] if i >= m else 0.0
        K[12, i] = a[i - m] if i >= m else 0.0
    pk.kinematics(ti, tf, qf, vf, K)
    for k in range(n):
        p = pk.parent(ti, k)
        if p < 0:
            alp, lxp, lzp, rx, rz = 0.0, 0.0, 0.0, 0.0, 0.0
        else:
            alp, lxp, lzp = K[13, p], K[14, p], K[15, p]
            rx = K[pk.K_PX, k] - K[pk.K_PX, p]
            rz = K[pk.K_PZ, k] - K[pk.K_PZ, p]
        lxk = lxp - alp * rz
        lzk = lzp + alp * rx
        typ = pk.joint_type(ti, k)
        ak = K[12, k]
        if typ == pk.REV:
            K[13, k] = alp + ak
        else:
            K[13, k] = alp
            if typ == pk.PX:
                lxk += K[pk.K_C, k] * ak
                lzk += K[pk.K_S, k] * ak
            else:
                lxk -= K[pk.K_S, k] * ak
                lzk += K[pk.K_C, k] * ak
        K[14, k] = lxk
        K[15, k] = lzk
    Y[:, :] = 0.0
    ob = pk.HEADER_F + 2 * n
    for b in range(nb):
        j = ti[pk.HEADER_I + 2 * n + b]
        Px, Pz, rx, rz = pk.frame_point(K, j, tf[ob + nb + b], tf[ob + 2 * nb + b])
        om2 = K[pk.K_OM, j] * K[pk.K_OM, j]
        alpha = K[13, j]
        ax = K[pk.K_AX, j] + K[14, j] - alpha * rz - om2 * rx
        az = K[pk.K_AZ, j] + K[15, j] + alpha * rx - om2 * rz + g
        k = j
        while k >= 0:
            jx, jz, jw = pk.jacobian_column(ti, K, k, Px, Pz)
            fm = jx * ax + jz * az
            fi = jw * alpha
            for c in range(npar):
                dm = D[b, c]
                di = D[nb + b, c]
                if dm != 0.0:
                    Y[k, c] += fm * dm
                if di != 0.0:
                    Y[k, c] += fi * di
            k = pk.parent(ti, k)


@numba.njit(numba.int64(_VI, _V, _M, _V, _V, _V, _M), cache=True)
def leg_regressor(ti, tf, D, q, qd, a, Y):
    """:func:`regressor_into` for a caller outside numba (explicit types: compiled once). Returns 0."""
    regressor_into(ti, tf, D, q, qd, a, Y)
    return 0


def combine(Y, A, B, Ainv, r, S, cov_W_obs, W_obs_restart, Jj, cov_qd, use_cov, K, dt, since, restarted,
            has_prev, Rres, theta, P, Yf, Yprev, W_t_restart, W_t, cov_W, dR, cov_dR):
    """The estimator's period after the regressor (``model_error``'s module docstring), in place. In: Y (9, 6)
    at this sample, A (6, 6), B (3, 6) the model's inertia and reaction rows, Ainv = A^-1, the observer's r
    (6,) [N m], S (2, 3), cov_W_obs (3, 3), the wrench it carried at its restart W_obs_restart (3,) and the time since
    ``since`` [s], Jj (3, 6), the rate covariance cov_qd (6, 6) (used if ``use_cov``), K [1/s], dt [s],
    ``restarted``, ``has_prev`` (a Y_j of the last sample is in Yprev), Rres = s_res^2 1 (3, 3). State,
    updated: theta (6,), P (6, 6), Y_f (6, 6), Yprev (6, 6) <- Y_j, W_t_restart (3,) (set by the caller at
    a restart). Out: W_t (3,), cov_W (3, 3), dR (2,) [N], cov_dR (2, 2)."""
    Yj = Y[3:]
    if restarted:
        Yf[:] = 0.0
    else:
        Ymid = 0.5 * (Yprev + Yj) if has_prev else Yj
        f = math.exp(-K * dt)
        Yf[:] = f * Yf + (1.0 - f) * Ymid
        # RLS on the swing rows: r_s = H theta + noise, H = -(Y_f)_s
        H = -Yf[3:6]
        Rm = Rres.copy()
        if use_cov:
            As = A[3:6]
            Rm += (K * K) * (As @ cov_qd @ As.T)          # = (A Sigma A)_s, A symmetric
        PHt = P @ H.T
        Sm = H @ PHt + Rm
        gain = np.linalg.solve(Sm, PHt.T).T
        theta += gain @ (r[3:6] - H @ theta)
        IKH = np.eye(theta.shape[0]) - gain @ H
        P[:] = IKH @ P @ IKH.T + gain @ Rm @ gain.T        # Joseph form
    Yprev[:] = Yj
    # the torso wrench from what the legs' error does not explain
    decay = math.exp(-K * since)
    r_t = r + Yf @ theta - Jj.T @ ((W_obs_restart - W_t_restart) * decay)
    # J_j^{T+}: the normal equations (J_j J_j^T)^-1 J_j where J_j (3, 6) is well inside full row rank, the SVD
    # pseudo-inverse where it is not (the stance knee near straight: the ankle-knee-hip chain then cannot move
    # the torso point and pitch independently). Test: det(J J^T) > 1e-6 (tr J J^T / 3)^3, i.e. the
    # eigenvalues' product not below 1e-6 of their mean cubed (condition of J J^T below about 1e6, so the
    # normal equations lose no more than ~1e-10 relative to the SVD).
    JJ = Jj @ Jj.T
    det = (JJ[0, 0] * (JJ[1, 1] * JJ[2, 2] - JJ[1, 2] * JJ[2, 1])
           - JJ[0, 1] * (JJ[1, 0] * JJ[2, 2] - JJ[1, 2] * JJ[2, 0])
           + JJ[0, 2] * (JJ[1, 0] * JJ[2, 1] - JJ[1, 1] * JJ[2, 0]))
    tr = (JJ[0, 0] + JJ[1, 1] + JJ[2, 2]) / 3.0
    if det > 1e-6 * tr * tr * tr:
        pinv = np.linalg.solve(JJ, Jj)
    else:
        pinv = np.linalg.pinv(np.ascontiguousarray(Jj.T))
    W_t[:] = pinv @ r_t
    cov_W[:] = cov_W_obs + np.diag((W_t_restart * decay) ** 2 - (W_obs_restart * decay) ** 2)
    G = Y[:2] - (B[:2] @ Ainv) @ Yj                        # (-B A^-1 Y_j + Y_r)[:2]
    Gt = G + S @ pinv @ Yf
    dR[:] = S @ W_t + G @ theta
    cov_dR[:] = S @ cov_W @ S.T + Gt @ P @ Gt.T


# rows of combine_kernel's one scratch array (npar columns): what each holds
_AC = 0      # 3 rows: A_s cov_q'
_PH = 3      # 3 rows: (P H^T)^T, then the gain's transpose (solved in place)
_IKH = 6     # 6 rows: I - gain H
_T1 = 12     # 6 rows: (I - gain H) P
_GR = 18     # 3 rows: (gain R_m)^T
_RT = 21     # 1 row: r_t
_PINV = 22   # 3 rows: J_j^{T+}
_BA = 25     # 2 rows: B[:2] A^-1
_G = 27      # 2 rows: G
_SP = 29     # 2 rows: S J_j^{T+}
_GT = 31     # 2 rows: G_t
_GP = 33     # 2 rows: G_t P
_ROWS = 35
_NPAR = 6    # combine_kernel's sizes as compile-time constants (loops of known length: unrolled, vectorised)
_NJ = 6


@numba.njit(cache=True)
def _chol3(a00, a10, a20, a11, a21, a22):
    """The lower Cholesky factor of the symmetric 3 x 3 matrix of lower triangle a: (ok, l00, l10, l20, l11,
    l21, l22); ok False if it is not positive definite (also a NaN)."""
    if not a00 > 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    l00 = math.sqrt(a00)
    l10 = a10 / l00
    l20 = a20 / l00
    d1 = a11 - l10 * l10
    if not d1 > 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    l11 = math.sqrt(d1)
    l21 = (a21 - l20 * l10) / l11
    d2 = a22 - l20 * l20 - l21 * l21
    if not d2 > 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return True, l00, l10, l20, l11, l21, math.sqrt(d2)


@numba.njit(cache=True)
def _solve3(l00, l10, l20, l11, l21, l22, b0, b1, b2):
    """x = (L L^T)^-1 b for the factor of :func:`_chol3`."""
    y0 = b0 / l00
    y1 = (b1 - l10 * y0) / l11
    y2 = (b2 - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    return x0, x1, x2


@numba.njit(cache=True, fastmath=_FAST)
def combine_kernel(Y, A, B, Ainv, r, S, cov_W_obs, W_obs_restart, Jj, cov_qd, use_cov, K, dt, since, restarted,
                   has_prev, Rres, theta, P, Yf, Yprev, W_t_restart, W_t, cov_W, dR, cov_dR):
    """:func:`combine` compiled for speed: the same arguments, maths and results to round-off (tested against
    :func:`combine` run by NumPy on every branch), its products written as loops into one scratch array (rows
    ``_AC`` ... ``_GP``; no other allocation: a small array costs about as much as these products), its two
    3 x 3 solves (S_m = H P H^T + R_m and J_j J_j^T, symmetric positive definite) by Cholesky
    (:func:`_chol3`), NumPy's solve and SVD pseudo-inverse where a factor fails, as :func:`combine`'s test.
    Sizes fixed at compile time: 6 parameters, 6 joint rows (``_NPAR``, ``_NJ``; ValueError otherwise)."""
    if theta.shape[0] != _NPAR or Yf.shape[0] != _NJ or Y.shape[0] != _NJ + 3:
        raise ValueError("combine_kernel: 6 parameters and 9 rows of Y expected")
    npar = _NPAR
    nj = _NJ
    w = np.empty((_ROWS, npar))
    w3 = np.empty((8, 3))                            # rows 0-2: R_m, 3-5: S_m, 6-7: S cov_W
    if restarted:
        Yf[:, :] = 0.0
    else:
        f = math.exp(-K * dt)
        for i in range(nj):
            for c in range(npar):
                ymid = 0.5 * (Yprev[i, c] + Y[3 + i, c]) if has_prev else Y[3 + i, c]
                Yf[i, c] = f * Yf[i, c] + (1.0 - f) * ymid
        # RLS on the swing rows: r_s = H theta + noise, H = -(Y_f)_s
        for i in range(3):
            for k in range(3):
                w3[i, k] = Rres[i, k]
        if use_cov:                                  # R_m += K^2 (A cov A)_s
            for i in range(3):
                for k in range(nj):
                    v = 0.0
                    for j in range(nj):
                        v += A[3 + i, j] * cov_qd[j, k]
                    w[_AC + i, k] = v
            k2 = K * K
            for i in range(3):
                for k in range(3):
                    v = 0.0
                    for j in range(nj):
                        v += w[_AC + i, j] * A[3 + k, j]
                    w3[i, k] += k2 * v
        for k in range(3):                           # w[_PH + k, i] = (P H^T)[i, k]
            for i in range(npar):
                v = 0.0
                for j in range(npar):
                    v -= P[i, j] * Yf[3 + k, j]
                w[_PH + k, i] = v
        for i in range(3):                           # S_m = H (P H^T) + R_m
            for k in range(3):
                v = 0.0
                for j in range(npar):
                    v -= Yf[3 + i, j] * w[_PH + k, j]
                w3[3 + i, k] = v + w3[i, k]
        ok, l00, l10, l20, l11, l21, l22 = _chol3(w3[3, 0], w3[4, 0], w3[5, 0], w3[4, 1], w3[5, 1], w3[5, 2])
        if ok:                                       # gain^T = S_m^-1 (P H^T)^T, column by column
            for i in range(npar):
                x0, x1, x2 = _solve3(l00, l10, l20, l11, l21, l22, w[_PH, i], w[_PH + 1, i], w[_PH + 2, i])
                w[_PH, i] = x0
                w[_PH + 1, i] = x1
                w[_PH + 2, i] = x2
        else:                                        # not positive definite (a non-finite input): NumPy's
            w[_PH:_PH + 3] = np.linalg.solve(np.ascontiguousarray(w3[3:6]), np.ascontiguousarray(w[_PH:_PH + 3]))
        h0 = 0.0
        h1 = 0.0
        h2 = 0.0
        for c in range(npar):                        # H theta
            h0 -= Yf[3, c] * theta[c]
            h1 -= Yf[4, c] * theta[c]
            h2 -= Yf[5, c] * theta[c]
        e0 = r[3] - h0                               # the innovation r_s - H theta
        e1 = r[4] - h1
        e2 = r[5] - h2
        for c in range(npar):
            theta[c] += w[_PH, c] * e0 + w[_PH + 1, c] * e1 + w[_PH + 2, c] * e2
        for i in range(npar):                        # I - gain H = I + gain (Y_f)_s
            for j in range(npar):
                v = 0.0
                for k in range(3):
                    v += w[_PH + k, i] * Yf[3 + k, j]
                w[_IKH + i, j] = (1.0 if i == j else 0.0) + v
        for i in range(npar):
            for j in range(npar):
                v = 0.0
                for k in range(npar):
                    v += w[_IKH + i, k] * P[k, j]
                w[_T1 + i, j] = v
        for j in range(3):                           # (gain R_m)^T
            for i in range(npar):
                v = 0.0
                for k in range(3):
                    v += w[_PH + k, i] * w3[k, j]
                w[_GR + j, i] = v
        for i in range(npar):                        # Joseph form
            for k in range(npar):
                v = 0.0
                for j in range(npar):
                    v += w[_T1 + i, j] * w[_IKH + k, j]
                u = 0.0
                for j in range(3):
                    u += w[_GR + j, i] * w[_PH + j, k]
                P[i, k] = v + u
    for i in range(nj):
        for c in range(npar):
            Yprev[i, c] = Y[3 + i, c]
    # the torso wrench from what the legs' error does not explain
    decay = math.exp(-K * since)
    d0 = (W_obs_restart[0] - W_t_restart[0]) * decay
    d1 = (W_obs_restart[1] - W_t_restart[1]) * decay
    d2 = (W_obs_restart[2] - W_t_restart[2]) * decay
    for i in range(nj):
        v = 0.0
        for c in range(npar):
            v += Yf[i, c] * theta[c]
        w[_RT, i] = r[i] + v - (Jj[0, i] * d0 + Jj[1, i] * d1 + Jj[2, i] * d2)
    # J_j^{T+}: as combine (the normal equations where J_j J_j^T is well conditioned, else the SVD)
    j00 = j01 = j02 = j11 = j12 = j22 = 0.0
    for k in range(nj):
        j00 += Jj[0, k] * Jj[0, k]
        j01 += Jj[0, k] * Jj[1, k]
        j02 += Jj[0, k] * Jj[2, k]
        j11 += Jj[1, k] * Jj[1, k]
        j12 += Jj[1, k] * Jj[2, k]
        j22 += Jj[2, k] * Jj[2, k]
    det = j00 * (j11 * j22 - j12 * j12) - j01 * (j01 * j22 - j12 * j02) + j02 * (j01 * j12 - j11 * j02)
    tr = (j00 + j11 + j22) / 3.0
    ok = False
    if det > 1e-6 * tr * tr * tr:
        ok, l00, l10, l20, l11, l21, l22 = _chol3(j00, j01, j02, j11, j12, j22)
    if ok:
        for k in range(nj):
            x0, x1, x2 = _solve3(l00, l10, l20, l11, l21, l22, Jj[0, k], Jj[1, k], Jj[2, k])
            w[_PINV, k] = x0
            w[_PINV + 1, k] = x1
            w[_PINV + 2, k] = x2
    else:
        w[_PINV:_PINV + 3] = np.linalg.pinv(np.ascontiguousarray(Jj.T))
    for a in range(3):
        v = 0.0
        for k in range(nj):
            v += w[_PINV + a, k] * w[_RT, k]
        W_t[a] = v
    for a in range(3):
        for c in range(3):
            cov_W[a, c] = cov_W_obs[a, c]
        wr = W_t_restart[a] * decay
        wo = W_obs_restart[a] * decay
        cov_W[a, a] += wr * wr - wo * wo
    # G = (-B A^-1 Y_j + Y_r)[:2], G_t = G + S J_j^{T+} Y_f
    for a in range(2):
        for k in range(nj):
            v = 0.0
            for j in range(nj):
                v += B[a, j] * Ainv[j, k]
            w[_BA + a, k] = v
        for c in range(npar):
            v = 0.0
            for k in range(nj):
                v += w[_BA + a, k] * Y[3 + k, c]
            w[_G + a, c] = Y[a, c] - v
        for k in range(nj):
            w[_SP + a, k] = S[a, 0] * w[_PINV, k] + S[a, 1] * w[_PINV + 1, k] + S[a, 2] * w[_PINV + 2, k]
        for c in range(npar):
            v = 0.0
            for k in range(nj):
                v += w[_SP + a, k] * Yf[k, c]
            w[_GT + a, c] = w[_G + a, c] + v
        v = S[a, 0] * W_t[0] + S[a, 1] * W_t[1] + S[a, 2] * W_t[2]
        u = 0.0
        for c in range(npar):
            u += w[_G + a, c] * theta[c]
        dR[a] = v + u
        for c in range(3):
            w3[6 + a, c] = S[a, 0] * cov_W[0, c] + S[a, 1] * cov_W[1, c] + S[a, 2] * cov_W[2, c]
        for c in range(npar):
            v = 0.0
            for j in range(npar):
                v += w[_GT + a, j] * P[j, c]
            w[_GP + a, c] = v
    for a in range(2):
        for b in range(2):
            v = w3[6 + a, 0] * S[b, 0] + w3[6 + a, 1] * S[b, 1] + w3[6 + a, 2] * S[b, 2]
            u = 0.0
            for c in range(npar):
                u += w[_GP + a, c] * w[_GT + b, c]
            cov_dR[a, b] = v + u


# ------------------------------------------------------------------------------------------ one sample
@numba.njit(cache=True, fastmath=_FAST)
def update(ti, tf, D, q, qd, A, B, H, Jj, r, S, cov_W_obs, W_obs_restart, since, cov_qd, K, dt, restarted,
           has_applied, applied, Rres, Rhold, settle_time, theta, P, Yf, Yprev, W_t_restart, last_torque, flags, W_t,
           cov_W, dR, cov_dR):
    """One observer sample of the estimator: ``LegModelError.update``'s maths after its model terms, in place
    (the compiled pipeline's; ``LegModelError`` stays the oracle). In: the state the observer saw (q, q')
    [rad, rad/s], the model's A (6, 6), B (3, 6) (root rows), H (6,) there (the observer's
    ``pipeline_kernels.momentum_terms``), J_j (3, 6) the torso wrench Jacobian's joint columns, the
    observer's r (6,) [N m], S (2, 3), cov_W_obs (3, 3), the wrench it carried at its last restart
    W_obs_restart (3,) and the time since [s], the rate covariance cov_qd (6, 6), K [1/s], dt [s],
    ``restarted`` (the observer restarted at this sample), ``has_applied`` and ``applied`` (6,) [N m] the
    torque over the interval that led here in this stance's paper order, Rres = s_res^2 1 (3, 3), Rhold =
    ``HOLD_VARIANCE`` 1 (3, 3) and ``settle_time`` [s] (``model_error_settle`` / K). State,
    updated: theta (6,), P (6, 6), Y_f (6, 6), Yprev (6, 6), W_t_restart (3,), last_torque (6,), flags (3,)
    = [a Y_j of the last sample is in Yprev (0/1), last_torque holds a torque (0/1), RLS updates made].
    W_t (3,): in, the last sample's torso wrench; out, this sample's. Out: cov_W (3, 3), dR (2,) [N],
    cov_dR (2, 2).

    As ``LegModelError.update``: the acceleration a = A^-1 (Gamma - H + r) under the torque applied, or at a
    restart (or without a torque) a = A^-1 (relabel(the last torque) - H) (0 torque before any), relabel
    = -x[::-1]; Y = :func:`regressor_into` at (q, q', a); at a restart W_t_restart <- the last torso wrench;
    within ``settle_time`` of the observer's restart the sample is held (Rhold in the combination, theta and P
    put back after it, bit for bit), otherwise one more update counted; then :func:`combine_kernel`. A^-1 by Cholesky (``LegModelError``:
    NumPy's LU inverse; the same to round-off). Returns False (nothing changed) if A is not positive
    definite."""
    if A.shape[0] != _NJ or theta.shape[0] != _NPAR:
        raise ValueError("update: 6 joints and 6 parameters expected")
    nj = _NJ
    u = np.empty((3 * nj + 5, nj))        # one scratch: rows Y (nj + 3), L (nj), A^-1 (nj), b, a
    Y = u[:nj + 3]
    L = u[nj + 3:2 * nj + 3]
    Ainv = u[2 * nj + 3:3 * nj + 3]
    if not pk.cholesky(A, L):
        return False
    for i in range(nj):                   # rows of 1 solved: A^-1 (symmetric)
        for k in range(nj):
            Ainv[i, k] = 1.0 if i == k else 0.0
    pk.chol_solve_rows(L, Ainv)
    ib, ia = 3 * nj + 3, 3 * nj + 4
    if restarted or not has_applied:
        for i in range(nj):
            tq = -last_torque[nj - 1 - i] if flags[1] != 0.0 else 0.0
            u[ib, i] = tq - H[i]
    else:
        for i in range(nj):
            u[ib, i] = applied[i] - H[i] + r[i]
            last_torque[i] = applied[i]
        flags[1] = 1.0
    for i in range(nj):
        v = 0.0
        for k in range(nj):
            v += Ainv[i, k] * u[ib, k]
        u[ia, i] = v
    regressor_into(ti, tf, D, q, qd, u[ia], Y)
    if restarted:
        W_t_restart[:] = W_t
    hold = (not restarted) and since < settle_time      # the observer's start transient (model_error)
    if hold:
        theta0 = theta.copy()
        P0 = P.copy()
    elif not restarted:
        flags[2] += 1.0
    combine_kernel(Y, A, B, Ainv, r, S, cov_W_obs, W_obs_restart, Jj, cov_qd, True, K, dt, since, restarted,
                   flags[0] != 0.0, Rhold if hold else Rres, theta, P, Yf, Yprev, W_t_restart, W_t, cov_W, dR,
                   cov_dR)
    if hold:                 # exactly no update (the combination used theta and P to round-off)
        theta[:] = theta0
        P[:, :] = P0
    flags[0] = 1.0
    return True
