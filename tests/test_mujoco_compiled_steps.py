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
    from biped_controller.core.control.controller import load_controller_config
    from biped_controller.studies.runner import ClosedLoop
    from biped_sim.robot.description import load_description
    from biped_sim.robot.gait_family import GaitFamily
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
