"""``dcm_wbc``: a DCM (capture-point) step layer above the whole-body QP, the stack of modern humanoids, as a
controller of the interface (``plugin.interface``), registered by the ``biped_controller`` distribution's
``biped.controllers`` entry point and run, like any plug-in, on the generic loop (``plugin.loop``).

Two layers, each period (paper joint coordinates of the stance, DESIGN.md; positions relative to the stance
ankle, x forward, y up [m]):

**Step layer** (:class:`DcmStepLayer`): where and when the next foot lands, from the divergent component of
motion. The linear inverted pendulum with its centre of mass at the constant height z_c [m] over the stance
ankle obeys x'' = omega^2 (x - u_cop), omega = sqrt(g / z_c) [1/s]; its DCM

    xi = x + x' / omega    [m]                                        (x, x': the CoM's forward position, velocity)

obeys xi' = omega (xi - u_cop), so with the centre of pressure at the ankle (u_cop = 0) it reaches
xi_T = xi sigma at touchdown, sigma = e^{omega T_r}, T_r [s] the time left in the step. z_c is the mean CoM height
of the preferred step q_d(p_d, .); xi_n(tau) is the DCM along the preferred step (tau' = 1), tabulated over
tau in [0, T]. On the preferred gait the touchdown DCM is c(tau) = xi_n(tau) sigma_n(tau), sigma_n =
e^{omega (T - tau)}, and the foot lands at p_d; the layer keeps that offset of the touchdown DCM from the next
foot:

    u(sigma) = p_d + xi sigma - c(tau)    [m]                         (the step location law)

and chooses the timing by the weighted cost min w_u (u - p_d)^2 + w_t (sigma - sigma_0)^2 over sigma
(sigma_0 = e^{omega t_0}, t_0 = T - tau held to the step-time bounds), whose minimiser is

    sigma* = (w_u xi c + w_t sigma_0) / (w_u xi^2 + w_t),

held to the bounds T_r in [max(t_min T - t_s, dt_min), t_max T - t_s] (t_s [s] since the touchdown). When u then
leaves the family's range [p_min, p_max] the range wins: sigma solves u = the violated bound (within the same
bounds) and p* = u held to the range. The DCM the measured one is compared with (in the dead band, in c and in the
reported error) is, by default (``commanded_dcm``), the DCM of the reference the layer commands,

    xi_r = x_r + x_r' / omega,   x_r = x_G(q_d(p, tau)),   x_r' = J_G(q_d) (dq/dp p' + dq/dtau tau')   [m]

at the period's p, p', tau, tau' (so c = xi_r e^{omega (T - tau)}); with p = p_d, tau' = 1 it is xi_n(tau). The
first law compared it with xi_n(tau) always (``commanded_dcm`` false), and so read its own quicker, longer
reference as a DCM error (docs/step_layer.md, "The correction"). Below, xi_n stands for the compared DCM. A DCM
error |xi - xi_n| below the dead band [m] counts as none, a larger one is reduced by it (xi -> xi_n + sign(e)
(|e| - dead_band)). The targets handed on are the stride p*
[m] and the time scaling tau'* = (T - tau) / T_r [-] (the reference reaches tau = T when the foot should land),
held to [tau_dot_min, tau_dot_max] (``config/controller.yaml``, the other modes' limits). From
``freeze_phase`` T on (the swing foot landing) the targets are held.

**Parameters.** p and tau follow the targets by the paper's second task (eq. 20) with p_d and 1 replaced by
the targets: p'' = k_p (p* - p) - k_v p', tau'' = k_v (tau'* - tau') (k_p, k_v: ``config/controller.yaml``'s
``kp``, ``kv``; with p* = p_d and tau'* = 1 these are mode ``wbc``'s x* exactly), advanced exactly over the
time elapsed (constant p'', tau''), p held to [p_min, p_max] (on a bound the outward part of p' is removed).
At a touchdown tau = 0; p, p', tau' carry over.

**Whole-body QP** (``core.control.wbc``, mode ``wbc``'s stage, its settings and rows): the reference
q_d(p, tau) with q_d' = dq/dp p' + dq/dtau tau' and q_d'' with the p'', tau'' terms (eq. 11,
``setup.reference.at(p, tau).motion``), the tracking law w* = q_d'' + K_v (q_d' - q') + K_p (q_d - q)
[rad/s^2] (eq. 16, ``setup.gains``), then w = argmin (w - w*)' M (w - w*) under the 17 contact and torque rows
G w <= h (stated with and without the disturbance observer's estimated force), Gamma = A(q) w + H(q, q') [N m]
(eq. 15). The disturbance observer is mode ``wbc``'s acceleration residual (``disturbance_observer``,
``observer_height``): F [N] = j . r / |j|^2, r = A_prev ((q' - q'_prev) / dt - w_prev), j the torso point's
x-Jacobian on the joints; none at the first period, the previous F kept over a touchdown; it shifts the
reaction drift h_b by B A^-1 j F - J_root F.

So with the dead band infinite (``--option dead_band=1e9``) the step layer never moves the reference and the
controller is mode ``wbc`` through the interface; with ``whole_body`` off it is the step layer above plain
computed torque (Gamma = A w* + H). Settings: ``config/controller.yaml``'s ``step_layer_*`` keys (each with its
reason), any of them overridden by the setup's options under its name without the prefix; a bad one is a
:class:`StepLayerSettingsError` naming it.

Status (per period): p [m], p_dot [m/s], p_ddot [m/s^2], tau [s], tau_dot [-], tau_ddot [1/s], p_target [m],
tau_dot_target [-], dcm [m], dcm_error [m] (xi - the compared DCM), time_left [s], step_frozen, timing_adapted,
wbc_status, wbc_deviation [rad/s^2], wbc_active (bit mask of the 17 rows), force_estimate [N], zmp [m],
tightest, max_tracking_error [rad].
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from biped_model.finite import finite_number
from biped_model.fixed_foot import FixedFootModel
from biped_model.settings import SettingsError, default_config_dir, read_settings
from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.wbc import WholeBodyStage
from biped_controller.core.qp.problem import UNCONSTRAINED
from biped_controller.plugin.interface import ControllerSetup, ControlResult, Observation

#: the prefix of the layer's keys in config/controller.yaml
PREFIX = "step_layer_"
#: the settings that are switches (true / false)
BOOLEANS = ("whole_body", "disturbance_observer", "commanded_dcm")


class StepLayerSettingsError(ValueError):
    """A setting of the step layer is unknown or out of range (the message names the key)."""


@dataclass(frozen=True)
class StepLayerSettings:
    """The step layer's settings (``config/controller.yaml``: ``step_layer_<name>``; reasons there)."""

    dead_band: float          # [m] DCM errors below this are none
    freeze_phase: float       # [-] fraction of T from which the targets are held
    step_time_min: float      # [T] the shortest step, a fraction of the preferred step time T
    step_time_max: float      # [T] the longest step
    min_time_left: float      # [s] the earliest the foot may land from now
    weight_step: float        # [1/m^2] w_u of (u - p_d)^2
    weight_time: float        # [-] w_t of (sigma - sigma_0)^2
    whole_body: bool          # the whole-body QP under the reference (False: plain computed torque)
    disturbance_observer: bool    # mode wbc's acceleration-residual observer feeds the QP's rows
    commanded_dcm: bool       # the DCM error against the commanded reference's DCM (False: the preferred step's)

    @classmethod
    def keys(cls) -> list[str]:
        return [PREFIX + f.name for f in fields(cls)]

    def validate(self) -> "StepLayerSettings":
        """Each value in its range, else :class:`StepLayerSettingsError` naming its key."""
        for name in ("dead_band", "min_time_left", "weight_step", "weight_time", "step_time_min"):
            finite_number(getattr(self, name), PREFIX + name, **({"above": 0} if name in ("min_time_left",
                          "step_time_min") else {"at_least": 0}), error=StepLayerSettingsError)
        finite_number(self.step_time_max, PREFIX + "step_time_max", above=self.step_time_min,
                      error=StepLayerSettingsError,
                      message=f"{PREFIX}step_time_max must be a finite number > {PREFIX}step_time_min "
                              f"({self.step_time_min!r}), got {self.step_time_max!r}")
        finite_number(self.freeze_phase, PREFIX + "freeze_phase", above=0, at_most=1, error=StepLayerSettingsError)
        if self.weight_step + self.weight_time <= 0:
            raise StepLayerSettingsError(f"{PREFIX}weight_step and {PREFIX}weight_time must not both be 0")
        for name in BOOLEANS:
            if not isinstance(getattr(self, name), bool):
                raise StepLayerSettingsError(f"{PREFIX}{name} must be true or false, got {getattr(self, name)!r}")
        return self

    @classmethod
    def load(cls, options=None) -> "StepLayerSettings":
        """``config/controller.yaml``'s ``step_layer_*`` values, overridden by ``options`` (name without the
        prefix, or with it), validated."""
        try:
            raw = read_settings(default_config_dir() / "controller.yaml", cls.keys())
        except SettingsError as exc:
            raise StepLayerSettingsError(str(exc)) from exc
        kw = {k[len(PREFIX):]: v for k, v in raw.items()}
        known = {f.name for f in fields(cls)}
        for key, value in dict(options or {}).items():
            name = key[len(PREFIX):] if isinstance(key, str) and key.startswith(PREFIX) else key
            if name not in known:
                raise StepLayerSettingsError(f"dcm_wbc: unknown option {key!r}; known: {sorted(known)}")
            if name in BOOLEANS and isinstance(value, str):
                if value.lower() not in ("true", "false", "1", "0", "on", "off"):
                    raise StepLayerSettingsError(f"{PREFIX}{name} must be true or false, got {value!r}")
                value = value.lower() in ("true", "1", "on")
            elif name not in BOOLEANS and isinstance(value, str):
                try:
                    value = float(value)
                except ValueError:
                    raise StepLayerSettingsError(f"{PREFIX}{name} must be a number, got {value!r}") from None
            kw[name] = value
        return cls(**kw).validate()


