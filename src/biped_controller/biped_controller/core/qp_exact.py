"""Exact solver of the adaptation QP for n = 1 and n = 2, in numpy: the reference (oracle) of
the other solvers (PIQP in :mod:`qp`, the numba kernel in :mod:`qp_fast`).

Same problem, sign conventions, units and statuses as :mod:`qp_types`::

    minimise 1/2 (x - x*)^T W (x - x*)   s.t.   G x <= h,   W = diag(W) > 0,  G (m, n), n in {1, 2}.

Method (finite enumeration, pure numpy). The optimum is unique (strictly convex objective).
By the KKT conditions it is x* itself, or it has an active set whose normals have positive
multipliers; in 2-D a set of at most two linearly independent active rows suffices
(Caratheodory), so the optimum is one of

* x*                                   (if G x* <= h, tolerance 0 -> UNCONSTRAINED; G x* - h as
                                        evaluated by :func:`qp_types.constraint_values`),
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
(see :func:`qp_types.least_violation_exact`, re-exported here), status INFEASIBLE_FALLBACK.
"""

from __future__ import annotations

import numpy as np

from biped_controller.core.qp_types import (
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
    _error_result,
    _finish,
    _nonfinite_name,
    _unconstrained_result,
    constraint_values,
    least_violation_exact,
    min_piecewise_quadratic_1d,
    validate,
    violation_message,
)

__all__ = ["solve_exact", "least_violation_exact", "min_piecewise_quadratic_1d"]

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
        the candidate formulas; the last term for those computed from x*, see qp_types).
    parallel_tol : pairs with |det [g_i; g_j]| <= parallel_tol |g_i| |g_j| are not intersected.
    Multipliers z (>= 0, W (x - x*) + G^T z = 0) of the chosen candidate are returned in ``z``.
    """
    G, h, x_star, W = validate(G, h, x_star, W)
    m, n = G.shape
    if n > 2:
        raise QPShapeError(f"qp_exact handles n = 1 or 2, G has {n} columns")
    bad = _nonfinite_name(G, h, x_star, W)
    if bad is not None or not np.all(W > 0):
        return _error_result(x_star, G, h, f"non-finite or invalid values in {bad or 'W'}", active_tol)
    v_star = constraint_values(G, x_star, h)
    if np.all(v_star <= 0.0):
        return _unconstrained_result(x_star, v_star, active_tol)

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
        return _finish(np.array([x0]), G, h, ACTIVE, "solved (exact, n=1)", active_tol, 0, z)

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
        return _finish(x, G, h, ACTIVE, f"solved (exact, n=2, projection on row {i if keep is None else keep[i]})",
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
    return _finish(x, G, h, ACTIVE, f"solved (exact, n=2, vertex of rows {i}, {j})", active_tol, 0, z)


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
    return _finish(x, G, h, INFEASIBLE_FALLBACK, violation_message(G, h, x, prefix), active_tol, it)
