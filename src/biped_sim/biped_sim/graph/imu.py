"""The torso IMU as a ROS 2 ``sensor_msgs/msg/Imu`` (ROS layer): built by the simulator, read by the controller.

The robot is planar: the torso turns about the world's -y axis only (DESIGN.md: every joint axis is
(0, -1, 0), angles counter-clockwise in the sagittal view x right / z up). With theta the torso pitch [rad]
and theta' its rate [rad/s] as the sensor model reports them (``biped_sim.plant.perturbation.SensorModel``):

- ``header.frame_id`` = ``torso`` (the URDF's root link; the IMU sits on it), ``header.stamp`` = the stamp of
  the ``/sim/state`` it goes with (the same sample: delayed with the joints under a delay);
- ``orientation`` = the torso frame w.r.t. ``world``, a rotation by theta about (0, -1, 0):
  (x, y, z, w) = (0, -sin(theta/2), 0, cos(theta/2)), the rotation of ``/tf``'s world -> torso;
- ``angular_velocity`` in the torso frame (a rotation about y keeps the y axis) = (0, -theta', 0);
- ``linear_acceleration``: not modelled: zeros, ``linear_acceleration_covariance[0] = -1`` (the message's
  "no estimate" convention);
- covariances, row-major 3x3 about x, y, z: ``orientation_covariance`` = diag(0, sigma_theta^2, 0),
  ``angular_velocity_covariance`` = diag(0, sigma_rate^2, 0) with the sensor model's noise standard
  deviations ``noise_pitch`` [rad] and ``noise_pitch_rate`` [rad/s] (0: a perfect sensor); the out-of-plane
  components are exactly 0 by construction of the planar model. The IMU has no quantisation (only the
  encoders have, ``encoder_bits``).

Reading back (:func:`imu_reading`): theta = 2 atan2(-y, w), theta' = -angular_velocity.y. The rate comes back
exactly; the pitch to within one unit in the last place (the sine / cosine round trip: 17 % of uniformly
drawn angles in [-0.6, 0.6] rad come back 1 ulp off), which is why the graph matches the in-process loop
to a stated tolerance and not bit for bit when the estimator takes the pitch (DESIGN.md).
"""
from __future__ import annotations

import math

from sensor_msgs.msg import Imu

from biped_sim.graph import cdr
from biped_sim.graph.names import IMU_FRAME
from biped_model.finite import finite_number

#: the largest out-of-plane quaternion component or unit-norm error a reader accepts (round-off is ~1e-16)
PLANAR_TOLERANCE = 1e-9


class ImuMessageError(ValueError):
    """An ``Imu`` message is not this robot's planar torso IMU (the message says which field)."""


class ImuBuilder:
    """Builds the ``/imu`` message of each state; one message object updated in place (as the /tf builder)."""

    def __init__(self, noise_pitch: float, noise_pitch_rate: float) -> None:
        for name, v in (('noise_pitch', noise_pitch), ('noise_pitch_rate', noise_pitch_rate)):
            finite_number(v, name, at_least=0.0,
                          message=f'ImuBuilder: {name} must be a finite standard deviation >= 0, got {v!r}')
        m = Imu()
        m.header.frame_id = IMU_FRAME
        m.orientation_covariance[4] = float(noise_pitch) ** 2
        m.angular_velocity_covariance[4] = float(noise_pitch_rate) ** 2
        m.linear_acceleration_covariance[0] = -1.0
        self._msg = m
        self._cdr = cdr.Imu(IMU_FRAME)
        self._covariances = (float(noise_pitch) ** 2, float(noise_pitch_rate) ** 2)

    def message(self, stamp, pitch: float, pitch_rate: float) -> Imu:
        """The IMU message at ``stamp`` for the torso pitch [rad] and pitch rate [rad/s] (counter-clockwise
        positive). The object is reused: publish it before the next call."""
        m = self._msg
        m.header.stamp = stamp
        o = m.orientation
        o.x, o.y, o.z, o.w = 0.0, -math.sin(0.5 * pitch), 0.0, math.cos(0.5 * pitch)
        m.angular_velocity.y = -float(pitch_rate)
        return m

    def encode(self, sec: int, nanosec: int, pitch: float, pitch_rate: float) -> bytes:
        """The CDR bytes (``biped_sim.graph.cdr``) of :meth:`message` at stamp ``(sec, nanosec)``: the same
        numbers in the message's order (orientation, its covariance, angular velocity, its covariance, linear
        acceleration, its covariance)."""
        var_pitch, var_rate = self._covariances
        return self._cdr.encode(sec, nanosec, (
            0.0, -math.sin(0.5 * pitch), 0.0, math.cos(0.5 * pitch),
            0.0, 0.0, 0.0, 0.0, var_pitch, 0.0, 0.0, 0.0, 0.0,
            0.0, -float(pitch_rate), 0.0,
            0.0, 0.0, 0.0, 0.0, var_rate, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0,
            -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))


def imu_reading(msg: Imu) -> tuple[float, float]:
    """(torso pitch [rad], pitch rate [rad/s]) of an ``/imu`` message (module docstring). Raises
    :class:`ImuMessageError` naming the field when the message is not a planar torso IMU: another
    ``frame_id``, a non-finite value, an orientation with a component about x or z or not of unit norm, an
    angular velocity about x or z."""
    if msg.header.frame_id != IMU_FRAME:
        raise ImuMessageError(f'header.frame_id must be {IMU_FRAME!r}, got {msg.header.frame_id!r}')
    o, w = msg.orientation, msg.angular_velocity
    values = {'orientation.x': o.x, 'orientation.y': o.y, 'orientation.z': o.z, 'orientation.w': o.w,
              'angular_velocity.x': w.x, 'angular_velocity.y': w.y, 'angular_velocity.z': w.z}
    for name, v in values.items():
        finite_number(v, name, error=ImuMessageError, message=f'{name} must be finite, got {v}')
    for name in ('orientation.x', 'orientation.z', 'angular_velocity.x', 'angular_velocity.z'):
        if abs(values[name]) > PLANAR_TOLERANCE:
            raise ImuMessageError(f'{name} must be 0 (a planar robot turns about y only), got {values[name]}')
    norm = math.sqrt(o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w)
    if abs(norm - 1.0) > PLANAR_TOLERANCE:
        raise ImuMessageError(f'orientation must be a unit quaternion, got norm {norm}')
    return 2.0 * math.atan2(-o.y, o.w), -w.y
