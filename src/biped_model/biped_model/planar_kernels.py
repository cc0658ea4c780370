"""Compiled dynamics of a planar rigid-body tree (numba), for the fast engine.

Pure numerics: NumPy + numba, no ROS, no Pinocchio. ``fast_engine`` builds the parameter arrays from
a ``RobotDescription``; nothing about the biped is typed here.

Model (sagittal x-z plane, world x forward, z up, angles counter-clockwise in that view, i.e. about
-y like every joint of the URDF). ``nj`` one-DOF joints, each with a parent joint of lower index (-1:
the world), so ``q``/``v`` have ``nj`` entries in joint order. Joint ``k`` sits at the offset ``d_k``
(2-vector, [m]) in its parent's frame and is

* ``PX``/``PZ``: a prism along the parent frame's x / z axis: ``p_k = p_par + R(th_par) (d_k + q_k e)``,
  ``th_k = th_par``;
* ``REV``: a hinge: ``p_k = p_par + R(th_par) d_k``, ``th_k = th_par + q_k``;

with ``R(t) = [[cos t, -sin t], [sin t, cos t]]``. ``nb`` rigid bodies, each fixed to one joint frame:
mass ``m`` [kg], centre of mass ``c`` (2-vector in that frame) [m], rotational inertia ``I`` about the
centre of mass and the plane's normal [kg m^2]. Gravity ``g`` [m/s^2] along -z.

Equations of motion ``M(q) a + h(q, v) = tau`` with, per body b (centre of mass ``P_b``, linear
Jacobian ``J_b`` (2 x nj), angular Jacobian ``w_b`` (1 x nj), entries 1 on its hinge ancestors):

    M = sum_b m_b J_b^T J_b + I_b w_b^T w_b
    h = sum_b J_b^T m_b (Jdot_b v + [0, g])        (planar: no gyroscopic term, wdot_b v = 0)

``Jdot_b v`` (the point's acceleration at ``a = 0``, "drift") comes from one forward recursion: for
a frame origin ``a_k = a_par - om_par^2 r_k`` (``+ 2 om_par perp(e) v_k`` for a prism), for a point
``r`` fixed in frame j ``a_j - om_j^2 r``; ``perp(x, z) = (-z, x)``, ``r`` in world axes.

The building blocks that other kernel modules compose (the controller's sensing and model-error kernels)
are public: the kinematics array ``K`` (rows ``K_TH``, ``K_C``, ``K_S`` angle and its cos, sin; ``K_PX``,
``K_PZ`` origin; ``K_OM`` angular velocity; ``K_VX``, ``K_VZ`` origin velocity; ``K_AX``, ``K_AZ`` origin
drift acceleration; ``K_ROWS`` rows) filled by :func:`kinematics`, the scratch of :func:`workspace`, the tree
accessors :func:`parent` and :func:`joint_type`, :func:`frame_point`, :func:`jacobian_column`,
:func:`point_jacobian` and :func:`composite_mass_bias` (M, h from a filled K). ``_``-prefixed names are this
module's own.

Parameter arrays (built and checked by ``fast_engine.tree_arrays``):

    ti (int64):   [nj, nb, push_joint, foot_0, foot_1, parent[nj], jtype[nj], body_joint[nb]]
    tf (float64): [g, l_min, l_max, dx[nj], dz[nj], m[nb], cx[nb], cz[nb], I[nb]]

``foot_0``/``foot_1``: the joints whose frame origins are the contact points (ankles, on the sole
line); a sole runs from ``l_min`` to ``l_max`` [m] along its frame's x axis. ``push_joint``: the
frame that carries pushes (the torso); a push point ``height`` [m] sits at ``(0, height)`` in it.
The floating-base kernels (projection, RK4 step) further require joints 0, 1, 2 to be PX, PZ, REV
from the world at zero offsets, and take joint torques for joints 3..nj-1 (``tau_j``, nj - 3).

Contact rows of a foot (x, z, pitch of its frame): ``J_c v = 0`` while held; the ground's action
``lambda = [F_x, F_z, m]`` (force [N], counter-clockwise moment about the ankle [N m]) enters the
dynamics as ``J_c^T lambda``. Public kernels write into caller-owned output arrays and return an int
status: ``STATUS_OK`` or ``STATUS_SINGULAR`` (a matrix that must be positive definite is not, e.g.
after a non-finite state); outputs are then undefined.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from biped_model import numba_cache
from biped_model.planar_abi import (  # noqa: F401  (the kernels' constants, also read as pk.<name>)
    HEADER_F, HEADER_I, IMPACT_SIZE, PERIOD_DONE, PERIOD_EVENT, PERIOD_LIMITS_SIZE, PERIOD_OUT_SIZE, POINT_SIZE,
    PROBE_SIZE, PX, PZ, REV, STATUS_OK, STATUS_SINGULAR)

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

# rows of the kinematics array K (10, nj)
K_TH, K_C, K_S, K_PX, K_PZ, K_OM, K_VX, K_VZ, K_AX, K_AZ = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
K_ROWS = 10

# numba types of the public kernels' arguments (explicit signatures: compiled once, all together; a
# wrong dtype or layout raises TypeError instead of compiling a slow variant)
_VI, _V, _MAT, _F, _I = "int64[::1]", "float64[::1]", "float64[:, ::1]", "float64", "int64"


def _sig(*args: str) -> str:
    return "int64(" + ", ".join(args) + ")"


# ------------------------------------------------------------------------------------------ layout
@njit(cache=True)
def parent(ti, k):
    return ti[HEADER_I + k]


@njit(cache=True)
def joint_type(ti, k):
    return ti[HEADER_I + ti[0] + k]


@njit(cache=True)
def _foot_joint(ti, foot):
    return ti[3 + foot]


# ------------------------------------------------------------------------------------------ workspace
@njit(cache=True)
def workspace(nj):
    """Scratch for one top-level call: K (10, nj) kinematics; M, L (nj, nj); R (10, nj) rows: contact
    Jacobian J (0-2), Y = (M^-1 J^T)^T (3-5) followed by one more solved vector (6), point Jacobian
    (7-9); U (8, nj) vectors; Cm (7, nj) composite-body sums."""
    K = np.empty((K_ROWS, nj))
    M = np.empty((nj, nj))
    L = np.empty((nj, nj))
    R = np.empty((10, nj))
    U = np.empty((8, nj))
    Cm = np.empty((7, nj))
    return K, M, L, R, U, Cm


# ------------------------------------------------------------------------------------------ kinematics
@njit(cache=True)
def kinematics(ti, tf, q, v, K):
    """Forward recursion over the joint frames: absolute angle (and its cos, sin), origin position,
    angular velocity, origin velocity and origin drift acceleration."""
    nj = ti[0]
    for k in range(nj):
        p = ti[HEADER_I + k]
        typ = ti[HEADER_I + nj + k]
        if p < 0:
            thp, cp, sp, pxp, pzp, omp, vxp, vzp, axp, azp = 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        else:
            thp, cp, sp = K[K_TH, p], K[K_C, p], K[K_S, p]
            pxp, pzp, omp = K[K_PX, p], K[K_PZ, p], K[K_OM, p]
            vxp, vzp, axp, azp = K[K_VX, p], K[K_VZ, p], K[K_AX, p], K[K_AZ, p]
        dx = tf[HEADER_F + k]
        dz = tf[HEADER_F + nj + k]
        if typ == PX:
            dx += q[k]
        elif typ == PZ:
            dz += q[k]
        rx = cp * dx - sp * dz
        rz = sp * dx + cp * dz
        K[K_PX, k] = pxp + rx
        K[K_PZ, k] = pzp + rz
        K[K_VX, k] = vxp - omp * rz
        K[K_VZ, k] = vzp + omp * rx
        w2 = omp * omp
        K[K_AX, k] = axp - w2 * rx
        K[K_AZ, k] = azp - w2 * rz
        if typ == REV:
            t = thp + q[k]
            K[K_TH, k] = t
            K[K_C, k] = math.cos(t)
            K[K_S, k] = math.sin(t)
            K[K_OM, k] = omp + v[k]
        else:
            K[K_TH, k] = thp
            K[K_C, k] = cp
            K[K_S, k] = sp
            K[K_OM, k] = omp
            if typ == PX:
                ex, ez = cp, sp
            else:
                ex, ez = -sp, cp
            K[K_VX, k] += ex * v[k]
            K[K_VZ, k] += ez * v[k]
            K[K_AX, k] += -2.0 * omp * ez * v[k]
            K[K_AZ, k] += 2.0 * omp * ex * v[k]


@njit(cache=True)
def jacobian_column(ti, K, k, Px, Pz):
    """Column k of the (x, z, angle) Jacobian of the world point (Px, Pz) moving with a descendant of k."""
    typ = joint_type(ti, k)
    if typ == REV:
        return -(Pz - K[K_PZ, k]), Px - K[K_PX, k], 1.0
    if typ == PX:
        return K[K_C, k], K[K_S, k], 0.0
    return -K[K_S, k], K[K_C, k], 0.0


@njit(cache=True)
def frame_point(K, j, lx, lz):
    """World (x, z) of the point (lx, lz) of frame j and its offset r from the frame origin."""
    rx = K[K_C, j] * lx - K[K_S, j] * lz
    rz = K[K_S, j] * lx + K[K_C, j] * lz
    return K[K_PX, j] + rx, K[K_PZ, j] + rz, rx, rz


@njit(cache=True)
def point_jacobian(ti, K, j, lx, lz, J):
    """J (3, nj) <- rows (x, z, angle) of the velocity of the point (lx, lz) of frame j. Returns its
    world position."""
    J[:, :] = 0.0
    Px, Pz, _, _ = frame_point(K, j, lx, lz)
    k = j
    while k >= 0:
        jx, jz, jw = jacobian_column(ti, K, k, Px, Pz)
        J[0, k] = jx
        J[1, k] = jz
        J[2, k] = jw
        k = parent(ti, k)
    return Px, Pz


@njit(cache=True)
def composite_mass_bias(ti, tf, K, M, h, Cm):
    """M (nj, nj) and h (nj,) = Coriolis + centrifugal + gravity forces, by composite bodies.

    For the subtree of joint j (bodies on j and its descendants), with positions relative to the
    origin o of frame 0: mass m_j, first moment S_j = sum m P, second moment Q_j = sum (m |P|^2 + I),
    force F_j = sum f_b and moment N_j = sum P_b x f_b of the bodies' inertial + weight forces
    f_b = m_b (drift_b + [0, g]) (a x b = a_x b_z - a_z b_x). For i an ancestor of j (or i = j), with
    unit motions dP/dq = perp(P - p) for a hinge and the world axis e for a prism:
        hinge i, hinge j:  M_ij = Q_j - (p_i + p_j) . S_j + m_j p_i . p_j
        prism i, hinge j:  M_ij = e_i . perp(S_j - m_j p_j)     (and symmetrically)
        prism i, prism j:  M_ij = m_j e_i . e_j
        h_j = N_j - p_j x F_j (hinge),  e_j . F_j (prism).
    Cm: scratch (7, nj)."""
    nj, nb = ti[0], ti[1]
    g = tf[0]
    ob = HEADER_F + 2 * nj
    ox = K[K_PX, 0]
    oz = K[K_PZ, 0]
    Cm[:, :] = 0.0
    for b in range(nb):
        j = ti[HEADER_I + 2 * nj + b]
        m = tf[ob + b]
        Px, Pz, rx, rz = frame_point(K, j, tf[ob + nb + b], tf[ob + 2 * nb + b])
        Px -= ox
        Pz -= oz
        w2 = K[K_OM, j] * K[K_OM, j]
        fx = m * (K[K_AX, j] - w2 * rx)
        fz = m * (K[K_AZ, j] - w2 * rz + g)
        Cm[0, j] += m
        Cm[1, j] += m * Px
        Cm[2, j] += m * Pz
        Cm[3, j] += m * (Px * Px + Pz * Pz) + tf[ob + 3 * nb + b]
        Cm[4, j] += fx
        Cm[5, j] += fz
        Cm[6, j] += Px * fz - Pz * fx
    for k in range(nj - 1, 0, -1):
        p = ti[HEADER_I + k]
        if p >= 0:
            for r in range(7):
                Cm[r, p] += Cm[r, k]
    M[:, :] = 0.0
    for j in range(nj):
        mj, sx, sz, qj = Cm[0, j], Cm[1, j], Cm[2, j], Cm[3, j]
        pjx = K[K_PX, j] - ox
        pjz = K[K_PZ, j] - oz
        tj = joint_type(ti, j)
        ux = uz = ejx = ejz = 0.0
        if tj == REV:
            h[j] = Cm[6, j] - (pjx * Cm[5, j] - pjz * Cm[4, j])
            # perp(S_j - m_j p_j), used against prisms above j
            ux = -(sz - mj * pjz)
            uz = sx - mj * pjx
        else:
            if tj == PX:
                ejx, ejz = K[K_C, j], K[K_S, j]
            else:
                ejx, ejz = -K[K_S, j], K[K_C, j]
            h[j] = ejx * Cm[4, j] + ejz * Cm[5, j]
        i = j
        while i >= 0:
            typ_i = joint_type(ti, i)
            if typ_i == REV:
                pix = K[K_PX, i] - ox
                piz = K[K_PZ, i] - oz
                if tj == REV:
                    val = qj - ((pix + pjx) * sx + (piz + pjz) * sz) + mj * (pix * pjx + piz * pjz)
                else:
                    val = ejx * (-(sz - mj * piz)) + ejz * (sx - mj * pix)
            else:
                if typ_i == PX:
                    eix, eiz = K[K_C, i], K[K_S, i]
                else:
                    eix, eiz = -K[K_S, i], K[K_C, i]
                if tj == REV:
                    val = eix * ux + eiz * uz
                else:
                    val = mj * (eix * ejx + eiz * ejz)
            M[i, j] = val
            M[j, i] = val
            i = ti[HEADER_I + i]


@njit(cache=True)
def _energy(ti, tf, K, out):
    """out <- [kinetic [J], potential [J] (zero at z = 0), centre of mass x, z [m], total mass [kg]]."""
    nj, nb = ti[0], ti[1]
    g = tf[0]
    ob = HEADER_F + 2 * nj
    ke = 0.0
    pe = 0.0
    mx = 0.0
    mz = 0.0
    mt = 0.0
    for b in range(nb):
        j = ti[HEADER_I + 2 * nj + b]
        m = tf[ob + b]
        inert = tf[ob + 3 * nb + b]
        Px, Pz, rx, rz = frame_point(K, j, tf[ob + nb + b], tf[ob + 2 * nb + b])
        om = K[K_OM, j]
        vx = K[K_VX, j] - om * rz
        vz = K[K_VZ, j] + om * rx
        ke += 0.5 * m * (vx * vx + vz * vz) + 0.5 * inert * om * om
        pe += m * g * Pz
        mx += m * Px
        mz += m * Pz
        mt += m
    out[0] = ke
    out[1] = pe
    out[2] = mx / mt
    out[3] = mz / mt
    out[4] = mt


# ------------------------------------------------------------------------------------------ linear algebra
@njit(cache=True)
def cholesky(A, L):
    """Lower Cholesky factor A = L L^T of the symmetric positive definite A (n, n), stored in L with its
    diagonal inverted (L[j, j] holds 1 / L_jj: the solves multiply instead of divide). False if A is
    not positive definite."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:  # also catches NaN
            return False
        inv = 1.0 / math.sqrt(s)
        L[j, j] = inv
        for i in range(j + 1, n):
            t = A[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t * inv
    return True


@njit(cache=True)
def chol_solve_rows(L, B):
    """Every row b of B (r, n) <- A^-1 b, A = L L^T (factor from cholesky). The rows are processed
    side by side so that their dependency chains overlap."""
    r, n = B.shape
    for i in range(n):
        for q in range(r):
            s = B[q, i]
            for k in range(i):
                s -= L[i, k] * B[q, k]
            B[q, i] = s * L[i, i]
    for i in range(n - 1, -1, -1):
        for q in range(r):
            s = B[q, i]
            for k in range(i + 1, n):
                s -= L[k, i] * B[q, k]
            B[q, i] = s * L[i, i]


@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True)
def _schur3(J, Y, rhs, lam):
    """lam <- (J Y^T)^-1 rhs for the 3 x 3 symmetric positive definite G = J M^-1 J^T (Y = (M^-1 J^T)^T),
    by a scalar Cholesky factorisation. False if G is not positive definite."""
    g00 = _dot(J[0], Y[0])
    g10 = _dot(J[1], Y[0])
    g20 = _dot(J[2], Y[0])
    g11 = _dot(J[1], Y[1])
    g21 = _dot(J[2], Y[1])
    g22 = _dot(J[2], Y[2])
    if not g00 > 0.0:
        return False
    l00 = math.sqrt(g00)
    l10 = g10 / l00
    l20 = g20 / l00
    d1 = g11 - l10 * l10
    if not d1 > 0.0:
        return False
    l11 = math.sqrt(d1)
    l21 = (g21 - l20 * l10) / l11
    d2 = g22 - l20 * l20 - l21 * l21
    if not d2 > 0.0:
        return False
    l22 = math.sqrt(d2)
    y0 = rhs[0] / l00
    y1 = (rhs[1] - l10 * y0) / l11
    y2 = (rhs[2] - l20 * y0 - l21 * y1) / l22
    lam[2] = y2 / l22
    lam[1] = (y1 - l21 * lam[2]) / l11
    lam[0] = (y0 - l10 * lam[1] - l20 * lam[2]) / l00
    return True


