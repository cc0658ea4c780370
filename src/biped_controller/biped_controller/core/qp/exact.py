"""Exact solver of the adaptation QP for n = 1 and n = 2, in numpy: the reference (oracle) of
the other solvers (PIQP in :mod:`solver`, the numba kernel in :mod:`exact_kernels`).

Same problem, sign conventions, units and statuses as :mod:`problem`::

    minimise 1/2 (x - x*)^T W (x - x*)   s.t.   G x <= h,   W = diag(W) > 0,  G (m, n), n in {1, 2}.

Method (finite enumeration, pure numpy). The optimum is unique (strictly convex objective).
By the KKT conditions it is x* itself, or it has an active set whose normals have positive
multipliers; in 2-D a set of at most two linearly independent active rows suffices
(Caratheodory), so the optimum is one of

* x*                                   (if G x* <= h, tolerance 0 -> UNCONSTRAINED; G x* - h as
                                        evaluated by :func:`problem.constraint_values`),
* the W-projection of x* onto a line g_i x = h_i for a row with g_i x* > h_i
  ``x = x* - (g_i x* - h_i) / (g_i W^-1 g_i^T) W^-1 g_i^T``,
* a vertex g_i x = h_i, g_j x = h_j of two non-parallel rows (n = 2 only); its multipliers
  come from that pair, or, if one is negative (more than two rows through the vertex), from the
  first pair of rows through it whose multipliers are both >= 0.

Every feasible candidate has an objective >= the optimum, so the feasible candidate with the
least objective is the optimum (ties: the first in the fixed order x*, projections by row,
vertices by (i, j) lexicographic). Parallel / near-parallel pairs (|sin angle| <= parallel_tol)
are skipped: their vertex is either undefined or the optimum is also a projection candidate.
For n = 1 the same enumeration collapses to the interval [lo, hi] of the bounds h_i / g_i,
and x = clip(x*, lo, hi).

Zero-norm rows (|g_i| <= 1e-13 max_j |g_j|): the constraint 0 <= h_i is infeasible if
h_i < -tol, ignored otherwise.

No feasible candidate -> the problem is infeasible; the answer is the least-violation point
(see :func:`least_violation_exact`), status INFEASIBLE_FALLBACK.
"""

from __future__ import annotations

import numpy as np

from biped_controller.core.qp.problem import (
    ACTIVE,
    DEFAULT_ACTIVE_TOL,
    DEFAULT_EPS_REG,
    DEFAULT_FEAS_RTOL,
    DEFAULT_PARALLEL_TOL,
    DEFAULT_ZERO_ROW_RTOL,
    INFEASIBLE_FALLBACK,
    QPResult,
    ROUNDING_RTOL,
    QPShapeError,
    error_result,
    finish_result,
    nonfinite_name,
    unconstrained_result,
    constraint_values,
    validate,
    violation_message,
)

__all__ = ["solve_exact", "least_violation_exact", "min_piecewise_quadratic_1d", "reg_weight"]

# ----------------------------------------------------------------------------------------
# the exact least-violation point (the INFEASIBLE_FALLBACK answer for n <= 2)
# ----------------------------------------------------------------------------------------


def reg_weight(G, W, eps_reg: float = DEFAULT_EPS_REG) -> float:
    """Effective regularisation weight eps_eff = eps_reg * min_i |g_i W^-1/2|^2 (> 0).

    The minimum is over the rows with non-negligible norm (> 1e-13 of the largest). With this
    scaling the regulariser is dimensionally consistent with the squared violations, invariant
    to a common rescaling of W, and moves the answer by at most ~eps_reg |x - x*| along any
    row direction (pulling x towards x* costs violation^2 ~ |g_i W^-1/2|^2 delta^2 in every
    row), so eps_reg is a pure relative number.
    """
    n2 = np.sum(G * G / W[None, :], axis=1)
    big = float(np.max(n2, initial=0.0))
    if not (big > 0.0 and np.isfinite(big)):
        return eps_reg
    return eps_reg * float(np.min(n2[n2 > 1e-26 * big]))