@dataclass(frozen=True)
class StepTargets:
    """One decision of the step layer: ``p`` = p* [m], ``time_left`` = T_r [s], ``tau_dot`` = tau'* [-],
    ``timing_adapted`` (T_r differs from the preferred T - tau held to the bounds)."""

    p: float
    time_left: float
    tau_dot: float
    timing_adapted: bool


class DcmStepLayer:
    """The step layer's law (module docstring) for the preferred gait of ``reference`` on ``model`` (the
    controller-side ``RobotModel``): ``omega`` [1/s], ``z_c`` [m], the table xi_n(tau)."""

    N_TABLE = 401      # points of xi_n over [0, T] (linear interpolation: micrometres on this gait)

    def __init__(self, reference, model, settings: StepLayerSettings, tau_dot_min: float, tau_dot_max: float):
        self.ref, self.model, self.s = reference, model, settings
        self.T, self.p_d, self.p_min, self.p_max = reference.T, reference.p_d, reference.p_min, reference.p_max
        self.tau_dot_min, self.tau_dot_max = float(tau_dot_min), float(tau_dot_max)
        taus = np.linspace(0.0, self.T, self.N_TABLE)
        x, z, v = np.empty(taus.size), np.empty(taus.size), np.empty(taus.size)
        for i, tau in enumerate(taus):
            g = reference.at(self.p_d, tau)
            com = model.com_state(g.q, g.dq_dtau)
            x[i], z[i], v[i] = com.position[0], com.position[1], com.velocity[0]
        self.z_c = float(np.mean(z))
        self.omega = math.sqrt(float(model.gravity) / self.z_c)
        self.taus = taus
        self.xi_table = x + v / self.omega

    def dcm(self, x: float, x_dot: float) -> float:
        """xi = x + x' / omega [m] (x [m], x' [m/s] the CoM's forward position and velocity from the ankle)."""
        return float(x) + float(x_dot) / self.omega

    def xi_n(self, tau: float) -> float:
        """The preferred step's DCM at phase ``tau`` [s] (held to [0, T])."""
        return float(np.interp(min(max(tau, 0.0), self.T), self.taus, self.xi_table))

    def reference_dcm(self, p: float, p_dot: float, tau: float, tau_dot: float) -> float:
        """The commanded reference's DCM xi_r = x_r + x_r' / omega [m] at (p [m], p' [m/s], tau [s] held to
        [0, T], tau' [-]): x_r = x_G(q_d(p, tau)), x_r' = J_G(q_d) (dq/dp p' + dq/dtau tau'). With p = p_d,
        p' = 0 and tau' = 1 it is xi_n(tau) (to the table's interpolation)."""
        g = self.ref.at(p, min(max(float(tau), 0.0), self.T))
        st = self.model.com_state(g.q, g.dq_dp * p_dot + g.dq_dtau * tau_dot)
        return float(st.position[0] + st.velocity[0] / self.omega)

    def targets(self, xi: float, tau: float, since_touchdown: float, xi_ref: float | None = None) -> StepTargets:
        """p*, T_r and tau'* for the DCM ``xi`` [m] at phase ``tau`` [s], ``since_touchdown`` [s] into the step,
        ``xi_ref`` [m] the DCM it is compared with (the error xi - xi_ref, and c = xi_ref sigma_n); None: the
        preferred step's xi_n(tau)."""
        s, om, T = self.s, self.omega, self.T
        tau = min(max(float(tau), 0.0), T)
        xn = self.xi_n(tau) if xi_ref is None else float(xi_ref)
        e = float(xi) - xn
        xi = xn + math.copysign(max(abs(e) - s.dead_band, 0.0), e)
        c = xn * math.exp(om * (T - tau))
        lo = max(s.step_time_min * T - since_touchdown, s.min_time_left)
        hi = max(s.step_time_max * T - since_touchdown, lo)
        t0 = min(max(T - tau, lo), hi)
        sig0, sig_lo, sig_hi = math.exp(om * t0), math.exp(om * lo), math.exp(om * hi)
        den = s.weight_step * xi * xi + s.weight_time
        sig = (s.weight_step * xi * c + s.weight_time * sig0) / den if den > 0 else sig0
        sig = min(max(sig, sig_lo), sig_hi)
        u = self.p_d + xi * sig - c
        if not self.p_min <= u <= self.p_max and xi != 0.0:
            bound = self.p_max if u > self.p_max else self.p_min
            r = (bound - self.p_d + c) / xi
            if r > 0.0:
                sig = min(max(r, sig_lo), sig_hi)
                u = self.p_d + xi * sig - c
        t_r = math.log(sig) / om
        tau_dot = min(max((T - tau) / t_r, self.tau_dot_min), self.tau_dot_max)
        return StepTargets(min(max(u, self.p_min), self.p_max), t_r, tau_dot, abs(t_r - t0) > 1e-12)


