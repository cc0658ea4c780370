"""The torso IMU (graph part): the gyro of the sensor model and the ``/imu`` message.

Oracles: the rotation matrix of the message's quaternion (the textbook formula, written here) against the
sagittal-view convention of DESIGN.md (a counter-clockwise pitch turns the torso's x axis towards +z); the
sample statistics of seeded noise against the standard deviation asked for; the identity of the other noise
sequences with and without the gyro's noise. Negative controls: a quaternion about another axis, another
frame, a non-unit quaternion are refused naming the field; a wrong sign of the rate would fail the rotation
check.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from biped_sim.plant.perturbation import PerturbationError, PlantPerturbation, SensorModel

pytest.importorskip('sensor_msgs.msg', reason='the ROS 2 message wheels are part of requirements.txt')
from builtin_interfaces.msg import Time  # noqa: E402


def rotation(x, y, z, w) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w) (textbook formula)."""
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_imu_message_follows_the_sagittal_convention_and_reads_back():
    from biped_sim.graph.imu import ImuBuilder, imu_reading
    b = ImuBuilder(noise_pitch=2e-3, noise_pitch_rate=3e-2)
    rng = np.random.default_rng(11)
    worst = 0.0
    for theta, rate in zip(rng.uniform(-0.6, 0.6, 2000), rng.uniform(-3.0, 3.0, 2000)):
        m = b.message(Time(), float(theta), float(rate))
        o = m.orientation
        R = rotation(o.x, o.y, o.z, o.w)
        # counter-clockwise in the view x right / z up: the torso's x axis turns towards +z
        np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [math.cos(theta), 0.0, math.sin(theta)], atol=1e-15)
        np.testing.assert_allclose(R @ [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
        # body rate = rotation about -y at theta'
        assert (m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) == (0.0, -rate, 0.0)
        p, r = imu_reading(m)
        assert r == rate                                   # the rate comes back exactly
        worst = max(worst, abs(p - theta) / np.spacing(abs(theta)))
    assert worst <= 1.0                                    # the pitch to one unit in the last place
    assert m.header.frame_id == 'torso'
    np.testing.assert_array_equal(m.orientation_covariance, [0, 0, 0, 0, 2e-3 ** 2, 0, 0, 0, 0])
    np.testing.assert_array_equal(m.angular_velocity_covariance, [0, 0, 0, 0, 3e-2 ** 2, 0, 0, 0, 0])
    assert m.linear_acceleration_covariance[0] == -1.0     # not measured (sensor_msgs/Imu convention)


@pytest.mark.parametrize('change,field', [
    (lambda m: setattr(m.header, 'frame_id', 'base_link'), 'header.frame_id'),
    (lambda m: setattr(m.orientation, 'x', 0.1), 'orientation.x'),
    (lambda m: setattr(m.orientation, 'w', 0.5), 'unit quaternion'),
    (lambda m: setattr(m.angular_velocity, 'z', 0.2), 'angular_velocity.z'),
    (lambda m: setattr(m.angular_velocity, 'y', math.nan), 'angular_velocity.y'),
])
def test_imu_reading_refuses_what_is_not_the_planar_torso_imu(change, field):
    from biped_sim.graph.imu import ImuBuilder, ImuMessageError, imu_reading
    m = ImuBuilder(0.0, 0.0).message(Time(), 0.1, 0.5)
    assert imu_reading(m) == pytest.approx((0.1, 0.5), abs=1e-16)     # control: the message as built reads
    change(m)
    with pytest.raises(ImuMessageError, match=field.replace('.', r'\.')):
        imu_reading(m)


def test_imu_builder_refuses_a_bad_standard_deviation():
    from biped_sim.graph.imu import ImuBuilder
    with pytest.raises(ValueError, match='noise_pitch_rate'):
        ImuBuilder(0.0, -1.0)


def test_gyro_noise_statistics_delay_and_independence():
    sigma = 4e-2
    q, qd = np.array([0.1, 0.2, -0.3, 0.1, 0.4, -0.2]), np.array([1.0, -2.0, 0.5, 0.3, 0.1, 0.2])
    true_rate = 0.7
    with_gyro = SensorModel(PlantPerturbation(noise_q=1e-3, noise_qd=1e-2, noise_pitch=1e-2,
                                              noise_pitch_rate=sigma, delay=3, seed=8))
    without = SensorModel(PlantPerturbation(noise_q=1e-3, noise_qd=1e-2, noise_pitch=1e-2, delay=3, seed=8))
    n = 4000
    rates = np.empty(n)
    for k in range(n):
        a = with_gyro.sample(k, 0, q, qd, pitch=0.05, pitch_rate=true_rate)
        b = without.sample(k, 0, q, qd, pitch=0.05, pitch_rate=true_rate)
        # the joints' and the pitch's noise sequences do not change with the gyro's noise
        assert np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
        assert with_gyro.imu_reading(k)[0] == without.imu_reading(k)[0]
        assert without.imu_reading(k)[1] == true_rate      # no gyro noise: the true rate
        rates[k] = with_gyro.imu_reading(k)[1]
    # delayed with the sample: period k receives the sample of k - 3 (the first one before that)
    err = rates[3:] - true_rate
    # mean within 4 standard errors, std within 4 x its standard error (chi-square, n - 3 samples)
    assert abs(err.mean()) < 4 * sigma / math.sqrt(err.size)
    assert abs(err.std() / sigma - 1.0) < 4 / math.sqrt(2 * err.size)
    assert np.all(rates[:4] == rates[0])                   # the pipeline holds the first sample
    # the default true rate is q1' + q2' + q3' (a flat stance foot)
    s = SensorModel(PlantPerturbation(noise_q=1e-3))
    s.sample(0, 0, q, qd)
    assert s.imu_reading(0) == (q[0] + q[1] + q[2], qd[0] + qd[1] + qd[2])
    with pytest.raises(PerturbationError, match='noise_pitch_rate'):
        PlantPerturbation(noise_pitch_rate=-1e-3)
    assert not PlantPerturbation(noise_pitch_rate=1e-3).sensing_is_perfect


def test_rigid_plant_reports_the_torso_rate():
    """Observation.pitch_rate is the floating base's pitch rate (perfect sensing), and the sensor model's
    sample of it with a gyro of zero noise (the joints noisy)."""
    from biped_sim.plant.config import load_sim_config
    from biped_sim.plant.rigid import Simulator
    from biped_model.description import LEFT, load_description
    from biped_model.gait_family import GaitFamily
    from biped_controller.core.control.config import load_controller_config
    from biped_controller.core.control.controller import AdaptiveController
    desc, cfg, family = load_description(), load_sim_config(), GaitFamily.load()
    q0, qd0 = family.initial_state()
    for pert in (PlantPerturbation(), PlantPerturbation(noise_q=1e-3, seed=2)):
        sim = Simulator(desc, cfg, pert)
        sim.reset(q0, qd0, LEFT)
        ctrl = AdaptiveController(load_controller_config(), family, desc)
        ctrl.reset(LEFT)
        first = sim.observe()
        # flat stance foot: theta = q1 + q2 + q3, theta' = q1' + q2' + q3' (to round-off)
        assert first.pitch_rate == pytest.approx(float(np.sum(qd0[:3])), abs=1e-12)
        assert first.pitch == pytest.approx(float(np.sum(q0[:3])), abs=1e-12)
        rates = []
        for _ in range(50):
            obs = sim.observe()
            assert obs.pitch_rate == float(sim.v[2]) and obs.pitch == float(sim.x[2])
            rates.append(obs.pitch_rate)
            sim.step(ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch).torque)
            assert sim.fall is None
        assert abs(rates[-1] - rates[0]) > 1e-3            # control: the torso's rate changes, read each period


def test_controller_status_table_covers_every_message_field():
    """``controller_node.STATUS_FIELDS`` (the table-driven ``status_message``) names every field of
    ControllerStatus.msg but the stamp, each a field of ``ControllerStatusData``; the message it builds
    carries the values. Negative control: a field left out of the table is caught by the same comparison."""
    import dataclasses
    from biped_msgs_py.msg import ControllerStatus
    from biped_controller.core.control.status import ControllerStatusData
    from biped_controller.graph.controller_node import STATUS_FIELDS, status_message
    names = [n for n, _ in STATUS_FIELDS]
    msg_fields = set(ControllerStatus.get_fields_and_field_types()) - {'stamp'}
    assert len(names) == len(set(names)) and set(names) == msg_fields
    assert set(names[1:]) != msg_fields                                     # control: one missing is seen
    data_fields = {f.name for f in dataclasses.fields(ControllerStatusData)}
    assert set(names) <= data_fields
    values = {}
    for i, f in enumerate(dataclasses.fields(ControllerStatusData)):
        if f.name in ('margins',):
            values[f.name] = np.arange(17, dtype=float) + 0.5
        elif f.name == 'predicted_reaction':
            values[f.name] = np.array([1.5, 2.5])
        elif f.name in ('mode', 'qp_message'):
            values[f.name] = f'text{i}'
        elif f.name in ('step', 'qp_status', 'tightest', 'stance', 'wbc_status', 'wbc_active'):
            values[f.name] = i % 2
        else:
            values[f.name] = i + 0.25
    s = ControllerStatusData(**values)
    m = status_message(s, Time(sec=3, nanosec=4))
    assert (m.stamp.sec, m.stamp.nanosec) == (3, 4)
    for name in names:
        got, want = getattr(m, name), values[name]
        assert np.array_equal(np.asarray(got), np.asarray(want)), name
