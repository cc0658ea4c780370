"""The legs' model-error estimator's algebra after its regressor (``model_error``, issue 22), as one function
run either by NumPy (``combine``, the oracle) or compiled by Numba (``combine_kernel``). A kernel module:
import it with ``model_error.load_model_error_kernels`` (``biped_sim.robot.numba_cache.load``), never
directly. The maths, units and conventions: ``model_error``'s module docstring and ``combine``'s."""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_sim.robot.numba_cache import require_configured

require_configured(__name__)


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


combine_kernel = numba.njit(cache=True)(combine)
