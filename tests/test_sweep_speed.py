"""Sweeps 5x faster (second part): a survival trial restored from the walk up to its push, on a
plant and a controller reused from earlier trials, is the trial run from t = 0 on new objects, hash for
hash (every field of every record, impact and status after the snapshot); a snapshot one period too
late is not (negative control); where no snapshot can be taken (a sensor model) the trial runs from the
start with the same outcome."""
from __future__ import annotations

import dataclasses
import hashlib

import pytest

from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.push import Push

from biped_controller.closed_loop import runner
from biped_controller.studies.trial import context as tcontext
from biped_controller.studies.trial import runs, trials
from biped_controller.studies.trial import settings as ts
from biped_controller.studies.fingerprint import feed

# (mode, signed force [N], duration [s], onset phase): survivals and falls, QP-heavy pushes, both directions
CASES = [("both", -300.0, 0.1, 0.5), ("both", 700.0, 0.025, 0.35), ("tau", 400.0, 0.025, 0.75),
         ("p", 300.0, 0.2, 0.95), ("none", 40.0, 0.025, 0.3), ("hybrid", 300.0, 0.025, 0.5),
         ("all", 700.0, 0.025, 0.35), ("lambda", -300.0, 0.1, 0.5)]


def digest(records, statuses, impacts, res: runner.RunResult) -> str:
    h = hashlib.sha256()
    for group in (records, impacts, statuses):
        for r in group:
            for f in dataclasses.fields(r):
                feed(h, getattr(r, f.name))
    feed(h, (res.steps_walked, res.fallen, res.fall_cause, res.fall_detail, float(res.fall_time)))
    return h.hexdigest()


def _trial(mode, force, duration, phase, pool=None, steps=None):
    ctx = tcontext.context()
    start = phase * ctx.family.T
    settings = ts.DEFAULT_SETTINGS
    n = steps if steps is not None else runs.push_step_index(Push(start, duration, force), ctx.family.T) + 3
    return runner.run(n, mode, (Push(start, duration, force),), sim_config=settings.sim_config(),
                      ctrl_config=settings.ctrl_config(mode), family=ctx.family, desc=ctx.desc, pool=pool), start


def _tail(res: runner.RunResult, k: int) -> tuple:
    """Records and statuses of the periods from index k on (one status per period)."""
    assert [r.step for r in res.records] == list(range(res.records[0].step, res.records[0].step + len(res.records)))
    j = k - res.records[0].step
    return res.records[j:], res.statuses[j:]


@pytest.mark.parametrize("mode,force,duration,phase", CASES)
def test_restored_trial_on_a_reused_loop_equals_the_fresh_trial(mode, force, duration, phase):
    fresh, start = _trial(mode, force, duration, phase)
    pool = runner.LoopPool()
    other, _ = _trial(mode, -0.5 * force, duration, phase, pool)      # the loop has run another trial first
    restored, _ = _trial(mode, force, duration, phase, pool)
    assert pool.walks == 1                                            # the walk to the onset was shared
    k = restored.records[0].step
    dt = tcontext.context().sim_config.control_period
    # the snapshot is the last control instant whose period the push does not change
    assert k > 0 or phase == 0.0
    assert fresh.records[k - 1].t_end <= start < runner.grid_end(fresh.records[k].t, dt)
    assert restored.records[0].t == fresh.records[k].t
    a = digest(*_tail(fresh, k), fresh.impacts, fresh)
    b = digest(*_tail(restored, k), restored.impacts, restored)
    assert a == b, (mode, force)
    assert fresh.fallen or fresh.steps_walked >= 1
    assert digest(*_tail(other, k), other.impacts, other) != a       # the hash sees a different trial


def test_a_snapshot_one_period_late_changes_the_trial():
    """Negative control: the same trial restored from a walk that ran the push's first period without the
    push gives other records (the test above can fail)."""
    mode, force, duration, phase = "both", 700.0, 0.025, 0.35
    fresh, start = _trial(mode, force, duration, phase)
    ctx = tcontext.context()
    s = ts.DEFAULT_SETTINGS
    loop = runner.ClosedLoop(s.sim_config(), s.ctrl_config(mode), ctx.family, ctx.desc)
    loop.reset()
    late = loop.walk_to(start + ctx.sim_config.control_period)
    loop.restore(late)
    res = loop.run(fresh.steps_walked + 1, (Push(start, duration, force),), limit=10.0)
    k = res.records[0].step
    assert k == _trial(mode, force, duration, phase, runner.LoopPool())[0].records[0].step + 1
    assert digest(*_tail(fresh, k), fresh.impacts, fresh) != digest(*_tail(res, k), res.impacts, res)


