"""Tiny client of ``/apply_push``: ``python -m biped_sim.graph.push_client --force N --duration S
[--start T | --delay D] [--height H] [--timeout S]``. Prints the response as YAML; exit 0 when the
push was accepted, 1 when rejected, 2 when the service did not answer."""

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
    a = ap.parse_args(argv)
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
