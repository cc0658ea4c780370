"""biped_sim.graph.sim_clock: use_sim_time without rclpy's per-message /clock reader.

Against rclpy's own behaviour in the same process: a node with use_sim_time has one /clock reader (the negative
control), with SimClock none; the clock reads what is fed (set) or the newest /clock waiting (poll); without
use_sim_time nothing is changed."""
from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.ros


def _node(ctx, name, sim_time: bool):
    import rclpy
    from rclpy.parameter import Parameter
    return rclpy.create_node(name, context=ctx, parameter_overrides=[
        Parameter('use_sim_time', Parameter.Type.BOOL, sim_time)])


def test_no_clock_reader_and_the_clock_reads_what_is_set(rclpy_context):
    from biped_sim.graph.sim_clock import SimClock
    plain = _node(rclpy_context, 'plain_sim_time', True)
    try:
        assert plain.count_subscribers('/clock') == 1          # rclpy's TimeSource reader (negative control)
        fed = _node(rclpy_context, 'fed_sim_time', True)
        clock = SimClock(fed)
        assert fed.count_subscribers('/clock') == 1            # only plain's is left
        assert fed.get_clock().now().nanoseconds == 0          # sim time before any
        clock.set(12_000_000_005)
        assert fed.get_clock().now().nanoseconds == 12_000_000_005
        assert clock.poll() == 12_000_000_005                  # no reader: the last value set
        clock.set(12_001_000_005)
        assert fed.get_clock().now().nanoseconds == 12_001_000_005
        fed.destroy_node()
        wall = _node(rclpy_context, 'wall_time', False)
        wclock = SimClock(wall)
        wclock.set(5)
        assert wall.get_clock().now().nanoseconds > 1_000_000_000 * 1_000_000   # still the system clock
        wall.destroy_node()
    finally:
        plain.destroy_node()


def test_poll_takes_the_newest_clock_waiting(rclpy_context):
    from rosgraph_msgs.msg import Clock
    from builtin_interfaces.msg import Time
    from biped_sim.graph import names as gn
    from biped_sim.graph.sim_clock import SimClock
    import rclpy
    node = _node(rclpy_context, 'polled_sim_time', True)
    clock = SimClock(node, poll_clock=True)
    src = rclpy.create_node('clock_source', context=rclpy_context)
    pub = src.create_publisher(Clock, gn.CLOCK, gn.QOS_CLOCK)
    try:
        assert node.count_subscribers(gn.CLOCK) == 1           # the polled reader
        assert clock.poll() is None
        deadline = time.monotonic() + 60.0
        while clock.poll() is None:                            # the writer matches the reader at some point
            assert time.monotonic() < deadline, 'the polled /clock reader never got a message'
            pub.publish(Clock(clock=Time(sec=1, nanosec=0)))
            time.sleep(0.01)
        for k in (7, 8, 9):
            pub.publish(Clock(clock=Time(sec=k, nanosec=250)))
        want = 9 * 1_000_000_000 + 250
        while clock.poll() != want:                            # best-effort reader: the last one again
            assert time.monotonic() < deadline, f'poll() = {clock.ns}, want {want}'
            time.sleep(0.01)
            pub.publish(Clock(clock=Time(sec=9, nanosec=250)))
        assert node.get_clock().now().nanoseconds == want
        assert clock.poll() == want                            # nothing new waiting: unchanged
    finally:
        clock.destroy()
        node.destroy_node()
        src.destroy_node()
