"""The family of reference trajectories q_d(p, tau) (paper eqs. 12-14) and its partial derivatives,
and its extension by a third parameter, the torso offset lambda (``with_torso``, ``eq11_torso``).

Pure Python (NumPy), no ROS. An asset of the robot that both sides use: the simulator takes its initial
state from it, the controller its reference (hence it lives in ``biped_sim``, which the controller
depends on).

Every representation has the paper's form in time (eq. 12): at stride p [m] and time-scaled phase
tau [s] in [0, T],

    q_i(tau, p) = sum_{j=0..4} a_ij(p) tau^j,        i = 1..6 [rad],

and differs only in how the 30 time coefficients a_ij depend on p. Two are read:

* ``"cubic_spline_in_p"`` (the family in use, ``robots/biped7/gait_family.json``): each a_ij(p) is a C2 cubic
  spline in p on breakpoints x_0 < ... < x_P, the "not-a-knot" spline through the values
  Y_k = a(x_k) (third derivative also continuous at x_1 and x_(P-1)). Piece k (p in [x_k, x_(k+1)])
  is a cubic in u = p - x_k:  a(p) = sum_{m=0..3} c_km u^m,  c_k0 = Y_k. So a, da/dp and d2a/dp2 are
  continuous in p (to round-off) and q_d is exact at every breakpoint: with p_d a breakpoint,
  a(p_d) is the stored Y exactly. The paper's single b_ijk (eq. 13) do *not* describe this family:
  ``paper_b`` gives one set of b_ijk (k = 0..3, powers of p) per piece instead.
* ``"polynomial_in_p"`` (the paper's eq. 13, the project's earlier files): a_ij(p) = sum_k b_ijk
  (p - center)^k, one polynomial of degree K - 1 over the whole range.

All partial derivatives that eq. (11) needs are evaluated in closed form. The fit of the spline values
to optimised strides (``fit_spline_family``) is a least-squares fit forced through p_d exactly; the
polynomial fit (``fit_family``) is kept for the legacy form and for comparisons.
"""
from __future__ import annotations

import bisect
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biped_model.finite import finite_array
from biped_model.settings import default_robot_dir

SPLINE = "cubic_spline_in_p"
POLYNOMIAL = "polynomial_in_p"
REPRESENTATIONS = (SPLINE, POLYNOMIAL)


class GaitFamilyError(ValueError):
    """The gait-family file is missing, malformed, or inconsistent with the robot."""


@dataclass(frozen=True)
class GaitSample:
    """q_d and its partial derivatives at (p, tau); every array has shape (6,) [rad, rad/m, rad/s, ...]."""

    q: np.ndarray
    dq_dp: np.ndarray
    dq_dtau: np.ndarray
    d2q_dp2: np.ndarray
    d2q_dtau2: np.ndarray
    d2q_dp_dtau: np.ndarray


