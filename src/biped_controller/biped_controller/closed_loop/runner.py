"""In-process closed loop (no ROS, no DDS): a plant + AdaptiveController, lockstep per control period.

The plant is ``make_plant(sim_config.plant, ...)``: the rigid ``Simulator`` (default, the reference) or the
MuJoCo plant (``--set plant=mujoco``); the compiled closed loop runs either (``segment.Segment`` on the rigid
plant, ``segment.MujocoSegment`` on MuJoCo).

The node graph does exactly this over DDS; ``run`` is the reference the DDS run is compared with.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from biped_sim.plant.period_grid import grid_end, last_grid_before
from biped_model.description import LEFT, RobotDescription, load_description
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.push import Push
from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.protocol import Plant, make_plant

from biped_controller.core.control.config import ControllerConfig, load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.control.controller_layout import M_
from biped_controller.plugin.result import RunResult
from biped_controller.closed_loop.segment import MujocoSegment, Segment
from biped_model.gait_family import GaitFamily


def run(steps: int = 10, mode: str = "both", pushes: tuple[Push, ...] = (), *,
        sim_config: SimConfig | None = None, ctrl_config: ControllerConfig | None = None,
        family: GaitFamily | None = None, desc: RobotDescription | None = None,
        integration_rate: bool = False, keep_qp: bool = False, max_time: float | None = None,
        extra_time_after_steps: float = 0.0, perturbation: PlantPerturbation | None = None,
        compiled_loop: bool = True, keep_records: bool = True,
        on_impact: Callable[[Plant, AdaptiveController], bool] | None = None,
        pool: "LoopPool | None" = None) -> RunResult:
    """Walk ``steps`` steps (impacts) or until a fall. ``integration_rate``: the controller's torque law is
    evaluated at every RK4 stage (no QP re-solve inside a period). ``perturbation`` goes to the
    simulator only: the plant and the sensors differ, the controller keeps ``desc``.

    ``compiled_loop`` (fast engine, ideal sensors -- or real sensing without a delay, the sensing pipeline
    compiled, on either plant --, held torques, no ``keep_qp``): the periods where nothing
    needs Python run in the compiled loop (``segment.Segment`` on the rigid plant, ``segment.MujocoSegment``
    on MuJoCo), with records identical to the objects' period by period (tested); on the rigid plant the
    objects take every period with a QP, an impact or a fall; on MuJoCo the compiled loop runs a period that
    ends in a touchdown or a fall and the plant's Python finishes it (``MujocoPlant.finish_compiled_period``).
    ``keep_records`` False (with the compiled loop): ``records``/``statuses`` keep only the periods the
    objects ran and the run's last period -- the run's outcome (fall, impacts, the last status) is the
    same, the time series is not there; without the compiled loop they keep the run's last period only, its
    status built once at the end. The compiled loop also takes the periods that need the QP: the
    controller decides them between two calls (``Segment.decide``), the objects take the modes whose
    whole-body stage follows a QP (and, on the rigid plant, the impacts and the falls).

    ``on_impact(sim, ctrl)`` (the sweeps' early stop) is called once per impact, one control
    period after it, once that period has completed without a fall (the controller's own post-impact torque
    has acted and passed the plant's checks; ``sim.impact_log[-1]`` the impact, ``sim.t`` the control
    instant one period after it; the compiled loop hands that period back on its own), and, with the rigid
    plant's compiled loop, once more at the end of the compiled segment that follows (the next QP or the next
    touchdown, so no trial is decided later than then; MuJoCo's compiled loop calls it as the objects do);
    True ends the run there (``steps_walked`` then counts the impacts so far).

    ``pool`` (the sweeps): the plant and the controller come from the pool, reused from an earlier
    run with the same settings (reset, bit-identical to new ones: tested), and when the run's first push is
    the same as other runs' (same onset), the walk up to it is simulated once and restored
    (:meth:`LoopPool.snapshot_at`; records before the push are then not in ``records``, the outcome is the
    same: tested hash for hash). Without a pool (default) every run builds its own."""
    desc = desc if desc is not None else load_description()
    family = family if family is not None else GaitFamily.load()
    scfg = sim_config if sim_config is not None else load_sim_config()
    ccfg = ctrl_config if ctrl_config is not None else load_controller_config(mode=mode, period=scfg.control_period)
    if ccfg.period != scfg.control_period:
        ccfg = ControllerConfig(**{**ccfg.__dict__, "period": scfg.control_period})
    limit = max_time if max_time is not None else (steps + 3) * family.T * 3
    if pool is None:
        loop = ClosedLoop(scfg, ccfg, family, desc, perturbation, keep_qp=keep_qp)
        loop.reset()
        snap = None
    else:
        loop = pool.loop(scfg, ccfg, family, desc, perturbation, keep_qp=keep_qp)
        snap = pool.snapshot_at(loop, pushes[0].start) if pushes and not integration_rate else None
        if snap is not None and (snap.impact_count >= steps or snap.t >= limit):
            snap = None      # the run would have ended before the push: nothing to share
        if snap is None:
            loop.reset()
        else:
            loop.restore(snap)
    return loop.run(steps, pushes, limit=limit, integration_rate=integration_rate,
                    extra_time_after_steps=extra_time_after_steps, compiled_loop=compiled_loop,
                    keep_records=keep_records, on_impact=on_impact,
                    seen=snap.impact_count if snap is not None else 0,
                    pending=snap.pending if snap is not None else False)


@dataclass(frozen=True, eq=False)
class LoopSnapshot:
    """A closed loop between two periods: the plant's and the controller's snapshots and the early-stop
    bookkeeping of the loop (impacts seen, one still waiting for its first full period)."""

    plant: object
    controller: np.ndarray
    t: float
    impact_count: int
    pending: bool


class ClosedLoop:
    """One plant and one controller in lockstep (``run``'s loop), built once and reusable: :meth:`reset` to
    the family's initial state, :meth:`snapshot` / :meth:`restore` between periods (either plant with ideal
    sensors and a controller without real sensing; :attr:`snapshots` False otherwise), :meth:`walk_to` the last control
    instant before a push, :meth:`run` the loop."""

    def __init__(self, sim_config: SimConfig, ctrl_config: ControllerConfig, family: GaitFamily,
                 desc: RobotDescription, perturbation: PlantPerturbation | None = None, keep_qp: bool = False):
        self.scfg, self.ccfg, self.family, self.desc = sim_config, ctrl_config, family, desc
        self.sim = make_plant(sim_config.plant, desc, sim_config, perturbation)
        self.ctrl = AdaptiveController(ctrl_config, family, desc, keep_qp=keep_qp)
        self.keep_qp = keep_qp
        self._segs: dict[bool, Segment | MujocoSegment] = {}
        self.snapshots = (hasattr(self.sim, "snapshot") and getattr(self.sim, "sensor", None) is not None
                          and self.sim.sensor.identity and not self.ctrl.cfg.real_sensing)

    def reset(self) -> None:
        q0, qd0 = self.family.initial_state()
        self.sim.reset(q0, qd0, LEFT)
        self.ctrl.reset(LEFT)

    def snapshot(self, pending: bool = False) -> LoopSnapshot:
        """The loop's state now (raises ``SnapshotUnsupported`` where an object cannot give it)."""
        return LoopSnapshot(self.sim.snapshot(), self.ctrl.snapshot(), self.sim.t, self.sim.impact_count, pending)

    def restore(self, snap: LoopSnapshot) -> None:
        self.sim.restore(snap.plant)
        self.ctrl.restore(snap.controller)

    def _segment(self, compiled_loop: bool, keep_records: bool, integration_rate: bool
                 ) -> Segment | MujocoSegment | None:
        """The compiled loop over this plant and controller (kept: its record buffers are reused), or None
        where it does not apply (module docstring of ``run``): ``Segment`` on the rigid plant,
        ``MujocoSegment`` on the MuJoCo plant."""
        sim, ctrl = self.sim, self.ctrl
        if not (compiled_loop and not integration_rate and not self.keep_qp):
            return None
        if self.scfg.plant == "rigid" and Segment.eligible(sim, ctrl):
            kind = Segment
        elif self.scfg.plant == "mujoco" and MujocoSegment.eligible(sim, ctrl):
            kind = MujocoSegment
        else:
            return None
        seg = self._segs.get(keep_records)
        if seg is None:
            seg = self._segs[keep_records] = kind(sim, ctrl, keep_records=keep_records)
        return seg

    def walk_to(self, t_push: float, compiled_loop: bool = True) -> LoopSnapshot:
        """From the current state, walk with no push while the coming period ends at or before ``t_push``
        [s] (a period that a push starting at ``t_push`` changes -- it acts in it, or splits its integration
        intervals -- is not run), and return the snapshot there: the state every run whose first push
        starts at ``t_push`` reaches, bit for bit. The early-stop bookkeeping is that of :meth:`run`."""
        sim, ctrl = self.sim, self.ctrl
        if sim.pushes:
            raise ValueError("walk_to: pushes are already scheduled")
        dt = self.scfg.control_period
        g = last_grid_before(t_push, dt)
        seg = self._segment(compiled_loop, False, False)
        seen, pending = sim.impact_count, False
        ctrl.build_status = False          # the walk's statuses are not kept
        try:
            pending = self._walk(t_push, g, seg, seen, pending)
        finally:
            ctrl.build_status, ctrl._pending_status = True, None
        if sim.fall is not None:
            raise RuntimeError(f"walk_to({t_push}): the undisturbed walk fell at t = {sim.fall.t} s ({sim.fall.cause})")
        return self.snapshot(pending)

    def _walk(self, t_push: float, g: float, seg: Segment | None, seen: int, pending: bool) -> bool:
        """:meth:`walk_to`'s loop; returns the early-stop bookkeeping's ``pending`` at its end."""
        sim, ctrl = self.sim, self.ctrl
        dt = self.scfg.control_period
        while grid_end(sim.t, dt) <= t_push and sim.fall is None:
            if seg is not None:
                recs, _ = seg.run(g)
                if recs and pending and sim.impact_count == seen:
                    pending = False
                if sim.impact_count > seen:        # the MuJoCo loop's last period ended in a touchdown
                    seen, pending = sim.impact_count, True
                if sim.fall is not None or grid_end(sim.t, dt) > t_push:
                    break
            obs = sim.observe()
            out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch, obs.pitch_rate)
            rec = sim.step(out.torque)
            if rec.fallen or sim.fall is not None:
                break
            if pending and sim.impact_count == seen:
                pending = False
            if sim.impact_count > seen:
                seen, pending = sim.impact_count, True
        return pending

    def run(self, steps: int, pushes: tuple[Push, ...] = (), *, limit: float, integration_rate: bool = False,
            extra_time_after_steps: float = 0.0, compiled_loop: bool = True, keep_records: bool = True,
            on_impact: Callable[[Plant, AdaptiveController], bool] | None = None, seen: int = 0,
            pending: bool = False) -> RunResult:
        """``run``'s loop from the current state (after :meth:`reset` or :meth:`restore`): schedules
        ``pushes`` and walks until ``steps`` impacts, a fall, ``limit`` [s] or ``on_impact`` says stop.
        ``seen``, ``pending``: the early-stop bookkeeping at the current state (a snapshot's)."""
        sim, ctrl = self.sim, self.ctrl
        for p in pushes:
            sim.schedule_push(p.start, p.duration, p.force, p.height)
        records, statuses, qps = [], [], []
        keep_qp = self.keep_qp
        seg = self._segment(compiled_loop, keep_records, integration_rate)
        # outcome only without the compiled loop (e.g. a sensor model on MuJoCo): the objects keep the last
        # period's record and status only, and the controller builds that status once, at the end (with real
        # sensing it builds every period's: the last one built is kept)
        lean = seg is None and not keep_records and not keep_qp
        if lean:
            ctrl.build_status, ctrl._pending_status = False, None
        try:
            if isinstance(seg, MujocoSegment):
                self._run_periods_mujoco(steps, limit, extra_time_after_steps, on_impact, seen, pending, seg,
                                         keep_records, records, statuses)
            else:
                self._run_periods(steps, limit, integration_rate, extra_time_after_steps, on_impact, seen, pending,
                                  seg, lean, keep_records, records, statuses, qps)
        finally:
            ctrl.build_status = True
        if lean:
            last = ctrl.last_status()
            ctrl._pending_status = None
            statuses += [last] if last is not None else []
        fall = sim.fall
        return RunResult(records=records, statuses=statuses, steps_walked=sim.impact_count,
                         fallen=fall is not None, fall_cause=fall.cause if fall else "",
                         fall_detail=fall.detail if fall else "", fall_time=fall.t if fall else math.nan,
                         impacts=list(sim.impact_log), qp_instances=qps,
                         param_range=tuple(float(ctrl.memory[o]) for o in (M_.p_lo, M_.p_hi, M_.tau_dot_lo,
                                                                           M_.tau_dot_hi)))

    def _run_periods(self, steps, limit, integration_rate, extra_time_after_steps, on_impact, seen, pending, seg,
                     lean, keep_records, records, statuses, qps) -> None:
        """:meth:`run`'s loop (its arguments; ``lean``: keep only the last record, statuses left to the
        controller's ``last_status``), filling ``records``, ``statuses``, ``qps``."""
        sim, ctrl = self.sim, self.ctrl
        keep_qp = self.keep_qp
        again = False
        decision = None
        last_in_seg = False       # the last period run so far was the compiled loop's
        while True:
            if seg is not None:
                t_stop = limit
                if sim.impact_count >= steps and extra_time_after_steps > 0:
                    t_stop = min(limit, sim.impact_log[steps - 1].t + extra_time_after_steps)
                # an impact waiting for its check: one period, then the check; if the outcome is not decided
                # there, once more at the end of the next segment (where the compiled loop hands back anyway)
                recs, stats = seg.run(t_stop, 1 if (pending and on_impact is not None) else 1 << 40, decision,
                                      build=keep_records)
                records += recs
                statuses += stats
                ran = seg.n > 0
                last_in_seg = ran or last_in_seg
                if ran and sim.t >= t_stop:
                    break
                if ran and again and sim.impact_count == seen and sim.fall is None:
                    again = False
                    if on_impact(sim, ctrl):
                        break
                if ran and pending and sim.impact_count == seen and sim.fall is None:
                    pending = False
                    if on_impact is not None:
                        again = True
                        if on_impact(sim, ctrl):
                            break
                # a period that needs the QP: decided here, taken by the next call; the objects
                # take it where the compiled loop cannot (and whenever that call hands it back unrun)
                decision = seg.decide() if not (decision is not None and not ran) else None
                if decision is not None:
                    continue
            last_in_seg = False
            obs = sim.observe()
            out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch, obs.pitch_rate)
            if not lean:
                statuses.append(out.status)
            if keep_qp and out.G is not None:
                qps.append((out.G, out.h, out.x_star, out.status.qp_status))
            if integration_rate:
                rec = sim.step(lambda s, q, qd, st: ctrl.torque_within_period(s, q, qd, st))
            else:
                rec = sim.step(out.torque)
            if lean:
                records[:] = (rec,)
                if out.status is not None:      # built anyway (real sensing): the last period's is kept
                    statuses[:] = (out.status,)
            else:
                records.append(rec)
            if rec.fallen or sim.fall is not None:
                break
            if pending and sim.impact_count == seen:
                pending = False
                if on_impact is not None and on_impact(sim, ctrl):
                    break
            if sim.impact_count > seen:
                seen, pending = sim.impact_count, True
            if sim.impact_count >= steps:
                if extra_time_after_steps <= 0 or sim.t >= sim.impact_log[steps - 1].t + extra_time_after_steps:
                    break
            if sim.t >= limit:
                break
        if seg is not None and last_in_seg:       # outcome only: the run's last period, when the compiled loop ran it
            recs, stats = seg.last()
            records += recs
            statuses += stats


    def _after_period(self, steps: int, limit: float, extra_time_after_steps: float, on_impact, seen: int,
                      pending: bool) -> tuple[bool, int, bool]:
        """The checks :meth:`_run_periods` makes after each period the objects ran (a fall, the early stop's
        call one period after an impact, the steps and the time limits): (stop, seen, pending)."""
        sim = self.sim
        if sim.fall is not None:
            return True, seen, pending
        if pending and sim.impact_count == seen:
            pending = False
            if on_impact is not None and on_impact(sim, self.ctrl):
                return True, seen, pending
        if sim.impact_count > seen:
            seen, pending = sim.impact_count, True
        if sim.impact_count >= steps:
            if extra_time_after_steps <= 0 or sim.t >= sim.impact_log[steps - 1].t + extra_time_after_steps:
                return True, seen, pending
        return sim.t >= limit, seen, pending

    def _run_periods_mujoco(self, steps, limit, extra_time_after_steps, on_impact, seen, pending,
                            seg: MujocoSegment, keep_records, records, statuses) -> None:
        """:meth:`_run_periods` with the MuJoCo plant's compiled loop: its calls run periods up to the next
        touchdown, fall, QP or the time to stop (``t_stop``: the limit, or the time after the last step), one
        period at a time while an impact waits for the early stop's check; after each call the objects'
        checks on its last period (:meth:`_after_period`: nothing in the periods before it would have
        stopped the run); a QP period the controller decides goes to the next call, one the compiled loop
        cannot take (or any period it hands back unrun) to the objects."""
        sim, ctrl = self.sim, self.ctrl
        decision = None
        last_in_seg = False
        while True:
            t_stop = limit
            if sim.impact_count >= steps and extra_time_after_steps > 0:
                t_stop = min(limit, sim.impact_log[steps - 1].t + extra_time_after_steps)
            recs, stats = seg.run(t_stop, 1 if (pending and on_impact is not None) else 1 << 40, decision,
                                  build=keep_records)
            decision = None
            records += recs
            statuses += stats
            if seg.n > 0:
                last_in_seg = True
                stop, seen, pending = self._after_period(steps, limit, extra_time_after_steps, on_impact, seen,
                                                         pending)
                if stop:
                    break
            if seg.needs_qp:
                decision = seg.decide()
                if decision is not None:
                    continue
            elif seg.n > 0:
                continue
            # the objects take the period the compiled loop handed back
            last_in_seg = False
            obs = sim.observe()
            out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch, obs.pitch_rate)
            statuses.append(out.status)
            rec = sim.step(out.torque)
            records.append(rec)
            stop, seen, pending = self._after_period(steps, limit, extra_time_after_steps, on_impact, seen, pending)
            if stop:
                break
        if last_in_seg:        # outcome only: the run's last period, when the compiled loop ran it
            recs, stats = seg.last()
            records += recs
            statuses += stats


