"""ROS 2 node ``bridge``: the running graph, live, on a Foxglove WebSocket server (``foxglove-sdk``).

Topics. Every topic of :data:`biped_sim.graph.names.TOPICS` is served and subscribed from the start; with
``lazy_streams`` a per-step stream (``graph_names.STREAM_QOS``) only while at least one client is
subscribed to its channel (subscribed and dropped on the executor's thread, by a timer every
``reconcile_period``; ``/clock``, the latched and the event topics always). Subscriptions are ``raw=True`` (the CDR
bytes are passed through, never deserialized) and the recorder's QoS (the topic's reliability and
durability, a keep-last history of at least ``recorder_node.RECORDING_DEPTH``: a lagging bridge loses
nothing, latched and event topics reach it). Each is served on a Foxglove channel with the schema
the MCAP writer stores (name ``pkg/msg/Type``, encoding ``ros2msg``, flattened ``.msg`` text) and
message encoding ``cdr``: one Foxglove layout works live and on replay.

Time. Each message is logged with ``log_time`` = the latest sim time received on ``/clock`` (ns; 0
before the first one), the recorder's log time, and every ``/clock`` is broadcast as the server
time, so Foxglove's timeline follows sim time. A client that subscribes to a latched topic
(``/robot_description``, ``/fall``) gets its last message again (late joiners see the robot; a
client already subscribed to it receives the copy too).

Service. ``/apply_push`` is offered as a Foxglove service (schema ``biped_msgs_py/srv/ApplyPush``,
request ``..._Request`` / response ``..._Response``, ``ros2msg`` texts, ``cdr`` encoding). A call is
checked (encoding ``cdr``, plain CDR header: :func:`bridge_core.check_call`), decoded into an
``ApplyPush.Request`` and sent to the ROS service ``/apply_push``; its response, serialized, is the
call's answer. The disturbance node's validation is therefore the only one: a rejected request
comes back with ``accepted: false`` and changes nothing. An undecodable call, or no answer from
``/apply_push`` within ``service_timeout`` (waiting for the service to appear included) fails the
call (Foxglove ``serviceCallFailure`` with the reason); nothing reaches the graph.

Bad input. Clients cannot publish into the graph (no ``clientPublish`` capability). Unknown
channels, garbage frames and disconnects are handled by the SDK's server (status message to that
client, or the client is dropped) and never reach ROS: the bridge's ROS side only ever reads the
graph and calls ``/apply_push``.

Parameters (``bridge: {ros__parameters: {...}}``), validated at start (exit 2 naming a bad one):

- ``host`` (string, default ``127.0.0.1``): address the server binds (``0.0.0.0``: every interface);
- ``port`` (int 0..65535, default 8765; 0 = a free port chosen by the system, logged);
- ``service_timeout`` (s > 0, default 10): wait for ``/apply_push`` and its answer;
- ``lazy_streams`` (bool, default false): read a per-step stream only while a client watches it;
- ``message_backlog`` (int 16..1000000, default 20000): messages queued per client before the
  oldest is dropped (the SDK's ``message_backlog_size``; 20000 = 1.3 s of all 15 topics at 1 kHz,
  for a client that lags).
- ``executor`` (``events`` | ``single_threaded``; ``config/graph.yaml``: ``events``): rclpy's C++
  ``EventsExecutor`` or its Python ``SingleThreadedExecutor``. Measured (``lab/benchmarks/bridge_profile``, py-spy at
  real time): on the ``SingleThreadedExecutor`` 86-90 % of the bridge's Python thread went to the
  executor's rounds (wait set rebuilt over every subscription, timer and service entity, task, callback), 9-19 %
  to ``Channel.log`` and 1-2 % to the bridge's own code; the bridge cost 0.9-1.7 ms of CPU per control step,
  as much as the simulator. The ``EventsExecutor`` takes each message in C++ and calls the handler directly
  (its raw, message-only subscriptions work; it takes no guard condition, hence ``reconcile_period``).
- ``drain_batch`` (int 0..100000; ``config/graph.yaml``: 0): with ``single_threaded``, after the message the
  executor handed over, at most this many more are taken directly, in the same callback, from *every*
  subscription (passes over them until one takes nothing; each topic's messages in their order; ``/clock``
  first in each pass, so the log time is the newest sim time), as the recorder does;
  0 = the handler is the subscription's callback (one message per callback: the ``EventsExecutor``'s way,
  where a drain would only add empty takes).
- ``host_process`` (``recorder`` | ``own``; ``config/graph.yaml``): read by the launcher (``scripts/launch --live``):
  ``recorder`` starts ``live_recorder`` (this node co-hosted in the recorder's process, fed by the recorder's
  readers: :mod:`biped_sim.live.live_recorder`) instead of ``recorder`` + ``bridge``; ``own`` this executable.
- ``reconcile_period`` (s, 0.001..10; ``config/graph.yaml``): with ``lazy_streams``, how often a steady timer
  looks at which streams the clients watch (the SDK's threads only mark a change).
- ``tcp_nodelay`` (bool; ``config/graph.yaml``: true): set ``TCP_NODELAY`` on the server's listening socket
  right after it started (accepted client sockets inherit it): the SDK leaves Nagle's algorithm on, and a frame
  then waits for the client's delayed ACK, up to 40 ms (:mod:`biped_sim.live.sockets`).
  Not found or not set: a warning, the server runs with Nagle's algorithm.

Exit status: 0 on SIGINT/SIGTERM, 2 for a bad parameter or a server that cannot start (port in use).
"""

