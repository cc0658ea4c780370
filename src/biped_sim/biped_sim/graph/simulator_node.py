"""ROS 2 node ``simulator``: the physical simulator in lockstep with the controller over DDS.

Owns a plant built by ``biped_sim.plant.protocol.make_plant`` from the parameter ``plant`` (``rigid``: the
rigid ``Simulator``, the default; ``mujoco``: ``biped_sim.plant.mujoco.MujocoPlant``), robot from
``robots/biped7/description.yaml``, ``SimConfig`` from the parameters below, which have the keys of
``config/simulator.yaml`` (the ``mujoco_*`` keys set the MuJoCo plant's contact). What each message
describes on the MuJoCo plant: DESIGN.md. Initial state: the start of
the preferred gait (``GaitFamily.initial_state()``), LEFT stance, as the in-process
``runner.run``.

Lockstep, per control step k (event-driven: the next state is published from inside the torque
callback, no polling):

1. publish the state at t_k = k * control_period: ``/clock``, ``/imu``, ``/sim/state`` (sequence k + 1),
   ``/tf``, ``/stance``;
2. wait for ``/controller/torque`` whose ``header.stamp`` equals the state's stamp (others are
   ignored with a warning); effort = paper torques q1..q6, names ``description.PAPER_JOINTS``;
3. ``sim.step(torque)``; publish what that period produced, stamped t_k: ``/joint_states`` (URDF
   joint order, ``effort`` = the applied, clipped torque mapped by ``floating.urdf_from_paper``),
   ``/ground_reaction`` and ``/ground_reaction/cop``; then state k + 1.

Signs of ``/ground_reaction`` (``geometry_msgs/WrenchStamped``, frame ``<stance>_foot``, which is
flat on the ground in single support, so its axes are the world's): ``force.x = F_x``,
``force.z = F_z`` (the ground's force on the stance foot, up positive: DESIGN.md's R_x, R_y) and
``torque.y = -m`` where m is the counter-clockwise moment about the ankle in the sagittal view
(DESIGN.md: Gamma_1 = l R_y). A counter-clockwise rotation in the view x right / z up is a rotation
about -y in ROS' right-handed frame, hence the minus sign. ``/ground_reaction/cop`` is the centre of
pressure in ``world``: x = ankle x + l, z = 0, l = m / F_z.

The run ends when ``max_steps`` impacts were walked (0 = no limit), when sim time reaches
``max_time`` (0 = no limit), on a fall (``/fall`` latched YAML {cause, time, detail, step}) or when no
torque arrives within ``command_timeout`` wall seconds (logged naming ``/controller/torque``,
``/fall`` cause ``controller timeout``, exit status 1). The final state is published (``fallen`` set
on a fall), then the node lingers ``linger`` seconds (default 0.5) so that the recorder receives
the last messages, and exits 0 (steps, time, fall) or 1 (controller timeout). SIGINT/SIGTERM end it
cleanly (status 0).

IMU (``biped_sim.graph.imu``): ``/imu`` (``sensor_msgs/msg/Imu``, frame ``torso``) carries the
torso pitch and pitch rate of the same sensor sample as ``/sim/state``'s q (its noise ``perturbation.noise_pitch``
and ``perturbation.noise_pitch_rate``, its delay), stamped with the state's stamp, published just before it;
not sent again with a fallen state at the instant already published (as ``/clock``). The controller pairs
the two by stamp.

Start: the first state is published once ``/sim/state`` has a subscriber and ``/controller/torque``
a publisher, every subscriber of ``/imu`` seen so far is matched (the controller creates its ``/imu``
reader before its ``/sim/state`` reader, and discovery announces a participant's readers in order), plus optionally (``wait_for_recorder``) the node ``recorder`` subscribed to every topic
the simulator publishes, and (``wait_for_pushes``) that many PushEvents received; then
``start_delay`` wall seconds. If that takes longer than ``start_timeout``: error naming what is
missing, exit 1.

Pushes: ``/push_events`` (PushEvent, transient local) are scheduled with ``sim.schedule_push`` with
the event's id; a repeated id is ignored.

Perturbations (``biped_sim.plant.perturbation``): the parameters ``perturbation.<field>`` for every
field of ``PlantPerturbation`` (``perturbation.torso_mass_scale``, ``perturbation.torso_com_shift``,
``perturbation.noise_qd``, ``perturbation.delay``, ...; defaults: none; ``perturbation.mu`` 0 = the
description's mu) make the simulated plant differ from ``robots/biped7/description.yaml``, which the controller keeps.
``/sim/state`` then carries what the sensors report (q, q' with noise and delay; ``base`` and the other
topics are true), and ``/sim/plant`` (latched ``std_msgs/String``, YAML of
``perturbation.plant_parameters``) the plant's actual parameters, so a recording can be checked against
the true plant.

Publishing (``publish_cdr``, default ``config/graph.yaml``: true): the per-step topics (``/clock``, ``/imu``,
``/sim/state``, ``/tf``, ``/stance``, ``/joint_states``, ``/ground_reaction``, ``/ground_reaction/cop``,
``/sim/push``) go out as CDR bytes encoded by ``biped_sim.graph.cdr`` (``Publisher.publish(bytes)``), the same
bytes as the message objects (false) produce: rclpy then skips building, converting and serialising a Python
message. The latched and event topics are always message objects.

Parameters are validated at start; a bad one is logged naming it and the node exits 2 before
anything is published.
"""

