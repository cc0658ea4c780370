"""Compiled (numba) whole-body stage of the modes ``wbc`` and ``hybrid``.

Pure numerics, no ROS, no side effects on import (load it with ``controller.load_wbc_kernels``, which goes
through ``numba_cache.load``). The compiled twin of :class:`wbc.WholeBodyStage` (the Python stage stays
the oracle of the tests): over w in R^6 (rad/s^2, paper joints q1..q6, stance foot fixed)::

    minimise    1/2 (w - w*)^T M (w - w*)
    subject to  G w <= h          (34 rows, :func:`wbc.rows_on_w`: the 17 rows of eq. 10 with the
                                   controller's margins, with and without the observer's estimate)

* :func:`rows` builds G, h from the period's arrays (``work``: A, H, B; ``res``: h_b, h_b,c; ``cons``: the
  controller's contact rows, margins and torque limits), element by element in the order of
  ``wbc.rows_on_w``'s numpy expressions (no BLAS), so the two give the same bits.
* The early-out "w* holds every row" is ``exact_kernels.rows_and_decision``, the expression of
  ``problem.constraint_values`` (zero tolerance, bit for bit the Python stage's decision): then w = w*
  and nothing else changes (status UNCONSTRAINED).
* Otherwise a dual active-set iteration from the unconstrained optimum w* (the optimum of the stage
  moves only as far as the rows require): add the row of largest violation in the metric of M
  (v_i / sqrt(g_i M^-1 g_i^T), the M-distance from w to the row's hyperplane), solve the
  equality-constrained problem on the active set S,
  ``(G_S M^-1 G_S^T) lambda = G_S w* - h_S,  w = w* - M^-1 G_S^T lambda``, drop the row of most negative
  multiplier and solve again while one is negative; stop when no row is violated beyond
  ``DEFAULT_FEAS_RTOL (|g_i| |w| + |h_i|)`` (problem's feasibility test). The answer then satisfies the
  KKT conditions of the convex QP (primal feasible, lambda >= 0, stationarity M (w - w*) + G_S^T lambda = 0
  by construction, complementarity on S), so it is the optimum (status ACTIVE). It does not settle --
  more than 6 rows, linearly dependent rows (a pivot of the Cholesky factor below ``PIVOT_RTOL`` of its
  diagonal), or ``MAX_ITER`` iterations -- when no w holds every row, or in a degenerate corner: the
  caller then takes PIQP (:class:`wbc.WholeBodyQP`, held, with the least-violation answer) and hands its w
  to :func:`apply`.
* Multipliers have the sign convention of :mod:`problem`: M (w - w*) + G^T z = 0, z >= 0.

With the stage's w: Gamma = A w + H (eq. 15), the reported margins, reaction, l and tightest row
(``controller_kernels._outputs``, the one home), the memory's w of the period (the observer's next
residual), and the status fields of ``RES`` (wbc_status, wbc_active: bit mask over the 17 rows folded
over both blocks, active when G w - h >= -DEFAULT_ACTIVE_TOL; wbc_deviation = |w - w*|_2).

Arrays: ``wbc`` (``controller_layout.WBC``: the stage's mode, M, M^-1), the controller's ``cons``, ``mem``,
``work``, ``res`` (``controller_layout``), G (34, 6) and h (34,) buffers.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_model import numba_cache
from biped_controller.core.control import controller_kernels as ck
from biped_controller.core.control.controller_layout import (
    C_, M_, R_, W_, WB_, N_JOINTS, WBC_MODE_OFF)
from biped_controller.core.qp.exact_kernels import rows_and_decision
from biped_controller.core.qp.problem import (
    ACTIVE, DEFAULT_ACTIVE_TOL, DEFAULT_FEAS_RTOL, UNCONSTRAINED)

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

N_ROWS = 17
WBC_ROWS = 2 * N_ROWS
#: status of a stage that did not run (ControllerStatus NO_ADAPTATION; ``wbc.NOT_RUN``)
NOT_RUN = 4
#: a bound on the active-set iterations (each adds or drops one row; an optimum needs at most 6 rows
#: active, so a settling run takes a few); reaching it means "does not settle": PIQP answers instead
MAX_ITER = 4 * WBC_ROWS
#: a row is linearly dependent on the active ones when its Cholesky pivot^2 is below this fraction of its
#: diagonal entry (dimensionless; the sine^2 of its angle to their span in the metric of M^-1)
PIVOT_RTOL = 1e-12
# return codes of ``stage``
UNCHANGED, SOLVED, NEEDS_PIQP, NONFINITE = 0, 1, 2, 3

_V = numba.types.Array(numba.types.float64, 1, "C")
_M = numba.types.Array(numba.types.float64, 2, "C")
_I = numba.types.int64
_B = numba.types.boolean


@numba.njit(cache=True)
def rows(cons, work, res, G, h):
    """G (34, 6), h (34,) of ``wbc.rows_on_w`` from the period's arrays (same expressions, same bits)."""
    for r in range(5):
        k = C_.qp_rows + 3 * r
        c0, c1, e = cons[k], cons[k + 1], cons[k + 2]
        for j in range(6):
            g = (c0 * work[W_.B, j] + c1 * work[W_.B + 1, j]) + e * work[W_.A, j]
            G[r, j] = g
            G[N_ROWS + r, j] = g
        bc = (c0 * res[R_.h_b_c] + c1 * res[R_.h_b_c + 1]) + e * work[W_.H, 0]
        b0 = (c0 * res[R_.h_b] + c1 * res[R_.h_b + 1]) + e * work[W_.H, 0]
        h[r] = -(bc + cons[C_.margin + r])
        h[N_ROWS + r] = -(b0 + cons[C_.margin + r])
    for i in range(6):
        for j in range(6):
            a = work[W_.A + i, j]
            G[5 + i, j] = a
            G[11 + i, j] = -a
            G[N_ROWS + 5 + i, j] = a
            G[N_ROWS + 11 + i, j] = -a
        hi = work[W_.H, i]
        up = -((hi - cons[C_.torque_max + i]) + cons[C_.margin + 5 + i])
        lo = -((cons[C_.torque_min + i] - hi) + cons[C_.margin + 11 + i])
        h[5 + i] = up
        h[11 + i] = lo
        h[N_ROWS + 5 + i] = up
        h[N_ROWS + 11 + i] = lo


