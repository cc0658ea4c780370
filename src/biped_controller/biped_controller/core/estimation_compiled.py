"""The sensing pipeline on compiled kernels (issue 22): the estimator and the momentum observer of
``sensing.SensingPipeline`` without a delay, for the controller's compiled period.

Pure Python + NumPy around ``estimation_kernels`` (numba), no ROS. One :class:`CompiledSensing` per
controller keeps its state in one array (``estimation_layout.SENS``) that the kernels update in place; the
Python cores stay the oracle (tests: the same seeded noisy run period by period, to round-off). A sensed
touchdown (once a step) takes the model's flat-foot impact map in Python (``predictor.flat_foot_impact``,
the same function as the Python pipeline's); everything else is one compiled call a period. The Smith
predictor (``delay_compensation`` > 0) is not compiled: the controller keeps the Python pipeline then.
"""
from __future__ import annotations

import math

import numpy as np

from biped_sim.robot import numba_cache
from biped_sim.robot.description import RobotDescription
from biped_sim.robot.floating import FloatingModel

from biped_controller.core.estimation import RELABEL, EstimatorConfig
from biped_controller.core.estimation_layout import SCONF, SENS, SC_, S_
from biped_controller.core.momentum_observer import Wrench
from biped_controller.core.predictor import flat_foot_impact

ESTIMATION_KERNELS = "biped_controller.core.estimation_kernels"
ESTIMATION_KERNELS_SOURCES = ("biped_sim.robot.planar_abi", "biped_sim.robot.planar_kernels",
                              "biped_sim.robot.layout", "biped_controller.core.estimation_layout")


def load_estimation_kernels():
    """``estimation_kernels`` through ``numba_cache.load`` (cache kept with its dependencies)."""
    return numba_cache.load(ESTIMATION_KERNELS, sources=ESTIMATION_KERNELS_SOURCES)


class SensingSingular(FloatingPointError):
    """A model matrix of the compiled pipeline was not positive definite (a non-finite state)."""


class CompiledSensing:
    """``SensingPipeline`` for delay 0 on ``estimation_kernels``. ``cfg``: the ControllerConfig; ``ti``, ``tf``:
    the fixed-foot tree's arrays (``FastFixedFootModel``); ``qp_rows`` (5, 2): the QP's contact rows' (C_x,
    C_y); ``torque_min``, ``torque_max``: the limits [N m]."""

    def __init__(self, cfg, desc: RobotDescription, ti: np.ndarray, tf: np.ndarray, qp_rows: np.ndarray,
                 torque_min: np.ndarray, torque_max: np.ndarray):
        if int(cfg.delay_compensation) != 0:
            raise ValueError("delay_compensation: the compiled pipeline has no predictor (use SensingPipeline)")
        self.ek = load_estimation_kernels()
        self.cfg = cfg
        self.ti, self.tf = ti, tf
        est = EstimatorConfig(sigma_q=cfg.sensor_noise_q, encoder_bits=int(cfg.sensor_encoder_bits),
                              sigma_qd=cfg.sensor_noise_qd, sigma_pitch=cfg.sensor_noise_pitch,
                              sigma_acc=cfg.estimator_accel_std, sigma_impact=cfg.estimator_impact_std)
        self.est_cfg = est
        self.estimator = bool(cfg.state_estimator)
        self.observer = bool(cfg.disturbance_observer and cfg.momentum_observer)
        if self.estimator:
            est.validate()
        c = SCONF.new()
        c[SC_.estimator] = float(self.estimator)
        c[SC_.observer] = float(self.observer)
        c[SC_.K] = cfg.momentum_observer_gain
        c[SC_.height] = cfg.observer_height
        c[SC_.sigma_acc] = cfg.estimator_accel_std
        c[SC_.var_q] = est.var_q
        c[SC_.var_qd] = est.sigma_qd ** 2 if math.isfinite(est.sigma_qd) else -1.0
        c[SC_.var_pitch] = est.sigma_pitch ** 2 if math.isfinite(est.sigma_pitch) else -1.0
        c[SC_.sigma_impact] = cfg.estimator_impact_std
        c[SC_.noise_qd] = cfg.sensor_noise_qd
        c[SC_.confidence] = cfg.estimate_confidence
        c[SCONF.slice("qp_rows")] = np.asarray(qp_rows, dtype=float).ravel()
        c[SCONF.slice("torque_min")] = torque_min
        c[SCONF.slice("torque_max")] = torque_max
        self.conf = c
        self.state = SENS.new()
        self.fm = FloatingModel(desc)
        self._q = np.empty(6)
        self._qd = np.empty(6)
        self.reset()

    def reset(self) -> None:
        s = self.state
        s[:] = 0.0
        s[SENS.slice("P")] = np.eye(12).ravel()   # as JointStateEstimator.__init__ (overwritten at the first sample)

    def sense(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int, pitch: float = math.nan):
        """The period's sample -> (q, q', stance) the controller acts on (views of arrays this object
        reuses: copy to keep)."""
        ek, s = self.ek, self.state
        code = ek.sense(self.ti, self.tf, self.conf, s, float(t), q, qd, int(stance), float(pitch), self._q, self._qd)
        if code == ek.NEEDS_IMPACT:
            self._impact()
            code = ek.sense_finish(self.ti, self.tf, self.conf, s, float(t), q, qd, int(stance), float(pitch),
                                   self._q, self._qd)
        if code != ek.DONE:
            raise SensingSingular("the compiled sensing pipeline met a singular model matrix")
        return self._q, self._qd, int(stance)

    def _impact(self) -> None:
        """The sensed touchdown on the time-updated estimate (``estimation.JointStateEstimator.relabel_impact``
        after ``predictor.flat_foot_impact``, as ``SensingPipeline.process``)."""
        s = self.state
        x = s[SENS.slice("x")]
        P = s[SENS.slice("P")].reshape(12, 12)
        qn, qdn = flat_foot_impact(self.fm, x[:6].copy(), x[6:].copy(), int(s[S_.stance]))
        x[:6], x[6:] = qn, qdn
        Pn = RELABEL @ P @ RELABEL.T
        Pn[6:, 6:] += self.cfg.estimator_impact_std ** 2 * np.eye(6)
        P[:, :] = Pn

    def into_res(self, out: np.ndarray) -> None:
        """out (8,) <- [dR (2) [N], F_x [N], the five contact rows' widening [N]] (the controller's RES.sens_*)."""
        self.ek.into_res(self.state, self.conf, out)

    def record(self, t: float, torque_sent: np.ndarray, told: int) -> None:
        """The decision of this period: the torque sent, in the paper order of the told stance."""
        s = self.state
        s[S_.t_prev] = t
        s[S_.torque_prev:S_.torque_prev + 6] = torque_sent
        s[S_.told_prev] = told
        s[S_.decided] = 1.0

    @property
    def P(self) -> np.ndarray | None:
        """The estimate's covariance (12 x 12; None without the estimator)."""
        return self.state[SENS.slice("P")].reshape(12, 12).copy() if self.estimator else None

    @property
    def wrench(self) -> Wrench | None:
        """The momentum observer's last estimate as the Python observer's ``Wrench`` (None: observer off or
        no sample yet)."""
        s = self.state
        if not self.observer or s[S_.mo_started] == 0.0:
            return None
        g = lambda name: s[SENS.slice(name)].copy()   # noqa: E731
        return Wrench(r=g("r"), W=g("W"), cov_W=g("cov_W").reshape(3, 3), dR=g("dR"),
                      cov_dR=g("cov_dR").reshape(2, 2), S=g("S").reshape(2, 3))
