"""Problem, result and status types of the adaptation QP, and the checks and result constructors its
solvers share (types only: the solvers live in :mod:`solver` (PIQP, and the least-violation fallback),
:mod:`exact` (numpy, the exact least-violation point) and :mod:`exact_kernels` (numba); no private name
crosses a module).

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
    "make_result",
    "error_result",
    "unconstrained_result",
    "finish_result",
    "as_float",
    "nonfinite_name",
    "bad_weight",
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


def make_result(x, status, message, max_violation, active, iterations, z) -> QPResult:
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


def as_float(a, name: str) -> np.ndarray:
    try:
        return np.asarray(a, dtype=float)
    except (TypeError, ValueError) as exc:  # e.g. ragged lists
        raise QPShapeError(f"{name} cannot be converted to a float array: {exc}") from exc


def validate(G, h, x_star, W=None, n: Optional[int] = None, m: Optional[int] = None):
    """Convert and check shapes. Returns float arrays (G (m,n), h (m,), x* (n,), W (n,) or None).

    Raises :class:`QPShapeError` naming the inconsistent array.
    """
    G = as_float(G, "G")
    h = as_float(h, "h")
    x_star = as_float(x_star, "x_star")
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
        W = as_float(W, "W")
        if W.shape != (nn,):
            raise QPShapeError(f"W has shape {W.shape}, expected ({nn},) (the diagonal)")
    return G, h, x_star, W


def constraint_values(G, x, h) -> np.ndarray:
    """v = G x - h (row units), evaluated as ``((G[:, 0] x_0 + G[:, 1] x_1) + ...) - h``.

    The one floating-point expression behind every "is x feasible" decision of the solvers
    (x* feasible <=> all v <= 0): IEEE products and sums in this order, no fused multiply-add.
    ``G @ x`` is not used because BLAS may fuse or reorder (it differs from this in the last bit
    for ~15 % of random rows), and the compiled kernels (:mod:`exact_kernels`) evaluate the same
    expression, so their decisions are bit-for-bit those of :mod:`exact`.
    """
    v = G[:, 0] * x[0]
    for j in range(1, G.shape[1]):
        v = v + G[:, j] * x[j]
    return v - h


def objective(x, x_star, W) -> float:
    """1/2 (x - x*)^T diag(W) (x - x*)."""
    d = np.asarray(x, float) - np.asarray(x_star, float)
    return 0.5 * float(np.dot(np.asarray(W, float) * d, d))


def nonfinite_name(G, h, x_star, W) -> Optional[str]:
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


def bad_weight(W) -> bool:
    return W is not None and not np.all(W > 0.0)


def error_result(x_star, G, h, message, active_tol) -> QPResult:
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


def unconstrained_result(x_star, viol, active_tol) -> QPResult:
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


def finish_result(x, G, h, status, message, active_tol, iterations, z=None) -> QPResult:
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
    x = as_float(x, "x")
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
        z = as_float(z, "z")
        if z.shape != h.shape:
            raise QPShapeError(f"z has shape {z.shape}, expected {h.shape}")
    return {
        "primal": float(max(np.max(v, initial=0.0), 0.0)),
        "dual": float(max(np.max(-z, initial=0.0), 0.0)),
        "complementarity": float(np.max(np.abs(z * v), initial=0.0)),
        "stationarity": float(np.max(np.abs(grad + G.T @ z), initial=0.0)),
        "z": z,
    }