# ------------------------------------------------------------------------------------------ building blocks
@njit(cache=True)
def _contact_rows(ti, K, L, fj, J, Y):
    """J <- contact rows (x, z, pitch) of frame fj; Y <- (M^-1 J^T)^T using the factor L of M (Y may
    carry extra rows, already filled, solved along)."""
    point_jacobian(ti, K, fj, 0.0, 0.0, J)
    for i in range(3):
        Y[i, :] = J[i, :]
    chol_solve_rows(L, Y)


@njit(cache=True)
def _generalized_force(ti, K, tau_j, forces, heights, Jp, tau):
    """tau <- [0, 0, 0, tau_j] + sum_i Jx_i^T forces[i]: joint torques [N m] and horizontal forces [N] at
    the points (0, heights[i]) of the push frame (Jx_i: x row of that point's Jacobian; Jp: scratch)."""
    nj = ti[0]
    tau[0] = 0.0
    tau[1] = 0.0
    tau[2] = 0.0
    for i in range(nj - 3):
        tau[3 + i] = tau_j[i]
    for i in range(forces.shape[0]):
        point_jacobian(ti, K, ti[2], 0.0, heights[i], Jp)
        for k in range(nj):
            tau[k] += Jp[0, k] * forces[i]


@njit(cache=True)
def _contact_accel(ti, tf, x, v, tau, fj, a, lam, W):
    """Contact dynamics at (x, v) under the generalized force tau (nj,): M a + h = tau + J^T lam,
    J a + Jdot v = 0 (Schur complement). K of W must hold the kinematics at (x, v). False if singular."""
    K, M, L, R, U, Cm = W
    h = U[0]
    rhs = U[1]
    J = R[0:3]
    Y = R[3:7]  # (M^-1 J^T)^T and, in row 3, a_free = M^-1 (tau - h)
    composite_mass_bias(ti, tf, K, M, h, Cm)
    if not cholesky(M, L):
        return False
    for k in range(a.shape[0]):
        Y[3, k] = tau[k] - h[k]
    _contact_rows(ti, K, L, fj, J, Y)
    af = Y[3]
    rhs[0] = -K[K_AX, fj] - _dot(J[0], af)
    rhs[1] = -K[K_AZ, fj] - _dot(J[1], af)
    rhs[2] = -_dot(J[2], af)
    if not _schur3(J, Y, rhs, lam):
        return False
    for k in range(a.shape[0]):
        a[k] = af[k] + Y[0, k] * lam[0] + Y[1, k] * lam[1] + Y[2, k] * lam[2]
    return True


