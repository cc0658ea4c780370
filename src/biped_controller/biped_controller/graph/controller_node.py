"""ROS 2 node ``controller``: a controller answering the simulator's lockstep, through the controller interface.

Owns one controller built by the interface's registry (``biped_controller.plugin.registry.make_controller``),
whatever it is: the p/tau-adaptive controller in one of its modes (``biped_controller.plugin.builtin``, an
:class:`biped_controller.core.control.controller.AdaptiveController` with its compiled period) or any plug-in.
The adaptive controller's configuration comes from the parameters, which have the keys of
``config/controller.yaml`` (defaults from that file) plus ``control_period`` (s, must equal the simulator's;
default ``config/simulator.yaml``): a built-in mode gets them as its setup's options.
``mode`` is validated against none | tau | p | both | wbc | hybrid | lambda | all (``controller.MODES``).
``profile`` (default ``config/graph.yaml``: ``default``) names a profile of ``config/profiles/``: its controller
settings replace the file's as the parameters' defaults (a parameter given explicitly still wins; the
profile's simulator settings and plant perturbation are the simulator node's).

IMU: with ``use_imu`` (default ``config/graph.yaml``) the node also subscribes to ``/imu``
(``sensor_msgs/msg/Imu``, ``biped_sim.graph.imu``; its reader is created before the ``/sim/state`` reader,
which the simulator's start relies on) and answers a state only once it holds the IMU message of the same
stamp, whichever of the two arrives first (exact-stamp pairing: the lockstep stays deterministic, nothing
waits on the wall clock); the IMU's pitch theta = 2 atan2(-y, w) and its gyro's pitch rate theta' =
-angular_velocity.y go to ``AdaptiveController.compute`` as the in-process loop passes ``Observation.pitch``
and ``Observation.pitch_rate`` (the state estimator fuses the pitch, and the rate with ``estimator_gyro``;
without the estimator neither is used). Without ``use_imu`` both are NaN (no IMU). An IMU message that is not
the planar torso IMU is logged naming the field and dropped (the simulator then reports the missing torque).

At start it publishes the latched ``/controller/info`` (``std_msgs/String``, YAML of
``plugin.provenance.controller_provenance``: ``controller``, ``options``, the SHA-256 of every file an option
names, a policy's ``policy_file`` and ``policy_sha256``; a built-in mode's ``mode``), which the recorder
also writes as the bag's metadata record ``biped_controller``.

For every ``/sim/state`` (SimState) it computes the torque and publishes
- ``/controller/torque`` (sensor_msgs/JointState): ``name`` = ``description.PAPER_JOINTS``,
  ``effort`` = paper torques q1..q6 [N m], ``header.stamp`` = the state's stamp;
- ``/controller/status`` (ControllerStatus): a built-in mode's every field of ``ControllerStatusData`` (the
  ``record`` of its ``ControlResult``); a plug-in's as below.

With ``publish_cdr`` (default ``config/graph.yaml``: true) both go out as CDR bytes encoded by
``biped_sim.graph.cdr`` (the same bytes as the message objects, which ``publish_cdr`` false publishes).

A state repeating the last sequence number is answered with the same torque (no second
computation, the parameter state advances once per step). A state with ``fallen`` set is not
answered. If no state arrives for ``state_timeout`` seconds (wall) after the first one, the node
logs once that ``/sim/state`` is silent and idles (the simulator ended or died; the launcher stops
the controller); it exits 0 on SIGINT / SIGTERM.

Any registered controller (``controller`` parameter; default ``config/graph.yaml``: ``''`` = the adaptive
controller in ``mode``): a built-in mode's name sets ``mode``, any other name (a ``biped.controllers``
entry point or ``module:Class``, ``biped_controller.plugin.registry``) names that controller. Every
controller runs behind the controller interface (``biped_controller.plugin.interface``, built from the
description, the gait family and ``control_period``; a built-in mode's options are the controller
parameters above, a plug-in's are the parameter ``controller_options``: a string array of ``KEY=VALUE``
(default ``config/graph.yaml``: ``[]``), parsed by ``plugin.options.parse_options``, the parser of the study
commands' ``--option`` (a value a float where it reads as one, ``true`` / ``false`` a bool, else the text; e.g.
``-p controller_options:="['file=/path/policy.onnx']"`` for ``onnx_policy``, docs/policies.md). A malformed
item, a key given twice, options for a built-in mode, a plug-in's missing ``required_options`` or options its
constructor refuses (a missing or malformed policy file) stop the node at start naming ``controller_options``). Each state becomes its ``Observation``: t = the stamp [s], step = the state's step,
the sensed q, q', stance, the IMU's pitch and rate (NaN without ``use_imu``), and the previous period's torque
clipped to the description's torque limits (what the nominal plant applies); a stance change is announced
by ``on_touchdown`` before ``compute``. Its torque is published as above; a plug-in's status keys that
name a numeric field of ControllerStatus (p, tau_dot, ...) fill that field, ``mode`` carries the controller's
name, the other fields keep their defaults. A controller fault (``ControllerFault``: a non-finite or wrongly shaped
torque, a malformed status, an exception) is logged naming the controller and the period, and that state
and every later one is left unanswered (the simulator reports the missing torque and stops).

Bad parameters: logged naming the parameter, exit status 2, nothing published.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from typing import Optional

import numpy as np
import yaml
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String

from biped_msgs_py.msg import ControllerStatus, SimState
from biped_sim.graph import cdr
from biped_sim.graph import names as gn
from biped_sim.graph.imu import ImuMessageError, imu_reading
from biped_sim.graph.sim_clock import SimClock
from biped_model.description import LEFT, PAPER_JOINTS
from biped_sim.graph.params import (
    ParameterError,
    declare_executor,
    get_profile,
    robot_settings,
    get_bool,
    get_float,
    get_str,
    get_str_list,
    load_robot_files,
    run_node,
)
from biped_model.loop import ENGINES, load_loop_settings

from biped_controller.core.control.config import (MODEL_ERROR_REGRESSORS, MODES, QP_SOLVERS, ControllerConfig,
                                                  ControllerConfigError, load_controller_config)
from biped_controller.core.control.status import ControllerStatusData
from biped_controller.plugin.builtin import compiled_mode
from biped_controller.plugin.interface import (ControllerFault, ControllerSetup, GuardedController, InterfaceError,
                                               Observation, stamp_time)
from biped_controller.plugin.options import ControllerOptionError, parse_options
from biped_controller.plugin.provenance import controller_provenance
from biped_controller.plugin.registry import (ControllerLoadError, UnknownControllerError, load_controller,
                                              make_controller)


#: the controller's settings that take one of a few names, with those names
CHOICES = {'mode': MODES, 'engine': ENGINES, 'qp_solver': QP_SOLVERS, 'model_error_regressor': MODEL_ERROR_REGRESSORS}


def read_controller_config(node: Node) -> ControllerConfig:
    """ControllerConfig from the parameters (one per field, defaults config/controller.yaml; ``control_period``
    from config/simulator.yaml), over the controller settings of the profile of parameter ``profile``: a name
    from ``CHOICES``, a bool, or a number; a bad one (or an unknown profile) raises ParameterError naming it."""
    profile = get_profile(node)
    fields = ControllerConfig.__dataclass_fields__
    own = dict(robot_settings(node))        # the robot's size-dependent values, under the profile's
    try:
        base = load_controller_config(**{k: v for k, v in (*own.items(), *profile.settings) if k in fields and k != 'period'})
    except ControllerConfigError as exc:
        raise ParameterError('profile', f"profile {profile.name}: {exc}") from exc
    kw = {}
    for name in ControllerConfig.__dataclass_fields__:
        if name == 'period':
            continue
        default = getattr(base, name)
        if name in CHOICES:
            kw[name] = get_str(node, name, default, choices=CHOICES[name])
        elif isinstance(default, bool):
            kw[name] = get_bool(node, name, default)
        else:
            kw[name] = get_float(node, name, default)
    kw['period'] = get_float(node, 'control_period', load_loop_settings().control_period, lo=0.0, lo_open=True)
    try:
        return ControllerConfig(**kw).validate()
    except ControllerConfigError as exc:
        name = str(exc).split()[0]
        raise ParameterError('control_period' if name == 'period' else name, str(exc)) from exc


def _float_list(v) -> list:
    return np.asarray(v, dtype=float).tolist()


#: every field of ControllerStatus but ``stamp``, with the conversion from ``ControllerStatusData``'s value
STATUS_FIELDS: tuple[tuple[str, object], ...] = (
    ('step', int), ('mode', str), ('p', float), ('p_dot', float), ('tau', float), ('tau_dot', float),
    ('p_ddot', float), ('tau_ddot', float), ('p_ddot_star', float), ('tau_ddot_star', float),
    ('qp_status', int), ('qp_message', str), ('margins', _float_list), ('tightest', int), ('zmp', float),
    ('stance', int), ('max_tracking_error', float), ('predicted_reaction', _float_list),
    ('force_estimate', float), ('wbc_status', int), ('wbc_active', int), ('wbc_deviation', float),
    ('lam', float), ('lam_dot', float), ('lam_ddot', float), ('lam_ddot_star', float))


def status_message(s, stamp) -> ControllerStatus:
    """The ``/controller/status`` message of one period's ``ControllerStatusData`` ``s``, stamped ``stamp``."""
    m = ControllerStatus()
    m.stamp = stamp
    for name, conv in STATUS_FIELDS:
        setattr(m, name, conv(getattr(s, name)))
    return m