from __future__ import annotations

import functools
import sys
import threading
import time
from typing import List, Optional

from rclpy._rclpy_pybind11 import RMWError
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message

from biped_sim.graph import names as gn
from biped_sim.live.bridge_core import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    BridgeRequestError,
    check_call,
    clock_ns,
    service_definition,
)
from biped_sim.recording.mcap_recorder import RecorderError, build_message_definition
from biped_sim.graph.params import (
    ParameterError,
    declare_executor,
    get_bool,
    get_float,
    get_int,
    get_str,
    run_node,
)
from biped_sim.graph.recorder_node import RecorderNode, recording_qos
from biped_sim.live.sockets import set_nodelay_on_port

NODE_NAME = gn.BRIDGE_NODE
SERVER_NAME = 'biped'
HOST_PROCESSES = ('recorder', 'own')   # the ``host_process`` parameter (module docstring)


class BridgeStartError(RuntimeError):
    """The WebSocket server could not start (address in use, unknown host)."""


class _Listener:
    """``foxglove.websocket.ServerListener``: called on the SDK's threads."""

    def __init__(self, node: 'BridgeNode'):
        self._node = node

    def on_subscribe(self, client, channel) -> None:
        self._node.on_client_subscribe(client.id, channel.topic)

    def on_unsubscribe(self, client, channel) -> None:
        self._node.on_client_unsubscribe(client.id, channel.topic)

    def on_client_advertise(self, client, channel) -> None:
        return None

    def on_client_unadvertise(self, client, client_channel_id) -> None:
        return None

    def on_message_data(self, client, client_channel_id, data) -> None:
        return None

    def on_get_parameters(self, client, param_names, request_id=None):
        return []

    def on_set_parameters(self, client, parameters, request_id=None):
        return parameters

    def on_parameters_subscribe(self, param_names) -> None:
        return None

    def on_parameters_unsubscribe(self, param_names) -> None:
        return None

    def on_connection_graph_subscribe(self) -> None:
        return None

    def on_connection_graph_unsubscribe(self) -> None:
        return None

    def on_playback_control_request(self, playback_control_request):
        return None


