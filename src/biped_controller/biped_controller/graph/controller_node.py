"""ROS 2 node ``controller``: the p/tau-adaptive controller answering the simulator's lockstep.

Owns an :class:`biped_controller.core.controller.AdaptiveController`; its configuration comes from the
parameters, which have the keys of ``config/controller.yaml`` (defaults from that file) plus
``control_period`` (s, must equal the simulator's; default ``config/simulator.yaml``).
``mode`` is validated against none | tau | p | both | wbc | hybrid | lambda | all (``controller.MODES``).

For every ``/sim/state`` (SimState) it computes the torque and publishes
- ``/controller/torque`` (sensor_msgs/JointState): ``name`` = ``description.PAPER_JOINTS``,
  ``effort`` = paper torques q1..q6 [N m], ``header.stamp`` = the state's stamp;
- ``/controller/status`` (ControllerStatus): every field of ``ControllerStatusData``.

A state repeating the last sequence number is answered with the same torque (no second
computation, the parameter state advances once per step). A state with ``fallen`` set is not
answered. If no state arrives for ``state_timeout`` seconds (wall) after the first one, the node
logs once that ``/sim/state`` is silent and idles (the simulator ended or died; the launcher stops
the controller); it exits 0 on SIGINT / SIGTERM.

Bad parameters: logged naming the parameter, exit status 2, nothing published.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Optional

import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from sensor_msgs.msg import JointState

from biped_msgs_py.msg import ControllerStatus, SimState
from biped_sim.graph import names as gn
from biped_sim.robot.description import PAPER_JOINTS, load_description
from biped_sim.graph.params import (
    ParameterError,
    declare_executor,
    get_bool,
    get_float,
    get_str,
    load_robot_files,
    run_node,
)
from biped_sim.robot.loop import ENGINES, load_loop_settings

from biped_controller.core.controller import MODES, QP_SOLVERS, AdaptiveController, ControllerConfig, ControllerConfigError, load_controller_config
from biped_sim.robot.gait_family import GaitFamily


def read_controller_config(node: Node) -> ControllerConfig:
    base = load_controller_config()
    kw = {}
    for name in ControllerConfig.__dataclass_fields__:
        if name == 'period':
            continue
        default = getattr(base, name)
        if name == 'mode':
            kw[name] = get_str(node, name, default, choices=MODES)
        elif name == 'engine':
            kw[name] = get_str(node, name, default, choices=ENGINES)
        elif name == 'qp_solver':
            kw[name] = get_str(node, name, default, choices=QP_SOLVERS)
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


def status_message(s, stamp) -> ControllerStatus:
    m = ControllerStatus()
    m.stamp = stamp
    m.step = int(s.step)
    m.mode = s.mode
    m.p = float(s.p)
    m.p_dot = float(s.p_dot)
    m.tau = float(s.tau)
    m.tau_dot = float(s.tau_dot)
    m.p_ddot = float(s.p_ddot)
    m.tau_ddot = float(s.tau_ddot)
    m.p_ddot_star = float(s.p_ddot_star)
    m.tau_ddot_star = float(s.tau_ddot_star)
    m.qp_status = int(s.qp_status)
    m.qp_message = str(s.qp_message)
    m.margins = np.asarray(s.margins, dtype=float).tolist()
    m.tightest = int(s.tightest)
    m.zmp = float(s.zmp)
    m.stance = int(s.stance)
    m.max_tracking_error = float(s.max_tracking_error)
    m.predicted_reaction = np.asarray(s.predicted_reaction, dtype=float).tolist()
    m.force_estimate = float(s.force_estimate)
    m.wbc_status = int(s.wbc_status)
    m.wbc_active = int(s.wbc_active)
    m.wbc_deviation = float(s.wbc_deviation)
    m.lam = float(s.lam)
    m.lam_dot = float(s.lam_dot)
    m.lam_ddot = float(s.lam_ddot)
    m.lam_ddot_star = float(s.lam_ddot_star)
    return m


class ControllerNode(Node):

    def __init__(self, **kwargs):
        super().__init__(gn.CONTROLLER_NODE, **kwargs)
        self.cfg = read_controller_config(self)
        declare_executor(self)
        self.state_timeout = get_float(self, 'state_timeout', lo=0.0, lo_open=True)
        self.wait_for_recorder = get_bool(self, 'wait_for_recorder')
        desc, family = load_robot_files(self)
        self.ctrl = AdaptiveController(self.cfg, family, desc)
        self.ctrl.reset()
        self.pub_torque = self.create_publisher(JointState, gn.CONTROLLER_TORQUE, gn.QOS_LOCKSTEP)
        self.pub_status = self.create_publisher(ControllerStatus, gn.CONTROLLER_STATUS, gn.QOS_SENSOR)
        self.state_sub = None
        if not self.wait_for_recorder:
            self._subscribe()
        self.last_sequence: Optional[int] = None
        self.last_reply: Optional[JointState] = None
        self.last_state_wall: Optional[float] = None
        self.silent_reported = False
        self.steps = 0
        # wall-clock timer: with use_sim_time a ROS-time timer would stop with /clock, i.e. exactly when
        # the simulator is gone or not started yet
        self.create_timer(0.05, self._on_timer, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f'controller ready: mode {self.cfg.mode}, period {self.cfg.period} s')

    def _subscribe(self):
        self.state_sub = self.create_subscription(SimState, gn.SIM_STATE, self._on_state, gn.QOS_LOCKSTEP)

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
            if self.last_reply is not None:
                self.pub_torque.publish(self.last_reply)
            return
        self.last_sequence = msg.sequence
        if msg.fallen:
            self.get_logger().info(f'simulator reports a fall ({msg.fall_cause}) at step {msg.step}')
            return
        t = msg.stamp.sec + 1e-9 * msg.stamp.nanosec
        out = self.ctrl.compute(t, np.asarray(msg.q, dtype=float), np.asarray(msg.q_dot, dtype=float),
                                int(msg.stance))
        js = JointState()
        js.header.stamp = msg.stamp
        js.name = list(PAPER_JOINTS)
        js.effort = np.asarray(out.torque, dtype=float).tolist()
        self.pub_torque.publish(js)
        self.last_reply = js
        self.pub_status.publish(status_message(out.status, msg.stamp))
        self.steps += 1

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
