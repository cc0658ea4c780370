"""ROS 2 node ``disturbance``: validates push requests and publishes the accepted ones.

Service ``/apply_push`` (biped_msgs_py/srv/ApplyPush). A request is checked by the pure
:func:`biped_sim.plant.push.validate_push`, in this order:
every used number finite (``force``, ``duration``, ``start`` or ``delay``; ``height`` may be NaN =
default), ``0 < duration <= max_duration``, ``|force| <= max_force``, ``delay >= 0``, start not
before the current sim time (``/clock``; this node runs with ``use_sim_time`` true), start not after
``horizon`` (the end of the run: a push that could never act is refused), ``height`` within
[0, torso length] (NaN: ``push_height``), and no overlap with a push already scheduled.
Rejected: ``accepted = false``, a message naming the field and the allowed range, nothing published
on ``/push_events``. Accepted: a PushEvent with a new id (1, 2, ...) on ``/push_events`` (reliable,
transient local: a simulator joining late still gets it); the response gives the id and the
scheduled start and end.

Every call, accepted or rejected, is published on ``/push_requests`` as YAML
(``graph_names.push_request_yaml``).

A schedule can also come from parameters: ``schedule_forces``, ``schedule_starts``,
``schedule_durations`` and ``schedule_heights`` (same length; heights may be omitted = default),
validated like requests at start (a bad entry: the node exits 2 naming the parameter) and
published at start.

Parameters: ``max_force`` (N, default 2000), ``max_duration`` (s, default 1.0), ``horizon`` (s of sim
time, default 3600: the latest start accepted; the launcher sets it to the simulator's ``max_time`` when
one is given), ``push_height`` (m, default config/simulator.yaml), the schedule arrays, ``executor``
(``events`` | ``single_threaded``, default config/graph.yaml: ``events``; the 1 kHz ``/clock`` of ``use_sim_time``
cost a wait-set round each under rclpy's Python ``SingleThreadedExecutor``, 0.3-0.5 ms of CPU per control step,
and still ~0.13 ms as the ``EventsExecutor``'s callback, so the sim time is read only at a request,
from a ``/clock`` reader that no executor dispatches, :class:`biped_sim.graph.sim_clock.SimClock`), ``wait_for_recorder`` (default config/graph.yaml:
true; ``/apply_push`` is served only once the writers of ``/push_events`` and ``/push_requests`` are matched
with every subscription the graph knows on them, the recorder's among them: :meth:`DisturbanceNode.events_matched`);
``use_sim_time`` is forced true.
"""

from __future__ import annotations

import math
import sys

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String

from biped_msgs_py.msg import PushEvent
from biped_msgs_py.srv import ApplyPush
from biped_sim.graph import names as gn
from biped_model.description import DescriptionError, load_description
from biped_sim.plant.push import PushBook, PushLimits, Rejected
from biped_sim.graph.params import (
    ParameterError,
    declare_executor,
    get_bool,
    get_float,
    get_float_list,
    get_robot_name,
    get_str,
    robot_settings,
    run_node,
)
from biped_sim.plant.config import load_sim_config
from biped_sim.graph.sim_clock import SimClock


MATCH_POLL = 0.02   # s (steady) between looks at whether the event writers are matched (at start only)


