"""Joint state estimation from encoders, a rate sensor and a torso pitch IMU. Pure NumPy, no ROS.

A Kalman filter on the joint state x = (q, q') (paper order q1..q6 [rad], q1'..q6' [rad/s]) whose time
update is the controller's model driven by the torque it applied, not a difference of measurements:

  time update over an interval dt with the model's joint acceleration a (held over the interval)
      q  <- q + q' dt + a dt^2 / 2,   q' <- q' + a dt,          F = [[I, dt I], [0, I]]
      P  <- F P F^T + Q,   Q = sigma_a^2 [[dt^4/4 I, dt^3/2 I], [dt^3/2 I, dt^2 I]]
  (piecewise-constant white acceleration noise sigma_a [rad/s^2]: what the model does not predict over
  one interval: the gait's jerk over a period, an unmodelled force until the momentum observer sees it);
  a = A(q)^-1 (Gamma - H(q, q') + r) is computed by the caller (``pipeline.SensingPipeline``) from the
  applied torque Gamma and the momentum observer's disturbance r.

  measurement update with z = (q_enc, q'_rate [, theta_imu] [, omega_gyro]),
      H = [[I, 0], [0, I] [, [1 1 1 0 0 0 | 0]] [, [0 | 1 1 1 0 0 0]]]
      R = diag(sigma_q^2 + Delta^2 / 12 (6x), sigma_qd^2 (6x) [, sigma_pitch^2] [, sigma_pitch_rate^2])
  where Delta = 2 pi / 2^bits is the encoder step (quantisation as uniform noise of variance Delta^2/12)
  and the IMU measures the torso pitch theta = q1 + q2 + q3 with the stance foot flat (counter-clockwise
  positive), its gyro the torso's pitch rate omega = theta' = q1' + q2' + q3' (same frame and sign; the
  stance foot flat and at rest). A non-finite or zero-weight sensor is left out (sigma = inf).

  touchdown (the measured stance changes): the flat-foot impact of the controller's model is applied to
  the estimate (``relabel_impact``): q -> relabel(q with the landing ankle laid flat), q' -> the impact
  map, P -> the relabelled P plus sigma_impact^2 on the rates (the impact map's error).

The filter is linear (F, H constant), so its covariance P is exact for a linear-Gaussian world; with the
quantisation's uniform error and a model error it is the filter's own statement of its uncertainty, which
the tests check against the true error (normalised errors under seeded noise).
Bandwidth: with positions only, the steady-state filter is a second-order tracker of natural frequency
about (sigma_a / sigma_q)^(1/2) [rad/s] (``bandwidth``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from biped_model.finite import finite_number

N = 6


class EstimatorConfigError(ValueError):
    """A setting of the estimator is invalid (the message names it)."""


@dataclass(frozen=True)
class EstimatorConfig:
    """The sensors the estimator assumes and its process noise (values: ``config/controller.yaml``)."""

    sigma_q: float          # [rad] encoder noise std (without the quantisation)
    encoder_bits: int       # [bits per turn] encoder resolution; 0: no quantisation
    sigma_qd: float         # [rad/s] rate sensor noise std; inf: no rate sensor
    sigma_pitch: float      # [rad] IMU torso pitch noise std; inf: no IMU
    sigma_acc: float        # [rad/s^2] white acceleration process noise std
    sigma_impact: float     # [rad/s] std added to each rate at a touchdown (impact map error)
    sigma_pitch_rate: float = math.inf   # [rad/s] IMU gyro pitch-rate noise std; inf: the gyro is not fused

    def validate(self) -> "EstimatorConfig":
        for name in ("sigma_q", "sigma_qd", "sigma_pitch", "sigma_acc", "sigma_impact", "sigma_pitch_rate"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or v < 0:
                raise EstimatorConfigError(f"{name} must be a number >= 0 (inf: sensor absent), got {v!r}")
        if isinstance(self.encoder_bits, bool) or not isinstance(self.encoder_bits, int) \
                or not 0 <= self.encoder_bits <= 52:
            raise EstimatorConfigError(f"encoder_bits must be an integer in [0, 52], got {self.encoder_bits!r}")
        if not self.sigma_acc > 0:
            raise EstimatorConfigError(f"sigma_acc must be > 0, got {self.sigma_acc!r}")
        if self.var_q <= 0:
            raise EstimatorConfigError("sigma_q and encoder_bits: an encoder with zero variance cannot be "
                                       "weighed (give sigma_q > 0 or encoder_bits > 0)")
        return self

    @property
    def encoder_step(self) -> float:
        return 2.0 * math.pi / 2.0 ** self.encoder_bits if self.encoder_bits else 0.0

    @property
    def var_q(self) -> float:
        """Variance of one encoder reading [rad^2]: noise plus uniform quantisation Delta^2 / 12."""
        return self.sigma_q ** 2 + self.encoder_step ** 2 / 12.0

    @property
    def bandwidth(self) -> float:
        """Natural frequency of the steady-state position-only filter, (sigma_a / sigma_q_eff)^(1/2) [rad/s]."""
        return math.sqrt(self.sigma_acc / math.sqrt(self.var_q))


@dataclass(frozen=True)
class Estimate:
    """The estimated joint state and its covariance (12 x 12 over (q, q'))."""

    q: np.ndarray           # (6,) rad
    qd: np.ndarray          # (6,) rad/s
    P: np.ndarray           # (12, 12)

    @property
    def std_q(self) -> np.ndarray:
        return np.sqrt(np.diag(self.P)[:N])

    @property
    def std_qd(self) -> np.ndarray:
        return np.sqrt(np.diag(self.P)[N:])


def _relabel_matrix() -> np.ndarray:
    """L with relabel(q) = L q = -q[::-1] (the legs exchange roles), for the 12-state (q, q')."""
    L6 = -np.fliplr(np.eye(N))
    L = np.zeros((2 * N, 2 * N))
    L[:N, :N] = L6
    L[N:, N:] = L6
    return L


RELABEL = _relabel_matrix()


class JointStateEstimator:
    """The Kalman filter of the module docstring. Call :meth:`reset` with the first measurement, then per
    sample :meth:`predict` (the interval since the last sample, the model's acceleration over it) and
    :meth:`update` (the new measurement)."""

    def __init__(self, config: EstimatorConfig):
        self.cfg = config.validate()
        c = self.cfg
        self._use_qd = math.isfinite(c.sigma_qd)
        self._use_pitch = math.isfinite(c.sigma_pitch)
        self._use_gyro = math.isfinite(c.sigma_pitch_rate)
        self.x = np.zeros(2 * N)
        self.P = np.eye(2 * N)

    # ------------------------------------------------------------------ set-up
    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> Estimate:
        """Start at the measurement: q from the encoders (variance var_q), q' from the rate sensor
        (sigma_qd^2) or 0 with a wide variance when there is none."""
        c = self.cfg
        self.x[:N] = np.asarray(q, dtype=float)
        vq = c.var_q
        if self._use_qd and qd is not None:
            self.x[N:] = np.asarray(qd, dtype=float)
            vqd = max(c.sigma_qd ** 2, 1e-30)
        else:
            self.x[N:] = 0.0
            vqd = 1e2
        self.P = np.diag(np.r_[np.full(N, vq), np.full(N, vqd)])
        return self.estimate()

    def estimate(self) -> Estimate:
        return Estimate(q=self.x[:N].copy(), qd=self.x[N:].copy(), P=self.P.copy())

    # ------------------------------------------------------------------ filter
    def predict(self, dt: float, acc: np.ndarray) -> Estimate:
        """Time update over ``dt`` [s] with the joint acceleration ``acc`` [rad/s^2] held over it."""
        finite_number(dt, "dt", at_least=0)
        a = np.asarray(acc, dtype=float)
        q, qd = self.x[:N], self.x[N:]
        self.x = np.r_[q + qd * dt + 0.5 * a * dt * dt, qd + a * dt]
        F = np.eye(2 * N)
        F[:N, N:] = dt * np.eye(N)
        s2 = self.cfg.sigma_acc ** 2
        Q = np.zeros((2 * N, 2 * N))
        Q[:N, :N] = 0.25 * dt ** 4 * s2 * np.eye(N)
        Q[:N, N:] = Q[N:, :N] = 0.5 * dt ** 3 * s2 * np.eye(N)
        Q[N:, N:] = dt * dt * s2 * np.eye(N)
        self.P = F @ self.P @ F.T + Q
        return self.estimate()

    def update(self, q_meas: np.ndarray, qd_meas: np.ndarray | None = None, pitch: float | None = None,
               pitch_rate: float | None = None) -> Estimate:
        """Measurement update (Joseph form) with the encoders, the rate sensor, the IMU's pitch [rad] and its
        gyro's pitch rate [rad/s] (each left out when absent from the configuration, None or NaN)."""
        c = self.cfg
        rows = [np.hstack([np.eye(N), np.zeros((N, N))])]
        z = [np.asarray(q_meas, dtype=float)]
        r = [np.full(N, c.var_q)]
        if self._use_qd and qd_meas is not None:
            rows.append(np.hstack([np.zeros((N, N)), np.eye(N)]))
            z.append(np.asarray(qd_meas, dtype=float))
            r.append(np.full(N, max(c.sigma_qd ** 2, 1e-30)))
        if self._use_pitch and pitch is not None and math.isfinite(pitch):
            h = np.zeros((1, 2 * N))
            h[0, :3] = 1.0
            rows.append(h)
            z.append(np.array([float(pitch)]))
            r.append(np.array([max(c.sigma_pitch ** 2, 1e-30)]))
        if self._use_gyro and pitch_rate is not None and math.isfinite(pitch_rate):
            h = np.zeros((1, 2 * N))
            h[0, N:N + 3] = 1.0
            rows.append(h)
            z.append(np.array([float(pitch_rate)]))
            r.append(np.array([max(c.sigma_pitch_rate ** 2, 1e-30)]))
        H = np.vstack(rows)
        zz = np.concatenate(z)
        R = np.diag(np.concatenate(r))
        S = H @ self.P @ H.T + R
        K = np.linalg.solve(S, H @ self.P).T
        self.x = self.x + K @ (zz - H @ self.x)
        IKH = np.eye(2 * N) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        return self.estimate()

    def relabel_impact(self, q_new: np.ndarray, qd_new: np.ndarray, J: np.ndarray | None = None) -> Estimate:
        """A touchdown: the state becomes the model's post-impact state (``q_new``, ``qd_new``, already
        relabelled by the caller), the covariance the relabelled one (``J``: the map's Jacobian over (q, q'),
        default the relabelling alone) plus sigma_impact^2 on each rate."""
        M = RELABEL if J is None else J
        self.x = np.r_[np.asarray(q_new, dtype=float), np.asarray(qd_new, dtype=float)]
        self.P = M @ self.P @ M.T
        self.P[N:, N:] += self.cfg.sigma_impact ** 2 * np.eye(N)
        return self.estimate()
