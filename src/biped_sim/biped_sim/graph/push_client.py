"""Tiny client of ``/apply_push``: ``python -m biped_sim.graph.push_client --force N --duration S
[--start T | --delay D] [--height H] [--timeout S] [--robot NAME|PATH]``. Prints the response as YAML; exit 0
when the push was accepted, 1 when rejected, 2 when the service did not answer, the robot named cannot be
used, or the running graph walks another robot.

``--robot``: the robot the push is meant for. Before the request, the client reads the graph's latched
``/robot_description`` and sends nothing unless it is that robot's URDF (a force sized for one robot is
never applied to another: the same newtons are a different dimensionless push on a robot of another
M sqrt(g L), docs/robots.md)."""

from __future__ import annotations

import argparse
import math
import sys

import yaml


def call_apply_push(force: float, duration: float, start: float | None = None, delay: float | None = None,
                    height: float = math.nan, timeout: float = 10.0, context=None):
    """Call /apply_push once; returns the response or raises TimeoutError."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from biped_msgs_py.srv import ApplyPush
    from biped_sim.graph import names as gn
    own = context is None
    if own:
        context = rclpy.Context()
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('push_client', context=context, start_parameter_services=False)
    try:
        client = node.create_client(ApplyPush, gn.APPLY_PUSH)
        if not client.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f'{gn.APPLY_PUSH} not available after {timeout} s')
        req = ApplyPush.Request()
        req.force = float(force)
        req.duration = float(duration)
        req.use_delay = delay is not None
        req.delay = float(delay) if delay is not None else 0.0
        req.start = float(start) if start is not None else 0.0
        req.height = float(height)
        future = client.call_async(req)
        from rclpy.executors import SingleThreadedExecutor
        ex = SingleThreadedExecutor(context=context)
        ex.add_node(node)
        ex.spin_until_future_complete(future, timeout_sec=timeout)
        ex.remove_node(node)
        if not future.done():
            raise TimeoutError(f'{gn.APPLY_PUSH} did not answer within {timeout} s')
        return future.result()
    finally:
        node.destroy_node()
        if own:
            rclpy.shutdown(context=context)


def graph_urdf(timeout: float = 10.0, context=None) -> str:
    """The running graph's ``/robot_description`` (latched: the simulator publishes it once); raises
    TimeoutError when none arrives within ``timeout`` [s]."""
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import String

    from biped_sim.graph import names as gn
    own = context is None
    if own:
        context = rclpy.Context()
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('push_client_robot', context=context, start_parameter_services=False)
    got: list[str] = []
    try:
        node.create_subscription(String, gn.ROBOT_DESCRIPTION, lambda m: got.append(m.data), gn.QOS_LATCHED)
        ex = SingleThreadedExecutor(context=context)
        ex.add_node(node)
        t_end = time.monotonic() + timeout
        while not got and time.monotonic() < t_end:
            ex.spin_once(timeout_sec=0.1)
        ex.remove_node(node)
        if not got:
            raise TimeoutError(f'no {gn.ROBOT_DESCRIPTION} within {timeout} s')
        return got[0]
    finally:
        node.destroy_node()
        if own:
            rclpy.shutdown(context=context)


def robot_urdf(robot: str) -> str:
    """The URDF of ``robot`` (a name under robots/ or a directory); raises ``RobotError`` (a ValueError)
    naming the directory, the file or the field."""
    from biped_model.description import make_urdf
    from biped_model.robot import resolve_robot
    return make_urdf(resolve_robot(robot).description())


def response_dict(res) -> dict:
    return {f: getattr(res, f) for f in ('accepted', 'message', 'push_id', 'scheduled_start', 'scheduled_end')}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='push', description='Request a push through /apply_push.')
    ap.add_argument('--force', type=float, required=True, help='N, + forward')
    ap.add_argument('--duration', type=float, required=True, help='s')
    g = ap.add_mutually_exclusive_group()
    g.add_argument('--start', type=float, help='absolute sim time of the onset [s]')
    g.add_argument('--delay', type=float, help='onset = current sim time + delay [s] (default: --delay 0)')
    ap.add_argument('--height', type=float, default=math.nan, help='m above the hip (default: torso CoM)')
    ap.add_argument('--timeout', type=float, default=10.0)
    ap.add_argument('--robot', default=None, metavar='NAME|PATH',
                    help='the robot the push is meant for (a name under robots/ or a robot directory); nothing is '
                         'sent unless the graph walks it (its /robot_description)')
    a = ap.parse_args(argv)
    if a.robot is not None:
        try:
            want = robot_urdf(a.robot)
        except ValueError as exc:
            print(f'push: {exc}', file=sys.stderr)
            return 2
        try:
            have = graph_urdf(a.timeout)
        except TimeoutError as exc:
            print(f'push: {exc}', file=sys.stderr)
            return 2
        if have != want:
            print(f'push: the running graph walks another robot than {a.robot} (its /robot_description differs): '
                  f'nothing sent', file=sys.stderr)
            return 2
    delay = a.delay if a.start is None else None
    if a.start is None and delay is None:
        delay = 0.0
    try:
        res = call_apply_push(a.force, a.duration, a.start, delay, a.height, a.timeout)
    except TimeoutError as exc:
        print(f'push: {exc}', file=sys.stderr)
        return 2
    print(yaml.safe_dump(response_dict(res), sort_keys=False), end='')
    return 0 if res.accepted else 1


if __name__ == '__main__':
    sys.exit(main())