class DisturbanceNode(Node):

    def __init__(self, **kwargs):
        overrides = [p for p in kwargs.pop('parameter_overrides', []) if p.name != 'use_sim_time']
        overrides.append(Parameter('use_sim_time', Parameter.Type.BOOL, True))
        super().__init__(gn.DISTURBANCE_NODE, parameter_overrides=overrides, **kwargs)
        # sim time read only at a request: a polled /clock reader instead of rclpy's callback per message
        self.sim_clock = SimClock(self, poll_clock=True)
        robot = get_robot_name(self)
        desc_path = get_str(self, 'description_path')
        try:
            from biped_model.robot import resolve_robot
            desc_file = desc_path or resolve_robot(robot or None).description_path
        except ValueError as exc:
            raise ParameterError('robot', str(exc)) from exc
        try:
            desc = load_description(desc_file)
        except (DescriptionError, OSError, ValueError) as exc:
            raise ParameterError('description_path', str(exc)) from exc
        max_force = get_float(self, 'max_force', lo=0.0, lo_open=True)
        max_duration = get_float(self, 'max_duration', lo=0.0, lo_open=True)
        own = {k: v for k, v in robot_settings(self) if k == 'push_height'}     # the robot's, if it has one
        default_height = get_float(self, 'push_height', load_sim_config(**own).push_height, lo=0.0,
                                   hi=desc.torso.length)
        horizon = get_float(self, 'horizon', lo=0.0, lo_open=True)
        declare_executor(self)
        self.book = PushBook(PushLimits(max_force, max_duration, desc.torso.length, default_height, horizon))
        forces = get_float_list(self, 'schedule_forces')
        starts = get_float_list(self, 'schedule_starts')
        durations = get_float_list(self, 'schedule_durations')
        heights = get_float_list(self, 'schedule_heights')
        n = len(forces)
        for name, arr in (('schedule_starts', starts), ('schedule_durations', durations)):
            if len(arr) != n:
                raise ParameterError(name, f'must have as many entries as schedule_forces ({n}), got {len(arr)}')
        if heights and len(heights) != n:
            raise ParameterError('schedule_heights', f'must be empty or have {n} entries, got {len(heights)}')
        schedule = []
        for i in range(n):
            h = heights[i] if heights else math.nan
            try:
                vp = self.book.check(forces[i], durations[i], starts[i], h, 0.0)
            except Rejected as exc:
                pname = {'force': 'schedule_forces', 'duration': 'schedule_durations', 'start': 'schedule_starts',
                         'delay': 'schedule_starts', 'height': 'schedule_heights'}[exc.field]
                raise ParameterError(pname, f'entry {i}: {exc}') from exc
            p = self.book.add(vp)
            schedule.append(PushEvent(id=p.id, start=p.start, duration=p.duration, force=p.force, height=p.height))

        self.pub_events = self.create_publisher(PushEvent, gn.PUSH_EVENTS, gn.QOS_EVENTS)
        self.pub_requests = self.create_publisher(String, gn.PUSH_REQUESTS, gn.QOS_EVENTS)
        for ev in schedule:
            self.pub_events.publish(ev)
            self.get_logger().info(f'scheduled push {ev.id} from parameters: {ev.force} N over '
                                   f'[{ev.start}, {ev.start + ev.duration}) s')
        self.wait_for_recorder = get_bool(self, 'wait_for_recorder')
        self._limits_text = f'|force| <= {max_force} N, duration <= {max_duration} s'
        self.service = None
        # the service comes up once our event writers are matched (steady clock: /clock may not run yet)
        self._match_timer = self.create_timer(MATCH_POLL, self._serve_when_matched,
                                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._serve_when_matched()
        if self.service is None:
            who = 'the recorder and every other subscriber' if self.wait_for_recorder else 'every subscriber'
            self.get_logger().info(f'{gn.APPLY_PUSH} is served once {who} of {gn.PUSH_EVENTS} and '
                                   f'{gn.PUSH_REQUESTS} is matched (wait_for_recorder: {self.wait_for_recorder})')

    def events_matched(self) -> bool:
        """Every subscription the graph knows on ``/push_events`` and ``/push_requests`` is matched by our
        writer, and (``wait_for_recorder``) the node ``recorder`` is among them. Until then a push accepted
        would be published to a reader that has not matched us yet: on a busy graph (the recorder's process
        not scheduled, or stopped and continued) that match may only complete after this node has exited,
        and the bag then lacks the push (measured: 2 of 30 runs of test_faults' lag-at-stop test lost both
        topics whole, with every writer acknowledged). The same rule as the controller's before it subscribes."""
        for pub in (self.pub_events, self.pub_requests):
            infos = self.get_subscriptions_info_by_topic(pub.topic_name)
            if self.wait_for_recorder and gn.RECORDER_NODE not in {i.node_name for i in infos}:
                return False
            if pub.get_subscription_count() < len(infos):
                return False
        return True

    def _serve_when_matched(self) -> None:
        if self.service is not None or not self.events_matched():
            return
        self._match_timer.cancel()
        self.service = self.create_service(ApplyPush, gn.APPLY_PUSH, self._on_apply_push)
        self.get_logger().info(f'serving {gn.APPLY_PUSH} ({self._limits_text})')

    def sim_time(self) -> float:
        """The current sim time [s]: the newest ``/clock`` received (0 before any), taken from the polled reader."""
        self.sim_clock.poll()
        return self.get_clock().now().nanoseconds * 1e-9

    def destroy_node(self):
        self.sim_clock.destroy()
        return super().destroy_node()

    def _on_apply_push(self, request, response):
        now = self.sim_time()
        try:
            vp = self.book.check(request.force, request.duration, request.start, request.height, now,
                                 use_delay=bool(request.use_delay), delay=request.delay)
        except Rejected as exc:
            response.accepted = False
            response.message = f'rejected: {exc}'
            response.push_id = 0
            response.scheduled_start = math.nan
            response.scheduled_end = math.nan
            self.get_logger().warning(f'{gn.APPLY_PUSH}: {response.message}')
        else:
            pid = self.book.add(vp).id
            start, height = vp.start, vp.height
            ev = PushEvent(id=pid, start=start, duration=vp.duration, force=vp.force, height=height)
            self.pub_events.publish(ev)
            response.accepted = True
            response.push_id = pid
            response.scheduled_start = start
            response.scheduled_end = start + request.duration
            response.message = (f'push {pid}: {request.force} N at {height} m above the hip over '
                                f'[{start}, {start + request.duration}) s sim time')
            self.get_logger().info(f'{gn.APPLY_PUSH}: accepted {response.message}')
        self.pub_requests.publish(String(data=gn.push_request_yaml(request, response, now)))
        return response


def main(args=None) -> int:
    return run_node('disturbance', DisturbanceNode, args)


if __name__ == '__main__':
    sys.exit(main())