@njit(cache=True)
def _stage(ti, tf, x, v, tau_j, forces, heights, fj, a, lam, W):
    """Acceleration under constant joint torques and push forces (generalized force at this state)."""
    K = W[0]
    tau = W[4][2]
    Jp = W[3][7:10]
    kinematics(ti, tf, x, v, K)
    _generalized_force(ti, K, tau_j, forces, heights, Jp, tau)
    return _contact_accel(ti, tf, x, v, tau, fj, a, lam, W)


@njit(cache=True)
def _project(ti, tf, x, v, fj, anchor, W):
    """In place: put frame fj exactly on anchor = (x, z, pitch) (pitch first through x[2], then the
    position through x[0], x[1]) and remove the velocity normal to the contact manifold:
    v <- v - M^-1 J^T (J M^-1 J^T)^-1 J v (the M-orthogonal projection onto J v = 0)."""
    K, M, L, R, U, Cm = W
    kinematics(ti, tf, x, v, K)
    x[2] += anchor[2] - K[K_TH, fj]
    kinematics(ti, tf, x, v, K)
    x[0] += anchor[0] - K[K_PX, fj]
    x[1] += anchor[1] - K[K_PZ, fj]
    kinematics(ti, tf, x, v, K)
    composite_mass_bias(ti, tf, K, M, U[0], Cm)
    if not cholesky(M, L):
        return False
    J = R[0:3]
    Y = R[3:6]
    _contact_rows(ti, K, L, fj, J, Y)
    rhs = U[1]
    mu = U[3]
    rhs[0] = _dot(J[0], v)
    rhs[1] = _dot(J[1], v)
    rhs[2] = _dot(J[2], v)
    if not _schur3(J, Y, rhs, mu):
        return False
    for k in range(v.shape[0]):
        v[k] -= Y[0, k] * mu[0] + Y[1, k] * mu[1] + Y[2, k] * mu[2]
    return True


