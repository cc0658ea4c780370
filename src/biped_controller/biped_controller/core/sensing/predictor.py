"""Smith predictor for a known measurement delay of d control periods, across a touchdown.
Pure NumPy + Pinocchio, no ROS.

At period k the controller receives the sample of period k - d (stance included: a touchdown reaches it d
periods late). It knows what happened since: the instants t_{k-d}, ..., t_k of its own decisions and the
torques Gamma_{k-d}, ..., Gamma_{k-1} it sent, each in the paper order of the stance it had been told
(the plant maps a torque to the motors with that stance). The predictor integrates its own model from
the sample over those intervals to the present:

  single support (stance foot fixed): A(q) q'' + H(q, q') = Gamma  (``FixedFootModel``; the plant's
  torque limits clip Gamma first), classical RK4 with ``substeps`` steps per interval (an interval
  cut short by an impact gets proportionally fewer, at least one);
  a torque sent for the other stance than the predicted one is relabelled, Gamma -> -Gamma[::-1];
  touchdown: once the swing foot has cleared ``clearance`` [m] (in the sample or the prediction), its
  lowest sole point (heel or toe, the sole through the ankle) reaching ``touchdown_height`` [m] at an
  interval's end is a touchdown there (the plant ends a period at its impact: with an exact model the
  prediction meets it at that instant); a crossing of the ground inside a substep is located by
  bisection to ``time_tolerance`` [s] and the rest of the substep continues in the new stance. At the
  touchdown the landing foot is laid flat by its ankle (q6 -= sum(q): the swing foot's pitch with the
  stance foot flat), the model's inelastic impact map gives q'+ (``floating.impact_paper``) and the legs
  are relabelled (q -> -q[::-1]).

The prediction is redone every period from the newest sample, so it is reconciled with the sensed stance
as soon as the touchdown's sample arrives (the sample then starts in the new stance). A sample is d periods
old (the first ones younger: k < d), except with a touchdown reported at once (the plant's
``touchdown_delayed`` False, the controller's ``predictor_touchdown_at_once``): the first sample of a new
stance is of the period it arrives in, then held while it ages to d periods. :meth:`DelayPredictor.predict`
takes the sample's age in periods (``periods``: the prediction runs through the last ``periods`` decisions
only; 0: the sample is the present state, the pending prediction of the old stance is dropped), which
``pipeline.SensingPipeline`` (and ``pipeline_compiled.CompiledSensing``) derive from the stance changes.
With the touchdown reported at once the present stance is always the sensed one (a touchdown before t_k is in
the sample of period k), so the pipeline builds the predictor with ``touchdowns`` False: it integrates in
the sample's stance and never predicts a touchdown, which could only be a false one (under sensor noise the
estimated swing sole reaches the ground early: docs/robustness.md).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from biped_model.description import RobotDescription
from biped_model.fixed_foot import FixedFootModel, relabel
from biped_model.finite import finite_number
from biped_model.floating import FloatingModel, impact_paper


def flat_foot_impact(fm: FloatingModel, q: np.ndarray, qd: np.ndarray, stance: int) -> tuple[np.ndarray, np.ndarray]:
    """Touchdown of the swing foot of ``stance`` at (q, q') on the model ``fm``: the landing foot laid flat
    by its ankle (q6 -= sum(q), the swing foot's pitch with the stance foot flat), the inelastic impact
    map (``floating.impact_paper``), the legs relabelled. Returns (q+, q'+) in the new stance's order."""
    qf = np.array(q, dtype=float)
    qf[5] -= float(np.sum(qf))
    qd_new, _ = impact_paper(fm, qf, np.asarray(qd, dtype=float), stance)
    return relabel(qf), qd_new


class PredictorError(ValueError):
    """A setting of the predictor is invalid (the message names it)."""


@dataclass(frozen=True)
class Prediction:
    """The predicted present state: paper (q [rad], q' [rad/s]) of the predicted ``stance``, and the
    number of touchdowns predicted since the sample."""

    q: np.ndarray
    qd: np.ndarray
    stance: int
    touchdowns: int


class DelayPredictor:
    """The predictor of the module docstring for ``delay`` = d >= 1 periods."""

    def __init__(self, desc: RobotDescription, delay: int, substeps: int, period: float,
                 touchdown_height: float, clearance: float, time_tolerance: float, touchdowns: bool = True):
        for name, v in (("delay_compensation", delay), ("predictor_substeps", substeps)):
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise PredictorError(f"{name} must be an integer >= 1, got {v!r}")
        for name, v in (("period", period), ("predictor_touchdown_height", touchdown_height),
                        ("predictor_clearance", clearance), ("predictor_time_tolerance", time_tolerance)):
            finite_number(v, name, above=0, error=PredictorError)
        self.d, self.substeps, self.period = delay, substeps, float(period)
        self.td_height, self.clearance, self.t_tol = float(touchdown_height), float(clearance), float(time_tolerance)
        self.touchdowns = bool(touchdowns)     # False: never predict a touchdown (it is reported at once)
        self.model = FixedFootModel(desc)
        self.fm = FloatingModel(desc)
        lo, hi = desc.torque_limits()
        self.lo, self.hi = np.array(lo, dtype=float), np.array(hi, dtype=float)
        self.foot = desc.foot
        self.reset()

    def reset(self) -> None:
        self.history: deque[tuple[float, np.ndarray, int]] = deque(maxlen=self.d)
        self._cleared = False
        self._sample_stance: int | None = None

    def record(self, t: float, torque: np.ndarray, told_stance: int) -> None:
        """The decision of the period starting at ``t``: the torque sent (paper order of ``told_stance``)."""
        self.history.append((float(t), np.array(torque, dtype=float), int(told_stance)))

    # ---------------------------------------------------------------- the model
    def _accel(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        dyn = self.model.dynamics(q, qd)
        return np.linalg.solve(dyn.A, tau - dyn.H)

    def _rk4(self, q, qd, tau, h):
        k1q, k1v = qd, self._accel(q, qd, tau)
        k2q, k2v = qd + 0.5 * h * k1v, self._accel(q + 0.5 * h * k1q, qd + 0.5 * h * k1v, tau)
        k3q, k3v = qd + 0.5 * h * k2v, self._accel(q + 0.5 * h * k2q, qd + 0.5 * h * k2v, tau)
        k4q, k4v = qd + h * k3v, self._accel(q + h * k3q, qd + h * k3v, tau)
        return (q + (h / 6.0) * (k1q + 2 * k2q + 2 * k3q + k4q), qd + (h / 6.0) * (k1v + 2 * k2v + 2 * k3v + k4v))

    def lowest_sole(self, q: np.ndarray) -> float:
        """Height [m] of the swing foot's lowest sole point (heel or toe) above the stance sole line."""
        pose, _ = self.model.swing_foot(q)
        z, th = pose[1], pose[2]
        return float(z + min(self.foot.l_min * math.sin(th), self.foot.l_max * math.sin(th)))

    def impact(self, q: np.ndarray, qd: np.ndarray, stance: int) -> tuple[np.ndarray, np.ndarray]:
        """The flat-foot touchdown of the module docstring: (q+, q'+) in the new stance's paper order."""
        return flat_foot_impact(self.fm, q, qd, stance)

    # ---------------------------------------------------------------- prediction
    def predict(self, t_now: float, q: np.ndarray, qd: np.ndarray, stance: int,
                periods: int | None = None) -> Prediction:
        """The present state from the sample (q, q', stance) taken at the instant of the decision ``periods``
        periods ago (None: the first recorded decision; the instants and torques of :meth:`record`),
        integrated through the decisions since to ``t_now``. ``periods`` is the sample's age, 0 to the
        number of decisions recorded (at most d); 0 returns the sample."""
        q = np.array(q, dtype=float)
        qd = np.array(qd, dtype=float)
        if stance != self._sample_stance:
            self._cleared = False
            self._sample_stance = stance
        if self.lowest_sole(q) > self.clearance:
            self._cleared = True
        cleared = self._cleared and self.touchdowns
        s = int(stance)
        n_td = 0
        items = list(self.history)
        if periods is not None:
            if isinstance(periods, bool) or not 0 <= int(periods) <= len(items):
                raise PredictorError(f"periods must be an integer in [0, {len(items)}] (the decisions recorded), "
                                     f"got {periods!r}")
            items = items[len(items) - int(periods):]
        for i, (t0, tau_sent, told) in enumerate(items):
            t1 = items[i + 1][0] if i + 1 < len(items) else float(t_now)
            dt = t1 - t0
            if dt <= 0:
                continue
            n = max(1, int(math.ceil(self.substeps * dt / self.period - 1e-9)))
            h = dt / n
            tau_told = np.clip(tau_sent, self.lo, self.hi)
            for j in range(n):
                tau = tau_told if told == s else relabel(tau_told)
                qn, qdn = self._rk4(q, qd, tau, h)
                z = self.lowest_sole(qn)
                if cleared and z < -self.td_height:
                    # the foot crosses the ground inside this substep: locate it, touch down, go on
                    lo_, hi_ = 0.0, h
                    while hi_ - lo_ > self.t_tol:
                        mid = 0.5 * (lo_ + hi_)
                        if self.lowest_sole(self._rk4(q, qd, tau, mid)[0]) > 0.0:
                            lo_ = mid
                        else:
                            hi_ = mid
                    qe, qde = self._rk4(q, qd, tau, hi_)
                    q, qd = self.impact(qe, qde, s)
                    s, cleared, n_td = 1 - s, False, n_td + 1
                    rest = h - hi_
                    if rest > 0:
                        tau = tau_told if told == s else relabel(tau_told)
                        q, qd = self._rk4(q, qd, tau, rest)
                    continue
                q, qd = qn, qdn
                if z > self.clearance and self.touchdowns:
                    cleared = True
                if cleared and j == n - 1 and z <= self.td_height:
                    # the interval ends on the ground: the plant's period ended at this touchdown
                    q, qd = self.impact(q, qd, s)
                    s, cleared, n_td = 1 - s, False, n_td + 1
        return Prediction(q=q, qd=qd, stance=s, touchdowns=n_td)
