"""Problem, result and status types of the adaptation QP, and the helpers its solvers share.

The solvers (:mod:`qp` with PIQP, :mod:`qp_exact` in numpy, :mod:`qp_fast` in numba) all import
from this module and never from each other's internals.

Problem (n = 2 variables, or n = 1 in single-parameter modes; m rows, m = 37 in the controller:
its 17 contact/actuator constraints with the estimated push force, the same 17 without it, and
3 parameter-range rows, see ``controller.QP_ROWS``)::

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

Multipliers (one sign convention for every solver): ``z`` (shape (m,)) with ``z >= 0`` and the
Lagrangian ``L(x, z) = 1/2 (x - x*)^T W (x - x*) + z^T (G x - h)``, so the KKT conditions are

    stationarity     W (x - x*) + G^T z = 0
    primal feas.     G x - h <= 0
    dual feas.       z >= 0
    complementarity  z_i (G x - h)_i = 0.

z_i has units [cost unit] / [unit of row i]; it is the marginal decrease of the optimal cost
per unit relaxation of h_i. PIQP reports the same quantity for one-sided rows as ``z_u``.

Status values equal the ROS message constants ``biped_msgs_py.msg.ControllerStatus.QP_*``:

* ``UNCONSTRAINED = 0``       x* is feasible (G x* <= h with zero tolerance, as evaluated by
  :func:`constraint_values`); x = x* bit-exact, no solver call.
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
    "validate",
    "constraint_values",
    "objective",
    "kkt_residuals",
    "least_violation",
    "least_violation_exact",
    "min_piecewise_quadratic_1d",
    "reg_weight",
    "violation_message",
    "DEFAULT_ACTIVE_TOL",
    "DEFAULT_EPS_REG",
    "DEFAULT_FEAS_RTOL",
    "DEFAULT_PARALLEL_TOL",
    "DEFAULT_ZERO_ROW_RTOL",
    "ROUNDING_RTOL",
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
#: A candidate answer x satisfies row i when
#: g_i x - h_i <= DEFAULT_FEAS_RTOL (|g_i| |x| + |h_i|) + ROUNDING_RTOL |g_i| |x*|
#: (rounding of the closed-form candidate formulas; dimensionless). The second term covers
#: candidates computed from x* (x = x* - lam W^-1 g^T): a projection landing on the origin from
#: x* = (0, 1) is ~eps |x*| off its row while |x| ~ 0.
DEFAULT_FEAS_RTOL = 1e-10
#: A few units of rounding (8 eps, dimensionless); see DEFAULT_FEAS_RTOL.
ROUNDING_RTOL = 8.0 * float(np.finfo(float).eps)
#: Two rows are not intersected when |det [g_i; g_j]| <= DEFAULT_PARALLEL_TOL |g_i| |g_j|
#: (|sine of the angle between them|; dimensionless).
DEFAULT_PARALLEL_TOL = 1e-10
#: A row is "zero" when |g_i| <= DEFAULT_ZERO_ROW_RTOL max_j |g_j| (dimensionless).
DEFAULT_ZERO_ROW_RTOL = 1e-13


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


_new_object = object.__new__


def _result(x, status, message, max_violation, active, iterations, z) -> QPResult:
    """Same as ``QPResult(...)`` (all fields given, already of the right types).

    The frozen dataclass ``__init__`` sets each field through ``object.__setattr__``; this fills
    the instance dictionary in one go, which costs about a third as much. Used on the 1 kHz path;
    the instance is indistinguishable from one built by the constructor.
    """
    r = _new_object(QPResult)
    r.__dict__.update(x=x, status=status, message=message, max_violation=max_violation, active=active,
                      iterations=iterations, z=z)
    return r


# ----------------------------------------------------------------------------------------
# shapes, finiteness, results
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


def constraint_values(G, x, h) -> np.ndarray:
    """v = G x - h (row units), evaluated as ``((G[:, 0] x_0 + G[:, 1] x_1) + ...) - h``.

    The one floating-point expression behind every "is x feasible" decision of the solvers
    (x* feasible <=> all v <= 0): IEEE products and sums in this order, no fused multiply-add.
    ``G @ x`` is not used because BLAS may fuse or reorder (it differs from this in the last bit
    for ~15 % of random rows), and the compiled kernels (:mod:`qp_fast`) evaluate the same
    expression, so their decisions are bit-for-bit those of :mod:`qp_exact`.
    """
    v = G[:, 0] * x[0]
    for j in range(1, G.shape[1]):
        v = v + G[:, j] * x[j]
    return v - h


def objective(x, x_star, W) -> float:
    """1/2 (x - x*)^T diag(W) (x - x*)."""
    d = np.asarray(x, float) - np.asarray(x_star, float)
    return 0.5 * float(np.dot(np.asarray(W, float) * d, d))


def _nonfinite_name(G, h, x_star, W) -> Optional[str]:
    """Name of the first of G, h, x_star, W holding a NaN or an infinity, else None."""
    # fast path: a sum is finite iff every term is (barring overflow of huge finite values,
    # which then only costs the detailed check below)
    with np.errstate(invalid="ignore", over="ignore"):
        total = G.sum() + h.sum() + x_star.sum() + (0.0 if W is None else W.sum())
    if np.isfinite(total):
        return None
    for name, a in (("G", G), ("h", h), ("x_star", x_star), ("W", W)):
        if a is not None and not np.all(np.isfinite(a)):
            return name
    return None


def _bad_weight(W) -> bool:
    return W is not None and not np.all(W > 0.0)


def _error_result(x_star, G, h, message, active_tol) -> QPResult:
    """SOLVER_ERROR with x = x* (a copy); max_violation is NaN when a row of G x* - h is not finite."""
    x = np.array(x_star, dtype=float, copy=True)
    with np.errstate(invalid="ignore", over="ignore"):
        v = constraint_values(G, x, h)
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
    """QPResult for the answer x: max_violation and the active mask from v = G x - h."""
    v = constraint_values(G, x, h)
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
    v = constraint_values(G, x, h)
    rows = np.flatnonzero(v > 0.0)
    if rows.size == 0:
        return f"{prefix}: least-violation answer violates no row"
    parts = ", ".join(f"row {i}: {v[i]:.3g}" for i in rows)
    return f"{prefix}: least-violation answer violates {rows.size} row(s) [{parts}]; sum sq {float(np.sum(v[rows] ** 2)):.3g}"


# ----------------------------------------------------------------------------------------
# least violation (the INFEASIBLE_FALLBACK answer)
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


def least_violation(G, h, x_star, W, eps_reg: float = DEFAULT_EPS_REG, active_tol: float = DEFAULT_ACTIVE_TOL,
                    prefix: str = "infeasible") -> QPResult:
    """Least-violation answer used when G x <= h has no solution.

    Minimises ``V(x) = sum_i max((G x - h)_i, 0)^2 + eps_eff (x - x*)^T W (x - x*)`` with
    ``eps_eff = reg_weight(G, W, eps_reg)``. V is strictly convex and C^1, so the answer is
    unique; as eps_reg -> 0 it tends to the W-closest-to-x* minimiser of the summed squared
    violations. For n <= 2 it is solved exactly by :func:`least_violation_exact`; for larger n
    by :class:`_SlackQP` (PIQP on the slack formulation). Status INFEASIBLE_FALLBACK.
    """
    G, h, x_star, W = validate(G, h, x_star, W)
    n = G.shape[1]
    if n <= 2:
        x, it = least_violation_exact(G, h, x_star, W, eps_reg)
    else:
        sq = _SlackQP(n, G.shape[0])
        x, it, ok = sq.solve(G, h, x_star, W, eps_reg)
        if not ok:
            return _error_result(x_star, G, h, "least-violation slack QP failed", active_tol)
    return _finish(x, G, h, INFEASIBLE_FALLBACK, violation_message(G, h, x, prefix), active_tol, it)


# ----------------------------------------------------------------------------------------
# PIQP plumbing shared by the least-violation slack QP and AdaptationQP
# ----------------------------------------------------------------------------------------


def _piqp():
    import piqp  # local import keeps `import qp_types` cheap for users of the exact solvers only

    return piqp


def _configure(settings, eps_abs: float, eps_rel: float, max_iter: int, preconditioner_iter: Optional[int] = None,
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


# ----------------------------------------------------------------------------------------
# KKT residuals (the oracle of the tests)
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
