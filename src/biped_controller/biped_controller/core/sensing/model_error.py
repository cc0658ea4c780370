"""The legs' model error, identified from the momentum observer's swing-leg rows. NumPy +
Pinocchio + Numba kernels (``model_error_kernels``), no ROS.

Why. The momentum observer (``momentum_observer``) estimates tau_d, everything the model does not contain,
in the six joint rows, and reads it as a wrench W on the torso, whose translational part goes to the
ground: dR = S W. That is right for a push on the torso and for a torso mass error (a force at the torso's
centre of mass), and a torso inertia error is its moment M_y. It is wrong for the legs' inertia (and mass)
errors: in the fixed-foot model the inertial parameters of a link enter the translational root rows only
through its mass (sum of m_b a_b), so a leg inertia error moves the ground force only through the joint
accelerations it changes, B A^-1 tau_d, and not by a force at the torso. Measured on the rigid plant with
the inertias 30 % larger (docs/robustness.md, "Model error"): the torso-wrench reading predicts R_y within
0-2 N of the model where the plant is 11-19 N below it, and after the touchdown that follows a 200 N push it
predicts +5 N where the plant is -17 N: over the toe. From the joint rows alone the two readings cannot be
told apart (any six joint torques are also moments on the six links above the stance foot); what tells them
apart is where they act. A force on the torso does not reach the swing leg's joints (the swing hip, knee and
ankle carry only the swing leg's own dynamics), a leg's model error does, and it is persistent while a
push is not.

The model. The description's legs are symmetric (one ``thigh``, ``shin``, ``foot`` entry), so the legs' error
is six parameters theta = (dm_thigh, dI_thigh, dm_shin, dI_shin, dm_foot, dI_foot) [kg, kg m^2] (plant minus
model; centres of mass and the torso not included), the same in both stances. The dynamics are linear in
them (centre of mass fixed, inertia about it): the error's generalized force on the locked-root chain,
    e(q, q', q'') = M_p [0; q''] + h_p - (M_m [0; q''] + h_m) = Y(q, q', q'') theta   (9 rows: root x, z,
    pitch, then the six joints),
with column j of Y = RNEA of the model with parameter j raised by one unit minus RNEA of the model (exact:
RNEA is linear in the inertial parameters), computed as Pinocchio's joint torque regressor (9 x 10 per joint
body) times the parameter's change of the bodies' dynamic parameters (``parameter_bumps``, ``LegRegressor``;
the RNEA differences are kept as ``RneaLegRegressor``, the tests' oracle), or in closed form on the planar
tree (``model_error_kernels.regressor_into``: each column the generalized force of a unit mass at a link's
centre of mass or of a unit inertia, summed over both legs' bodies by ``body_combination``;
``CompiledLegRegressor``), which the compiled pipeline runs with the whole sample below inside its kernel
(``model_error_kernels.update``, called by ``pipeline_kernels.sense_finish``; this class stays the
Python pipeline's estimator and the oracle). The observer's r is tau_d = -e_j
through its first-order filter (r' = K (tau_d - r)), so its swing-leg rows obey r_s = -(Y_f theta)_s, Y_f the
joint rows of Y through the same filter (discrete: Y_f <- e^{-K dt} Y_f + (1 - e^{-K dt}) (Y_{k-1} + Y_k) / 2,
restarted at 0 with the observer, whose restart leaves the swing rows at 0). theta is estimated by recursive
least squares (a Kalman filter on a constant) on the swing rows: prior theta ~ N(0, diag((s_m m)^2, (s_I I)^2)) from the
stated uncertainty of the masses and inertias, measurement noise s_res^2 I + K^2 (A Sigma_qd A)_s (the
observer's rate noise, as ``momentum_observer``); no update in the period of a restart.

What the QP gets. With the legs' error predicted, the torso wrench is read from what remains,
r_t = r + Y_f theta (and, after a restart, the observer's carried wrench replaced by the carried torso
wrench: - J_j^T (W_obs,restart - W_t,restart) e^{-K t}), W_t = J_j^{T+} r_t, and the predicted ground force
moves by
    dR = S W_t + G theta,   G = (-B A^-1 Y_j + Y_r)[:2]
(the legs' error changes the joint accelerations by -A^-1 Y_j theta and the root rows by Y_r theta). Y is
evaluated at the sample's (q, q') and the model's acceleration under the torque applied over the last
interval and the observer's r, a = A^-1 (Gamma - H + r) (at a restart: the last torque relabelled, r = 0).
Its covariance: Sigma_dR = S Sigma_W S^T + G_t P G_t^T, G_t = G + S J_j^{T+} Y_f (W_t depends on theta too),
Sigma_W the observer's noise covariance with the carried-wrench term taken for W_t,restart.

What the regressor is fed (``model_error_regressor``, ``REGRESSOR_INPUTS``). "measured" (above): Y at the
sample's (q, q') and a = A^-1 (Gamma - H + r). Under sensor noise this is an errors-in-variables regression
with correlated errors: the observer's r contains the sample's rate error, dr = K A dq' (high-passed), and the
same dq' enters the regressor through a (da = A^-1 dr, into the inertial columns: dY_j = dM_j da, dM_j the
inertia matrix's change per unit of parameter j) and quadratically through the Coriolis terms, so least
squares on r_s = H theta + v, H = -(Y_f)_s, tends to theta + E[H^T H]^-1 E[H^T v] with E[H^T v] != 0 even
for theta = 0. "reference": Y is evaluated on the controller's reference at the sample's instant,
Y_ref = Y(q_d, q_d', q_d''), (q_d, q_d', q_d'') = eq. (11) at the parameters of the last decision advanced
to the sample's instant with the held (p'', tau'') (``AdaptiveController.reference_at``), and Y_ref replaces
Y everywhere above (Y_f, the RLS row, G). The parameters evolve as p'' = -k_v p' + k_p (p_d - p),
tau'' = k_v (1 - tau') whenever x* is feasible (no measurement enters) and through the QP's rows otherwise,
so Y_ref is uncorrelated with the sample's noise (an instrumental variable, Soderstrom and Stoica,
"Instrumental variable methods for system identification", used as the regressor itself): E[H_ref^T v] = 0.
Under a true error the data obey r_s = H_ref theta + (H - H_ref) theta + v, a relative bias of the order of
the tracking error (about 2e-3 rad undisturbed), and none at theta = 0; P stays the symmetric RLS
covariance the QP's widening needs. Measured (rigid, nominal plant, 5e-4 rad, 5e-2 rad/s, 14 bits, K = 50,
seeds 0 and 1, 4 s, with the settling time below): the two estimates differ by at most 0.15 prior std
(0.07 after 3.2 s); the errors-in-variables bias is small at these noise levels (the drift first blamed on
it was the start transient below), so "measured" (exact for a true error) is the default.

When the update happens (``model_error_settle`` = n, in observer time constants). After the observer's
(re)start (the first sample, every touchdown) its r carries the start transient: with p = A q' measured,
r(t) - (filtered tau_d) = K (dp(t) - lowpass(dp)(t)) - K e^{-K t} dp(0), and dp(0) = A dq'(0) is the rate
error of the restart sample, larger than later (the estimator starts from the raw rate, 5e-2 rad/s, and a
touchdown widens its rates by ``estimator_impact_std``). That term is one random vector decaying over 1/K,
a coherent error across ~1/(K dt) samples that the white residual model (s_res^2 + K^2 (A Sigma_qd A)_s per
sample) overweighs by that factor; adding its marginal variance K^2 e^{-2 K t} (A Sigma_0 A)_s to the
residual was measured not to be enough (thigh mass 5.7 posterior std off 0 at 0.1 s, seed 0). So no update
while since < n / K (e^{-n} of the term left): the sample then carries no information, which the kernel
is given as a residual variance of ``HOLD_VARIANCE`` (the gain, ~1e-200 P H^T, so the combination in the
same call uses theta and P to round-off), and theta and P are put back afterwards, bit for bit. Measured (same
runs): without it the thigh mass is 8.4 (seed 0) and 2.9 (seed 1) posterior std off 0 at 0.1 s, dR_y
averages 24 and 29 N over 0.1-0.2 and 0.2-0.3 s before any push (seed 0), and the foot's inertia drifts
to 1.0-1.3 prior std within 3.2 s (7 touchdowns); with n = 3 theta stays within 1.1 posterior std
(Mahalanobis distance at 4 s: 2.1 and 0.6 for 6 degrees of freedom) and dR_y averages 3-4 N.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from biped_model import numba_cache
from biped_model.description import RobotDescription
from biped_model.fast_engine import fixed_foot_tree
from biped_model.fixed_foot import FixedFootModel, relabel
from biped_model.finite import finite_number

from biped_controller.core.sensing.momentum_observer import Wrench

#: the identified parameters, in the order of theta: (link of the description, field)
LEG_PARAMETERS: tuple[tuple[str, str], ...] = (("thigh", "mass"), ("thigh", "inertia"), ("shin", "mass"),
                                               ("shin", "inertia"), ("foot", "mass"), ("foot", "inertia"))
SWING = slice(3, 6)     # the swing leg's rows among the six joint rows (paper order q4..q6)
#: [N^2 m^2] the swing rows' variance during the settling time after a restart (module docstring): the RLS
#: gain is then about 1e-200 P H^T (theta and P are then restored exactly)
HOLD_VARIANCE = 1e200
#: what the regressor is evaluated on (module docstring, "What the regressor is fed")
REGRESSOR_INPUTS = ("measured", "reference")
MODEL_ERROR_KERNELS = "biped_controller.core.sensing.model_error_kernels"
MODEL_ERROR_KERNELS_SOURCES = ("biped_model.planar_abi", "biped_model.planar_kernels")


def load_model_error_kernels(warm: bool = False):
    """``model_error_kernels`` through ``numba_cache.load`` (its cache in build/numba-cache, kept with the
    planar kernels it calls); ``warm``: call ``combine_kernel`` once on zeros so that it is compiled (or loaded
    from the cache) now, not at the first sample (``leg_regressor`` has explicit types: compiled at import)."""
    mod = numba_cache.load(MODEL_ERROR_KERNELS, sources=MODEL_ERROR_KERNELS_SOURCES)
    if warm:
        z3, z6 = np.zeros((3, 3)), np.zeros((6, 6))
        mod.combine_kernel(np.zeros((9, 6)), np.eye(6), np.zeros((3, 6)), np.eye(6), np.zeros(6), np.zeros((2, 3)),
                           z3.copy(), np.zeros(3), np.hstack([np.eye(3), np.zeros((3, 3))]), z6.copy(), False, 1.0,
                           1e-3, 0.0, True, False, np.eye(3), np.zeros(6), np.eye(6), z6.copy(), z6.copy(),
                           np.zeros(3), np.zeros(3), z3.copy(), np.zeros(2), np.zeros((2, 2)))
    return mod


class ModelErrorConfigError(ValueError):
    """A setting of the model-error estimator is invalid (the message names it)."""


@dataclass(frozen=True)
class LegErrorEstimate:
    """theta (6,) [kg, kg m^2, ...] in ``LEG_PARAMETERS`` order and its covariance P (6, 6)."""

    theta: np.ndarray
    P: np.ndarray


def _bumped(desc: RobotDescription, link: str, name: str) -> RobotDescription:
    part = getattr(desc, link)
    return dataclasses.replace(desc, **{link: dataclasses.replace(part, **{name: getattr(part, name) + 1.0})})


#: which joint of ``build_fixed_foot_model`` carries which link's body (the stance foot rides on the locked
#: root pitch joint; every joint carries exactly one body, appended at the joint's origin)
LINK_JOINTS: dict[str, tuple[str, str]] = {"thigh": ("q2_stance_knee", "q4_swing_hip"),
                                           "shin": ("q1_stance_ankle", "q5_swing_knee"),
                                           "foot": ("root_pitch", "q6_swing_ankle")}
_VECH = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))   # Pinocchio's order of I in the dynamic parameters


def parameter_bumps(model: pin.Model) -> tuple[np.ndarray, np.ndarray]:
    """The combination of the joint torque regressor's columns that gives Y: (joints (k,), D (k, 10, 6)).

    Pinocchio's dynamic parameters of the body on joint i (``Inertia.toDynamicParameters``, the columns
    10 (i - 1) .. 10 i - 1 of ``computeJointTorqueRegressor``) are pi_i = [m, m c_x, m c_y, m c_z, I_xx,
    I_xy, I_yy, I_xz, I_yz, I_zz], c the centre of mass and I the rotational inertia about the joint frame's
    origin, in the joint frame: I = I_c + m (|c|^2 1 - c c^T). With c and I_c fixed, d pi / d m =
    [1, c, vech(|c|^2 1 - c c^T)] (the parallel-axis term: for a centre of mass on the link's axis z,
    c = (0, 0, c_z), it adds c_z^2 to I_xx and I_yy); the description's scalar inertia is the model's
    I_c = I 1 (``fixed_foot._inertia``), so d pi / d I = [0, 0, 0, 0, 1, 0, 1, 0, 0, 1] (only I_yy, about the
    plane's normal, reaches the planar rows). Both legs' bodies of a link (``LINK_JOINTS``) carry the
    parameter, so its column of Y is the sum over them: Y = sum_k R[:, cols(joint_k)] D_k."""
    joints, blocks = [], []
    for j, (link, name) in enumerate(LEG_PARAMETERS):
        for jname in LINK_JOINTS[link]:
            jid = model.getJointId(jname)
            if jid >= model.njoints:
                raise ValueError(f"the fixed-foot model has no joint {jname!r}")
            c = np.array(model.inertias[jid].lever)
            d = np.zeros(10)
            if name == "mass":
                S = (c @ c) * np.eye(3) - np.outer(c, c)
                d[0], d[1:4] = 1.0, c
                d[4:] = [S[r, s] for r, s in _VECH]
            else:
                d[4:] = [1.0 if r == s else 0.0 for r, s in _VECH]
            if jid not in joints:
                joints.append(jid)
                blocks.append(np.zeros((10, len(LEG_PARAMETERS))))
            blocks[joints.index(jid)][:, j] += d
    return np.array(joints), np.array(blocks)


class LegRegressor:
    """Y(q, q', q'') (9, 6) of the module docstring from Pinocchio's joint torque regressor R (9, 10 n) of the
    locked-root chain (``pin.computeJointTorqueRegressor``: tau = R pi, pi the stacked dynamic parameters,
    its own ``Data``), combined into the six leg parameters by ``parameter_bumps``: one Pinocchio pass and
    one (9, 90) x (90, 6) product a call. Rows: root x [N], z [N], pitch [N m], then q1..q6 [N m]."""

    def __init__(self, desc: RobotDescription):
        self.base = FixedFootModel(desc)
        self._model = self.base.model
        self._data = self._model.createData()
        joints, D = parameter_bumps(self._model)
        self._D = np.zeros((10 * (self._model.njoints - 1), len(LEG_PARAMETERS)))   # zero off the legs' joints
        for i, Di in zip(joints, D):
            self._D[10 * (i - 1):10 * i] = Di
        self._q = np.zeros(self._model.nq)
        self._v = np.zeros(self._model.nv)
        self._a = np.zeros(self._model.nv)

    def __call__(self, q: np.ndarray, qd: np.ndarray, a: np.ndarray) -> np.ndarray:
        self._q[3:], self._v[3:], self._a[3:] = q, qd, a
        R = pin.computeJointTorqueRegressor(self._model, self._data, self._q, self._v, self._a)
        return R @ self._D


def body_combination(bodies) -> np.ndarray:
    """D (2 nb, 6): the combination Y = F D of ``model_error_kernels.regressor_into``'s per-body columns F
    (column b: a unit mass at body b's centre of mass; column nb + b: a unit inertia of body b) into the six
    parameters of ``LEG_PARAMETERS``. ``bodies``: the fixed-foot tree's (``fast_engine.fixed_foot_tree``);
    the description's legs are alike, so a link's parameter is carried by both legs' bodies of that link,
    ``stance_<link>`` and ``swing_<link>`` (as ``LINK_JOINTS`` on Pinocchio's model): D[b, j] = 1 for a mass
    parameter, D[nb + b, j] = 1 for an inertia. Raises ``ValueError`` naming the link unless exactly those
    two bodies exist."""
    nb = len(bodies)
    names = [b.name for b in bodies]
    D = np.zeros((2 * nb, len(LEG_PARAMETERS)))
    for j, (link, name) in enumerate(LEG_PARAMETERS):
        for side in ("stance", "swing"):
            body = f"{side}_{link}"
            if names.count(body) != 1:
                raise ValueError(f"the fixed-foot tree must have one body {body!r} for the parameter {link}.{name}")
            b = names.index(body)
            D[b if name == "mass" else nb + b, j] = 1.0
    return D


class CompiledLegRegressor:
    """``LegRegressor``'s Y(q, q', q'') (9, 6) in closed form on the planar fixed-foot tree
    (``model_error_kernels.leg_regressor``, Numba; ``body_combination``): the same call, rows and units;
    no Pinocchio. What the compiled pipeline runs inside its kernel; this class is its entry for the tests
    and the benchmark."""

    def __init__(self, desc: RobotDescription):
        tree = fixed_foot_tree(desc)
        self.ti, self.tf = tree.arrays()
        self.D = body_combination(tree.bodies)
        self._kern = load_model_error_kernels()

    def __call__(self, q: np.ndarray, qd: np.ndarray, a: np.ndarray) -> np.ndarray:
        Y = np.empty((9, len(LEG_PARAMETERS)))
        self._kern.leg_regressor(self.ti, self.tf, self.D, np.ascontiguousarray(q, dtype=float),
                                 np.ascontiguousarray(qd, dtype=float), np.ascontiguousarray(a, dtype=float), Y)
        return Y


class RneaLegRegressor:
    """The reference oracle of ``LegRegressor`` (its first implementation, kept for the tests and the
    benchmark): column j = RNEA of the locked-root chain with parameter j raised by one unit minus RNEA of the
    model (exact: RNEA is linear in the inertial parameters); 7 models, 7 RNEA calls a call."""

    def __init__(self, desc: RobotDescription):
        self.base = FixedFootModel(desc)
        self.bumped = [FixedFootModel(_bumped(desc, link, name)) for link, name in LEG_PARAMETERS]

    def __call__(self, q: np.ndarray, qd: np.ndarray, a: np.ndarray) -> np.ndarray:
        tau0, root0 = self.base.inverse_dynamics(q, qd, a)
        Y = np.empty((9, len(self.bumped)))
        for j, m in enumerate(self.bumped):
            tau, root = m.inverse_dynamics(q, qd, a)
            Y[:3, j] = root - root0
            Y[3:, j] = tau - tau0
        return Y


def prior_std(desc: RobotDescription, mass_uncertainty: float, inertia_uncertainty: float) -> np.ndarray:
    """The prior standard deviations of theta: the stated relative uncertainty times the nominal value."""
    out = []
    for link, name in LEG_PARAMETERS:
        out.append((mass_uncertainty if name == "mass" else inertia_uncertainty) * getattr(getattr(desc, link), name))
    return np.array(out)


class LegModelError:
    """The estimator and the combination of the module docstring, fed once per observer sample. The algebra
    after the regressor runs in ``model_error_kernels.combine_kernel`` (Numba; ``compiled=False``: the same
    function run by NumPy, ``combine``, the tests' oracle). ``regressor_input`` (``REGRESSOR_INPUTS``) and
    ``settle`` [observer time constants 1/K] are ``model_error_regressor`` and ``model_error_settle`` of
    config/controller.yaml (module docstring, "What the regressor is fed", "When the update happens")."""

    def __init__(self, desc: RobotDescription, K: float, mass_uncertainty: float, inertia_uncertainty: float,
                 residual_std: float, compiled: bool = True, *, regressor_input: str, settle: float):
        if regressor_input not in REGRESSOR_INPUTS:
            raise ModelErrorConfigError(f"model_error_regressor must be one of {REGRESSOR_INPUTS}, "
                                        f"got {regressor_input!r}")
        self.regressor_input = regressor_input
        for name, v in (("model_mass_uncertainty", mass_uncertainty),
                        ("model_inertia_uncertainty", inertia_uncertainty), ("model_error_residual_std", residual_std)):
            finite_number(v, name, above=0, error=ModelErrorConfigError)
        self.K = finite_number(K, "momentum_observer_gain", above=0, error=ModelErrorConfigError)
        settle = finite_number(settle, "model_error_settle", at_least=0, error=ModelErrorConfigError)
        self.settle_time = settle / self.K     # [s] no update this long after the observer's (re)start
        self.reg = LegRegressor(desc)
        self.model = self.reg.base
        self.P0 = np.diag(prior_std(desc, mass_uncertainty, inertia_uncertainty) ** 2)
        self.var_res = float(residual_std) ** 2
        self._Rres = self.var_res * np.eye(3)
        self._Rhold = HOLD_VARIANCE * np.eye(3)     # a held sample: no information (docstring)
        self._zero6 = np.zeros((6, 6))
        kern = load_model_error_kernels(warm=compiled)      # compiled now, not at the first sample
        self._combine = kern.combine_kernel if compiled else kern.combine
        self.reset()

    def reset(self) -> None:
        n = len(LEG_PARAMETERS)
        self.theta = np.zeros(n)
        self.P = self.P0.copy()
        self._Yf = np.zeros((6, n))
        self._Yprev = np.zeros((6, n))     # Y_j of the last sample (valid once _has_prev)
        self._has_prev = False
        self._W_t = np.zeros(3)            # the last torso wrench (carried at a restart)
        self._W_t_restart = np.zeros(3)
        self._last_torque: np.ndarray | None = None
        self.updates = 0                   # RLS updates made (periods that informed theta)

    @property
    def estimate(self) -> LegErrorEstimate:
        return LegErrorEstimate(theta=self.theta.copy(), P=self.P.copy())

    def update(self, q: np.ndarray, qd: np.ndarray, applied: np.ndarray | None, restarted: bool, dt: float,
               obs: Wrench, W_obs_restart: np.ndarray, since: float, Jj: np.ndarray,
               cov_qd: np.ndarray | None, reference: tuple | None = None) -> Wrench:
        """One observer sample. ``q, qd`` the state the observer saw [rad, rad/s]; ``applied`` the torque over
        the interval that led here in this stance's paper order [N m] (None at a restart: the last one
        relabelled is used for the acceleration); ``restarted``: the observer restarted at this sample;
        ``dt`` [s] the interval; ``obs`` the observer's output; ``W_obs_restart`` the wrench it carried at
        its last restart and ``since`` [s] the time since; ``Jj`` (3, 6) the torso wrench Jacobian's joint
        columns; ``cov_qd`` the rate covariance (None: 0); ``reference`` (q_d, q_d', q_d'') at the sample's
        instant in this stance's paper order [rad, rad/s, rad/s^2], required when ``regressor_input`` is
        "reference" (module docstring; ignored otherwise). Returns the combined ``Wrench`` (r: the
        observer's, unchanged; W, cov_W: the torso wrench; dR, cov_dR: with the legs' error)."""
        if self.regressor_input == "reference" and reference is None:
            raise ValueError("LegModelError.update: regressor_input 'reference' needs the reference "
                             "(q_d, q_d', q_d'') at the sample")
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        dyn = self.model.dynamics(q, qd)
        K = self.K
        Ainv = np.linalg.inv(dyn.A)          # once: the acceleration and G (A symmetric positive definite)
        if restarted or applied is None:
            tq = relabel(self._last_torque) if self._last_torque is not None else np.zeros(6)
            acc = Ainv @ (tq - dyn.H)
        else:
            tq = np.asarray(applied, dtype=float)
            acc = Ainv @ (tq - dyn.H + obs.r)
            self._last_torque = tq.copy()
        if self.regressor_input == "reference":
            Y = self.reg(*(np.asarray(v, dtype=float) for v in reference))
        else:
            Y = self.reg(q, qd, acc)
        if restarted:
            self._W_t_restart = self._W_t.copy()
        hold = (not restarted) and since < self.settle_time      # the observer's start transient (docstring)
        if hold:
            theta0, P0 = self.theta.copy(), self.P.copy()
        elif not restarted:
            self.updates += 1
        cov = self._zero6 if cov_qd is None else np.ascontiguousarray(cov_qd, dtype=float)
        W_t, cov_W, dR, cov_dR = np.empty(3), np.empty((3, 3)), np.empty(2), np.empty((2, 2))
        self._combine(Y, dyn.A, dyn.B, Ainv, np.ascontiguousarray(obs.r, dtype=float),
                      np.ascontiguousarray(obs.S, dtype=float), np.ascontiguousarray(obs.cov_W, dtype=float),
                      np.ascontiguousarray(W_obs_restart, dtype=float), np.ascontiguousarray(Jj, dtype=float),
                      cov, cov_qd is not None, K, float(dt), float(since), bool(restarted), self._has_prev,
                      self._Rhold if hold else self._Rres, self.theta, self.P, self._Yf, self._Yprev,
                      self._W_t_restart,
                      W_t, cov_W, dR, cov_dR)
        if hold:                 # exactly no update (the kernel's gain was ~1e-200: its combination used them)
            self.theta[:], self.P[:] = theta0, P0
        self._has_prev = True
        self._W_t = W_t.copy()
        return Wrench(r=obs.r.copy(), W=W_t, cov_W=cov_W, dR=dR, cov_dR=cov_dR, S=obs.S.copy())
