"""The family of reference trajectories q_d(p, tau) (paper eqs. 13-14) and its partial derivatives.

Pure Python, no ROS. An asset of the robot that both sides use: the simulator takes its initial state
from it, the controller its reference (hence it lives in ``biped_sim``, which the controller depends on).   q_i(tau, p) = sum_{j=0..4} ( sum_{k=0..7} b_ijk p^k ) tau^j,
p: stride [m], tau: time-scaled phase [s] in [0, T]. All the partial derivatives that eq. (11) needs
are evaluated in closed form from b_ijk.

The fit (``fit_family``) is an equality-constrained least-squares fit of every time coefficient a_ij by
a degree-7 polynomial in p, forced through the preferred gait p_d exactly: in u = p - p_d,
a_ij(u) = a_ij(p_d) + sum_{k=1..7} beta_ijk u^k, then expanded in powers of p.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .settings import default_config_dir


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


class GaitFamily:
    """b_ijk (6 x 5 x 8) with the step duration T, the preferred stride p_d and the valid stride range."""

    def __init__(self, b: np.ndarray, T: float, p_d: float, p_min: float, p_max: float, meta: dict | None = None,
                 center: float = 0.0):
        """``b[i, j, k]`` multiplies (p - center)^k tau^j. With center = 0 this is the paper's b_ijk
        (eq. 13); the fit stores the family centred on p_d, which is far better conditioned (the
        monomial coefficients reach ~1e8 and cancel), and ``paper_b`` expands it in powers of p."""
        b = np.asarray(b, dtype=float)
        self.center = float(center)
        if b.ndim != 3 or b.shape[0] != 6 or b.shape[1] != 5:
            raise GaitFamilyError(f"gait family: b must have shape (6, 5, K), got {b.shape}")
        if not np.all(np.isfinite(b)):
            raise GaitFamilyError("gait family: b contains non-finite values")
        if not (p_min <= p_d <= p_max) or not T > 0:
            raise GaitFamilyError(f"gait family: need p_min <= p_d <= p_max and T > 0 (got {p_min}, {p_d}, {p_max}, {T})")
        self.b = b
        self.T = float(T)
        self.p_d = float(p_d)
        self.p_min = float(p_min)
        self.p_max = float(p_max)
        self.meta = meta or {}
        K = b.shape[2]
        self._k = np.arange(K, dtype=float)
        self._j = np.arange(5, dtype=float)

    @staticmethod
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

    def coefficients(self, p: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a(p), da/dp, d2a/dp2), each (6, 5): time coefficients of eq. (12) at stride p."""
        c = self.b @ self._powers(float(p) - self.center, self.b.shape[2]).T   # (6, 5, 3)
        return c[:, :, 0], c[:, :, 1], c[:, :, 2]

    def evaluate(self, p: float, tau: float) -> GaitSample:
        c = self.b @ self._powers(float(p) - self.center, self.b.shape[2]).T   # (6, 5, 3): a, da/dp, d2a/dp2
        tp = self._powers(float(tau), 5)                          # (3, 5): tau^j and derivatives
        m = np.einsum("ijk,lj->ikl", c, tp)                       # (6, 3 [p-deriv], 3 [tau-deriv])
        return GaitSample(q=m[:, 0, 0], dq_dp=m[:, 1, 0], dq_dtau=m[:, 0, 1], d2q_dp2=m[:, 2, 0],
                          d2q_dtau2=m[:, 0, 2], d2q_dp_dtau=m[:, 1, 1])

    def reference(self, p: float, p_dot: float, tau: float, tau_dot: float,
                  p_ddot: float = 0.0, tau_ddot: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q_d, q_d', q_d'') of eq. (11) at (p, tau)."""
        return eq11(self.evaluate(p, tau), p_dot, tau_dot, p_ddot, tau_ddot)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Start of the preferred step, where every run starts: (q_d(p_d, 0), dq_d/dtau(p_d, 0)) [rad,
        rad/s] with tau' = 1, the LEFT foot in stance (the simulator's initial state and the controller's
        initial reference)."""
        g = self.evaluate(self.p_d, 0.0)
        return g.q.copy(), g.dq_dtau.copy()

    # ------------------------------------------------------------------ I/O
    @property
    def paper_b(self) -> np.ndarray:
        """b_ijk of eq. (13): the same polynomials expanded in powers of p."""
        return expand_in_p(self.b, self.center)

    def to_dict(self) -> dict:
        return {"b": self.paper_b.tolist(), "b_centered": self.b.tolist(), "center": self.center,
                "T": self.T, "p_d": self.p_d, "p_min": self.p_min, "p_max": self.p_max}

    @classmethod
    def load(cls, path: str | Path | None = None) -> "GaitFamily":
        p = Path(path) if path is not None else default_config_dir() / "gait_family.json"
        if not p.is_file():
            raise GaitFamilyError(f"gait family: file not found: {p} (run scripts/generate_gait_family)")
        try:
            with open(p, encoding="utf-8") as fh:
                data = json.load(fh)
            fam = data["family"]
            if "b_centered" in fam:
                return cls(np.array(fam["b_centered"]), fam["T"], fam["p_d"], fam["p_min"], fam["p_max"], meta=data,
                           center=fam["center"])
            return cls(np.array(fam["b"]), fam["T"], fam["p_d"], fam["p_min"], fam["p_max"], meta=data)
        except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
            raise GaitFamilyError(f"gait family: malformed file {p}: {exc}") from exc


def expand_in_p(b_centered: np.ndarray, center: float) -> np.ndarray:
    """Coefficients in powers of (p - center) -> coefficients in powers of p (binomial expansion)."""
    K = b_centered.shape[2]
    out = np.zeros_like(b_centered)
    for k in range(K):
        for m in range(k + 1):
            out[:, :, m] += b_centered[:, :, k] * math.comb(k, m) * (-center) ** (k - m)
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
