"""The IMU in the ROS graph: real sensing over the real DDS graph equals the in-process loop.

The launcher starts the whole graph (Fast DDS on loopback, isolated domain: ``ros_domain``) with the
simulator's sensor model on (joint noise 5e-4 rad and 5e-2 rad/s, 14-bit encoders, IMU pitch noise 1e-3 rad
and gyro noise 2e-2 rad/s, seed 7) and the controller's estimator and momentum observer on (the design
point of docs/robustness.md), the estimator fusing the gyro too (``estimator_gyro``, 2e-2 rad/s). The
controller node pairs each ``/sim/state`` with the ``/imu`` of its stamp and passes the pitch and the pitch
rate to its estimator. From the MCAP bag read back by ``bag_reader``:

- one ``/imu`` per state, stamped as that state, frame ``torso``, covariances from the sensor model;
- the run equals, bit for bit, the in-process loop that passes the pitch and the rate through the same ``Imu``
  message (theta = 2 atan2(-y, w): the quaternion round trip can move the pitch by one unit in the last place;
  the rate = -angular_velocity.y is exact);
- it equals ``runner.run`` (the pitch as the plant gives it) to ``TOL`` (see below);
- Foxglove's own MCAP reader (``tests/js/read_bag.mjs``, ``@mcap/core``) finds the same ``/imu`` messages:
  one per ``/sim/state``, the same stamps and quaternions;
- negative controls: the in-process loop without the IMU (pitch and rate NaN, the estimator runs on the joints
  alone), and the one without the gyro's rate alone (the pitch kept), are other runs, far outside ``TOL``, so
  the comparisons above can fail and see the rate.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
JS_DIR = ROOT / 'tests' / 'js'
PY = ROOT / '.venv' / 'bin' / 'python'
STEPS = 1
PERT = dict(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, noise_pitch=1e-3, noise_pitch_rate=2e-2, seed=7)
CTRL = dict(state_estimator=True, sensor_noise_q=5e-4, sensor_noise_qd=5e-2, sensor_encoder_bits=14,
            sensor_noise_pitch=1e-3, momentum_observer=True, momentum_observer_gain=50.0, estimator_gyro=True,
            sensor_noise_pitch_rate=2e-2)
# the graph against runner.run: the IMU's pitch differs from the plant's by at most 1 ulp (~1e-17 rad) in
# some periods; the closed loop carries that round-off, it does not amplify it to anything near this
TOL = 1e-9

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def _param(v) -> str:
    return 'true' if v is True else 'false' if v is False else repr(v)


def _in_process(ccfg, pert, through_imu: bool | str | None):
    """The in-process closed loop of ``runner.run``'s object path, with the pitch and rate as the plant gives
    them (``None``), through the ``/imu`` message (``True``), dropped (``False``: NaN), or through the message
    without the rate (``'no_rate'``)."""
    from builtin_interfaces.msg import Time
    from biped_sim.graph.imu import ImuBuilder, imu_reading
    from biped_sim.plant.config import load_sim_config
    from biped_model.description import load_description
    from biped_model.gait_family import GaitFamily
    from biped_controller.closed_loop.runner import ClosedLoop
    loop = ClosedLoop(load_sim_config(), ccfg, GaitFamily.load(), load_description(), pert)
    loop.reset()
    sim, ctrl = loop.sim, loop.ctrl
    imu = ImuBuilder(pert.noise_pitch, pert.noise_pitch_rate)
    recs, obs_list, torques = [], [], []
    while sim.impact_count < STEPS and sim.fall is None:
        obs = sim.observe()
        pitch, rate = obs.pitch, obs.pitch_rate
        if through_imu in (True, 'no_rate'):
            pitch, rate = imu_reading(imu.message(Time(), obs.pitch, obs.pitch_rate))
        if through_imu is False:
            pitch = float('nan')
        if through_imu in (False, 'no_rate'):
            rate = float('nan')
        out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, pitch, rate)
        obs_list.append(obs)
        torques.append(np.array(out.torque, dtype=float))
        recs.append(sim.step(out.torque))
    return recs, obs_list, torques, sim.fall


def test_imu_over_dds_with_real_sensing_equals_the_in_process_loop(ros_domain, tmp_path):
    from biped_sim.graph.imu import imu_reading
    from biped_sim.plant.perturbation import PlantPerturbation
    from biped_sim.recording.bag_reader import read_bag
    from biped_controller.core.control.config import load_controller_config
    from biped_controller.closed_loop import runner

    bag, ready = tmp_path / 'bag', tmp_path / 'ready'
    cmd = [str(PY), '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--ready-file', str(ready),
           '--steps', str(STEPS)]
    for k, v in PERT.items():
        cmd += ['--sim-param', f'perturbation.{k}:={_param(v)}']
    for k, v in CTRL.items():
        cmd += ['--ctrl-param', f'{k}:={_param(v)}']
    # nothing to do while it runs: subprocess.run kills the launcher on a timeout (its nodes die with it)
    run = subprocess.run(cmd, env=dict(os.environ), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:]

    pert = PlantPerturbation(**PERT)
    ccfg = load_controller_config(mode='both', **CTRL)
    recs, obs, torques, fall = _in_process(ccfg, pert, through_imu=True)
    assert fall is None and len(recs) > 400

    d = read_bag(bag, decode=True)
    states = [m for t, _, _, m in d['messages'] if t == '/sim/state']
    imus = [m for t, _, _, m in d['messages'] if t == '/imu']
    torque = [m for t, _, _, m in d['messages'] if t == '/controller/torque']
    assert len(states) == len(recs) + 1 and not any(s.fallen for s in states)
    # one /imu per state, stamped as that state, the torso's, with the sensor model's covariances
    assert [(m.header.stamp.sec, m.header.stamp.nanosec) for m in imus] == \
        [(s.stamp.sec, s.stamp.nanosec) for s in states]
    assert {m.header.frame_id for m in imus} == {'torso'}
    for m in imus:
        assert list(m.orientation_covariance) == [0, 0, 0, 0, 1e-3 ** 2, 0, 0, 0, 0]
        assert list(m.angular_velocity_covariance) == [0, 0, 0, 0, 2e-2 ** 2, 0, 0, 0, 0]
        assert m.linear_acceleration_covariance[0] == -1.0
    # bit for bit: the noisy samples, the true base, the torques, the IMU's reading
    assert len(torque) >= len(recs)
    for k, (rec, o) in enumerate(zip(recs, obs)):
        s = states[k]
        assert np.array_equal(np.array(s.q), o.q) and np.array_equal(np.array(s.q_dot), o.qd), k
        assert np.array_equal(np.array(s.base), rec.x[:3]) and np.array_equal(np.array(s.base_dot), rec.v[:3]), k
        assert np.array_equal(np.array(torque[k].effort), torques[k]), k
        pitch, rate = imu_reading(imus[k])
        assert rate == o.pitch_rate and abs(pitch - o.pitch) <= np.spacing(abs(o.pitch)), k
    # the IMU is noisy (against the true pitch, the base's), the estimator took it (not a NaN run)
    true_pitch = np.array([rec.x[2] for rec in recs])
    imu_pitch = np.array([imu_reading(m)[0] for m in imus[:len(recs)]])
    assert 0.5e-3 < np.std(imu_pitch - true_pitch) < 2e-3

    # the independent reader (Foxglove's npm libraries): the same /imu, one per state
    if shutil.which('node') is None or not (JS_DIR / 'node_modules' / '@mcap' / 'core').is_dir():
        pytest.fail('the Node.js reader (tests/js, scripts/setup) is needed for this test')
    from biped_sim.recording.bag_reader import find_mcap
    js = subprocess.run(['node', str(JS_DIR / 'read_bag.mjs'), str(find_mcap(bag))], capture_output=True,
                        text=True, timeout=300, cwd=JS_DIR)
    assert js.returncode == 0, js.stderr[-2000:]
    doc = json.loads(js.stdout)
    assert doc['counts']['/imu'] == doc['counts']['/sim/state'] == len(states)
    js_imu = [m['msg'] for m in doc['messages'] if m['topic'] == '/imu']
    assert [(int(m['header']['stamp']['sec']), int(m['header']['stamp']['nanosec']), m['header']['frame_id'],
             m['orientation']['y'], m['orientation']['w'], m['angular_velocity']['y']) for m in js_imu] == \
        [(m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id, m.orientation.y, m.orientation.w,
          m.angular_velocity.y) for m in imus]

    moved = sum(imu_reading(m)[0] != o.pitch for m, o in zip(imus, obs))

    def gap(records) -> tuple[float, float]:
        """largest |difference| of the bag's base pose and base velocity from ``records``'"""
        n = min(len(records), len(recs))
        return (max(float(np.max(np.abs(np.array(states[k].base) - records[k].x[:3]))) for k in range(n)),
                max(float(np.max(np.abs(np.array(states[k].base_dot) - records[k].v[:3]))) for k in range(n)))

    # to TOL: runner.run, the pitch as the plant gives it
    ref = runner.run(steps=STEPS, mode='both', ctrl_config=ccfg, perturbation=pert)
    assert len(ref.records) == len(recs)
    gap_ref = gap(ref.records)
    assert max(gap_ref) <= TOL, gap_ref
    # negative control: without the IMU the estimator gives another run, far outside TOL
    recs_nan, _, _, _ = _in_process(ccfg, pert, through_imu=False)
    gap_nan = gap(recs_nan)
    assert min(gap_nan) > 1e3 * TOL, gap_nan
    # negative control: without the gyro's rate (the pitch kept) another run too: the node passed the rate
    recs_nr, _, _, _ = _in_process(ccfg, pert, through_imu='no_rate')
    gap_nr = gap(recs_nr)
    assert min(gap_nr) > 1e3 * TOL, gap_nr
    print(f'\n{len(recs)} periods; IMU pitch 1 ulp off the plant\'s in {moved}; the bag against runner.run: '
          f'base {gap_ref[0]:.3g}, base rate {gap_ref[1]:.3g}; against the run without IMU: base {gap_nan[0]:.3g}, '
          f'base rate {gap_nan[1]:.3g}; without the rate: base {gap_nr[0]:.3g}, base rate {gap_nr[1]:.3g}')
