"""Physical simulator of the planar biped: floating base, rigid flat stance contact, impacts, pushes.

Pure Python (NumPy + Pinocchio through ``floating.FloatingModel``), no ROS.

Integration scheme: classical RK4 on the floating state (x, v) with ``substeps`` steps per control
period; control periods end on the grid k * control_period, except that a touchdown ends the current
period at the impact instant (an event-triggered control update right after every impact); joint torques are held constant over a period (zero-order hold) unless a torque *function* is
given (then it is evaluated at every RK4 stage: "controller at the integration rate"). In single
support the stance foot's (x, z, pitch) are held by a rigid contact: at every stage the contact
wrench comes from the Schur complement of the full dynamics (``FloatingModel.contact_dynamics``);
after every RK4 step the state is projected back onto the contact manifold (base pose corrected so the
foot sits exactly on its anchor, velocity projected onto J_c v = 0), which removes integration drift.

Physics decides everything, never the controller's bookkeeping:
  * fall checks on the actual wrench at each substep start: F_z > 0 (take-off), |F_x| <= mu F_z (slip),
    l = m / F_z inside [l_min, l_max] (tipping over heel or toe); the first violation ends the run;
  * touchdown: the lowest sole point of the swing foot reaches the ground while moving down, after the
    foot has cleared ``clearance_before_touchdown`` since the last impact; the crossing time is located
    by bisection, the foot is laid flat by its ankle angle (the paper's flat-foot impact), the inelastic
    impact map is applied and the legs exchange roles;
  * pushes: horizontal forces at a height on the torso, applied through that point's Jacobian over
    exactly [start, start + duration): the integration intervals are split at every push start and end,
    and on each interval the force is constant (the same at every RK4 stage), so the impulse delivered
    is exactly force x duration and nothing acts outside the window.
Deterministic: no randomness but a perturbation's seeded sensor noise, fixed operation order; the same
inputs give bit-identical records. Perturbations (``perturbation.PlantPerturbation``: model error,
friction, sensor noise and delay) act here only, never in the controller.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from biped_model.description import LEFT, RobotDescription, load_description
from biped_model.floating import paper_from_urdf, urdf_from_paper
from biped_model.floating_base import CompiledFloatingModel, FloatingBaseModel, make_floating_model
from biped_model.layout import SnapshotUnsupported
from biped_sim.plant.period_grid import grid_end, period_knots
from biped_sim.plant.push import Push, ScheduledPushes
from biped_sim.plant.perturbation import ZERO, PerturbationError, PlantPerturbation, SensorModel
from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.records import FallInfo, ImpactRecord, Observation, StepRecord
from biped_sim.plant.rigid_layout import L_, S_, SIM_LIMITS, SIM_STATE

TorqueFn = Callable[[float, np.ndarray, np.ndarray, int], np.ndarray]


def _state_field(name: str, kind):
    """A property over field ``name`` of the simulator's ``sim_state`` array: a scalar as ``kind``, a vector
    as a view (assigning copies into the array)."""
    sl = SIM_STATE.slice(name)
    if SIM_STATE.sizes[name] == 1:
        o = sl.start
        return property(lambda self: kind(self.sim_state[o]), lambda self, v: self.sim_state.__setitem__(o, v),
                        doc=f"SIM_STATE.{name}")

    def set_(self, value):
        self.sim_state[sl] = value
    return property(lambda self: self.sim_state[sl], set_, doc=f"SIM_STATE.{name} (a view of the state array)")


@dataclass(frozen=True, eq=False)
class SimSnapshot:
    """Everything :class:`Simulator` carries from one period to the next: a copy of its
    ``sim_state`` array (t, period index, stance, clearance, anchor, x, v), the impacts so far, the fall
    (None while walking) and the push schedule. Impact records are immutable and shared, not copied."""

    sim_state: np.ndarray
    impact_count: int
    impact_log: tuple[ImpactRecord, ...]
    fall: FallInfo | None
    pushes: tuple[Push, ...]
    next_push_id: int


class Simulator(ScheduledPushes):
    """Owns its FloatingModel (own Pinocchio Data).

    Its per-period state is the array ``sim_state`` (``rigid_layout.SIM_STATE``): ``t``, ``step_index``,
    ``stance``, ``cleared``, ``anchor``, ``x``, ``v`` are views of it (``x``, ``v``, ``anchor`` are array views:
    copy them to keep a value); its fixed limits are ``limits`` (``SIM_LIMITS``). The compiled closed loop
    takes the same arrays.

    ``perturbation`` (``biped_sim.plant.perturbation``; None = none): the simulated plant is
    ``perturbation.apply(desc)`` (``self.desc``: masses, centres of mass, inertias, friction of the fall
    checks), ``self.nominal_desc`` is ``desc`` as given (the controller's model); :meth:`observe` returns
    what the sensors report (noise, delay: ``self.sensor``) while every record keeps the true state."""

    t = _state_field("t", float)
    step_index = _state_field("step", int)
    stance = _state_field("stance", int)
    cleared = _state_field("cleared", bool)
    anchor = _state_field("anchor", None)
    x = _state_field("x", None)
    v = _state_field("v", None)

    def __init__(self, desc: RobotDescription | None = None, config: SimConfig | None = None,
                 perturbation: PlantPerturbation | None = None):
        self.nominal_desc = desc if desc is not None else load_description()
        self.perturbation = perturbation if perturbation is not None else ZERO
        self.desc = self.perturbation.apply(self.nominal_desc)      # the plant
        self.sensor = SensorModel(self.perturbation)
        self.cfg = (config if config is not None else load_sim_config()).validate()
        self.fm: FloatingBaseModel = make_floating_model(self.desc, self.cfg.engine)
        self._fast = isinstance(self.fm, CompiledFloatingModel)
        self._pk = self.fm.pk if self._fast else None       # the compiled kernels (fast engine)
        self._tau_const: np.ndarray | None = None   # the period's held URDF torque (fast RK4 kernel)
        self.book = self._new_book()
        self.sim_state = SIM_STATE.new()
        self.stance = LEFT
        self.limits = self._limits()
        self.fall: FallInfo | None = None
        self.impact_count = 0
        self.cleared = False
        self.impact_log: list[ImpactRecord] = []

    @property
    def compiled(self) -> bool:
        """True on the fast engine (the compiled kernels: ``self.fm`` is a ``CompiledFloatingModel``)."""
        return self._fast

    def _limits(self) -> np.ndarray:
        """The ``SIM_LIMITS`` array of this plant and configuration."""
        d, c, lim = self.desc, self.cfg, SIM_LIMITS.new()
        lo, hi = d.torque_limits()
        for name, value in (("mu", d.mu), ("l_min", d.foot.l_min), ("l_max", d.foot.l_max),
                            ("touchdown_tolerance", c.touchdown_tolerance), ("clearance", c.clearance_before_touchdown),
                            ("liftoff_penetration", c.liftoff_penetration), ("dt", c.control_period),
                            ("substeps", float(c.substeps)), ("torque_min", lo), ("torque_max", hi)):
            lim[SIM_LIMITS.slice(name)] = value
        return lim

    # ------------------------------------------------------------ setup
    def reset(self, q: np.ndarray, qd: np.ndarray, stance: int = LEFT, ankle_x: float = 0.0) -> None:
        """Start from paper (q, q') with the stance foot flat at (ankle_x, 0)."""
        self.x, self.v = self.fm.state_from_paper(np.asarray(q, float), np.asarray(qd, float), stance, ankle_x)
        self.stance = stance
        self.anchor = np.array([ankle_x, 0.0, 0.0])
        self.t = 0.0
        self.step_index = 0
        self.fall = None
        self.impact_count = 0
        self.cleared = False
        self.impact_log = []
        self.book = self._new_book()
        self.sensor.reset()

    def snapshot(self) -> SimSnapshot:
        """The state between two periods (:class:`SimSnapshot`); :meth:`restore` brings it back, after which
        every period is bit-identical to the one that followed the snapshot. Raises
        :class:`SnapshotUnsupported` with a sensor model (its noise generator and delay line are not part
        of the state arrays)."""
        if not self.sensor.identity:
            raise SnapshotUnsupported("Simulator.snapshot: a sensor model (noise, quantisation, delay) carries "
                                      "state outside sim_state")
        return SimSnapshot(self.sim_state.copy(), self.impact_count, tuple(self.impact_log),
                           None if self.fall is None else FallInfo(**self.fall.__dict__),
                           tuple(self.book.pushes), self.book.next_id)

    def restore(self, snap: SimSnapshot) -> None:
        """Back to the state of :meth:`snapshot` (the arrays copied in; the same object goes on)."""
        self.sim_state[:] = snap.sim_state
        self.impact_count = snap.impact_count
        self.impact_log = list(snap.impact_log)
        self.fall = None if snap.fall is None else FallInfo(**snap.fall.__dict__)
        self.book = self._new_book()
        self.book.pushes.extend(snap.pushes)
        self.book.next_id = snap.next_push_id
        self._tau_const = None

    # ------------------------------------------------------------ queries
    def observe(self) -> Observation:
        """What the controller measures at the start of the current period: the true paper (q, q') and
        stance, or with a perturbation's sensor model the noisy sample of ``delay`` periods ago (time and
        period index are the current ones)."""
        q, qd = self.fm.paper_from_state(self.x, self.v, self.stance)
        pitch = float(self.x[2])          # the torso (the floating base) pitch in the world
        rate = float(self.v[2])           # and its rate (the IMU's gyro)
        if self.sensor.identity:
            return Observation(self.step_index, self.t, self.stance, q, qd, pitch, rate)
        self.sensor.sample(self.step_index, self.stance, q, qd, pitch, rate)
        stance, qs, qds = self.sensor.reading(self.step_index)
        return Observation(self.step_index, self.t, stance, qs, qds, *self.sensor.imu_reading(self.step_index))

    def push_force_at(self, t: float) -> list[tuple[float, float]]:
        """(force [N], height [m]) of every push acting at instant ``t`` (on over [start, end))."""
        return [(p.force, p.height) for p in self.pushes if p.start <= t < p.end]

    def _generalized_force(self, x: np.ndarray, tau_j: np.ndarray, pushes) -> np.ndarray:
        tau = np.zeros(9)
        tau[3:] = tau_j
        for f, h in pushes:
            tau += self.fm.push_jacobian(x, h).T @ np.array([f, 0.0])
        return tau

    def _accel(self, x, v, tau_j, pushes):
        sol = self.fm.contact_dynamics(x, v, self._generalized_force(x, tau_j, pushes), self.stance)
        return sol.a, sol.wrench

    def _check_wrench(self, w: np.ndarray, t: float) -> FallInfo | None:
        fx, fz, m = w
        mu = self.desc.mu
        if not np.all(np.isfinite(w)):
            return FallInfo("numerical", t, f"non-finite contact wrench {w}")
        if fz <= 0.0:
            return FallInfo("take_off", t, f"normal force F_z = {fz:.3f} N <= 0", dict(fx=fx, fz=fz, m=m))
        if abs(fx) > mu * fz:
            side = "forward" if fx > 0 else "backward"
            return FallInfo("slip", t, f"|F_x| = {abs(fx):.3f} N > mu F_z = {mu * fz:.3f} N (friction {side})",
                            dict(fx=fx, fz=fz, m=m))
        l = m / fz
        if l < self.desc.foot.l_min:
            return FallInfo("tip_heel", t, f"centre of pressure l = {l:.4f} m behind the heel ({self.desc.foot.l_min} m)",
                            dict(fx=fx, fz=fz, m=m, l=l))
        if l > self.desc.foot.l_max:
            return FallInfo("tip_toe", t, f"centre of pressure l = {l:.4f} m beyond the toe ({self.desc.foot.l_max} m)",
                            dict(fx=fx, fz=fz, m=m, l=l))
        return None

    # ------------------------------------------------------------ integration
    def _project(self, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Put the stance foot exactly on its anchor and remove the velocity normal to the manifold."""
        x = x.copy()
        pose = self.fm.foot_pose(x, self.stance)
        x[2] += self.anchor[2] - pose[2]
        pose = self.fm.foot_pose(x, self.stance)
        x[0] += self.anchor[0] - pose[0]
        x[1] += self.anchor[1] - pose[1]
        J = self.fm.contact_jacobian(x, self.stance)
        MiJt = self.fm.inverse_mass_matrix(x) @ J.T
        v = v - MiJt @ np.linalg.solve(J @ MiJt, J @ v)
        return x, v

    def _rk4(self, x, v, tau_src, t, h, pushes):
        """One RK4 step of length h from time t; ``pushes`` act with a constant force over the step.
        With the fast engine and a held torque, the whole step (and the projection) is one compiled call."""
        if self._fast and self._tau_const is not None:
            xn, vn, _ = self.fm.rk4_step(x, v, self._tau_const, pushes, self.stance, self.anchor, h)
            return xn, vn
        def f(xx, vv, tt):
            tj = tau_src(tt, xx, vv)
            a, _ = self._accel(xx, vv, tj, pushes)
            return vv, a
        k1x, k1v = f(x, v, t)
        k2x, k2v = f(x + 0.5 * h * k1x, v + 0.5 * h * k1v, t + 0.5 * h)
        k3x, k3v = f(x + 0.5 * h * k2x, v + 0.5 * h * k2v, t + 0.5 * h)
        k4x, k4v = f(x + h * k3x, v + h * k3v, t + h)
        xn = x + (h / 6.0) * (k1x + 2 * k2x + 2 * k3x + k4x)
        vn = v + (h / 6.0) * (k1v + 2 * k2v + 2 * k3v + k4v)
        return self._project(xn, vn)

    def _lowest_sole(self, x: np.ndarray, foot: int) -> float:
        return float(np.min(self.fm.sole_points(x, foot)[:, 1]))

    def _touchdown(self, x: np.ndarray, v: np.ndarray) -> bool:
        swing = 1 - self.stance
        z = self._lowest_sole(x, swing)
        if not self.cleared:
            return False
        if z > self.cfg.touchdown_tolerance:
            return False
        vz = self.fm.foot_velocity(x, v, swing)[1]
        pts = self.fm.sole_points(x, swing)
        # moving down at the lowest point (ankle vertical rate plus rotation effect is captured by the
        # lowest point's height decreasing; use the ankle rate and the pitch rate together)
        fv = self.fm.foot_velocity(x, v, swing)
        i = int(np.argmin(pts[:, 1]))
        l = (self.desc.foot.l_min, self.desc.foot.l_max)[i]
        th = self.fm.foot_pose(x, swing)[2]
        vz_pt = fv[1] + l * math.cos(th) * fv[2]
        return vz_pt < 0.0 or vz < 0.0

    def _apply_impact(self, x: np.ndarray, v: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Touchdown at ``t``: lay the landing foot flat by its ankle (the paper's flat-foot impact; a
        configuration jump of the ankle joint only, velocities unchanged), apply the inelastic impact map
        in that configuration, exchange the legs' roles, project onto the new contact. Every stage is
        logged as an :class:`ImpactRecord`."""
        swing = 1 - self.stance
        x_minus = x.copy()
        tilt = float(self.fm.foot_pose(x, swing)[2])
        x_flat = x.copy()
        x_flat[5 if swing == LEFT else 8] -= tilt
        res = self.fm.impact(x_flat, v, swing)
        old = self.stance
        self.stance = swing
        ank = self.fm.foot_pose(x_flat, swing)
        self.anchor = np.array([ank[0], 0.0, 0.0])
        xn, vn = self._project(x_flat, res.v_plus)
        self.impact_count += 1
        self.cleared = False
        self.impact_log.append(ImpactRecord(
            index=self.impact_count, t=t, old_stance=old, new_stance=swing, x_minus=x_minus, v_minus=v.copy(),
            foot_tilt=tilt, x_flat=x_flat, v_plus=res.v_plus.copy(), x_plus=xn.copy(), v_plus_projected=vn.copy(),
            impulse=res.impulse.copy(), energy_loss=float(res.energy_loss),
            old_foot_velocity=res.old_foot_velocity.copy(), ankle_x=float(ank[0])))
        return xn, vn

    def _advance(self, x, v, tau_src, t0, t1):
        """Integrate [t0, t1] in one RK4 step with touchdown detection (bisection on the step length)."""
        pushes = self.interval_pushes(t0, t1)
        xn, vn = self._rk4(x, v, tau_src, t0, t1 - t0, pushes)
        if not self._touchdown(xn, vn):
            self._update_clearance(xn, t1)
            return xn, vn, t1
        swing = 1 - self.stance
        lo, hi = 0.0, t1 - t0
        while hi - lo > self.cfg.event_time_tolerance:
            mid = 0.5 * (lo + hi)
            xm, _ = self._rk4(x, v, tau_src, t0, mid, pushes)
            if self._lowest_sole(xm, swing) > self.cfg.touchdown_tolerance:
                lo = mid
            else:
                hi = mid
        xe, ve = self._rk4(x, v, tau_src, t0, hi, pushes)
        xi, vi = self._apply_impact(xe, ve, t0 + hi)
        # The control period ends at the impact: the controller is called right after it (event-triggered
        # update), so no held torque of the old stance is applied to the relabelled legs.
        return xi, vi, t0 + hi

    def _update_clearance(self, x: np.ndarray, t: float) -> None:
        """Clearance bookkeeping at the end ``t`` of an interval: the swing foot has cleared once its lowest
        sole point is above ``clearance_before_touchdown``; sinking below -``liftoff_penetration`` before
        that is the ``no_liftoff`` fall, at ``t`` (the step ends there)."""
        swing = 1 - self.stance
        z = self._lowest_sole(x, swing)
        if z > self.cfg.clearance_before_touchdown:
            self.cleared = True
        elif not self.cleared and z < -self.cfg.liftoff_penetration and self.fall is None:
            self.fall = FallInfo("no_liftoff", t, f"the released foot sank {-z * 1e3:.2f} mm into the ground "
                                 "before clearing it (double support is not modelled)")

    def _fast_period(self, knots: list[float], t_start: float, t_end: float, applied: np.ndarray,
                     obs_stance: int) -> StepRecord | None:
        """The whole period in one compiled call (``planar_kernels.period``: the same RK4 intervals, wrench
        checks, touchdown probe and clearance update as the event path below) when nothing happens in it.
        Returns None, with nothing changed, when the kernel meets an event (a failed wrench check, a
        touchdown candidate, a sinking foot, a singular or non-finite state) or two pushes share an
        interval: the caller then integrates the period on its event path."""
        pk = self._pk
        n = len(knots) - 1
        forces = np.zeros(n)
        heights = np.full(n, np.nan)
        if self.book.pushes:
            for i in range(n):
                act = self.interval_pushes(knots[i], knots[i + 1])
                if len(act) > 1:
                    return None
                if act:
                    forces[i], heights[i] = act[0]
        L = self.limits     # the period kernel's limits: mu, l_min, l_max, td tolerance, clearance, penetration, cleared
        lim = np.array([L[L_.mu], L[L_.l_min], L[L_.l_max], L[L_.touchdown_tolerance], L[L_.clearance],
                        L[L_.liftoff_penetration], self.sim_state[S_.cleared]])
        xo = np.empty(9)
        vo = np.empty(9)
        w0 = np.empty(3)
        out = np.empty(pk.PERIOD_OUT_SIZE)
        status = pk.period(self.fm.ti, self.fm.tf, self.x, self.v, self._tau_const, np.array(knots), forces, heights,
                           int(self.stance), self.anchor, lim, xo, vo, w0, out)
        if status != pk.PERIOD_DONE:
            return None
        x, v = self.x.copy(), self.v.copy()
        q, qd = self.fm.paper_from_state(x, v, self.stance)
        if obs_stance != self.stance:     # the record keeps the true stance: the torque in its paper order
            applied = paper_from_urdf(self._tau_const, self.stance)
        rec = StepRecord(step=self.step_index, t=t_start, stance=self.stance, q=q, qd=qd, base=x[:3].copy(),
                         base_dot=v[:3].copy(), x=x, v=v, torque=applied, wrench=w0,
                         cop=float(w0[2] / w0[1]), push_force=float(forces[0]) if heights[0] == heights[0] else 0.0,
                         impacts=self.impact_count, fallen=False, fall_cause="", fall_detail="", t_end=t_end,
                         push_impulse=float(out[2]))
        self.x, self.v = xo, vo
        self.cleared = bool(out[1])
        self.step_index += 1
        self.t = t_end
        return rec

    def step(self, torque: np.ndarray | TorqueFn) -> StepRecord:
        """Advance one control period. ``torque``: paper-order joint torques [N m] for the current stance
        (with a delayed sensor model: for the stance of :meth:`observe`, the one the controller was told), held over the period (zero-order hold), or a function ``(s, q, qd, stance) -> torques`` evaluated at
        every RK4 stage (s = time since the period start). The period ends at the next grid instant, or
        at a touchdown (the impact is applied and the period ends there: no torque of the old labelling
        acts on the relabelled legs), or at a fall (the state is left at the instant of the fall)."""
        if self.fall is not None:
            raise RuntimeError("the robot has fallen; reset() the simulator")
        dt_nom = self.cfg.control_period
        t_start = self.t
        # periods end on the grid k * control_period, except a period cut short by an impact
        t_grid_end = grid_end(t_start, dt_nom)
        dt = t_grid_end - t_start
        obs_stance = self.stance
        if not self.sensor.identity:
            if callable(torque):
                raise PerturbationError("noise_q/noise_qd/delay", "a torque function sees the true state at every "
                                        "RK4 stage: use held torques (the sensor model applies to observe())")
            # every period is sampled (the delay line); the torques refer to the legs the controller was told
            # are in stance (a delayed touchdown): they are mapped to the motors with that stance
            obs_stance = self.observe().stance
        lo_tq, hi_tq = self.desc.torque_limits()
        lo_tq, hi_tq = np.array(lo_tq), np.array(hi_tq)
        self._tau_const = None
        if callable(torque):
            fn = torque

            def tau_src(tt, xx, vv):
                q, qd = self.fm.paper_from_state(xx, vv, obs_stance)
                g = np.clip(fn(tt - t_start, q, qd, obs_stance), lo_tq, hi_tq)
                return urdf_from_paper(g, obs_stance)
            applied = np.clip(fn(0.0, *self.fm.paper_from_state(self.x, self.v, obs_stance), obs_stance), lo_tq, hi_tq)
        else:
            applied = np.clip(np.asarray(torque, dtype=float), lo_tq, hi_tq)
            tj = urdf_from_paper(applied, obs_stance)
            self._tau_const = tj

            def tau_src(tt, xx, vv):
                return tj
        # the period's integration intervals: RK4 substeps, split exactly at every push start and end
        n_sub = max(1, int(math.ceil(self.cfg.substeps * dt / dt_nom - 1e-9)))
        knots = period_knots(t_start, t_grid_end, n_sub, (c for p in self.pushes for c in (p.start, p.end)))
        if self._fast and self._tau_const is not None:
            rec = self._fast_period(knots, t_start, t_grid_end, applied, obs_stance)
            if rec is not None:
                return rec
        # record at the period start, under this period's torque and the push of its first interval
        first_pushes = self.interval_pushes(knots[0], knots[1])
        _, w0 = self._accel(self.x, self.v, tau_src(t_start, self.x, self.v), first_pushes)
        q, qd = self.fm.paper_from_state(self.x, self.v, self.stance)
        if obs_stance != self.stance:     # the record keeps the true stance: the torque in its paper order
            applied = paper_from_urdf(tau_src(t_start, self.x, self.v), self.stance)
        pf = sum(f for f, _ in first_pushes)
        fall = self._check_wrench(w0, t_start)
        rec_args = dict(step=self.step_index, t=t_start, stance=self.stance, q=q, qd=qd, base=self.x[:3].copy(),
                        base_dot=self.v[:3].copy(), x=self.x.copy(), v=self.v.copy(), torque=applied, wrench=w0,
                        cop=float(w0[2] / w0[1]) if w0[1] != 0 else math.nan, push_force=pf,
                        impacts=self.impact_count)
        if fall is not None:
            self.fall = fall
            self.step_index += 1
            return StepRecord(**rec_args, fallen=True, fall_cause=fall.cause, fall_detail=fall.detail,
                              t_end=t_start, push_impulse=0.0)
        x, v = self.x, self.v
        t_end = t_grid_end
        impulse = 0.0
        impacts_before = self.impact_count
        for t0, t1 in zip(knots[:-1], knots[1:]):
            if t0 > t_start:
                _, w = self._accel(x, v, tau_src(t0, x, v), self.interval_pushes(t0, t1))
                f = self._check_wrench(w, t0)
                if f is not None:
                    self.fall = f
                    t_end = t0
                    break
            x, v, t_reached = self._advance(x, v, tau_src, t0, t1)
            impulse += sum(fp for fp, _ in self.interval_pushes(t0, t1)) * (t_reached - t0)
            if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
                self.fall = FallInfo("numerical", t1, "non-finite state")
                t_end = t1
                break
            if self.impact_count != impacts_before:
                # the period ends at the impact: the controller is called right after it
                t_end = t_reached
                break
            if self.fall is not None:      # no_liftoff: the released foot sank; the state is the fall's
                t_end = t_reached
                break
        self.x, self.v = x, v
        self.step_index += 1
        self.t = t_end
        return StepRecord(**rec_args, fallen=self.fall is not None, fall_cause=self.fall.cause if self.fall else "",
                          fall_detail=self.fall.detail if self.fall else "", t_end=t_end, push_impulse=impulse)