def status_cdr(enc: cdr.ControllerStatus, s, sec: int, nanosec: int) -> bytes:
    """The CDR bytes (``biped_sim.graph.cdr``) of :func:`status_message`: the same conversions of the same fields."""
    v = {name: conv(getattr(s, name)) for name, conv in STATUS_FIELDS}
    return enc.encode(sec, nanosec, v['step'], v['mode'],
                      (v['p'], v['p_dot'], v['tau'], v['tau_dot'], v['p_ddot'], v['tau_ddot'], v['p_ddot_star'],
                       v['tau_ddot_star']), v['qp_status'], v['qp_message'], v['margins'], v['tightest'], v['zmp'],
                      v['stance'], v['max_tracking_error'], v['predicted_reaction'], v['force_estimate'],
                      v['wbc_status'], v['wbc_active'],
                      (v['wbc_deviation'], v['lam'], v['lam_dot'], v['lam_ddot'], v['lam_ddot_star']))


#: the ControllerStatus fields a plug-in's status may fill (a number each), with their conversion
PLUGIN_STATUS_FIELDS: dict[str, object] = {name: conv for name, conv in STATUS_FIELDS
                                           if conv in (int, float) and name not in ('step', 'stance')}


def build_controller(name: str, desc, family, cfg: ControllerConfig,
                     options: Optional[dict] = None) -> GuardedController:
    """The registered controller ``name`` (a built-in mode or a plug-in) built and reset for a run starting in
    LEFT stance at t = 0, with the period ``cfg.period`` [s]; a built-in mode (``plugin.builtin.compiled_mode``)
    gets ``cfg``'s settings as its options, a plug-in ``options`` (the parsed ``controller_options``).
    ParameterError naming ``controller`` when it cannot be found or loaded; naming ``controller_options`` when
    options are given to a built-in mode, a plug-in's ``required_options`` are missing, or the plug-in refuses
    its options (its constructor or reset raises)."""
    options = dict(options or {})
    try:
        cls = load_controller(name)
    except (UnknownControllerError, ControllerLoadError) as exc:
        raise ParameterError('controller', str(exc)) from exc
    builtin = compiled_mode(cls) is not None
    if builtin and options:
        raise ParameterError('controller_options', f"{sorted(options)}: the built-in mode {name!r} takes its "
                             f"settings as this node's own parameters (config/controller.yaml's keys), not options")
    missing = [k for k in (getattr(cls, 'required_options', ()) or ()) if k not in options]
    if missing:
        raise ParameterError('controller_options', f"controller {name!r} needs the option(s) "
                             f"{', '.join(missing)}: e.g. controller_options:=\"['{missing[0]}=...']\"")
    if builtin:
        options = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in ('mode', 'period')}
    try:
        ctrl = make_controller(name, ControllerSetup(desc, family, cfg.period, options))
        ctrl.reset(0.0, LEFT)
    except (UnknownControllerError, ControllerLoadError) as exc:
        raise ParameterError('controller', str(exc)) from exc
    except (InterfaceError, ControllerFault) as exc:
        raise ParameterError('controller_options' if options and not builtin else 'controller', str(exc)) from exc
    except Exception as exc:    # the plug-in's own constructor refuses its options (e.g. PolicyFileError)
        if builtin:
            raise
        raise ParameterError('controller_options' if options else 'controller',
                             f"controller {name!r} with options {options}: {type(exc).__name__}: {exc}") from exc
    return ctrl


