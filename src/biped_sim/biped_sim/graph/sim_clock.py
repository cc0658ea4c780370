"""A node's sim-time clock without rclpy's per-message ``/clock`` callback.

With ``use_sim_time`` true, rclpy's ``TimeSource`` gives a node a ``/clock`` reader whose Python callback runs on
every message: at 1 kHz that is a DDS delivery, an executor dispatch, a deserialisation and a ``Time`` per control
step in each such node (the disturbance node spent ~0.13 ms of CPU per control step on nothing else; the
controller and the recorder had one each too, beside their own readers), and one more reader the simulator
writes each ``/clock`` to.

:class:`SimClock` keeps ``use_sim_time``'s meaning (the node's ROS clock, ``node.get_clock().now()``, reads sim
time) and removes that reader; the node feeds the clock itself, in one of two ways:

- :meth:`SimClock.set` with a sim time the node already has (the controller: the stamp of the state it answers;
  the recorder: the ``/clock`` message it records);
- :meth:`SimClock.poll`, with ``poll_clock=True``: a ``/clock`` reader (best effort, keep-last 1, as rclpy's own)
  that no executor dispatches; :meth:`poll` takes what waits and sets the clock to the newest, so a node that needs
  the sim time only now and then (the disturbance node, at a push request) pays a DDS delivery per message and no
  Python at all. The newest message a poll finds is the newest the middleware received: at least as recent as what
  rclpy's callback would have set by then (its callback may still be queued behind others).

If ``use_sim_time`` is false the node keeps the system clock and :meth:`set` / :meth:`poll` change nothing. If
``use_sim_time`` is turned off and on again at run time, rclpy's ``TimeSource`` subscribes again as usual (its
reader comes back; :meth:`set` then competes with it).

This relies on two private attributes of rclpy 7.1 (Jazzy), checked at construction: ``Node._time_source`` (the
node's ``TimeSource``) and its ``_clock_sub``; the tests hold the behaviour (no ``/clock`` reader of the node, the
clock following what is fed).
"""
from __future__ import annotations

from typing import Optional

from rclpy.node import Node
from rclpy.time import Time


class SimClockError(RuntimeError):
    """rclpy's time source is not what this module was written against."""


class SimClock:
    """The sim-time clock of ``node`` fed by the node (module docstring).

    :param node: a node constructed with ``use_sim_time`` (any value).
    :param poll_clock: also create an undispatched ``/clock`` reader for :meth:`poll`.
    :raises SimClockError: rclpy's ``TimeSource`` has no ``_clock_sub`` attribute (another rclpy).
    """

    def __init__(self, node: Node, *, poll_clock: bool = False) -> None:
        self.node = node
        ts = getattr(node, '_time_source', None)
        if ts is None or not hasattr(ts, '_clock_sub'):
            raise SimClockError('rclpy.node.Node._time_source._clock_sub not found: this rclpy is not 7.1 (Jazzy)')
        self._ts = ts
        self.active = bool(node.get_parameter('use_sim_time').value)
        if ts._clock_sub is not None:          # rclpy's per-message /clock callback: removed
            node.destroy_subscription(ts._clock_sub)
            ts._clock_sub = None
        self.ns: Optional[int] = None          # the last sim time fed [ns]
        self._reader = None
        self._msg_type = None
        if poll_clock and self.active:
            from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
            from rclpy.qos import QoSProfile, ReliabilityPolicy
            from rosgraph_msgs.msg import Clock
            from biped_sim.graph import names as gn
            qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
            self._msg_type = Clock
            with node.handle:
                self._reader = _rclpy.Subscription(node.handle, Clock, gn.CLOCK, qos.get_c_qos_profile())

    def set(self, ns: int) -> None:
        """Sim time ``ns`` [ns] is now (the node's clock and every clock attached to its time source)."""
        self.ns = int(ns)
        if self.active and self._ts.ros_time_is_active:
            self._ts._last_time_set = t = Time(nanoseconds=self.ns)
            for clock in self._ts._associated_clocks:
                clock.set_ros_time_override(t)

    def poll(self) -> Optional[int]:
        """Take every ``/clock`` message waiting on the polled reader and set the clock to the newest; returns the
        clock's sim time [ns] (None before any). Without the reader: the last :meth:`set` value."""
        if self._reader is not None:
            newest = None
            with self._reader:
                while True:
                    taken = self._reader.take_message(self._msg_type, False)
                    if taken is None or taken[0] is None:
                        break
                    newest = taken[0].clock
            if newest is not None:
                self.set(int(newest.sec) * 1_000_000_000 + int(newest.nanosec))
        return self.ns

    def destroy(self) -> None:
        """Destroy the polled reader (before the node is destroyed)."""
        if self._reader is not None:
            self._reader.destroy_when_not_in_use()
            self._reader = None
