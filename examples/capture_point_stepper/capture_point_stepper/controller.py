"""A capture-point step adjuster on the biped's gait family q_d(p, tau), behind the controller interface.

The controller walks the same gait family as the paper's controller (stride p [m], phase tau [s] in
[0, T], time scaling tau' = dtau/dt) and changes p and tau' like the divergent-component-of-motion
(DCM) step adapters do: from the linear-inverted-pendulum (LIP) capture point, not from the contact
constraints (no QP).

LIP and capture point. With the centre of mass (CoM) at a constant height z_c over the stance ankle,
x'' = omega^2 (x - u_cop), omega = sqrt(g / z_c) [1/s]. The DCM (instantaneous capture point)
xi = x + x'/omega [m] obeys xi' = omega (xi - u_cop); with the centre of pressure at the ankle
(u_cop = 0) it diverges as xi(t + s) = xi(t) e^{omega s}. Here x, x' are the CoM's horizontal
position and velocity relative to the stance ankle, from the sensed (q, q') by the controller-side
model of its setup (``setup.model.com_state``: x_G and J_G q'); z_c is the mean CoM height of the
preferred step q_d(p_d, .) (``setup.reference``).

Step location and timing. With T_r [s] the time left until touchdown, the DCM at touchdown is
xi_T = xi e^{omega T_r} (relative to the stance ankle). The preferred gait defines the DCM offset
c(tau) = xi_n(tau) e^{omega (T - tau)}, xi_n the DCM along q_d(p_d, .) at phase tau (tabulated at start):
on the preferred gait the touchdown DCM is c and the foot lands at p_d. The step adjuster puts the
next foot where the same offset from the new stance ankle is restored:

    u(T_r) = p_d + xi e^{omega T_r} - c(tau)           (the step location law)

and picks the timing as the DCM step-timing adapters do, over sigma = e^{omega T_r} (u is linear in
sigma): min w_u (u - p_d)^2 + w_t (sigma - sigma_n)^2, sigma_n = e^{omega (T - tau)} the preferred
timing, i.e. sigma = (w_u xi c + w_t sigma_n) / (w_u xi^2 + w_t), bounded to the step-time range
T_r in [max(T_min - t_s, dt_min), T_max - t_s] (t_s [s] the time since the touchdown, T_min, T_max the
step-time bounds). When u then leaves the family's range [p_min, p_max], the range wins: sigma solves
u = the violated bound, sigma = (bound - p_d + c) / xi, within the same bounds, and p* = clip(u, p_min,
p_max). A dead band keeps the preferred gait exact: a DCM error |xi - xi_n(tau)| below ``dead_band`` [m]
(what the tracking error alone produces) counts as none, a larger one is reduced by it. The time-scaling
target is
tau'* = (T - tau) / T_r (tau reaches T when the foot should land), bounded to [tau_dot_min, tau_dot_max].
After ``freeze_phase`` T of the step the targets are held (the swing foot is landing).

Parameters follow the targets with second-order dynamics, integrated exactly over the elapsed time:
p'' = k_p (p* - p) - k_v p',  tau'' = k_tau (tau'* - tau').  At a touchdown tau = 0; p, p', tau'
carry over.

Torque: the computed-torque law of the paper on q_d(p, tau) (eqs. 11, 15-17), q_d' = dq/dp p' +
dq/dtau tau', q_d'' with the p'', tau'' terms (``setup.reference.at(p, tau).motion(p', tau', p'', tau'')``),
w = q_d'' + K_v (q_d' - q') + K_p (q_d - q) (K_p, K_v: ``setup.gains`` unless given as options),
Gamma = A(q) w + H(q, q') [N m] (``setup.model.dynamics``, the robot as the controller knows it).

Everything comes from the plug-in package (``biped_controller.plugin``): the interface's types and the
setup's model, gains and reference.

Status (per period): p [m], p_dot [m/s], tau [s], tau_dot [-], p_target [m], tau_dot_target [-],
dcm [m] (xi), dcm_error [m] (xi - xi_n(tau)), time_left [s] (T_r), timing_adapted (bool: T_r differs
from the preferred), max_tracking_error [rad].
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from biped_controller.plugin.interface import ControllerSetup, ControlResult, Observation
from biped_controller.plugin.model import Gains


class StepperSettingsError(ValueError):
    """A setting of the step adjuster is unknown or out of range (the message names it)."""


@dataclass(frozen=True)
class StepperSettings:
    """The step adjuster's settings (``ControllerSetup.options`` override them by name)."""

    Kp: float                 # [1/s^2] joint PD stiffness (eq. 16); default: the setup's gains
    Kv: float                 # [1/s] joint PD damping; default: the setup's gains
    kp: float = 25.0          # [1/s^2] p -> p*: the paper's second-task gain for p -> p_d (omega_n = 5 rad/s)
    kv: float = 10.0          # [1/s] critical damping for kp (the paper's k_v)
    k_tau: float = 10.0       # [1/s] tau' -> tau'*: the paper's k_v for tau' -> 1
    step_time_min: float = 0.6    # [T] shortest step, as a fraction of the preferred step time T
    step_time_max: float = 1.5    # [T] longest step
    min_time_left: float = 0.05   # [s] the earliest the foot may land from now
    tau_dot_min: float = 0.3      # [-] bounds of tau'*
    tau_dot_max: float = 2.5
    freeze_phase: float = 0.85    # [-] fraction of T after which p*, tau'* are held
    dead_band: float = 0.002      # [m] DCM errors |xi - xi_n| below this are none (the undisturbed walk's: < 7e-4 m)
    weight_step: float = 400.0    # [1/m^2] cost of (u - p_d)^2: 5 cm of stride ...
    weight_time: float = 1.0      # [-] ... cost as much as 0.1 of sigma = e^{omega T_r} (about 5 % of its mid-step value)

    def validate(self) -> "StepperSettings":
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise StepperSettingsError(f"capture_point: {f.name} must be a finite number >= 0, got {v!r}")
        for name in ("Kp", "Kv", "kp", "kv", "k_tau", "min_time_left", "tau_dot_min"):
            if getattr(self, name) <= 0:
                raise StepperSettingsError(f"capture_point: {name} must be > 0, got {getattr(self, name)!r}")
        if not self.step_time_min < self.step_time_max:
            raise StepperSettingsError("capture_point: step_time_min must be < step_time_max")
        if not self.tau_dot_min < self.tau_dot_max:
            raise StepperSettingsError("capture_point: tau_dot_min must be < tau_dot_max")
        if not 0 < self.freeze_phase <= 1:
            raise StepperSettingsError(f"capture_point: freeze_phase must be in (0, 1], got {self.freeze_phase!r}")
        return self

    @classmethod
    def from_options(cls, options, gains: Gains) -> "StepperSettings":
        """The settings with ``gains`` (``ControllerSetup.gains``) as Kp, Kv, overridden by ``options``."""
        known = {f.name for f in fields(cls)}
        bad = sorted(set(options) - known)
        if bad:
            raise StepperSettingsError(f"capture_point: unknown option(s) {bad}; known: {sorted(known)}")
        base = cls(Kp=gains.Kp, Kv=gains.Kv)
        return replace(base, **{k: float(v) for k, v in options.items()}).validate()