@njit(cache=True)
def _rk4(ti, tf, x, v, tau_j, forces, heights, foot, anchor, h, x_out, v_out, wrench, W, S):
    """One classical RK4 step of length h [s] (constant tau_j and push forces), then the projection.
    wrench <- lambda at the step start. S (9, nj): stage scratch."""
    fj = _foot_joint(ti, foot)
    n = x.shape[0]
    a1, a2, a3, a4 = S[0], S[1], S[2], S[3]
    xs, vs2, vs3, vs4 = S[4], S[5], S[6], S[7]
    lam = S[8][:3]
    if not _stage(ti, tf, x, v, tau_j, forces, heights, fj, a1, wrench, W):
        return False
    hh = 0.5 * h
    for k in range(n):
        xs[k] = x[k] + hh * v[k]
        vs2[k] = v[k] + hh * a1[k]
    if not _stage(ti, tf, xs, vs2, tau_j, forces, heights, fj, a2, lam, W):
        return False
    for k in range(n):
        xs[k] = x[k] + hh * vs2[k]
        vs3[k] = v[k] + hh * a2[k]
    if not _stage(ti, tf, xs, vs3, tau_j, forces, heights, fj, a3, lam, W):
        return False
    for k in range(n):
        xs[k] = x[k] + h * vs3[k]
        vs4[k] = v[k] + h * a3[k]
    if not _stage(ti, tf, xs, vs4, tau_j, forces, heights, fj, a4, lam, W):
        return False
    h6 = h / 6.0
    for k in range(n):
        x_out[k] = x[k] + h6 * (v[k] + 2.0 * vs2[k] + 2.0 * vs3[k] + vs4[k])
        v_out[k] = v[k] + h6 * (a1[k] + 2.0 * a2[k] + 2.0 * a3[k] + a4[k])
    return _project(ti, tf, x_out, v_out, fj, anchor, W)


