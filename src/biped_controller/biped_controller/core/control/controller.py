"""p/tau-adaptive computed-torque controller (paper section 4). Pure Python, no ROS.

At each control period, from the measured (q, q') and the controller's own parameter state
(p, p', tau, tau'):

  reference (eq. 11)   q_d = q_d(p, tau), q_d' = dq/dp p' + dq/dtau tau'
  joint law (eqs. 16-17)  w = dq/dp p'' + dq/dtau tau'' + v,
      v = d2q/dp2 p'^2 + d2q/dtau2 tau'^2 + 2 d2q/dp dtau p' tau' + Kv (q_d' - q') + Kp (q_d - q)
  second task (eq. 20) p''* = -k_v p' + k_p (p_d - p),  tau''* = k_v (1 - tau')
  QP (eq. 21)          min (x - x*)^T W (x - x*)  s.t.  A_q (D x + v) + b_q <= -margin,  D = [dq/dp, dq/dtau]
                       (rows stated twice when a push is estimated: with and without the estimated force)
                       over the adapted parameters x (p'' and/or tau'' by mode); the others stay at x*.
  torque (eq. 15)      Gamma = A(q) w + H(q, q')

Then (p, p', tau, tau') advance with constant p'', tau'' (exact integration) over the time that has
actually elapsed when the next decision is taken (a period cut short by an impact is shorter), and p is held
to the family's range [p_min, p_max] by that integration (an integrator with limits): where the advance
would carry p to or past a bound, p is put on the bound and the outward part of p' is removed
(``controller_kernels.limited``; in modes lambda and all lambda, lambda' likewise at +-lambda_max).
At an impact (the measured stance leg changes) tau goes back to 0 (tau -= T is not used: the gait
restarts), p and p' are carried over; the measured q is already relabelled by the simulator.

Fallback when the QP is infeasible: the least-violation answer of ``AdaptationQP`` (status
INFEASIBLE_FALLBACK). The controller never raises inside the loop: a numerical failure gives
status SOLVER_ERROR and x = x*.

p is kept inside the family's valid range by two extra QP rows (p after one period within
[p_min, p_max]), and tau' > 0 by one row (tau' after one period >= tau_dot_min). These ranges are hard: on
an answer that does not hold the rows (least violation, or the solver's error answer) each adapted
parameter's acceleration is held to the interval of its own range rows (``_hold_ranges``), in every path
(the Python steps, the compiled period and the compiled loop take the decision from the same two callers);
that hold also keeps tau' (after one period) <= tau_dot_max, an end the QP has no row for. Rows and hold
bound p at the end of a full period only; p(h) = p + p' h + p'' h^2 / 2 can peak inside the period (by up
to p'^2 / (2 |p''|)), and a period cut short by an impact ends there: the integration's limit above holds
p in range at every instant the controller evaluates it (every path's advance is ``period_start``'s;
``reference_at`` and ``torque_within_period`` use the same limited advance). tau' is linear in time over a
period, so it needs no such limit.

State: the controller's state between periods is one array, ``memory`` (``controller_layout.MEMORY``), shared
with the compiled period and the compiled loop; the advance, the observer's mode and the commit of a
period are ``controller_kernels``' numba functions for every path (their one home).

Modes ``wbc`` and ``hybrid`` (:mod:`wbc`) add a whole-body stage after the decision:
``wbc`` keeps the reference (x = x*, as mode none: p = p_d, tau' = 1) and relaxes w itself by the
whole-body QP min (w - w*)' M (w - w*) s.t. the same 17 rows (twice) on w, w* = the tracking law's w;
``hybrid`` decides (p'', tau'') exactly as mode ``both`` and runs the same whole-body QP around the
adapted w only when the p/tau QP did not hold its rows (INFEASIBLE_FALLBACK or SOLVER_ERROR).
Whenever w holds every row the whole-body stage changes nothing (bit for bit). With the compiled period
the stage is compiled too (``wbc_kernels``, PIQP when its active set does not settle; the compiled loop
runs it as well); the Python steps (and ``_FastPeriod.python_stage``, the tests' oracle) run
``wbc.WholeBodyStage``. Either overwrites the period's w (in ``memory``, the observer's next residual),
torque and reported outputs when it changes w.

Modes ``lambda`` and ``all`` (docs/torso_parameter.md) add a third parameter, the torso offset
lambda [rad] of ``gait_family.with_torso``: q_d(p, tau, lambda) = q_d(p, tau) + lambda phi(tau/T) e. Then
D = [dq/dp, dq/dtau, dq/dlambda], x = (p'', tau'', lambda''), lambda''* = -kv_lambda lambda' - kp_lambda
lambda, four more rows (lambda and lambda' after one period within +-lambda_max, +-lambda_dot_max), held
hard on a least-violation answer; lambda, lambda' advance exactly like p, p' and carry over an impact.
``lambda`` adapts lambda alone (p'', tau'' = x*), ``all`` the three. The compiled period covers them (the PIQP
fallback and the torso's hold through Python, as for the other modes' QP); the Python steps are its oracle.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from biped_model.description import RobotDescription, load_description
from biped_model.loop import ENGINES, load_loop_settings
from biped_model.settings import SettingsError, default_config_dir, read_settings

from biped_model.gait_family import GaitFamily, eq11, eq11_torso
from biped_model.fixed_foot import N_CONSTRAINTS, Dynamics, FixedFootModel, contact_rows, relabel
from biped_model import numba_cache
from biped_model.layout import SnapshotUnsupported
from biped_model.finite import finite_number
from biped_controller.core.control.controller_layout import (
    CONS, GAINS, MEMORY, OBS_KEEP, OBS_RESIDUAL, QP_ROWS, RES, TORSO_QP_ROWS, TORSO_ROWS, WBC, WORK, M_, R_, W_,
    WB_)
from biped_controller.core.qp.solver import SOLVER_ERROR, SOLVERS as QP_SOLVERS, AdaptationQP
from biped_controller.core.qp.problem import ACTIVE, INFEASIBLE_FALLBACK, UNCONSTRAINED
from biped_controller.core.control.wbc import WBC_MODES, WholeBodyStage, weight_matrix

MODES = ("none", "tau", "p", "both", "wbc", "hybrid", "lambda", "all")
#: what the legs' model-error estimator's regressor is evaluated on (``model_error.REGRESSOR_INPUTS``)
MODEL_ERROR_REGRESSORS = ("measured", "reference")
#: the paper's four modes: the default set of the tables and maps (wbc and hybrid on request, --modes)
PAPER_MODES = ("none", "tau", "p", "both")
#: the parameters each mode's p/tau QP adapts (0: p'', 1: tau'', 2: lambda'', the torso offset);
#: wbc keeps the reference fixed like none
ADAPTED = {"none": (), "tau": (1,), "p": (0,), "both": (0, 1), "wbc": (), "hybrid": (0, 1), "lambda": (2,),
           "all": (0, 1, 2)}
#: the modes whose reference has the torso parameter lambda; TORSO_ROWS (controller_layout): the rows it adds
#: to the QP, lambda and lambda' after one period within [-lambda_max, lambda_max] and [-lambda_dot_max, lambda_dot_max]
TORSO_MODES = ("lambda", "all")
NO_ADAPTATION = 4
NO_ADAPTATION_STATUS = NO_ADAPTATION
MSG_NO_ADAPTATION = "mode none: classical computed torque"
MSG_FIXED_REFERENCE = {"none": MSG_NO_ADAPTATION, "wbc": "mode wbc: fixed reference, whole-body QP on w"}
MSG_X_STAR_FEASIBLE = "x* feasible"

CONTROLLER_KERNELS = "biped_controller.core.control.controller_kernels"
# what the compiled period is compiled against besides its own source (kernels it calls, offsets it reads)
CONTROLLER_KERNELS_SOURCES = ("biped_model.planar_abi", "biped_model.planar_kernels", "biped_model.layout",
                           "biped_model.gait_family",
                           "biped_controller.core.control.controller_layout", "biped_controller.core.qp.problem",
                           "biped_controller.core.qp.exact_kernels")


WBC_KERNELS = "biped_controller.core.control.wbc_kernels"
WBC_KERNELS_SOURCES = CONTROLLER_KERNELS_SOURCES + (CONTROLLER_KERNELS,)


def load_wbc_kernels():
    """The compiled whole-body stage (``wbc_kernels``, modes wbc and hybrid) through ``numba_cache.load``."""
    load_controller_kernels()
    return numba_cache.load(WBC_KERNELS, sources=WBC_KERNELS_SOURCES)


def load_controller_kernels():
    """The compiled control period (``controller_kernels``), through ``numba_cache.load``: its ``begin`` and
    ``commit`` are the one home of the parameter advance, the observer's mode and the period's commit, for
    the compiled period and the Python steps alike."""
    return numba_cache.load(CONTROLLER_KERNELS, sources=CONTROLLER_KERNELS_SOURCES)


class ControllerConfigError(ValueError):
    """A controller setting is missing or out of range (message names it)."""


@dataclass(frozen=True)
class ControllerConfig:
    """Controller settings. The values and their reasons live in ``config/controller.yaml`` only (the
    control period in ``config/simulator.yaml``): build one with :func:`load_controller_config`."""

    mode: str                     # none | tau | p | both | wbc | hybrid | lambda | all: which parameters the QP adapts
    Kp: float                     # [1/s^2] joint PD stiffness of eq. (16)
    Kv: float                     # [1/s] joint PD damping of eq. (16)
    kp: float                     # [1/s^2] second task eq. (20), p -> p_d
    kv: float                     # [1/s] second task eq. (20), p' -> 0 and tau' -> 1
    weight_p: float               # QP weight on (p'' - p''*)^2
    weight_tau: float             # QP weight on (tau'' - tau''*)^2
    margin_normal_force: float    # [N] QP keeps R_y >= this
    margin_friction: float        # [-] QP keeps |R_x| <= margin_friction mu R_y
    margin_zmp: float             # [m] QP keeps l within [l_m + margin, l_M - margin]
    margin_torque: float          # [N m] QP keeps |Gamma_i| <= Gamma_iM - margin
    tau_dot_min: float            # [-] QP keeps tau' (after one period) >= this
    tau_dot_max: float            # [-] a held answer keeps tau' (after one period) <= this (no QP row)
    qp_solver: str                # "piqp" (the product's solver) or "exact" (dedicated n <= 2 solver)
    disturbance_observer: bool    # estimate a horizontal torso force (not in the paper) for the QP rows
    observer_height: float        # [m] assumed application height of the estimated force above the hip
    wbc_weight_joint: float       # whole-body QP weight M = wbc_weight_joint I + wbc_weight_torso s s^T (wbc.py)
    wbc_weight_torso: float       # torso-pitch task weight of M (s . w = torso pitch acceleration)
    engine: str                   # "fast": compiled model terms (biped_model.fast_engine); "reference": Pinocchio
    period: float                 # [s] control period (config/simulator.yaml control_period)
    # the torso parameter lambda (modes lambda and all): second task and range of lambda
    kp_lambda: float              # [1/s^2] lambda -> 0 (lambda''* = -kv_lambda lambda' - kp_lambda lambda)
    kv_lambda: float              # [1/s] lambda' -> 0
    weight_lambda: float          # QP weight on (lambda'' - lambda''*)^2
    lambda_max: float             # [rad] QP keeps |lambda| (after one period) <= this: the torso's range
    lambda_dot_max: float         # [rad/s] QP keeps |lambda'| (after one period) <= this
    # real sensing: core/sensing/pipeline.py; with all of them off the controller is the one above
    momentum_observer: bool       # the observer is the generalized-momentum one (else acceleration residual)
    momentum_observer_gain: float   # [1/s] its bandwidth K
    estimate_confidence: float      # [-] k: the QP's contact rows keep k sigma of the estimate's spread
    state_estimator: bool         # Kalman filter on (q, q') (core/sensing/estimation.py)
    sensor_noise_q: float           # [rad] encoder noise std the controller assumes
    sensor_encoder_bits: int          # [bits per turn] encoder resolution it assumes (0: none)
    sensor_noise_qd: float          # [rad/s] rate sensor noise std it assumes
    sensor_noise_pitch: float       # [rad] IMU pitch noise std it assumes
    estimator_gyro: bool            # the estimator fuses the IMU gyro's pitch rate
    sensor_noise_pitch_rate: float  # [rad/s] IMU gyro pitch-rate noise std it assumes
    estimator_accel_std: float      # [rad/s^2] the filter's process noise
    estimator_impact_std: float     # [rad/s] added to each rate's std at a touchdown
    delay_compensation: int           # [periods] known delay the Smith predictor compensates (0: none)
    predictor_substeps: int           # RK4 steps per period of the predictor
    predictor_touchdown_height: float   # [m] a swing sole this low at a period's end has touched down
    predictor_clearance: float      # [m] the swing foot must have risen this high before
    predictor_time_tolerance: float     # [s] a touchdown inside a substep located to this
    model_error_estimator: bool       # identify the legs' mass and inertia error from the observer (model_error.py)
    model_mass_uncertainty: float     # [-] prior std of each leg link's mass error, relative to its mass
    model_inertia_uncertainty: float  # [-] prior std of each leg link's inertia error, relative to its inertia
    model_error_residual_std: float   # [N m] std of what the legs' regressor leaves in a swing-leg row of r
    model_error_regressor: str        # what its regressor is evaluated on: "measured" | "reference" (model_error.py)
    model_error_settle: float         # [observer time constants 1/K] no update this long after the observer's start
    predictor_touchdown_at_once: bool   # a sensed touchdown's first sample is fresh (plant touchdown_delayed False)
    touchdown_band_sigmas: float      # k of the predicted touchdown's band |z| <= k sigma_z (touchdown_band.py)

    def validate(self) -> "ControllerConfig":
        if self.engine not in ENGINES:
            raise ControllerConfigError(f"engine must be one of {ENGINES}, got {self.engine!r}")
        if self.qp_solver not in QP_SOLVERS:
            raise ControllerConfigError(f"qp_solver must be one of {QP_SOLVERS}, got {self.qp_solver!r}")
        if self.mode not in MODES:
            raise ControllerConfigError(f"mode must be one of {MODES}, got {self.mode!r}")
        for name in ("Kp", "Kv", "kp", "kv", "weight_p", "weight_tau", "period", "tau_dot_min", "kp_lambda",
                     "kv_lambda", "weight_lambda", "lambda_max", "lambda_dot_max"):
            finite_number(getattr(self, name), name, above=0, error=ControllerConfigError)
        for name in ("margin_normal_force", "margin_zmp", "margin_torque"):
            finite_number(getattr(self, name), name, at_least=0, error=ControllerConfigError)
        if not isinstance(self.disturbance_observer, bool):
            raise ControllerConfigError(f"disturbance_observer must be true or false, got {self.disturbance_observer!r}")
        finite_number(self.observer_height, "observer_height", error=ControllerConfigError)
        try:
            weight_matrix(self.wbc_weight_joint, self.wbc_weight_torso)
        except ValueError as exc:
            raise ControllerConfigError(str(exc)) from exc
        finite_number(self.tau_dot_max, "tau_dot_max", above=self.tau_dot_min, error=ControllerConfigError)
        if not (0 < self.margin_friction <= 1):
            raise ControllerConfigError(f"margin_friction must be in (0, 1], got {self.margin_friction}")
        for name in ("momentum_observer", "state_estimator", "model_error_estimator", "predictor_touchdown_at_once",
                     "estimator_gyro"):
            if not isinstance(getattr(self, name), bool):
                raise ControllerConfigError(f"{name} must be true or false, got {getattr(self, name)!r}")
        ints = {}
        for name in ("sensor_encoder_bits", "delay_compensation", "predictor_substeps"):
            ints[name] = int(finite_number(getattr(self, name), name, at_least=0, integer=True,
                                           error=ControllerConfigError))   # (a ROS parameter arrives as a float)
        for name in ("momentum_observer_gain", "estimate_confidence", "sensor_noise_q", "sensor_noise_qd",
                     "sensor_noise_pitch", "sensor_noise_pitch_rate", "estimator_accel_std", "estimator_impact_std",
                     "predictor_touchdown_height", "predictor_clearance", "predictor_time_tolerance",
                     "touchdown_band_sigmas"):
            finite_number(getattr(self, name), name, at_least=0, error=ControllerConfigError)
        if self.momentum_observer and self.disturbance_observer and self.momentum_observer_gain <= 0:
            raise ControllerConfigError("momentum_observer_gain must be > 0 with the momentum observer on")
        if self.model_error_estimator:
            for name in ("model_mass_uncertainty", "model_inertia_uncertainty", "model_error_residual_std"):
                v = getattr(self, name)
                finite_number(v, name, above=0, error=ControllerConfigError,
                              message=f"{name} must be a finite number > 0 with model_error_estimator on, got {v!r}")
            v = self.model_error_settle
            finite_number(v, "model_error_settle", at_least=0, error=ControllerConfigError,
                          message=f"model_error_settle must be a finite number >= 0 with model_error_estimator on, "
                                  f"got {v!r}")
            if not (self.disturbance_observer and self.momentum_observer):
                raise ControllerConfigError("model_error_estimator needs disturbance_observer and momentum_observer on")
            if self.model_error_regressor not in MODEL_ERROR_REGRESSORS:
                raise ControllerConfigError(f"model_error_regressor must be one of {MODEL_ERROR_REGRESSORS}, "
                                            f"got {self.model_error_regressor!r}")
            if self.model_error_regressor == "reference" and self.mode in TORSO_MODES:
                raise ControllerConfigError("model_error_regressor 'reference' is not done for the torso modes "
                                            f"{TORSO_MODES} (their reference has lambda), got mode {self.mode!r}")
        if self.state_estimator and (self.estimator_accel_std <= 0 or
                                     (self.sensor_noise_q <= 0 and ints["sensor_encoder_bits"] == 0)):
            raise ControllerConfigError("estimator_accel_std must be > 0, and sensor_noise_q > 0 or "
                                        "sensor_encoder_bits > 0, with the state estimator on")
        if ints["delay_compensation"] > 0:
            for name in ("predictor_touchdown_height", "predictor_clearance", "predictor_time_tolerance"):
                if getattr(self, name) <= 0:
                    raise ControllerConfigError(f"{name} must be > 0 with delay_compensation > 0")
            if ints["predictor_substeps"] < 1:
                raise ControllerConfigError("predictor_substeps must be >= 1 with delay_compensation > 0")
        if any(getattr(self, k) != v or type(getattr(self, k)) is not int for k, v in ints.items()):
            return replace(self, **ints)
        return self

    @property
    def real_sensing(self) -> bool:
        """Any part of real sensing on: the sensing pipeline runs (Python steps, no compiled period)."""
        return bool(self.state_estimator or self.delay_compensation > 0
                    or (self.disturbance_observer and self.momentum_observer))



def load_controller_config(path: str | Path | None = None, **overrides) -> ControllerConfig:
    """``config/controller.yaml`` (or ``path``) with ``overrides`` applied, validated. ``period`` comes
    from ``config/simulator.yaml`` (control_period) unless overridden."""
    p = Path(path) if path is not None else default_config_dir() / "controller.yaml"
    keys = [k for k in ControllerConfig.__dataclass_fields__ if k not in ("period", "engine")]
    try:
        kw = read_settings(p, keys)
    except SettingsError as exc:
        raise ControllerConfigError(str(exc)) from exc
    if "period" not in overrides or "engine" not in overrides:
        # one home for both: the loop's settings in config/simulator.yaml (biped_model.loop)
        loop = load_loop_settings()
        kw["period"], kw["engine"] = loop.control_period, loop.engine
    kw.update(overrides)
    return ControllerConfig(**kw).validate()


class ParamState:
    """The trajectory parameters: stride p [m], p' [m/s], phase tau [s], tau' [-]: a view of four fields of
    an array (the controller's ``MEMORY``: the values at the last decision, i.e. at the start of the period
    being applied; before the first decision the initial ones)."""

    __slots__ = ("_a", "_o")

    def __init__(self, array: np.ndarray, offset: int):
        self._a, self._o = array, offset

    p = property(lambda s: float(s._a[s._o]), lambda s, v: s._a.__setitem__(s._o, v))
    p_dot = property(lambda s: float(s._a[s._o + 1]), lambda s, v: s._a.__setitem__(s._o + 1, v))
    tau = property(lambda s: float(s._a[s._o + 2]), lambda s, v: s._a.__setitem__(s._o + 2, v))
    tau_dot = property(lambda s: float(s._a[s._o + 3]), lambda s, v: s._a.__setitem__(s._o + 3, v))

    def __repr__(self) -> str:
        return f"ParamState(p={self.p!r}, p_dot={self.p_dot!r}, tau={self.tau!r}, tau_dot={self.tau_dot!r})"


@dataclass(frozen=True)
class ControllerStatusData:
    """Every field of biped_msgs_py/ControllerStatus (pure-Python mirror)."""

    step: int
    t: float
    mode: str
    p: float
    p_dot: float
    tau: float
    tau_dot: float
    p_ddot: float
    tau_ddot: float
    p_ddot_star: float
    tau_ddot_star: float
    qp_status: int
    qp_message: str
    margins: np.ndarray
    tightest: int
    zmp: float
    stance: int
    max_tracking_error: float
    predicted_reaction: np.ndarray = field(default_factory=lambda: np.zeros(2))
    force_estimate: float = 0.0
    wbc_status: int = NO_ADAPTATION_STATUS   # whole-body stage (modes wbc, hybrid): problem status, or 4 = not run
    wbc_active: int = 0                      # bit i: row CONSTRAINT_NAMES[i] active in the whole-body QP's answer
    wbc_deviation: float = 0.0               # [rad/s^2] |w - w*| of the whole-body stage (0 when w* held)
    lam: float = 0.0                         # [rad] torso offset lambda of the period (modes lambda, all; else 0)
    lam_dot: float = 0.0                     # [rad/s] lambda'
    lam_ddot: float = 0.0                    # [rad/s^2] lambda'' chosen
    lam_ddot_star: float = 0.0               # [rad/s^2] lambda''* of the second task


_NEW = object.__new__
_SENS_RES = slice(RES.at.sens_dR, RES.at.sens_margin + RES.sizes["sens_margin"])
_MG = RES.slice("margins")
_RR = RES.slice("reaction")


def status_records(rows: np.ndarray, steps: Sequence[int], times: Sequence[float], mode: str, stance: int,
                   qp_status: int, qp_message: str) -> list[ControllerStatusData]:
    """The one builder of :class:`ControllerStatusData`: from rows of the ``RES`` layout (n, RES.size), one a
    period (the period's p, p', tau, tau', x = (p'', tau''), x*, margins, tightest row, l, max |e|, R, F),
    with their period indices ``steps``, times [s], the mode, the stance and the QP's status and message.
    Each instance's ``__dict__`` is filled at once (the frozen dataclass's ``__init__`` costs ~4 us, as
    much as a compiled period); every field is set here, and ``margins`` / ``predicted_reaction`` are views
    of ``rows`` (pass rows nobody writes again)."""
    c = rows.T.tolist()     # columns, as exact Python floats
    P, PD, TA, TAD, X0, X1, XS0, XS1 = (c[R_.p], c[R_.p_dot], c[R_.tau], c[R_.tau_dot], c[R_.x], c[R_.x + 1],
                                        c[R_.x_star], c[R_.x_star + 1])
    TIGHT, ZMP, ERR, F = [int(v) for v in c[R_.tightest]], c[R_.zmp], c[R_.max_error], c[R_.force]
    MG, RR = rows[:, _MG], rows[:, _RR]
    wbc = mode in WBC_MODES       # the whole-body stage's fields (RES wbc_*); the class defaults otherwise
    if wbc:
        WS, WA, WD = ([int(v) for v in c[R_.wbc_status]], [int(v) for v in c[R_.wbc_active]], c[R_.wbc_deviation])
    torso = mode in TORSO_MODES   # torso modes: lambda, lambda', lambda'', lambda''* (RES lam, x[2], x_star[2])
    if torso:
        LA, LD, X2, XS2 = c[R_.lam], c[R_.lam + 1], c[R_.x + 2], c[R_.x_star + 2]
    out = []
    for j in range(len(P)):
        s = _NEW(ControllerStatusData)
        s.__dict__.update(
            step=steps[j], t=times[j], mode=mode, p=P[j], p_dot=PD[j], tau=TA[j], tau_dot=TAD[j], p_ddot=X0[j],
            tau_ddot=X1[j], p_ddot_star=XS0[j], tau_ddot_star=XS1[j], qp_status=qp_status, qp_message=qp_message,
            margins=MG[j], tightest=TIGHT[j], zmp=ZMP[j], stance=stance, max_tracking_error=ERR[j],
            predicted_reaction=RR[j], force_estimate=F[j])
        if wbc:
            s.__dict__.update(wbc_status=WS[j], wbc_active=WA[j], wbc_deviation=WD[j])
        if torso:
            s.__dict__.update(lam=LA[j], lam_dot=LD[j], lam_ddot=X2[j], lam_ddot_star=XS2[j])
        out.append(s)
    return out


def computed_torque(A: np.ndarray, H: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Eq. (15): Gamma = A(q) w + H(q, q') [N m] (the Python steps; ``controller_kernels._finish`` is its
    compiled twin)."""
    return A @ w + H