def test_survival_outcomes_with_and_without_the_pool_are_identical():
    T = tcontext.context().family.T
    pool = runner.LoopPool()
    for mode, force, duration, phase in CASES[:5] + [("both", -2000.0, 0.025, 0.25), ("p", 40.0, 0.1, 0.0)]:
        push = runs.paper_push(force, start=phase * T, duration=duration)
        a = trials.survives(push, mode, pool=False)
        b = trials.survives(push, mode, pool=pool)
        assert a == b, (mode, force)


def test_no_snapshot_with_a_sensor_model_the_trial_runs_from_the_start():
    pert = PlantPerturbation(noise_q=1e-4, seed=3)
    settings = ts.RunSettings(perturbation=pert)
    ctx = tcontext.context()
    pool = runner.LoopPool()
    loop = pool.loop(settings.sim_config(), settings.ctrl_config("both"), ctx.family, ctx.desc, pert)
    assert not loop.snapshots and pool.snapshot_at(loop, 0.2) is None and pool.walks == 0
    args = (runs.paper_push(150.0, start=0.2315, duration=0.025), "both", settings)
    assert trials.survives(*args, pool=pool) == trials.survives(*args, pool=False)


def test_walk_to_refuses_scheduled_pushes():
    ctx = tcontext.context()
    s = ts.DEFAULT_SETTINGS
    loop = runner.ClosedLoop(s.sim_config(), s.ctrl_config("none"), ctx.family, ctx.desc)
    loop.reset()
    loop.sim.schedule_push(0.1, 0.025, 100.0)
    with pytest.raises(ValueError, match="pushes are already scheduled"):
        loop.walk_to(0.2)


@pytest.mark.parametrize("mode,force", [("both", -300.0), ("tau", 400.0), ("p", -150.0), ("hybrid", 300.0)])
def test_the_compiled_loop_takes_the_qp_periods_bit_for_bit(monkeypatch, mode, force):
    """The periods that need the QP are decided between two calls of the compiled loop (Segment.decide) and
    run by it: records, statuses (QP status and message included) and impacts are the objects' bit for bit;
    hybrid's whole-body stage keeps them with the objects (decide answers None)."""
    from biped_controller.closed_loop import segment
    from biped_controller.core.qp.problem import UNCONSTRAINED
    from biped_controller.core.control.status import NO_ADAPTATION
    answers = []
    orig = segment.Segment.decide

    def counting(self):
        d = orig(self)
        answers.append(d is not None)
        return d
    monkeypatch.setattr(segment.Segment, "decide", counting)
    kw = dict(steps=3, mode=mode, pushes=(Push(0.2315, 0.1, force),))
    loop = runner.run(**kw)
    taken = sum(answers)
    objects = runner.run(compiled_loop=False, **kw)
    n_qp = sum(1 for s in objects.statuses if s.qp_status not in (UNCONSTRAINED, NO_ADAPTATION))
    assert n_qp >= 20, n_qp
    if mode == "hybrid":
        assert taken == 0 and answers
    else:
        assert taken >= 0.9 * n_qp, (taken, n_qp)
    assert len(loop.records) == len(objects.records)
    assert digest(loop.records, loop.statuses, loop.impacts, loop) == \
        digest(objects.records, objects.statuses, objects.impacts, objects)


def test_the_pool_keeps_at_most_max_loops_and_drops_their_snapshots():
    ctx = tcontext.context()
    s = ts.DEFAULT_SETTINGS
    pool = runner.LoopPool(max_loops=2)
    loops = [pool.loop(s.sim_config(), s.ctrl_config(m), ctx.family, ctx.desc) for m in ("none", "tau")]
    for lp in loops:
        pool.snapshot_at(lp, 0.1)
    assert pool.loop(s.sim_config(), s.ctrl_config("none"), ctx.family, ctx.desc) is loops[0]   # reused, now recent
    p_loop = pool.loop(s.sim_config(), s.ctrl_config("p"), ctx.family, ctx.desc)                # "tau" goes
    assert pool.loop(s.sim_config(), s.ctrl_config("none"), ctx.family, ctx.desc) is loops[0]
    assert pool.loop(s.sim_config(), s.ctrl_config("tau"), ctx.family, ctx.desc) is not loops[1]
    assert all(k[0] is not loops[1] for k in pool._snaps) and pool.walks == 2
    assert p_loop is not loops[0]
    with pytest.raises(ValueError, match="max_loops"):
        runner.LoopPool(max_loops=0)
