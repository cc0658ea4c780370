"""What the compiled closed loops take from a plant, through its public API (``closed_loop.segment`` reads no
private attribute of the plant):

- ``push_rows()`` on both plants (``ScheduledPushes``): the scheduled pushes as (start, end [s], force [N],
  height [m]) rows in the book's order, checked against the pushes as scheduled, the same array while the
  schedule does not change;
- ``MujocoPlant.compiled_plant()``: one object for the plant's life whose arrays are MuJoCo's and the plant's
  own memory (a write through it is the plant's state), its constants the configuration's and the
  description's;
- the segment module's source reads no ``sim._`` attribute.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from biped_model.description import LEFT, load_description
from biped_model.gait_family import GaitFamily
from biped_sim.plant.config import load_sim_config
from biped_sim.plant.protocol import make_plant

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("plant", ["rigid", "mujoco"])
def test_push_rows_are_the_schedule(plant):
    if plant == "mujoco":
        pytest.importorskip("mujoco")
    cfg = load_sim_config(plant=plant)
    sim = make_plant(plant, load_description(), cfg)
    q0, qd0 = GaitFamily.load().initial_state()
    sim.reset(q0, qd0, LEFT)
    empty = sim.push_rows()
    assert empty.shape == (0, 4)
    sim.schedule_push(0.2, 0.025, 150.0)
    sim.schedule_push(0.5, 0.01, -80.0, 0.1)
    rows = sim.push_rows()
    want = np.array([[0.2, 0.2 + 0.025, 150.0, cfg.push_height], [0.5, 0.5 + 0.01, -80.0, 0.1]])
    assert rows.shape == (2, 4) and np.allclose(rows, want, rtol=0, atol=1e-15)
    assert np.array_equal(rows, [[p.start, p.end, p.force, p.height] for p in sim.pushes])
    assert sim.push_rows() is rows                 # unchanged schedule: the same array


def test_compiled_plant_is_the_plant_s_own_memory():
    pytest.importorskip("mujoco")
    desc = load_description()
    cfg = load_sim_config(plant="mujoco")
    sim = make_plant("mujoco", desc, cfg)
    q0, qd0 = GaitFamily.load().initial_state()
    sim.reset(q0, qd0, LEFT)
    cp = sim.compiled_plant()
    assert sim.compiled_plant() is cp
    cfrc, xpos, scom, qpos, qvel, xfrc, ctrl = cp.mj_arrays
    d = sim.data
    for mine, theirs in ((cfrc, d.cfrc_ext), (xpos, d.xpos), (scom, d.subtree_com), (qpos, d.qpos),
                         (qvel, d.qvel), (xfrc, d.xfrc_applied), (ctrl, d.ctrl)):
        assert np.shares_memory(mine, theirs)
    assert cp.model_address == sim.model._address and cp.data_address == d._address
    assert float(cp.timestep[0]) == cfg.mujoco_timestep == cp.mujoco_step
    lo, hi = desc.torque_limits()
    assert np.array_equal(cp.torque_min, lo) and np.array_equal(cp.torque_max, hi)
    assert cp.torso_com == desc.torso.com
    assert cp.bad_warnings.dtype == np.int64 and len(cp.bad_warnings) == 3
    assert np.shares_memory(cp.warnings, d.warning.number)
    assert len(cp.step_arguments()) == 3 + 7 + 3 + 2 + 2
    # the bookkeeping arrays are the plant's: a reset writes them in place
    before = cp.acc.copy()
    sim.step(np.zeros(6))
    assert not np.array_equal(before, cp.acc)
    sim.reset(q0, qd0, LEFT)
    assert sim.compiled_plant() is cp and np.array_equal(cp.acc, before, equal_nan=True)


def test_the_compiled_loop_reads_no_private_plant_attribute():
    text = (ROOT / "src/biped_controller/biped_controller/closed_loop/segment.py").read_text()
    assert re.findall(r"\bsim\._\w+", text) == []