from __future__ import annotations

import math
import sys
import time
import xml.etree.ElementTree as ET
from typing import Optional

import numpy as np
import yaml
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PointStamped, TransformStamped, WrenchStamped
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String, UInt8
from tf2_msgs.msg import TFMessage

from biped_msgs_py.msg import AppliedPush, Impact, PushEvent, SimState
from biped_sim.graph import cdr
from biped_sim.graph import names as gn
from biped_model.description import LEFT, URDF_JOINTS, make_urdf
from biped_model.floating import urdf_from_paper
from biped_sim.graph.params import (
    ParameterError,
    declare_executor,
    wait_all_acked,
    get_bool,
    get_float,
    get_int,
    get_profile,
    robot_settings,
    get_str,
    load_robot_files,
    run_node,
)
from biped_sim.graph.checks import RobotFilesError, check_urdf_joints
from biped_sim.graph.imu import ImuBuilder
from biped_sim.plant.perturbation import PerturbationError, PlantPerturbation, plant_yaml
from biped_sim.plant.push import Rejected
from biped_model.loop import ENGINES
from biped_sim.plant.config import MUJOCO_CONES, MUJOCO_INTEGRATORS, PLANT_NAMES, SimConfig, SimConfigError, load_sim_config
from biped_sim.plant.protocol import make_plant

SIDES = ('left', 'right')
WORLD_FRAME = 'world'
EXIT_OK = 0
EXIT_FAILURE = 1


