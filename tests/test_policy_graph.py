"""An ONNX policy as the ROS graph's controller over real DDS equals the in-process plug-in loop.

A linear PD-like policy, built here with the ``onnx`` package (action = tanh((q_ref - q) Kp / tau_max -
q' Kd / tau_max) per joint in paper order, q_ref the gait family's initial posture), is written to a file
and given to the controller node as ``controller: onnx_policy`` with ``controller_options: ['file=PATH']``
(the launcher's ``--ctrl-param``). The whole graph runs on the MuJoCo plant (Fast DDS on loopback, isolated domain:
``ros_domain``; the rigid plant's strict fall rules end a run of a standing policy in its first period) with
one push scheduled by the disturbance node, for ``T`` s of sim time
(``max_time``) or until the plant's fall. The bag, read back by ``bag_reader``, is compared with
``plugin.loop.run`` of ``onnx_policy`` with the same file, push and time limit:

- the states (the torso's pose and its rates, q2..q6 and their rates, stance, step) are the
  same, bit for bit, and the torques are the same, bit for bit (the policy sees the same observation: its time
  is the stamp's, ``interface.stamp_time``, in both), through the push and the fall (the bag's ``/fall`` cause
  is the in-process run's);
- the status carries the controller's name; the latched ``/controller/info`` and the bag's MCAP metadata
  record ``biped_controller`` (read with the ``mcap`` package) name the controller, its options and the
  policy file's SHA-256 (the file's own hash, computed here);
- a negative control: another policy (other gains) gives other torques, so the comparison can fail.

A bad option stops the node at start naming ``controller_options`` (exit 2, nothing published).
"""
from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import graph_params_with_push, run_launch

