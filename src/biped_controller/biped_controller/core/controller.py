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
actually elapsed when the next decision is taken (a period cut short by an impact is shorter).
At an impact (the measured stance leg changes) tau goes back to 0 (tau -= T is not used: the gait
restarts), p and p' are carried over; the measured q is already relabelled by the simulator.

Fallback when the QP is infeasible: the least-violation answer of ``AdaptationQP`` (status
INFEASIBLE_FALLBACK). The controller never raises inside the loop: a numerical failure gives
status SOLVER_ERROR and x = x*.

p is kept inside the family's valid range by two extra QP rows (p after one period within
[p_min, p_max]), and tau' > 0 by one row (tau' after one period >= tau_dot_min).

Modes ``wbc`` and ``hybrid`` (issue 26; :mod:`wbc`) add a whole-body stage after the decision:
``wbc`` keeps the reference (x = x*, as mode none: p = p_d, tau' = 1) and relaxes w itself by the
whole-body QP min (w - w*)' M (w - w*) s.t. the same 17 rows (twice) on w, w* = the tracking law's w;
``hybrid`` decides (p'', tau'') exactly as mode ``both`` and runs the same whole-body QP around the
adapted w only when the p/tau QP did not hold its rows (INFEASIBLE_FALLBACK or SOLVER_ERROR).
Whenever w holds every row the whole-body stage changes nothing (bit for bit).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from biped_sim.robot.description import RobotDescription, load_description
from biped_sim.robot.loop import ENGINES, load_loop_settings
from biped_sim.robot.settings import SettingsError, default_config_dir, read_settings

from biped_sim.robot.gait_family import GaitFamily, eq11
from biped_sim.robot.fixed_foot import N_CONSTRAINTS, Dynamics, FixedFootModel, contact_rows
from biped_controller.core.qp import SOLVER_ERROR, SOLVERS as QP_SOLVERS, AdaptationQP
from biped_controller.core.qp_types import UNCONSTRAINED
from biped_controller.core.wbc import WholeBodyStage, weight_matrix

MODES = ("none", "tau", "p", "both", "wbc", "hybrid")
#: the paper's four modes: the default set of the tables and maps (wbc and hybrid on request, --modes)
PAPER_MODES = ("none", "tau", "p", "both")
#: the parameters each mode's p/tau QP adapts (0: p'', 1: tau''); wbc keeps the reference fixed like none
ADAPTED = {"none": (), "tau": (1,), "p": (0,), "both": (0, 1), "wbc": (), "hybrid": (0, 1)}
# rows of the adaptation QP: the 17 constraints with the estimated push force, the same without it,
# and 3 parameter-range rows (p within the family's range, tau' >= tau_dot_min)
QP_ROWS = 2 * N_CONSTRAINTS + 3
NO_ADAPTATION = 4
NO_ADAPTATION_STATUS = NO_ADAPTATION
_FIXED_REFERENCE = {"none": "mode none: classical computed torque",
                    "wbc": "mode wbc: fixed reference, whole-body QP on w"}


class ControllerConfigError(ValueError):
    """A controller setting is missing or out of range (message names it)."""


@dataclass(frozen=True)
class ControllerConfig:
    """Controller settings. The values and their reasons live in ``config/controller.yaml`` only (the
    control period in ``config/simulator.yaml``): build one with :func:`load_controller_config`."""

    mode: str                     # none | tau | p | both | wbc | hybrid (MODES, ADAPTED)
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
    qp_solver: str                # "piqp" (the product's solver) or "exact" (dedicated n <= 2 solver)
    disturbance_observer: bool    # estimate a horizontal torso force (not in the paper) for the QP rows
    observer_height: float        # [m] assumed application height of the estimated force above the hip
    wbc_weight_joint: float       # whole-body QP weight M = wbc_weight_joint I + wbc_weight_torso s s^T (wbc.py)
    wbc_weight_torso: float       # torso-pitch task weight of M (s . w = torso pitch acceleration)
    engine: str                   # "fast": compiled model terms (biped_sim.robot.fast_engine); "reference": Pinocchio
    period: float                 # [s] control period (config/simulator.yaml control_period)

    def validate(self) -> "ControllerConfig":
        if self.engine not in ENGINES:
            raise ControllerConfigError(f"engine must be one of {ENGINES}, got {self.engine!r}")
        if self.qp_solver not in QP_SOLVERS:
            raise ControllerConfigError(f"qp_solver must be one of {QP_SOLVERS}, got {self.qp_solver!r}")
        if self.mode not in MODES:
            raise ControllerConfigError(f"mode must be one of {MODES}, got {self.mode!r}")
        for name in ("Kp", "Kv", "kp", "kv", "weight_p", "weight_tau", "period", "tau_dot_min"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ControllerConfigError(f"{name} must be a finite number > 0, got {v!r}")
        for name in ("margin_normal_force", "margin_zmp", "margin_torque"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ControllerConfigError(f"{name} must be a finite number >= 0, got {v!r}")
        if not isinstance(self.disturbance_observer, bool):
            raise ControllerConfigError(f"disturbance_observer must be true or false, got {self.disturbance_observer!r}")
        if isinstance(self.observer_height, bool) or not isinstance(self.observer_height, (int, float)) \
                or not math.isfinite(self.observer_height):
            raise ControllerConfigError(f"observer_height must be a finite number, got {self.observer_height!r}")
        try:
            weight_matrix(self.wbc_weight_joint, self.wbc_weight_torso)
        except ValueError as exc:
            raise ControllerConfigError(str(exc)) from exc
        if not (0 < self.margin_friction <= 1):
            raise ControllerConfigError(f"margin_friction must be in (0, 1], got {self.margin_friction}")
        return self


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
        # one home for both: the loop's settings in config/simulator.yaml (biped_sim.robot.loop)
        loop = load_loop_settings()
        kw["period"], kw["engine"] = loop.control_period, loop.engine
    kw.update(overrides)
    return ControllerConfig(**kw).validate()


@dataclass
class ParamState:
    """The trajectory parameters: stride p [m], p' [m/s], phase tau [s], tau' [-]."""

    p: float
    p_dot: float
    tau: float
    tau_dot: float


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
    wbc_status: int = NO_ADAPTATION_STATUS   # whole-body stage (modes wbc, hybrid): qp_types status, or 4 = not run
    wbc_active: int = 0                      # bit i: row CONSTRAINT_NAMES[i] active in the whole-body QP's answer
    wbc_deviation: float = 0.0               # [rad/s^2] |w - w*| of the whole-body stage (0 when w* held)


@dataclass(frozen=True)
class _Reference:
    """The reference terms of one period: w = D x + v (eq. 17), x* (eq. 20), tracking error q_d - q."""

    D: np.ndarray          # (6, 2) [dq_d/dp, dq_d/dtau]
    v: np.ndarray          # (6,) rad/s^2
    x_star: np.ndarray     # (2,) (p''*, tau''*)
    error: np.ndarray      # (6,) rad


@dataclass(frozen=True)
class _Previous:
    """What the observer needs of the last period: measured q', commanded w, A, stance, time."""

    qd: np.ndarray
    w: np.ndarray
    A: np.ndarray
    stance: int
    t: float


@dataclass(frozen=True)
class ControlOutput:
    torque: np.ndarray            # paper q1..q6 [N m]
    status: ControllerStatusData
    G: np.ndarray | None = None   # the QP instance (for benchmarks/tests); None in mode 'none'
    h: np.ndarray | None = None
    x_star: np.ndarray | None = None


class AdaptiveController:
    """Owns its FixedFootModel (own Pinocchio Data) and its PIQP solver object."""

    def __init__(self, config: ControllerConfig | None = None, family: GaitFamily | None = None,
                 desc: RobotDescription | None = None, keep_qp: bool = False):
        self.cfg = (config if config is not None else load_controller_config()).validate()
        self.desc = desc if desc is not None else load_description()
        self.family = family if family is not None else GaitFamily.load()
        self.model = FixedFootModel(self.desc)
        self._fast = None
        self._kernel = None
        if self.cfg.engine == "fast":
            from biped_sim.robot.fast_engine import FastFixedFootModel   # compiled kernels only when used
            self._fast = FastFixedFootModel(self.desc)
        self.keep_qp = keep_qp
        c = self.cfg
        # constraint margins (subtracted from the right-hand side), in the row order of CONSTRAINT_NAMES
        self.margin = np.concatenate([
            [c.margin_normal_force, 0.0, 0.0, 0.0, 0.0], np.full(12, c.margin_torque)])
        self._mu_ratio = c.margin_friction
        self.adapted = ADAPTED[c.mode]
        self._adapted_idx = list(self.adapted)
        self._fixed_idx = [i for i in (0, 1) if i not in self.adapted]
        n = len(self.adapted)
        self.qp = AdaptationQP(n, QP_ROWS, np.array([c.weight_p, c.weight_tau])[list(self.adapted)],
                               solver=c.qp_solver) if n else None
        self.state = ParamState(self.family.p_d, 0.0, 0.0, 1.0)
        self.stance: int | None = None
        self.step_index = 0
        self._decision = (0.0, 0.0)
        self._prev: _Previous | None = None
        self._t_last = None            # time of the last decision [s]
        self.force_estimate = 0.0      # estimated horizontal force on the torso [N]
        m = self.model
        self.whole_body = WholeBodyStage.for_controller(c, m) if c.mode in ("wbc", "hybrid") else None
        if self._fast is not None:
            self._kernel = _FastPeriod(self)   # the compiled period (fast engine)

    def reset(self, stance: int | None = None) -> None:
        self.state = ParamState(self.family.p_d, 0.0, 0.0, 1.0)
        self.stance = stance
        self.step_index = 0
        self._prev = None
        self.force_estimate = 0.0
        self._t_last = None

    # --------------------------------------------------------------- the steps of one period
    def _advance_parameters(self, t: float, stance: int) -> None:
        """(p, p', tau, tau') advance over the time actually elapsed since the last decision, with the
        constant p'', tau'' chosen then (exact integration; a period cut short by an impact is shorter).
        The elapsed time comes from integer nanoseconds, so a time that travelled through a ROS stamp
        gives bit-identical arithmetic to the in-process float time. At an impact (the measured stance
        changes) the next step starts: tau = 0; p, p', tau' carry over."""
        if self._t_last is not None:
            h_el = (round(t * 1e9) - round(self._t_last * 1e9)) * 1e-9
            s0 = self.state
            p_dd0, t_dd0 = self._decision
            s0.p += s0.p_dot * h_el + 0.5 * p_dd0 * h_el * h_el
            s0.p_dot += p_dd0 * h_el
            s0.tau += s0.tau_dot * h_el + 0.5 * t_dd0 * h_el * h_el
            s0.tau_dot += t_dd0 * h_el
        self._t_last = t
        if self.stance is not None and stance != self.stance:
            self.state.tau = 0.0
        self.stance = stance

    def _reference(self, q: np.ndarray, qd: np.ndarray) -> _Reference:
        """Eqs. (11), (16), (17), (20): w = D x + v with D = [dq/dp, dq/dtau], x = (p'', tau''), and the
        second task's x* = (-k_v p' + k_p (p_d - p), k_v (1 - tau'))."""
        s, c, fam = self.state, self.cfg, self.family
        g = fam.evaluate(s.p, s.tau)
        q_d, qd_d, qdd_drift = eq11(g, s.p_dot, s.tau_dot)
        e = q_d - q
        v = qdd_drift + c.Kv * (qd_d - qd) + c.Kp * e
        D = np.column_stack([g.dq_dp, g.dq_dtau])
        x_star = np.array([-c.kv * s.p_dot + c.kp * (fam.p_d - s.p), c.kv * (1.0 - s.tau_dot)])
        return _Reference(D=D, v=v, x_star=x_star, error=e)

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

    def _observe(self, t: float, qd: np.ndarray, stance: int, dyn: Dynamics, Jp: np.ndarray | None
                 ) -> tuple[Dynamics, float]:
        """Disturbance observer (ours, not the paper's; ``disturbance_observer``): the joint-space residual
        of the last period, r = A (a_measured - w_applied), explained by a horizontal force F on the torso
        at ``observer_height`` (least squares, one unknown): r = J6^T F. F only enters the prediction of
        the ground reaction used by the QP: with F acting, the joint acceleration is w + A^-1 J6^T F, so
        R = B (w + A^-1 J6^T F) + h_b - Jb^T F, i.e. h_b is shifted. One period of lag. Returns the
        dynamics with the shifted h_b (``dyn`` itself when the observer is off) and F [N]."""
        if not self.cfg.disturbance_observer:
            return dyn, 0.0
        j6 = Jp[3:]                       # Jp: (9,) x-row of the torso point Jacobian
        F = 0.0
        if self._prev is not None and self._prev.stance != stance:
            # the last period ended with an impact: its residual is meaningless, but a push acting on the
            # torso does not care about the stance: keep the previous estimate
            F = self.force_estimate
        elif self._prev is not None:
            prev = self._prev
            dt = (round(t * 1e9) - round(prev.t * 1e9)) * 1e-9
            r = prev.A @ ((qd - prev.qd) / dt - prev.w)
            nrm = float(j6 @ j6)
            F = float(j6 @ r) / nrm if nrm > 1e-12 else 0.0
        delta = dyn.B @ np.linalg.solve(dyn.A, j6 * F) - Jp[:3] * F
        return replace(dyn, h_b=dyn.h_b + delta), F

    def _qp_rows(self, ref: _Reference, dyn: Dynamics, dyn_c: Dynamics) -> tuple[np.ndarray, np.ndarray]:
        """Eq. (21): G x <= h over x = (p'', tau'') (both columns; the caller keeps the adapted ones).

        The 17 rows of eq. (18) with the controller's margins (tighter mu, l range, R_y >= margin, ...),
        stated twice, robust to the push ending: with the estimated force (``dyn_c``) and without it
        (``dyn``), since the push may stop during the coming period (identical rows when F = 0). The
        estimate only shifts h_b, so the matrix rows are the same and only the five contact offsets differ
        by C (h_b,c - h_b). Then three parameter-range rows: p + p' dt + p'' dt^2/2 within [p_min, p_max],
        tau' + tau'' dt >= tau_dot_min."""
        c, s, fam, m = self.cfg, self.state, self.family, self.model
        mu = c.margin_friction * m.mu
        lm, lM = m.l_min + c.margin_zmp, m.l_max - c.margin_zmp
        cm = m.constraints(None, None, dyn_c, mu=mu, l_min=lm, l_max=lM)
        A, b = cm.A_q, cm.b_q + self.margin
        b0 = b
        if dyn_c is not dyn:
            C, _ = contact_rows(mu, lm, lM)
            b0 = b.copy()
            b0[:5] -= C @ (dyn_c.h_b[:2] - dyn.h_b[:2])
        AD = A @ ref.D
        Av = A @ ref.v
        dt = c.period
        G = np.vstack([AD, AD, [[0.5 * dt * dt, 0.0], [-0.5 * dt * dt, 0.0], [0.0, -dt]]])
        h = np.concatenate([-(Av + b), -(Av + b0),
                            [fam.p_max - s.p - s.p_dot * dt, s.p + s.p_dot * dt - fam.p_min, s.tau_dot - c.tau_dot_min]])
        return G, h

    def _decide(self, ref: _Reference, dyn: Dynamics, dyn_c: Dynamics):
        """Eqs. (19)-(21): x = x* when it satisfies the rows, else the QP's answer over the adapted
        parameters (the others stay at x*). Returns (x (2,), status, message, G, h, x*) with the reduced
        instance (None in mode none)."""
        x = ref.x_star.copy()
        if not self.adapted:
            return x, NO_ADAPTATION, _FIXED_REFERENCE[self.cfg.mode], None, None, None
        try:
            Gall, hall = self._qp_rows(ref, dyn, dyn_c)
            idx, fixed = self._adapted_idx, self._fixed_idx
            h = hall - Gall[:, fixed] @ x[fixed] if fixed else hall
            G, xs = Gall[:, idx], x[idx]
            res = self.qp.solve(G, h, xs)
            x[idx] = res.x
            if not np.all(np.isfinite(x)):
                raise FloatingPointError("non-finite QP answer")
            return x, res.status, res.message, G, h, xs
        except (FloatingPointError, np.linalg.LinAlgError) as exc:
            # numerical failure only (programming errors such as QPShapeError propagate): desired values
            return ref.x_star.copy(), SOLVER_ERROR, f"{type(exc).__name__}: {exc}", None, None, None

    def compute(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int) -> ControlOutput:
        """One control period: advance the parameters, observe, reference, rows, decide, torque.

        With the fast engine the steps after the advance are one compiled call
        (``control_kernels.step``, the same equations) and, when x* is not feasible, the QP and one more
        call; a non-finite value anywhere falls back to the reference steps below."""
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        self._advance_parameters(t, stance)
        if self._kernel is not None:
            out = self._kernel.compute(t, q, qd, stance)
            if out is not None:
                return out
        s = self.state
        ref = self._reference(q, qd)
        dyn, jp = self._model_terms(q, qd)                     # eq. (1): A, H and the reaction rows
        dyn_c, F = self._observe(t, qd, stance, dyn, jp)
        x, status, msg, G, h, xs = self._decide(ref, dyn, dyn_c)
        w = ref.D @ x + ref.v                                    # eq. (17)
        wb = None
        if self.whole_body is not None:                          # modes wbc, hybrid (wbc.py)
            wb = self.whole_body.decide(w, status, dyn.A, dyn.H, dyn.B, dyn.h_b, dyn_c.h_b)
            if wb is not None:
                w = wb.w
        torque = dyn.A @ w + dyn.H                               # eq. (15)
        cm = self.model.constraints(q, qd, dyn_c)
        margins = -(cm.A_q @ w + cm.b_q)
        R = dyn_c.B[:2] @ w + dyn_c.h_b[:2]
        p_dd, t_dd = float(x[0]), float(x[1])
        status_rec = ControllerStatusData(
            step=self.step_index, t=t, mode=self.cfg.mode, p=s.p, p_dot=s.p_dot, tau=s.tau, tau_dot=s.tau_dot,
            p_ddot=p_dd, tau_ddot=t_dd, p_ddot_star=float(ref.x_star[0]), tau_ddot_star=float(ref.x_star[1]),
            qp_status=int(status), qp_message=msg, margins=margins,
            tightest=int(np.argmin(margins / self.model.row_scale)),
            zmp=float(torque[0] / R[1]) if R[1] != 0 else math.nan, stance=int(stance),
            max_tracking_error=float(np.max(np.abs(ref.error))), predicted_reaction=R, force_estimate=F,
            **WholeBodyStage.status_fields(wb),
        )
        self.force_estimate = F
        self._prev = _Previous(qd=qd.copy(), w=w, A=dyn.A, stance=stance, t=t)
        self._decision = (p_dd, t_dd)
        self._period_start = ParamState(s.p, s.p_dot, s.tau, s.tau_dot)
        self.step_index += 1
        keep = self.keep_qp
        return ControlOutput(torque=torque, status=status_rec, G=G if keep else None, h=h if keep else None,
                             x_star=xs if keep else None)

    def torque_within_period(self, s_time: float, q: np.ndarray, qd: np.ndarray, stance: int) -> np.ndarray:
        """Computed torque at time s_time into the current period, with (p, tau) propagated by the
        period's decision (p'', tau'') and no new QP: the controller "at the integration rate"."""
        s0 = self._period_start
        p_dd, t_dd = self._decision
        p = s0.p + s0.p_dot * s_time + 0.5 * p_dd * s_time**2
        pdot = s0.p_dot + p_dd * s_time
        tau = s0.tau + s0.tau_dot * s_time + 0.5 * t_dd * s_time**2
        taud = s0.tau_dot + t_dd * s_time
        qr, qdr, qddr = eq11(self.family.evaluate(p, tau), pdot, taud, p_dd, t_dd)
        c = self.cfg
        w = qddr + c.Kv * (qdr - qd) + c.Kp * (qr - q)
        dyn, _ = self._model_terms(q, qd)
        return dyn.A @ w + dyn.H


class _FastPeriod:
    """The compiled period of an :class:`AdaptiveController` (fast engine): packs the controller's
    settings once, its state every period, into the arrays of ``control_kernels.step`` and unpacks the
    answer into the same ``ControlOutput`` and observer memory as the reference steps."""

    def __init__(self, ctrl: AdaptiveController):
        from biped_controller.core import control_kernels as ck
        self.ck = ck
        self.ctrl = ctrl
        c, m, fam = ctrl.cfg, ctrl.model, ctrl.family
        self.coef, self.inner, self.centers = fam.piece_arrays()
        self.ti, self.tf = ctrl._fast.ti, ctrl._fast.tf
        par = np.zeros(ck.PAR_SIZE)
        par[ck.P_KP], par[ck.P_KV], par[ck.P_KP2], par[ck.P_KV2] = c.Kp, c.Kv, c.kp, c.kv
        par[ck.P_PD] = fam.p_d
        par[ck.P_DT] = c.period
        par[ck.P_PMIN], par[ck.P_PMAX], par[ck.P_TAUD_MIN] = fam.p_min, fam.p_max, c.tau_dot_min
        par[ck.P_OBS_ON] = 1.0 if c.disturbance_observer else 0.0
        par[ck.P_OBS_H] = c.observer_height
        par[ck.P_ADAPT_P] = 1.0 if 0 in ctrl.adapted else 0.0
        par[ck.P_ADAPT_TAU] = 1.0 if 1 in ctrl.adapted else 0.0
        self.par = par
        # the contact rows as data (model.contact_rows, written once): the QP's with the controller's
        # margins on mu and the foot range, the robot's own for the reported margins
        qp_C, qp_e = contact_rows(c.margin_friction * m.mu, m.l_min + c.margin_zmp, m.l_max - c.margin_zmp)
        true_C, true_e = contact_rows(m.mu, m.l_min, m.l_max)
        self.cons = np.concatenate([ctrl.margin, m.row_scale, m.torque_min, m.torque_max,
                                    np.column_stack([qp_C, qp_e]).ravel(),
                                    np.column_stack([true_C, true_e]).ravel()]).astype(float)
        assert self.cons.size == ck.CONS_SIZE
        self.prev = np.zeros((8, 6))
        self.G = np.zeros((ck.QP_ROWS, 2))
        self.h = np.zeros(ck.QP_ROWS)

    def compute(self, t: float, q: np.ndarray, qd: np.ndarray, stance: int) -> ControlOutput | None:
        ck, ctrl, par = self.ck, self.ctrl, self.par
        s = ctrl.state
        par[ck.P_P], par[ck.P_PDOT], par[ck.P_TAU], par[ck.P_TAUDOT] = s.p, s.p_dot, s.tau, s.tau_dot
        prev = ctrl._prev
        if prev is None:
            par[ck.P_OBS_MODE] = ck.OBS_NONE
        elif prev.stance != stance:
            par[ck.P_OBS_MODE] = ck.OBS_KEEP
            par[ck.P_F_PREV] = ctrl.force_estimate
        else:
            par[ck.P_OBS_MODE] = ck.OBS_RESIDUAL
            par[ck.P_OBS_DT] = (round(t * 1e9) - round(prev.t * 1e9)) * 1e-9
            P = self.prev
            P[0] = prev.qd
            P[1] = prev.w
            P[2:] = prev.A
        if q.dtype != np.float64 or not q.flags.c_contiguous:
            q = np.ascontiguousarray(q, dtype=float)
        if qd.dtype != np.float64 or not qd.flags.c_contiguous:
            qd = np.ascontiguousarray(qd, dtype=float)
        work = np.empty((ck.WORK_ROWS, 6))
        res = np.empty(ck.RES_SIZE)
        G, h = self.G, self.h
        code = ck.step(self.coef, self.inner, self.centers, self.ti, self.tf, q, qd, par, self.cons, self.prev,
                       G, h, work, res)
        if code == ck.NONFINITE:
            return None
        xs_full = res[ck.R_XS:ck.R_XS + 2]
        Gr = hr = xs = None
        if not ctrl.adapted:
            status, msg = NO_ADAPTATION, _FIXED_REFERENCE[ctrl.cfg.mode]
        else:
            idx, fixed = ctrl._adapted_idx, ctrl._fixed_idx
            Gr, xs = G[:, idx], xs_full[idx]
            hr = h - G[:, fixed] @ xs_full[fixed] if fixed else h.copy()
            if code == ck.FEASIBLE:
                status, msg = UNCONSTRAINED, "x* feasible"
            else:
                qres = ctrl.qp.solve(Gr, hr, xs)
                x = xs_full.copy()
                x[idx] = qres.x
                if not np.all(np.isfinite(x)):
                    return None
                status, msg = qres.status, qres.message
                res[ck.R_X:ck.R_X + 2] = x
                ck.finish(par, self.cons, work, res)
        torque = work[ck.W_TORQUE].copy()
        w = work[ck.W_W].copy()
        F = float(res[ck.R_F])
        p_dd, t_dd = float(res[ck.R_X]), float(res[ck.R_X + 1])
        margins, tightest, zmp = res[ck.R_MARGINS:].copy(), int(res[ck.R_TIGHT]), float(res[ck.R_ZMP])
        R = res[ck.R_R:ck.R_R + 2].copy()
        wb = None
        if ctrl.whole_body is not None:        # modes wbc, hybrid: the whole-body stage (wbc.py), in Python
            A, H, B = work[ck.W_A:ck.W_A + 6], work[ck.W_H], work[ck.W_B:ck.W_B + 3]
            hbc = res[ck.R_HBC:ck.R_HBC + 3]
            wb = ctrl.whole_body.decide(w, status, A, H, B, res[ck.R_HB:ck.R_HB + 3], hbc)
            if wb is not None and wb.status != UNCONSTRAINED:
                w = wb.w
                torque, R, margins, tightest, zmp = ctrl.whole_body.outputs(w, A, H, B, hbc)
        status_rec = ControllerStatusData(
            step=ctrl.step_index, t=t, mode=ctrl.cfg.mode, p=s.p, p_dot=s.p_dot, tau=s.tau, tau_dot=s.tau_dot,
            p_ddot=p_dd, tau_ddot=t_dd, p_ddot_star=float(xs_full[0]), tau_ddot_star=float(xs_full[1]),
            qp_status=int(status), qp_message=msg, margins=margins, tightest=tightest,
            zmp=zmp, stance=int(stance), max_tracking_error=float(res[ck.R_MAXERR]),
            predicted_reaction=R, force_estimate=F, **WholeBodyStage.status_fields(wb))
        ctrl.force_estimate = F
        ctrl._prev = _Previous(qd=qd.copy(), w=w, A=work[ck.W_A:ck.W_A + 6].copy(), stance=stance, t=t)
        ctrl._decision = (p_dd, t_dd)
        ctrl._period_start = ParamState(s.p, s.p_dot, s.tau, s.tau_dot)
        ctrl.step_index += 1
        keep = ctrl.keep_qp
        return ControlOutput(torque=torque, status=status_rec, G=Gr.copy() if keep and Gr is not None else None,
                             h=hr if keep else None, x_star=xs.copy() if keep and xs is not None else None)
