"""The sensing pipeline on compiled kernels: the estimator, the momentum observer and the Smith
predictor of ``pipeline.SensingPipeline``, for the controller's compiled period.

Pure Python + NumPy around ``pipeline_kernels`` (numba), no ROS. One :class:`CompiledSensing` per
controller keeps its state in one array (``pipeline_layout.SENS``) that the kernels update in place; the
Python cores stay the oracle (tests: the same seeded noisy run period by period, to round-off). A sensed
touchdown (once a step) takes the model's flat-foot impact map in Python (``predictor.flat_foot_impact``,
the same function as the Python pipeline's); everything else is one compiled call a period. With a known
delay of d > 0 periods (``delay_compensation``) the bookkeeping of the delayed samples is the Python
pipeline's (which period's sample, the interval since the previous one and the torque applied over it, from
the log of the controller's decisions), the estimator and the observer run on the sample, and the predictor
(``pipeline_kernels.predict``: RK4 on the fixed-foot chain, the touchdown and its flat-foot impact map
compiled) takes it to the present through the last d decisions. The legs' model-error estimator
(``model_error``) runs inside the same compiled call, after the observer (``pipeline_kernels.sense_finish``
-> ``model_error_kernels.update``: its regressor in closed form, its state in ``SENS``'s ``me_*`` fields);
``use_model_error_kernel(False)`` runs ``model_error.LegModelError`` (Pinocchio) after the compiled call
instead, with the same inputs (the tests' oracle and the benchmark's "before").
"""
from __future__ import annotations

import math

import numpy as np

from biped_model import numba_cache
from biped_model.description import RobotDescription
from biped_model.fast_engine import fixed_foot_tree
from biped_model.floating import FloatingModel

from collections import deque

from biped_model.fixed_foot import relabel

from biped_controller.core.sensing.estimation import RELABEL
from biped_controller.core.sensing.pipeline import estimator_config
from biped_controller.core.sensing.pipeline_layout import N_LEG_PARAMETERS, N_TREE_BODIES, SCONF, SENS, SC_, S_
from biped_controller.core.sensing.model_error import (HOLD_VARIANCE, LEG_PARAMETERS, LegErrorEstimate, LegModelError,
                                                body_combination, load_model_error_kernels)
from biped_controller.core.sensing.momentum_observer import Wrench
from biped_controller.core.sensing.predictor import flat_foot_impact
from biped_controller.core.sensing.touchdown_band import (TouchdownBand, in_band, propagated_position_cov,
                                                  lever_bound, sigma_bound, sole_rate,
                                                  sole_height_std)

PIPELINE_KERNELS = "biped_controller.core.sensing.pipeline_kernels"
PIPELINE_KERNELS_SOURCES = ("biped_model.planar_abi", "biped_model.planar_kernels",
                              "biped_model.layout", "biped_controller.core.sensing.pipeline_layout",
                              "biped_controller.core.sensing.model_error_kernels")


def load_pipeline_kernels():
    """``pipeline_kernels`` through ``numba_cache.load`` (cache kept with its dependencies; the model-error
    kernels it calls loaded first through their own loader)."""
    load_model_error_kernels()
    return numba_cache.load(PIPELINE_KERNELS, sources=PIPELINE_KERNELS_SOURCES)


class SensingSingular(FloatingPointError):
    """A model matrix of the compiled pipeline was not positive definite (a non-finite state)."""


class KernelLegError:
    """The compiled pipeline's legs' model-error estimate, read from its state array (``SENS``'s ``me_*``
    fields): the attributes of ``model_error.LegModelError`` that callers read (theta, P, updates,
    estimate; copies; P0 the prior covariance)."""

    def __init__(self, state: np.ndarray, P0: np.ndarray):
        self._s = state
        self.P0 = P0

    @property
    def theta(self) -> np.ndarray:
        return self._s[SENS.slice("me_theta")].copy()

    @property
    def P(self) -> np.ndarray:
        return self._s[SENS.slice("me_P")].reshape(N_LEG_PARAMETERS, N_LEG_PARAMETERS).copy()

    @property
    def updates(self) -> int:
        return int(self._s[S_.me_flags + 2])

    @property
    def estimate(self) -> LegErrorEstimate:
        return LegErrorEstimate(theta=self.theta, P=self.P)