class CapturePointStepper:
    """The capture-point step adjuster (module docstring) as an interface controller."""

    description = "capture-point (LIP DCM) step adjuster: stride p and timing tau' from the DCM, computed torque on q_d(p, tau)"

    N_TABLE = 401       # points of the preferred gait's DCM table over tau in [0, T]

    def __init__(self, setup: ControllerSetup):
        self.s = StepperSettings.from_options(setup.options, setup.gains)
        self.ref = ref = setup.reference
        self.model = setup.model
        self.T, self.p_d, self.p_min, self.p_max = ref.T, ref.p_d, ref.p_min, ref.p_max
        taus = np.linspace(0.0, ref.T, self.N_TABLE)
        xs, zs, vs = [], [], []
        for tau in taus:
            g = ref.at(ref.p_d, tau)
            com = self.model.com_terms(g.q, g.dq_dtau)
            xs.append(com.position[0])
            zs.append(com.position[1])
            vs.append((com.jacobian @ g.dq_dtau)[0])
        self.z_c = float(np.mean(zs))                              # [m]
        self.omega = math.sqrt(self.model.gravity / self.z_c)      # [1/s]
        self._taus = taus
        self._xi_n = np.array(xs) + np.array(vs) / self.omega      # [m] DCM along the preferred step
        self._offset = self._xi_n * np.exp(self.omega * (ref.T - taus))   # c(tau) [m]
        self.reset(0.0, 0)

    # ------------------------------------------------------------------ interface
    def reset(self, t: float, stance: int) -> None:
        """p = p_d, p' = 0, tau = 0, tau' = 1, targets at the preferred gait, the step starting at ``t``."""
        self.p, self.p_dot, self.tau, self.tau_dot = self.p_d, 0.0, 0.0, 1.0
        self.p_ddot = self.tau_ddot = 0.0
        self.p_target, self.tau_dot_target, self.time_left = self.p_d, 1.0, self.T
        self.stance, self.t_last, self.t_step = stance, float(t), float(t)
        self._touched = False

    def on_touchdown(self, t: float, stance: int) -> None:
        """A new step starts at ``t`` [s] (applied at the next ``compute``: tau = 0)."""
        self.stance, self.t_step, self._touched = stance, float(t), True

    def compute(self, obs: Observation) -> ControlResult:
        h = obs.t - self.t_last
        self._advance(h)
        if self._touched or obs.stance != self.stance:
            if not self._touched:                  # a stance change seen without the call
                self.stance, self.t_step = obs.stance, obs.t
            self.tau, self._touched = 0.0, False
        self.t_last = obs.t
        q, qd = obs.q, obs.qd
        com = self.model.com_state(q, qd)
        xi = float(com.position[0] + com.velocity[0] / self.omega)
        tau_c = min(max(self.tau, 0.0), self.T)
        xi_n = float(np.interp(tau_c, self._taus, self._xi_n))
        adapted = False
        if self.tau < self.s.freeze_phase * self.T:
            self.p_target, self.time_left, adapted = self._targets(xi, tau_c, obs.t - self.t_step)
            self.tau_dot_target = min(max((self.T - tau_c) / self.time_left, self.s.tau_dot_min), self.s.tau_dot_max)
        s = self.s
        self.p_ddot = s.kp * (self.p_target - self.p) - s.kv * self.p_dot
        self.tau_ddot = s.k_tau * (self.tau_dot_target - self.tau_dot)
        ref = self.ref.at(self.p, self.tau).motion(self.p_dot, self.tau_dot, self.p_ddot, self.tau_ddot)
        q_d = ref.q
        w = ref.qdd + s.Kv * (ref.qd - qd) + s.Kp * (q_d - q)
        dyn = self.model.dynamics(q, qd)
        torque = dyn.A @ w + dyn.H
        status = {"p": self.p, "p_dot": self.p_dot, "tau": self.tau, "tau_dot": self.tau_dot,
                  "p_target": self.p_target, "tau_dot_target": self.tau_dot_target, "dcm": xi,
                  "dcm_error": xi - xi_n, "time_left": self.time_left, "timing_adapted": adapted,
                  "max_tracking_error": float(np.max(np.abs(q_d - q)))}
        return ControlResult(torque, status)

    # ------------------------------------------------------------------ the law
    def _advance(self, h: float) -> None:
        """(p, p', tau, tau') over ``h`` [s] with the held p'', tau'' (exact for constant accelerations)."""
        if h <= 0:
            return
        self.p += self.p_dot * h + 0.5 * self.p_ddot * h * h
        self.p_dot += self.p_ddot * h
        self.tau += self.tau_dot * h + 0.5 * self.tau_ddot * h * h
        self.tau_dot += self.tau_ddot * h

    def stride_at(self, xi: float, tau: float, time_left: float) -> float:
        """u(T_r) = p_d + xi e^{omega T_r} - c(tau) [m] (the step location law)."""
        return self.p_d + xi * math.exp(self.omega * time_left) - float(np.interp(tau, self._taus, self._offset))

    def _targets(self, xi: float, tau: float, since_touchdown: float) -> tuple[float, float, bool]:
        """(p* [m], T_r [s], timing adapted) for the DCM ``xi`` [m] at phase ``tau`` [s] (module docstring)."""
        s, om = self.s, self.omega
        xi_n = float(np.interp(tau, self._taus, self._xi_n))
        e = xi - xi_n
        xi = xi_n + math.copysign(max(abs(e) - s.dead_band, 0.0), e)      # the dead band on the DCM error
        c = float(np.interp(tau, self._taus, self._offset))
        lo = max(s.step_time_min * self.T - since_touchdown, s.min_time_left)
        hi = max(s.step_time_max * self.T - since_touchdown, lo)
        t_nom = min(max(self.T - tau, lo), hi)
        sig_nom, sig_lo, sig_hi = math.exp(om * t_nom), math.exp(om * lo), math.exp(om * hi)
        wu, wt = s.weight_step, s.weight_time
        sig = (wu * xi * c + wt * sig_nom) / (wu * xi * xi + wt)        # argmin of the weighted cost
        sig = min(max(sig, sig_lo), sig_hi)
        u = self.p_d + xi * sig - c
        if not self.p_min <= u <= self.p_max and xi != 0.0:             # the range first: the timing takes the rest
            bound = self.p_max if u > self.p_max else self.p_min
            r = (bound - self.p_d + c) / xi
            if r > 0.0:
                sig = min(max(r, sig_lo), sig_hi)
                u = self.p_d + xi * sig - c
        t_r = math.log(sig) / om
        return min(max(u, self.p_min), self.p_max), t_r, abs(t_r - t_nom) > 1e-12
