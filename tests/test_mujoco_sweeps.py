"""MuJoCo sweeps: a survival trial restored from the walk up to its push (MuJoCo's own integration state,
``mj_getState``/``mj_setState``, plus the plant's bookkeeping) on a plant and a controller reused from an
earlier trial is the trial run from t = 0 on new objects, hash for hash (every field of every record,
impact and status after the snapshot); a snapshot one period too late is not (negative control); the
survival outcomes with and without the pool are identical."""
from __future__ import annotations

import pytest

from biped_sim.plant.push import Push
from biped_model.layout import SnapshotUnsupported

from biped_controller.closed_loop import runner
from biped_controller.studies.trial import context as tcontext
from biped_controller.studies.trial import runs, trials
from biped_controller.studies.trial import settings as ts

from test_sweep_speed import _tail, digest

MUJOCO = ts.parse_overrides(["plant=mujoco"])
# (mode, signed force [N], duration [s], onset phase): a survival, a fall, a backward push, another mode
CASES = [("both", 300.0, 0.025, 0.5), ("both", 1500.0, 0.025, 0.35), ("tau", -300.0, 0.1, 0.5),
         ("none", 200.0, 0.025, 0.3)]


def _trial(mode, force, duration, phase, pool=None, steps=None):
    ctx = tcontext.context()
    start = phase * ctx.family.T
    n = steps if steps is not None else runs.push_step_index(Push(start, duration, force), ctx.family.T) + 3
    return runner.run(n, mode, (Push(start, duration, force),), sim_config=MUJOCO.sim_config(),
                      ctrl_config=MUJOCO.ctrl_config(mode), family=ctx.family, desc=ctx.desc, pool=pool), start


@pytest.mark.parametrize("mode,force,duration,phase", CASES)
def test_restored_mujoco_trial_on_a_reused_loop_equals_the_fresh_trial(mode, force, duration, phase):
    fresh, start = _trial(mode, force, duration, phase)
    pool = runner.LoopPool()
    other, _ = _trial(mode, -0.5 * force, duration, phase, pool)      # the loop has run another trial first
    restored, _ = _trial(mode, force, duration, phase, pool)
    assert pool.walks == 1                                            # the walk to the onset was shared
    k = restored.records[0].step
    assert k > 0
    dt = tcontext.context().sim_config.control_period
    assert fresh.records[k - 1].t_end <= start < runner.grid_end(fresh.records[k].t, dt)
    assert restored.records[0].t == fresh.records[k].t
    a = digest(*_tail(fresh, k), fresh.impacts, fresh)
    assert digest(*_tail(restored, k), restored.impacts, restored) == a, (mode, force)
    assert digest(*_tail(other, k), other.impacts, other) != a       # the hash sees a different trial
    loop = next(iter(pool._loops.values()))
    # the contact diagnostics are the plant's state too: the restored run's are the fresh run's
    fresh_loop = runner.ClosedLoop(MUJOCO.sim_config(), MUJOCO.ctrl_config(mode), tcontext.context().family,
                                   tcontext.context().desc)
    fresh_loop.reset()
    T = tcontext.context().family.T
    n = runs.push_step_index(Push(start, duration, force), T) + 3
    again = fresh_loop.run(n, (Push(start, duration, force),), limit=(n + 3) * T * 3)
    assert digest(*_tail(again, k), again.impacts, again) == a
    assert loop.sim.diagnostics.as_dict() == fresh_loop.sim.diagnostics.as_dict()
    assert loop.sim.diagnostics.touchdown_forces == fresh_loop.sim.diagnostics.touchdown_forces


def test_a_mujoco_snapshot_one_period_late_changes_the_trial():
    """Negative control: the trial restored from a walk that ran the push's first period without the push
    gives other records (the test above can fail)."""
    mode, force, duration, phase = "both", 700.0, 0.025, 0.35
    fresh, start = _trial(mode, force, duration, phase)
    ctx = tcontext.context()
    loop = runner.ClosedLoop(MUJOCO.sim_config(), MUJOCO.ctrl_config(mode), ctx.family, ctx.desc)
    loop.reset()
    late = loop.walk_to(start + ctx.sim_config.control_period)
    loop.restore(late)
    res = loop.run(fresh.steps_walked + 1, (Push(start, duration, force),), limit=10.0)
    k = res.records[0].step
    assert digest(*_tail(fresh, k), fresh.impacts, fresh) != digest(*_tail(res, k), res.impacts, res)


def test_mujoco_survival_outcomes_with_and_without_the_pool_are_identical():
    T = tcontext.context().family.T
    pool = runner.LoopPool()
    for mode, force, duration, phase in CASES:
        push = runs.paper_push(force, start=phase * T, duration=duration)
        a = trials.survives(push, mode, MUJOCO, pool=False)
        b = trials.survives(push, mode, MUJOCO, pool=pool)
        assert a == b, (mode, force)
    assert pool.walks == len({(m, ph) for m, _, _, ph in CASES})


def test_no_mujoco_snapshot_with_a_sensor_model_or_a_trace():
    from biped_sim.plant.perturbation import PlantPerturbation
    ctx = tcontext.context()
    loop = runner.ClosedLoop(MUJOCO.sim_config(), MUJOCO.ctrl_config("both"), ctx.family, ctx.desc,
                             PlantPerturbation(noise_q=1e-4, seed=3))
    assert not loop.snapshots
    with pytest.raises(SnapshotUnsupported, match="sensor model"):
        loop.sim.snapshot()
    loop = runner.ClosedLoop(MUJOCO.sim_config(), MUJOCO.ctrl_config("both"), ctx.family, ctx.desc)
    loop.reset()
    loop.sim.trace = []
    with pytest.raises(SnapshotUnsupported, match="trace"):
        loop.sim.snapshot()


@pytest.mark.parametrize("mode,force", [("both", 300.0), ("both", 1500.0), ("hybrid", 300.0)])
def test_outcome_only_mujoco_run_keeps_the_last_record_and_status_of_the_full_run(mode, force):
    """Without the compiled loop an outcome-only run keeps the last period's record and status (the status
    built once at the end): the same objects, hash for hash, as the last ones of the run that keeps every
    period; the impacts and the outcome are the same."""
    ctx = tcontext.context()
    push = (Push(0.5 * ctx.family.T, 0.025, force),)
    kw = dict(sim_config=MUJOCO.sim_config(), ctrl_config=MUJOCO.ctrl_config(mode), family=ctx.family, desc=ctx.desc,
              compiled_loop=False)
    full = runner.run(4, mode, push, **kw)
    lean = runner.run(4, mode, push, keep_records=False, **kw)
    assert len(lean.records) == len(lean.statuses) == 1 and len(full.records) > 200
    assert digest(full.records[-1:], full.statuses[-1:], full.impacts, full) == \
        digest(lean.records, lean.statuses, lean.impacts, lean)
