"""p/tau-adaptive computed-torque controller (paper section 4): the control law. Pure Python, no ROS.

The controller's other concerns have their own modules of ``core/control``: its settings and their checks
(``config``: ``ControllerConfig``, ``load_controller_config``, the modes), what a period reports
(``status``: ``ControllerStatusData``, ``ControlOutput``), and the compiled period that runs this law's
kernels (``controller_compiled``: ``CompiledPeriod``, the kernels' loaders).

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
runs it as well); the Python steps (and ``controller_compiled.CompiledPeriod.python_stage``, the tests' oracle) run
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
from dataclasses import dataclass, replace

import numpy as np

from biped_model.description import RobotDescription, load_description
from biped_model.gait_family import GaitFamily, eq11, eq11_torso
from biped_model.fixed_foot import N_CONSTRAINTS, Dynamics, FixedFootModel, contact_rows, relabel
from biped_model.layout import SnapshotUnsupported
from biped_controller.core.control.config import (ADAPTED, TORSO_MODES, ControllerConfig,
                                                   load_controller_config)
from biped_controller.core.control.controller_compiled import (CompiledPeriod, load_controller_kernels)
from biped_controller.core.control.controller_layout import (
    CONS, GAINS, MEMORY, OBS_KEEP, OBS_RESIDUAL, QP_ROWS, RES, TORSO_ROWS, WBC, WORK, M_, R_, W_,
    WB_)
from biped_controller.core.control.status import (MSG_FIXED_REFERENCE, NO_ADAPTATION,
                                                   ControllerStatusData, ControlOutput, status_records)
from biped_controller.core.qp.solver import SOLVER_ERROR, AdaptationQP
from biped_controller.core.qp.problem import ACTIVE, UNCONSTRAINED
from biped_controller.core.control.wbc import WBC_MODES, WholeBodyStage

_NEW = object.__new__


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
            self._kernel = CompiledPeriod(self)   # the compiled period (fast engine)

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
    def compiled_period(self) -> "CompiledPeriod | None":
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