@njit(cache=True)
def _probe(ti, tf, x, v, foot, out, W):
    """out <- [lowest sole z, ankle z rate, z rate of that lowest sole point] of a foot (heel at
    l_min, toe at l_max along its frame x; the heel wins a tie)."""
    K = W[0]
    J = W[3][7:10]
    kinematics(ti, tf, x, v, K)
    fj = _foot_joint(ti, foot)
    point_jacobian(ti, K, fj, 0.0, 0.0, J)
    th = K[K_TH, fj]
    l_min = tf[1]
    l_max = tf[2]
    z_heel = K[K_PZ, fj] + l_min * math.sin(th)
    z_toe = K[K_PZ, fj] + l_max * math.sin(th)
    if z_toe < z_heel:
        z, l = z_toe, l_max
    else:
        z, l = z_heel, l_min
    vz = _dot(J[1], v)
    om = _dot(J[2], v)
    out[0] = z
    out[1] = vz
    out[2] = vz + l * math.cos(th) * om


# ------------------------------------------------------------------------------------------ public kernels
@njit(_sig(_VI, _V, _V, _V, _MAT, _V), cache=True)
def mass_bias(ti, tf, q, v, M, h):
    """M <- M(q) (nj, nj); h <- h(q, v) (nj,) (Coriolis, centrifugal and gravity generalized forces)."""
    W = workspace(ti[0])
    kinematics(ti, tf, q, v, W[0])
    composite_mass_bias(ti, tf, W[0], M, h, W[5])
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _I, _F, _F, _MAT, _V), cache=True)
def point_state(ti, tf, q, v, joint, lx, lz, J, out):
    """Point (lx, lz) [m] of frame ``joint``: J (3, nj) <- rows (x, z, angle) of its velocity (world
    axes); out (8,) <- [x, z, angle, vx, vz, omega, drift_x, drift_z] (world position [m], absolute
    frame angle [rad], velocity J v, drift = acceleration at a = 0 [m/s^2]; the angular drift is 0)."""
    W = workspace(ti[0])
    K = W[0]
    kinematics(ti, tf, q, v, K)
    Px, Pz = point_jacobian(ti, K, joint, lx, lz, J)
    _, _, rx, rz = frame_point(K, joint, lx, lz)
    w2 = K[K_OM, joint] * K[K_OM, joint]
    out[0] = Px
    out[1] = Pz
    out[2] = K[K_TH, joint]
    out[3] = _dot(J[0], v)
    out[4] = _dot(J[1], v)
    out[5] = _dot(J[2], v)
    out[6] = K[K_AX, joint] - w2 * rx
    out[7] = K[K_AZ, joint] - w2 * rz
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _V), cache=True)
def energy(ti, tf, q, v, out):
    """out (5,) <- [kinetic [J], potential m g z [J], centre of mass x, z [m], total mass [kg]]."""
    W = workspace(ti[0])
    kinematics(ti, tf, q, v, W[0])
    _energy(ti, tf, W[0], out)
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _V, _V), cache=True)
def free_dynamics(ti, tf, q, v, tau, a):
    """a <- M^-1 (tau - h): acceleration with no contact (flight)."""
    K, M, L, R, U, Cm = workspace(ti[0])
    kinematics(ti, tf, q, v, K)
    composite_mass_bias(ti, tf, K, M, U[0], Cm)
    if not cholesky(M, L):
        return STATUS_SINGULAR
    for k in range(a.shape[0]):
        a[k] = tau[k] - U[0, k]
    chol_solve_rows(L, a.reshape((1, a.shape[0])))
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _V, _I, _V, _V), cache=True)
def contact_dynamics(ti, tf, x, v, tau, foot, a, lam):
    """a (nj,), lam (3,) <- solution of M a + h = tau + J_c^T lam, J_c a + Jdot_c v = 0 for the held
    foot ``foot`` (0/1) under the generalized force tau (nj,), by the Schur complement
    lam = (J M^-1 J^T)^-1 (-Jdot v - J M^-1 (tau - h)), a = M^-1 (tau - h + J^T lam)."""
    W = workspace(ti[0])
    kinematics(ti, tf, x, v, W[0])
    if not _contact_accel(ti, tf, x, v, tau, _foot_joint(ti, foot), a, lam, W):
        return STATUS_SINGULAR
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _I, _V, _V), cache=True)
def impact(ti, tf, x, v, new_foot, v_plus, out):
    """Inelastic impact of foot ``new_foot`` (it stops dead in x, z and pitch; the other is released):
    Lambda = -(J M^-1 J^T)^-1 J v-, v+ = v- + M^-1 J^T Lambda.
    v_plus (nj,) <- v+; out (7,) <- [Lambda (3) [N s, N s, N m s], velocity (x, z, pitch) of the
    other foot after the impact (3), kinetic energy lost 0.5 (v-^T M v- - v+^T M v+) [J]]."""
    K, M, L, R, U, Cm = workspace(ti[0])
    n = ti[0]
    kinematics(ti, tf, x, v, K)
    composite_mass_bias(ti, tf, K, M, U[0], Cm)
    if not cholesky(M, L):
        return STATUS_SINGULAR
    J = R[0:3]
    Y = R[3:6]
    _contact_rows(ti, K, L, _foot_joint(ti, new_foot), J, Y)
    rhs = U[1]
    lam = U[2]
    for i in range(3):
        rhs[i] = -_dot(J[i], v)
    if not _schur3(J, Y, rhs, lam):
        return STATUS_SINGULAR
    for k in range(n):
        v_plus[k] = v[k] + Y[0, k] * lam[0] + Y[1, k] * lam[1] + Y[2, k] * lam[2]
    Jo = R[7:10]
    point_jacobian(ti, K, _foot_joint(ti, 1 - new_foot), 0.0, 0.0, Jo)
    for i in range(3):
        out[i] = lam[i]
        out[3 + i] = _dot(Jo[i], v_plus)
    e_minus = 0.0
    e_plus = 0.0
    for i in range(n):
        si = 0.0
        sp = 0.0
        for k in range(n):
            si += M[i, k] * v[k]
            sp += M[i, k] * v_plus[k]
        e_minus += v[i] * si
        e_plus += v_plus[i] * sp
    out[6] = 0.5 * (e_minus - e_plus)
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _I, _V, _V, _V), cache=True)
def project(ti, tf, x, v, foot, anchor, x_out, v_out):
    """x_out, v_out <- the state put back on the contact manifold of ``foot`` at ``anchor`` (x, z,
    pitch): pitch fixed through x[2], then position through x[0], x[1] (joints 0-2 = the planar root);
    v_out = v - M^-1 J^T (J M^-1 J^T)^-1 J v at the corrected x."""
    W = workspace(ti[0])
    x_out[:] = x
    v_out[:] = v
    if not _project(ti, tf, x_out, v_out, _foot_joint(ti, foot), anchor, W):
        return STATUS_SINGULAR
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _V, _V, _V, _I, _V, _F, _V, _V, _V), cache=True)
def rk4_step(ti, tf, x, v, tau_j, forces, heights, foot, anchor, h, x_out, v_out, wrench):
    """One RK4 step of length h [s] of the contact-constrained dynamics, foot ``foot`` held, with the
    joint torques tau_j (nj - 3,) [N m] (joints 3.., URDF order) and horizontal forces ``forces[i]`` [N]
    at the points (0, ``heights[i]``) [m] of the push frame (empty arrays: no push), all constant over
    the step; then ``project`` onto the anchor. x_out, v_out <- the new state; wrench (3,) <- lambda = [F_x, F_z, m] at the step start."""
    n = ti[0]
    W = workspace(n)
    S = np.empty((9, n))
    if not _rk4(ti, tf, x, v, tau_j, forces, heights, foot, anchor, h, x_out, v_out, wrench, W, S):
        return STATUS_SINGULAR
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _V, _V, _V, _I, _V, _F, _MAT, _MAT, _MAT, _MAT), cache=True)
def rk4_steps(ti, tf, x, v, tau_j, forces, heights, foot, anchor, h, X, V, Wr, P):
    """``X.shape[0]`` consecutive ``rk4_step``s from (x, v) (same torques and pushes). X[i], V[i] <- the
    state after step i; Wr[i] (3,) <- lambda at the start of step i; P[i] (3,) <- probe of the other
    (swing) foot after step i: [lowest sole z [m], ankle z rate [m/s], z rate of that sole point
    [m/s]]. Returns the number of steps completed (X.shape[0] unless a step was singular)."""
    n = ti[0]
    W = workspace(n)
    S = np.empty((9, n))
    for i in range(X.shape[0]):
        xi = x if i == 0 else X[i - 1]
        vi = v if i == 0 else V[i - 1]
        if not _rk4(ti, tf, xi, vi, tau_j, forces, heights, foot, anchor, h, X[i], V[i], Wr[i], W, S):
            return i
        _probe(ti, tf, X[i], V[i], 1 - foot, P[i], W)
    return X.shape[0]