def joint_law(q_d: np.ndarray, qd_d: np.ndarray, qdd_d: np.ndarray, q: np.ndarray, qd: np.ndarray,
              Kp: float, Kv: float) -> np.ndarray:
    """Eq. (16): w = q_d'' + K_v (q_d' - q') + K_p (q_d - q) [rad/s^2] (q_d'' without or with the p'', tau''
    terms: the drift v of eq. (17), or the whole reference acceleration within a period)."""
    return qdd_d + Kv * (qd_d - qd) + Kp * (q_d - q)


@dataclass(frozen=True)
class _Reference:
    """The reference terms of one period: w = D x + v (eq. 17), x* (eq. 20), tracking error q_d - q."""

    D: np.ndarray          # (6, 2) [dq_d/dp, dq_d/dtau] (modes lambda, all: (6, 3), and dq_d/dlambda)
    v: np.ndarray          # (6,) rad/s^2
    x_star: np.ndarray     # (2,) (p''*, tau''*) (modes lambda, all: (3,), and lambda''*)
    error: np.ndarray      # (6,) rad


@dataclass(frozen=True)
class ControlOutput:
    torque: np.ndarray            # paper q1..q6 [N m]
    status: ControllerStatusData
    G: np.ndarray | None = None   # the QP instance (for benchmarks/tests); None in mode 'none'
    h: np.ndarray | None = None
    x_star: np.ndarray | None = None


