"""The adaptive controller's settings: the modes (``MODES``, the parameters each adapts), :class:`ControllerConfig`
with its checks (``validate``: one :class:`ControllerConfigError` naming the bad setting), and
:func:`load_controller_config` (``config/controller.yaml``; the control period [s] and the engine from
``config/simulator.yaml``, ``biped_model.loop``). Pure Python, no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from biped_model.finite import finite_number
from biped_model.loop import ENGINES, load_loop_settings
from biped_model.settings import SettingsError, default_config_dir, read_settings
from biped_controller.core.control.wbc import weight_matrix
from biped_controller.core.qp.solver import SOLVERS as QP_SOLVERS

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