def min_piecewise_quadratic_1d(alpha, beta, q: float, t0: float) -> float:
    """Exact minimiser of phi(t) = sum_i max(alpha_i t - beta_i, 0)^2 + q (t - t0)^2, q >= 0.

    phi is convex and C^1; phi'(t)/2 = sum_i alpha_i max(alpha_i t - beta_i, 0) + q (t - t0)
    is continuous, non-decreasing and piecewise linear with kinks at t_i = beta_i / alpha_i.
    We evaluate it at the sorted kinks (vectorised, m x m), locate the interval where it
    changes sign, and solve the linear equation valid on that interval (fixed set S of
    positive terms): t = (sum_S alpha_i beta_i + q t0) / (sum_S alpha_i^2 + q).
    """
    alpha = np.asarray(alpha, float)
    beta = np.asarray(beta, float)
    nz = alpha != 0.0
    a, b = alpha[nz], beta[nz]
    if a.size == 0:
        return float(t0)
    bp = np.sort(b / a)
    D = np.sum(a[None, :] * np.maximum(a[None, :] * bp[:, None] - b[None, :], 0.0), axis=1) + q * (bp - t0)
    ge = D >= 0.0
    k = int(np.argmax(ge)) if np.any(ge) else bp.size
    if k < bp.size and D[k] == 0.0:
        return float(bp[k])
    lo = bp[k - 1] if k > 0 else -np.inf
    hi = bp[k] if k < bp.size else np.inf
    if np.isfinite(lo) and np.isfinite(hi):
        tm = 0.5 * (lo + hi)
    elif np.isfinite(lo):
        tm = lo + max(1.0, abs(lo))
    elif np.isfinite(hi):
        tm = hi - max(1.0, abs(hi))
    else:  # pragma: no cover - bp is non-empty
        tm = 0.0
    S = a * tm - b > 0.0
    den = float(np.dot(a[S], a[S])) + q
    if den <= 0.0:  # flat piece (q = 0, no positive term): phi' constant, pick the finite end
        return float(lo if np.isfinite(lo) else (hi if np.isfinite(hi) else t0))
    t = (float(np.dot(a[S], b[S])) + q * t0) / den
    return float(min(max(t, lo), hi))


def least_violation_exact(G, h, x_star, W, eps_reg: float = DEFAULT_EPS_REG, max_iter: int = 100):
    """Exact least-violation point for n in {1, 2}. Returns (x, iterations).

    Minimises ``V(x) = sum_i max(g_i x - h_i, 0)^2 + e (x - x*)^T W (x - x*)`` with
    ``e = reg_weight(G, W, eps_reg) > 0`` (see :func:`least_violation`).

    In scaled coordinates y = W^1/2 (x - x*), a_i = g_i W^-1/2, r_i = h_i - g_i x*:
    ``F(y) = sum_i max(a_i y - r_i, 0)^2 + e |y|^2`` — strongly convex, C^1, piecewise
    quadratic (one quadratic per cell of the arrangement of the lines a_i y = r_i).

    * n = 1: F is the 1-D function of :func:`min_piecewise_quadratic_1d` -> exact in one shot.
    * n = 2: generalised Newton with exact line search. At y let S = {i: a_i y > r_i}; the
      Newton direction d minimises the quadratic piece F_S; the step length minimises F exactly
      along y + t d (again a 1-D piecewise quadratic). F decreases strictly at every step that
      is not at the minimiser and has finitely many pieces, and once S is the optimal cell's set
      the full Newton step lands exactly on the minimiser (finite termination, as in
      Mangasarian's finite Newton method for piecewise-quadratic strongly convex functions).
      Stops when the full step is taken with an unchanged S, or the step is below rounding.
    """
    G, h, x_star, W = validate(G, h, x_star, W)
    n = G.shape[1]
    if n > 2:
        raise QPShapeError(f"least_violation_exact handles n = 1 or 2, G has {n} columns")
    sw = np.sqrt(W)
    A = G / sw[None, :]
    r = -constraint_values(G, x_star, h)
    e = reg_weight(G, W, eps_reg)
    if n == 1:
        t = min_piecewise_quadratic_1d(A[:, 0], r, e, 0.0)
        return x_star + np.array([t]) / sw, 1

    y = np.zeros(2)
    S_prev = None
    it = 0
    for it in range(1, max_iter + 1):
        u = A @ y - r
        S = u > 0.0
        AS = A[S]
        g = AS.T @ u[S] + e * y
        H = AS.T @ AS
        h00, h01, h11 = H[0, 0] + e, H[0, 1], H[1, 1] + e
        dH = h00 * h11 - h01 * h01
        if dH > 1e-13 * h00 * h11 and np.isfinite(dH):
            d = -np.array([h11 * g[0] - h01 * g[1], h00 * g[1] - h01 * g[0]]) / dH
        else:
            # numerically singular piece (one active row and a regularisation below rounding, e.g.
            # rows spanning many decades): minimum-norm Newton step; the exact line search below
            # still decreases F, so the iteration stays monotone and finite.
            d = -np.linalg.lstsq(np.array([[h00, h01], [h01, h11]]), g, rcond=1e-13)[0]
            if not np.all(np.isfinite(d)):
                break
        dd = float(d @ d)
        if not dd > (4e-16 * max(float(np.linalg.norm(y)), 1e-300)) ** 2:
            break
        t = min_piecewise_quadratic_1d(A @ d, -u, e * dd, -float(y @ d) / dd)
        y = y + t * d
        full = abs(t - 1.0) <= 1e-12
        if full and S_prev is not None and np.array_equal(S, S_prev):
            break
        S_prev = S if full else None
    return x_star + y / sw, it



