"""The controller's view of the robot from real sensing: estimator, momentum observer and delay
predictor in one per-period pipeline. Pure NumPy + Pinocchio, no ROS.

Per control period k the controller receives a sample (stance, q, q' [, IMU pitch]); with a known delay
of d periods (``delay_compensation``) it is the sample of period k - d, taken at the instant t_{k-d} of
the controller's own decision of that period (the first sample while k < d). With a touchdown reported at
once (``predictor_touchdown_at_once``, the plant's ``touchdown_delayed`` False) the sample is that of period
j = max(k - d, s), s the period whose sample first showed the current stance (a sample whose stance differs
from the last one used is of the period it arrives in): the sensor model's rule, so a touchdown sensed while
the predictor still runs from an old-stance sample replaces that prediction at once. The pipeline:

 1. a new sample (period j = max(k - d, 0), or as above, > the last one used): the estimator's time update over
    [t_{j-1}, t_j) with the model's acceleration under the torque applied then, a = A^-1 (Gamma - H + r)
    (r: the momentum observer's disturbance; Gamma clipped to the limits and relabelled if it was sent
    for the other stance); if the sample's stance differs from the estimate's, the model's flat-foot
    impact at t_j; then the measurement update (``estimation.JointStateEstimator``). Without the
    estimator the sample itself is the state.
 2. the momentum observer on that state (``momentum_observer.MomentumObserver``), its velocity covariance
    from the estimator (or the sensor's rate noise without one).
 3. with d > 0 the Smith predictor from the sample's state to t_k (``predictor.DelayPredictor``), through
    the k - j torques sent since; a predicted touchdown changes the stance the controller acts in.

The controller then decides in the predicted stance and sends its torque in the paper order of the stance
it was told (relabelled when the two differ: the plant maps it to the motors with the told stance), and
records it here (:meth:`SensingPipeline.record`).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from biped_model.description import RobotDescription
from biped_model.fixed_foot import FixedFootModel, relabel
from biped_model.floating import FloatingModel

from biped_controller.core.sensing.estimation import EstimatorConfig, JointStateEstimator
from biped_controller.core.sensing.model_error import LegModelError
from biped_controller.core.sensing.momentum_observer import MomentumObserver, Wrench
from biped_controller.core.sensing.predictor import DelayPredictor, flat_foot_impact
from biped_controller.core.sensing.touchdown_band import (TouchdownBand, in_band, propagated_position_cov,
                                                  lever_bound, sigma_bound, sole_rate,
                                                  sole_height_std)


def estimator_config(cfg) -> EstimatorConfig:
    """The estimator's sensors and noise from the controller's settings ``cfg`` (a ControllerConfig): the gyro
    (``sensor_noise_pitch_rate``) only with ``estimator_gyro`` on (off: sigma = inf, not fused)."""
    return EstimatorConfig(sigma_q=cfg.sensor_noise_q, encoder_bits=int(cfg.sensor_encoder_bits),
                           sigma_qd=cfg.sensor_noise_qd, sigma_pitch=cfg.sensor_noise_pitch,
                           sigma_acc=cfg.estimator_accel_std, sigma_impact=cfg.estimator_impact_std,
                           sigma_pitch_rate=cfg.sensor_noise_pitch_rate if cfg.estimator_gyro else math.inf)


@dataclass(frozen=True)
class View:
    """What the controller acts on this period: paper (q, q') of ``stance`` at t_k, the wrench estimate
    (None without the momentum observer) and the estimate's covariance at the sample (None without the
    estimator)."""

    q: np.ndarray
    qd: np.ndarray
    stance: int
    wrench: Wrench | None
    P: np.ndarray | None


class SensingPipeline:
    """The pipeline of the module docstring for one controller (its settings ``cfg``: a ControllerConfig)."""

    def __init__(self, cfg, desc: RobotDescription):
        self.cfg = cfg
        self.d = int(cfg.delay_compensation)
        self.at_once = bool(cfg.predictor_touchdown_at_once)
        self.model = FixedFootModel(desc)
        self.fm = FloatingModel(desc)
        lo, hi = desc.torque_limits()
        self.lo, self.hi = np.array(lo, dtype=float), np.array(hi, dtype=float)
        self.est_cfg = estimator_config(cfg)
        self.est = JointStateEstimator(self.est_cfg) if cfg.state_estimator else None
        self.mo = (MomentumObserver(desc, cfg.momentum_observer_gain, cfg.observer_height)
                   if cfg.disturbance_observer and cfg.momentum_observer else None)
        self.me = (LegModelError(desc, cfg.momentum_observer_gain, cfg.model_mass_uncertainty,
                                 cfg.model_inertia_uncertainty, cfg.model_error_residual_std,
                                 regressor_input=cfg.model_error_regressor, settle=cfg.model_error_settle)
                   if self.mo is not None and cfg.model_error_estimator else None)
        self.band_k = float(cfg.touchdown_band_sigmas)
        self._lever = lever_bound(desc)
        #: (t [s], stance) -> the controller's (q_d, q_d', q_d'') at t (``AdaptiveController.reference_at``);
        #: set by the controller when the model-error estimator's regressor is fed the reference
        self.reference_source = None
        self.pred = (DelayPredictor(desc, self.d, int(cfg.predictor_substeps), cfg.period,
                                    cfg.predictor_touchdown_height, cfg.predictor_clearance,
                                    cfg.predictor_time_tolerance, touchdowns=not self.at_once)
                     if self.d > 0 else None)
        self.reset()

    def reset(self) -> None:
        self.k = 0
        self.log: deque[tuple[float, np.ndarray, int]] = deque(maxlen=self.d + 2)
        self._j: int | None = None            # the period of the last sample used
        self._stance: int | None = None       # the stance of the state at the last sample
        self._seg = 0                         # the period whose sample first showed the current stance
        self._r = np.zeros(6)
        self.wrench: Wrench | None = None
        self.band: TouchdownBand | None = None     # the period's touchdown band (touchdown_band.py), or None
        if self.est is not None:
            self.est.__init__(self.est_cfg)
        if self.mo is not None:
            self.mo.reset()
        if self.me is not None:
            self.me.reset()
        if self.pred is not None:
            self.pred.reset()

    def _decision(self, j: int) -> tuple[float, np.ndarray, int]:
        """The recorded decision of period j (< k)."""
        return self.log[j - (self.k - len(self.log))]

    def _applied(self, torque: np.ndarray, told: int, stance: int) -> np.ndarray:
        g = np.clip(torque, self.lo, self.hi)
        return g if told == stance else relabel(g)

    def sample_period(self, stance: int) -> int:
        """The period j whose sample arrives now, with ``stance`` (module docstring)."""
        if self.at_once and self._stance is not None and stance != self._stance:
            self._seg = self.k            # a touchdown reported at once: a fresh sample
        return max(self.k - self.d, self._seg if self.at_once else 0)

    def process(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int, pitch: float = math.nan,
                pitch_rate: float = math.nan) -> View:
        j = self.sample_period(stance)
        new = self._j is None or j > self._j
        P = None
        if new and self._j is not None:
            t_prev, tau_prev, told_prev = self._decision(self._j)
            t_s = t if j == self.k else self._decision(j)[0]
            dt = (round(t_s * 1e9) - round(t_prev * 1e9)) * 1e-9
            applied = self._applied(tau_prev, told_prev, self._stance)
        else:
            dt, applied = 0.0, None
        # 1. the estimator
        if self.est is not None:
            if self._j is None:
                e = self.est.reset(q, qd)
            elif new:
                qe, qde = self.est.x[:6], self.est.x[6:]
                dyn = self.model.dynamics(qe, qde)
                acc = np.linalg.solve(dyn.A, applied - dyn.H + self._r)
                self.est.predict(dt, acc)
                if stance != self._stance:
                    qn, qdn = flat_foot_impact(self.fm, self.est.x[:6], self.est.x[6:], self._stance)
                    self.est.relabel_impact(qn, qdn)
                e = self.est.update(q, qd, pitch, pitch_rate)
            else:
                e = self.est.estimate()
            qs, qds, P = e.q, e.qd, e.P
        else:
            qs, qds = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        # 2. the momentum observer
        if self.mo is not None and new:
            cov = P[6:, 6:] if P is not None else self.cfg.sensor_noise_qd ** 2 * np.eye(6)
            torque = applied if (applied is not None and stance == self._stance) else None
            self.wrench = self.mo.update(qs, qds, stance, torque, dt, cov)
            if self.me is not None:     # the legs' model error (model_error.py): the torso wrench and dR
                mo = self.mo
                t_s = t if (self._j is None or j == self.k) else self._decision(j)[0]    # the sample's instant
                ref = self.reference_source(t_s, stance) if self.reference_source is not None else None
                self.wrench = self.me.update(qs, qds, torque, mo._since == 0.0, dt, self.wrench, mo._W_restart,
                                             mo._since, mo.terms.wrench_jacobian(qs, mo.height)[:, 3:], cov, ref)
            self._r = self.wrench.r
        if new:
            self._j = j
            self._stance = stance
        # 3. the predictor
        self.band = None
        if self.pred is not None:
            pr = self.pred.predict(t, qs, qds, stance, self.k - j)
            qc, qdc, sc = pr.q, pr.qd, pr.stance
            if P is not None and not self.at_once and self.pred._cleared and self.band_k > 0:
                self.band = self._band(t, j, qs, qds, stance, P, pr)
        else:
            qc, qdc, sc = qs, qds, stance
        return View(q=qc, qd=qdc, stance=sc, wrench=self.wrench, P=P)

    def _band(self, t: float, j: int, qs, qds, stance: int, P: np.ndarray, pr) -> TouchdownBand | None:
        """The touchdown band of ``touchdown_band`` at t_k for the sample (qs, qds, stance) of period j and its
        covariance P, beside the predictor's answer ``pr``: None outside the band."""
        pred = self.pred
        if pr.touchdowns == 0:
            p0 = pr
        else:
            pred.touchdowns = False                # the old stance's hypothesis: no touchdown predicted
            try:
                p0 = pred.predict(t, qs, qds, stance, self.k - j)
            finally:
                pred.touchdowns = True
        t_j = t if j == self.k else self._decision(j)[0]
        Pqq = propagated_position_cov(P, t - t_j, self.est_cfg.sigma_acc)
        z = pred.lowest_sole(p0.q)
        if z > self.band_k * sigma_bound(self._lever, Pqq) or sole_rate(pred.lowest_sole, p0.q, p0.qd) >= 0.0:
            return None
        sz = sole_height_std(pred.lowest_sole, p0.q, Pqq)
        if not in_band(z, sz, self.band_k):
            return None
        if pr.touchdowns > 0:
            qn, qdn, sn = pr.q, pr.qd, pr.stance
        else:
            qn, qdn = pred.impact(p0.q, p0.qd, stance)
            sn = 1 - stance
        return TouchdownBand(z=z, sigma_z=sz, q_old=p0.q, qd_old=p0.qd, stance_old=int(stance),
                             q_new=np.asarray(qn), qd_new=np.asarray(qdn), stance_new=int(sn))

    def sense(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int, pitch: float = math.nan,
              pitch_rate: float = math.nan):
        """:meth:`process`'s (q, q', stance) (the controller's one call, as ``CompiledSensing.sense``)."""
        v = self.process(t, q, qd, stance, pitch, pitch_rate)
        return v.q, v.qd, v.stance

    def record(self, t: float, torque_sent: np.ndarray, told: int) -> None:
        """The decision of this period: the torque sent, in the paper order of the told stance."""
        self.log.append((float(t), np.array(torque_sent, dtype=float), int(told)))
        if self.pred is not None:
            self.pred.record(t, torque_sent, told)
        self.k += 1