def _mem_scalar(name: str, kind=float):
    o = getattr(M_, name)
    return property(lambda self: kind(self.memory[o]), lambda self, v: self.memory.__setitem__(o, v),
                    doc=f"MEMORY.{name} of the controller's state array")


class AdaptiveController:
    """Owns its FixedFootModel (own Pinocchio Data) and its PIQP solver object.

    Real sensing (``ControllerConfig.real_sensing``): on the fast engine the estimator, the
    momentum observer and the Smith predictor run as compiled kernels (``pipeline_compiled.CompiledSensing``)
    before the compiled period; on the reference engine, or with
    ``python_sensing`` True (the tests' oracle) the Python pipeline (``pipeline.SensingPipeline``) and the
    Python steps.

    Its state between periods is the array ``memory`` (``controller_layout.MEMORY``: parameters, the held
    decision, the last decision's time and stance, F, the observer's memory); ``state``, ``stance``,
    ``step_index`` and ``force_estimate`` are views of it. The compiled period (``controller_kernels``) and the
    compiled loop (``loop_kernels``) take the same array."""

    step_index = _mem_scalar("step", int)
    force_estimate = _mem_scalar("force")      # estimated horizontal force on the torso [N]

    def __init__(self, config: ControllerConfig | None = None, family: GaitFamily | None = None,
                 desc: RobotDescription | None = None, keep_qp: bool = False, python_sensing: bool = False):
        self.cfg = (config if config is not None else load_controller_config()).validate()
        self.desc = desc if desc is not None else load_description()
        self.family = family if family is not None else GaitFamily.load()
        self.model = FixedFootModel(self.desc)
        self.ck = load_controller_kernels()
        self._fast = None
        self._kernel = None
        if self.cfg.engine == "fast":
            from biped_model.fast_engine import FastFixedFootModel   # compiled kernels only when used
            self._fast = FastFixedFootModel(self.desc)
        self.keep_qp = keep_qp
        # False: compute() leaves ControlOutput.status None and keeps what builds it (last_status()): a run
        # that keeps only its outcome saves the status object of every period (the torque and the memory are
        # the same); ignored with real sensing (its touchdown band reads the status)
        self.build_status = True
        self._pending_status: tuple | None = None
        c = self.cfg
        # constraint margins (subtracted from the right-hand side), in the row order of CONSTRAINT_NAMES
        self.margin = np.concatenate([
            [c.margin_normal_force, 0.0, 0.0, 0.0, 0.0], np.full(12, c.margin_torque)])
        self._mu_ratio = c.margin_friction
        self.adapted = ADAPTED[c.mode]
        self.whole_body = WholeBodyStage.for_controller(c, self.model) if c.mode in WBC_MODES else None
        self.wbc = WBC.new()           # the compiled stage's constants (controller_layout.WBC; mode 0: off)
        if self.whole_body is not None:
            self.wbc[WB_.mode] = WBC_MODES[c.mode]
            self.wbc[WBC.slice("M")] = self.whole_body.qp.M.ravel()
            self.wbc[WBC.slice("Minv")] = np.linalg.inv(self.whole_body.qp.M).ravel()
        self.torso = c.mode in TORSO_MODES     # the reference has the torso parameter lambda
        nx = 3 if self.torso else 2
        self._adapted_idx = list(self.adapted)
        self._fixed_idx = [i for i in range(nx) if i not in self.adapted]
        n = len(self.adapted)
        weights = np.array([c.weight_p, c.weight_tau, c.weight_lambda])[list(self.adapted)]
        self.qp = AdaptationQP(n, QP_ROWS + (TORSO_ROWS if self.torso else 0), weights,
                               solver="piqp" if self.torso and n > 2 else c.qp_solver) if n else None
        self.gains = self._gains()
        self.cons = self._cons()
        self.memory = MEMORY.new()
        self._sensing = None
        self._extra_margin = np.zeros(N_CONSTRAINTS)
        self._compiled_sensing = False
        if self.cfg.real_sensing:
            if self._fast is not None and not python_sensing and not self.torso:
                # real sensing: the estimator and the momentum observer as compiled kernels (pipeline_kernels)
                from biped_controller.core.sensing.pipeline_compiled import CompiledSensing
                m = self.model
                qp_C, _ = contact_rows(c.margin_friction * m.mu, m.l_min + c.margin_zmp, m.l_max - c.margin_zmp)
                self._sensing = CompiledSensing(self.cfg, self.desc, self._fast.ti, self._fast.tf, qp_C,
                                                m.torque_min, m.torque_max)
                self._compiled_sensing = True
            else:
                from biped_controller.core.sensing.pipeline import SensingPipeline
                self._sensing = SensingPipeline(self.cfg, self.desc)
            if self.cfg.delay_compensation > 0:
                from biped_controller.core.sensing.touchdown_band import BothStancesTorque
                m = self.model
                self._both = BothStancesTorque(m, self.margin, c.margin_friction * m.mu, m.l_min + c.margin_zmp,
                                               m.l_max - c.margin_zmp)
        self.band_periods = 0           # periods inside a predicted touchdown's band (touchdown_band.py)
        self.band_changed = 0           # of which the torque was replaced by the one admissible in both stances
        # the legs' model-error estimator on the reference (model_error_regressor "reference"): the decisions'
        # parameters, so that a sample of any age within the delay gets the reference of its instant
        self._ref_log: deque | None = None
        if (self._sensing is not None and c.model_error_estimator and c.model_error_regressor == "reference"
                and getattr(self._sensing, "me", None) is not None):
            self._ref_log = deque(maxlen=int(c.delay_compensation) + 3)
            self._sensing.reference_source = self.reference_at
        self.reset(None)
        if self._fast is not None and (self._sensing is None or self._compiled_sensing):
            self._kernel = _FastPeriod(self)   # the compiled period (fast engine)

    def _gains(self) -> np.ndarray:
        """The ``GAINS`` array (eqs. 16, 20, the p range, the observer, the adapted parameters)."""
        c, fam, g = self.cfg, self.family, GAINS.new()
        for name, value in (("Kp", c.Kp), ("Kv", c.Kv), ("kp", c.kp), ("kv", c.kv), ("p_d", fam.p_d), ("dt", c.period),
                            ("p_min", fam.p_min), ("p_max", fam.p_max), ("tau_dot_min", c.tau_dot_min),
                            ("observer", float(c.disturbance_observer)), ("observer_height", c.observer_height),
                            ("adapt_p", float(0 in self.adapted)), ("adapt_tau", float(1 in self.adapted)),
                            ("momentum", float(c.disturbance_observer and c.momentum_observer)),
                            ("torso", float(self.torso)), ("adapt_lam", float(2 in self.adapted)), ("T", fam.T),
                            ("kp_lam", c.kp_lambda), ("kv_lam", c.kv_lambda), ("lam_max", c.lambda_max),
                            ("lam_dot_max", c.lambda_dot_max)):
            g[getattr(GAINS.at, name)] = value
        return g

    def _cons(self) -> np.ndarray:
        """The ``CONS`` array: the contact rows as data (``contact_rows``, written once): the QP's with the
        controller's margins on mu and the foot range, the robot's own for the reported margins."""
        c, m = self.cfg, self.model
        qp_C, qp_e = contact_rows(c.margin_friction * m.mu, m.l_min + c.margin_zmp, m.l_max - c.margin_zmp)
        true_C, true_e = contact_rows(m.mu, m.l_min, m.l_max)
        cons = CONS.new()
        for name, value in (("margin", self.margin), ("row_scale", m.row_scale), ("torque_min", m.torque_min),
                            ("torque_max", m.torque_max), ("qp_rows", np.column_stack([qp_C, qp_e]).ravel()),
                            ("true_rows", np.column_stack([true_C, true_e]).ravel())):
            cons[CONS.slice(name)] = value
        return cons

    @property
    def wrench(self):
        """The momentum observer's last estimate (``momentum_observer.Wrench``; None: none)."""
        return self._sensing.wrench if self._sensing is not None else None

    @wrench.setter
    def wrench(self, value) -> None:
        """Set the Python pipeline's estimate (tests of the QP rows; the compiled pipeline's is its state)."""
        self._sensing.wrench = value

    @property
    def compiled_period(self) -> "_FastPeriod | None":
        """The compiled period (fast engine), None on the Python steps."""
        return self._kernel

    @property
    def state(self) -> ParamState:
        """(p, p', tau, tau') at the last decision (a view of ``memory``)."""
        return ParamState(self.memory, M_.p)

    @property
    def stance(self) -> int | None:
        """The stance of the last decision (or of the reset); None before any."""
        s = self.memory[M_.stance]
        return None if s < 0 else int(s)

    def reset(self, stance: int | None = None) -> None:
        """Back to the start: p = p_d, p' = 0, tau = 0, tau' = 1, lambda = lambda' = lambda'' = 0, no decision
        (p'' = tau'' = 0), no observer
        memory, F = 0, period index 0; ``stance`` the stance the first period is expected in (None: any)."""
        mem = self.memory
        mem[:] = 0.0
        mem[M_.p], mem[M_.tau_dot] = self.family.p_d, 1.0
        mem[M_.stance] = -1.0 if stance is None else stance
        if self._sensing is not None:
            self._sensing.reset()
        if self._ref_log is not None:
            self._ref_log.clear()

    def _log_reference(self) -> None:
        """After a decision: its (t [s], stance, p, p', tau, tau', p'', tau'') from the memory, for
        :meth:`reference_at`."""
        if self._ref_log is not None:
            m = self.memory
            self._ref_log.append((float(m[M_.t_last]), int(m[M_.stance]))
                                 + tuple(float(v) for v in m[M_.p:M_.p + 6]))

    def reference_at(self, t: float, stance: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The controller's reference (q_d [rad], q_d' [rad/s], q_d'' [rad/s^2], paper order of ``stance``) at
        instant ``t`` [s]: eq. (11) at the parameters of the last decision taken at or before ``t``, advanced
        over the integer nanoseconds since with the (p'', tau'') held then (``controller_kernels.advance``, the
        period's own advance), tau = 0 if ``stance`` differs from that decision's (an impact: the next step
        starts, as ``period_start``); before any decision the initial parameters (p = p_d, tau = 0, tau' = 1).
        It depends on the controller's parameters only, not on the sample taken at ``t`` (model_error.py,
        "What the regressor is fed")."""
        tn = round(float(t) * 1e9)
        entry = None
        if self._ref_log:
            for e in reversed(self._ref_log):
                if round(e[0] * 1e9) <= tn:
                    entry = e
                    break
        if entry is None:
            m = self.memory
            if m[M_.decided] != 0.0:
                raise ValueError(f"reference_at: t = {t!r} s is before the oldest decision kept")
            entry = (float(t), int(m[M_.stance])) + tuple(float(v) for v in m[M_.p:M_.p + 6])   # reset's values
        t0, s0, p, pd, tau, taud, p_dd, t_dd = entry
        h = (tn - round(t0 * 1e9)) * 1e-9
        p, pd, tau, taud = self.ck.advance_in_range(p, pd, tau, taud, p_dd, t_dd, h, self.family.p_min,
                                                    self.family.p_max)
        if s0 >= 0 and int(stance) != s0:
            tau = 0.0
        return eq11(self.family.evaluate(p, tau), pd, taud, p_dd, t_dd)

    def snapshot(self) -> np.ndarray:
        """The state between two periods: a copy of ``memory``. The held solvers (PIQP, the
        whole-body QP) keep nothing from one call to the next that changes the next answer (every PIQP solve
        is set up from its instance: ``solver.AdaptationQP``; tested by reusing a controller across trials,
        tests/test_history.py), so the memory is all there is. Raises :class:`SnapshotUnsupported` with real sensing (its filters hold state of their
        own)."""
        if self._sensing is not None:
            raise SnapshotUnsupported("AdaptiveController.snapshot: real sensing (estimator, observer, predictor) "
                                      "carries state outside memory")
        return self.memory.copy()

    def restore(self, memory: np.ndarray) -> None:
        """Back to the state of :meth:`snapshot` (copied into ``memory``; the same object goes on)."""
        self.memory[:] = memory
        self._extra_margin = np.zeros(N_CONSTRAINTS)

    # --------------------------------------------------------------- the steps of one period
    def _begin(self, t: float, stance: int) -> np.ndarray:
        """The period's start (``controller_kernels.begin``, the one home of the equation, shared with the
        compiled period and loop): a ``RES`` row holding (p, p', tau, tau') advanced over the time actually
        elapsed since the last decision with the p'', tau'' chosen then (exact integration, from integer
        nanoseconds, so a time that travelled through a ROS stamp gives the same arithmetic; a period cut
        short by an impact is shorter), tau = 0 when the stance changed (an impact: the next step starts;
        p, p', tau' carry over), and the observer's mode. The memory is not changed."""
        res = np.empty(RES.size)
        self.ck.begin(self.memory, self.gains, float(t), int(stance), res)
        return res

    def _torso_begin(self, res: np.ndarray) -> tuple[float, float]:
        """(lambda [rad], lambda' [rad/s]) of the period (``res``'s lam, written by :meth:`_begin`, the one home of
        the advance): the memory's advanced with the held lambda'' over the time elapsed since the last decision
        (exact integration, as p). An impact carries lambda and lambda' over (phi(0) = 0: no jump)."""
        return float(res[R_.lam]), float(res[R_.lam + 1])

    def _params(self, res: np.ndarray | None) -> tuple[float, float, float, float]:
        """(p, p', tau, tau') of the period (``res``, a RES row from :meth:`_begin`), or the memory's when None."""
        a, o = (self.memory, M_.p) if res is None else (res, R_.p)
        return float(a[o]), float(a[o + 1]), float(a[o + 2]), float(a[o + 3])

    def _reference(self, q: np.ndarray, qd: np.ndarray, res: np.ndarray | None = None,
                   lam: tuple[float, float] | None = None) -> _Reference:
        """Eqs. (11), (16), (17), (20): w = D x + v with D = [dq/dp, dq/dtau], x = (p'', tau''), and the
        second task's x* = (-k_v p' + k_p (p_d - p), k_v (1 - tau')), at the period's parameters (``res``;
        None: the memory's). With the torso parameter (``lam`` = (lambda, lambda'), modes lambda and all):
        D = [dq/dp, dq/dtau, dq/dlambda], x = (p'', tau'', lambda''), v with the lambda terms of
        ``eq11_torso`` and lambda''* = -kv_lambda lambda' - kp_lambda lambda."""
        c, fam = self.cfg, self.family
        p, p_dot, tau, tau_dot = self._params(res)
        if lam is not None:
            gt = fam.evaluate_torso(p, tau, lam[0])
            q_d, qd_d, qdd_drift = eq11_torso(gt, p_dot, tau_dot, lam[1])
            v = joint_law(q_d, qd_d, qdd_drift, q, qd, c.Kp, c.Kv)
            D = np.column_stack([gt.dq_dp, gt.dq_dtau, gt.dq_dlam])
            x_star = np.array([-c.kv * p_dot + c.kp * (fam.p_d - p), c.kv * (1.0 - tau_dot),
                               -c.kv_lambda * lam[1] - c.kp_lambda * lam[0]])
            return _Reference(D=D, v=v, x_star=x_star, error=q_d - q)
        g = fam.evaluate(p, tau)
        q_d, qd_d, qdd_drift = eq11(g, p_dot, tau_dot)
        v = joint_law(q_d, qd_d, qdd_drift, q, qd, c.Kp, c.Kv)
        D = np.column_stack([g.dq_dp, g.dq_dtau])
        x_star = np.array([-c.kv * p_dot + c.kp * (fam.p_d - p), c.kv * (1.0 - tau_dot)])
        return _Reference(D=D, v=v, x_star=x_star, error=q_d - q)

    def _model_terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[Dynamics, np.ndarray | None]:
        """Eq. (1) and the reaction rows (A, H, B, h_b), and the x-row of the torso point Jacobian at
        ``observer_height`` when the observer needs it: one compiled call (fast engine) or Pinocchio."""
        h = self.cfg.observer_height
        if self._fast is not None:
            A, H, B, hb, jp = self._fast.terms(q, qd, h)
            return Dynamics(A=A, H=H, B=B, h_b=hb), jp
        dyn = self.model.dynamics(q, qd)
        jp = self.model.torso_point_jacobian(q, h)[0] if self.cfg.disturbance_observer else None
        return dyn, jp

    def _observe(self, res: np.ndarray, qd: np.ndarray, dyn: Dynamics, Jp: np.ndarray | None
                 ) -> tuple[Dynamics, float]:
        """Disturbance observer (ours, not the paper's; ``disturbance_observer``): the joint-space residual
        of the last period, r = A (a_measured - w_applied), explained by a horizontal force F on the torso
        at ``observer_height`` (least squares, one unknown): r = J6^T F. F only enters the prediction of
        the ground reaction used by the QP: with F acting, the joint acceleration is w + A^-1 J6^T F, so
        R = B (w + A^-1 J6^T F) + h_b - Jb^T F, i.e. h_b is shifted. One period of lag. After an impact
        (mode keep) the residual is meaningless, but a push acting on the torso does not care about the
        stance: the previous estimate is kept. Returns the dynamics with the shifted h_b (``dyn`` itself
        when the observer is off) and F [N]."""
        if not self.cfg.disturbance_observer:
            return dyn, 0.0
        if self.cfg.momentum_observer:
            return self._observe_momentum(dyn)
        j6 = Jp[3:]                       # Jp: (9,) x-row of the torso point Jacobian
        F = 0.0
        mode, mem = res[R_.obs_mode], self.memory
        if mode == OBS_KEEP:
            F = float(mem[M_.force])
        elif mode == OBS_RESIDUAL:
            A_prev = mem[MEMORY.slice("prev_A")].reshape(6, 6)
            r = A_prev @ ((qd - mem[MEMORY.slice("prev_qd")]) / res[R_.obs_dt] - mem[MEMORY.slice("prev_w")])
            nrm = float(j6 @ j6)
            F = float(j6 @ r) / nrm if nrm > 1e-12 else 0.0
        delta = dyn.B @ np.linalg.solve(dyn.A, j6 * F) - Jp[:3] * F
        return replace(dyn, h_b=dyn.h_b + delta), F

    def _observe_momentum(self, dyn: Dynamics) -> tuple[Dynamics, float]:
        """The momentum observer's torso wrench W (``momentum_observer``) moves the predicted ground force
        by dR = S W; its covariance S Sigma_W S^T widens the contact rows of the estimate's QP rows by
        ``estimate_confidence`` standard deviations each (row i: C_i dR, std sqrt(C_i Sigma_dR C_i^T)).
        Returns the shifted dynamics and F_x [N] (the reported force estimate)."""
        w = self.wrench
        self._extra_margin = np.zeros(N_CONSTRAINTS)
        if w is None:
            return dyn, 0.0
        hb = dyn.h_b.copy()
        hb[:2] += w.dR
        c, m = self.cfg, self.model
        C, _ = contact_rows(c.margin_friction * m.mu, m.l_min + c.margin_zmp, m.l_max - c.margin_zmp)
        var = np.einsum("ij,jk,ik->i", C, w.cov_dR, C)
        self._extra_margin[:5] = c.estimate_confidence * np.sqrt(np.maximum(var, 0.0))
        return replace(dyn, h_b=hb), float(w.W[0])

    def _qp_rows(self, ref: _Reference, dyn: Dynamics, dyn_c: Dynamics, res: np.ndarray | None = None,
                 lam: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Eq. (21): G x <= h over x = (p'', tau'') (both columns; the caller keeps the adapted ones).

        The 17 rows of eq. (18) with the controller's margins (tighter mu, l range, R_y >= margin, ...),
        stated twice, robust to the push ending: with the estimated force (``dyn_c``) and without it
        (``dyn``), since the push may stop during the coming period (identical rows when F = 0). The
        estimate only shifts h_b, so the matrix rows are the same and only the five contact offsets differ
        by C (h_b,c - h_b). Then three parameter-range rows: p + p' dt + p'' dt^2/2 within [p_min, p_max],
        tau' + tau'' dt >= tau_dot_min (at the period's parameters ``res``; None: the memory's). With the torso
        parameter (``lam`` = (lambda, lambda')): a third column (lambda'') and four more rows, the torso's range
        lambda + lambda' dt + lambda'' dt^2/2 within [-lambda_max, lambda_max] and its rate lambda' + lambda'' dt
        within [-lambda_dot_max, lambda_dot_max] (the offset moves only the two hips, which have no joint limits
        in robots/biped7/description.yaml; their torques are among the 17 rows)."""
        c, fam, m = self.cfg, self.family, self.model
        p, p_dot, _, tau_dot = self._params(res)
        mu = c.margin_friction * m.mu
        lm, lM = m.l_min + c.margin_zmp, m.l_max - c.margin_zmp
        cm = m.constraints(None, None, dyn_c, mu=mu, l_min=lm, l_max=lM)
        A, b = cm.A_q, cm.b_q + self.margin
        b0 = b
        if dyn_c is not dyn:
            C, _ = contact_rows(mu, lm, lM)
            b0 = b.copy()
            b0[:5] -= C @ (dyn_c.h_b[:2] - dyn.h_b[:2])
            if self._sensing is not None:
                b = b + self._extra_margin      # the estimate's spread (momentum observer): its rows only
        AD = A @ ref.D
        Av = A @ ref.v
        dt = c.period
        if lam is not None:
            hh = 0.5 * dt * dt
            G = np.vstack([AD, AD, [[hh, 0.0, 0.0], [-hh, 0.0, 0.0], [0.0, -dt, 0.0], [0.0, 0.0, hh], [0.0, 0.0, -hh],
                                    [0.0, 0.0, dt], [0.0, 0.0, -dt]]])
            h = np.concatenate([-(Av + b), -(Av + b0),
                                [fam.p_max - p - p_dot * dt, p + p_dot * dt - fam.p_min, tau_dot - c.tau_dot_min,
                                 c.lambda_max - lam[0] - lam[1] * dt, lam[0] + lam[1] * dt + c.lambda_max,
                                 c.lambda_dot_max - lam[1], lam[1] + c.lambda_dot_max]])
            return G, h
        G = np.vstack([AD, AD, [[0.5 * dt * dt, 0.0], [-0.5 * dt * dt, 0.0], [0.0, -dt]]])
        h = np.concatenate([-(Av + b), -(Av + b0),
                            [fam.p_max - p - p_dot * dt, p + p_dot * dt - fam.p_min, tau_dot - c.tau_dot_min]])
        return G, h

    def _decide(self, ref: _Reference, dyn: Dynamics, dyn_c: Dynamics, res: np.ndarray | None = None,
                lam: tuple[float, float] | None = None):
        """Eqs. (19)-(21): x = x* when it satisfies the rows, else the QP's answer over the adapted
        parameters (the others stay at x*). Returns (x (2,) or (3,) with lambda, status, message, G, h, x*)
        with the reduced instance (None in mode none)."""
        x = ref.x_star.copy()
        if not self.adapted:
            return x, NO_ADAPTATION, MSG_FIXED_REFERENCE[self.cfg.mode], None, None, None
        try:
            Gall, hall = self._qp_rows(ref, dyn, dyn_c, res, lam)
            idx, fixed = self._adapted_idx, self._fixed_idx
            h = hall - Gall[:, fixed] @ x[fixed] if fixed else hall
            G, xs = Gall[:, idx], x[idx]
            qres = self.qp.solve(G, h, xs)
            x[idx] = qres.x
            if not np.all(np.isfinite(x)):
                raise FloatingPointError("non-finite QP answer")
            msg = qres.message
            if qres.status not in (UNCONSTRAINED, ACTIVE):
                msg += self._hold_ranges(x, res, lam)
            return x, qres.status, msg, G, h, xs
        except (FloatingPointError, np.linalg.LinAlgError) as exc:
            # numerical failure only (programming errors such as QPShapeError propagate): desired values
            return ref.x_star.copy(), SOLVER_ERROR, f"{type(exc).__name__}: {exc}", None, None, None

    def _hold_ranges(self, x: np.ndarray, res: np.ndarray | None, lam: tuple[float, float] | None) -> str:
        """After an answer that does not hold the rows (least violation, or the solver's error answer x*): the
        parameters' ranges are hard, so each adapted parameter's acceleration in ``x`` (changed in place) is
        held to the interval of its own range rows, at the period's parameters ``res`` (None: the memory's):

          p'' in [2 (p_min - p - p' dt) / dt^2, 2 (p_max - p - p' dt) / dt^2]   (p after one period in range)
          and, where it meets that interval, p + 2 p' dt + 3/2 p'' dt^2 in [p_min, p_max] (after a second
          period at the new p' with no acceleration: bounds p')
          tau'' in [(tau_dot_min - tau') / dt, (tau_dot_max - tau') / dt]        (tau' after one period in range)

        and lambda'' by :meth:`_torso_box` (modes lambda and all, ``lam`` = (lambda, lambda')). The
        least-violation answer weighs a violation of these rows [m, -] against violations of the contact and
        torque rows [N, N m]: without the hold it lets p and tau' run away (p'' ~ 1e6 m/s^2, tau' ~ 1e4), and in mode
        hybrid, where the whole-body stage then takes over the period's w, nothing brings them back. The
        parameters that are not adapted stay at x* (their rows are not the QP's). Returns the message's
        suffix naming what was held ("" when nothing changed)."""
        c, fam, dt = self.cfg, self.family, self.cfg.period
        p, p_dot, _, tau_dot = self._params(res)
        held = []
        if 0 in self.adapted:
            k, sd = 1.0 / (dt * dt), p_dot * dt
            lo, hi = 2.0 * (fam.p_min - p - sd) * k, 2.0 * (fam.p_max - p - sd) * k
            # and, where the two meet, p after a second period at the new p' (no acceleration) in range too:
            # p + 2 p' dt + 3/2 p'' dt^2 within [p_min, p_max]. Held so, p' stays bounded (|p'| dt <= p_max -
            # p_min); without it p bounces between the bounds with a growing p'. (Inside a period, p is held
            # by the integration's limit, ``controller_kernels.limited``.)
            clo, chi = (fam.p_min - p - 2.0 * sd) * k / 1.5, (fam.p_max - p - 2.0 * sd) * k / 1.5
            if max(lo, clo) <= min(hi, chi):
                lo, hi = max(lo, clo), min(hi, chi)
            v = min(max(float(x[0]), lo), hi)
            if v != x[0]:
                x[0] = v
                held.append("p''")
        if 1 in self.adapted:
            # the lower end is the QP's own row; the upper end has none, and it is the least-violation answers,
            # which weigh the range against the contact rows, that took tau' past it (1.6e4 in a MuJoCo fall)
            lo, hi = (c.tau_dot_min - tau_dot) / dt, (c.tau_dot_max - tau_dot) / dt
            v = min(max(float(x[1]), lo), hi)
            if v != x[1]:
                x[1] = v
                held.append("tau''")
        msg = f"; {', '.join(held)} held to the parameters' ranges" if held else ""
        if lam is not None:
            x[2], clipped = self._torso_box(x[2], lam)
            if clipped:
                msg += "; lambda'' held to the torso's range"
        return msg

    def _torso_box(self, lam_ddot: float, lam: tuple[float, float]) -> tuple[float, bool]:
        """The torso's range is hard: lambda'' held to the interval of its four range rows (lambda within
        +-lambda_max and lambda' within +-lambda_dot_max after one period; the range of lambda alone when the
        two intervals do not meet). The least-violation answer of an infeasible QP weighs a violation of
        these rows [rad, rad/s] against violations in N and N m, so it would let lambda run away. Returns
        (lambda'' [rad/s^2], whether it changed)."""
        c, dt = self.cfg, self.cfg.period
        k = 2.0 / (dt * dt)
        lo, hi = (-c.lambda_max - lam[0] - lam[1] * dt) * k, (c.lambda_max - lam[0] - lam[1] * dt) * k
        vlo, vhi = (-c.lambda_dot_max - lam[1]) / dt, (c.lambda_dot_max - lam[1]) / dt
        if max(lo, vlo) <= min(hi, vhi):
            lo, hi = max(lo, vlo), min(hi, vhi)
        out = min(max(lam_ddot, lo), hi)
        return out, out != lam_ddot

    def _output(self, res: np.ndarray, torque: np.ndarray, t: float, stance: int, status: int, msg: str,
                G, h, xs, wb=None) -> ControlOutput:
        """The period's ``ControlOutput`` from its ``RES`` row (the one status builder); the period index
        is the memory's, already advanced by the commit."""
        if wb is not False and self.whole_body is not None:   # the Python stage's (False: the compiled one wrote res)
            for k, v in WholeBodyStage.status_fields(wb).items():
                res[getattr(R_, k)] = v
        if not self.build_status and self._sensing is None:
            self._pending_status = (res, int(self.memory[M_.step]) - 1, t, int(stance), int(status), msg)
            rec = None
        else:
            rec = status_records(res[None], range(int(self.memory[M_.step]) - 1, int(self.memory[M_.step])), [t],
                                 self.cfg.mode, int(stance), int(status), msg)[0]
        keep = self.keep_qp
        out = _NEW(ControlOutput)     # the fields at once (the frozen dataclass's __init__ costs ~1.5 us a period)
        out.__dict__.update(torque=torque, status=rec, G=G if keep else None, h=h if keep else None,
                            x_star=xs if keep else None)
        return out

    def compute(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int, pitch: float = math.nan,
                pitch_rate: float = math.nan) -> ControlOutput:
        """One control period: advance the parameters, observe, reference, rows, decide, torque, commit.

        With the fast engine the steps are one compiled call (``controller_kernels.step``, the same
        equations) and, when x* is not feasible, the QP and one more call; a non-finite value anywhere
        falls back to the Python steps below (the memory is then unchanged by the compiled call).

        With real sensing (``ControllerConfig.real_sensing``) the measurement (stance, q, q' and
        the IMU's torso ``pitch`` [rad] and its gyro's ``pitch_rate`` [rad/s], NaN: none) goes through
        ``pipeline.SensingPipeline`` first: the Python steps run on its estimate, in the stance it predicts,
        and the torque returned is in the paper order of the stance given here (relabelled when a touchdown
        is predicted before it is sensed). Inside a predicted touchdown's band (``touchdown_band``, with the
        estimator and a delay) that torque is replaced by one holding both stances' rows when it does not."""
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        told = stance
        if self._sensing is not None:
            q, qd, stance = self._sensing.sense(t, q, qd, stance, pitch, pitch_rate)
        if self._kernel is not None:
            out = self._kernel.compute(t, q, qd, stance)
            if out is not None:
                if self._sensing is not None:
                    if stance != told:      # a touchdown predicted before it is sensed: sent in the told order
                        out = replace(out, torque=relabel(out.torque))
                    out = self._band_torque(out, told)
                    self._log_reference()
                    self._sensing.record(t, out.torque, told)
                return out
        res = self._begin(t, stance)
        lam = self._torso_begin(res) if self.torso else None     # (lambda, lambda') of the period (torso modes)
        ref = self._reference(q, qd, res, lam)
        dyn, jp = self._model_terms(q, qd)                     # eq. (1): A, H and the reaction rows
        dyn_c, F = self._observe(res, qd, dyn, jp)
        x, status, msg, G, h, xs = self._decide(ref, dyn, dyn_c, res, lam)
        w = ref.D @ x + ref.v                                    # eq. (17)
        wb = None
        if self.whole_body is not None:                          # modes wbc, hybrid (wbc.py)
            wb = self.whole_body.decide(w, status, dyn.A, dyn.H, dyn.B, dyn.h_b, dyn_c.h_b)
            if wb is not None:
                w = wb.w
        torque = computed_torque(dyn.A, dyn.H, w)                # eq. (15)
        cm = self.model.constraints(q, qd, dyn_c)
        margins = -(cm.A_q @ w + cm.b_q)
        R = dyn_c.B[:2] @ w + dyn_c.h_b[:2]
        res[R_.x:R_.x + x.size] = x                 # (modes lambda, all: and lambda'', committed to the memory)
        res[R_.x_star:R_.x_star + x.size] = ref.x_star
        res[R_.force] = F
        res[R_.max_error] = np.max(np.abs(ref.error))
        res[R_.zmp] = torque[0] / R[1] if R[1] != 0 else math.nan
        res[R_.tightest] = np.argmin(margins / self.model.row_scale)
        res[RES.slice("reaction")] = R
        res[RES.slice("margins")] = margins
        work = np.empty((WORK.size, 6))
        work[W_.w] = w
        work[W_.A:W_.A + 6] = dyn.A
        self.ck.commit(self.memory, res, work, qd if qd.flags.c_contiguous else np.ascontiguousarray(qd),
                       float(t), int(stance))
        if self._sensing is not None:
            if stance != told:
                torque = relabel(torque)        # sent in the order of the stance the plant told us
            self._log_reference()
            if self._sensing.band is not None:
                return self._band_torque(self._output(res, torque, t, stance, status, msg, G, h, xs, wb), told,
                                         record=t)
            self._sensing.record(t, torque, told)
        return self._output(res, torque, t, stance, status, msg, G, h, xs, wb)

    def last_status(self) -> ControllerStatusData | None:
        """The status of the last period computed with ``build_status`` False (None: none since), the object
        ``compute`` would have returned then."""
        if self._pending_status is None:
            return None
        res, step, t, stance, status, msg = self._pending_status
        return status_records(res[None], range(step, step + 1), [t], self.cfg.mode, stance, status, msg)[0]

    def _band_torque(self, out: ControlOutput, told: int, record: float | None = None) -> ControlOutput:
        """A period inside the predicted touchdown's band (``touchdown_band``): the torque (told stance's
        order) replaced by the one admissible in both stances when it is not; ``record``: the period's t, to
        record the torque sent in the sensing pipeline here."""
        band = self._sensing.band
        if band is not None:
            self.band_periods += 1
            torque, changed = self._both.torque(band, out.torque, told)
            if changed:
                self.band_changed += 1
                out = replace(out, torque=torque)
        if record is not None:
            self._sensing.record(record, out.torque, told)
        return out

    def torque_within_period(self, s_time: float, q: np.ndarray, qd: np.ndarray, stance: int) -> np.ndarray:
        """Computed torque at time s_time [s] into the current period, with (p, tau) propagated from the
        period's start by the period's decision (p'', tau'') and no new QP: the controller "at the
        integration rate" (eqs. 11, 16, 15). Before any decision: the initial parameters, p'' = tau'' = 0."""
        p0, pd0, tau0, taud0, p_dd, t_dd = (float(v) for v in self.memory[M_.p:M_.p + 6])
        fam = self.family
        p, pdot, tau, taud = self.ck.advance_in_range(p0, pd0, tau0, taud0, p_dd, t_dd, float(s_time), fam.p_min,
                                                      fam.p_max)   # the one advance, held to p's range
        if self.torso:
            l0, ld0, l_dd = (float(self.memory[o]) for o in (M_.lam, M_.lam_dot, M_.lam_ddot))
            h, lm = float(s_time), self.cfg.lambda_max
            lam, lam_dot = self.ck.limit(l0 + (ld0 * h + 0.5 * l_dd * h * h), ld0 + l_dd * h, -lm, lm)
            qr, qdr, qddr = fam.reference_torso(p, pdot, tau, taud, lam, lam_dot, p_dd, t_dd, l_dd)
        else:
            qr, qdr, qddr = eq11(fam.evaluate(p, tau), pdot, taud, p_dd, t_dd)
        w = joint_law(qr, qdr, qddr, q, qd, self.cfg.Kp, self.cfg.Kv)
        dyn, _ = self._model_terms(q, qd)
        return computed_torque(dyn.A, dyn.H, w)


class _FastPeriod:
    """The compiled period of an :class:`AdaptiveController` (fast engine): ``controller_kernels.step`` on the
    controller's own arrays (gains, cons, memory), the QP when x* is not feasible, the same
    ``ControlOutput`` as the Python steps."""

    def __init__(self, ctrl: AdaptiveController):
        self.ck = ctrl.ck
        self.ctrl = ctrl
        self.coef, self.inner, self.centers = ctrl.family.piece_arrays()
        self.ti, self.tf = ctrl._fast.ti, ctrl._fast.tf
        # the rows G x <= h of the period (modes lambda, all: the four torso rows and the column of lambda'')
        self.nx = 3 if ctrl.torso else 2
        self.G = np.zeros((TORSO_QP_ROWS, 3) if ctrl.torso else (QP_ROWS, 2))
        self.h = np.zeros(self.G.shape[0])
        # modes wbc, hybrid: the compiled whole-body stage (wbc_kernels) with PIQP when it does not settle;
        # ``python_stage`` True runs the Python stage (wbc.WholeBodyStage, the tests' oracle) instead
        self.wk = load_wbc_kernels() if ctrl.whole_body is not None else None
        self.python_stage = False
        self.stage_counts = {"solved": 0, "piqp": 0}   # periods the compiled stage changed w / handed to PIQP
        self.Gw = np.zeros((2 * N_CONSTRAINTS, 6))
        self.hw = np.zeros(2 * N_CONSTRAINTS)

    def compute(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int) -> ControlOutput | None:
        ck, ctrl = self.ck, self.ctrl
        if q.dtype != np.float64 or not q.flags.c_contiguous:
            q = np.ascontiguousarray(q, dtype=float)
        if qd.dtype != np.float64 or not qd.flags.c_contiguous:
            qd = np.ascontiguousarray(qd, dtype=float)
        work = np.empty((WORK.size, 6))
        res = np.empty(RES.size)
        if ctrl._compiled_sensing:              # the momentum observer's inputs to the period
            ctrl._sensing.into_res(res[_SENS_RES])
        G, h = self.G, self.h
        t, stance = float(t), int(stance)
        code = ck.step(self.coef, self.inner, self.centers, self.ti, self.tf, q, qd, t, stance, ctrl.gains,
                       ctrl.cons, ctrl.memory, G, h, work, res)
        if code == ck.NONFINITE:
            return None
        Gr = hr = xs = None
        if not ctrl.adapted:
            status, msg = NO_ADAPTATION, MSG_FIXED_REFERENCE[ctrl.cfg.mode]
        elif code == ck.FEASIBLE:
            if ctrl.keep_qp:                  # the instance is only handed out when kept
                Gr, hr, xs = self.reduced(G, h, res)
            status, msg = UNCONSTRAINED, MSG_X_STAR_FEASIBLE
        else:
            answer = self.solve_qp(G, h, res)
            if answer is None:
                return None
            x, status, msg, Gr, hr, xs = answer
            res[R_.x:R_.x + x.size] = x
            ck.finish(ctrl.cons, ctrl.memory, work, res, qd, t, stance)
        torque, wb = work[W_.torque].copy(), None
        if ctrl.whole_body is not None:       # modes wbc, hybrid: the whole-body stage
            if self.python_stage:
                torque, wb = self._whole_body(work, res, torque, status)
            else:
                torque, wb = self._whole_body_compiled(work, res, status, t)
        return ctrl._output(res, torque, t, stance, status, msg,
                            Gr.copy() if Gr is not None else None, hr, xs.copy() if xs is not None else None, wb)

    def _whole_body_compiled(self, work: np.ndarray, res: np.ndarray, status: int, t: float):
        """The compiled whole-body stage (``wbc_kernels.stage``) after the compiled period (which has
        committed its w to ``memory``): it writes the stage's status fields into ``res`` and, when it changes
        w, the torque, outputs and the memory's w; when its active-set iteration does not settle, the held
        PIQP of the Python stage answers (least violation when no w holds every row) and ``wbc_kernels.apply``
        takes that w. Returns (torque, False: the status fields are in ``res``)."""
        ctrl, wk = self.ctrl, self.wk
        run = ctrl.whole_body.mode == "wbc" or status in (INFEASIBLE_FALLBACK, SOLVER_ERROR)
        code = wk.stage(ctrl.wbc, ctrl.cons, ctrl.memory, work, res, self.Gw, self.hw, bool(run))
        if code == wk.SOLVED:
            self.stage_counts["solved"] += 1
        elif code == wk.NEEDS_PIQP:
            self.stage_counts["piqp"] += 1
            w_star = work[W_.w].copy()
            wb = ctrl.whole_body.qp.solve(self.Gw, self.hw, w_star)
            wk.apply(ctrl.cons, ctrl.memory, work, res, self.Gw, self.hw, w_star,
                     np.ascontiguousarray(wb.w, dtype=float), int(wb.status))
        elif code == wk.NONFINITE:      # non-finite rows: w* is kept (the Python stage's SOLVER_ERROR)
            res[R_.wbc_status] = SOLVER_ERROR
        return work[W_.torque].copy(), False

    def reduced(self, G: np.ndarray, h: np.ndarray, res: np.ndarray):
        """The QP over the adapted parameters of the rows G x <= h (x = (p'', tau''), modes lambda and all
        (p'', tau'', lambda'')) and x* of ``res``: a parameter that is not adapted stays at x* and moves to the
        right-hand side. Returns (G_r, h_r, x*_r)."""
        ctrl = self.ctrl
        xs_full = res[R_.x_star:R_.x_star + self.nx]
        idx, fixed = ctrl._adapted_idx, ctrl._fixed_idx
        Gr, xs = G[:, idx], xs_full[idx]
        hr = h - G[:, fixed] @ xs_full[fixed] if fixed else h.copy()
        return Gr, hr, xs

    def solve_qp(self, G: np.ndarray, h: np.ndarray, res: np.ndarray):
        """The period's decision when x* is not feasible (``controller_kernels.step`` returned NEEDS_QP with G,
        h and ``res``): the controller's QP on the adapted parameters. Returns (x (2,), status, message, G_r,
        h_r, x*_r), or None when the answer is not finite (the caller takes the reference path). Also the
        compiled loop's QP periods (``segment``): one home of the decision. Modes lambda and all: x (3,), and
        lambda'' held to the torso's range after an answer that does not hold the rows (as the Python steps)."""
        Gr, hr, xs = self.reduced(G, h, res)
        qres = self.ctrl.qp.solve(Gr, hr, xs)
        x = res[R_.x_star:R_.x_star + self.nx].copy()
        x[self.ctrl._adapted_idx] = qres.x
        if not np.all(np.isfinite(x)):
            return None
        msg = qres.message
        if qres.status not in (UNCONSTRAINED, ACTIVE):
            msg += self.ctrl._hold_ranges(x, res, (float(res[R_.lam]), float(res[R_.lam + 1]))
                                          if self.nx == 3 else None)
        return x, qres.status, msg, Gr, hr, xs

    def _whole_body(self, work: np.ndarray, res: np.ndarray, torque: np.ndarray, status: int):
        """The whole-body stage after the compiled period (which has committed its w to ``memory``): when it
        changes w, the torque, the reported margins, reaction, l and tightest row follow the new w, and the
        memory's w (the observer's next residual) is the new w. Returns (torque, WBCResult or None)."""
        ctrl = self.ctrl
        A, H, B = work[W_.A:W_.A + 6], work[W_.H], work[W_.B:W_.B + 3]
        hbc = res[R_.h_b_c:R_.h_b_c + 3]
        wb = ctrl.whole_body.decide(work[W_.w].copy(), status, A, H, B, res[R_.h_b:R_.h_b + 3], hbc)
        if wb is None or wb.status == UNCONSTRAINED:
            return torque, wb
        torque, R, margins, tightest, zmp = ctrl.whole_body.outputs(wb.w, A, H, B, hbc)
        res[RES.slice("margins")] = margins
        res[RES.slice("reaction")] = R
        res[R_.tightest], res[R_.zmp] = tightest, zmp
        ctrl.memory[MEMORY.slice("prev_w")] = wb.w
        return torque, wb
