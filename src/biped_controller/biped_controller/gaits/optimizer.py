"""Energy-optimal cyclic walking step for a given stride (paper section 3.2, criterion of its ref. [1]).

Pure Python (NumPy, SciPy, Pinocchio), no ROS.

Parametrisation (eq. 12): q_i(t) = sum_j a_ij t^j, j = 0..4, t in [0, T]. The optimiser works on the
normalised coefficients c_ij = a_ij T^j (s = t / T in [0, 1]) for conditioning.

Minimised criterion (Chevallereau & Aoustin 2001):   C(p) = (1 / p) * integral_0^T  Gamma(t)^T Gamma(t) dt
[N^2 m^2 s / m], Gamma from inverse dynamics of the single-support model along q(t) (Simpson's rule on
the optimisation grid).

Constraints (all stated in robots/biped7/gait.yaml with their reasons):
  * cyclic: q(0) = relabel(q(T)) and q'(0) = relabel(impact(q(T), q'(T))) (the impact is the inelastic
    flat-foot impact of the floating-base model, biped_model.floating);
  * the swing foot lands flat at horizontal distance p: swing ankle (x, z, angle)(T) = (p, 0, 0);
  * on the grid: the 17 constraints of eq. (10) with margins (R_y >= r M g, |R_x| <= f mu R_y,
    l in [l_m + d, l_M - d], |Gamma_i| <= u Gamma_iM); heel and toe of the swing foot above a
    clearance profile h (4 s (1 - s))^2; knee flexion within its joint limits (no hyperextension);
  * at impact: swing ankle speed <= v_max and descending; impulse on the new foot compressive and inside
    the friction cone; the former stance foot leaves the ground (vertical velocity >= 0).

Gradients: exact for everything evaluated on the grid (Pinocchio's RNEA derivatives and frame
Jacobians, chained through the polynomial basis); central finite differences (step 1e-7) of the impact
map w.r.t. the 12 numbers (q(T), q'(T)) for the end-of-step conditions.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from scipy.optimize import minimize

from biped_model.description import LEFT, RobotDescription, load_description
from biped_model.settings import SettingsError, default_robot_dir, load_yaml_tree, read_settings
from biped_model.floating import FloatingModel, impact_paper

from biped_model.fixed_foot import FixedFootModel, contact_rows, relabel

NJ = 6


class GaitConfigError(ValueError):
    """robots/biped7/gait.yaml is missing a value or has an inconsistent one."""


@dataclass(frozen=True)
class GaitSettings:
    T: float
    p_d: float
    strides: tuple[float, ...]
    time_degree: int
    representation: str
    stride_degree: int
    smoothing_breakpoints: tuple[float, ...]
    smoothing_weights: tuple[float, ...]
    fit_tolerance_q: float
    fit_tolerance_qdot: float
    grid_intervals: int
    min_normal_force: float
    friction_use: float
    zmp_margin: float
    torque_use: float
    clearance: float
    touchdown_speed: float
    touchdown_descent: float
    min_impulse_normal: float
    knee_min_flexion: float
    liftoff_speed: float
    max_iterations: int
    tolerance: float
    raw: dict = field(default_factory=dict, compare=False)


def load_gait_settings(path: str | Path | None = None) -> GaitSettings:
    p = Path(path) if path is not None else default_robot_dir() / "gait.yaml"
    keys = ("step_duration", "preferred_stride", "strides", "time_degree", "family_representation", "stride_degree",
            "smoothing_breakpoints", "smoothing_weights", "fit_tolerance_q", "fit_tolerance_qdot", "grid_intervals",
            "min_normal_force", "friction_use", "zmp_margin", "torque_use", "clearance", "touchdown_speed",
            "touchdown_descent", "min_impulse_normal", "knee_min_flexion", "liftoff_speed", "max_iterations",
            "tolerance")
    try:
        values = read_settings(p, keys)
        tree = load_yaml_tree(p)
    except SettingsError as exc:
        raise GaitConfigError(str(exc)) from exc

    def val(k: str) -> Any:
        return values[k]

    s = GaitSettings(
        T=float(val("step_duration")), p_d=float(val("preferred_stride")),
        strides=tuple(float(x) for x in val("strides")), time_degree=int(val("time_degree")),
        representation=str(val("family_representation")), stride_degree=int(val("stride_degree")),
        smoothing_breakpoints=tuple(float(x) for x in val("smoothing_breakpoints")),
        smoothing_weights=tuple(float(x) for x in val("smoothing_weights")),
        fit_tolerance_q=float(val("fit_tolerance_q")), fit_tolerance_qdot=float(val("fit_tolerance_qdot")),
        grid_intervals=int(val("grid_intervals")),
        min_normal_force=float(val("min_normal_force")), friction_use=float(val("friction_use")),
        zmp_margin=float(val("zmp_margin")), torque_use=float(val("torque_use")),
        clearance=float(val("clearance")), touchdown_speed=float(val("touchdown_speed")),
        touchdown_descent=float(val("touchdown_descent")), min_impulse_normal=float(val("min_impulse_normal")),
        knee_min_flexion=float(val("knee_min_flexion")), liftoff_speed=float(val("liftoff_speed")),
        max_iterations=int(val("max_iterations")), tolerance=float(val("tolerance")), raw=tree,
    )
    if s.time_degree != 4:
        raise GaitConfigError(f"{p}: time_degree must be 4 (paper eq. 12)")
    if s.grid_intervals % 2:
        raise GaitConfigError(f"{p}: grid_intervals must be even (Simpson's rule)")
    if s.p_d not in s.strides:
        raise GaitConfigError(f"{p}: strides must contain preferred_stride")
    if list(s.strides) != sorted(set(s.strides)):
        raise GaitConfigError(f"{p}: strides must be strictly increasing")
    if s.representation not in ("cubic_spline_in_p", "polynomial_in_p"):
        raise GaitConfigError(f"{p}: family_representation must be cubic_spline_in_p or "
                              f"polynomial_in_p, got {s.representation!r}")
    if s.representation == "cubic_spline_in_p":
        bp = s.smoothing_breakpoints
        if list(bp) != sorted(set(bp)) or len(bp) < 4:
            raise GaitConfigError(f"{p}: smoothing_breakpoints must be at least 4 increasing values")
        if s.p_d not in bp:
            raise GaitConfigError(f"{p}: smoothing_breakpoints must contain preferred_stride (exact at p_d)")
        if bp[0] != s.strides[0] or bp[-1] != s.strides[-1]:
            raise GaitConfigError(f"{p}: smoothing_breakpoints must start and end at the first and last stride")
        if len(s.strides) < 4:
            raise GaitConfigError(f"{p}: the spline family needs at least 4 strides")
    if not s.smoothing_weights or any(w <= 0 for w in s.smoothing_weights):
        raise GaitConfigError(f"{p}: smoothing_weights must be positive")
    return s


def basis(s: np.ndarray, T: float, degree: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows phi_j(s) = s^j and their first and second time derivatives (d/dt = (1/T) d/ds)."""
    s = np.atleast_1d(np.asarray(s, dtype=float))
    j = np.arange(degree + 1)
    phi = s[:, None] ** j
    dphi = np.where(j >= 1, j * s[:, None] ** np.maximum(j - 1, 0), 0.0) / T
    ddphi = np.where(j >= 2, j * (j - 1) * s[:, None] ** np.maximum(j - 2, 0), 0.0) / T**2
    return phi, dphi, ddphi