ROOT = Path(__file__).resolve().parents[1]
PY = ROOT / '.venv' / 'bin' / 'python'
T = 0.3                      # s of sim time
PUSH = dict(force=40.0, duration=0.025, start=0.05)
KP, KD = 50.0, 5.0           # N m/rad, N m s/rad: the robot stands ~0.18 s, pushed at 0.05 s, then falls

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def pd_policy_file(path: Path, kp: float, kd: float) -> Path:
    """The linear PD-like policy as ONNX: action = tanh(obs W + b), W and b from ``kp``, ``kd`` (module
    docstring), float64, input (batch, 22), output (batch, 6)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper
    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily
    from biped_controller.policy.spec import OBS_SIZE, torque_limits
    q_ref, _ = GaitFamily.load().initial_state()
    tmax = torque_limits(load_description())
    W = np.zeros((OBS_SIZE, 6))
    W[np.arange(6), np.arange(6)] = -kp / tmax             # q1..q6
    W[6 + np.arange(6), np.arange(6)] = -kd / tmax         # qd1..qd6
    b = kp * q_ref / tmax
    x = helper.make_tensor_value_info('obs', TensorProto.DOUBLE, ['batch', OBS_SIZE])
    y = helper.make_tensor_value_info('action', TensorProto.DOUBLE, ['batch', 6])
    nodes = [helper.make_node('MatMul', ['obs', 'W'], ['h']), helper.make_node('Add', ['h', 'b'], ['z']),
             helper.make_node('Tanh', ['z'], ['action'])]
    g = helper.make_graph(nodes, 'pd_policy', [x], [y], [numpy_helper.from_array(W, 'W'),
                                                          numpy_helper.from_array(b, 'b')])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid('', 17)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    onnx.save(m, str(path))
    return path


def test_onnx_policy_in_graph_equals_in_process(ros_env, tmp_path):
    from biped_sim.plant.push import Push
    from biped_sim.recording.bag_reader import read_bag
    from mcap.reader import make_reader
    from biped_sim.plant.config import load_sim_config
    from biped_controller.plugin import loop as plugin_loop

    policy = pd_policy_file(tmp_path / 'pd.onnx', KP, KD)
    bag = tmp_path / 'bag'
    cmd = [str(PY), '-m', 'biped_sim.graph.launch', '--params', str(graph_params_with_push(tmp_path, PUSH)), '--bag', str(bag),
           '--sim-param', 'plant:=mujoco', '--sim-param', f'max_time:={T}', '--ctrl-param', 'controller:=onnx_policy',
           '--ctrl-param', f"controller_options:=['file={policy}']"]
    out = run_launch(cmd, ros_env)
    assert "controller ready: controller 'onnx_policy' with options {'file': " in out, out[-4000:]

    push = Push(PUSH['start'], PUSH['duration'], PUSH['force'])
    scfg = load_sim_config(plant='mujoco')
    ref = plugin_loop.run('onnx_policy', steps=10, pushes=(push,), options={'file': str(policy)}, limit=T,
                          sim_config=scfg)
    assert ref.fault is None
    d = read_bag(bag, decode=True)
    states = [m for t, _, _, m in d['messages'] if t == '/sim/state']
    torques = [m for t, _, _, m in d['messages'] if t == '/controller/torque']
    status = [m for t, _, _, m in d['messages'] if t == '/controller/status']
    n = len(ref.records)
    print(f'{n} periods in process ({ref.fall_cause or "no fall"}), bag: {len(states)} states, '
          f'{len(torques)} torques')
    assert n >= 100
    falls = [m for t, _, _, m in d['messages'] if t == '/fall']
    if ref.fallen:      # the bag's fall is the in-process run's
        assert len(falls) == 1 and yaml.safe_load(falls[0].data)['cause'] == ref.fall_cause
    assert len(states) == n + 1 and len(torques) == len(status) >= n
    for k, rec in enumerate(ref.records):
        s = states[k]
        assert s.step == rec.step == k and s.stance == rec.stance
        assert (torques[k].header.stamp.sec, torques[k].header.stamp.nanosec) == (s.stamp.sec, s.stamp.nanosec)
        # the same plant state, bit for bit: the torso's pose (x, z, pitch), its rates, and the
        # joints q2..q6 (on MuJoCo /sim/state reports q1 against the ground, the record the ankle joint)
        assert np.array_equal(s.base, rec.base) and np.array_equal(s.base_dot, rec.base_dot), k
        assert np.array_equal(s.q[1:], rec.q[1:]) and np.array_equal(s.q_dot[1:], rec.qd[1:]), k
        # the same torque, bit for bit (the policy saw the same observation)
        assert np.array_equal(np.clip(np.array(torques[k].effort), -150.0, 150.0), rec.torque), k
        assert status[k].mode == 'onnx_policy'
    # the controller and its policy file, in the bag: the latched /controller/info and the MCAP metadata
    # record 'biped_controller' (read with the mcap package), against the file's hash computed here
    sha = hashlib.sha256(policy.read_bytes()).hexdigest()
    (info_msg,) = [m for t, _, _, m in d['messages'] if t == '/controller/info']
    (mcap_file,) = bag.glob('*.mcap')
    with open(mcap_file, 'rb') as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta['biped_controller']['yaml'] == info_msg.data
    info = yaml.safe_load(info_msg.data)
    assert info['controller'] == 'onnx_policy' and info['options'] == {'file': str(policy)}
    assert info['policy_sha256'] == info['files']['file']['sha256'] == sha
    assert info['policy_file'] == str(policy.resolve()) and info['policy_period'] == 0.01
    tq = np.array([r.torque for r in ref.records])
    assert np.abs(tq).max() > 10.0                       # the policy acts (not a zero torque)
    # negative control: other gains, other torques on the same first state
    other = plugin_loop.run('onnx_policy', steps=10, pushes=(push,), limit=0.02, sim_config=scfg,
                            options={'file': str(pd_policy_file(tmp_path / 'other.onnx', 2 * KP, KD))})
    assert np.abs(np.array([r.torque for r in other.records]) - tq[:len(other.records)]).max() > 1.0


def test_controller_node_refuses_a_bad_option_naming_the_parameter(ros_env, tmp_path):
    for opts in ("['file']", f"['file={tmp_path / 'none.onnx'}']"):
        p = subprocess.run([str(PY), '-m', 'biped_controller.graph.controller_node', '--ros-args', '-p',
                            'controller:=onnx_policy', '-p', f'controller_options:={opts}'], env=ros_env, cwd=ROOT,
                           capture_output=True, text=True, timeout=120)
        assert p.returncode == 2, (p.stdout[-2000:], p.stderr[-2000:])
        assert "invalid parameter 'controller_options'" in p.stderr, p.stderr[-2000:]
        assert 'controller ready' not in p.stdout + p.stderr
