"""Adaptation QP for the walking controller: choose x = (p'', tau'') closest to x*.

Problem (n = 2 variables, or n = 1 in single-parameter modes; m = 17 rows)::

    minimise    1/2 (x - x*)^T W (x - x*)
    subject to  G x <= h

* ``x``   : the chosen second derivatives of the gait parameters. Units follow the caller:
  p'' in [p-unit]/s^2 and tau'' in [tau-unit]/s^2 (the controller uses SI derived units).
* ``x*``  : the desired value (same units as x).
* ``W``   : diagonal weight, given as its positive diagonal (shape (n,)); units are
  1/[x]^2 times an arbitrary cost unit, so only the ratio W_0/W_1 matters.
* ``G, h``: G = A_p and h = -b_p - margin from the robot's contact/actuator constraints
  A_p x + b_p < 0 (margin handled by the caller). Row i has the units of constraint i
  (N for force rows, m for centre-of-pressure rows, N m for torque rows ...).

Multipliers (sign convention used everywhere in this module and in :mod:`qp_exact`):
``z`` (shape (m,)) with ``z >= 0`` and the Lagrangian
``L(x, z) = 1/2 (x - x*)^T W (x - x*) + z^T (G x - h)``, so the KKT conditions are

    stationarity     W (x - x*) + G^T z = 0
    primal feas.     G x - h <= 0
    dual feas.       z >= 0
    complementarity  z_i (G x - h)_i = 0.

z_i has units [cost unit] / [unit of row i]; it is the marginal decrease of the optimal cost
per unit relaxation of h_i. PIQP reports the same quantity for one-sided rows as ``z_u``.

Status values mirror the ROS message constants (``biped_msgs_py``):

* ``UNCONSTRAINED = 0``       x* is feasible (G x* <= h with zero tolerance); x = x* bit-exact,
  no solver call.
* ``ACTIVE = 1``              solved; at least one constraint is active.
* ``INFEASIBLE_FALLBACK = 2`` no x satisfies G x <= h; x is the least-violation answer
  ``argmin sum_i max(G x - h, 0)_i^2 + eps_eff |x - x*|_W^2`` (see :func:`least_violation`).
* ``SOLVER_ERROR = 3``        non-finite input data or an unrecoverable solver failure; x = x*.

Only shape inconsistencies raise (:class:`QPShapeError`); they are programming errors.
Everything else is reported through the status.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

__all__ = [
    "UNCONSTRAINED",
    "ACTIVE",
    "INFEASIBLE_FALLBACK",
    "SOLVER_ERROR",
    "STATUS_NAMES",
    "QPResult",
    "QPShapeError",
    "AdaptationQP",
    "solve_with_qpsolvers",
    "kkt_residuals",
    "least_violation",
    "objective",
    "DEFAULT_ACTIVE_TOL",
    "DEFAULT_EPS_REG",
]

UNCONSTRAINED = 0
ACTIVE = 1
INFEASIBLE_FALLBACK = 2
SOLVER_ERROR = 3
STATUS_NAMES = {
    UNCONSTRAINED: "UNCONSTRAINED",
    ACTIVE: "ACTIVE",
    INFEASIBLE_FALLBACK: "INFEASIBLE_FALLBACK",
    SOLVER_ERROR: "SOLVER_ERROR",
}

#: A row counts as active when G x - h >= -DEFAULT_ACTIVE_TOL (units of the row).
DEFAULT_ACTIVE_TOL = 1e-8
#: Relative weight of the regulariser of the least-violation problem (dimensionless, see
#: :func:`least_violation`).
DEFAULT_EPS_REG = 1e-9


class QPShapeError(ValueError):
    """Inconsistent array shapes passed to a QP routine (a programming error)."""


@dataclass(frozen=True)
class QPResult:
    """Answer of the adaptation QP.

    Attributes
    ----------
    x : (n,) chosen value (units of x*).
    status : one of UNCONSTRAINED, ACTIVE, INFEASIBLE_FALLBACK, SOLVER_ERROR.
    message : human-readable detail (which rows are violated and by how much, solver status).
    max_violation : max(max(G x - h), 0), in the units of the worst row (0 if feasible).
    active : (m,) bool mask of rows with G x - h >= -active_tol.
    iterations : solver iterations (0 when no iterative solver ran).
    z : (m,) multipliers (z >= 0, W (x - x*) + G^T z = 0) when known, else None.
    """

    x: np.ndarray
    status: int
    message: str
    max_violation: float
    active: np.ndarray
    iterations: int
    z: Optional[np.ndarray] = field(default=None, compare=False)

    @property
    def status_name(self) -> str:
        return STATUS_NAMES.get(self.status, str(self.status))


# ----------------------------------------------------------------------------------------
# shared helpers
# ----------------------------------------------------------------------------------------


def _as_float(a, name: str) -> np.ndarray:
    try:
        return np.asarray(a, dtype=float)
    except (TypeError, ValueError) as exc:  # e.g. ragged lists
        raise QPShapeError(f"{name} cannot be converted to a float array: {exc}") from exc


def validate(G, h, x_star, W=None, n: Optional[int] = None, m: Optional[int] = None):
    """Convert and check shapes. Returns float arrays (G (m,n), h (m,), x* (n,), W (n,) or None).

    Raises :class:`QPShapeError` naming the inconsistent array.
    """
    G = _as_float(G, "G")
    h = _as_float(h, "h")
    x_star = _as_float(x_star, "x_star")
    if G.ndim != 2:
        raise QPShapeError(f"G must be 2-D (m, n), got shape {G.shape}")
    mm, nn = G.shape
    if nn < 1:
        raise QPShapeError(f"G must have at least one column, got shape {G.shape}")
    if n is not None and nn != n:
        raise QPShapeError(f"G has {nn} columns, expected n = {n}")
    if m is not None and mm != m:
        raise QPShapeError(f"G has {mm} rows, expected m = {m}")
    if h.shape != (mm,):
        raise QPShapeError(f"h has shape {h.shape}, expected ({mm},) to match G {G.shape}")
    if x_star.shape != (nn,):
        raise QPShapeError(f"x_star has shape {x_star.shape}, expected ({nn},) to match G {G.shape}")
    if W is not None:
        W = _as_float(W, "W")
        if W.shape != (nn,):
            raise QPShapeError(f"W has shape {W.shape}, expected ({nn},) (the diagonal)")
    return G, h, x_star, W


def objective(x, x_star, W) -> float:
    """1/2 (x - x*)^T diag(W) (x - x*)."""
    d = np.asarray(x, float) - np.asarray(x_star, float)
    return 0.5 * float(np.dot(np.asarray(W, float) * d, d))


def _nonfinite_name(G, h, x_star, W) -> Optional[str]:
    # fast path: a sum is finite iff every term is (barring overflow of huge finite values,
    # which then only costs the detailed check below)
    total = G.sum() + h.sum() + x_star.sum() + (0.0 if W is None else W.sum())
    if total - total == 0.0:
        return None
    for name, a in (("G", G), ("h", h), ("x_star", x_star), ("W", W)):
        if a is not None and not np.all(np.isfinite(a)):
            return name
    return None


def _bad_weight(W) -> bool:
    return W is not None and not np.all(W > 0.0)


def _error_result(x_star, G, h, message, active_tol) -> QPResult:
    x = np.array(x_star, dtype=float, copy=True)
    with np.errstate(invalid="ignore", over="ignore"):
        v = G @ x - h
    finite = np.isfinite(v)
    maxv = float(np.max(np.maximum(v[finite], 0.0))) if np.any(finite) else float("nan")
    if not np.all(finite):
        maxv = float("nan")
    active = np.zeros(h.shape, dtype=bool)
    active[finite] = v[finite] >= -active_tol
    return QPResult(x, SOLVER_ERROR, message, maxv, active, 0, None)


def _unconstrained_result(x_star, viol, active_tol) -> QPResult:
    """x* itself (a bit-exact copy); viol = G x* - h <= 0; multipliers are all zero."""
    return QPResult(
        np.array(x_star, dtype=float, copy=True),
        UNCONSTRAINED,
        "x* feasible",
        0.0,
        viol >= -active_tol,
        0,
        np.zeros(viol.shape),
    )


def _finish(x, G, h, status, message, active_tol, iterations, z=None) -> QPResult:
    v = G @ x - h
    return QPResult(
        x,
        status,
        message,
        max(float(v.max()), 0.0) if v.size else 0.0,
        v >= -active_tol,
        int(iterations),
        z,
    )


def violation_message(G, h, x, prefix: str = "infeasible") -> str:
    """Describe which rows G x - h > 0 and by how much (units of each row)."""
    v = G @ x - h
    rows = np.flatnonzero(v > 0.0)
    if rows.size == 0:
        return f"{prefix}: least-violation answer violates no row"
    parts = ", ".join(f"row {i}: {v[i]:.3g}" for i in rows)
    return f"{prefix}: least-violation answer violates {rows.size} row(s) [{parts}]; sum sq {float(np.sum(v[rows] ** 2)):.3g}"


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


def least_violation(G, h, x_star, W, eps_reg: float = DEFAULT_EPS_REG, active_tol: float = DEFAULT_ACTIVE_TOL,
                    prefix: str = "infeasible") -> QPResult:
    """Least-violation answer used when G x <= h has no solution.

    Minimises ``V(x) = sum_i max((G x - h)_i, 0)^2 + eps_eff (x - x*)^T W (x - x*)`` with
    ``eps_eff = reg_weight(G, W, eps_reg)``. V is strictly convex and C^1, so the answer is
    unique; as eps_reg -> 0 it tends to the W-closest-to-x* minimiser of the summed squared
    violations. For n <= 2 it is solved exactly by :func:`qp_exact.least_violation_exact`; for
    larger n by :class:`_SlackQP` (PIQP on the slack formulation). Status INFEASIBLE_FALLBACK.
    """
    G, h, x_star, W = validate(G, h, x_star, W)
    n = G.shape[1]
    if n <= 2:
        x, it = _exact.least_violation_exact(G, h, x_star, W, eps_reg)
    else:
        sq = _SlackQP(n, G.shape[0])
        x, it, ok = sq.solve(G, h, x_star, W, eps_reg)
        if not ok:
            return _error_result(x_star, G, h, "least-violation slack QP failed", active_tol)
    return _finish(x, G, h, INFEASIBLE_FALLBACK, violation_message(G, h, x, prefix), active_tol, it)


def polish(G, h, x_star, W, z, x=None, feas_rtol: float = 1e-10):
    """Refine an interior-point answer (x, z) on the active set it suggests.

    Active-set guess A = {i : z_i / max z > s_i / (|g_i| |x| + |h_i|)}, the usual interior-point
    indicator "multiplier larger than slack" made unit-free (s = h - G x; z_i s_i ~ mu -> 0, so
    active rows have z >> s and inactive rows s >> z). Without x: A = {i : z_i > 1e-6 max z}.
    Then solve ``min 1/2 |x - x*|_W^2  s.t.  G_A x = h_A``:  x = x* - W^-1 G_A^T lam,
    ``(G_A W^-1 G_A^T) lam = G_A x* - h_A`` (least squares if rank deficient, e.g. duplicated
    rows). Accept only if the KKT conditions hold for (x, z = lam on A): G x <= h within
    feas_rtol (|G| |x| + |h|) and lam >= -feas_rtol max|lam| -- then x is the exact optimum
    up to rounding. Returns (x, z) or None (keep the unpolished answer).
    """
    zmax = float(np.max(z, initial=0.0))
    if not zmax > 0.0:
        return None
    if x is None:
        A = np.flatnonzero(z > 1e-6 * zmax)
    else:
        slack = h - G @ x
        A = np.flatnonzero(z / zmax > slack / (np.abs(G) @ np.abs(x) + np.abs(h) + 1e-300))
    if A.size == 0:
        return None
    GA = G[A]
    GWinv = GA / W[None, :]
    Mat = GWinv @ GA.T
    rhs = GA @ x_star - h[A]
    if A.size == 1:
        lam = rhs / Mat[0]
    else:
        lam = np.linalg.lstsq(Mat, rhs, rcond=None)[0]
    x = x_star - GWinv.T @ lam
    if not np.all(np.isfinite(x)):
        return None
    if np.any(lam < -feas_rtol * float(np.max(np.abs(lam)))):
        return None
    if np.any(G @ x - h > feas_rtol * (np.abs(G) @ np.abs(x) + np.abs(h))):
        return None
    zp = np.zeros_like(z)
    zp[A] = np.maximum(lam, 0.0)
    return x, zp


# ----------------------------------------------------------------------------------------
# PIQP-based solvers
# ----------------------------------------------------------------------------------------


def _piqp():
    import piqp  # local import keeps `import qp` cheap for users of the exact solver only

    return piqp


def _configure(settings, eps_abs: float, eps_rel: float, max_iter: int) -> None:
    # PIQP also stops on a duality-gap test whose defaults (1e-8 abs, 1e-9 rel) are much looser
    # than eps_abs here: with them an answer can sit ~1e-5 inside its active row with a 15 %
    # wrong multiplier while reporting primal/dual residuals ~1e-13. Tie them to eps_abs/rel.
    settings.eps_abs = eps_abs
    settings.eps_rel = eps_rel
    settings.eps_duality_gap_abs = eps_abs
    settings.eps_duality_gap_rel = eps_rel
    settings.max_iter = max_iter
    settings.verbose = False
    settings.compute_timings = False


class _SlackQP:
    """Least-violation problem as a QP in v = (x, s) in R^(n+m), solved by PIQP.

    minimise   1/2 v^T P v + c^T v,  P = diag(2 eps_eff W, 2 I_m),  c = (-2 eps_eff W x*, 0)
    subject to [G  -I] v <= h,  s >= 0  (x free).

    At the optimum s = max(G x - h, 0), so the cost equals V(x) - const of
    :func:`least_violation`. The solver object is set up once and updated afterwards.
    """

    def __init__(self, n: int, m: int, eps_abs: float = 1e-10, eps_rel: float = 1e-11, max_iter: int = 250):
        piqp = _piqp()
        self.n, self.m = n, m
        self._ok = piqp.Status.PIQP_SOLVED
        self.solver = piqp.DenseSolver()
        _configure(self.solver.settings, eps_abs, eps_rel, max_iter)
        N = n + m
        self._P = np.asfortranarray(np.eye(N))
        self._c = np.zeros(N)
        self._A = np.asfortranarray(np.hstack([np.zeros((m, n)), -np.eye(m)]))
        self._xl = np.concatenate([np.full(n, -np.inf), np.zeros(m)])
        self.solver.setup(self._P, self._c, None, None, self._A, None, np.ones(m), self._xl, None)

    def solve(self, G, h, x_star, W, eps_reg):
        n = self.n
        e = reg_weight(G, W, eps_reg)
        idx = np.arange(n)
        self._P[idx, idx] = 2.0 * e * W
        self._c[:n] = -2.0 * e * W * x_star
        self._A[:, :n] = G
        self.solver.update(P=self._P, c=self._c, G=self._A, h_u=np.ascontiguousarray(h))
        status = self.solver.solve()
        res = self.solver.result
        x = np.array(res.x[:n], dtype=float, copy=True)
        return x, int(res.info.iter), status == self._ok and np.all(np.isfinite(x))


class AdaptationQP:
    """Re-usable PIQP dense solver for fixed sizes (n, m), updated at every control step.

    The PIQP ``DenseSolver`` is created and ``setup`` once in the constructor (with
    placeholder data); :meth:`solve` only calls ``update(c=..., G=..., h_u=...)`` and
    ``solve()``, so the 1 kHz loop never rebuilds or reallocates the solver.

    PIQP 0.7 formulates ``min 1/2 x^T P x + c^T x  s.t.  A x = b,  h_l <= G x <= h_u,
    x_l <= x <= x_u``; we use P = diag(W), c = -W x*, G = G, h_u = h and leave h_l = -inf
    (None at setup). The objective then differs from 1/2 (x-x*)^T W (x-x*) by a constant.

    Parameters
    ----------
    n, m : problem sizes (n = 1 or 2 in the controller; any n >= 1 works).
    W : positive diagonal weight (n,). Change it later with :meth:`set_weights`.
    active_tol : tolerance (row units) for the ``active`` mask.
    eps_reg : relative regularisation of the least-violation fallback (see :func:`least_violation`).
    fallback : "exact" (qp_exact, default for n <= 2) or "piqp" (slack QP with a second,
        also pre-built PIQP solver; used automatically for n > 2).
    eps_abs, eps_rel, max_iter : PIQP termination settings.
    polish : refine PIQP's interior-point answer on its active set (see :func:`polish`);
        without it x lies ~eps_abs inside the active rows and ``active`` may miss them.
    """

    def __init__(self, n: int, m: int, W, *, active_tol: float = DEFAULT_ACTIVE_TOL,
                 eps_reg: float = DEFAULT_EPS_REG, fallback: Optional[str] = None,
                 eps_abs: float = 1e-10, eps_rel: float = 1e-11, max_iter: int = 250, polish: bool = True):
        if n < 1 or m < 1:
            raise QPShapeError(f"n and m must be >= 1, got n={n}, m={m}")
        W = _as_float(W, "W")
        if W.shape != (n,):
            raise QPShapeError(f"W has shape {W.shape}, expected ({n},) (the diagonal)")
        if not np.all(np.isfinite(W)) or not np.all(W > 0):
            raise ValueError(f"W must be finite and positive, got {W}")
        if fallback is None:
            fallback = "exact" if n <= 2 else "piqp"
        if fallback not in ("exact", "piqp") or (fallback == "exact" and n > 2):
            raise ValueError(f"fallback must be 'exact' (n <= 2) or 'piqp', got {fallback!r} with n={n}")
        piqp = _piqp()
        self.n, self.m = int(n), int(m)
        self.active_tol = float(active_tol)
        self.eps_reg = float(eps_reg)
        self.fallback = fallback
        self.polish = bool(polish)
        self._status_solved = piqp.Status.PIQP_SOLVED
        self._status_infeasible = piqp.Status.PIQP_PRIMAL_INFEASIBLE
        self.W = W.copy()
        self.solver = piqp.DenseSolver()
        _configure(self.solver.settings, eps_abs, eps_rel, max_iter)
        self._P = np.asfortranarray(np.diag(self.W))
        self._c = np.zeros(n)
        self._G = np.asfortranarray(np.zeros((m, n)))
        self._h = np.ones(m)
        self.solver.setup(self._P, self._c, None, None, self._G, None, self._h, None, None)
        self._slack = _SlackQP(n, m, eps_abs, eps_rel, max_iter) if fallback == "piqp" else None
        self.calls = 0  # number of PIQP solves (diagnostics)

    def set_weights(self, W) -> None:
        """Change the diagonal weight W (n,) (updates PIQP's P in place; no rebuild)."""
        W = _as_float(W, "W")
        if W.shape != (self.n,):
            raise QPShapeError(f"W has shape {W.shape}, expected ({self.n},)")
        if not np.all(np.isfinite(W)) or not np.all(W > 0):
            raise ValueError(f"W must be finite and positive, got {W}")
        self.W = W.copy()
        idx = np.arange(self.n)
        self._P[idx, idx] = self.W
        self.solver.update(P=self._P)

    def solve(self, G, h, x_star) -> QPResult:
        """Solve the QP for this step's data. Raises only :class:`QPShapeError`.

        1. non-finite G, h or x* -> SOLVER_ERROR, x = x*;
        2. G x* <= h (tolerance 0) -> UNCONSTRAINED, x = x* bit-exact, PIQP not called;
        3. PIQP (update + solve); PIQP_SOLVED -> ACTIVE (z = PIQP's z_u);
        4. PIQP_PRIMAL_INFEASIBLE or any other PIQP failure (MAX_ITER_REACHED, NUMERICS):
           n <= 2 ("exact" fallback): :func:`qp_exact.solve_exact` decides -- its exact
           optimum (ACTIVE) if the problem is feasible after all, else its exact
           least-violation answer (INFEASIBLE_FALLBACK); the message names PIQP's status.
           "piqp" fallback: least-violation slack QP (INFEASIBLE_FALLBACK), SOLVER_ERROR with
           x = x* if that fails too.
        """
        G, h, x_star, _ = validate(G, h, x_star, None, self.n, self.m)
        tol = self.active_tol
        bad = _nonfinite_name(G, h, x_star, None)
        if bad is not None:
            return _error_result(x_star, G, h, f"non-finite values in {bad}", tol)
        v_star = G @ x_star - h
        if np.all(v_star <= 0.0):
            return _unconstrained_result(x_star, v_star, tol)

        W = self.W
        self._c[:] = -W * x_star
        self._G[:, :] = G
        self._h[:] = h
        self.solver.update(c=self._c, G=self._G, h_u=self._h)
        status = self.solver.solve()
        self.calls += 1
        res = self.solver.result
        it = int(res.info.iter)
        if status == self._status_solved:
            x = np.array(res.x, dtype=float, copy=True)
            z = np.array(res.z_u, dtype=float, copy=True)
            if np.all(np.isfinite(x)):
                msg = "solved (PIQP)"
                if self.polish:
                    pol = polish(G, h, x_star, W, z, x)
                    if pol is not None:
                        x, z = pol
                        msg = "solved (PIQP, polished)"
                return _finish(x, G, h, ACTIVE, msg, tol, it, z)
            status_name = "PIQP_SOLVED with non-finite x"
        else:
            status_name = status.name

        # PIQP did not solve it (PIQP_PRIMAL_INFEASIBLE, or MAX_ITER / NUMERICS ...).
        if self.fallback == "exact":
            # n <= 2: the exact enumeration decides feasibility itself; it returns the exact QP
            # optimum (ACTIVE) if PIQP gave up on a feasible problem, else the least-violation
            # answer (INFEASIBLE_FALLBACK).
            ex = _exact.solve_exact(G, h, x_star, W, active_tol=tol, eps_reg=self.eps_reg)
            prefix = f"PIQP status {status_name}; exact solver: "
            return QPResult(ex.x, ex.status, prefix + ex.message, ex.max_violation, ex.active,
                            it + ex.iterations, ex.z)
        x, it2, ok = self._slack.solve(G, h, x_star, W, self.eps_reg)
        if not ok:
            return _error_result(x_star, G, h, f"PIQP status {status_name}; least-violation slack QP failed", tol)
        msg = violation_message(G, h, x, prefix=f"PIQP status {status_name}; infeasible")
        return _finish(x, G, h, INFEASIBLE_FALLBACK, msg, tol, it + it2)


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
    bad = _nonfinite_name(G, h, x_star, W)
    if bad is not None or _bad_weight(W):
        return _error_result(x_star, G, h, f"non-finite or invalid values in {bad or 'W'}", active_tol)
    v_star = G @ x_star - h
    if skip_if_feasible and np.all(v_star <= 0.0):
        return _unconstrained_result(x_star, v_star, active_tol)
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
        return _finish(x, G, h, ACTIVE, f"solved ({solver} via qpsolvers)", active_tol, 0, z)
    return least_violation(G, h, x_star, W, eps_reg, active_tol, prefix=f"{solver}: {why}; infeasible")


# ----------------------------------------------------------------------------------------
# KKT residuals
# ----------------------------------------------------------------------------------------


def kkt_residuals(G, h, x_star, W, x, z=None, active_tol: float = 1e-7) -> dict:
    """KKT residuals of x (and multipliers z) for the QP, all as infinity norms.

    Returns a dict with
      ``primal``          max(G x - h, 0)                 [row units]
      ``dual``            max(-z, 0)                       [cost / row units]
      ``complementarity`` max |z_i (G x - h)_i|            [cost units]
      ``stationarity``    |W (x - x*) + G^T z|_inf        [cost / x units]
      ``z``               the multipliers used.
    If z is None it is recovered by non-negative least squares
    ``min_{z_A >= 0} |G_A^T z_A + W (x - x*)|`` over the rows with G x - h >= -active_tol
    (z = 0 on the other rows), so ``dual`` is 0 and ``stationarity`` measures optimality.
    """
    from scipy.optimize import nnls

    G, h, x_star, W = validate(G, h, x_star, W)
    x = _as_float(x, "x")
    if x.shape != x_star.shape:
        raise QPShapeError(f"x has shape {x.shape}, expected {x_star.shape}")
    v = G @ x - h
    grad = W * (x - x_star)
    if z is None:
        z = np.zeros(G.shape[0])
        act = np.flatnonzero(v >= -active_tol)
        if act.size:
            za, _ = nnls(G[act].T, -grad)
            z[act] = za
    else:
        z = _as_float(z, "z")
        if z.shape != h.shape:
            raise QPShapeError(f"z has shape {z.shape}, expected {h.shape}")
    return {
        "primal": float(max(np.max(v, initial=0.0), 0.0)),
        "dual": float(max(np.max(-z, initial=0.0), 0.0)),
        "complementarity": float(np.max(np.abs(z * v), initial=0.0)),
        "stationarity": float(np.max(np.abs(grad + G.T @ z), initial=0.0)),
        "z": z,
    }


# Imported last: qp_exact imports QPResult and the helpers above from this module.
from . import qp_exact as _exact  # noqa: E402