_ZERO_ROW_RTOL = DEFAULT_ZERO_ROW_RTOL
_PAIR_CACHE: dict = {}


def _pairs(k: int):
    p = _PAIR_CACHE.get(k)
    if p is None:
        p = np.triu_indices(k, 1)
        _PAIR_CACHE[k] = p
    return p


def solve_exact(G, h, x_star, W, *, active_tol: float = DEFAULT_ACTIVE_TOL, eps_reg: float = DEFAULT_EPS_REG,
                feas_rtol: float = DEFAULT_FEAS_RTOL, parallel_tol: float = DEFAULT_PARALLEL_TOL) -> QPResult:
    """Exact QP solution for n in {1, 2}. Raises only :class:`QPShapeError`.

    feas_rtol : relative feasibility tolerance for candidates: row i accepts x when
        g_i x - h_i <= feas_rtol (|g_i| |x| + |h_i|) + ROUNDING_RTOL |g_i| |x*| (rounding of
        the candidate formulas; the last term for those computed from x*, see problem).
    parallel_tol : pairs with |det [g_i; g_j]| <= parallel_tol |g_i| |g_j| are not intersected.
    Multipliers z (>= 0, W (x - x*) + G^T z = 0) of the chosen candidate are returned in ``z``.
    """
    G, h, x_star, W = validate(G, h, x_star, W)
    m, n = G.shape
    if n > 2:
        raise QPShapeError(f"exact handles n = 1 or 2, G has {n} columns")
    bad = nonfinite_name(G, h, x_star, W)
    if bad is not None or not np.all(W > 0):
        return error_result(x_star, G, h, f"non-finite or invalid values in {bad or 'W'}", active_tol)
    v_star = constraint_values(G, x_star, h)
    if np.all(v_star <= 0.0):
        return unconstrained_result(x_star, v_star, active_tol)

    sq = np.einsum("ij,ij->i", G, G)
    gmax2 = sq.max() if m else 0.0
    zero = sq <= (_ZERO_ROW_RTOL * _ZERO_ROW_RTOL) * gmax2 if gmax2 > 0 else np.ones(m, dtype=bool)
    if zero.any():
        hscale = float(np.abs(h).max())
        if np.any(zero & (h < -feas_rtol * hscale)):
            return _infeasible(G, h, x_star, W, eps_reg, active_tol, "infeasible (zero-norm row with h < 0)")
        keep = np.flatnonzero(~zero)
        Gk, hk, vk, sqk = G[keep], h[keep], v_star[keep], sq[keep]
    else:
        keep = None
        Gk, hk, vk, sqk = G, h, v_star, sq
    z = np.zeros(m)

    if n == 1:
        g = Gk[:, 0]
        b = hk / g
        up = g > 0
        hi = b.min(where=up, initial=np.inf)
        lo = b.max(where=~up, initial=-np.inf)
        xs = x_star[0]
        if lo > hi and lo - hi > feas_rtol * (abs(lo) + abs(hi)):
            return _infeasible(G, h, x_star, W, eps_reg, active_tol)
        if lo > hi:  # within rounding: a single point
            x0 = 0.5 * (lo + hi)
        else:
            x0 = min(max(xs, lo), hi)
        if x0 != xs:
            # multiplier of the binding bound (the tightest one on the side of x*)
            i_loc = int(np.argmin(np.where(up, b, np.inf))) if xs > x0 else int(np.argmax(np.where(up, -np.inf, b)))
            z[i_loc if keep is None else keep[i_loc]] = W[0] * (xs - x0) / g[i_loc]
        return finish_result(np.array([x0]), G, h, ACTIVE, "solved (exact, n=1)", active_tol, 0, z)

    # ---- n == 2: candidate enumeration -------------------------------------------------
    # Stage 1: projections onto the violated rows. A feasible projection onto row i is the
    # optimum (it minimises the objective over the half-plane of row i, a superset of the
    # feasible set), so vertices are only needed when no projection is feasible.
    winv = 1.0 / W
    absG = np.abs(Gk)
    absh = np.abs(hk)
    viol = np.flatnonzero(vk > 0.0)
    WinvG = Gk[viol] * winv
    lam = vk[viol] / np.einsum("ij,ij->i", Gk[viol], WinvG)  # (g x* - h) / (g W^-1 g^T)
    X = x_star - lam[:, None] * WinvG
    c, how = _best_feasible(X, Gk, hk, absG, absh, x_star, W, feas_rtol)
    if c >= 0:
        x = X[c]
        i = viol[c]
        z[i if keep is None else keep[i]] = lam[c]
        return finish_result(x, G, h, ACTIVE, f"solved (exact, n=2, projection on row {i if keep is None else keep[i]})",
                       active_tol, 0, z)

    # Stage 2: vertices of non-parallel pairs.
    ii, jj = _pairs(Gk.shape[0])
    gi, gj = Gk[ii], Gk[jj]
    det = gi[:, 0] * gj[:, 1] - gi[:, 1] * gj[:, 0]
    ok = det * det > (parallel_tol * parallel_tol) * (sqk[ii] * sqk[jj])
    dets = np.where(ok, det, 1.0)
    hi_, hj_ = hk[ii], hk[jj]
    X = np.empty((det.size, 2))
    X[:, 0] = (hi_ * gj[:, 1] - hj_ * gi[:, 1]) / dets
    X[:, 1] = (gi[:, 0] * hj_ - gj[:, 0] * hi_) / dets
    c, _ = _best_feasible(X, Gk, hk, absG, absh, x_star, W, feas_rtol, ok)
    if c < 0:
        return _infeasible(G, h, x_star, W, eps_reg, active_tol)
    x = X[c]
    i, j = ii[c], jj[c]
    rhs = -W * (x - x_star)  # z2 solves [g_i; g_j]^T z2 = -W (x - x*)
    zi, zj = _pair_multipliers(Gk[i], Gk[j], det[c], rhs)
    if zi < 0.0 or zj < 0.0:
        # more than two rows through the vertex: this pair's multipliers need not be >= 0, but
        # the rows through it hold a pair whose are (-W (x - x*) lies in their cone; conic
        # Caratheodory); the first such pair (i, j lexicographic) certifies the optimum
        i, j, zi, zj = _nonnegative_pair(Gk, hk, sqk, x, x_star, rhs, feas_rtol, parallel_tol, (i, j, zi, zj))
    if keep is not None:
        i, j = keep[i], keep[j]
    z[i], z[j] = zi, zj
    return finish_result(x, G, h, ACTIVE, f"solved (exact, n=2, vertex of rows {i}, {j})", active_tol, 0, z)


