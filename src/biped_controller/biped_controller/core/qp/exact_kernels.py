"""Compiled (numba) kernels of the adaptation QP (problem, units, signs and statuses: :mod:`problem`).

Kernels, each one call from Python:

* :func:`early_out` -- is x* feasible, G x* <= h, with zero tolerance? The rows are evaluated
  as :func:`problem.constraint_values` does (IEEE products and sums left to right; numba emits
  no fused multiply-add without fastmath), so the decision is exact's bit for bit.
* :func:`solve_small` -- the exact optimum for n <= 2, a compiled counterpart of
  :func:`exact.solve_exact` with the same candidates, tolerances, tie rules, multipliers and
  least-violation fallback (:func:`exact.least_violation_exact`). Candidates: x*, the
  projections onto violated rows, then the vertices of non-parallel pairs. Vertices are visited
  first for pairs holding a row violated at x* (the support of the optimal multipliers always
  holds one: sum_i z_i (g_i x* - h_i) = |x* - x|_W^2 > 0), then the remaining pairs only when
  their lower bound max(d_i, d_j), d_k = (g_k x* - h_k)^2 / (g_k W^-1 g_k^T) (the W-distance^2
  from x* to row k's line), does not exceed the best objective found; the answer is the
  feasible candidate of least objective, as in the reference.
* :func:`polish` -- refines an interior-point answer (x, z): active-set guess from z, a greedy
  choice of linearly independent rows in order of decreasing z, the equality-constrained
  optimum on them, and a KKT check; failing that, the projections onto the rows of largest z,
  one at a time.
* :func:`load_piqp` -- drops duplicated rows (exact presolve) and fills PIQP's held buffers.

The four kernels called from Python have explicit signatures (float64 arrays of any layout --
the controller's G is column-major -- and float64 scalars): importing this module (through
``biped_model.numba_cache.load``, which keeps the cache in ``<repo>/build/numba-cache`` and says
on stderr when it compiles, ~30 s on the project machine; loading takes ~1 s) compiles them or loads
them from the cache. Other
argument types raise TypeError instead of compiling on the fly. The kernels do not check shapes
(numba does not bound-check): call them through :func:`solve_exact`, :func:`solver.polish` or
:class:`solver.AdaptationQP`, which do.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from biped_model import numba_cache
from biped_controller.core.qp.problem import (
    ACTIVE,
    DEFAULT_ACTIVE_TOL,
    DEFAULT_EPS_REG,
    DEFAULT_FEAS_RTOL,
    DEFAULT_PARALLEL_TOL,
    DEFAULT_ZERO_ROW_RTOL,
    INFEASIBLE_FALLBACK,
    ROUNDING_RTOL,
    SOLVER_ERROR,
    UNCONSTRAINED,
    QPResult,
    QPShapeError,
    error_result,
    make_result,
    validate,
    violation_message,
)

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

__all__ = ["solve_exact", "message", "early_out", "solve_small", "polish", "load_piqp",
           "EARLY_FEASIBLE", "EARLY_NOT_FEASIBLE", "EARLY_NONFINITE",
           "KIND_UNCONSTRAINED", "KIND_INTERVAL", "KIND_PROJECTION", "KIND_VERTEX", "KIND_INFEASIBLE",
           "KIND_INFEASIBLE_ZERO_ROW", "KIND_ERROR"]

#: :func:`early_out` codes.
EARLY_FEASIBLE = 0
EARLY_NOT_FEASIBLE = 1
EARLY_NONFINITE = 2

#: How :func:`solve_small` found its answer (returned with the row indices involved).
KIND_UNCONSTRAINED = 0
KIND_INTERVAL = 1          # n = 1: clip of x* to [lo, hi]
KIND_PROJECTION = 2        # n = 2: projection on row i
KIND_VERTEX = 3            # n = 2: vertex of rows i, j
KIND_INFEASIBLE = 4        # least-violation answer
KIND_INFEASIBLE_ZERO_ROW = 5  # least-violation answer, a zero-norm row with h < 0
KIND_ERROR = 6             # non-finite data (bad = 0 G, 1 h, 2 x_star, 3 W) or W <= 0 (bad = 3)

_jit = numba.njit(cache=True)


def _kernel(*arg_types):
    """Decorator of a kernel called from Python: compiled now for these argument types."""
    return numba.njit([arg_types], cache=True)


_A2 = numba.types.Array(numba.types.float64, 2, "A")   # any layout: the controller's G is column-major
_A1 = numba.types.Array(numba.types.float64, 1, "A")
_R1 = numba.types.Array(numba.types.float64, 1, "A", readonly=True)   # PIQP's result vectors are read-only
_C1 = numba.types.Array(numba.types.float64, 1, "C")
_I1 = numba.types.Array(numba.types.int64, 1, "A", readonly=True)
_I1C = numba.types.Array(numba.types.int64, 1, "C")
_O1 = numba.types.Array(numba.types.float64, 1, "C")      # outputs
_B1 = numba.types.Array(numba.types.boolean, 1, "C")
_f8 = numba.types.float64


# ----------------------------------------------------------------------------------------
# x* feasible?
# ----------------------------------------------------------------------------------------


@_jit
def rows_and_decision(G, h, x, v):
    """Fill v = G x - h as :func:`problem.constraint_values` evaluates it (rows summed left to
    right, no fused multiply-add) and return True when every v_i <= 0 (NaN counts as > 0)."""
    m, n = G.shape
    feasible = True
    for i in range(m):
        s = G[i, 0] * x[0]
        for j in range(1, n):
            s += G[i, j] * x[j]
        r = s - h[i]
        v[i] = r
        if not (r <= 0.0):
            feasible = False
    return feasible


@_jit
def _first_nonfinite(G, h, x, W, check_w):
    """0 if G, 1 if h, 2 if x holds a NaN/inf, 3 if W does (or has an entry <= 0), else -1."""
    m, n = G.shape
    for i in range(m):
        for j in range(n):
            if not math.isfinite(G[i, j]):
                return 0
    for i in range(m):
        if not math.isfinite(h[i]):
            return 1
    for j in range(n):
        if not math.isfinite(x[j]):
            return 2
    if check_w:
        for j in range(n):
            if not math.isfinite(W[j]):
                return 3
        for j in range(n):
            if not (W[j] > 0.0):
                return 3
    return -1


@_kernel(_A2, _A1, _A1, _f8, _B1)
def early_out(G, h, x_star, active_tol, active):
    """Decide G x* <= h (zero tolerance; the decision of exact bit for bit). Returns a code:

    EARLY_FEASIBLE (0): x* feasible; ``active`` (m,) is set to the mask G x* - h >= -active_tol;
    EARLY_NOT_FEASIBLE (1): some row has g_i x* - h_i > 0;
    EARLY_NONFINITE (2): G, h or x* holds a NaN or an infinity.

    The mask is an argument, and the caller copies x* and shares one read-only zero z: an array
    handed back to Python costs about as much as the whole decision.
    """
    m, n = G.shape
    if _first_nonfinite(G, h, x_star, x_star, False) >= 0:
        return EARLY_NONFINITE
    v = np.empty(m)
    if not rows_and_decision(G, h, x_star, v):
        return EARLY_NOT_FEASIBLE
    for i in range(m):
        active[i] = v[i] >= -active_tol
    return EARLY_FEASIBLE


# ----------------------------------------------------------------------------------------
# least violation (compiled counterpart of exact.least_violation_exact)
# ----------------------------------------------------------------------------------------


@_jit
def _reg_weight(G, W, eps_reg):
    m, n = G.shape
    n2 = np.empty(m)
    big = 0.0
    for i in range(m):
        s = 0.0
        for j in range(n):
            s += G[i, j] * G[i, j] / W[j]
        n2[i] = s
        if s > big:
            big = s
    if not (big > 0.0 and math.isfinite(big)):
        return eps_reg
    lo = np.inf
    for i in range(m):
        if n2[i] > 1e-26 * big and n2[i] < lo:
            lo = n2[i]
    return eps_reg * lo


@_jit
def _min_pwq_1d(alpha, beta, q, t0):
    """Exact minimiser of sum_i max(alpha_i t - beta_i, 0)^2 + q (t - t0)^2 (see
    :func:`exact.min_piecewise_quadratic_1d`, same steps)."""
    k = 0
    for i in range(alpha.size):
        if alpha[i] != 0.0:
            k += 1
    if k == 0:
        return t0
    a = np.empty(k)
    b = np.empty(k)
    c = 0
    for i in range(alpha.size):
        if alpha[i] != 0.0:
            a[c] = alpha[i]
            b[c] = beta[i]
            c += 1
    bp = np.sort(b / a)
    kk = k
    for r in range(k):
        s = 0.0
        for i in range(k):
            u = a[i] * bp[r] - b[i]
            if u > 0.0:
                s += a[i] * u
        D = s + q * (bp[r] - t0)
        if D >= 0.0:
            kk = r
            if D == 0.0:
                return bp[r]
            break
    lo = bp[kk - 1] if kk > 0 else -np.inf
    hi = bp[kk] if kk < k else np.inf
    if math.isfinite(lo) and math.isfinite(hi):
        tm = 0.5 * (lo + hi)
    elif math.isfinite(lo):
        tm = lo + max(1.0, abs(lo))
    elif math.isfinite(hi):
        tm = hi - max(1.0, abs(hi))
    else:
        tm = 0.0
    saa = 0.0
    sab = 0.0
    for i in range(k):
        if a[i] * tm - b[i] > 0.0:
            saa += a[i] * a[i]
            sab += a[i] * b[i]
    den = saa + q
    if den <= 0.0:
        if math.isfinite(lo):
            return lo
        if math.isfinite(hi):
            return hi
        return t0
    t = (sab + q * t0) / den
    return min(max(t, lo), hi)


@_jit
def _sym2_pinv_solve(h00, h01, h11, g0, g1, rcond):
    """Minimum-norm least-squares solution of [[h00, h01], [h01, h11]] d = (g0, g1), singular
    values below rcond * the largest dropped (numpy.linalg.lstsq on a symmetric 2x2)."""
    if h01 == 0.0:
        l0, l1 = h00, h11
        u00, u10, u01, u11 = 1.0, 0.0, 0.0, 1.0
    else:
        mid = 0.5 * (h00 + h11)
        rad = math.hypot(0.5 * (h00 - h11), h01)
        l0 = mid + rad
        l1 = mid - rad
        # eigenvector of l0: (h01, l0 - h00) or (l0 - h11, h01), the better conditioned
        ax, ay = h01, l0 - h00
        bx, by = l0 - h11, h01
        if ax * ax + ay * ay >= bx * bx + by * by:
            nx, ny = ax, ay
        else:
            nx, ny = bx, by
        nr = math.hypot(nx, ny)
        u00, u10 = nx / nr, ny / nr
        u01, u11 = -u10, u00
    smax = max(abs(l0), abs(l1))
    d0 = 0.0
    d1 = 0.0
    if abs(l0) > rcond * smax and l0 != 0.0:
        c = (u00 * g0 + u10 * g1) / l0
        d0 += c * u00
        d1 += c * u10
    if abs(l1) > rcond * smax and l1 != 0.0:
        c = (u01 * g0 + u11 * g1) / l1
        d0 += c * u01
        d1 += c * u11
    return d0, d1


@_jit
def _least_violation(G, h, xs, W, eps_reg, max_iter):
    """(x, iterations): the exact least-violation point, n in {1, 2} (steps of
    :func:`exact.least_violation_exact`)."""
    m, n = G.shape
    sw = np.sqrt(W)
    A = np.empty((m, n))
    r = np.empty(m)
    for i in range(m):
        s = G[i, 0] * xs[0]
        for j in range(n):
            A[i, j] = G[i, j] / sw[j]
            if j > 0:
                s += G[i, j] * xs[j]
        r[i] = h[i] - s
    e = _reg_weight(G, W, eps_reg)
    x = np.empty(n)
    if n == 1:
        t = _min_pwq_1d(A[:, 0].copy(), r, e, 0.0)
        x[0] = xs[0] + t / sw[0]
        return x, 1
    y0 = 0.0
    y1 = 0.0
    u = np.empty(m)
    Ad = np.empty(m)
    negu = np.empty(m)
    S = np.zeros(m, np.bool_)
    S_prev = np.zeros(m, np.bool_)
    have_prev = False
    it = 0
    for it in range(1, max_iter + 1):
        g0 = e * y0
        g1 = e * y1
        H00 = 0.0
        H01 = 0.0
        H11 = 0.0
        for i in range(m):
            ui = A[i, 0] * y0 + A[i, 1] * y1 - r[i]
            u[i] = ui
            S[i] = ui > 0.0
            if ui > 0.0:
                g0 += A[i, 0] * ui
                g1 += A[i, 1] * ui
                H00 += A[i, 0] * A[i, 0]
                H01 += A[i, 0] * A[i, 1]
                H11 += A[i, 1] * A[i, 1]
        h00 = H00 + e
        h01 = H01
        h11 = H11 + e
        dH = h00 * h11 - h01 * h01
        if dH > 1e-13 * h00 * h11 and math.isfinite(dH):
            d0 = -(h11 * g0 - h01 * g1) / dH
            d1 = -(h00 * g1 - h01 * g0) / dH
        else:
            d0, d1 = _sym2_pinv_solve(h00, h01, h11, g0, g1, 1e-13)
            d0 = -d0
            d1 = -d1
            if not (math.isfinite(d0) and math.isfinite(d1)):
                break
        dd = d0 * d0 + d1 * d1
        ny = math.sqrt(y0 * y0 + y1 * y1)
        lim = 4e-16 * max(ny, 1e-300)
        if not dd > lim * lim:
            break
        for i in range(m):
            Ad[i] = A[i, 0] * d0 + A[i, 1] * d1
            negu[i] = -u[i]
        t = _min_pwq_1d(Ad, negu, e * dd, -(y0 * d0 + y1 * d1) / dd)
        y0 = y0 + t * d0
        y1 = y1 + t * d1
        full = abs(t - 1.0) <= 1e-12
        if full and have_prev:
            same = True
            for i in range(m):
                if S[i] != S_prev[i]:
                    same = False
                    break
            if same:
                break
        if full:
            S_prev[:] = S
            have_prev = True
        else:
            have_prev = False
    x[0] = xs[0] + y0 / sw[0]
    x[1] = xs[1] + y1 / sw[1]
    return x, it


# ----------------------------------------------------------------------------------------
# exact solver, n <= 2
# ----------------------------------------------------------------------------------------


@_jit
def _feasible_within(G, h, keep, nk, X0, X1, xs0, xs1, feas_rtol):
    """Every kept row accepts (X0, X1):
    g x - h <= feas_rtol (|g| |x| + |h|) + ROUNDING_RTOL |g| |x*| (problem.DEFAULT_FEAS_RTOL)."""
    a0 = abs(X0)
    a1 = abs(X1)
    r0 = ROUNDING_RTOL * abs(xs0)
    r1 = ROUNDING_RTOL * abs(xs1)
    for c in range(nk):
        k = keep[c]
        g0 = G[k, 0]
        g1 = G[k, 1]
        tol = feas_rtol * (a0 * abs(g0) + a1 * abs(g1) + abs(h[k])) + r0 * abs(g0) + r1 * abs(g1)
        if X0 * g0 + X1 * g1 - h[k] > tol:
            return False
    return True


@_jit
def _through(G, h, k, X0, X1, xs0, xs1, feas_rtol):
    """Row k passes through (X0, X1): |g x - h| within the tolerance of :func:`_feasible_within`."""
    g0 = G[k, 0]
    g1 = G[k, 1]
    tol = (feas_rtol * (abs(X0) * abs(g0) + abs(X1) * abs(g1) + abs(h[k]))
           + ROUNDING_RTOL * (abs(xs0) * abs(g0) + abs(xs1) * abs(g1)))
    return abs(X0 * g0 + X1 * g1 - h[k]) <= tol


@_jit
def finish_result(G, h, x, active_tol, active):
    """max(max(G x - h), 0) and the active mask G x - h >= -active_tol."""
    m, n = G.shape
    vmax = -np.inf
    for i in range(m):
        s = G[i, 0] * x[0]
        for j in range(1, n):
            s += G[i, j] * x[j]
        v = s - h[i]
        active[i] = v >= -active_tol
        if v > vmax:
            vmax = v
    if m == 0:
        return 0.0
    return max(vmax, 0.0)


@_kernel(_A2, _A1, _A1, _A1, _f8, _f8, _f8, _f8, _f8, _O1, _O1, _B1)
def solve_small(G, h, x_star, W, active_tol, eps_reg, feas_rtol, parallel_tol, zero_rtol, x, z, active):
    """Exact optimum for n in {1, 2} (see the module docstring), written into x (n,), z (m,)
    multipliers (zeros for the fallback and errors) and active (m,) bool. Returns
    (status, max_violation, iterations, kind, i, j):

    status : UNCONSTRAINED / ACTIVE / INFEASIBLE_FALLBACK / SOLVER_ERROR (problem);
    kind : KIND_* (how the answer was found); i, j : the rows involved (-1 if none), or for
        KIND_ERROR i = 0 G, 1 h, 2 x_star, 3 W (the first array with a NaN/inf, or W <= 0).
    The outputs are arguments because handing new arrays back to Python costs more than the
    solve (about 1 us each).
    """
    m, n = G.shape
    x[:] = x_star
    z[:] = 0.0
    active[:] = False
    bad = _first_nonfinite(G, h, x_star, W, True)
    if bad >= 0:
        return SOLVER_ERROR, np.nan, 0, KIND_ERROR, bad, -1
    v = np.empty(m)
    if rows_and_decision(G, h, x_star, v):
        for i in range(m):
            active[i] = v[i] >= -active_tol
        return UNCONSTRAINED, 0.0, 0, KIND_UNCONSTRAINED, -1, -1

    # zero-norm rows: 0 <= h_i must hold (within feas_rtol max|h|); otherwise they are dropped
    sq = np.empty(m)
    gmax2 = 0.0
    for i in range(m):
        s = 0.0
        for j in range(n):
            s += G[i, j] * G[i, j]
        sq[i] = s
        if s > gmax2:
            gmax2 = s
    keep = np.empty(m, np.int64)
    nk = 0
    hscale = 0.0
    for i in range(m):
        if abs(h[i]) > hscale:
            hscale = abs(h[i])
    zero_row_infeasible = False
    for i in range(m):
        is_zero = sq[i] <= (zero_rtol * zero_rtol) * gmax2 if gmax2 > 0.0 else True
        if is_zero:
            if h[i] < -feas_rtol * hscale:
                zero_row_infeasible = True
        else:
            keep[nk] = i
            nk += 1
    if zero_row_infeasible:
        xl, it = _least_violation(G, h, x_star, W, eps_reg, 100)
        x[:] = xl
        mv = finish_result(G, h, x, active_tol, active)
        return INFEASIBLE_FALLBACK, mv, it, KIND_INFEASIBLE_ZERO_ROW, -1, -1

    if n == 1:
        hi = np.inf
        lo = -np.inf
        for c in range(nk):
            k = keep[c]
            b = h[k] / G[k, 0]
            if G[k, 0] > 0.0:
                if b < hi:
                    hi = b
            elif b > lo:
                lo = b
        xs = x_star[0]
        if lo > hi and lo - hi > feas_rtol * (abs(lo) + abs(hi)):
            xl, it = _least_violation(G, h, x_star, W, eps_reg, 100)
            x[:] = xl
            mv = finish_result(G, h, x, active_tol, active)
            return INFEASIBLE_FALLBACK, mv, it, KIND_INFEASIBLE, -1, -1
        if lo > hi:
            x0 = 0.5 * (lo + hi)
        else:
            x0 = lo if lo > xs else xs
            x0 = hi if hi < x0 else x0
        row = -1
        if x0 != xs:
            # the binding bound's multiplier: the first tightest row on the side of x*
            best = np.inf if xs > x0 else -np.inf
            for c in range(nk):
                k = keep[c]
                b = h[k] / G[k, 0]
                up = G[k, 0] > 0.0
                if xs > x0:
                    val = b if up else np.inf
                    if row < 0 or val < best:
                        best, row = val, k
                else:
                    val = -np.inf if up else b
                    if row < 0 or val > best:
                        best, row = val, k
            z[row] = W[0] * (xs - x0) / G[row, 0]
        x[0] = x0
        mv = finish_result(G, h, x, active_tol, active)
        return ACTIVE, mv, 0, KIND_INTERVAL, row, -1

    # ---- n == 2 ------------------------------------------------------------------------
    w0 = W[0]
    w1 = W[1]
    i0 = 1.0 / w0
    i1 = 1.0 / w1
    xs0 = x_star[0]
    xs1 = x_star[1]
    # stage 1: projections onto the violated rows (first feasible of least objective)
    best = np.inf
    bi = -1
    bx0 = 0.0
    bx1 = 0.0
    blam = 0.0
    for c in range(nk):
        k = keep[c]
        if v[k] > 0.0:
            wg0 = G[k, 0] * i0
            wg1 = G[k, 1] * i1
            lam = v[k] / (G[k, 0] * wg0 + G[k, 1] * wg1)
            X0 = xs0 - lam * wg0
            X1 = xs1 - lam * wg1
            D0 = X0 - xs0
            D1 = X1 - xs1
            obj = D0 * D0 * w0 + D1 * D1 * w1
            if obj < best and _feasible_within(G, h, keep, nk, X0, X1, xs0, xs1, feas_rtol):
                best, bi, bx0, bx1, blam = obj, k, X0, X1, lam
    if bi >= 0:
        x[0] = bx0
        x[1] = bx1
        z[bi] = blam
        mv = finish_result(G, h, x, active_tol, active)
        return ACTIVE, mv, 0, KIND_PROJECTION, bi, -1

    # stage 2: vertices. Pairs with a violated row first, then the rest with the distance bound.
    cand = np.zeros(m, np.bool_)
    dist = np.empty(m)
    for c in range(nk):
        k = keep[c]
        cand[k] = v[k] > 0.0
        dist[k] = v[k] * v[k] / (G[k, 0] * G[k, 0] * i0 + G[k, 1] * G[k, 1] * i1)
    best = np.inf
    bi = -1
    bj = -1
    bx0 = 0.0
    bx1 = 0.0
    bdet = 1.0
    ptol2 = parallel_tol * parallel_tol
    for sweep in range(2):
        for ci in range(nk):
            a = keep[ci]
            for cj in range(ci + 1, nk):
                b = keep[cj]
                either = cand[a] or cand[b]
                if sweep == 0:
                    if not either:
                        continue
                else:
                    if either:
                        continue
                    lb = max(dist[a], dist[b])
                    if lb * (1.0 - 1e-12) > best:
                        continue
                ga0 = G[a, 0]
                ga1 = G[a, 1]
                gb0 = G[b, 0]
                gb1 = G[b, 1]
                det = ga0 * gb1 - ga1 * gb0
                if not (det * det > ptol2 * (sq[a] * sq[b])):
                    continue
                X0 = (h[a] * gb1 - h[b] * ga1) / det
                X1 = (ga0 * h[b] - gb0 * h[a]) / det
                D0 = X0 - xs0
                D1 = X1 - xs1
                obj = D0 * D0 * w0 + D1 * D1 * w1
                if obj < best and _feasible_within(G, h, keep, nk, X0, X1, xs0, xs1, feas_rtol):
                    best, bi, bj, bx0, bx1, bdet = obj, a, b, X0, X1, det
    if bi < 0:
        xl, it = _least_violation(G, h, x_star, W, eps_reg, 100)
        x[:] = xl
        mv = finish_result(G, h, x, active_tol, active)
        return INFEASIBLE_FALLBACK, mv, it, KIND_INFEASIBLE, -1, -1
    x[0] = bx0
    x[1] = bx1
    # multipliers: [g_i; g_j]^T (z_i, z_j) = -W (x - x*)
    r0 = -w0 * (bx0 - xs0)
    r1 = -w1 * (bx1 - xs1)
    zi = (r0 * G[bj, 1] - r1 * G[bj, 0]) / bdet
    zj = (G[bi, 0] * r1 - G[bi, 1] * r0) / bdet
    if zi < 0.0 or zj < 0.0:
        # more than two rows through the vertex: the first pair of rows through it (in row
        # order) whose multipliers are both >= 0 (see exact)
        found = False
        for ca in range(nk):
            a = keep[ca]
            if not _through(G, h, a, bx0, bx1, xs0, xs1, feas_rtol):
                continue
            for cb in range(ca + 1, nk):
                b = keep[cb]
                if not _through(G, h, b, bx0, bx1, xs0, xs1, feas_rtol):
                    continue
                det = G[a, 0] * G[b, 1] - G[a, 1] * G[b, 0]
                if not (det * det > ptol2 * (sq[a] * sq[b])):
                    continue
                za = (r0 * G[b, 1] - r1 * G[b, 0]) / det
                zb = (G[a, 0] * r1 - G[a, 1] * r0) / det
                if za >= 0.0 and zb >= 0.0:
                    bi, bj, zi, zj = a, b, za, zb
                    found = True
                    break
            if found:
                break
    z[bi] = zi
    z[bj] = zj
    mv = finish_result(G, h, x, active_tol, active)
    return ACTIVE, mv, 0, KIND_VERTEX, bi, bj


# ----------------------------------------------------------------------------------------
# polish of an interior-point answer (any n)
# ----------------------------------------------------------------------------------------


#: polish: rows of largest z tried alone when the greedy active set is rejected
_POLISH_SINGLES = 4


@_jit
def _nonzero_row(G, i):
    for j in range(G.shape[1]):
        if G[i, j] != 0.0:
            return True
    return False


@_jit
def _try_active_set(G, h, x_star, W, order, n_order, max_rows, feas_rtol, x_out, lam_out, sel):
    """Equality-constrained optimum on a greedy independent subset of the rows ``order[:n_order]``
    (at most ``max_rows``), then the KKT check. Returns the number of rows used (0 = rejected).

    Rows are taken in the given order; a row joins when its W^-1-Schur complement against the rows
    already chosen exceeds 1e-12 of its own W^-1-norm^2 (pivoted Cholesky of G_A W^-1 G_A^T = L L^T).
    Then x = x* - W^-1 G_A^T lam with (G_A W^-1 G_A^T) lam = G_A x* - h_A; accepted when
    lam >= -feas_rtol max|lam| and every row has
    g x - h <= feas_rtol (|g| |x| + |h|) + ROUNDING_RTOL |g| |x*| (problem.DEFAULT_FEAS_RTOL).
    """
    m, n = G.shape
    L = np.zeros((n, n))
    col = np.empty(n)
    ns = 0
    for t in range(n_order):
        r = order[t]
        nrm = 0.0
        for j in range(n):
            nrm += G[r, j] * G[r, j] / W[j]
        if not (nrm > 0.0):
            continue
        # col_k = g_sel_k W^-1 g_r, forward substitution L l = col
        for k in range(ns):
            s = 0.0
            for j in range(n):
                s += G[sel[k], j] * G[r, j] / W[j]
            for p in range(k):
                s -= L[k, p] * col[p]
            col[k] = s / L[k, k]
        d = nrm
        for k in range(ns):
            d -= col[k] * col[k]
        if d > 1e-12 * nrm:
            for k in range(ns):
                L[ns, k] = col[k]
            L[ns, ns] = math.sqrt(d)
            sel[ns] = r
            ns += 1
            if ns == max_rows:
                break
    if ns == 0:
        return 0
    # solve L L^T lam = G_A x* - h_A
    rhs = np.empty(ns)
    for k in range(ns):
        s = 0.0
        for j in range(n):
            s += G[sel[k], j] * x_star[j]
        rhs[k] = s - h[sel[k]]
    for k in range(ns):
        s = rhs[k]
        for p in range(k):
            s -= L[k, p] * rhs[p]
        rhs[k] = s / L[k, k]
    for k in range(ns - 1, -1, -1):
        s = rhs[k]
        for p in range(k + 1, ns):
            s -= L[p, k] * lam_out[p]
        lam_out[k] = s / L[k, k]
    lmax = 0.0
    for k in range(ns):
        if abs(lam_out[k]) > lmax:
            lmax = abs(lam_out[k])
    for k in range(ns):
        if lam_out[k] < -feas_rtol * lmax:
            return 0
    for j in range(n):
        s = 0.0
        for k in range(ns):
            s += G[sel[k], j] * lam_out[k]
        x_out[j] = x_star[j] - s / W[j]
        if not math.isfinite(x_out[j]):
            return 0
    for i in range(m):
        s = 0.0
        a = abs(h[i])
        r = 0.0
        for j in range(n):
            s += G[i, j] * x_out[j]
            a += abs(G[i, j]) * abs(x_out[j])
            r += abs(G[i, j]) * abs(x_star[j])
        if s - h[i] > feas_rtol * a + ROUNDING_RTOL * r:
            return 0
    return ns


@_kernel(_A2, _A1, _A1, _A1, _R1, _I1, _R1, _f8, _f8, _O1, _O1, _B1)
def polish(G, h, x_star, W, z_sub, rows, x, feas_rtol, active_tol, xo, zo, active):
    """Refine an interior-point answer (x, z) to the exact optimum on the active set it suggests.

    z_sub are the multipliers of the rows ``rows[:len(z_sub)]`` of G (the rows the interior-point
    solver saw, see :func:`load_piqp`); the other rows have z = 0. Active-set guess
    A = {i : g_i != 0, z_i / max z > s_i / (|g_i| (|x| + |x*|) + |h_i|)}, s = h - G x (max over
    rows g_i != 0): the interior-point indicator "multiplier larger than slack" made unit-free
    (z_i s_i ~ mu -> 0, so active rows have z >> s and inactive rows s >> z; |x*| keeps the
    scale meaningful when the answer is near the origin and h ~ 0). Zero rows (0 <= h_i) can
    carry any multiplier and are left out. Rows of A in order of decreasing z_i go to
    :func:`_try_active_set` (at most n independent rows, KKT checked on every row of G); if that
    is rejected, each of the _POLISH_SINGLES rows of largest z alone. Writes the answer into xo (n,), zo (m,, z of
    all rows) and active (m,) and returns its max_violation; NaN = rejected (keep the
    interior-point answer; the outputs are then meaningless).
    """
    m, n = G.shape
    k_sub = z_sub.shape[0]
    zo[:] = 0.0
    zmax = 0.0
    for t in range(k_sub):
        if z_sub[t] > zmax and _nonzero_row(G, rows[t]):
            zmax = z_sub[t]
    if not (zmax > 0.0 and math.isfinite(zmax)):
        return np.nan
    cand = np.empty(k_sub, np.int64)
    zc = np.empty(k_sub)
    nc = 0
    for t in range(k_sub):
        i = rows[t]
        if not _nonzero_row(G, i):   # 0 <= h_i: any multiplier, no direction
            continue
        s = 0.0
        a = abs(h[i])
        for j in range(n):
            s += G[i, j] * x[j]
            a += abs(G[i, j]) * (abs(x[j]) + abs(x_star[j]))
        slack = h[i] - s
        if z_sub[t] / zmax > slack / (a + 1e-300):
            cand[nc] = i
            zc[nc] = z_sub[t]
            nc += 1
    if nc == 0:
        return np.nan
    # insertion sort of the candidates by decreasing z (stable: ties keep row order)
    for t in range(1, nc):
        ci = cand[t]
        cz = zc[t]
        p = t - 1
        while p >= 0 and zc[p] < cz:
            cand[p + 1] = cand[p]
            zc[p + 1] = zc[p]
            p -= 1
        cand[p + 1] = ci
        zc[p + 1] = cz
    lam = np.empty(n)
    sel = np.empty(n, np.int64)
    ns = _try_active_set(G, h, x_star, W, cand, nc, n, feas_rtol, xo, lam, sel)
    # an early-stopped interior point can rank a wrong row first: single rows, by decreasing z
    t = 0
    while ns == 0 and t < min(nc, _POLISH_SINGLES):
        ns = _try_active_set(G, h, x_star, W, cand[t:], 1, 1, feas_rtol, xo, lam, sel)
        t += 1
    if ns == 0:
        return np.nan
    for k in range(ns):
        zo[sel[k]] = max(lam[k], 0.0)
    return finish_result(G, h, xo, active_tol, active)


@_kernel(_A2, _A1, _A1, _A1, _C1, _C1, _C1, _I1C)
def load_piqp(G, h, x_star, W, g_buf, h_buf, c, rows):
    """Presolve and load one step's data into PIQP's held buffers; returns k, the rows kept.

    Presolve: of rows with identical g_i (every entry equal) only the one with the least h_i is
    kept (the first on ties): the others are implied by it, so feasibility, the optimum and its
    multipliers (zero on the dropped rows) are unchanged. (Not the least-violation answer of an
    infeasible problem, where duplicates count twice: the fallbacks work on the full problem.) The controller's G always holds each
    of its 17 contact/actuator rows twice (with and without the estimated push, which only moves
    h), so PIQP sees 20 rows instead of 37. ``rows[:k]`` = kept row indices (first-occurrence
    order); ``g_buf[:k * n]`` = G[rows[:k]] column-major (an F-ordered (k, n) matrix);
    ``h_buf[:k]`` = h[rows[:k]]; ``c`` = -W x* (PIQP's linear cost, P = diag(W)).
    """
    m, n = G.shape
    k = 0
    for i in range(m):
        dup = -1
        for t in range(k):
            r = rows[t]
            same = True
            for j in range(n):
                if G[i, j] != G[r, j]:
                    same = False
                    break
            if same:
                dup = t
                break
        if dup < 0:
            rows[k] = i
            k += 1
        elif h[i] < h[rows[dup]]:
            rows[dup] = i
    for j in range(n):
        c[j] = -W[j] * x_star[j]
        for t in range(k):
            g_buf[j * k + t] = G[rows[t], j]
    for t in range(k):
        h_buf[t] = h[rows[t]]
    return k


# ----------------------------------------------------------------------------------------
# Python entry points
# ----------------------------------------------------------------------------------------

_ARRAY_NAMES = ("G", "h", "x_star", "W")


def message(kind: int, i: int, j: int, G, h, x) -> str:
    """The message :func:`exact.solve_exact` gives for the same answer (kind, rows i, j)."""
    if kind == KIND_UNCONSTRAINED:
        return "x* feasible"
    if kind == KIND_INTERVAL:
        return "solved (exact, n=1)"
    if kind == KIND_PROJECTION:
        return f"solved (exact, n=2, projection on row {i})"
    if kind == KIND_VERTEX:
        return f"solved (exact, n=2, vertex of rows {i}, {j})"
    if kind == KIND_INFEASIBLE:
        return violation_message(G, h, x, "infeasible")
    if kind == KIND_INFEASIBLE_ZERO_ROW:
        return violation_message(G, h, x, "infeasible (zero-norm row with h < 0)")
    if kind == KIND_ERROR:
        return f"non-finite or invalid values in {_ARRAY_NAMES[i]}"
    raise ValueError(f"unknown kind {kind}")


def solve_exact(G, h, x_star, W, *, active_tol: float = DEFAULT_ACTIVE_TOL, eps_reg: float = DEFAULT_EPS_REG,
                feas_rtol: float = DEFAULT_FEAS_RTOL, parallel_tol: float = DEFAULT_PARALLEL_TOL) -> QPResult:
    """Exact QP solution for n in {1, 2}, compiled; same contract, tolerances and statuses as
    :func:`exact.solve_exact`. Raises only :class:`QPShapeError`. For SOLVER_ERROR x = x*
    (max_violation and the active mask as exact gives them); the least-violation answer carries
    no multipliers (z None)."""
    G, h, x_star, W = validate(G, h, x_star, W)
    if G.shape[1] > 2:
        raise QPShapeError(f"exact_kernels.solve_exact handles n = 1 or 2, G has {G.shape[1]} columns")
    m, n = G.shape
    x, z, active = np.empty(n), np.empty(m), np.empty(m, dtype=bool)
    st, mv, it, kind, i, j = solve_small(G, h, x_star, W, float(active_tol), float(eps_reg), float(feas_rtol),
                                         float(parallel_tol), DEFAULT_ZERO_ROW_RTOL, x, z, active)
    if st == SOLVER_ERROR:
        return error_result(x_star, G, h, message(kind, i, j, G, h, x), float(active_tol))
    z_out = z if st in (UNCONSTRAINED, ACTIVE) else None
    return make_result(x, int(st), message(kind, i, j, G, h, x), float(mv), active, int(it), z_out)
