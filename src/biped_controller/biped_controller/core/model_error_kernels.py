"""The legs' model-error estimator's kernels (``model_error``, issue 22): its algebra after the regressor, as
one function run either by NumPy (``combine``, the oracle) or compiled by Numba (``combine_kernel``); the
six-column leg regressor Y(q, q', q'') in closed form on the planar fixed-foot tree (``leg_regressor``,
Pinocchio's joint torque regressor its oracle); and the estimator's whole sample compiled (``update``: the
maths of ``LegModelError.update`` after the model terms, run by the compiled sensing pipeline inside
``estimation_kernels.sense_finish``). A kernel module: import it with ``model_error.load_model_error_kernels``
(``biped_sim.robot.numba_cache.load``), never directly. The maths, units and conventions: ``model_error``'s
module docstring, ``combine``'s, ``leg_regressor``'s and ``update``'s."""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_sim.robot.numba_cache import require_configured

require_configured(__name__)

from biped_sim.robot import planar_kernels as pk   # noqa: E402  (a kernel module: after the check)

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
      (``planar_kernels._column``: perp(P_b - p_k) for a hinge, the prism's axis), a_b = P_b'' the centre of
      mass's acceleration, g e_z gravity's (z up); 0 where k is not an ancestor of b's joint;
    * column nb + b (unit rotational inertia of body b about its centre of mass and the plane's normal):
      F[k, nb + b] = w_b,k alpha_b, w_b,k = 1 for a hinge ancestor (0 for a prism), alpha_b the body's
      angular acceleration.

    Both are the Newton-Euler equations of that unit body (the inertial + weight wrench m (a + g e_z),
    I alpha mapped to the coordinates by the transposed Jacobian), so Y is exact: the inverse dynamics are
    linear in the inertial parameters. Accelerations by one forward recursion over the frames: origin
    acceleration = the drift of ``planar_kernels._kinematics`` (the part at q'' = 0) + the part linear in
    q'': l_k = l_par + alpha_par perp(r_k) (+ e_k q''_k for a prism), alpha_k = alpha_par (+ q''_k for a
    hinge), r_k the origin's offset from its parent's, perp(x, z) = (-z, x); a point r from the origin of
    frame j: a_j + alpha_j perp(r) - omega_j^2 r. Signs as ``planar_kernels``: angles counter-clockwise in
    the sagittal view (about -y), moments counter-clockwise."""
    n = ti[0]
    nb = ti[1]
    npar = D.shape[1]
    g = tf[0]
    K = np.empty((10, n))
    qf = np.zeros(n)
    vf = np.zeros(n)
    af = np.zeros(n)
    m = n - q.shape[0]
    for i in range(q.shape[0]):
        qf[m + i] = q[i]
        vf[m + i] = qd[i]
        af[m + i] = a[i]
    pk._kinematics(ti, tf, qf, vf, K)
    al = np.empty(n)
    lx = np.empty(n)
    lz = np.empty(n)
    for k in range(n):
        p = pk._parent(ti, k)
        if p < 0:
            alp, lxp, lzp, rx, rz = 0.0, 0.0, 0.0, 0.0, 0.0
        else:
            alp, lxp, lzp = al[p], lx[p], lz[p]
            rx = K[pk._PX, k] - K[pk._PX, p]
            rz = K[pk._PZ, k] - K[pk._PZ, p]
        lxk = lxp - alp * rz
        lzk = lzp + alp * rx
        typ = pk._jtype(ti, k)
        if typ == pk.REV:
            al[k] = alp + af[k]
        else:
            al[k] = alp
            if typ == pk.PX:
                lxk += K[pk._C, k] * af[k]
                lzk += K[pk._S, k] * af[k]
            else:
                lxk -= K[pk._S, k] * af[k]
                lzk += K[pk._C, k] * af[k]
        lx[k] = lxk
        lz[k] = lzk
    Y[:, :] = 0.0
    ob = pk.HEADER_F + 2 * n
    for b in range(nb):
        j = ti[pk.HEADER_I + 2 * n + b]
        Px, Pz, rx, rz = pk._point(K, j, tf[ob + nb + b], tf[ob + 2 * nb + b])
        om2 = K[pk._OM, j] * K[pk._OM, j]
        alpha = al[j]
        ax = K[pk._AX, j] + lx[j] - alpha * rz - om2 * rx
        az = K[pk._AZ, j] + lz[j] + alpha * rx - om2 * rz + g
        k = j
        while k >= 0:
            jx, jz, jw = pk._column(ti, K, k, Px, Pz)
            fm = jx * ax + jz * az
            fi = jw * alpha
            for c in range(npar):
                Y[k, c] += fm * D[b, c] + fi * D[nb + b, c]
            k = pk._parent(ti, k)


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


combine_numba = numba.njit(cache=True)(combine)   # the NumPy function compiled as it is (kept for comparison)


@numba.njit(cache=True, fastmath=_FAST)
def _matmul(X, Yb, out):
    """out (a, c) <- X (a, b) Yb (b, c) (plain loops: for these 2 to 9 row matrices a loop beats a BLAS call)."""
    for i in range(X.shape[0]):
        for k in range(Yb.shape[1]):
            v = 0.0
            for j in range(X.shape[1]):
                v += X[i, j] * Yb[j, k]
            out[i, k] = v


@numba.njit(cache=True, fastmath=_FAST)
def _matmul_bt(X, Yb, out):
    """out (a, c) <- X (a, b) Yb^T, Yb (c, b)."""
    for i in range(X.shape[0]):
        for k in range(Yb.shape[0]):
            v = 0.0
            for j in range(X.shape[1]):
                v += X[i, j] * Yb[k, j]
            out[i, k] = v


@numba.njit(cache=True, fastmath=_FAST)
def combine_kernel(Y, A, B, Ainv, r, S, cov_W_obs, W_obs_restart, Jj, cov_qd, use_cov, K, dt, since, restarted,
                   has_prev, Rres, theta, P, Yf, Yprev, W_t_restart, W_t, cov_W, dR, cov_dR):
    """:func:`combine` compiled, its products written as loops and its two solves by Cholesky (S_m = H P H^T
    + R_m and J_j J_j^T, both symmetric positive definite; ``planar_kernels.cholesky``): the same arguments,
    maths and results to round-off (tested against :func:`combine` run by NumPy on every branch). The SVD
    pseudo-inverse of the rank-deficient J_j stays NumPy's, as :func:`combine`'s."""
    npar = theta.shape[0]
    nj = Yf.shape[0]
    nr = 3                                   # the swing rows, joints 3..5 of the six
    if restarted:
        Yf[:, :] = 0.0
    else:
        f = math.exp(-K * dt)
        for i in range(nj):
            for c in range(npar):
                ymid = 0.5 * (Yprev[i, c] + Y[3 + i, c]) if has_prev else Y[3 + i, c]
                Yf[i, c] = f * Yf[i, c] + (1.0 - f) * ymid
        # RLS on the swing rows: r_s = H theta + noise, H = -(Y_f)_s
        H = np.empty((nr, npar))
        for i in range(nr):
            for c in range(npar):
                H[i, c] = -Yf[3 + i, c]
        Rm = np.empty((nr, nr))
        for i in range(nr):
            for k in range(nr):
                Rm[i, k] = Rres[i, k]
        if use_cov:
            T = np.empty((nr, nj))                   # A_s cov
            for i in range(nr):
                for k in range(nj):
                    v = 0.0
                    for j in range(nj):
                        v += A[3 + i, j] * cov_qd[j, k]
                    T[i, k] = v
            k2 = K * K
            for i in range(nr):
                for k in range(nr):
                    v = 0.0
                    for j in range(nj):
                        v += T[i, j] * A[3 + k, j]
                    Rm[i, k] += k2 * v
        PHt = np.empty((npar, nr))
        _matmul_bt(P, H, PHt)
        Sm = np.empty((nr, nr))
        _matmul(H, PHt, Sm)
        for i in range(nr):
            for k in range(nr):
                Sm[i, k] += Rm[i, k]
        Ls = np.empty((nr, nr))
        gain = PHt.copy()                            # rows: (S_m^-1 PH^T row)^T = gain's rows (S_m symmetric)
        if pk.cholesky(Sm, Ls):
            pk.chol_solve_rows(Ls, gain)
        else:                                        # not positive definite (a non-finite input): as NumPy would
            gain[:, :] = np.linalg.solve(Sm, np.ascontiguousarray(PHt.T)).T
        inn = np.empty(nr)
        for i in range(nr):
            v = r[3 + i]
            for c in range(npar):
                v -= H[i, c] * theta[c]
            inn[i] = v
        for c in range(npar):
            v = 0.0
            for i in range(nr):
                v += gain[c, i] * inn[i]
            theta[c] += v
        IKH = np.empty((npar, npar))
        _matmul(gain, H, IKH)
        for i in range(npar):
            for k in range(npar):
                IKH[i, k] = (1.0 if i == k else 0.0) - IKH[i, k]
        T1 = np.empty((npar, npar))
        _matmul(IKH, P, T1)
        GR = np.empty((npar, nr))
        _matmul(gain, Rm, GR)
        for i in range(npar):
            for k in range(npar):
                v = 0.0
                for j in range(npar):
                    v += T1[i, j] * IKH[k, j]
                w = 0.0
                for j in range(nr):
                    w += GR[i, j] * gain[k, j]
                P[i, k] = v + w                      # Joseph form
    for i in range(nj):
        for c in range(npar):
            Yprev[i, c] = Y[3 + i, c]
    # the torso wrench from what the legs' error does not explain
    decay = math.exp(-K * since)
    dW = np.empty(3)
    for a in range(3):
        dW[a] = (W_obs_restart[a] - W_t_restart[a]) * decay
    r_t = np.empty(nj)
    for i in range(nj):
        v = r[i]
        for c in range(npar):
            v += Yf[i, c] * theta[c]
        for a in range(3):
            v -= Jj[a, i] * dW[a]
        r_t[i] = v
    # J_j^{T+}: as combine (the normal equations where J_j J_j^T is well conditioned, else the SVD)
    JJ = np.empty((3, 3))
    _matmul_bt(Jj, Jj, JJ)
    det = (JJ[0, 0] * (JJ[1, 1] * JJ[2, 2] - JJ[1, 2] * JJ[2, 1])
           - JJ[0, 1] * (JJ[1, 0] * JJ[2, 2] - JJ[1, 2] * JJ[2, 0])
           + JJ[0, 2] * (JJ[1, 0] * JJ[2, 1] - JJ[1, 1] * JJ[2, 0]))
    tr = (JJ[0, 0] + JJ[1, 1] + JJ[2, 2]) / 3.0
    pinv = np.empty((3, nj))
    Lj = np.empty((3, 3))
    if det > 1e-6 * tr * tr * tr and pk.cholesky(JJ, Lj):
        pinvT = np.ascontiguousarray(Jj.T)       # rows: columns of J_j, solved
        pk.chol_solve_rows(Lj, pinvT)
        for a in range(3):
            for k in range(nj):
                pinv[a, k] = pinvT[k, a]
    else:
        pinv[:, :] = np.linalg.pinv(np.ascontiguousarray(Jj.T))
    for a in range(3):
        v = 0.0
        for k in range(nj):
            v += pinv[a, k] * r_t[k]
        W_t[a] = v
    for a in range(3):
        for c in range(3):
            cov_W[a, c] = cov_W_obs[a, c]
        wr = W_t_restart[a] * decay
        wo = W_obs_restart[a] * decay
        cov_W[a, a] += wr * wr - wo * wo
    # G = (-B A^-1 Y_j + Y_r)[:2], G_t = G + S J_j^{T+} Y_f
    BA = np.empty((2, nj))
    _matmul(B[:2], Ainv, BA)
    G = np.empty((2, npar))
    for a in range(2):
        for c in range(npar):
            v = 0.0
            for k in range(nj):
                v += BA[a, k] * Y[3 + k, c]
            G[a, c] = Y[a, c] - v
    SP = np.empty((2, nj))
    _matmul(S, pinv, SP)
    Gt = np.empty((2, npar))
    _matmul(SP, Yf, Gt)
    for a in range(2):
        for c in range(npar):
            Gt[a, c] += G[a, c]
    for a in range(2):
        v = 0.0
        for c in range(3):
            v += S[a, c] * W_t[c]
        for c in range(npar):
            v += G[a, c] * theta[c]
        dR[a] = v
    SC = np.empty((2, 3))
    _matmul(S, cov_W, SC)
    GP = np.empty((2, npar))
    _matmul(Gt, P, GP)
    for a in range(2):
        for b in range(2):
            v = 0.0
            for c in range(3):
                v += SC[a, c] * S[b, c]
            for c in range(npar):
                v += GP[a, c] * Gt[b, c]
            cov_dR[a, b] = v


# ------------------------------------------------------------------------------------------ one sample
@numba.njit(cache=True, fastmath=_FAST)
def update(ti, tf, D, q, qd, A, B, H, Jj, r, S, cov_W_obs, W_obs_restart, since, cov_qd, K, dt, restarted,
           has_applied, applied, Rres, theta, P, Yf, Yprev, W_t_restart, last_torque, flags, W_t, cov_W, dR, cov_dR):
    """One observer sample of the estimator: ``LegModelError.update``'s maths after its model terms, in place
    (the compiled pipeline's; ``LegModelError`` stays the oracle). In: the state the observer saw (q, q')
    [rad, rad/s], the model's A (6, 6), B (3, 6) (root rows), H (6,) there (the observer's
    ``estimation_kernels.momentum_terms``), J_j (3, 6) the torso wrench Jacobian's joint columns, the
    observer's r (6,) [N m], S (2, 3), cov_W_obs (3, 3), the wrench it carried at its last restart
    W_obs_restart (3,) and the time since [s], the rate covariance cov_qd (6, 6), K [1/s], dt [s],
    ``restarted`` (the observer restarted at this sample), ``has_applied`` and ``applied`` (6,) [N m] the
    torque over the interval that led here in this stance's paper order, Rres = s_res^2 1 (3, 3). State,
    updated: theta (6,), P (6, 6), Y_f (6, 6), Yprev (6, 6), W_t_restart (3,), last_torque (6,), flags (3,)
    = [a Y_j of the last sample is in Yprev (0/1), last_torque holds a torque (0/1), RLS updates made].
    W_t (3,): in, the last sample's torso wrench; out, this sample's. Out: cov_W (3, 3), dR (2,) [N],
    cov_dR (2, 2).

    As ``LegModelError.update``: the acceleration a = A^-1 (Gamma - H + r) under the torque applied, or at a
    restart (or without a torque) a = A^-1 (relabel(the last torque) - H) (0 torque before any), relabel
    = -x[::-1]; Y = :func:`regressor_into` at (q, q', a); at a restart W_t_restart <- the last torso wrench,
    otherwise one more update counted; then :func:`combine_kernel`. A^-1 by Cholesky (``LegModelError``:
    NumPy's LU inverse; the same to round-off). Returns False (nothing changed) if A is not positive
    definite."""
    nj = A.shape[0]
    L = np.empty((nj, nj))
    if not pk.cholesky(A, L):
        return False
    Ainv = np.eye(nj)                     # rows of 1 solved: A^-1 (symmetric)
    pk.chol_solve_rows(L, Ainv)
    tq = np.zeros(nj)
    b = np.empty(nj)
    if restarted or not has_applied:
        if flags[1] != 0.0:
            for i in range(nj):
                tq[i] = -last_torque[nj - 1 - i]
        for i in range(nj):
            b[i] = tq[i] - H[i]
    else:
        for i in range(nj):
            tq[i] = applied[i]
            b[i] = tq[i] - H[i] + r[i]
            last_torque[i] = tq[i]
        flags[1] = 1.0
    acc = np.empty(nj)
    for i in range(nj):
        v = 0.0
        for k in range(nj):
            v += Ainv[i, k] * b[k]
        acc[i] = v
    Y = np.empty((nj + 3, theta.shape[0]))
    regressor_into(ti, tf, D, q, qd, acc, Y)
    if restarted:
        W_t_restart[:] = W_t
    else:
        flags[2] += 1.0
    combine_kernel(Y, A, B, Ainv, r, S, cov_W_obs, W_obs_restart, Jj, cov_qd, True, K, dt, since, restarted,
                   flags[0] != 0.0, Rres, theta, P, Yf, Yprev, W_t_restart, W_t, cov_W, dR, cov_dR)
    flags[0] = 1.0
    return True