def _pair_multipliers(gi, gj, det, rhs):
    """(z_i, z_j) with z_i g_i + z_j g_j = rhs (2-D, det = det [g_i; g_j] != 0), by Cramer's rule."""
    return (rhs[0] * gj[1] - rhs[1] * gj[0]) / det, (gi[0] * rhs[1] - gi[1] * rhs[0]) / det


def _nonnegative_pair(Gk, hk, sqk, x, x_star, rhs, feas_rtol, parallel_tol, default):
    """First pair (i < j) of non-parallel rows through x (|g x - h| within the tolerance of
    :func:`_best_feasible`) whose multipliers for rhs are both >= 0; ``default``
    (i, j, z_i, z_j) if none is."""
    r = np.abs(Gk @ x - hk)
    absG = np.abs(Gk)
    through = np.flatnonzero(r <= feas_rtol * (absG @ np.abs(x) + np.abs(hk)) + ROUNDING_RTOL * (absG @ np.abs(x_star)))
    for a_pos, a in enumerate(through):
        for b in through[a_pos + 1:]:
            det = Gk[a, 0] * Gk[b, 1] - Gk[a, 1] * Gk[b, 0]
            if not det * det > (parallel_tol * parallel_tol) * (sqk[a] * sqk[b]):
                continue
            za, zb = _pair_multipliers(Gk[a], Gk[b], det, rhs)
            if za >= 0.0 and zb >= 0.0:
                return a, b, za, zb
    return default


def _best_feasible(X, Gk, hk, absG, absh, x_star, W, feas_rtol, valid=None):
    """Index of the feasible row of X with the least objective (first on ties), or -1."""
    if X.shape[0] == 0:
        return -1, None
    R = X @ Gk.T - hk
    T = feas_rtol * (np.abs(X) @ absG.T + absh) + ROUNDING_RTOL * (absG @ np.abs(x_star))[None, :]
    feas = (R <= T).all(axis=1)
    if valid is not None:
        feas &= valid
    if not feas.any():
        return -1, None
    D = X - x_star
    obj = np.where(feas, (D * D) @ W, np.inf)
    return int(np.argmin(obj)), None


def _infeasible(G, h, x_star, W, eps_reg, active_tol, prefix="infeasible") -> QPResult:
    x, it = least_violation_exact(G, h, x_star, W, eps_reg)
    return finish_result(x, G, h, INFEASIBLE_FALLBACK, violation_message(G, h, x, prefix), active_tol, it)
