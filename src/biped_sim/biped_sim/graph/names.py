"""Every topic, service and QoS profile of the biped's ROS 2 graph, named in one place.

This is a ROS-layer module (it imports ``rclpy``); the pure cores must not import it.
Nodes, the recorder, the launcher and the tests take names, types and QoS from here only.

Topics (``TOPICS``), all under the node's namespace ``/``:

=========================  ======================================  ==============
name                       type                                    QoS key
=========================  ======================================  ==============
/clock                     rosgraph_msgs/msg/Clock                 clock
/sim/state                 biped_msgs_py/msg/SimState              lockstep
/imu                       sensor_msgs/msg/Imu                     lockstep
/joint_states              sensor_msgs/msg/JointState              sensor
/ground_reaction           geometry_msgs/msg/WrenchStamped         sensor
/ground_reaction/cop       geometry_msgs/msg/PointStamped          sensor
/stance                    std_msgs/msg/UInt8                      sensor
/tf                        tf2_msgs/msg/TFMessage                  tf
/robot_description         std_msgs/msg/String                     latched
/fall                      std_msgs/msg/String                     latched
/sim/impacts               biped_msgs_py/msg/Impact                events
/sim/push                  biped_msgs_py/msg/AppliedPush           sensor
/sim/plant                 std_msgs/msg/String (YAML)              latched
/controller/torque         sensor_msgs/msg/JointState (effort)     lockstep
/controller/status         biped_msgs_py/msg/ControllerStatus      sensor
/controller/info           std_msgs/msg/String (YAML)              latched
/push_events               biped_msgs_py/msg/PushEvent             events
/push_requests             std_msgs/msg/String (YAML, see below)   events
=========================  ======================================  ==============

Service: ``/apply_push`` (``biped_msgs_py/srv/ApplyPush``).

``/push_requests``: the disturbance node publishes, for every ``/apply_push`` call, one
``std_msgs/msg/String`` whose ``data`` is a YAML mapping ``{request: {...}, response: {...}}``
with every field of the request and of the response (NaN written as ``.nan``), see
:func:`push_request_yaml`. A plain String is used because rosbag2-style service-event types
(``*_Event``) are rejected by ``mcap_ros2``'s decoder and by Lichtblick, while a String decodes
everywhere and keeps rejected requests too (PushEvent only describes accepted pushes).

QoS:
- ``lockstep``: reliable, volatile, keep-last STREAM_DEPTH (simulator <-> controller handshake).
- ``clock``: reliable, volatile, keep-last STREAM_DEPTH.
- ``sensor``: reliable, volatile, keep-last STREAM_DEPTH (visualisation / logging streams).
- ``tf``: reliable, volatile, keep-last STREAM_DEPTH.
  (STREAM_DEPTH = 5000: deep enough for the recorder to lag behind the lockstep loop.)
- ``latched``: reliable, transient local, keep-last 1 (late joiners get the last value).
- ``events``: reliable, transient local, keep-last 100 (every push of a run for late joiners).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

# --------------------------------------------------------------------------- names
# the topic names live in a pure module (bag readers use them without ROS); re-exported here
from biped_sim.recording.topics import (  # noqa: E402, F401
    CLOCK, CONTROLLER_INFO, CONTROLLER_STATUS, CONTROLLER_TORQUE, FALL, GROUND_REACTION, GROUND_REACTION_COP, IMU,
    JOINT_STATES, PUSH_EVENTS, PUSH_REQUESTS, ROBOT_DESCRIPTION, SIM_IMPACTS, SIM_PLANT, SIM_PUSH, SIM_STATE, STANCE, TF)

IMU_FRAME = 'torso'                 # the IMU is on the torso link (URDF root)

APPLY_PUSH = '/apply_push'          # service
APPLY_PUSH_TYPE = 'biped_msgs_py/srv/ApplyPush'

# Node names (used for parameters files: ``<node>: {ros__parameters: ...}``).
SIMULATOR_NODE = 'simulator'
CONTROLLER_NODE = 'controller'
DISTURBANCE_NODE = 'disturbance'
RECORDER_NODE = 'recorder'
BRIDGE_NODE = 'bridge'

# --------------------------------------------------------------------------- QoS
# Plain description of each profile, also the source of the rclpy QoSProfile objects.
# Depth of the per-step streams: the lockstep pair (simulator, controller) never has more than one
# message in flight, but the recorder (one more Python process on the same cores) may lag behind
# the loop; its reader history must hold that lag or messages are silently overwritten (keep-last).
# Measured on a loaded 2-core machine with depth 10: about 2 % of /sim/state lost in a 2-step run.
STREAM_DEPTH = 5000   # 5 s of sim time at 1 kHz
# QoS keys of the per-step streams: the live bridge subscribes to them only while a client watches
# (/clock, latched and event topics it always subscribes)
STREAM_QOS = ('lockstep', 'sensor', 'tf')
QOS_SPECS: dict[str, dict] = {
    'lockstep': {'history': 'keep_last', 'depth': STREAM_DEPTH, 'reliability': 'reliable',
                 'durability': 'volatile'},
    'clock': {'history': 'keep_last', 'depth': STREAM_DEPTH, 'reliability': 'reliable',
              'durability': 'volatile'},
    'sensor': {'history': 'keep_last', 'depth': STREAM_DEPTH, 'reliability': 'reliable',
               'durability': 'volatile'},
    'tf': {'history': 'keep_last', 'depth': STREAM_DEPTH, 'reliability': 'reliable',
           'durability': 'volatile'},
    'latched': {'history': 'keep_last', 'depth': 1, 'reliability': 'reliable',
                'durability': 'transient_local'},
    'events': {'history': 'keep_last', 'depth': 100, 'reliability': 'reliable',
               'durability': 'transient_local'},
}

_HISTORY = {'keep_last': HistoryPolicy.KEEP_LAST, 'keep_all': HistoryPolicy.KEEP_ALL}
_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
                'best_effort': ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'volatile': DurabilityPolicy.VOLATILE,
               'transient_local': DurabilityPolicy.TRANSIENT_LOCAL}


def make_qos(key: str) -> QoSProfile:
    """A fresh ``rclpy.qos.QoSProfile`` for one of the keys of ``QOS_SPECS``."""
    s = QOS_SPECS[key]
    return QoSProfile(history=_HISTORY[s['history']], depth=s['depth'],
                      reliability=_RELIABILITY[s['reliability']],
                      durability=_DURABILITY[s['durability']],
                      liveliness=LivelinessPolicy.AUTOMATIC)


QOS_LOCKSTEP = make_qos('lockstep')
QOS_CLOCK = make_qos('clock')
QOS_SENSOR = make_qos('sensor')
QOS_TF = make_qos('tf')
QOS_LATCHED = make_qos('latched')
QOS_EVENTS = make_qos('events')
QOS = {key: make_qos(key) for key in QOS_SPECS}


def rosbag2_qos_dict(key: str) -> dict:
    """One entry of rosbag2's ``offered_qos_profiles`` (Jazzy, metadata version 9: policy names
    as strings, durations as ``{sec, nsec}``; zero durations = not set / default)."""
    s = QOS_SPECS[key]
    zero = {'sec': 0, 'nsec': 0}
    return {
        'history': s['history'],
        'depth': s['depth'],
        'reliability': s['reliability'],
        'durability': s['durability'],
        'deadline': dict(zero),
        'lifespan': dict(zero),
        'liveliness': 'automatic',
        'liveliness_lease_duration': dict(zero),
        'avoid_ros_namespace_conventions': False,
    }


# --------------------------------------------------------------------------- topics
@dataclass(frozen=True)
class TopicSpec:
    name: str       # fully qualified topic name
    type: str       # 'pkg/msg/Type'
    qos: str        # key into QOS_SPECS / QOS
    doc: str

    @property
    def qos_profile(self) -> QoSProfile:
        return make_qos(self.qos)

    @property
    def qos_dict(self) -> dict:
        return rosbag2_qos_dict(self.qos)

    def msg_class(self):
        return message_class(self.type)


TOPICS: dict[str, TopicSpec] = {t.name: t for t in [
    TopicSpec(CLOCK, 'rosgraph_msgs/msg/Clock', 'clock',
              'simulation time, published by the simulator every step'),
    TopicSpec(SIM_STATE, 'biped_msgs_py/msg/SimState', 'lockstep',
              'lockstep state, simulator -> controller'),
    TopicSpec(IMU, 'sensor_msgs/msg/Imu', 'lockstep',
              "the torso IMU's pitch (orientation about -y) and pitch rate as the controller receives them with "
              '/sim/state (same stamp; noise and delay of the sensor model); frame torso; simulator -> controller'),
    TopicSpec(JOINT_STATES, 'sensor_msgs/msg/JointState', 'sensor',
              'URDF joint positions/velocities (rad, rad/s)'),
    TopicSpec(GROUND_REACTION, 'geometry_msgs/msg/WrenchStamped', 'sensor',
              'ground force and moment on the stance foot at its ankle (N, N m) at the start of a control '
              'period under that period\'s torque and push; frame: the stance foot (left_foot / right_foot, '
              'flat on the ground, so its axes are the world\'s); moment about -y = counter-clockwise'),
    TopicSpec(GROUND_REACTION_COP, 'geometry_msgs/msg/PointStamped', 'sensor',
              'centre of pressure (m), world frame, same instant as /ground_reaction'),
    TopicSpec(STANCE, 'std_msgs/msg/UInt8', 'sensor', 'stance leg: 0 left, 1 right'),
    TopicSpec(TF, 'tf2_msgs/msg/TFMessage', 'tf', 'link transforms for Foxglove 3D'),
    TopicSpec(ROBOT_DESCRIPTION, 'std_msgs/msg/String', 'latched', 'URDF text'),
    TopicSpec(FALL, 'std_msgs/msg/String', 'latched', 'fall cause, published once on a fall'),
    TopicSpec(SIM_IMPACTS, 'biped_msgs_py/msg/Impact', 'events',
              'every touchdown: pre/post state, foot re-pose, impulse, energy lost'),
    TopicSpec(SIM_PUSH, 'biped_msgs_py/msg/AppliedPush', 'sensor',
              'push force and impulse actually applied over each control period'),
    TopicSpec(SIM_PLANT, 'std_msgs/msg/String', 'latched',
              "YAML of the simulated plant's actual parameters (masses, centres of mass, inertias, friction, "
              'sensor noise and delay: biped_sim.plant.perturbation.plant_parameters); the controller keeps the nominal '
              'robots/biped7/description.yaml'),
    TopicSpec(CONTROLLER_TORQUE, 'sensor_msgs/msg/JointState', 'lockstep',
              'joint torques (N m) in effort, controller -> simulator'),
    TopicSpec(CONTROLLER_STATUS, 'biped_msgs_py/msg/ControllerStatus', 'sensor',
              'controller status, one per control step'),
    TopicSpec(CONTROLLER_INFO, 'std_msgs/msg/String', 'latched',
              "YAML of the run's controller: its name, its options (controller_options) and the SHA-256 of every "
              'file it reads, e.g. an ONNX policy (biped_controller.plugin.provenance); published once at start'),
    TopicSpec(PUSH_EVENTS, 'biped_msgs_py/msg/PushEvent', 'events', 'every accepted push'),
    TopicSpec(PUSH_REQUESTS, 'std_msgs/msg/String', 'events',
              'YAML {request, response} of every /apply_push call'),
]}

SERVICES: dict[str, str] = {APPLY_PUSH: APPLY_PUSH_TYPE}


def offered_qos_profiles(topic: str) -> list[dict]:
    """rosbag2-style ``offered_qos_profiles`` list (one publisher) for a topic of ``TOPICS``."""
    return [TOPICS[topic].qos_dict]


def message_class(type_name: str):
    """Import the Python class of ``'pkg/msg/Type'`` or ``'pkg/srv/Type'``."""
    import importlib
    pkg, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), name)


# --------------------------------------------------------------------------- /push_requests
_REQUEST_FIELDS = ('force', 'duration', 'start', 'use_delay', 'delay', 'height')
_RESPONSE_FIELDS = ('accepted', 'message', 'push_id', 'scheduled_start', 'scheduled_end')


def _plain(v):
    if isinstance(v, float) and math.isnan(v):
        return float('nan')
    return v


def push_request_yaml(request, response, received_sim_time: float | None = None) -> str:
    """The ``data`` of a ``/push_requests`` String: YAML ``{request, response}`` (+ sim time)."""
    import yaml
    doc = {
        'request': {f: _plain(getattr(request, f)) for f in _REQUEST_FIELDS},
        'response': {f: _plain(getattr(response, f)) for f in _RESPONSE_FIELDS},
    }
    if received_sim_time is not None:
        doc['received_sim_time'] = float(received_sim_time)
    return yaml.safe_dump(doc, sort_keys=False)