class ControllerNode(Node):

    def __init__(self, **kwargs):
        super().__init__(gn.CONTROLLER_NODE, **kwargs)
        # use_sim_time: the node's clock is the stamp of the state it answers (no /clock reader: graph.sim_clock)
        self.sim_clock = SimClock(self)
        self.cfg = read_controller_config(self)
        declare_executor(self)
        self.state_timeout = get_float(self, 'state_timeout', lo=0.0, lo_open=True)
        self.wait_for_recorder = get_bool(self, 'wait_for_recorder')
        self.use_imu = get_bool(self, 'use_imu')
        # /controller/torque and /controller/status as CDR bytes (biped_sim.graph.cdr), as the simulator's
        self.publish_cdr = get_bool(self, 'publish_cdr')
        self._cdr_torque, self._cdr_status = cdr.JointState(), cdr.ControllerStatus()
        desc, family = load_robot_files(self)
        name = get_str(self, 'controller')
        try:
            self.controller_options = parse_options(get_str_list(self, 'controller_options'), 'controller_options')
        except ControllerOptionError as exc:
            raise ParameterError('controller_options', str(exc)) from exc
        if name in MODES:
            self.cfg = dataclasses.replace(self.cfg, mode=name).validate()
        # one route for every controller: the interface (a built-in mode included, its compiled period inside)
        self.controller_name = name or self.cfg.mode
        self.controller = build_controller(self.controller_name, desc, family, self.cfg, self.controller_options)
        self._torque_min, self._torque_max = (np.array(v, dtype=float) for v in desc.torque_limits())
        self._last_torque, self._last_stance, self._faulted = np.zeros(6), None, False
        self.pub_torque = self.create_publisher(JointState, gn.CONTROLLER_TORQUE, gn.QOS_LOCKSTEP)
        self.pub_status = self.create_publisher(ControllerStatus, gn.CONTROLLER_STATUS, gn.QOS_SENSOR)
        # latched: the run's controller, its options and the hashes of the files it reads (plugin.provenance)
        self.info = controller_provenance(self.controller_name, self.controller_options, self.controller)
        if self.controller_name in MODES:
            self.info['mode'] = self.cfg.mode
        self.pub_info = self.create_publisher(String, gn.CONTROLLER_INFO, gn.QOS_LATCHED)
        self.pub_info.publish(String(data=yaml.safe_dump(self.info, sort_keys=False)))
        self.state_sub = None
        self.imu_sub = None
        # stamp [ns] -> the IMU's (pitch [rad], pitch rate [rad/s]), not yet used
        self.imu_pitch: dict[int, tuple[float, float]] = {}
        self.pending: Optional[SimState] = None      # a state waiting for its IMU message
        if not self.wait_for_recorder:
            self._subscribe()
        self.last_sequence: Optional[int] = None
        self.last_reply: Optional[JointState | bytes] = None
        self.last_state_wall: Optional[float] = None
        self.silent_reported = False
        self.steps = 0
        # wall-clock timer: with use_sim_time a ROS-time timer would stop with /clock, i.e. exactly when
        # the simulator is gone or not started yet
        self.create_timer(0.05, self._on_timer, clock=Clock(clock_type=ClockType.STEADY_TIME))
        what = f'mode {self.cfg.mode}' if self.controller_name == self.cfg.mode else f'controller {self.controller_name!r}'
        if self.controller_options:
            what += f' with options {self.controller_options}'
        self.get_logger().info(f'controller ready: {what}, period {self.cfg.period} s, profile '
                               f'{self.get_parameter("profile").value}, publishing '
                               f'{"CDR bytes" if self.publish_cdr else "message objects"}')

    def _subscribe(self):
        # /imu first: the simulator starts once the controller's /sim/state reader and every /imu reader it
        # has seen are matched; discovery announces this node's readers in the order they are created
        if self.use_imu:
            self.imu_sub = self.create_subscription(Imu, gn.IMU, self._on_imu, gn.QOS_LOCKSTEP)
        self.state_sub = self.create_subscription(SimState, gn.SIM_STATE, self._on_state, gn.QOS_LOCKSTEP)

    @staticmethod
    def _stamp_ns(stamp) -> int:
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)

    def _on_imu(self, msg: Imu):
        try:
            pitch, rate = imu_reading(msg)
        except ImuMessageError as exc:
            self.get_logger().error(f'{gn.IMU}: {exc}: dropped')
            return
        key = self._stamp_ns(msg.header.stamp)
        self.imu_pitch[key] = (pitch, rate)
        if self.pending is not None and self._stamp_ns(self.pending.stamp) == key:
            state, self.pending = self.pending, None
            self._answer(state)

    def _recorder_matched(self) -> bool:
        """The recorder is subscribed to both of our topics and every known subscription is matched
        (so that the first torque and status of the run are recorded)."""
        for pub in (self.pub_torque, self.pub_status):
            infos = self.get_subscriptions_info_by_topic(pub.topic_name)
            if gn.RECORDER_NODE not in {i.node_name for i in infos}:
                return False
            if pub.get_subscription_count() < len(infos):
                return False
        return True

    def _on_state(self, msg: SimState):
        self.last_state_wall = time.monotonic()
        if self.silent_reported:
            self.get_logger().info(f'{gn.SIM_STATE} is back')
            self.silent_reported = False
        if self.last_sequence is not None and msg.sequence == self.last_sequence:
            if self.last_reply is not None and self.pending is None:   # (a pending state has no reply yet)
                self.pub_torque.publish(self.last_reply)
            return
        self.last_sequence = msg.sequence
        if msg.fallen:
            self.get_logger().info(f'simulator reports a fall ({msg.fall_cause}) at step {msg.step}')
            return
        if self.use_imu and self._stamp_ns(msg.stamp) not in self.imu_pitch:
            self.pending = msg            # answered by _on_imu when the IMU of this stamp arrives
            return
        self._answer(msg)

    def _answer(self, msg: SimState):
        """Compute and publish the torque of state ``msg`` (with the IMU pitch and pitch rate of its stamp, when
        used)."""
        pitch = rate = math.nan
        if self.use_imu:
            key = self._stamp_ns(msg.stamp)
            pitch, rate = self.imu_pitch[key]
            self.imu_pitch = {k: v for k, v in self.imu_pitch.items() if k > key}
        t = msg.stamp.sec + 1e-9 * msg.stamp.nanosec
        self.sim_clock.set(self._stamp_ns(msg.stamp))
        self._answer_state(msg, stamp_time(t), pitch, rate)

    def _answer_state(self, msg: SimState, t: float, pitch: float, rate: float):
        """:meth:`_answer` through the controller interface (module docstring): the observation of ``msg`` at
        ``t`` [s] (the stamp), ``on_touchdown`` on a stance change, ``compute``, then the torque and the status
        published."""
        if self._faulted:
            return
        stance = int(msg.stance)
        obs = Observation.frozen(t, int(msg.step), stance, np.asarray(msg.q, dtype=float),
                                 np.asarray(msg.q_dot, dtype=float), pitch, rate, self._last_torque,
                                 stance if self._last_stance is None else self._last_stance)
        try:
            if self._last_stance is not None and stance != self._last_stance:
                self.controller.on_touchdown(t, stance)
            res = self.controller.compute(obs)
        except ControllerFault as exc:
            self._faulted = True
            self.get_logger().error(f'{exc}: no torque for this state or any later one')
            return
        torque = res.torque.tolist()
        self._last_torque = np.minimum(np.maximum(res.torque, self._torque_min), self._torque_max)   # np.clip's values
        self._last_stance = stance
        sec, nsec = msg.stamp.sec, msg.stamp.nanosec
        if self.publish_cdr:
            js = self._cdr_torque.encode(sec, nsec, '', PAPER_JOINTS, (), (), torque)
        else:
            js = JointState()
            js.header.stamp = msg.stamp
            js.name = list(PAPER_JOINTS)
            js.effort = torque
        if isinstance(res.record, ControllerStatusData):       # a built-in mode: its whole status
            status = (status_cdr(self._cdr_status, res.record, sec, nsec) if self.publish_cdr
                      else status_message(res.record, msg.stamp))
        else:
            status = self._plugin_status(msg, stance, res.status)
        self.pub_torque.publish(js)
        self.last_reply = js
        self.pub_status.publish(status)
        self.steps += 1

    def _plugin_status(self, msg: SimState, stance: int, values) -> ControllerStatus:
        """The ``/controller/status`` of a plug-in's status mapping (module docstring)."""
        m = ControllerStatus()
        m.stamp = msg.stamp
        m.mode = self.controller_name
        m.stance = stance
        m.step = self.steps
        for k, v in values.items():
            conv = PLUGIN_STATUS_FIELDS.get(k)
            if conv is not None:
                setattr(m, k, conv(v))
        return m

    def _on_timer(self):
        if self.state_sub is None:
            if self._recorder_matched():
                self.get_logger().info('recorder matched: subscribing to ' + gn.SIM_STATE)
                self._subscribe()
            return
        if self.last_state_wall is None or self.silent_reported:
            return
        if time.monotonic() - self.last_state_wall > self.state_timeout:
            self.silent_reported = True
            pubs = self.count_publishers(gn.SIM_STATE)
            what = 'the simulator is gone' if pubs == 0 else 'the simulator stopped publishing'
            self.get_logger().warning(
                f'{gn.SIM_STATE} is silent for {self.state_timeout} s after {self.steps} steps '
                f'({pubs} publisher(s) left: {what}): idling')


    def after_spin(self, _executor, _signum) -> int:
        self.get_logger().info(f'controller stopping after {self.steps} steps')
        return 0   # run_node then waits for the acknowledgements of the last torques and statuses


def main(args=None) -> int:
    return run_node('controller', ControllerNode, args)


if __name__ == '__main__':
    sys.exit(main())