def eq11(g: GaitSample, p_dot: float, tau_dot: float, p_ddot: float = 0.0, tau_ddot: float = 0.0
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paper eq. (11), written once: (q_d, q_d', q_d'') from the partial derivatives at (p, tau),
    q_d' = dq/dp p' + dq/dtau tau',
    q_d'' = dq/dp p'' + dq/dtau tau'' + d2q/dp2 p'^2 + d2q/dtau2 tau'^2 + 2 d2q/dpdtau p' tau'."""
    qd = g.dq_dp * p_dot + g.dq_dtau * tau_dot
    qdd = (g.dq_dp * p_ddot + g.dq_dtau * tau_ddot + g.d2q_dp2 * p_dot**2 + g.d2q_dtau2 * tau_dot**2
           + 2.0 * g.d2q_dp_dtau * p_dot * tau_dot)
    return g.q, qd, qdd


# ---------------------------------------------------------------------- the torso parameter lambda
#: dq/dlambda per unit profile: the torso's absolute pitch q1 + q2 + q3 changes by lambda phi, the stance
#: thigh's (q1 + q2) and the swing thigh's (q1 + q2 + q3 + q4) absolute angles do not: q3 += lambda phi
#: (torso w.r.t. stance thigh), q4 -= lambda phi (swing thigh w.r.t. torso). Paper order q1..q6.
TORSO_DIRECTION = np.array([0.0, 0.0, 1.0, -1.0, 0.0, 0.0])


def torso_profile(s: float) -> tuple[float, float, float]:
    """(phi, dphi/ds, d2phi/ds2) of the torso offset's profile over the step, s = tau / T [-]:
    phi(s) = 16 s^2 (1 - s)^2 on [0, 1] (phi(1/2) = 1; phi = phi' = 0 at s = 0 and s = 1), and 0 outside
    [0, 1] (a step that lasts longer than T, or tau < 0: no offset). phi is C1 everywhere; phi'' jumps
    at s = 0 and 1 (from 32 to 0), so q_d and q_d' are continuous in tau, q_d'' is not there."""
    if s <= 0.0 or s >= 1.0:
        return 0.0, 0.0, 0.0
    u = 1.0 - s
    return 16.0 * s * s * u * u, 32.0 * s * u * (u - s), 32.0 * (u * u - 4.0 * s * u + s * s)


@dataclass(frozen=True)
class TorsoGaitSample:
    """q_d(p, tau, lambda) = q_d(p, tau) + lambda phi(tau / T) e (e = ``TORSO_DIRECTION``) and its partial
    derivatives; arrays (6,). The lambda terms change q, dq/dtau and d2q/dtau2; the new ones are
    dq/dlambda = phi e [rad/rad] and d2q/dtau dlambda = phi'(s) / T e [1/s]; d2q/dlambda2 = d2q/dp dlambda
    = 0 (q_d is affine in lambda and lambda does not touch the p-dependence)."""

    q: np.ndarray
    dq_dp: np.ndarray
    dq_dtau: np.ndarray
    dq_dlam: np.ndarray
    d2q_dp2: np.ndarray
    d2q_dtau2: np.ndarray
    d2q_dp_dtau: np.ndarray
    d2q_dtau_dlam: np.ndarray


def with_torso(g: GaitSample, tau: float, lam: float, T: float) -> TorsoGaitSample:
    """The sample ``g`` of q_d(p, tau) extended by the torso offset lambda [rad] at phase tau [s] of a
    step of duration T [s] (see :class:`TorsoGaitSample`)."""
    phi, dphi, d2phi = torso_profile(float(tau) / T)
    e = TORSO_DIRECTION
    return TorsoGaitSample(q=g.q + (lam * phi) * e, dq_dp=g.dq_dp, dq_dtau=g.dq_dtau + (lam * dphi / T) * e,
                           dq_dlam=phi * e, d2q_dp2=g.d2q_dp2, d2q_dtau2=g.d2q_dtau2 + (lam * d2phi / (T * T)) * e,
                           d2q_dp_dtau=g.d2q_dp_dtau, d2q_dtau_dlam=(dphi / T) * e)


def eq11_torso(g: TorsoGaitSample, p_dot: float, tau_dot: float, lam_dot: float, p_ddot: float = 0.0,
               tau_ddot: float = 0.0, lam_ddot: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. (11) with the third parameter: (q_d, q_d', q_d'') along (p, tau, lambda)(t),
    q_d' = dq/dp p' + dq/dtau tau' + dq/dlambda lambda',
    q_d'' = dq/dp p'' + dq/dtau tau'' + dq/dlambda lambda'' + d2q/dp2 p'^2 + d2q/dtau2 tau'^2
            + 2 d2q/dpdtau p' tau' + 2 d2q/dtaudlambda tau' lambda'   (d2q/dlambda2 = d2q/dpdlambda = 0)."""
    qd = g.dq_dp * p_dot + g.dq_dtau * tau_dot + g.dq_dlam * lam_dot
    qdd = (g.dq_dp * p_ddot + g.dq_dtau * tau_ddot + g.dq_dlam * lam_ddot + g.d2q_dp2 * p_dot**2
           + g.d2q_dtau2 * tau_dot**2 + 2.0 * g.d2q_dp_dtau * p_dot * tau_dot + 2.0 * g.d2q_dtau_dlam * tau_dot * lam_dot)
    return g.q, qd, qdd


def _powers(x: float, n: int) -> np.ndarray:
    """(3, n): rows x^k, d/dx x^k = k x^(k-1), d2/dx2 x^k = k (k-1) x^(k-2), k = 0..n-1."""
    out = np.zeros((3, n))
    pw = 1.0
    for k in range(n):
        out[0, k] = pw
        if k + 1 < n:
            out[1, k + 1] = (k + 1) * pw
        if k + 2 < n:
            out[2, k + 2] = (k + 2) * (k + 1) * pw
        pw *= x
    return out


class GaitFamily:
    """q_d(p, tau) as pieces in p: on piece k, a_ij(p) = sum_m coef[k, i, j, m] (p - centers[k])^m.

    Build with ``GaitFamily(b, ...)`` (one polynomial piece, the paper's eq. 13, ``b[i, j, k]``
    multiplying (p - center)^k tau^j) or ``GaitFamily.spline(breakpoints, values, ...)`` (C2 cubic
    spline in p). ``p_min``/``p_max`` [m] is the range the controller may use; ``T`` [s] the step
    duration; ``p_d`` [m] the preferred stride."""

    def __init__(self, b: np.ndarray, T: float, p_d: float, p_min: float, p_max: float, meta: dict | None = None,
                 center: float = 0.0):
        """One polynomial in p: ``b[i, j, k]`` multiplies (p - center)^k tau^j. With center = 0 this is
        the paper's b_ijk (eq. 13); centred on p_d it is far better conditioned (the monomial
        coefficients reach ~1e8 and cancel), and ``paper_b`` expands it in powers of p."""
        b = np.asarray(b, dtype=float)
        if b.ndim != 3 or b.shape[0] != 6 or b.shape[1] != 5:
            raise GaitFamilyError(f"gait family: b must have shape (6, 5, K), got {b.shape}")
        self._setup(POLYNOMIAL, b[None], np.array([float(center)]), [], T, p_d, p_min, p_max, meta)
        self.b = b
        self.center = float(center)

    def _setup(self, representation: str, coef: np.ndarray, centers: np.ndarray, inner: list[float], T: float,
               p_d: float, p_min: float, p_max: float, meta: dict | None) -> None:
        finite_array(coef, "coefficients", error=GaitFamilyError,
                     message="gait family: coefficients contain non-finite values")
        if not (p_min <= p_d <= p_max) or not T > 0:
            raise GaitFamilyError(f"gait family: need p_min <= p_d <= p_max and T > 0 (got {p_min}, {p_d}, {p_max}, {T})")
        self.representation = representation
        self._coef = np.ascontiguousarray(coef)          # (P, 6, 5, K)
        self._centers = [float(c) for c in centers]      # (P,)
        self._inner = [float(x) for x in inner]          # P - 1 interior breakpoints (bisect)
        self.T = float(T)
        self.p_d = float(p_d)
        self.p_min = float(p_min)
        self.p_max = float(p_max)
        self.meta = meta or {}

    @classmethod
    def spline(cls, breakpoints, values, T: float, p_d: float, p_min: float | None = None,
               p_max: float | None = None, meta: dict | None = None) -> "GaitFamily":
        """C2 not-a-knot cubic spline in p through ``values[k] = a(breakpoints[k])`` ((P+1, 6, 5),
        a_ij in rad/s^j). p_d must be a breakpoint (the family is then exact there). The range
        defaults to [x_0, x_P]."""
        x = np.asarray(breakpoints, dtype=float)
        Y = np.asarray(values, dtype=float)
        if Y.shape != (x.size, 6, 5):
            raise GaitFamilyError(f"gait family: spline values must have shape ({x.size}, 6, 5), got {Y.shape}")
        if not np.any(x == p_d):
            raise GaitFamilyError(f"gait family: p_d = {p_d} must be one of the spline breakpoints")
        coef = spline_pieces(x, Y)
        self = cls.__new__(cls)
        lo = float(x[0]) if p_min is None else float(p_min)
        hi = float(x[-1]) if p_max is None else float(p_max)
        if lo < x[0] - 1e-12 or hi > x[-1] + 1e-12:
            raise GaitFamilyError(f"gait family: range [{lo}, {hi}] leaves the spline's breakpoints [{x[0]}, {x[-1]}]")
        self._setup(SPLINE, coef, x[:-1], list(x[1:-1]), T, p_d, lo, hi, meta)
        self.breakpoints = x
        self.values = Y
        return self

    # ------------------------------------------------------------------ evaluation
    def _piece(self, p: float) -> int:
        """Index of the piece holding p (a breakpoint belongs to the piece on its right; outside the
        breakpoints the end pieces are extended)."""
        return bisect.bisect_right(self._inner, p)

    def piece_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(coef (P, 6, 5, K), inner breakpoints (P-1,), centers (P,)) as float64 arrays, for compiled code:
        on piece k = #{inner <= p}, a_ij(p) = sum_m coef[k, i, j, m] (p - centers[k])^m."""
        return (np.ascontiguousarray(self._coef, dtype=float), np.array(self._inner, dtype=float),
                np.array(self._centers, dtype=float))

    @property
    def n_pieces(self) -> int:
        """Number of polynomial pieces in p (1 for the polynomial family)."""
        return self._coef.shape[0]

    def piece_coefficients(self, k: int, p: float) -> np.ndarray:
        """(4, 6, 5): a, da/dp, d2a/dp2, d3a/dp3 of piece k's polynomial at p (the polynomial extended
        beyond its interval: one-sided limits at the breakpoints, for continuity checks)."""
        K = self._coef.shape[3]
        u = float(p) - self._centers[k]
        out = np.zeros((4, 6, 5))
        for m in range(K):
            for d in range(min(m, 3) + 1):
                out[d] += self._coef[k, :, :, m] * (math.perm(m, d) * u ** (m - d))
        return out

    def coefficients(self, p: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a(p), da/dp, d2a/dp2), each (6, 5): time coefficients of eq. (12) at stride p [rad/s^j,
        rad/(m s^j), rad/(m^2 s^j)]."""
        k = self._piece(float(p))
        c = self._coef[k] @ _powers(float(p) - self._centers[k], self._coef.shape[3]).T   # (6, 5, 3)
        return c[:, :, 0], c[:, :, 1], c[:, :, 2]

    def evaluate(self, p: float, tau: float) -> GaitSample:
        """q_d and its five partial derivatives at (p [m], tau [s])."""
        p = float(p)
        k = self._piece(p)
        c = self._coef[k] @ _powers(p - self._centers[k], self._coef.shape[3]).T   # (6, 5, 3): a, da/dp, d2a/dp2
        tp = _powers(float(tau), 5)                                               # (3, 5): tau^j and derivatives
        m = np.einsum("ijk,lj->ikl", c, tp)                                       # (6, 3 [p-deriv], 3 [tau-deriv])
        return GaitSample(q=m[:, 0, 0], dq_dp=m[:, 1, 0], dq_dtau=m[:, 0, 1], d2q_dp2=m[:, 2, 0],
                          d2q_dtau2=m[:, 0, 2], d2q_dp_dtau=m[:, 1, 1])

    def reference(self, p: float, p_dot: float, tau: float, tau_dot: float,
                  p_ddot: float = 0.0, tau_ddot: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q_d, q_d', q_d'') of eq. (11) at (p, tau)."""
        return eq11(self.evaluate(p, tau), p_dot, tau_dot, p_ddot, tau_ddot)

    def evaluate_torso(self, p: float, tau: float, lam: float) -> TorsoGaitSample:
        """q_d(p, tau, lambda) and its partial derivatives (lambda [rad]: the torso offset's amplitude)."""
        return with_torso(self.evaluate(p, tau), tau, float(lam), self.T)

    def reference_torso(self, p: float, p_dot: float, tau: float, tau_dot: float, lam: float, lam_dot: float,
                        p_ddot: float = 0.0, tau_ddot: float = 0.0, lam_ddot: float = 0.0
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q_d, q_d', q_d'') of eq. (11) with the torso parameter (:func:`eq11_torso`)."""
        return eq11_torso(self.evaluate_torso(p, tau, lam), p_dot, tau_dot, lam_dot, p_ddot, tau_ddot, lam_ddot)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Start of the preferred step, where every run starts: (q_d(p_d, 0), dq_d/dtau(p_d, 0)) [rad,
        rad/s] with tau' = 1, the LEFT foot in stance (the simulator's initial state and the controller's
        initial reference)."""
        g = self.evaluate(self.p_d, 0.0)
        return g.q.copy(), g.dq_dtau.copy()

    # ------------------------------------------------------------------ I/O
    @property
    def paper_b(self) -> np.ndarray:
        """b_ijk of eq. (13) in powers of p. Polynomial family: (6, 5, K). Spline family: the paper's
        single b_ijk do not exist; one set per piece, (P, 6, 5, 4), valid on [x_k, x_(k+1)]."""
        if self.representation == POLYNOMIAL:
            return expand_in_p(self.b, self.center)
        return np.array([expand_in_p(self._coef[k], self._centers[k]) for k in range(self._coef.shape[0])])

    def to_dict(self) -> dict:
        """JSON-ready description; ``GaitFamily.from_dict`` (and ``load``) read it back."""
        common = {"representation": self.representation, "T": self.T, "p_d": self.p_d,
                  "p_min": self.p_min, "p_max": self.p_max}
        if self.representation == POLYNOMIAL:
            return {**common, "b": self.paper_b.tolist(), "b_centered": self.b.tolist(), "center": self.center}
        return {**common,
                "breakpoints": self.breakpoints.tolist(),
                "values": self.values.tolist(),
                "pieces": self._coef.tolist(),
                "note": ("a_ij(p) is the C2 not-a-knot cubic spline through values[k][i][j] = a_ij(breakpoints[k]) "
                         "(a_ij multiplies tau^j, eq. 12). pieces[k][i][j][m] multiplies (p - breakpoints[k])^m on "
                         "[breakpoints[k], breakpoints[k+1]] (redundant with values; checked on load). The paper's "
                         "single b_ijk (eq. 13) do not describe this family; paper_b_per_piece[k] gives them piece "
                         "by piece (powers of p)."),
                "paper_b_per_piece": self.paper_b.tolist()}

    @classmethod
    def from_dict(cls, fam: dict, meta: dict | None = None) -> "GaitFamily":
        """Inverse of ``to_dict``. A dict without ``representation`` is the earlier polynomial file."""
        rep = fam.get("representation", POLYNOMIAL)
        if rep == SPLINE:
            out = cls.spline(np.array(fam["breakpoints"], dtype=float), np.array(fam["values"], dtype=float),
                             fam["T"], fam["p_d"], fam["p_min"], fam["p_max"], meta=meta)
            if "pieces" in fam:
                stored = np.array(fam["pieces"], dtype=float)
                if stored.shape != out._coef.shape or not np.allclose(stored, out._coef, rtol=1e-9, atol=1e-9):
                    raise GaitFamilyError("gait family: stored spline pieces disagree with the spline through the "
                                          "stored values")
            return out
        if rep == POLYNOMIAL:
            if "b_centered" in fam:
                return cls(np.array(fam["b_centered"]), fam["T"], fam["p_d"], fam["p_min"], fam["p_max"], meta=meta,
                           center=fam["center"])
            return cls(np.array(fam["b"]), fam["T"], fam["p_d"], fam["p_min"], fam["p_max"], meta=meta)
        raise GaitFamilyError(f"gait family: unknown representation {rep!r} (known: {', '.join(REPRESENTATIONS)})")

    @classmethod
    def load(cls, path: str | Path | None = None) -> "GaitFamily":
        p = Path(path) if path is not None else default_robot_dir() / "gait_family.json"
        if not p.is_file():
            raise GaitFamilyError(f"gait family: file not found: {p} (run scripts/generate_gait_family)")
        try:
            with open(p, encoding="utf-8") as fh:
                data = json.load(fh)
            return cls.from_dict(data["family"], meta=data)
        except GaitFamilyError as exc:
            raise GaitFamilyError(f"{exc} ({p})") from exc
        except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
            raise GaitFamilyError(f"gait family: malformed file {p}: {exc}") from exc


# ---------------------------------------------------------------------- cubic splines in p
def spline_second_derivatives(x: np.ndarray) -> np.ndarray:
    """Matrix K ((P+1) x (P+1)) with M = K Y: second derivatives at the breakpoints x_0..x_P of the
    not-a-knot C2 cubic spline through the values Y (P >= 3 pieces).

    Rows: C2 continuity at the interior breakpoints,
      h_(i-1) M_(i-1) + 2 (h_(i-1) + h_i) M_i + h_i M_(i+1) = 6 [(Y_(i+1) - Y_i)/h_i - (Y_i - Y_(i-1))/h_(i-1)],
    and not-a-knot (third derivative continuous) at x_1 and x_(P-1):
      h_1 M_0 - (h_0 + h_1) M_1 + h_0 M_2 = 0 (and the mirror image)."""
    x = np.asarray(x, dtype=float)
    P = x.size - 1
    if P < 3:
        raise GaitFamilyError(f"gait family: a not-a-knot spline needs at least 4 breakpoints, got {x.size}")
    h = np.diff(x)
    if np.any(h <= 0):
        raise GaitFamilyError("gait family: spline breakpoints must be strictly increasing")
    A = np.zeros((P + 1, P + 1))
    B = np.zeros((P + 1, P + 1))
    A[0, 0:3] = (h[1], -(h[0] + h[1]), h[0])
    A[P, P - 2:P + 1] = (h[P - 1], -(h[P - 2] + h[P - 1]), h[P - 2])
    for i in range(1, P):
        A[i, i - 1:i + 2] = (h[i - 1], 2.0 * (h[i - 1] + h[i]), h[i])
        B[i, i - 1] = 6.0 / h[i - 1]
        B[i, i] = -6.0 / h[i - 1] - 6.0 / h[i]
        B[i, i + 1] = 6.0 / h[i]
    return np.linalg.solve(A, B)


def spline_pieces(x: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Local coefficients (P, *Y.shape[1:], 4) of the not-a-knot spline through Y ((P+1, ...)): on
    piece k, s(p) = sum_m c_km (p - x_k)^m with c_k0 = Y_k (bitwise), c_k1 = (Y_(k+1) - Y_k)/h_k -
    h_k (2 M_k + M_(k+1))/6, c_k2 = M_k / 2, c_k3 = (M_(k+1) - M_k) / (6 h_k)."""
    x = np.asarray(x, dtype=float)
    Y = np.asarray(Y, dtype=float)
    flat = Y.reshape(x.size, -1)
    M = spline_second_derivatives(x) @ flat
    h = np.diff(x)[:, None]
    c = np.empty((x.size - 1, flat.shape[1], 4))
    c[:, :, 0] = flat[:-1]
    c[:, :, 1] = (flat[1:] - flat[:-1]) / h - h * (2.0 * M[:-1] + M[1:]) / 6.0
    c[:, :, 2] = 0.5 * M[:-1]
    c[:, :, 3] = (M[1:] - M[:-1]) / (6.0 * h)
    return c.reshape((x.size - 1,) + Y.shape[1:] + (4,))


def spline_weights(x: np.ndarray, p: np.ndarray) -> np.ndarray:
    """W (len(p), P+1): s(p_s) = W[s] @ Y for the not-a-knot spline on breakpoints x through any Y
    (the spline is linear in its values)."""
    x = np.asarray(x, dtype=float)
    E = spline_pieces(x, np.eye(x.size))              # (P, P+1, 4): piece k of the spline through e_l
    inner = list(x[1:-1])
    W = np.empty((len(p), x.size))
    for s, ps in enumerate(np.asarray(p, dtype=float)):
        k = bisect.bisect_right(inner, ps)
        u = ps - x[k]
        W[s] = E[k] @ (u ** np.arange(4))
    return W


def fit_spline_family(strides: np.ndarray, a: np.ndarray, p_d: float, breakpoints: np.ndarray) -> np.ndarray:
    """Values Y ((P+1, 6, 5)) at the breakpoints of the not-a-knot spline that fits a ((S, 6, 5), the
    time coefficients of the optimised strides) in least squares, with Y(p_d) = a(p_d) exactly (p_d
    must be a stride and a breakpoint). When the strides are the breakpoints the spline interpolates."""
    strides = np.asarray(strides, dtype=float)
    x = np.asarray(breakpoints, dtype=float)
    a = np.asarray(a, dtype=float)
    idx = np.flatnonzero(strides == p_d)
    kd = np.flatnonzero(x == p_d)
    if idx.size != 1 or kd.size != 1:
        raise GaitFamilyError("fit_spline_family: p_d must appear exactly once among the strides and the breakpoints")
    if strides.min() < x[0] - 1e-12 or strides.max() > x[-1] + 1e-12:
        raise GaitFamilyError("fit_spline_family: strides outside the breakpoints (no extrapolation)")
    a_d = a[idx[0]].reshape(-1)
    W = spline_weights(x, strides)
    free = np.delete(np.arange(x.size), kd[0])
    rhs = a.reshape(strides.size, -1) - W[:, kd[0]][:, None] * a_d[None, :]
    Wf = W[:, free]
    if np.linalg.matrix_rank(Wf) < free.size:
        raise GaitFamilyError("fit_spline_family: the strides do not determine the spline values "
                              "(some piece pair has too few strides)")
    sol, *_ = np.linalg.lstsq(Wf, rhs, rcond=None)
    Y = np.empty((x.size, a_d.size))
    Y[free] = sol
    Y[kd[0]] = a_d
    return Y.reshape((x.size, 6, 5))


# ---------------------------------------------------------------------- polynomials in p (eq. 13)
def expand_in_p(b_centered: np.ndarray, center: float) -> np.ndarray:
    """Coefficients in powers of (p - center) -> coefficients in powers of p (binomial expansion)."""
    K = b_centered.shape[-1]
    out = np.zeros_like(b_centered)
    for k in range(K):
        for m in range(k + 1):
            out[..., m] += b_centered[..., k] * math.comb(k, m) * (-center) ** (k - m)
    return out


def fit_family(strides: np.ndarray, a: np.ndarray, p_d: float, degree: int = 7, centered: bool = False) -> np.ndarray:
    """Least-squares fit of a_ij(p) (a: (S, 6, 5) at the S strides) by degree-``degree`` polynomials,
    passing exactly through the stride p_d (which must be one of ``strides``).

    Returns b (6, 5, degree+1) in powers of p (the paper's b_ijk), or with ``centered`` in powers of
    u = p - p_d (better conditioned; use ``GaitFamily(..., center=p_d)``)."""
    strides = np.asarray(strides, dtype=float)
    idx = np.flatnonzero(np.isclose(strides, p_d, rtol=0, atol=1e-12))
    if idx.size != 1:
        raise GaitFamilyError("fit_family: p_d must appear exactly once among the strides")
    a_d = a[idx[0]]
    others = np.delete(np.arange(len(strides)), idx[0])
    u = strides[others] - p_d
    V = u[:, None] ** np.arange(1, degree + 1)[None, :]          # (S-1, degree)
    Y = (a[others] - a_d[None]).reshape(len(others), -1)         # (S-1, 30)
    beta, *_ = np.linalg.lstsq(V, Y, rcond=None)                  # (degree, 30)
    coef_u = np.vstack([a_d.reshape(1, -1), beta]).T.reshape(6, 5, degree + 1)
    return coef_u if centered else expand_in_p(coef_u, p_d)