@njit(_sig(_VI, _V, _V, _V, _I, _V), cache=True)
def swing_probe(ti, tf, x, v, foot, out):
    """out (3,) <- [lowest sole z [m], ankle z rate [m/s], z rate of that lowest sole point [m/s]] of
    foot ``foot``: the quantities of the simulator's touchdown test."""
    W = workspace(ti[0])
    _probe(ti, tf, x, v, foot, out, W)
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _F, _MAT, _V, _MAT, _V, _V), cache=True)
def fixed_root_terms(ti, tf, q, qd, height, A, H, B, hb, jp):
    """Chain on a locked planar root (joints 0-2 at rest at zero), actuated joints 3..nj-1 at (q, qd):
    with M, h of the whole tree, A <- M[3:, 3:], H <- h[3:], B <- M[:3, 3:], hb <- h[:3] (so the
    joint torques are A w + H and the root's generalized forces, i.e. the ground's action on the
    root body, B w + hb); jp (nj,) <- x row of the Jacobian of the point (0, height) of the push
    frame w.r.t. all nj coordinates (root included)."""
    n = ti[0]
    K, M, L, R, U, Cm = workspace(n)
    qf = U[4]
    vf = U[5]
    h = U[0]
    qf[:3] = 0.0
    vf[:3] = 0.0
    qf[3:] = q
    vf[3:] = qd
    kinematics(ti, tf, qf, vf, K)
    composite_mass_bias(ti, tf, K, M, h, Cm)
    m = n - 3
    for i in range(m):
        H[i] = h[3 + i]
        for k in range(m):
            A[i, k] = M[3 + i, 3 + k]
    for i in range(3):
        hb[i] = h[i]
        for k in range(m):
            B[i, k] = M[i, 3 + k]
    Jp = R[7:10]
    point_jacobian(ti, K, ti[2], 0.0, height, Jp)
    jp[:] = Jp[0]
    return STATUS_OK