@numba.njit(cache=True)
def _row_value(G, h, w, i):
    """g_i w - h_i, summed left to right (``problem.constraint_values``' expression)."""
    s = G[i, 0] * w[0]
    for j in range(1, G.shape[1]):
        s += G[i, j] * w[j]
    return s - h[i]


@numba.njit(cache=True)
def _equality_solve(G, h, w_star, Minv, S, nS, lam, w):
    """The optimum on the active rows S[:nS] held as equalities: lambda (nS,) and w (module docstring).
    False when the rows are linearly dependent (relative pivot below PIVOT_RTOL) or a value is not finite."""
    n = w_star.shape[0]
    P = np.empty((nS, n))                  # P = G_S M^-1
    for a in range(nS):
        i = S[a]
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += G[i, k] * Minv[k, j]
            P[a, j] = s
    K = np.empty((nS, nS))                 # K = G_S M^-1 G_S^T
    for a in range(nS):
        for b in range(a + 1):
            s = 0.0
            for k in range(n):
                s += P[a, k] * G[S[b], k]
            K[a, b] = s
            K[b, a] = s
    L = np.zeros((nS, nS))
    for j in range(nS):                    # Cholesky, K = L L^T
        s = K[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not (s > PIVOT_RTOL * K[j, j]):
            return False
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, nS):
            t = K[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    y = np.empty(nS)
    for a in range(nS):                    # rhs = G_S w* - h_S, then L L^T lambda = rhs
        t = _row_value(G, h, w_star, S[a])
        for k in range(a):
            t -= L[a, k] * y[k]
        y[a] = t / L[a, a]
    for a in range(nS - 1, -1, -1):
        t = y[a]
        for k in range(a + 1, nS):
            t -= L[k, a] * lam[k]
        lam[a] = t / L[a, a]
    for j in range(n):
        s = w_star[j]
        for a in range(nS):
            s -= P[a, j] * lam[a]
        w[j] = s
        if not math.isfinite(s):
            return False
    return True


@numba.njit(cache=True)
def solve_active_set(G, h, w_star, Minv, w, lam, S):
    """The dual active-set iteration of the module docstring. Returns the number of active rows (their
    indices in S, multipliers in lam, the answer in w), or -1 when it does not settle."""
    m, n = G.shape
    gnorm = np.empty(m)                    # sqrt(g_i M^-1 g_i^T): the M-distance scale of row i
    gabs = np.empty(m)                     # |g_i|
    for i in range(m):
        s = 0.0
        a = 0.0
        for j in range(n):
            a += G[i, j] * G[i, j]
            t = 0.0
            for k in range(n):
                t += Minv[j, k] * G[i, k]
            s += G[i, j] * t
        gnorm[i] = math.sqrt(s) if s > 0.0 else 0.0
        gabs[i] = math.sqrt(a)
    inS = np.zeros(m, dtype=np.bool_)
    for j in range(n):
        w[j] = w_star[j]
    nS = 0
    for _ in range(MAX_ITER):
        wn = 0.0
        for j in range(n):
            wn += w[j] * w[j]
        wn = math.sqrt(wn)
        best = -1
        bestv = 0.0
        for i in range(m):
            if inS[i]:
                continue
            v = _row_value(G, h, w, i)
            if v > DEFAULT_FEAS_RTOL * (gabs[i] * wn + abs(h[i])):
                if gnorm[i] == 0.0:        # a zero row with h < 0: no w holds it
                    return -1
                d = v / gnorm[i]
                if d > bestv:
                    bestv = d
                    best = i
        if best < 0:
            return nS                      # primal feasible, lambda >= 0: the KKT point
        if nS == n:
            return -1
        S[nS] = best
        inS[best] = True
        nS += 1
        while True:
            if not _equality_solve(G, h, w_star, Minv, S, nS, lam, w):
                return -1
            lmax = 0.0
            for a in range(nS):
                lmax = max(lmax, abs(lam[a]))
            worst = -1
            wv = -DEFAULT_FEAS_RTOL * lmax
            for a in range(nS):
                if lam[a] < wv:
                    wv = lam[a]
                    worst = a
            if worst < 0:
                break
            inS[S[worst]] = False
            for a in range(worst, nS - 1):
                S[a] = S[a + 1]
            nS -= 1
            if nS == 0:
                for j in range(n):
                    w[j] = w_star[j]
                break
    return -1


@numba.njit(cache=True)
def _report(G, h, w, w_star, status, res):
    """The RES status fields of the stage's answer w (module docstring)."""
    mask = 0
    for i in range(WBC_ROWS):
        if _row_value(G, h, w, i) >= -DEFAULT_ACTIVE_TOL:
            mask |= 1 << (i % N_ROWS)
    d = 0.0
    for j in range(N_JOINTS):
        d += (w[j] - w_star[j]) ** 2
    res[R_.wbc_status] = status
    res[R_.wbc_active] = mask
    res[R_.wbc_deviation] = math.sqrt(d)


@numba.njit(cache=True)
def _take(cons, mem, work, res, w, committed):
    """The period's w becomes ``w``: torque, margins, reaction, l, tightest row (``ck._outputs``) and, when
    the period is already ``committed``, the memory's w of the period (else the commit takes work[w])."""
    for j in range(N_JOINTS):
        work[W_.w, j] = w[j]
        if committed:
            mem[M_.prev_w + j] = w[j]
    ck._outputs(cons, work, res)


@numba.njit(cache=True)
def run_stage(wbc, cons, mem, work, res, G, h, run, committed):
    """The whole-body stage after the period's decision (its w in work[W_.w], outputs in res): ``run``
    False (mode off, or hybrid with a p/tau answer that holds its rows) -> status NOT_RUN, UNCHANGED.
    Else the rows; w* holds every row -> UNCONSTRAINED, UNCHANGED (nothing but the status fields
    written); the active-set answer -> ACTIVE, SOLVED (w, torque, outputs and the memory's w replaced);
    NEEDS_PIQP (not settled: nothing changed; G, h filled) or NONFINITE (rows not finite: nothing changed).
    The memory is written only on SOLVED and only when the period is already ``committed`` (the compiled
    period commits before the stage; the compiled loop commits after it, and may still give the period
    back to the objects)."""
    res[R_.wbc_status] = NOT_RUN
    res[R_.wbc_active] = 0.0
    res[R_.wbc_deviation] = 0.0
    if not run or wbc[WB_.mode] == WBC_MODE_OFF:
        return UNCHANGED
    rows(cons, work, res, G, h)
    for i in range(WBC_ROWS):
        if not math.isfinite(h[i]):
            return NONFINITE
        for j in range(N_JOINTS):
            if not math.isfinite(G[i, j]):
                return NONFINITE
    w_star = work[W_.w].copy()
    for j in range(N_JOINTS):
        if not math.isfinite(w_star[j]):
            return NONFINITE
    v = np.empty(WBC_ROWS)
    if rows_and_decision(G, h, w_star, v):
        mask = 0
        for i in range(WBC_ROWS):
            if v[i] >= -DEFAULT_ACTIVE_TOL:
                mask |= 1 << (i % N_ROWS)
        res[R_.wbc_status] = UNCONSTRAINED
        res[R_.wbc_active] = mask
        return UNCHANGED
    Minv = wbc[WB_.Minv:WB_.Minv + N_JOINTS * N_JOINTS].reshape(N_JOINTS, N_JOINTS)
    w = np.empty(N_JOINTS)
    lam = np.empty(N_JOINTS)
    S = np.empty(N_JOINTS, dtype=np.int64)
    if solve_active_set(G, h, w_star, Minv, w, lam, S) < 0:
        return NEEDS_PIQP
    _report(G, h, w, w_star, ACTIVE, res)
    _take(cons, mem, work, res, w, committed)
    return SOLVED


@numba.njit(_I(_V, _V, _V, _M, _V, _M, _V, _B), cache=True)
def stage(wbc, cons, mem, work, res, G, h, run):
    """:func:`run_stage` from Python (the compiled period of ``controller_compiled.CompiledPeriod``, committed)."""
    return run_stage(wbc, cons, mem, work, res, G, h, run, True)


@numba.njit(_I(_V, _V, _M, _V, _M, _V, _V, _V, _I), cache=True)
def apply(cons, mem, work, res, G, h, w_star, w, status):
    """PIQP's answer ``w`` (status ``status``: ACTIVE, INFEASIBLE_FALLBACK or SOLVER_ERROR, problem) around
    ``w_star`` taken as the period's: status fields, torque, outputs, the memory's w."""
    _report(G, h, w, w_star, status, res)
    _take(cons, mem, work, res, w, True)
    return 0


@numba.njit(_I(_M, _V, _V, _M, _V, _V, _V), cache=True)
def solve(G, h, w_star, Minv, w, lam, S_out):
    """:func:`solve_active_set` from Python (tests, benchmarks): the number of active rows or -1; their
    indices in S_out (float), multipliers in lam."""
    S = np.empty(N_JOINTS, dtype=np.int64)
    k = solve_active_set(G, h, w_star, Minv, w, lam, S)
    for a in range(max(k, 0)):
        S_out[a] = S[a]
    return k


@numba.njit(_I(_V, _M, _V, _M, _V), cache=True)
def build_rows(cons, work, res, G, h):
    """:func:`rows` from Python (tests)."""
    rows(cons, work, res, G, h)
    return 0