class DcmWholeBody:
    """The DCM step layer above the whole-body QP (module docstring) as an interface controller."""

    description = ("DCM step layer (stride p and timing tau' from the capture point) above mode wbc's whole-body "
                   "QP on q_d(p, tau) under the 17 contact and torque rows")

    def __init__(self, setup: ControllerSetup):
        self.s = StepLayerSettings.load(setup.options)
        self.cfg = load_controller_config(mode="wbc", period=setup.period)
        self.ref, self.model, self.gains = setup.reference, setup.model, setup.gains
        self.layer = DcmStepLayer(self.ref, self.model, self.s, self.cfg.tau_dot_min, self.cfg.tau_dot_max)
        self._ff = FixedFootModel(setup.desc)        # the contact rows' geometry and the torso point's Jacobian
        self.stage = WholeBodyStage.for_controller(self.cfg, self._ff)
        self.reset(0.0, 0)

    # ------------------------------------------------------------------ interface
    def reset(self, t: float, stance: int) -> None:
        """p = p_d, p' = 0, tau = 0, tau' = 1, no decision yet, no observer memory, the step starting at ``t``."""
        self.p, self.p_dot, self.tau, self.tau_dot = self.ref.p_d, 0.0, 0.0, 1.0
        self.p_ddot = self.tau_ddot = 0.0
        self.targets = StepTargets(self.ref.p_d, self.ref.T, 1.0, False)
        self.stance, self.t_last, self.t_step = int(stance), float(t), float(t)
        self.decided = False
        self.force = 0.0
        self._prev = None            # (A, q', w) of the last period, for the observer

    def on_touchdown(self, t: float, stance: int) -> None:
        """Nothing to do here: the next ``compute`` sees the stance change (tau = 0 there)."""

    def compute(self, obs: Observation) -> ControlResult:
        h = round(obs.t * 1e9) * 1e-9 - round(self.t_last * 1e9) * 1e-9 if self.decided else 0.0
        self._advance(h)
        new_step = obs.stance != self.stance
        if new_step:
            self.tau, self.stance, self.t_step = 0.0, int(obs.stance), float(obs.t)
        q, qd = np.asarray(obs.q, dtype=float), np.asarray(obs.qd, dtype=float)
        lay, T = self.layer, self.ref.T
        com = self.model.com_state(q, qd)
        xi = lay.dcm(com.position[0], com.velocity[0])
        xi_ref = self._compared_dcm()
        frozen = self.tau >= self.s.freeze_phase * T
        if not frozen:
            self.targets = lay.targets(xi, self.tau, float(obs.t) - self.t_step, xi_ref)
        kp, kv = self.cfg.kp, self.cfg.kv
        self.p_ddot = kp * (self.targets.p - self.p) - kv * self.p_dot
        self.tau_ddot = kv * (self.targets.tau_dot - self.tau_dot)
        ref = self.ref.at(self.p, self.tau).motion(self.p_dot, self.tau_dot, self.p_ddot, self.tau_ddot)
        w_star = ref.qdd + self.gains.Kv * (ref.qd - qd) + self.gains.Kp * (ref.q - q)
        dyn = self._ff.dynamics(q, qd)
        h_b_c = self._observe(q, qd, dyn, h, new_step)
        w, wb = w_star, None
        if self.s.whole_body:
            wb = self.stage.decide(w_star, UNCONSTRAINED, dyn.A, dyn.H, dyn.B, dyn.h_b, h_b_c)
            w = wb.w
        torque, _, _, tightest, zmp = self.stage.outputs(w, dyn.A, dyn.H, dyn.B, h_b_c)
        self._prev = (dyn.A, qd.copy(), np.array(w, dtype=float))
        self.t_last, self.decided = float(obs.t), True
        status = {"p": self.p, "p_dot": self.p_dot, "p_ddot": self.p_ddot, "tau": self.tau,
                  "tau_dot": self.tau_dot, "tau_ddot": self.tau_ddot, "p_target": self.targets.p,
                  "tau_dot_target": self.targets.tau_dot, "dcm": xi, "dcm_error": xi - xi_ref,
                  "time_left": self.targets.time_left, "step_frozen": bool(frozen),
                  "timing_adapted": bool(self.targets.timing_adapted), "force_estimate": self.force,
                  "zmp": zmp, "tightest": int(tightest), "max_tracking_error": float(np.max(np.abs(ref.q - q))),
                  **WholeBodyStage.status_fields(wb)}
        return ControlResult(np.asarray(torque, dtype=float), status)

    # ------------------------------------------------------------------ pieces
    def _compared_dcm(self) -> float:
        """The DCM the measured one is compared with [m]: the commanded reference's at this period's (p, p', tau,
        tau') when ``commanded_dcm`` (the adopted law), else the preferred step's xi_n(tau) (the first law)."""
        if self.s.commanded_dcm:
            return self.layer.reference_dcm(self.p, self.p_dot, self.tau, self.tau_dot)
        return self.layer.xi_n(self.tau)

    def _advance(self, h: float) -> None:
        """(p, p', tau, tau') over ``h`` [s] with the held p'', tau'' (exact for constant accelerations), p held
        to [p_min, p_max] (on a bound, the outward part of p' removed)."""
        if h <= 0.0:
            return
        p = self.p + self.p_dot * h + 0.5 * self.p_ddot * h * h
        p_dot = self.p_dot + self.p_ddot * h
        if p > self.ref.p_max:
            p, p_dot = self.ref.p_max, min(p_dot, 0.0)
        elif p < self.ref.p_min:
            p, p_dot = self.ref.p_min, max(p_dot, 0.0)
        self.p, self.p_dot = p, p_dot
        self.tau += self.tau_dot * h + 0.5 * self.tau_ddot * h * h
        self.tau_dot += self.tau_ddot * h

    def _observe(self, q: np.ndarray, qd: np.ndarray, dyn, h: float, new_step: bool) -> np.ndarray:
        """The reaction drift with the estimated torso force, h_b,c (module docstring); h_b when the observer
        is off. Sets ``force`` [N]."""
        if not (self.s.disturbance_observer and self.cfg.disturbance_observer):
            self.force = 0.0
            return dyn.h_b
        jp = self._ff.torso_point_jacobian(q, self.cfg.observer_height)[0]
        j6 = jp[3:]
        if self._prev is None or h <= 0.0:
            F = 0.0
        elif new_step:
            F = self.force
        else:
            A_prev, qd_prev, w_prev = self._prev
            r = A_prev @ ((qd - qd_prev) / h - w_prev)
            nrm = float(j6 @ j6)
            F = float(j6 @ r) / nrm if nrm > 1e-12 else 0.0
        self.force = F
        return dyn.h_b + (dyn.B @ np.linalg.solve(dyn.A, j6 * F) - jp[:3] * F)


def settings_for(**overrides) -> StepLayerSettings:
    """The configured settings with ``overrides`` (by name without the prefix), validated (tests, studies)."""
    return replace(StepLayerSettings.load(), **overrides).validate()