class BridgeNode(Node):
    """Subscribes raw to the graph's topics and serves them, sim time and ``/apply_push`` over a
    Foxglove WebSocket server (module docstring).

    :raises ParameterError: a parameter is invalid (nothing is started).
    :raises BridgeStartError: the server cannot bind ``host:port``.
    """

    def __init__(self, subscribe: bool = True, **kwargs) -> None:
        """``subscribe`` False: no ROS subscription at all; the messages come from :meth:`tap` (the bridge
        co-hosted in the recorder's process, :mod:`biped_sim.live.live_recorder`)."""
        super().__init__(NODE_NAME, **kwargs)
        import foxglove
        from foxglove import Channel, MessageSchema, Schema, Service, ServiceSchema
        from foxglove.websocket import Capability

        self.host = get_str(self, 'host').strip()
        if not self.host:
            raise ParameterError('host', 'must name an address to bind (empty)')
        port = get_int(self, 'port', lo=0, hi=65535)
        self.service_timeout = get_float(self, 'service_timeout', lo=0.0, lo_open=True)
        backlog = get_int(self, 'message_backlog', lo=16, hi=1_000_000)
        # true: a per-step stream is read only while a client watches it (less load on a busy machine; a
        # stream subscribed on demand starts after DDS discovery, some 0.1-0.3 s of messages later)
        self.lazy_streams = get_bool(self, 'lazy_streams')
        self.drain_batch = get_int(self, 'drain_batch', lo=0, hi=100_000)
        self.executor_kind = declare_executor(self)
        self.reconcile_period = get_float(self, 'reconcile_period', lo=0.001, hi=10.0)
        self.host_process = get_str(self, 'host_process')
        if self.host_process not in HOST_PROCESSES:
            raise ParameterError('host_process', f"must be one of {', '.join(HOST_PROCESSES)}, got {self.host_process!r}")

        self.sim_time_ns = 0
        self.clock_errors = 0
        self.counts: dict[str, int] = {}
        self._latched: dict[str, bytes] = {}      # topic -> last message of a 'latched' topic
        self._latched_topics = {t.name for t in gn.TOPICS.values() if t.qos == 'latched'}
        self._calls = 0
        self._fg_context = foxglove.Context()
        prefixes = RecorderNode._prefixes_list()

        self._channels = {}
        specs = []
        for spec in gn.TOPICS.values():
            try:
                spec.msg_class()
                definition = build_message_definition(spec.type, prefixes)
            except (ImportError, AttributeError, RecorderError) as exc:
                self.get_logger().error(f'not serving {spec.name} ({spec.type}): {exc}')
                continue
            self._channels[spec.name] = Channel(
                spec.name, schema=Schema(name=spec.type, encoding=SCHEMA_ENCODING, data=definition.encode()),
                message_encoding=MESSAGE_ENCODING, context=self._fg_context)
            specs.append(spec)

        self._srv_class = gn.message_class(gn.APPLY_PUSH_TYPE)
        srv = service_definition(gn.APPLY_PUSH_TYPE, prefixes)
        service = Service(gn.APPLY_PUSH, schema=ServiceSchema(
            srv.name,
            request=MessageSchema(encoding=MESSAGE_ENCODING, schema=Schema(
                name=srv.request_name, encoding=SCHEMA_ENCODING, data=srv.request_text.encode())),
            response=MessageSchema(encoding=MESSAGE_ENCODING, schema=Schema(
                name=srv.response_name, encoding=SCHEMA_ENCODING, data=srv.response_text.encode()))),
            handler=self._on_service_call)
        self._client = self.create_client(self._srv_class, gn.APPLY_PUSH)

        try:
            self.server = foxglove.start_server(
                name=SERVER_NAME, host=self.host, port=port, context=self._fg_context,
                capabilities=[Capability.Time, Capability.Services], supported_encodings=[MESSAGE_ENCODING],
                services=[service], server_listener=_Listener(self), message_backlog_size=backlog)
        except RuntimeError as exc:   # the SDK's FoxgloveError ("Failed to bind port: ...")
            raise BridgeStartError(f'cannot serve on {self.host}:{port}: {exc}') from exc
        self.port = self.server.port
        # Nagle's algorithm off for every client (the SDK leaves it on: frames then wait up to the client's
        # 40 ms delayed ACK; biped_sim.live.sockets)
        self.tcp_nodelay = get_bool(self, 'tcp_nodelay')
        if self.tcp_nodelay:
            report = set_nodelay_on_port(self.port)
            if report.listening == 0 or report.set < report.listening + report.connected:
                self.get_logger().warning(
                    f'tcp_nodelay: found {report.listening} listening socket(s) on port {self.port}, set '
                    f'TCP_NODELAY on {report.set}: frames may wait for the client\'s delayed ACK (up to 40 ms)')

        # subscriptions last: nothing arrives before the channels and the server exist. /clock (the server's
        # time), latched and event topics always; a per-step stream only while a client is subscribed to
        # its channel (the bridge's cost follows what the clients show: 15 topics x 1 kHz through one
        # Python process lag a real-time run by ~0.1 s)
        self._specs = {spec.name: spec for spec in specs}
        if not subscribe and self.lazy_streams:
            raise ParameterError('lazy_streams', 'must be false for a bridge in the recorder\'s process (the recorder '
                                 'reads every topic anyway)')
        self.subscribes = subscribe
        self._tap_handlers = {spec.name: self._handler(spec.name) for spec in specs}
        self._streams = {spec.name for spec in specs if self.lazy_streams and spec.qos in gn.STREAM_QOS}
        self._ros_subs: dict = {}
        self._handlers: dict = {}
        self._wanted: dict[str, int] = {}         # topic -> clients subscribed (SDK threads, under _lock)
        self._lock = threading.Lock()
        self._dirty = False                       # a client (un)subscribed to a stream since the last reconcile
        for spec in specs:
            if subscribe and spec.name not in self._streams:
                self._subscribe(spec.name)
        if self._streams:   # the EventsExecutor takes no guard condition: a steady timer looks for changes
            self._reconcile_timer = self.create_timer(
                self.reconcile_period, self._reconcile, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(
            f'serving {len(specs)} topics and {gn.APPLY_PUSH} on ws://{self.host}:{self.port} '
            f'(Foxglove: Open connection > Foxglove WebSocket)')

    # ------------------------------------------------------------------ topics
    def _on_clock(self, msg: bytes) -> None:
        try:
            t = clock_ns(msg)
        except BridgeRequestError as exc:
            self.clock_errors += 1
            if self.clock_errors == 1:
                self.get_logger().error(f'{gn.CLOCK}: cannot read the sim time ({exc}); keeping {self.sim_time_ns} ns')
        else:
            self.sim_time_ns = t
            self.server.broadcast_time(t)
        self._on_message(gn.CLOCK, msg)

    def _on_message(self, topic: str, msg: bytes) -> None:
        if topic in self._latched_topics:
            self._latched[topic] = msg
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self._channels[topic].log(msg, log_time=self.sim_time_ns)

    def tap(self, topic: str, msg: bytes) -> None:
        """A message another node of this process took (the co-hosted recorder, right after writing it): served as
        if this bridge had taken it (``/clock`` also sets the server time). A topic without a channel is ignored."""
        handler = self._tap_handlers.get(topic)
        if handler is not None:
            handler(msg)

    def _handler(self, topic: str):
        return self._on_clock if topic == gn.CLOCK else functools.partial(self._on_message, topic)

    def _on_ready(self, topic: str, msg: bytes) -> None:
        """(executor thread) The message the executor took, then up to ``drain_batch`` more already
        waiting on every subscription, taken directly (module docstring: ``drain_batch``)."""
        self._handlers[topic](msg)
        left = self.drain_batch
        while left > 0:
            taken_pass = 0
            for other, sub in list(self._ros_subs.items()):   # /clock first (subscribed first)
                handler = self._handlers[other]
                while left > 0:
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, True)
                    if taken is None:
                        break
                    handler(taken[0])
                    taken_pass += 1
                    left -= 1
            if taken_pass == 0:
                return

    def _subscribe(self, topic: str) -> None:
        spec = self._specs[topic]
        self._handlers[topic] = self._handler(topic)
        # drain_batch 0: the handler itself (one message per executor callback, the EventsExecutor's way)
        callback = functools.partial(self._on_ready, topic) if self.drain_batch else self._handlers[topic]
        self._ros_subs[topic] = self.create_subscription(spec.msg_class(), topic, callback,
                                                         recording_qos(spec.qos_profile), raw=True)

    def _reconcile(self) -> None:
        """(executor thread, every ``reconcile_period``) Subscribe to the streams some client watches, drop the
        others."""
        with self._lock:
            if not self._dirty:
                return
            self._dirty = False
            wanted = {t for t, n in self._wanted.items() if n > 0}
        for topic in sorted(self._streams):
            if topic in wanted and topic not in self._ros_subs:
                self._subscribe(topic)
            elif topic not in wanted and topic in self._ros_subs:
                self.destroy_subscription(self._ros_subs.pop(topic))

    def on_client_subscribe(self, client_id: int, topic: str) -> None:
        """(SDK thread) A client subscribed: log it; a stream is subscribed on the ROS side (on the executor's
        thread); a latched topic's last message is sent again."""
        self.get_logger().info(f'client {client_id} subscribed to {topic}')
        with self._lock:
            self._wanted[topic] = self._wanted.get(topic, 0) + 1
            self._dirty = True
        last = self._latched.get(topic)
        if last is not None:
            self._channels[topic].log(last, log_time=self.sim_time_ns)

    def on_client_unsubscribe(self, client_id: int, topic: str) -> None:
        """(SDK thread) A client unsubscribed (or left): the stream is dropped when nobody watches it."""
        self.get_logger().info(f'client {client_id} unsubscribed from {topic}')
        with self._lock:
            self._wanted[topic] = max(0, self._wanted.get(topic, 0) - 1)
            self._dirty = True

    # ------------------------------------------------------------------ /apply_push
    def _on_service_call(self, request) -> bytes:
        """(SDK thread) A Foxglove client's ``/apply_push`` call -> the ROS service -> its response.
        Raising fails the call with the exception's message (``serviceCallFailure``)."""
        self._calls += 1
        check_call(request.encoding, bytes(request.payload))
        try:
            ros_request = deserialize_message(bytes(request.payload), self._srv_class.Request)
        except RMWError as exc:
            raise BridgeRequestError(f'the payload is not a CDR {gn.APPLY_PUSH_TYPE} request: {exc}') from exc
        deadline = time.monotonic() + self.service_timeout
        if not self._client.wait_for_service(timeout_sec=self.service_timeout):
            raise BridgeRequestError(f'the ROS service {gn.APPLY_PUSH} is not available '
                                     f'(waited {self.service_timeout} s)')
        future = self._client.call_async(ros_request)
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        while not future.done() and time.monotonic() < deadline:
            done.wait(0.05)
        if not future.done():
            self._client.remove_pending_request(future)
            raise TimeoutError(f'no answer from the ROS service {gn.APPLY_PUSH} within {self.service_timeout} s')
        response = future.result()
        self.get_logger().info(
            f'Foxglove client {request.client_id}: {gn.APPLY_PUSH} force {ros_request.force} N, duration '
            f'{ros_request.duration} s -> accepted {response.accepted}: {response.message}')
        return serialize_message(response)

    # ------------------------------------------------------------------ end
    def after_spin(self, _executor, _signum) -> int:
        """Stop the server (``run_node``); exit 0."""
        self.server.stop()
        self.get_logger().info(
            f'stopped; messages served per topic: {", ".join(f"{k} {v}" for k, v in self.counts.items()) or "none"}'
            f'; {self._calls} service call(s)')
        return 0


def main(args: Optional[List[str]] = None) -> int:
    return run_node(NODE_NAME, BridgeNode, args, startup_errors=(BridgeStartError,))


if __name__ == '__main__':
    sys.exit(main())
