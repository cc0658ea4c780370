"""Adaptation QP for the walking controller: choose x = (p'', tau'') closest to x*.

The problem, units, multiplier signs and statuses are stated once, in :mod:`problem`::

    minimise    1/2 (x - x*)^T W (x - x*)
    subject to  G x <= h            (n = 2 or 1 variables, m = 37 rows in the controller)

This module holds the solver the controller uses, :class:`AdaptationQP`, and a qpsolvers-based
helper for benchmarks. The names of :mod:`problem` (statuses, :class:`QPResult`,
:func:`kkt_residuals` ...) are re-exported here.

Per control step, :meth:`AdaptationQP.solve` first decides whether x* is feasible (compiled
kernel :func:`exact_kernels.early_out`, the decision of :func:`exact.solve_exact` bit for bit;
~97 % of the steps end there). Otherwise:

* ``solver="piqp"`` (default, the product's solver): PIQP (objects held per row count, set up
  afresh from each instance: every answer a function of its instance alone, see
  :class:`AdaptationQP`), on the problem without its duplicated rows (the controller states each
  contact row twice: 37 -> 20 rows). PIQP first runs to a screening tolerance, then its answer is polished on the
  active set its multipliers indicate and accepted only if the KKT conditions hold
  (:func:`polish`); if not, PIQP runs again to the tight tolerance. Infeasible problems go to
  the least-violation fallback.
* ``solver="exact"`` (n <= 2): the compiled exact solver :func:`exact_kernels.solve_small`, whose
  answers equal :func:`exact.solve_exact`'s.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from biped_model.finite import finite_array
from biped_controller.core.qp.exact import least_violation_exact, reg_weight
from biped_controller.core.qp.problem import (
    ACTIVE,
    DEFAULT_ACTIVE_TOL,
    DEFAULT_EPS_REG,
    DEFAULT_FEAS_RTOL,
    DEFAULT_PARALLEL_TOL,
    DEFAULT_ZERO_ROW_RTOL,
    INFEASIBLE_FALLBACK,
    SOLVER_ERROR,
    STATUS_NAMES,
    UNCONSTRAINED,
    QPResult,
    QPShapeError,
    as_float,
    bad_weight,
    error_result,
    finish_result,
    make_result,
    nonfinite_name,
    unconstrained_result,
    constraint_values,
    kkt_residuals,
    objective,
    validate,
    violation_message,
)

__all__ = [
    "UNCONSTRAINED",
    "ACTIVE",
    "INFEASIBLE_FALLBACK",
    "SOLVER_ERROR",
    "STATUS_NAMES",
    "QPResult",
    "QPShapeError",
    "AdaptationQP",
    "SOLVERS",
    "polish",
    "solve_with_qpsolvers",
    "kkt_residuals",
    "least_violation",
    "objective",
    "reg_weight",
    "validate",
    "constraint_values",
    "violation_message",
    "DEFAULT_ACTIVE_TOL",
    "DEFAULT_EPS_REG",
    "DEFAULT_SCREEN_EPS",
]

#: Values of the ``solver`` option of :class:`AdaptationQP`.
SOLVERS = ("piqp", "exact")
#: PIQP's absolute tolerance of the screening solve (row units; eps_rel = 0.1 of it). Its answer
#: is only used through :func:`polish`, which accepts it after checking the KKT conditions.
DEFAULT_SCREEN_EPS = 1e-6

_F64 = np.dtype(np.float64)
_ND = np.ndarray
_BOOL = np.dtype(bool)
_empty = np.empty


# ----------------------------------------------------------------------------------------
# PIQP plumbing shared by the least-violation slack QP and AdaptationQP
# ----------------------------------------------------------------------------------------


def piqp_module():
    import piqp  # local import keeps `import problem` cheap for users of the exact solvers only

    return piqp


def configure_piqp(settings, eps_abs: float, eps_rel: float, max_iter: int, preconditioner_iter: Optional[int] = None,
               check_duality_gap: bool = True) -> None:
    """Set PIQP's termination tolerances (absolute in row units, relative dimensionless).

    PIQP also stops on a duality-gap test whose defaults (1e-8 abs, 1e-9 rel) are much looser
    than eps_abs here: with them an answer can sit ~1e-5 inside its active row with a 15 %
    wrong multiplier while reporting primal/dual residuals ~1e-13. Tie them to eps_abs/rel, or
    switch the test off (``check_duality_gap=False``) for a solve whose answer is checked
    otherwise (AdaptationQP's screening solve, accepted only through the KKT check of the polish).
    ``preconditioner_iter`` (Ruiz equilibration sweeps at setup/update; None keeps PIQP's default).
    """
    settings.eps_abs = eps_abs
    settings.eps_rel = eps_rel
    settings.eps_duality_gap_abs = eps_abs
    settings.eps_duality_gap_rel = eps_rel
    settings.check_duality_gap = bool(check_duality_gap)
    settings.max_iter = max_iter
    settings.verbose = False
    settings.compute_timings = False
    if preconditioner_iter is not None:
        settings.preconditioner_iter = int(preconditioner_iter)


class SlackQP:
    """Least-violation problem as a QP in v = (x, s) in R^(n+m), solved by PIQP.

    minimise   1/2 v^T P v + c^T v,  P = diag(2 eps_eff W, 2 I_m),  c = (-2 eps_eff W x*, 0)
    subject to [G  -I] v <= h,  s >= 0  (x free).

    At the optimum s = max(G x - h, 0), so the cost equals V(x) - const of
    :func:`least_violation`. The solver object is held and set up afresh from each instance
    (:meth:`solve`; PIQP's ``update`` would carry the previous instance's scaling in its data:
    :class:`AdaptationQP`).
    """

    def __init__(self, n: int, m: int, eps_abs: float = 1e-10, eps_rel: float = 1e-11, max_iter: int = 250):
        piqp = piqp_module()
        self.n, self.m = n, m
        self._ok = piqp.Status.PIQP_SOLVED
        self.solver = piqp.DenseSolver()
        configure_piqp(self.solver.settings, eps_abs, eps_rel, max_iter)
        N = n + m
        self._P = np.asfortranarray(np.eye(N))
        self._c = np.zeros(N)
        self._A = np.asfortranarray(np.hstack([np.zeros((m, n)), -np.eye(m)]))
        self._xl = np.concatenate([np.full(n, -np.inf), np.zeros(m)])

    def solve(self, G, h, x_star, W, eps_reg):
        n = self.n
        e = reg_weight(G, W, eps_reg)
        idx = np.arange(n)
        self._P[idx, idx] = 2.0 * e * W
        self._c[:n] = -2.0 * e * W * x_star
        self._A[:, :n] = G
        self.solver.setup(self._P, self._c, None, None, self._A, None, np.ascontiguousarray(h), self._xl, None)
        status = self.solver.solve()
        res = self.solver.result
        x = np.array(res.x[:n], dtype=float, copy=True)
        return x, int(res.info.iter), status == self._ok and np.all(np.isfinite(x))


# ----------------------------------------------------------------------------------------
# KKT residuals (the oracle of the tests)
# ----------------------------------------------------------------------------------------


def least_violation(G, h, x_star, W, eps_reg: float = DEFAULT_EPS_REG, active_tol: float = DEFAULT_ACTIVE_TOL,
                    prefix: str = "infeasible") -> QPResult:
    """Least-violation answer used when G x <= h has no solution.

    Minimises ``V(x) = sum_i max((G x - h)_i, 0)^2 + eps_eff (x - x*)^T W (x - x*)`` with
    ``eps_eff = reg_weight(G, W, eps_reg)``. V is strictly convex and C^1, so the answer is
    unique; as eps_reg -> 0 it tends to the W-closest-to-x* minimiser of the summed squared
    violations. For n <= 2 it is solved exactly by :func:`least_violation_exact`; for larger n
    by :class:`SlackQP` (PIQP on the slack formulation). Status INFEASIBLE_FALLBACK.
    """
    G, h, x_star, W = validate(G, h, x_star, W)
    n = G.shape[1]
    if n <= 2:
        x, it = least_violation_exact(G, h, x_star, W, eps_reg)
    else:
        sq = SlackQP(n, G.shape[0])
        x, it, ok = sq.solve(G, h, x_star, W, eps_reg)
        if not ok:
            return error_result(x_star, G, h, "least-violation slack QP failed", active_tol)
    return finish_result(x, G, h, INFEASIBLE_FALLBACK, violation_message(G, h, x, prefix), active_tol, it)


EXACT_KERNELS = "biped_controller.core.qp.exact_kernels"
EXACT_KERNELS_SOURCES = ("biped_controller.core.qp.problem",)


def load_exact_kernels():
    """The compiled QP kernels (``exact_kernels``), loaded through ``numba_cache.load`` when a solver is built,
    not by users of the constants."""
    from biped_model import numba_cache

    return numba_cache.load(EXACT_KERNELS, sources=EXACT_KERNELS_SOURCES)




def polish(G, h, x_star, W, z, x, feas_rtol: float = DEFAULT_FEAS_RTOL):
    """Refine an interior-point answer (x, z) on the active set its multipliers indicate.

    Active-set guess A = {i : g_i != 0, z_i / max z > s_i / (|g_i| (|x| + |x*|) + |h_i|)},
    s = h - G x (the interior-point indicator "multiplier larger than slack", unit-free). Up to
    n linearly independent rows of A, taken in order of decreasing z, give the equality-
    constrained optimum ``x = x* - W^-1 G_A^T lam``, ``(G_A W^-1 G_A^T) lam = G_A x* - h_A``;
    it is accepted only if the KKT conditions hold: G x <= h within the tolerance of
    problem.DEFAULT_FEAS_RTOL on every row and lam >= -feas_rtol max|lam| -- then x is the
    exact optimum up to rounding. If rejected, the rows of largest z are tried alone (up to
    four). Returns (x, z) or None (keep the unpolished answer). Compiled: :func:`exact_kernels.polish`.
    """
    G, h, x_star, W = validate(G, h, x_star, W)
    z = as_float(z, "z")
    x = as_float(x, "x")
    if z.shape != h.shape or x.shape != x_star.shape:
        raise QPShapeError(f"z {z.shape} / x {x.shape} do not match h {h.shape} / x_star {x_star.shape}")
    m, n = G.shape
    xp, zp, active = np.empty(n), np.empty(m), np.empty(m, dtype=bool)
    mv = load_exact_kernels().polish(G, h, x_star, W, z, np.arange(m, dtype=np.int64), x, float(feas_rtol), DEFAULT_ACTIVE_TOL,
                        xp, zp, active)
    return (xp, zp) if mv == mv else None


class _Held:
    """The PIQP objects for one row count k (after the duplicate-row presolve): the screening
    solver (or the only one without polish) and the tight one, with views of the shared data
    buffers they are set up from (G: an F-ordered (k, n) view of the column-major buffer)."""

    __slots__ = ("k", "G", "h", "screen", "tight")

    def __init__(self, k, G, h, screen, tight):
        self.k, self.G, self.h, self.screen, self.tight = k, G, h, screen, tight


class AdaptationQP:
    """The controller's QP solver for fixed sizes (n, m), called once per control step.

    Parameters
    ----------
    n, m : problem sizes (n = 1 or 2 in the controller; any n >= 1 works with solver="piqp").
    W : positive diagonal weight (n,). Change it later with :meth:`set_weights`.
    solver : "piqp" (default) or "exact" (n <= 2 only; the compiled exact solver).
    active_tol : tolerance (row units) for the ``active`` mask.
    eps_reg : relative regularisation of the least-violation fallback (see
        :func:`least_violation`).
    fallback : for solver="piqp", what answers when PIQP does not solve: "exact" (n <= 2,
        default there) or "piqp" (slack QP on a second, also pre-built PIQP solver; the default
        and only choice for n > 2).
    eps_abs, eps_rel, max_iter : PIQP's tight termination settings.
    polish : refine PIQP's interior-point answer on its active set (see :func:`polish`);
        without it x lies ~eps_abs inside the active rows and ``active`` may miss them. With it,
        PIQP first runs to ``screen_eps`` only and runs to eps_abs/eps_rel only if the polish
        is rejected.
    screen_eps : PIQP's absolute tolerance of the screening solve (relative: screen_eps / 10;
        PIQP's duality-gap test off: the polish checks the answer). On the controller's
        instances it stops after 6.9 iterations on average (14 for the tight settings) and its
        answer is polished in all of them; on random instances with rows scaled over six decades
        ~2.5 % go on to the tight solve.
    preconditioner_iter : PIQP's Ruiz equilibration sweeps per update of the screening solve
        (default 0: on the controller's instances the sweeps add iterations, 7.9 -> 11.3 on
        average, and cost time per update; None: PIQP's own default, 10). The tight solve, which
        decides when the screening answer is not verified, keeps PIQP's default.

    PIQP 0.7 formulates ``min 1/2 x^T P x + c^T x  s.t.  h_l <= G x <= h_u`` (and more); we use
    P = diag(W), c = -W x*, G = G[rows], h_u = h[rows], h_l = -inf (None at setup), where rows
    drops duplicated rows (:func:`exact_kernels.load_piqp`; 37 -> 20 rows for the controller): the
    objective differs from 1/2 (x-x*)^T W (x-x*) by a constant. The PIQP objects of a row count
    are created on its first use (the one for m rows in the constructor) and kept; every solve
    sets one up from the instance (``setup``, then ``solve``), so that each answer is a function
    of its instance (G, h, x*, W) alone, whatever the object solved before. PIQP's ``update``
    would not give that: it unscales the data it holds with the previous instance's Ruiz scaling
    and scales it again with the new one, so the data not passed again (P, and the box scaling
    no argument resets) drift by rounding from solve to solve, and a controller reused across
    trials answered a trial's QPs differently after other trials (measured: an ulp in p, a
    different count of tight solves, fall times of modes hybrid and all a few ms apart;
    docs/capability_map.md, "One trial, one record"). A setup costs what an update does on
    these sizes (n <= 6, a few tens of rows).

    Attributes ``calls`` and ``tight_calls`` count PIQP solves (all, and tight re-solves);
    :attr:`piqp_solvers` lists the held PIQP objects by row count.
    """

    def __init__(self, n: int, m: int, W, *, solver: str = "piqp", active_tol: float = DEFAULT_ACTIVE_TOL,
                 eps_reg: float = DEFAULT_EPS_REG, fallback: Optional[str] = None,
                 eps_abs: float = 1e-10, eps_rel: float = 1e-11, max_iter: int = 250, polish: bool = True,
                 screen_eps: float = DEFAULT_SCREEN_EPS, preconditioner_iter: Optional[int] = 0):
        if n < 1 or m < 1:
            raise QPShapeError(f"n and m must be >= 1, got n={n}, m={m}")
        W = as_float(W, "W")
        if W.shape != (n,):
            raise QPShapeError(f"W has shape {W.shape}, expected ({n},) (the diagonal)")
        finite_array(W, "W", positive=True)
        if solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        if solver == "exact" and n > 2:
            raise ValueError(f"solver='exact' handles n <= 2, got n={n}")
        if fallback is None:
            fallback = "exact" if n <= 2 else "piqp"
        if fallback not in ("exact", "piqp") or (fallback == "exact" and n > 2):
            raise ValueError(f"fallback must be 'exact' (n <= 2) or 'piqp', got {fallback!r} with n={n}")
        if not (screen_eps > 0.0):
            raise ValueError(f"screen_eps must be > 0, got {screen_eps}")
        self._k = load_exact_kernels()
        self.n, self.m = int(n), int(m)
        self.solver_name = solver
        self.active_tol = float(active_tol)
        self.eps_reg = float(eps_reg)
        self.fallback = fallback
        self.polish = bool(polish)
        self.W = np.ascontiguousarray(W, dtype=float).copy()
        self._shape_G = (self.m, self.n)
        self._shape_h = (self.m,)
        self._shape_x = (self.n,)
        self._z0 = np.zeros(self.m)       # z of every UNCONSTRAINED answer: shared, hence read-only
        self._z0.flags.writeable = False
        self.calls = 0
        self.tight_calls = 0
        self._held: dict = {}
        self._slack = None
        if solver == "exact":
            return
        self._piqp_mod = piqp_module()
        self._status_solved = self._piqp_mod.Status.PIQP_SOLVED
        self._piqp_settings = (float(eps_abs), float(eps_rel), int(max_iter), preconditioner_iter,
                               float(screen_eps))
        self._P = np.asfortranarray(np.diag(self.W))
        self._c = np.zeros(n)
        self._g_buf = np.zeros(m * n)
        self._h_buf = np.ones(m)
        self._rows = np.arange(m, dtype=np.int64)
        self._held_for(self.m)
        self._slack = SlackQP(n, m, eps_abs, eps_rel, max_iter) if fallback == "piqp" else None

    @property
    def piqp_solvers(self) -> dict:
        """{row count k: (screening or only PIQP solver, tight solver or None)}."""
        return {k: (e.screen, e.tight) for k, e in self._held.items()}

    def _held_for(self, k: int) -> _Held:
        """The PIQP objects for k rows (created and configured on the first use of k; each solve sets
        one up, :meth:`_run`)."""
        e = self._held.get(k)
        if e is not None:
            return e
        eps_abs, eps_rel, max_iter, pre, screen_eps = self._piqp_settings
        G = self._g_buf[:k * self.n].reshape(self.n, k).T      # F-ordered (k, n) view
        h = self._h_buf[:k]

        def held(eps_a, eps_r, precond, gap):
            s = self._piqp_mod.DenseSolver()
            configure_piqp(s.settings, eps_a, eps_r, max_iter, precond, gap)
            return s

        if self.polish:
            e = _Held(k, G, h, held(screen_eps, 0.1 * screen_eps, pre, False), held(eps_abs, eps_rel, None, True))
        else:
            e = _Held(k, G, h, held(eps_abs, eps_rel, None, True), None)
        self._held[k] = e
        return e

    def set_weights(self, W) -> None:
        """Change the diagonal weight W (n,) (PIQP's P: the next solve sets its object up with it)."""
        W = as_float(W, "W")
        if W.shape != (self.n,):
            raise QPShapeError(f"W has shape {W.shape}, expected ({self.n},)")
        finite_array(W, "W", positive=True)
        self.W = np.ascontiguousarray(W, dtype=float).copy()
        if self.solver_name == "piqp":
            idx = np.arange(self.n)
            self._P[idx, idx] = self.W

    def solve(self, G, h, x_star) -> QPResult:
        """Solve the QP for this step's data. Raises only :class:`QPShapeError`.

        1. non-finite G, h or x* -> SOLVER_ERROR, x = x*;
        2. G x* <= h (zero tolerance, :func:`problem.constraint_values`) -> UNCONSTRAINED,
           x = x* bit-exact, no solver;
        3. solver="exact": the compiled exact solver (ACTIVE or INFEASIBLE_FALLBACK);
        4. solver="piqp": duplicated rows dropped, PIQP (update + solve) to screen_eps and
           :func:`polish` -> ACTIVE; if the polish is rejected or PIQP did not report
           PIQP_SOLVED, PIQP to eps_abs/eps_rel with its default preconditioning (polished when
           possible). PIQP_SOLVED -> ACTIVE (z = PIQP's z_u on the rows kept, 0 on the
           duplicates);
        5. PIQP_PRIMAL_INFEASIBLE or any other PIQP failure (MAX_ITER_REACHED, NUMERICS):
           "exact" fallback (n <= 2): the compiled exact solver decides -- its exact optimum
           (ACTIVE) if the problem is feasible after all, else its exact least-violation answer
           (INFEASIBLE_FALLBACK); the message names PIQP's status.
           "piqp" fallback: least-violation slack QP (INFEASIBLE_FALLBACK), SOLVER_ERROR with
           x = x* if that fails too.
        """
        # fast path: float64 ndarrays of the right shapes (any layout; the dtype test is an identity
        # test for arrays numpy made, an equality test for the others, e.g. unpickled ones)
        if not (type(G) is _ND and type(h) is _ND and type(x_star) is _ND
                and (G.dtype is _F64 or G.dtype == _F64) and (h.dtype is _F64 or h.dtype == _F64)
                and (x_star.dtype is _F64 or x_star.dtype == _F64)
                and G.shape == self._shape_G and h.shape == self._shape_h and x_star.shape == self._shape_x):
            G, h, x_star, _ = validate(G, h, x_star, None, self.n, self.m)
        tol = self.active_tol
        active = _empty(self.m, _BOOL)
        code = self._k.early_out(G, h, x_star, tol, active)
        if code == 0:
            return make_result(x_star.copy(), UNCONSTRAINED, "x* feasible", 0.0, active, 0, self._z0)
        if code == 2:
            return error_result(x_star, G, h, f"non-finite values in {nonfinite_name(G, h, x_star, None)}", tol)
        if self.solver_name == "exact":
            return self._exact(G, h, x_star, "", 0)
        return self._piqp_solve(G, h, x_star)

    # -- internals ------------------------------------------------------------------------

    def _exact(self, G, h, x_star, prefix: str, iterations: int) -> QPResult:
        k = self._k
        x, z, active = _empty(self.n), _empty(self.m), _empty(self.m, _BOOL)
        st, mv, it, kind, i, j = k.solve_small(
            G, h, x_star, self.W, self.active_tol, self.eps_reg, DEFAULT_FEAS_RTOL, DEFAULT_PARALLEL_TOL,
            DEFAULT_ZERO_ROW_RTOL, x, z, active)
        msg = k.message(kind, i, j, G, h, x)
        return make_result(x, int(st), prefix + msg, float(mv), active, int(iterations + it),
                       None if st == INFEASIBLE_FALLBACK else z)

    def _run(self, solver, held: _Held):
        """setup (from this instance: P, c, G, h_u) + solve one held PIQP object; returns (status,
        result)."""
        # positional (P, c, A, b, G, h_l, h_u, x_l, x_u): pybind11 matches them faster than keywords
        solver.setup(self._P, self._c, None, None, held.G, None, held.h, None, None)
        status = solver.solve()
        self.calls += 1
        return status, solver.result

    def _accept(self, res, k, G, h, x_star, it, polished_msg, raw_msg):
        """The polished answer if the polish accepts it, else PIQP's own (None when raw_msg is
        None or x is not finite)."""
        if self.polish:
            x, z, active = _empty(self.n), _empty(self.m), _empty(self.m, _BOOL)
            mv = self._k.polish(G, h, x_star, self.W, res.z_u, self._rows, res.x, DEFAULT_FEAS_RTOL, self.active_tol,
                                x, z, active)
            if mv == mv:  # not NaN: accepted
                return make_result(x, ACTIVE, polished_msg, mv, active, it, z)
        if raw_msg is None:
            return None
        x = np.array(res.x, dtype=float, copy=True)
        if not np.all(np.isfinite(x)):
            return None
        z = np.zeros(self.m)
        z[self._rows[:k]] = res.z_u
        return finish_result(x, G, h, ACTIVE, raw_msg, self.active_tol, it, z)

    def _piqp_solve(self, G, h, x_star) -> QPResult:
        k = self._k.load_piqp(G, h, x_star, self.W, self._g_buf, self._h_buf, self._c, self._rows)
        held = self._held.get(k) or self._held_for(k)
        status, res = self._run(held.screen, held)
        it = int(res.info.iter)
        if status == self._status_solved:
            out = self._accept(res, k, G, h, x_star, it, "solved (PIQP, polished)",
                               None if held.tight is not None else "solved (PIQP)")
            if out is not None:
                return out
        if held.tight is not None:
            # the screening answer was not verified, or the screening solve (no preconditioning)
            # did not solve: PIQP with its default preconditioning, to eps_abs, decides
            self.tight_calls += 1
            status, res = self._run(held.tight, held)
            it += int(res.info.iter)
            if status == self._status_solved:
                out = self._accept(res, k, G, h, x_star, it, "solved (PIQP tight, polished)", "solved (PIQP tight)")
                if out is not None:
                    return out
        status_name = status.name if status != self._status_solved else "PIQP_SOLVED with non-finite x"

        # PIQP did not solve it (PIQP_PRIMAL_INFEASIBLE, or MAX_ITER / NUMERICS ...).
        if self.fallback == "exact":
            # n <= 2: the exact solver decides feasibility itself; it returns the exact QP
            # optimum (ACTIVE) if PIQP gave up on a feasible problem, else the least-violation
            # answer (INFEASIBLE_FALLBACK).
            return self._exact(G, h, x_star, f"PIQP status {status_name}; exact solver: ", it)
        x, it2, ok = self._slack.solve(G, h, x_star, self.W, self.eps_reg)
        if not ok:
            return error_result(x_star, G, h, f"PIQP status {status_name}; least-violation slack QP failed",
                                 self.active_tol)
        msg = violation_message(G, h, x, prefix=f"PIQP status {status_name}; infeasible")
        return finish_result(x, G, h, INFEASIBLE_FALLBACK, msg, self.active_tol, it + it2)


# ----------------------------------------------------------------------------------------
# qpsolvers comparison helper
# ----------------------------------------------------------------------------------------


def solve_with_qpsolvers(G, h, x_star, W, solver: str = "piqp", *, active_tol: float = DEFAULT_ACTIVE_TOL,
                         eps_reg: float = DEFAULT_EPS_REG, skip_if_feasible: bool = True, **solver_kwargs) -> QPResult:
    """Same QP through ``qpsolvers.solve_problem`` (builds the problem on every call; benchmarks only).

    Same status logic as :meth:`AdaptationQP.solve`: x* feasible -> UNCONSTRAINED (unless
    ``skip_if_feasible`` is False, then the solver is always called); solver found a
    solution -> ACTIVE with z from ``solution.z`` (qpsolvers uses the same sign convention,
    z >= 0 for G x <= h); not found -> least-violation fallback (INFEASIBLE_FALLBACK).
    """
    import qpsolvers

    G, h, x_star, W = validate(G, h, x_star, W)
    bad = nonfinite_name(G, h, x_star, W)
    if bad is not None or bad_weight(W):
        return error_result(x_star, G, h, f"non-finite or invalid values in {bad or 'W'}", active_tol)
    v_star = constraint_values(G, x_star, h)
    if skip_if_feasible and np.all(v_star <= 0.0):
        return unconstrained_result(x_star, v_star, active_tol)
    problem = qpsolvers.Problem(np.diag(W), -W * x_star, G, h)
    try:
        sol = qpsolvers.solve_problem(problem, solver=solver, **solver_kwargs)
    except Exception as exc:  # noqa: BLE001 - any backend failure becomes a status
        sol = None
        why = f"{type(exc).__name__}: {exc}"
    else:
        why = "no solution found"
    if sol is not None and sol.found and sol.x is not None and np.all(np.isfinite(sol.x)):
        x = np.array(sol.x, dtype=float, copy=True)
        z = None if sol.z is None else np.array(sol.z, dtype=float, copy=True)
        return finish_result(x, G, h, ACTIVE, f"solved ({solver} via qpsolvers)", active_tol, 0, z)
    return least_violation(G, h, x_star, W, eps_reg, active_tol, prefix=f"{solver}: {why}; infeasible")


def held_update_run(qp: AdaptationQP, solver, held: _Held):
    """``AdaptationQP._run`` as it was before every solve was set up from its instance: a held PIQP object
    set up (P, c, G, h_u) on its first solve, then only updated (c, G, h_u), so the previous instance's
    scaling stays in the object's data and an answer depends on the instances solved before it. The solver
    never calls it: it is the negative control of ``tests/test_history.py`` (patched in for
    ``AdaptationQP._run``) and the ``update`` path of ``lab/benchmarks/piqp_setup.py``. Returns
    (status, result) as ``_run`` does."""
    done = qp.__dict__.setdefault("_held_set_up", {})
    if id(solver) in done:
        solver.update(None, qp._c, None, None, held.G, None, held.h)
    else:
        solver.setup(qp._P, qp._c, None, None, held.G, None, held.h, None, None)
        done[id(solver)] = solver             # kept alive: its id stays its own
    status = solver.solve()
    qp.calls += 1
    return status, solver.result