def stamp_of(t: float) -> Time:
    ns = int(round(t * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def quat_about_minus_y(angle: float):
    """(x, y, z, w) of a rotation by ``angle`` about (0, -1, 0)."""
    return 0.0, -math.sin(0.5 * angle), 0.0, math.cos(0.5 * angle)


def joint_origins(urdf: str) -> dict[str, tuple[str, str, tuple[float, float, float]]]:
    """joint name -> (parent link, child link, origin xyz) read from the URDF text."""
    out = {}
    for j in ET.fromstring(urdf).iter('joint'):
        xyz = tuple(float(v) for v in j.find('origin').get('xyz').split())
        out[j.get('name')] = (j.find('parent').get('link'), j.find('child').get('link'), xyz)
    return out


class TransformBuilder:
    """world -> torso from the floating base, torso -> thigh -> shin -> foot from the joint angles."""

    def __init__(self, urdf: str):
        self.joints = joint_origins(urdf)
        missing = [n for n in URDF_JOINTS if n not in self.joints]
        if missing:
            raise ValueError(f'URDF lacks joints {missing}')
        self._msg: TFMessage | None = None
        self._cdr = cdr.TfMessage([(WORLD_FRAME, 'torso')] + [self.joints[n][:2] for n in URDF_JOINTS])

    @staticmethod
    def _tf(stamp, parent, child, xyz, angle) -> TransformStamped:
        m = TransformStamped()
        m.header.stamp = stamp
        m.header.frame_id = parent
        m.child_frame_id = child
        m.transform.translation.x, m.transform.translation.y, m.transform.translation.z = xyz
        r = m.transform.rotation
        r.x, r.y, r.z, r.w = quat_about_minus_y(angle)
        return m

    def message(self, stamp, x: np.ndarray) -> TFMessage:
        """The /tf message of floating state x. One message object is built once and updated in place
        (stamps, torso translation, rotations): constructing seven TransformStamped per step was the
        most expensive publication of the lockstep loop (about 0.2 ms of its 1 ms budget)."""
        if self._msg is None:
            tfs = [self._tf(stamp, WORLD_FRAME, 'torso', (float(x[0]), 0.0, float(x[1])), float(x[2]))]
            for i, name in enumerate(URDF_JOINTS):
                parent, child, xyz = self.joints[name]
                tfs.append(self._tf(stamp, parent, child, xyz, float(x[3 + i])))
            self._msg = TFMessage(transforms=tfs)
            return self._msg
        tfs = self._msg.transforms
        tr = tfs[0].transform.translation
        tr.x, tr.z = float(x[0]), float(x[1])
        for k, m in enumerate(tfs):
            m.header.stamp = stamp
            r = m.transform.rotation
            r.x, r.y, r.z, r.w = quat_about_minus_y(float(x[2 + k]))
        return self._msg

    def encode(self, sec: int, nanosec: int, x: np.ndarray) -> bytes:
        """The CDR bytes of :meth:`message` (``biped_sim.graph.cdr``): the same transforms, frames and numbers."""
        poses = [(float(x[0]), 0.0, float(x[1]), *quat_about_minus_y(float(x[2])))]
        for i, name in enumerate(URDF_JOINTS):
            poses.append((*self.joints[name][2], *quat_about_minus_y(float(x[3 + i]))))
        return self._cdr.encode(sec, nanosec, poses)


def read_sim_config(node: Node) -> SimConfig:
    """SimConfig from the parameters (defaults: config/simulator.yaml with the simulator settings of the
    profile of parameter ``profile``, config/profiles/; an unknown profile raises ParameterError naming
    ``profile`` and the known ones)."""
    profile = get_profile(node)
    own = dict(robot_settings(node))        # the robot's size-dependent values, under the profile's
    try:
        base = load_sim_config(**{k: v for k, v in (*own.items(), *profile.settings) if k in SimConfig.__dataclass_fields__})
    except SimConfigError as exc:
        raise ParameterError('profile', f"profile {profile.name}: {exc}") from exc
    kw = {}
    for name in SimConfig.__dataclass_fields__:
        default = getattr(base, name)
        if name == 'substeps':
            kw[name] = get_int(node, name, default, lo=1, hi=1000)
        elif name == 'mujoco_sole_points':
            kw[name] = get_int(node, name, default, lo=0, hi=101)
        elif name == 'engine':
            kw[name] = get_str(node, name, default, choices=ENGINES)
        elif name == 'plant':
            kw[name] = get_str(node, name, default, choices=PLANT_NAMES)
        elif name == 'mujoco_integrator':
            kw[name] = get_str(node, name, default, choices=MUJOCO_INTEGRATORS)
        elif name == 'mujoco_cone':
            kw[name] = get_str(node, name, default, choices=MUJOCO_CONES)
        else:
            kw[name] = get_float(node, name, default)
    try:
        return SimConfig(**kw).validate()
    except SimConfigError as exc:
        name = str(exc).split()[0]
        raise ParameterError(name, str(exc)) from exc


def read_perturbation(node: Node, desc) -> PlantPerturbation:
    """The plant's perturbation from the parameters ``perturbation.<field>`` (defaults: the profile's
    perturbation, else none; ``perturbation.mu`` 0 = the description's friction), validated against ``desc``:
    a bad value raises ``ParameterError`` naming ``perturbation.<field>``."""
    try:
        zero = PlantPerturbation.from_dict(dict(get_profile(node).perturbation))
    except PerturbationError as exc:
        raise ParameterError('profile', f"perturbation: {exc}") from exc
    kw = {}
    for name in PlantPerturbation.__dataclass_fields__:
        key = f'perturbation.{name}'
        if name in ('delay', 'seed', 'encoder_bits'):
            kw[name] = get_int(node, key, getattr(zero, name), lo=0)
        elif name == 'touchdown_delayed':
            kw[name] = get_bool(node, key, getattr(zero, name))
        elif name == 'mu':
            mu = get_float(node, key, zero.mu or 0.0, lo=0.0)
            kw[name] = None if mu == 0.0 else mu
        else:
            kw[name] = get_float(node, key, getattr(zero, name))
    try:
        p = PlantPerturbation(**kw)
        p.apply(desc)
    except PerturbationError as exc:
        raise ParameterError(f'perturbation.{exc.field}', str(exc)) from exc
    return p


class SimulatorNode(Node):

    def __init__(self, **kwargs):
        super().__init__(gn.SIMULATOR_NODE, **kwargs)
        self._read_parameters()
        self.desc, family = load_robot_files(self)
        urdf_path = get_str(self, 'urdf_path')
        if urdf_path:
            try:
                with open(urdf_path, encoding='utf-8') as fh:
                    self.urdf = fh.read()
            except OSError as exc:
                raise ParameterError('urdf_path', f'cannot read {urdf_path}: {exc}') from exc
        else:
            self.urdf = make_urdf(self.desc)
        try:
            check_urdf_joints(self.urdf)
        except RobotFilesError as exc:
            raise ParameterError('urdf_path', f'{urdf_path or "generated URDF"}: {exc}') from exc
        self.perturbation = read_perturbation(self, self.desc)
        self.sim = make_plant(self.cfg.plant, self.desc, self.cfg, self.perturbation)   # parameter 'plant'
        q0, qd0 = family.initial_state()
        self.sim.reset(q0, qd0, LEFT)
        self.tfb = TransformBuilder(self.urdf)
        self.imub = ImuBuilder(self.perturbation.noise_pitch, self.perturbation.noise_pitch_rate)
        self._cdr_state, self._cdr_joints = cdr.SimState(), cdr.JointState()
        self._cdr_wrench, self._cdr_point = cdr.Stamped('WrenchStamped', 6), cdr.Stamped('PointStamped', 3)

        self.pub_clock = self.create_publisher(Clock, gn.CLOCK, gn.QOS_CLOCK)
        self.pub_state = self.create_publisher(SimState, gn.SIM_STATE, gn.QOS_LOCKSTEP)
        self.pub_imu = self.create_publisher(Imu, gn.IMU, gn.QOS_LOCKSTEP)
        self.pub_joints = self.create_publisher(JointState, gn.JOINT_STATES, gn.QOS_SENSOR)
        self.pub_wrench = self.create_publisher(WrenchStamped, gn.GROUND_REACTION, gn.QOS_SENSOR)
        self.pub_cop = self.create_publisher(PointStamped, gn.GROUND_REACTION_COP, gn.QOS_SENSOR)
        self.pub_stance = self.create_publisher(UInt8, gn.STANCE, gn.QOS_SENSOR)
        self.pub_tf = self.create_publisher(TFMessage, gn.TF, gn.QOS_TF)
        self.pub_desc = self.create_publisher(String, gn.ROBOT_DESCRIPTION, gn.QOS_LATCHED)
        self.pub_fall = self.create_publisher(String, gn.FALL, gn.QOS_LATCHED)
        self.pub_impacts = self.create_publisher(Impact, gn.SIM_IMPACTS, gn.QOS_EVENTS)
        self.pub_push = self.create_publisher(AppliedPush, gn.SIM_PUSH, gn.QOS_SENSOR)
        self.pub_plant = self.create_publisher(String, gn.SIM_PLANT, gn.QOS_LATCHED)
        self.published_topics = [gn.CLOCK, gn.SIM_STATE, gn.IMU, gn.JOINT_STATES, gn.GROUND_REACTION,
                                 gn.GROUND_REACTION_COP, gn.STANCE, gn.TF, gn.ROBOT_DESCRIPTION,
                                 gn.SIM_IMPACTS, gn.SIM_PUSH, gn.SIM_PLANT]
        self.sub_torque = self.create_subscription(JointState, gn.CONTROLLER_TORQUE, self._on_torque,
                                                   gn.QOS_LOCKSTEP)
        self.create_subscription(PushEvent, gn.PUSH_EVENTS, self._on_push, gn.QOS_EVENTS)

        self.pub_desc.publish(String(data=self.urdf))
        self.pub_plant.publish(String(data=plant_yaml(self.desc, self.perturbation)))
        self.push_ids: set[int] = set()
        self.sequence = 0
        self.started = False
        self.waiting_since = time.monotonic()
        self.ready_since: Optional[float] = None
        self.current_stamp_ns: Optional[int] = None
        self.last_state_wall = 0.0
        self.anchor_x = 0.0
        self.finished = False          # the run is over (lingering)
        self.done = False              # leave the spin loop
        self.exit_code = EXIT_OK
        self.end_reason = ''
        self.finish_wall: Optional[float] = None
        self.run_start_wall: Optional[float] = None
        self.steps_done = 0
        self.impacts_published = 0
        self.create_timer(0.02, self._on_timer)
        self.get_logger().info(
            f'simulator ready: plant {self.cfg.plant}, control_period {self.cfg.control_period} s, substeps {self.cfg.substeps}, '
            f'max_steps {self.max_steps}, max_time {self.max_time} s, publishing '
            f'{"CDR bytes" if self.publish_cdr else "message objects"}; waiting for the controller')

    # ------------------------------------------------------------------ parameters
    def _read_parameters(self):
        """Declare and read every parameter (defaults: config/graph.yaml, config/simulator.yaml); a bad one raises
        ParameterError naming it, before anything is created."""
        if self.get_parameter('use_sim_time').value:
            raise ParameterError('use_sim_time', 'the simulator is the clock source: must be false')
        self.cfg = read_sim_config(self)
        declare_executor(self)
        self.max_steps = get_int(self, 'max_steps', lo=0)
        self.max_time = get_float(self, 'max_time', lo=0.0)
        self.command_timeout = get_float(self, 'command_timeout', lo=0.0, lo_open=True)
        self.start_timeout = get_float(self, 'start_timeout', lo=0.0, lo_open=True)
        self.start_delay = get_float(self, 'start_delay', lo=0.0)
        self.linger = get_float(self, 'linger', lo=0.0, hi=60.0)
        # after the linger, wait (at most this long) until every subscriber has acknowledged everything
        self.ack_timeout = get_float(self, 'ack_timeout', lo=0.0, hi=60.0)
        self.wait_for_recorder = get_bool(self, 'wait_for_recorder')
        self.wait_for_pushes = get_int(self, 'wait_for_pushes', lo=0)
        # the live bridge (launch --live): wait until this node sees it on /clock, so that its readers are
        # among the subscribers every published topic must have matched before the first state
        self.wait_for_bridge = get_bool(self, 'wait_for_bridge')
        # pacing: 1.0 = sim time follows the wall clock (a live viewer sees real time), 0 = as fast as
        # the lockstep allows (experiments), r = r x real time
        self.real_time_factor = get_float(self, 'real_time_factor', lo=0.0, hi=1000.0)
        # the per-step topics as CDR bytes encoded here (biped_sim.graph.cdr) instead of message objects:
        # the same bytes on the wire, a fraction of rclpy's publish cost
        self.publish_cdr = get_bool(self, 'publish_cdr')

    # ------------------------------------------------------------------ start
    def _missing_for_start(self) -> list[str]:
        missing = []
        # matched (not only discovered): the first state and the first torque are volatile messages
        state_subs = {i.node_name for i in self.get_subscriptions_info_by_topic(gn.SIM_STATE)}
        if gn.CONTROLLER_NODE not in state_subs or self.pub_state.get_subscription_count() < 1:
            missing.append(f'the controller subscribed to {gn.SIM_STATE} (matched)')
        if self.count_publishers(gn.CONTROLLER_TORQUE) < 1 or self.sub_torque.get_publisher_count() < 1:
            missing.append(f'a publisher on {gn.CONTROLLER_TORQUE} (controller, matched)')
        # the controller's /imu reader (when it has one) must be matched too: its first IMU is volatile
        if self.pub_imu.get_subscription_count() < len(self.get_subscriptions_info_by_topic(gn.IMU)):
            missing.append(f'every subscriber of {gn.IMU} matched')
        if self.wait_for_recorder:
            pubs = {p.topic_name: p for p in (self.pub_clock, self.pub_state, self.pub_imu, self.pub_joints, self.pub_wrench,
                                               self.pub_cop, self.pub_stance, self.pub_tf, self.pub_desc,
                                               self.pub_impacts, self.pub_push, self.pub_plant)}
            for topic in self.published_topics:
                infos = self.get_subscriptions_info_by_topic(topic)
                if gn.RECORDER_NODE not in {i.node_name for i in infos}:
                    missing.append(f'the recorder subscribed to {topic}')
                elif pubs[topic].get_subscription_count() < len(infos):
                    missing.append(f'every subscriber of {topic} matched')
        if self.wait_for_bridge:
            infos = self.get_subscriptions_info_by_topic(gn.CLOCK)
            if gn.BRIDGE_NODE not in {i.node_name for i in infos}:
                missing.append(f'the bridge subscribed to {gn.CLOCK}')
            elif self.pub_clock.get_subscription_count() < len(infos):
                missing.append(f'every subscriber of {gn.CLOCK} matched')
        if len(self.push_ids) < self.wait_for_pushes:
            missing.append(f'{self.wait_for_pushes - len(self.push_ids)} more push event(s) on {gn.PUSH_EVENTS}')
        return missing

    def _on_timer(self):
        now = time.monotonic()
        if self.finished:
            if now - self.finish_wall >= self.linger:
                late = wait_all_acked(self, self.ack_timeout)
                if late:
                    self.get_logger().warning(f'not acknowledged within {self.ack_timeout} s: {", ".join(late)}')
                self.done = True
            return
        if not self.started:
            missing = self._missing_for_start()
            if missing:
                self.ready_since = None
                if now - self.waiting_since > self.start_timeout:
                    self.get_logger().error(
                        f'not started after {self.start_timeout} s: waiting for {"; ".join(missing)}')
                    self._finish(EXIT_FAILURE, 'start timeout')
                return
            if self.ready_since is None:
                self.ready_since = now
            if now - self.ready_since >= self.start_delay:
                self.started = True
                self.run_start_wall = now
                self.get_logger().info('controller connected: starting the lockstep run')
                self._publish_state()
                self._publish_visuals()
            return
        if now - self.last_state_wall > self.command_timeout:
            self.get_logger().error(
                f'no command on {gn.CONTROLLER_TORQUE} for step {self.sim.step_index} within '
                f'{self.command_timeout} s: {gn.CONTROLLER_TORQUE} is silent, stopping')
            self._publish_fall('controller timeout', self.sim.t,
                               f'no message on {gn.CONTROLLER_TORQUE} within {self.command_timeout} s (wall)')
            self._publish_final_state('controller timeout')
            self._finish(EXIT_FAILURE, 'controller timeout')

    # ------------------------------------------------------------------ publishing
    def _publish_final_state(self, cause: str):
        """The fallen state (a fall or a controller timeout). At the instant of the state already published
        (a fall under the new torque at the period start, a timeout) ``/clock`` and ``/tf`` are not sent
        again: the clock would repeat a time and the pose is the same; ``/sim/state`` carries the flag."""
        same_instant = stamp_ns(stamp_of(self.sim.t)) == self.current_stamp_ns
        self._publish_state(fallen=True, cause=cause, clock=not same_instant)
        if not same_instant:
            self._publish_visuals()

    def _publish_state(self, fallen: bool = False, cause: str = '', clock: bool = True):
        sim = self.sim
        obs = sim.observe()
        self.sequence += 1
        self.anchor_x = float(sim.anchor[0])
        if self.publish_cdr:
            sec, nsec = cdr.stamp_parts(obs.t)
            self.current_stamp_ns = sec * 1_000_000_000 + nsec
            state = self._cdr_state.encode(sec, nsec, obs.step, obs.stance, obs.q.tolist(), obs.qd.tolist(),
                                           sim.x[:3].tolist(), sim.v[:3].tolist(), fallen, cause, self.sequence)
            if clock:
                self.pub_clock.publish(cdr.clock(sec, nsec))
                self.pub_imu.publish(self.imub.encode(sec, nsec, obs.pitch, obs.pitch_rate))
            self.pub_state.publish(state)
            self.last_state_wall = time.monotonic()
            self._visual_stamp = (sec, nsec)
            self._visual_stance = obs.stance
            self._visual_x = sim.x.copy()
            return
        stamp = stamp_of(obs.t)
        self.current_stamp_ns = stamp_ns(stamp)
        m = SimState()
        m.stamp = stamp
        m.step = obs.step
        m.stance = obs.stance
        m.q = obs.q.tolist()
        m.q_dot = obs.qd.tolist()
        m.base = sim.x[:3].tolist()
        m.base_dot = sim.v[:3].tolist()
        m.fallen = fallen
        m.fall_cause = cause
        m.sequence = self.sequence
        # /clock first (the recorder's log time), then the state the controller waits for; the
        # visualisation topics go out while the controller computes (publish_visuals).
        if clock:
            self.pub_clock.publish(Clock(clock=stamp))
            self.pub_imu.publish(self.imub.message(stamp, obs.pitch, obs.pitch_rate))
        self.pub_state.publish(m)
        self.last_state_wall = time.monotonic()
        self._visual_stamp = stamp
        self._visual_stance = obs.stance
        self._visual_x = sim.x.copy()

    def _publish_visuals(self):
        """/tf and /stance of the state just published (after /sim/state, so they overlap with the
        controller's computation)."""
        if self.publish_cdr:
            sec, nsec = self._visual_stamp
            self.pub_tf.publish(self.tfb.encode(sec, nsec, self._visual_x))
            self.pub_stance.publish(cdr.uint8(self._visual_stance))
            return
        self.pub_tf.publish(self.tfb.message(self._visual_stamp, self._visual_x))
        self.pub_stance.publish(UInt8(data=self._visual_stance))

    def _publish_record(self, rec, anchor_x: float):
        if self.publish_cdr:
            sec, nsec = cdr.stamp_parts(rec.t)
            self.pub_joints.publish(self._cdr_joints.encode(
                sec, nsec, '', URDF_JOINTS, urdf_from_paper(rec.q, rec.stance).tolist(),
                urdf_from_paper(rec.qd, rec.stance).tolist(), urdf_from_paper(rec.torque, rec.stance).tolist()))
            fx, fz, mom = (float(v) for v in rec.wrench)
            self.pub_wrench.publish(self._cdr_wrench.encode(sec, nsec, f'{SIDES[rec.stance]}_foot',
                                                            (fx, 0.0, fz, 0.0, -mom, 0.0)))
            cop_x = anchor_x + (float(rec.cop) if math.isfinite(rec.cop) else 0.0)
            self.pub_cop.publish(self._cdr_point.encode(sec, nsec, WORLD_FRAME, (cop_x, 0.0, 0.0)))
            return
        stamp = stamp_of(rec.t)
        js = JointState()
        js.header.stamp = stamp
        js.name = list(URDF_JOINTS)
        js.position = urdf_from_paper(rec.q, rec.stance).tolist()
        js.velocity = urdf_from_paper(rec.qd, rec.stance).tolist()
        js.effort = urdf_from_paper(rec.torque, rec.stance).tolist()
        self.pub_joints.publish(js)
        fx, fz, mom = (float(v) for v in rec.wrench)
        w = WrenchStamped()
        w.header.stamp = stamp
        w.header.frame_id = f'{SIDES[rec.stance]}_foot'
        w.wrench.force.x = fx
        w.wrench.force.z = fz
        w.wrench.torque.y = -mom  # counter-clockwise (sagittal view) = about -y
        self.pub_wrench.publish(w)
        c = PointStamped()
        c.header.stamp = stamp
        c.header.frame_id = WORLD_FRAME
        c.point.x = anchor_x + (float(rec.cop) if math.isfinite(rec.cop) else 0.0)
        self.pub_cop.publish(c)

    def _pace(self, sim_t: float) -> None:
        """With real_time_factor r > 0, hold the next state until wall time = start + sim_t / r."""
        if self.real_time_factor > 0 and self.run_start_wall is not None:
            ahead = self.run_start_wall + sim_t / self.real_time_factor - time.monotonic()
            if ahead > 0:
                time.sleep(ahead)

    def _publish_applied_push(self, rec):
        if self.publish_cdr:
            period = float(rec.t_end - rec.t)
            force, impulse = float(rec.push_force), float(rec.push_impulse)
            mean_force = float(impulse / period) if period > 0 else force
            acting = self.sim.interval_pushes(rec.t, rec.t_end) if period > 0 else ()
            height = float(acting[0][1]) if acting else math.nan
            self.pub_push.publish(cdr.applied_push(*cdr.stamp_parts(rec.t), period, force, impulse, mean_force,
                                                   height))
            return
        m = AppliedPush()
        m.stamp = stamp_of(rec.t)
        m.period = float(rec.t_end - rec.t)
        m.force = float(rec.push_force)
        m.impulse = float(rec.push_impulse)
        m.mean_force = float(rec.push_impulse / m.period) if m.period > 0 else float(rec.push_force)
        acting = self.sim.interval_pushes(rec.t, rec.t_end) if m.period > 0 else ()
        m.height = float(acting[0][1]) if acting else math.nan
        self.pub_push.publish(m)

    def _publish_impacts(self):
        for imp in self.sim.impact_log[self.impacts_published:]:
            m = Impact()
            m.stamp = stamp_of(imp.t)
            m.index = int(imp.index)
            m.old_stance = int(imp.old_stance)
            m.new_stance = int(imp.new_stance)
            m.x_minus = imp.x_minus.tolist()
            m.v_minus = imp.v_minus.tolist()
            m.foot_tilt = float(imp.foot_tilt)
            m.x_flat = imp.x_flat.tolist()
            m.v_plus = imp.v_plus.tolist()
            m.impulse = imp.impulse.tolist()
            m.energy_loss = float(imp.energy_loss)
            m.released_foot_velocity = imp.old_foot_velocity.tolist()
            m.x_plus = imp.x_plus.tolist()
            m.v_plus_projected = imp.v_plus_projected.tolist()
            m.ankle_x = float(imp.ankle_x)
            self.pub_impacts.publish(m)
        self.impacts_published = len(self.sim.impact_log)

    def _publish_fall(self, cause: str, t: float, detail: str):
        doc = {'cause': cause, 'time': float(t), 'detail': detail, 'step': int(self.sim.step_index),
               'impacts': int(self.sim.impact_count)}
        self.pub_fall.publish(String(data=yaml.safe_dump(doc, sort_keys=False)))

    # ------------------------------------------------------------------ callbacks
    def _on_torque(self, msg: JointState):
        if not self.started or self.finished:
            return
        if stamp_ns(msg.header.stamp) != self.current_stamp_ns:
            self.get_logger().warning(
                f'{gn.CONTROLLER_TORQUE}: stamp {stamp_ns(msg.header.stamp)} ns is not the current state\'s '
                f'({self.current_stamp_ns} ns): ignored')
            return
        if len(msg.effort) != 6:
            self.get_logger().error(f'{gn.CONTROLLER_TORQUE}: expected 6 efforts, got {len(msg.effort)}: ignored')
            return
        sim = self.sim
        anchor_x = self.anchor_x
        rec = sim.step(np.asarray(msg.effort, dtype=float))
        self.steps_done += 1
        if sim.fall is not None:
            f = sim.fall
            self.get_logger().info(f'fall at t = {f.t:.4f} s: {f.cause} ({f.detail})')
            self._publish_record(rec, anchor_x)
            self._publish_applied_push(rec)
            self._publish_impacts()        # an impact of the period that fell (e.g. a non-finite state after it)
            self._publish_fall(f.cause, f.t, f.detail)
            self._publish_final_state(f.cause)
            self._finish(EXIT_OK, f'fall: {f.cause}')
            return
        self._pace(sim.t)
        self._publish_state()
        self._publish_record(rec, anchor_x)
        self._publish_applied_push(rec)
        self._publish_impacts()
        self._publish_visuals()
        if self.max_steps and sim.impact_count >= self.max_steps:
            self._finish(EXIT_OK, f'{sim.impact_count} steps walked')
        elif self.max_time and sim.t >= self.max_time - 1e-12:
            self._finish(EXIT_OK, f'max_time {self.max_time} s reached')

    def _on_push(self, msg: PushEvent):
        pid = int(msg.id)
        if pid in self.push_ids:
            return
        try:
            p = self.sim.schedule_push(msg.start, msg.duration, msg.force, msg.height, push_id=pid)
        except Rejected as exc:
            self.get_logger().error(f'{gn.PUSH_EVENTS}: push {pid} not scheduled: {exc}')
            return
        self.push_ids.add(pid)
        late = '' if p.start >= self.sim.t else f' (WARNING: starts before the current sim time {self.sim.t:.4f} s)'
        self.get_logger().info(f'push {pid} scheduled: {p.force} N over [{p.start}, {p.end}) s '
                               f'at {p.height} m{late}')

    # ------------------------------------------------------------------ end
    def after_spin(self, _executor, signum) -> int:
        """Exit code for ``run_node``: the run's own (0, or 1 on a timeout) or 0 when stopped by a signal."""
        if signum is not None and not self.finished:
            self.get_logger().info(f'stopped by signal {signum} at sim time {self.sim.t:.3f} s')
            return EXIT_OK
        return self.exit_code

    def _finish(self, code: int, reason: str):
        if self.finished:
            return
        self.finished = True
        self.exit_code = code
        self.end_reason = reason
        self.finish_wall = time.monotonic()
        wall = self.finish_wall - self.run_start_wall if self.run_start_wall else 0.0
        rate = self.steps_done / wall if wall > 0 else 0.0
        self.get_logger().info(
            f'run over: {reason}; {self.steps_done} control steps, sim time {self.sim.t:.3f} s, '
            f'{self.sim.impact_count} impacts, wall {wall:.2f} s ({rate:.0f} steps/s)')


def main(args=None) -> int:
    return run_node('simulator', SimulatorNode, args)


if __name__ == '__main__':
    sys.exit(main())
