"""A plug-in controller in the ROS graph over real DDS equals the in-process loop.

The launcher starts the whole graph (Fast DDS on loopback, isolated domain: ``ros_domain``) with the
controller node's ``controller`` parameter naming the example package's capture-point step adjuster
(``capture_point``, registered through its entry point) and one push scheduled by the disturbance node
(40 N on the back for 25 ms from t = 0.2315 s, below its 50 N boundary: the adjuster speeds up its step). The bag,
read back by ``bag_reader``, is compared with ``plugin.loop.run`` of the same controller, push and steps:

- the states (q, q', stance, step) are the same, bit for bit, as in ``tests/test_graph.py`` (the controller
  sees the same observation: its time is the stamp's, ``interface.stamp_time``, in both);
- the torques, clipped to the torque limits the simulator applies, agree to 1e-4 N m as there;
- the status carries the controller's name and its stride p and time scaling tau' of the in-process run
  (tau' leaves 1 by more than 1e-3 after the push: the run compared is an adapting one);
- a negative control: the in-process run without the push is another run, far from the bag, so the
  comparison can fail.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from helpers import graph_params_with_push, run_launch

ROOT = Path(__file__).resolve().parents[1]
PY = ROOT / '.venv' / 'bin' / 'python'
STEPS = 2
NAME = 'capture_point'
PUSH = dict(force=40.0, duration=0.025, start=0.2315)

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_plugin_in_graph_equals_in_process(ros_env, tmp_path):
    pytest.importorskip('capture_point_stepper')
    from biped_sim.plant.push import Push
    from biped_sim.recording.bag_reader import read_bag
    from biped_controller.plugin import loop as plugin_loop

    bag = tmp_path / 'bag'
    cmd = [str(PY), '-m', 'biped_sim.graph.launch', '--params', str(graph_params_with_push(tmp_path, PUSH)), '--bag', str(bag),
           '--steps', str(STEPS), '--ctrl-param', f'controller:={NAME}']
    out = run_launch(cmd, ros_env)
    assert f"controller ready: controller '{NAME}'" in out, out[-4000:]

    push = Push(PUSH['start'], PUSH['duration'], PUSH['force'])
    ref = plugin_loop.run(NAME, steps=STEPS, pushes=(push,))
    assert ref.fault is None and not ref.fallen and ref.steps_walked == STEPS
    d = read_bag(bag, decode=True)
    states = [m for t, _, _, m in d['messages'] if t == '/sim/state']
    torques = [m for t, _, _, m in d['messages'] if t == '/controller/torque']
    status = [m for t, _, _, m in d['messages'] if t == '/controller/status']
    assert len(states) == len(ref.records) + 1        # + the final state
    assert len(torques) == len(status) >= len(ref.records)   # (the final state may be answered too)
    lo, hi = -150.0, 150.0
    for k, rec in enumerate(ref.records):
        s = states[k]
        assert s.step == rec.step == k
        assert s.stance == rec.stance
        assert np.array_equal(np.array(s.q), rec.q), (k, np.max(np.abs(np.array(s.q) - rec.q)))
        assert np.array_equal(np.array(s.q_dot), rec.qd), (k, np.max(np.abs(np.array(s.q_dot) - rec.qd)))
        assert (torques[k].header.stamp.sec, torques[k].header.stamp.nanosec) == (s.stamp.sec, s.stamp.nanosec)
        assert np.max(np.abs(np.clip(np.array(torques[k].effort), lo, hi) - rec.torque)) < 1e-4, k
        assert status[k].mode == NAME
        assert status[k].p == ref.statuses[k]['p'] and status[k].tau_dot == ref.statuses[k]['tau_dot'], k
    # the push made the adjuster change its timing: the comparison above covers an adapting run
    assert np.max(np.abs(ref.series('tau_dot') - 1.0)) > 1e-3
    # negative control: without the push the in-process run is another run
    other = plugin_loop.run(NAME, steps=STEPS)
    n = min(len(other.records), len(ref.records))
    assert max(np.max(np.abs(other.records[k].q - ref.records[k].q)) for k in range(n)) > 1e-3


def test_controller_node_refuses_an_unknown_controller_naming_it(ros_env):
    p = subprocess.run([str(PY), '-m', 'biped_controller.graph.controller_node', '--ros-args', '-p',
                        'controller:=no_such_controller'], env=ros_env, cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 2, (p.stdout[-2000:], p.stderr[-2000:])
    assert "'controller'" in p.stdout + p.stderr and 'no_such_controller' in p.stdout + p.stderr
