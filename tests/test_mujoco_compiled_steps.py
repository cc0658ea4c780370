"""The MuJoCo plant's compiled period (``mujoco_kernels.substeps``: a period's MuJoCo steps in one call) against
its Python loop (one iteration per MuJoCo step, ``MujocoPlant.compiled_steps`` False), bit for bit: every
field of every record, status and impact, the contact diagnostics and MuJoCo's integration state, on a pushed
walk whose push starts and ends inside control periods, and on a fall."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from biped_sim.plant.config import load_sim_config
from biped_sim.plant.push import Push

mujoco = pytest.importorskip("mujoco")

MJ = load_sim_config(plant="mujoco")


def _loop():
    from biped_controller.core.control.config import load_controller_config
    from biped_controller.closed_loop.runner import ClosedLoop
    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily
    return ClosedLoop(MJ, load_controller_config(mode="both", period=MJ.control_period), GaitFamily.load(),
                      load_description())


def _equal(a, b) -> bool:
    """Equal field for field, arrays and floats bit for bit (NaN equal to NaN)."""
    if dataclasses.is_dataclass(a):
        return type(a) is type(b) and all(_equal(getattr(a, f.name), getattr(b, f.name))
                                          for f in dataclasses.fields(a))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        return a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return type(a) is type(b) and np.float64(a).tobytes() == np.float64(b).tobytes()
    return a == b


class _Count:
    def __init__(self, fn):
        self.fn, self.n = fn, 0

    def __call__(self, *a):
        self.n += 1
        return self.fn(*a)


def _run(loop, compiled: bool, steps: int, pushes: tuple, monkeypatch):
    """The run on one path, with the path's own calls counted (the compiled kernel, or the bindings' mj_step)."""
    sim = loop.sim
    sim.compiled_steps = compiled
    kernel = _Count(sim._k.substeps)
    step = _Count(mujoco.mj_step)
    sim._substeps = kernel
    with monkeypatch.context() as mp:
        mp.setattr(mujoco, "mj_step", step)
        loop.reset()
        r = loop.run(steps, pushes, limit=10.0, compiled_loop=False)
    sim._substeps = sim._k.substeps
    st = np.empty(mujoco.mj_stateSize(sim.model, mujoco.mjtState.mjSTATE_INTEGRATION))
    mujoco.mj_getState(sim.model, sim.data, st, mujoco.mjtState.mjSTATE_INTEGRATION)
    return r, sim.diagnostics, st, kernel.n, step.n


@pytest.mark.parametrize("steps,push,fallen", [
    (2, Push(0.2315, 0.025, 300.0), False),      # onset and end inside a period (0.2315 s, 0.2565 s)
    (2, Push(0.2315, 0.025, 1500.0), True),      # the foot rotates: a fall named after a compiled call
])
def test_compiled_steps_bit_identical_to_the_python_loop(steps, push, fallen, monkeypatch):
    loop = _loop()
    ref, dg_ref, st_ref, k_ref, s_ref = _run(loop, False, steps, (push,), monkeypatch)
    new, dg_new, st_new, k_new, s_new = _run(loop, True, steps, (push,), monkeypatch)
    # each path ran as asked: the Python loop through the bindings' mj_step, the compiled one never
    assert k_ref == 0 and s_ref > 4 * len(ref.records)
    assert s_new == 0 and k_new >= len(new.records)
    assert ref.fallen is fallen and new.fallen is fallen
    assert any(r.push_impulse != 0.0 for r in ref.records)
    assert len(new.records) == len(ref.records)
    for a, b in zip(ref.records, new.records):
        assert _equal(a, b), (a.t, a, b)
    assert _equal(ref.statuses, new.statuses)
    assert _equal(ref.impacts, new.impacts)
    assert (ref.steps_walked, ref.fall_cause, ref.fall_detail) == (new.steps_walked, new.fall_cause, new.fall_detail)
    assert _equal(ref.fall_time, new.fall_time)
    assert dg_ref.as_dict() == dg_new.as_dict() and dg_ref.touchdown_forces == dg_new.touchdown_forces
    assert st_ref.tobytes() == st_new.tobytes()


def test_the_comparison_sees_a_one_ulp_difference(monkeypatch):
    """Negative control of the test above: the push's force one ulp larger on the compiled path only changes a
    record bit (the comparison is bit for bit, and the compiled path reads the push it is given)."""
    loop = _loop()
    push = Push(0.2315, 0.025, 300.0)
    ref, *_ = _run(loop, False, 1, (push,), monkeypatch)
    new, *_ = _run(loop, True, 1, (Push(0.2315, 0.025, float(np.nextafter(300.0, np.inf))),), monkeypatch)
    assert not all(_equal(a, b) for a, b in zip(ref.records, new.records))


def test_opt_timestep_view_is_the_models_field():
    """The view ``opt_timestep_view`` gives writes ``model.opt.timestep`` and leaves it as it was found."""
    from biped_sim.plant.mujoco import MujocoPlant, opt_timestep_view
    p = MujocoPlant(config=MJ)
    h0 = p.model.opt.timestep
    v = opt_timestep_view(p.model)
    assert p.model.opt.timestep == h0 and v[0] == h0
    v[0] = 3.0e-5
    assert p.model.opt.timestep == 3.0e-5
    p.model.opt.timestep = h0
    assert v[0] == h0


# ------------------------------------------------------------------------------------------ the compiled loop
def _loop_mode(mode: str):
    from biped_controller.core.control.config import load_controller_config
    from biped_controller.closed_loop.runner import ClosedLoop
    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily
    return ClosedLoop(MJ, load_controller_config(mode=mode, period=MJ.control_period), GaitFamily.load(),
                      load_description())


def _run_loop(loop, compiled_loop: bool, steps: int, pushes: tuple, **kw):
    """The run through the runner's loop with or without the compiled closed loop (the plant's compiled steps
    either way), the MuJoCo segment's calls counted; with the early stop's calls (t, impacts) logged."""
    from biped_controller.closed_loop import segment
    calls = []
    kernel = _Count(segment.load_mujoco_loop_kernels().run_mujoco_segment)
    on_impact = kw.pop("stop_at", None)

    def check(sim, ctrl):
        calls.append((sim.t, sim.impact_count, ctrl.step_index))
        return on_impact is not None and sim.impact_count >= on_impact
    loop.sim.compiled_steps = True
    loop.reset()
    mk = segment.load_mujoco_loop_kernels()
    orig = mk.run_mujoco_segment
    mk.run_mujoco_segment = kernel
    try:
        r = loop.run(steps, pushes, limit=10.0, compiled_loop=compiled_loop, on_impact=check, **kw)
    finally:
        mk.run_mujoco_segment = orig
    st = np.empty(mujoco.mj_stateSize(loop.sim.model, mujoco.mjtState.mjSTATE_INTEGRATION))
    mujoco.mj_getState(loop.sim.model, loop.sim.data, st, mujoco.mjtState.mjSTATE_INTEGRATION)
    return r, loop.sim.diagnostics, st, kernel.n, calls, loop.ctrl.memory.copy()


@pytest.mark.parametrize("mode,steps,push,fallen", [
    ("both", 3, Push(0.2315, 0.025, 300.0), False),     # push inside periods, QP periods decided between calls
    ("both", 2, Push(0.2315, 0.025, 1500.0), True),     # a fall named after a compiled call
    ("tau", 2, Push(0.6, 0.025, -150.0), False),
    ("wbc", 1, Push(0.2315, 0.025, 200.0), False),      # the compiled whole-body stage in the loop
])
def test_compiled_loop_bit_identical_to_the_objects(mode, steps, push, fallen):
    """The MuJoCo compiled closed loop (``MujocoSegment``) against the objects period by period (controller
    ``compute`` + ``MujocoPlant.step``): every field of every record, status and impact, the outcome, the
    early stop's calls (time, impacts, controller period), the contact diagnostics, MuJoCo's state and the
    controller's memory at the end, bit for bit."""
    loop = _loop_mode(mode)
    ref, dg_ref, st_ref, k_ref, calls_ref, mem_ref = _run_loop(loop, False, steps, (push,))
    new, dg_new, st_new, k_new, calls_new, mem_new = _run_loop(loop, True, steps, (push,))
    assert k_ref == 0 and k_new > 0
    assert ref.fallen is fallen and new.fallen is fallen
    assert len(new.records) == len(ref.records) and len(new.statuses) == len(ref.statuses)
    for a, b in zip(ref.records, new.records):
        assert _equal(a, b), (a.t, a, b)
    for a, b in zip(ref.statuses, new.statuses):
        assert _equal(a, b), (a.t, a, b)
    assert _equal(ref.impacts, new.impacts)
    assert (ref.steps_walked, ref.fall_cause, ref.fall_detail) == (new.steps_walked, new.fall_cause, new.fall_detail)
    assert _equal(ref.fall_time, new.fall_time)
    assert calls_ref == calls_new
    assert dg_ref.as_dict() == dg_new.as_dict() and dg_ref.touchdown_forces == dg_new.touchdown_forces
    assert st_ref.tobytes() == st_new.tobytes() and mem_ref.tobytes() == mem_new.tobytes()


def test_compiled_loop_early_stop_and_outcome_only():
    """The early stop ending a run at its second impact's check and a run keeping only its outcome
    (``keep_records`` False): the compiled loop's records (those kept), statuses, outcome and calls equal the
    objects'."""
    loop = _loop_mode("both")
    push = (Push(0.2315, 0.025, 300.0),)
    for kw in (dict(stop_at=2), dict(keep_records=False)):
        ref, _, st_ref, _, calls_ref, _ = _run_loop(loop, False, 3, push, **dict(kw))
        new, _, st_new, k_new, calls_new, _ = _run_loop(loop, True, 3, push, **dict(kw))
        assert k_new > 0
        assert calls_ref == calls_new and len(calls_ref) >= 2
        assert (ref.steps_walked, ref.fallen) == (new.steps_walked, new.fallen)
        assert _equal(ref.records[-1], new.records[-1]) and _equal(ref.statuses[-1], new.statuses[-1])
        assert st_ref.tobytes() == st_new.tobytes()
        if "stop_at" in kw:
            assert ref.steps_walked == 2
            assert _equal(ref.records, new.records) and _equal(ref.statuses, new.statuses)