class LoopPool:
    """Closed loops kept for reuse within one process (the sweeps' worker processes): one
    :class:`ClosedLoop` per settings (plant and controller configuration, perturbation, robot, family), and
    per loop the snapshots at the push onsets asked for (:meth:`snapshot_at`), at most ``max_snapshots``
    (the oldest dropped first; each holds two small arrays). At most ``max_loops`` loops are kept (the least
    recently used dropped with its snapshots: a loop's compiled-loop buffers hold a few MB, and the
    robustness table asks for one loop per plant perturbation and mode)."""

    def __init__(self, max_snapshots: int = 512, max_loops: int = 8):
        if not (isinstance(max_loops, int) and max_loops >= 1 and isinstance(max_snapshots, int) and max_snapshots >= 1):
            raise ValueError(f"LoopPool: max_loops and max_snapshots must be integers >= 1, got {max_loops!r}, "
                             f"{max_snapshots!r}")
        self.max_snapshots = max_snapshots
        self.max_loops = max_loops
        self._loops: dict = {}
        self._snaps: dict = {}
        self.walks = 0          # walks to an onset simulated (the others were restored)

    def loop(self, sim_config: SimConfig, ctrl_config: ControllerConfig, family: GaitFamily, desc: RobotDescription,
             perturbation: PlantPerturbation | None = None, keep_qp: bool = False) -> ClosedLoop:
        key = (sim_config, ctrl_config, id(family), id(desc), perturbation, keep_qp)
        lp = self._loops.pop(key, None)
        if lp is None or lp.family is not family or lp.desc is not desc:
            lp = ClosedLoop(sim_config, ctrl_config, family, desc, perturbation, keep_qp)
            while len(self._loops) >= self.max_loops:          # the least recently used goes, with its snapshots
                old = self._loops.pop(next(iter(self._loops)))
                self._snaps = {k: v for k, v in self._snaps.items() if k[0] is not old}
        self._loops[key] = lp      # most recently used last
        return lp

    def snapshot_at(self, loop: ClosedLoop, t_push: float) -> LoopSnapshot | None:
        """The loop's state at the last control instant before a push starting at ``t_push`` [s] (walked
        once from the initial state, then kept), or None where the loop takes no snapshot (a sensor model,
        real sensing: the caller runs from the start)."""
        if not loop.snapshots:
            return None
        key = (loop, float(t_push))
        snap = self._snaps.get(key)
        if snap is None:
            loop.reset()
            snap = loop.walk_to(t_push)
            self.walks += 1
            if len(self._snaps) >= self.max_snapshots:
                self._snaps.pop(next(iter(self._snaps)))
            self._snaps[key] = snap
        return snap


def tracking_error(result: RunResult) -> float:
    return float(max(s.max_tracking_error for s in result.statuses))