@njit(_sig(_VI, _V, _V, _V, _V, _V, _V, _V, _I, _V, _V, _V, _V, _V, _V), cache=True)
def period(ti, tf, x, v, tau_j, knots, forces, heights, foot, anchor, lim, x_out, v_out, w0, out):
    """One control period of the simulator in one call, for the common case with nothing to decide.

    The integration intervals [knots[i], knots[i+1]] (RK4 substeps, already split at push starts and
    ends) are integrated one ``rk4_step`` each with the held URDF torques tau_j and, on interval i, the
    horizontal push ``forces[i]`` [N] at ``heights[i]`` [m] above the hip (NaN height: no push), foot
    ``foot`` held at ``anchor``. At each interval start the contact wrench lambda = [F_x, F_z, m] is
    checked as the simulator's fall test does (finite, F_z > 0, |F_x| <= mu F_z, l = m / F_z within
    [l_min, l_max]); after each interval the other foot's lowest sole point z is probed: touchdown
    candidate when the foot has cleared (lim[6] or z > clearance on an earlier interval) and z <=
    touchdown_tolerance; a foot that has not cleared and sinks below -liftoff_penetration is a fall.

    lim = [mu, l_min, l_max, touchdown_tolerance [m], clearance [m], liftoff_penetration [m], cleared (0/1)].
    Outcome out = [status, cleared after (0/1), push impulse sum_i forces[i] (knots[i+1] - knots[i]) [N s],
    event interval]. PERIOD_DONE: x_out, v_out hold the state at knots[-1], w0 the wrench at knots[0].
    PERIOD_EVENT: a wrench check failed, a touchdown candidate, a sinking foot, a non-finite or singular
    state on interval out[3]: the caller integrates the whole period again on its event path (x, v are
    never modified; x_out, v_out, w0 are then undefined)."""
    n = ti[0]
    W = workspace(n)
    S = np.empty((9, n))
    P = np.empty(PROBE_SIZE)
    xa = np.empty(n)
    va = np.empty(n)
    wi = np.empty(3)
    xa[:] = x
    va[:] = v
    mu, l_min, l_max = lim[0], lim[1], lim[2]
    cleared = lim[6] != 0.0
    impulse = 0.0
    out[0] = PERIOD_EVENT
    out[2] = 0.0
    for i in range(knots.shape[0] - 1):
        out[3] = i
        t0 = knots[i]
        t1 = knots[i + 1]
        if math.isnan(heights[i]):
            fs = forces[0:0]
            hs = heights[0:0]
            f = 0.0
        else:
            fs = forces[i:i + 1]
            hs = heights[i:i + 1]
            f = forces[i]
        if not _rk4(ti, tf, xa, va, tau_j, fs, hs, foot, anchor, t1 - t0, x_out, v_out, wi, W, S):
            return PERIOD_EVENT
        fx, fz, m = wi[0], wi[1], wi[2]
        if not (math.isfinite(fx) and math.isfinite(fz) and math.isfinite(m)):
            return PERIOD_EVENT
        if fz <= 0.0 or abs(fx) > mu * fz:
            return PERIOD_EVENT
        l = m / fz
        if l < l_min or l > l_max:
            return PERIOD_EVENT
        if i == 0:
            w0[:] = wi
        for k in range(n):
            if not (math.isfinite(x_out[k]) and math.isfinite(v_out[k])):
                return PERIOD_EVENT
        _probe(ti, tf, x_out, v_out, 1 - foot, P, W)
        z = P[0]
        if cleared and z <= lim[3]:
            return PERIOD_EVENT
        if z > lim[4]:
            cleared = True
        elif not cleared and z < -lim[5]:
            return PERIOD_EVENT
        impulse += f * (t1 - t0)
        xa[:] = x_out
        va[:] = v_out
    out[0] = PERIOD_DONE
    out[1] = 1.0 if cleared else 0.0
    out[2] = impulse
    out[3] = -1.0
    return PERIOD_DONE