def simpson_weights(n_intervals: int, T: float) -> np.ndarray:
    w = np.ones(n_intervals + 1)
    w[1:-1:2] = 4.0
    w[2:-1:2] = 2.0
    return w * (T / n_intervals) / 3.0


@dataclass
class StepSolution:
    """One optimised step: normalised coefficients c (6, 5) and diagnostics."""

    stride: float
    T: float
    c: np.ndarray
    criterion: float
    success: bool
    message: str
    iterations: int
    seconds: float
    periodicity_residual: float = math.nan
    min_margin: float = math.nan
    min_margin_name: str = ""
    min_clearance: float = math.nan
    impact_energy_loss: float = math.nan
    impact_energy_fraction: float = math.nan
    touchdown_speed: float = math.nan

    @property
    def a(self) -> np.ndarray:
        """Paper coefficients a_ij of eq. (12) (t in seconds)."""
        return self.c / self.T ** np.arange(5)[None, :]


class StepOptimizer:
    """Builds and solves the NLP of one cyclic step. Owns its models (own Pinocchio Data)."""

    def __init__(self, desc: RobotDescription | None = None, settings: GaitSettings | None = None):
        self.desc = desc if desc is not None else load_description()
        self.st = settings if settings is not None else load_gait_settings()
        self.fixed = FixedFootModel(self.desc)
        self.floating = FloatingModel(self.desc)
        self.model = self.fixed.model
        self.data = self.model.createData()
        self.M = self.fixed.mass
        self.g = self.desc.gravity
        tmax = self.fixed.torque_max
        st = self.st
        Mg = self.M * self.g
        # Margin rows, linear in tau9 = [R_x, R_y, m_a, Gamma_1..6]: g = (C tau9 + d) / scale >= 0
        C = np.zeros((17, 9))
        d = np.zeros(17)
        mu = st.friction_use * self.desc.mu
        lm = self.desc.foot.l_min + st.zmp_margin
        lM = self.desc.foot.l_max - st.zmp_margin
        # the five contact rows of eqs. (5)-(8) as written once in model.contact_rows (C R + e Gamma_1 < 0),
        # as margins -(C R + e Gamma_1) >= 0, here in the order take_off, slide_forward, slide_backward,
        # zmp_heel, zmp_toe; R_y >= min_normal_force M g instead of R_y > 0
        Cc, ec = contact_rows(mu, lm, lM)
        order = [0, 2, 1, 3, 4]
        C[:5, :2] = 0.0 - Cc[order]        # 0.0 - x: no negative zeros (the same bits as the rows written out)
        C[:5, 3] = 0.0 - ec[order]
        d[0] = -st.min_normal_force * Mg
        for i in range(6):
            C[5 + i, 3 + i] = -1.0; d[5 + i] = st.torque_use * tmax[i]
            C[11 + i, 3 + i] = 1.0; d[11 + i] = st.torque_use * tmax[i]
        scale = np.concatenate([[Mg] * 3, [0.1 * Mg] * 2, tmax, tmax])
        self.C = C / scale[:, None]
        self.d = d / scale
        self.n = st.grid_intervals
        self.s = np.linspace(0.0, 1.0, self.n + 1)
        self.phi, self.dphi, self.ddphi = basis(self.s, st.T)
        self.w = simpson_weights(self.n, st.T)
        self.obj_scale = 1e-4
        self._cache_key: bytes | None = None
        self._cache: dict[str, np.ndarray] = {}
        self.p = st.p_d
        # optional smoothing term rho |z - z_target|^2 (normalised coefficients), see gait_generation
        self.penalty_target: np.ndarray | None = None
        self.penalty_weight = 0.0

    # -------------------------------------------------------------- evaluation
    def _endpoint(self, qT: np.ndarray, qdT: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q'(0+) demanded by the impact (6,), end-of-step inequality values (>= 0), scaled)."""
        st = self.st
        qd_new, res = impact_paper(self.floating, qT, qdT, LEFT)
        _, vel = self.fixed.swing_foot(qT, qdT)
        vx, vz = vel[0], vel[1]
        lam_x, lam_z = res.impulse[0], res.impulse[1]
        mu = st.friction_use * self.desc.mu
        ineq = np.array([
            (st.touchdown_speed**2 - vx**2 - vz**2),
            (-vz - st.touchdown_descent),
            (lam_z - st.min_impulse_normal) / 10.0,
            (mu * lam_z - lam_x) / 10.0,
            (mu * lam_z + lam_x) / 10.0,
            (res.old_foot_velocity[1] - st.liftoff_speed),
        ])
        return qd_new, ineq

    def _objective_terms(self, obj: float, gobj: np.ndarray, z: np.ndarray) -> tuple[float, np.ndarray, float]:
        """Scale the raw effort integral to the criterion per metre (obj_scale / p) and add the penalty.

        Returns (objective, its gradient, criterion): the criterion is the scaled effort alone, the objective
        adds ``penalty_weight * |z - penalty_target|^2`` when a penalty target is set.
        """
        obj *= self.obj_scale / self.p
        gobj *= self.obj_scale / self.p
        crit = obj
        if self.penalty_target is not None and self.penalty_weight > 0:
            dz = z - self.penalty_target
            obj = obj + self.penalty_weight * float(dz @ dz)
            gobj = gobj + 2.0 * self.penalty_weight * dz
        return obj, gobj, crit

    def _knee_rows(self, q: np.ndarray) -> np.ndarray:
        """Knee limits as rows >= 0 (linear in q): stance flexion is q2, swing flexion is -q5 (rad)."""
        kmin = max(self.st.knee_min_flexion, self.desc.knee_min_flexion)
        kmax = self.desc.knee_max_flexion
        return np.concatenate([q[:, 1] - kmin, kmax - q[:, 1], -q[:, 4] - kmin, kmax + q[:, 4]])

    def _knee_jacobian(self, n: int) -> np.ndarray:
        """d(knee rows)/dz, (4 (n+1), 30): constant, the basis values at the n+1 instants."""
        knee_jac = np.zeros((4 * (n + 1), 30))
        knee_jac[0:n + 1, 5:10] = self.phi
        knee_jac[n + 1:2 * (n + 1), 5:10] = -self.phi
        knee_jac[2 * (n + 1):3 * (n + 1), 20:25] = -self.phi
        knee_jac[3 * (n + 1):, 20:25] = self.phi
        return knee_jac

    def evaluate(self, z: np.ndarray) -> dict[str, np.ndarray]:
        key = z.tobytes()
        if key == self._cache_key:
            return self._cache
        c = z.reshape(NJ, 5)
        st = self.st
        q = self.phi @ c.T
        qd = self.dphi @ c.T
        qdd = self.ddphi @ c.T
        n = self.n
        obj = 0.0
        gobj = np.zeros(30)
        g_rows, g_jac = [], []
        clear_rows, clear_jac = [], []
        q9 = np.zeros(9); v9 = np.zeros(9); a9 = np.zeros(9)
        ft = self.desc.foot
        for k in range(n + 1):
            q9[3:] = q[k]; v9[3:] = qd[k]; a9[3:] = qdd[k]
            tau = pin.rnea(self.model, self.data, q9, v9, a9).copy()
            Dq, Dv, Ma = pin.computeRNEADerivatives(self.model, self.data, q9, v9, a9)
            Ma = np.triu(Ma) + np.triu(Ma, 1).T
            dtau = (Dq[:, 3:, None] * self.phi[k][None, None, :]
                    + Dv[:, 3:, None] * self.dphi[k][None, None, :]
                    + Ma[:, 3:, None] * self.ddphi[k][None, None, :]).reshape(9, 30)
            gam = tau[3:]
            obj += self.w[k] * float(gam @ gam)
            gobj += self.w[k] * 2.0 * (gam @ dtau[3:])
            g_rows.append(self.C @ tau + self.d)
            g_jac.append(self.C @ dtau)
            if 0 < k < n:
                pin.forwardKinematics(self.model, self.data, q9)
                pin.computeJointJacobians(self.model, self.data, q9)
                pin.updateFramePlacements(self.model, self.data)
                fid = self.fixed.swing_frame
                tz = self.data.oMf[fid].translation[2]
                J = pin.getFrameJacobian(self.model, self.data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
                ang = float(np.sum(q[k]))
                h = st.clearance * (4.0 * self.s[k] * (1.0 - self.s[k])) ** 2
                for l in (ft.l_min, ft.l_max):
                    val = tz + l * math.sin(ang) - h
                    row = J[2, 3:] + l * math.cos(ang) * np.ones(6)
                    clear_rows.append(val / 0.01)
                    clear_jac.append((row[:, None] * self.phi[k][None, :]).ravel() / 0.01)
        obj, gobj, crit = self._objective_terms(obj, gobj, z)
        knee_rows = self._knee_rows(q)
        knee_jac = self._knee_jacobian(n)
        # end of step
        qT, qdT = q[-1], qd[-1]
        qd0_req, end_ineq = self._endpoint(qT, qdT)
        eps = 1e-7
        J_req = np.zeros((6, 12)); J_end = np.zeros((end_ineq.size, 12))
        for m in range(12):
            dq = np.zeros(12); dq[m] = eps
            a1, b1 = self._endpoint(qT + dq[:6], qdT + dq[6:])
            a0, b0 = self._endpoint(qT - dq[:6], qdT - dq[6:])
            J_req[:, m] = (a1 - a0) / (2 * eps)
            J_end[:, m] = (b1 - b0) / (2 * eps)
        # d(qT)/dz and d(qdT)/dz
        dqT = np.zeros((6, 30)); dqdT = np.zeros((6, 30))
        for i in range(6):
            dqT[i, i * 5:(i + 1) * 5] = self.phi[-1]
            dqdT[i, i * 5:(i + 1) * 5] = self.dphi[-1]
        dq0 = np.zeros((6, 30)); dqd0 = np.zeros((6, 30))
        for i in range(6):
            dq0[i, i * 5:(i + 1) * 5] = self.phi[0]
            dqd0[i, i * 5:(i + 1) * 5] = self.dphi[0]
        D_end = np.hstack([dqT.T, dqdT.T]).T  # (12, 30)
        pose, _ = self.fixed.swing_foot(qT)
        Jsw = self.fixed.swing_foot_jacobian(qT)
        R = -np.eye(6)[::-1]  # relabel as a matrix
        eq = np.concatenate([
            pose - np.array([self.p, 0.0, 0.0]),
            q[0] - R @ qT,
            (qd[0] - qd0_req) * st.T,
        ])
        eq_jac = np.vstack([
            Jsw @ dqT,
            dq0 - R @ dqT,
            (dqd0 - J_req @ D_end) * st.T,
        ])
        ineq = np.concatenate([np.concatenate(g_rows), np.array(clear_rows), knee_rows, end_ineq])
        ineq_jac = np.vstack([np.vstack(g_jac), np.array(clear_jac), knee_jac, J_end @ D_end])
        self._cache_key = key
        self._cache = dict(obj=obj, crit=crit, gobj=gobj, eq=eq, eq_jac=eq_jac, ineq=ineq, ineq_jac=ineq_jac)
        return self._cache

    # -------------------------------------------------------------- solving
    def initial_guess(self, p: float) -> np.ndarray:
        """Stated initial guess: double-support postures at both ends (hip at the gait settings'
        ``initial_hip_height`` [m] above the ground, 0.74 m when they do not give it, midway between the
        feet, torso upright, knees bent forwards), joined linearly, plus a swing-knee flexion bump of
        0.6 sin(pi s) rad; projected on degree-4 polynomials by least squares."""
        hip = self.st.raw.get("initial_hip_height", {}).get("value", 0.74) if isinstance(self.st.raw, dict) else 0.74
        qT = double_support_posture(self.desc, p, hip_height=float(hip))
        q0 = relabel(qT)
        s = np.linspace(0, 1, 50)
        traj = q0[None, :] + (qT - q0)[None, :] * s[:, None]
        traj[:, 4] -= 0.6 * np.sin(np.pi * s)
        traj[:, 3] += 0.15 * np.sin(np.pi * s)
        phi, _, _ = basis(s, self.st.T)
        c, *_ = np.linalg.lstsq(phi, traj, rcond=None)
        return c.T.copy()

    def solve(self, p: float, c0: np.ndarray | None = None, maxiter: int | None = None,
              target: np.ndarray | None = None, weight: float = 0.0, diagnose: bool = True) -> StepSolution:
        """Optimal step for stride p. With ``target``/``weight``, minimise C(p)/C_scale + weight *
        |c - target|^2 instead (a smoothing term used to make the family smooth in p); the reported
        criterion is always C alone. ``diagnose=False`` leaves the diagnostics of :meth:`diagnose` NaN
        (they depend on the solution alone and can be filled later, for the solutions kept)."""
        self.p = float(p)
        self.penalty_target = None if target is None else np.asarray(target, dtype=float).ravel().copy()
        self.penalty_weight = float(weight)
        self._cache_key = None
        z0 = (self.initial_guess(p) if c0 is None else np.asarray(c0, dtype=float)).ravel().copy()
        t0 = time.perf_counter()
        res = minimize(
            lambda z: (self.evaluate(z)["obj"], self.evaluate(z)["gobj"]),
            z0, jac=True, method="SLSQP",
            constraints=[
                {"type": "eq", "fun": lambda z: self.evaluate(z)["eq"], "jac": lambda z: self.evaluate(z)["eq_jac"]},
                {"type": "ineq", "fun": lambda z: self.evaluate(z)["ineq"], "jac": lambda z: self.evaluate(z)["ineq_jac"]},
            ],
            options={"maxiter": maxiter or self.st.max_iterations, "ftol": self.st.tolerance},
        )
        c = res.x.reshape(NJ, 5)
        ev = self.evaluate(res.x)
        ok = bool(res.success) and float(np.max(np.abs(ev["eq"]))) < 1e-7 and float(np.min(ev["ineq"])) > -1e-7
        sol = StepSolution(
            stride=self.p, T=self.st.T, c=c, criterion=float(ev["crit"] / self.obj_scale), success=ok,
            message=str(res.message), iterations=int(res.nit), seconds=time.perf_counter() - t0,
        )
        self.penalty_target = None
        self.penalty_weight = 0.0
        self._cache_key = None
        if diagnose:
            self.diagnose(sol)
        return sol

    def diagnose(self, sol: StepSolution, refine: int = 10) -> None:
        """Fill periodicity residual, the smallest true-constraint margin (17 rows, no design margins) and
        clearance on a grid ``refine`` times finer, impact energy loss and touchdown speed."""
        T = sol.T
        c = sol.c
        n = self.n * refine
        s = np.linspace(0, 1, n + 1)
        phi, dphi, ddphi = basis(s, T)
        q, qd, qdd = phi @ c.T, dphi @ c.T, ddphi @ c.T
        fm = self.fixed
        worst, worst_name = math.inf, ""
        from biped_model.fixed_foot import CONSTRAINT_NAMES
        clear = math.inf
        ft = self.desc.foot
        for k in range(n + 1):
            m = fm.margins_direct(q[k], qd[k], qdd[k]) / fm.row_scale
            i = int(np.argmin(m))
            if m[i] < worst:
                worst, worst_name = float(m[i]), CONSTRAINT_NAMES[i]
            if 0 < k < n:
                pose, _ = fm.swing_foot(q[k])
                for l in (ft.l_min, ft.l_max):
                    clear = min(clear, pose[1] + l * math.sin(pose[2]))
        qd_new, res = impact_paper(self.floating, q[-1], qd[-1], LEFT)
        per = max(float(np.max(np.abs(q[0] - relabel(q[-1])))), float(np.max(np.abs(qd[0] - qd_new))))
        _, vel = fm.swing_foot(q[-1], qd[-1])
        ke = fm.kinetic_energy(q[-1], qd[-1])
        sol.periodicity_residual = per
        sol.min_margin = worst
        sol.min_margin_name = worst_name
        sol.min_clearance = clear
        sol.impact_energy_loss = res.energy_loss
        sol.impact_energy_fraction = res.energy_loss / ke if ke > 0 else math.nan
        sol.touchdown_speed = float(np.hypot(vel[0], vel[1]))


def double_support_posture(desc: RobotDescription, p: float, hip_height: float, torso: float = 0.0) -> np.ndarray:
    """Paper q with both feet flat, the swing ankle at (p, 0), the hip at (p/2, hip_height), knees bent
    forwards, torso at absolute angle ``torso`` (ccw)."""
    Ls, Lt = desc.shin.length, desc.thigh.length

    def two_link(dx: float, dz: float, a: float, b: float) -> tuple[float, float]:
        d = math.hypot(dx, dz)
        d = min(d, (a + b) * 0.999999)
        cos_k = (a * a + b * b - d * d) / (2 * a * b)
        knee = math.pi - math.acos(max(-1.0, min(1.0, cos_k)))
        return d, knee

    hx, hz = p / 2.0, hip_height
    # stance leg: ankle (0,0) -> hip; link "up" at abs angle phi points to (-sin phi, cos phi)
    _, k1 = two_link(hx, hz, Ls, Lt)
    phi_u = math.atan2(-hx, hz)
    d = math.hypot(hx, hz)
    alpha = math.acos(min(1.0, (Ls * Ls + d * d - Lt * Lt) / (2 * Ls * d)))
    phi1 = phi_u - alpha
    phi2 = phi1 + k1
    q1, q2 = phi1, k1
    q3 = torso - phi2
    # swing leg: hip -> ankle (p, 0); link "down" at abs angle phi points to (sin phi, -cos phi)
    dx, dz = p - hx, -hz
    _, k2 = two_link(dx, dz, Lt, Ls)
    phi_d = math.atan2(dx, -dz)
    d2 = math.hypot(dx, dz)
    beta = math.acos(min(1.0, (Lt * Lt + d2 * d2 - Ls * Ls) / (2 * Lt * d2)))
    phi4 = phi_d + beta
    phi5 = phi4 - k2
    q4 = phi4 - torso
    q5 = -k2
    q6 = -phi5
    return np.array([q1, q2, q3, q4, q5, q6])