class CompiledSensing:
    """``SensingPipeline`` for delay 0 on ``pipeline_kernels``. ``cfg``: the ControllerConfig; ``ti``, ``tf``:
    the fixed-foot tree's arrays (``FastFixedFootModel``); ``qp_rows`` (5, 2): the QP's contact rows' (C_x,
    C_y); ``torque_min``, ``torque_max``: the limits [N m]."""

    def __init__(self, cfg, desc: RobotDescription, ti: np.ndarray, tf: np.ndarray, qp_rows: np.ndarray,
                 torque_min: np.ndarray, torque_max: np.ndarray):
        self.d = int(cfg.delay_compensation)
        self.at_once = bool(cfg.predictor_touchdown_at_once)
        self.ek = load_pipeline_kernels()
        self.cfg = cfg
        self.ti, self.tf = ti, tf
        est = estimator_config(cfg)
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
        c[SC_.var_pitch_rate] = est.sigma_pitch_rate ** 2 if math.isfinite(est.sigma_pitch_rate) else -1.0
        c[SC_.sigma_impact] = cfg.estimator_impact_std
        c[SC_.noise_qd] = cfg.sensor_noise_qd
        c[SC_.confidence] = cfg.estimate_confidence
        c[SCONF.slice("qp_rows")] = np.asarray(qp_rows, dtype=float).ravel()
        c[SCONF.slice("torque_min")] = torque_min
        c[SCONF.slice("torque_max")] = torque_max
        c[SC_.period] = cfg.period
        c[SC_.pred_substeps] = cfg.predictor_substeps
        c[SC_.pred_td_height] = cfg.predictor_touchdown_height
        # a touchdown reported at once is never predicted (DelayPredictor(touchdowns=False)): the kernel counts
        # a touchdown only once the swing sole has cleared this height, so an infinite one switches it off
        c[SC_.pred_clearance] = math.inf if self.at_once else cfg.predictor_clearance
        c[SC_.pred_t_tol] = cfg.predictor_time_tolerance
        self.me_on = bool(self.observer and cfg.model_error_estimator)
        if self.me_on:        # the legs' model-error estimator (model_error.py), run inside the kernel
            if len(LEG_PARAMETERS) != N_LEG_PARAMETERS or int(ti[1]) != N_TREE_BODIES:
                raise ValueError(f"pipeline_layout declares {N_LEG_PARAMETERS} leg parameters and {N_TREE_BODIES} "
                                 f"tree bodies; the model has {len(LEG_PARAMETERS)} and {int(ti[1])}")
            # the settings' checks and the prior: LegModelError's own (also the oracle path's estimator)
            self._me_py = LegModelError(desc, cfg.momentum_observer_gain, cfg.model_mass_uncertainty,
                                        cfg.model_inertia_uncertainty, cfg.model_error_residual_std,
                                        regressor_input=cfg.model_error_regressor, settle=cfg.model_error_settle)
            c[SC_.me_var_res] = self._me_py.var_res
            c[SC_.me_settle] = self._me_py.settle_time
            c[SC_.me_var_hold] = HOLD_VARIANCE
            c[SCONF.slice("me_P0")] = self._me_py.P0.ravel()
            c[SCONF.slice("me_D")] = body_combination(fixed_foot_tree(desc).bodies).ravel()
        self.conf = c
        self.band_k = float(cfg.touchdown_band_sigmas)
        self._lever = lever_bound(desc)
        self._conf_notd = c.copy()                # the predictor without touchdowns (the band's old hypothesis)
        self._conf_notd[SC_.pred_clearance] = math.inf
        self.band: TouchdownBand | None = None
        self.last_height: tuple | None = None     # (t, stance, z, sigma_z) of the last band check
        self.lo, self.hi = np.asarray(torque_min, dtype=float), np.asarray(torque_max, dtype=float)
        self.state = SENS.new()
        self.fm = FloatingModel(desc)
        self._q = np.empty(6)
        self._qd = np.empty(6)
        self._qp = np.empty(6)
        self._qdp = np.empty(6)
        self._pout = np.empty(2)
        self._hist = np.zeros((max(self.d, 1), 8))
        # the legs' model error (model_error.py): its combined estimate replaces the observer's dR, F_x and the
        # rows' widening in what the compiled period reads; in the kernel (the measured regressor, default), or in
        # Python after it (the reference regressor: the controller's reference at the sample, Python)
        self.me = None
        self._me_python = False
        #: (t [s], stance) -> the controller's (q_d, q_d', q_d'') at t (``AdaptiveController.reference_at``);
        #: set by the controller when the model-error estimator's regressor is fed the reference
        self.reference_source = None
        self._me_wrench: Wrench | None = None
        self._qp_rows = np.asarray(qp_rows, dtype=float).reshape(5, 2)
        self.use_model_error_kernel(self.me_on and cfg.model_error_regressor == "measured")

    def use_model_error_kernel(self, kernel: bool) -> None:
        """Where the legs' model-error estimator runs (when it is on): ``kernel`` True inside the compiled call
        (``SCONF.me`` 1; ``me`` reads its state; the measured regressor only), False as
        ``model_error.LegModelError`` (Pinocchio's regressor) after it, with the same inputs (the reference
        regressor's path, the oracle of the tests, the benchmark's "before"). Resets the pipeline."""
        if self.me_on and kernel and self.cfg.model_error_regressor != "measured":
            raise ValueError("the compiled model-error estimator evaluates the measured regressor only "
                             f"(model_error_regressor {self.cfg.model_error_regressor!r}: use the Python one)")
        if self.me_on:
            self.conf[SC_.me] = 1.0 if kernel else 0.0
            self.me = KernelLegError(self.state, self._me_py.P0.copy()) if kernel else self._me_py
        self._me_python = self.me_on and not kernel       # the estimator runs in Python after the compiled call
        self.reset()

    def reset(self) -> None:
        s = self.state
        s[:] = 0.0
        s[SENS.slice("P")] = np.eye(12).ravel()   # as JointStateEstimator.__init__ (overwritten at the first sample)
        s[S_.pred_sample_stance] = -1.0
        self.k = 0                                # periods decided since the reset
        self.log: deque = deque(maxlen=self.d + 2)   # (t, torque sent, told stance) of the last decisions
        self._j = None                            # the period of the last sample used (delay > 0)
        self._stance = None                       # its stance
        self._seg = 0                             # the period whose sample first showed the current stance
        if self.me_on:
            self._me_py.reset()
            self._me_wrench = None
            s[SENS.slice("me_P")] = self.conf[SCONF.slice("me_P0")]

    def sense(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int, pitch: float = math.nan,
              pitch_rate: float = math.nan):
        """The period's sample (the IMU's ``pitch`` [rad] and gyro ``pitch_rate`` [rad/s]: NaN when absent) ->
        (q, q', stance) the controller acts on (views of arrays this object reuses: copy to keep)."""
        pitch_rate = float(pitch_rate)
        if self.d > 0:
            return self._sense_delayed(float(t), q, qd, int(stance), float(pitch), pitch_rate)
        ek, s = self.ek, self.state
        pre = self._before() if self._me_python else None
        code = ek.sense(self.ti, self.tf, self.conf, s, float(t), q, qd, int(stance), float(pitch), pitch_rate,
                        self._q, self._qd)
        if code == ek.NEEDS_IMPACT:
            self._impact()
            code = ek.sense_finish(self.ti, self.tf, self.conf, s, float(t), q, qd, int(stance), float(pitch),
                                   pitch_rate, self._q, self._qd)
        if code != ek.DONE:
            raise SensingSingular("the compiled sensing pipeline met a singular model matrix")
        if pre is not None:
            self._model_error(float(t), int(stance), pre)
        return self._q, self._qd, int(stance)

    def _before(self) -> tuple:
        """What the model-error estimator needs of the state before the kernel's sample: (first sample,
        a decision was recorded, its time, torque sent, told stance, the state's stance at the last sample)."""
        s = self.state
        return (s[S_.started] == 0.0, s[S_.decided] != 0.0, float(s[S_.t_prev]),
                s[S_.torque_prev:S_.torque_prev + 6].copy(), int(s[S_.told_prev]), int(s[S_.stance]))

    def _model_error(self, t_s: float, stance: int, pre: tuple) -> None:
        """The legs' model error in Python (``use_model_error_kernel(False)``) on the sample the compiled
        observer has just taken (``model_error``, the Python pipeline's call with the same inputs: the interval
        and the torque applied over it as ``pipeline_kernels._elapsed_applied``, the restart as the
        kernel's). The kernel's ``_model_error`` takes the same inputs."""
        s = self.state
        first, decided, t_prev, torque_prev, told_prev, stance_prev = pre
        restarted = bool(s[S_.since] == 0.0)
        applied, dt = None, 0.0
        if not restarted and not first and decided:
            dt = (round(t_s * 1e9) - round(t_prev * 1e9)) * 1e-9
            g = np.clip(torque_prev, self.lo, self.hi)
            applied = g if told_prev == stance_prev else relabel(g)
        obs = self._observer_wrench()
        q = self._q.copy()
        J = self.me.model.torso_point_jacobian(q, self.cfg.observer_height)
        Jj = np.vstack([J[:, 3:], np.ones((1, 6)) * np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])])
        if self.estimator:
            cov = s[SENS.slice("P")].reshape(12, 12)[6:, 6:].copy()
        else:
            cov = self.cfg.sensor_noise_qd ** 2 * np.eye(6)
        ref = self.reference_source(t_s, stance) if self.reference_source is not None else None
        self._me_wrench = self.me.update(q, self._qd.copy(), applied, restarted, dt, obs,
                                         s[SENS.slice("W_restart")].copy(), float(s[S_.since]), Jj, cov, ref)

    def _decision(self, j: int):
        return self.log[j - (self.k - len(self.log))]

    def _sense_delayed(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int, pitch: float,
                       pitch_rate: float = math.nan):
        """Delay d > 0 (``SensingPipeline.process``): the sample is that of period j = max(k - d, 0), taken at
        the instant of the controller's decision j; a new one goes through the estimator and the observer
        (the interval since the previous sample and the torque applied over it from the log), then the
        predictor takes the sample's state to t through the last k - j decisions. With
        ``predictor_touchdown_at_once`` a sample whose stance differs from the last one used is of this
        period, j = max(k - d, that period) after it (``SensingPipeline.sample_period``)."""
        ek, s = self.ek, self.state
        if self.at_once and self._stance is not None and stance != self._stance:
            self._seg = self.k
        j = max(self.k - self.d, self._seg if self.at_once else 0)
        new = self._j is None or j > self._j
        if new:
            t_s = t
            if self._j is not None:
                t_prev, tau_prev, told_prev = self._decision(self._j)
                t_s = t if j == self.k else self._decision(j)[0]
                s[S_.t_prev] = t_prev
                s[S_.torque_prev:S_.torque_prev + 6] = tau_prev
                s[S_.told_prev] = told_prev
                s[S_.decided] = 1.0
            pre = self._before() if self._me_python else None
            code = ek.sense(self.ti, self.tf, self.conf, s, t_s, q, qd, stance, pitch, pitch_rate, self._q, self._qd)
            if code == ek.NEEDS_IMPACT:
                self._impact()
                code = ek.sense_finish(self.ti, self.tf, self.conf, s, t_s, q, qd, stance, pitch, pitch_rate,
                                       self._q, self._qd)
            if code != ek.DONE:
                raise SensingSingular("the compiled sensing pipeline met a singular model matrix")
            if pre is not None:
                self._model_error(t_s, stance, pre)
            self._j = j
            self._stance = stance
        elif self.estimator:
            self._q[:], self._qd[:] = s[S_.x:S_.x + 6], s[S_.x + 6:S_.x + 12]
        else:
            self._q[:], self._qd[:] = q, qd
        n = self.k - j                            # the sample's age: the decisions since it (<= d)
        for i in range(n):
            tt, tau, told = self.log[len(self.log) - n + i]
            self._hist[i, 0], self._hist[i, 1], self._hist[i, 2:] = tt, told, tau
        code = ek.predict(self.ti, self.tf, self.conf, s, self._hist, n, t, self._q, self._qd, stance,
                          self._qp, self._qdp, self._pout)
        if code != ek.DONE:
            raise SensingSingular("the compiled predictor met a singular model matrix")
        self.band = None
        if self.estimator and not self.at_once and self.band_k > 0 and s[S_.pred_cleared] != 0.0:
            self.band = self._band(t, j, n, stance)
        return self._qp, self._qdp, int(self._pout[0])

    def _band(self, t: float, j: int, n: int, stance: int) -> TouchdownBand | None:
        """``SensingPipeline._band`` on the compiled predictor: the prediction without a touchdown (the
        predictor's own when it predicted none; otherwise redone with the cleared flag cleared for the call
        and the clearance infinite), its sole height, whether it descends, its spread."""
        ek, s = self.ek, self.state
        if int(self._pout[1]) == 0:
            q0, qd0 = self._qp.copy(), self._qdp.copy()
        else:
            cleared = s[S_.pred_cleared]
            s[S_.pred_cleared] = 0.0
            q0, qd0, out0 = np.empty(6), np.empty(6), np.empty(2)
            try:
                code = ek.predict(self.ti, self.tf, self._conf_notd, s, self._hist, n, t, self._q, self._qd,
                                  stance, q0, qd0, out0)
            finally:
                s[S_.pred_cleared] = cleared
            if code != ek.DONE:
                raise SensingSingular("the compiled predictor met a singular model matrix")
        sole = lambda qq: float(ek.lowest_sole(self.ti, self.tf, np.ascontiguousarray(qq)))   # noqa: E731
        t_j = t if j == self.k else self._decision(j)[0]
        Pqq = propagated_position_cov(s[SENS.slice("P")].reshape(12, 12), t - t_j, self.cfg.estimator_accel_std)
        z = sole(q0)
        if z > self.band_k * sigma_bound(self._lever, Pqq) or sole_rate(sole, q0, qd0) >= 0.0:
            return None
        sz = sole_height_std(sole, q0, Pqq)
        self.last_height = (t, int(stance), z, sz)        # the band's inputs this period (diagnostics)
        if not in_band(z, sz, self.band_k):
            return None
        if int(self._pout[1]) > 0:
            qn, qdn, sn = self._qp.copy(), self._qdp.copy(), int(self._pout[0])
        else:
            qn, qdn = np.empty(6), np.empty(6)
            if not ek.flat_foot_impact(self.ti, self.tf, q0, qd0, qn, qdn):
                raise SensingSingular("the compiled impact map met a singular model matrix")
            sn = 1 - stance
        return TouchdownBand(z=z, sigma_z=sz, q_old=q0, qd_old=qd0, stance_old=int(stance), q_new=qn, qd_new=qdn,
                             stance_new=int(sn))

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
        w = self._me_wrench if self._me_python else None
        if w is not None:           # the legs' model error: the combined estimate (controller._observe_momentum)
            C = self._qp_rows
            out[0], out[1], out[2] = w.dR[0], w.dR[1], w.W[0]
            var = np.einsum("ij,jk,ik->i", C, w.cov_dR, C)
            out[3:8] = self.cfg.estimate_confidence * np.sqrt(np.maximum(var, 0.0))

    def record(self, t: float, torque_sent: np.ndarray, told: int) -> None:
        """The decision of this period: the torque sent, in the paper order of the told stance."""
        if self.d > 0:
            self.log.append((float(t), np.array(torque_sent, dtype=float), int(told)))
            self.k += 1
            return
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
        no sample yet); with the model-error estimator, the combined one (``model_error``)."""
        if self._me_python and self._me_wrench is not None:
            return self._me_wrench
        s = self.state
        if self.me_on and not self._me_python and s[S_.mo_started] != 0.0 and s[S_.me_flags] != 0.0:
            g = lambda name: s[SENS.slice(name)].copy()   # noqa: E731
            return Wrench(r=g("r"), W=g("me_W"), cov_W=g("me_cov_W").reshape(3, 3), dR=g("me_dR"),
                          cov_dR=g("me_cov_dR").reshape(2, 2), S=g("S").reshape(2, 3))
        return self._observer_wrench()

    def _observer_wrench(self) -> Wrench | None:
        """The compiled observer's own estimate (its state array) as a ``Wrench``."""
        s = self.state
        if not self.observer or s[S_.mo_started] == 0.0:
            return None
        g = lambda name: s[SENS.slice(name)].copy()   # noqa: E731
        return Wrench(r=g("r"), W=g("W"), cov_W=g("cov_W").reshape(3, 3), dR=g("dR"),
                      cov_dR=g("cov_dR").reshape(2, 2), S=g("S").reshape(2, 3))
