"""ROS layer of the recorder: subscribe raw to every topic of the graph, write a rosbag2 bag.

Node ``recorder``. Every topic of :data:`biped_sim.graph.names.TOPICS` is subscribed with
``raw=True`` (the CDR bytes are passed through, never deserialized) and with the topic's QoS.
For each message:

- ``log_time``  = the sim time of the latest ``/clock`` *published* before this message among those the recorder
  has received, looked up by DDS source timestamp (:mod:`biped_sim.recording.log_time`, ``LogTimeQueue``), so a
  ``/sim/state``'s log time is its own stamp and a controller message's the step it answers. Each topic keeps its
  order in DDS, topics among themselves need not: a message repaired after a loss (a frozen or starved recorder's
  full shared-memory queue) can arrive after many later ``/clock``; taken in order it got the newest of them (0-10
  of 928 states in 2-step real-time runs, ``lab/benchmarks/recorder_logtime.py``; 8-250 of 300 in a loaded run of the
  frozen-recorder test). A ``/clock`` can be repaired late too (1 of 300 states got the step before's in a CI run
  of that test): a message is held until a ``/clock`` published at or after it has been received, at most
  ``log_time.CLOCK_WAIT`` s of wall time, then written; the bag is written in publication order. Before the first
  ``/clock``, the node's clock (``use_sim_time`` is forced on: 0 until a ``/clock`` arrives);
- ``publish_time`` = the source timestamp DDS hands over in the message info.

Parameters (``recorder: {ros__parameters: {...}}``), validated at start; a bad one makes
``main()`` exit with status 2 and a message naming it:

- ``output_dir``  (string, required): the bag directory; must not exist, or be empty.
- ``compression`` (string, ``zstd`` | ``lz4`` | ``none``; default ``zstd``): MCAP chunk compression.
- ``chunk_size``  (int bytes, 4096 .. 1073741824; default 262144): uncompressed chunk size, which
  also bounds what a SIGKILL loses.
- ``chunk_time``  (float s, 0 or 0.001 .. 3600; 0 = by size only; default: ``config/graph.yaml``): a chunk is also written out once its
  first message is this old (wall clock; checked at each message and by a steady timer every
  ``chunk_time`` / 2), so a SIGKILL loses at most about ``chunk_time`` s of messages (plus what DDS still
  held for the recorder). ``config/graph.yaml`` sets it.
- ``sync``        (bool; default: ``config/graph.yaml``): ``fdatasync`` each chunk (a power cut then loses at most the chunk
  being built; without it, what the kernel had not written back yet too).
- ``batch_wait``  (float s, 0 .. 0.1; default: ``config/graph.yaml``): after each executor callback (the message
  and what waited on every subscription) the recorder's thread sleeps this long, so a real-time graph's
  messages are taken in batches of a step or more instead of one rclpy wait-set round (Python: every
  subscription, task, callback; ~0.1-0.3 ms of CPU) for every few messages (one round per
  message took 97 % of the recorder's thread at real time). It adds at most ``batch_wait`` to a message's time in the
  recorder's DDS queue (deep enough: ``STREAM_DEPTH``) and to what a SIGKILL loses. 0 = no wait.
- ``executor`` (``wait_set`` | ``single_threaded``; default: ``config/graph.yaml``): how the recorder's thread
  waits for messages. ``single_threaded``: rclpy's Python ``SingleThreadedExecutor`` (each round rebuilds a wait
  set over every entity of the node in Python, then one callback takes what waits on every subscription).
  ``wait_set``: one rcl wait set over the subscriptions, built once and refilled each wake-up (rcl clears the
  entries that were not ready), then only the *ready* subscriptions are read with raw takes (message and info),
  the batch is recorded in publication order as above; every ``SERVICE_PERIOD`` s one non-blocking executor
  round serves the rest (the chunk timer, parameter services; the co-hosted bridge's service client). The
  ``EventsExecutor`` cannot be used: it fails for raw subscriptions whose callback takes the message info.

The bag is finished cleanly on SIGINT and SIGTERM (own handlers stop the spin loop, then
``finish()`` runs) and when the ROS context is shut down by anything else.
Exit status: 0 clean finish, 1 I/O error while recording, 2 bad parameter / cannot create the bag.
"""

from __future__ import annotations

import functools
import time
import sys
from pathlib import Path
from typing import Dict, List, Optional

import rclpy
from rclpy.callback_groups import CallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, ReliabilityPolicy

from biped_sim.graph.sim_clock import SimClock
from biped_sim.graph import names as graph_names
from biped_sim.graph.params import ParameterError, graph_default, run_node
from biped_sim.recording.log_time import LogTimeQueue
from biped_sim.recording.mcap_recorder import (
    DEFAULT_CHUNK_SIZE,
    INFINITE_DURATION,
    QosProfile,
    RecorderError,
    Rosbag2McapWriter,
    build_message_definition,
    prefixes_from_env,
)

COMPRESSIONS = ("zstd", "lz4", "none")
MIN_CHUNK_SIZE = 4096
MAX_CHUNK_SIZE = 1 << 30
MIN_CHUNK_TIME = 0.001   # s: below, a chunk per message or two (the index would outweigh the data)
MAX_CHUNK_TIME = 3600.0
MAX_BATCH_WAIT = 0.1     # s: above, the wait would rival chunk_time in what a SIGKILL loses


def _policy_name(value, table: Dict[object, str]) -> str:
    return table.get(value, "unknown")


_HISTORY = {HistoryPolicy.KEEP_LAST: "keep_last", HistoryPolicy.KEEP_ALL: "keep_all",
            HistoryPolicy.SYSTEM_DEFAULT: "system_default"}
_RELIABILITY = {ReliabilityPolicy.RELIABLE: "reliable",
                ReliabilityPolicy.BEST_EFFORT: "best_effort",
                ReliabilityPolicy.SYSTEM_DEFAULT: "system_default"}
_DURABILITY = {DurabilityPolicy.VOLATILE: "volatile",
               DurabilityPolicy.TRANSIENT_LOCAL: "transient_local",
               DurabilityPolicy.SYSTEM_DEFAULT: "system_default"}
_LIVELINESS = {LivelinessPolicy.AUTOMATIC: "automatic",
               LivelinessPolicy.MANUAL_BY_TOPIC: "manual_by_topic",
               LivelinessPolicy.SYSTEM_DEFAULT: "system_default"}


def _duration(d) -> tuple:
    ns = d.nanoseconds
    if ns >= INFINITE_DURATION[0] * 10**9:  # rclpy's "infinite"
        return INFINITE_DURATION
    return (ns // 10**9, ns % 10**9)


RECORDING_DEPTH = 5000  # the recorder's own queue: it must never drop a message while it lags


def recording_qos(profile):
    """The topic's QoS (reliability, durability: so it matches the publisher and gets latched
    messages) with a keep-last history of at least RECORDING_DEPTH: a latched topic's depth 1 is
    right for its late joiners but would make a lagging recorder lose messages."""
    from rclpy.qos import QoSProfile
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(int(profile.depth), RECORDING_DEPTH),
                      reliability=profile.reliability, durability=profile.durability,
                      liveliness=profile.liveliness)


def qos_from_rclpy(profile) -> QosProfile:
    """An ``rclpy.qos.QoSProfile`` (e.g. a publisher's offered profile) in rosbag2 terms."""
    return QosProfile(
        history=_policy_name(profile.history, _HISTORY),
        depth=int(profile.depth),
        reliability=_policy_name(profile.reliability, _RELIABILITY),
        durability=_policy_name(profile.durability, _DURABILITY),
        deadline=_duration(profile.deadline),
        lifespan=_duration(profile.lifespan),
        liveliness=_policy_name(profile.liveliness, _LIVELINESS),
        liveliness_lease_duration=_duration(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


PLANT_METADATA = "biped_plant"   # MCAP metadata record: {"yaml": the /sim/plant text} (the true plant)
CONTROLLER_METADATA = "biped_controller"   # MCAP metadata record: {"yaml": the /controller/info text}
DRAIN_BATCH = 256  # messages taken at most per executor callback, from every subscription (see _on_message)
DRAIN_PER_TOPIC = 16  # messages taken at most from one subscription per pass (no topic starves another)
DRAIN_IDLE = 0.3   # s without a new message before the bag is finished after a stop request (publishers left)
DRAIN_MAX = 25.0   # s, upper bound of the drain (below the launcher's recorder stop timeout, 30 s)
RECORDER_LOOPS = ("wait_set", "single_threaded")   # the ``executor`` parameter (module docstring)
SERVICE_PERIOD = 0.1    # s between the wait-set loop's executor rounds (parameter services; the co-hosted bridge's
                        # /apply_push answers, late by at most this): each round rebuilds rclpy's wait set over every
                        # entity (at 0.02 s, 13 % of the co-hosted recorder's thread, py-spy). The chunk age is
                        # checked by the loop itself after every wait (at most WAIT_SLICE apart)
WAIT_SLICE = 0.02       # s the wait set waits at most (then run_node looks at its stop conditions)


class _LoopOnly(CallbackGroup):
    """A callback group no executor runs (``can_execute`` false: rclpy's executors leave its entities out of their
    wait sets): the recorder's subscriptions under ``executor: wait_set``, read by its own loop only."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        return None


class RecorderNode(Node):
    """Thin ROS wrapper around :class:`Rosbag2McapWriter`.

    :raises ParameterError: if a parameter is invalid (before any file is created).
    :raises RecorderError: if the bag cannot be created.
    """

    def __init__(self, **kwargs) -> None:
        overrides = list(kwargs.pop("parameter_overrides", []))
        # The recorder's log time is sim time by design: force use_sim_time on.
        overrides = [p for p in overrides if p.name != "use_sim_time"]
        overrides.append(Parameter("use_sim_time", Parameter.Type.BOOL, True))
        super().__init__(graph_names.RECORDER_NODE, parameter_overrides=overrides, **kwargs)
        # the node's clock follows the /clock it records (no second /clock reader: graph.sim_clock)
        self.sim_clock = SimClock(self)
        self.declare_parameter("output_dir", "")
        self.declare_parameter("compression", "zstd")
        self.declare_parameter("chunk_size", DEFAULT_CHUNK_SIZE)
        self.declare_parameter("chunk_time", float(graph_default(graph_names.RECORDER_NODE, "chunk_time")))
        self.declare_parameter("sync", bool(graph_default(graph_names.RECORDER_NODE, "sync")))
        # dynamic typing: a value of the wrong type is named by _read_parameters (exit 2), not refused by rclpy
        self.declare_parameter("batch_wait", float(graph_default(graph_names.RECORDER_NODE, "batch_wait")),
                               ParameterDescriptor(name="batch_wait", dynamic_typing=True))
        self.declare_parameter("executor", str(graph_default(graph_names.RECORDER_NODE, "executor")),
                               ParameterDescriptor(name="executor", dynamic_typing=True))
        output_dir, compression, chunk_size, chunk_time, sync, self.batch_wait = self._read_parameters()
        self.loop = self.get_parameter("executor").value
        if self.loop not in RECORDER_LOOPS:
            raise ParameterError("executor", f"must be one of {', '.join(RECORDER_LOOPS)}; got {self.loop!r}")
        # observers of every message the recorder takes, called (topic, CDR bytes) in the recorder's thread in
        # the order it records them, each batch just before it is written (the co-hosted live view,
        # biped_sim.live.live_recorder)
        self.taps: List = []
        self.wakeups = 0   # wait-set wake-ups that found a message (logged at the end: messages per wake-up)

        self.failure: Optional[RecorderError] = None
        # the log time of each message taken, held until it is known (biped_sim.recording.log_time)
        self._log_times = LogTimeQueue()
        self.taken = 0   # messages taken from DDS (written or held)
        self.done = False   # run_node leaves its loop (then drains and finishes) once set
        self._prefixes = self._prefixes_list()
        self._specs = self._recordable_topics()
        self._writer = Rosbag2McapWriter(output_dir, prefixes=self._prefixes,
                                         compression=compression, chunk_size=chunk_size,
                                         chunk_time=chunk_time or None, sync=sync)
        if chunk_time:   # a steady timer (the node's own clock is sim time): closes a quiet graph's chunk too
            self._chunk_timer = self.create_timer(chunk_time / 2, self._poll_chunk,
                                                  clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._subscriptions_by_topic = {}
        # wait_set: the subscriptions are the loop's alone; the executor's rounds serve the rest (parameter
        # services, the co-hosted bridge's /apply_push client). Seen by the executor, a busy graph's always-ready
        # subscriptions came first in every round (rclpy serves subscriptions before clients) and a Foxglove push
        # call's answer waited 1.7 s (tests/test_bridge.py's live test, once).
        group = _LoopOnly() if self.loop == "wait_set" else None
        for spec in self._specs:
            callback = functools.partial(self._on_message, spec)
            self._subscriptions_by_topic[spec.name] = self.create_subscription(
                spec.msg_class(), spec.name, callback, recording_qos(spec.qos_profile), raw=True,
                callback_group=group)
        self.get_logger().info(
            f"recording {len(self._specs)} topics to {self._writer.bag_dir} "
            f"({compression}, chunks of {chunk_size} B"
            f"{f' or {chunk_time} s' if chunk_time else ''}{', synced' if sync else ''})")

    # -- parameters ----------------------------------------------------------------------------

    def _read_parameters(self):
        def value(name, expected_type):
            param = self.get_parameter(name)
            if param.type_ != expected_type:
                raise ParameterError(
                    name, f"expected {expected_type.name.lower()}, got {param.type_.name.lower()}")
            return param.value

        output_dir = value("output_dir", Parameter.Type.STRING).strip()
        if not output_dir:
            raise ParameterError("output_dir", "must name the bag directory (empty)")
        compression = value("compression", Parameter.Type.STRING)
        if compression not in COMPRESSIONS:
            raise ParameterError("compression",
                                 f"must be one of {', '.join(COMPRESSIONS)}; got {compression!r}")
        chunk_size = value("chunk_size", Parameter.Type.INTEGER)
        if not MIN_CHUNK_SIZE <= chunk_size <= MAX_CHUNK_SIZE:
            raise ParameterError(
                "chunk_size",
                f"must be in [{MIN_CHUNK_SIZE}, {MAX_CHUNK_SIZE}] bytes; got {chunk_size}")
        raw = self.get_parameter("chunk_time")
        if raw.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER):
            raise ParameterError("chunk_time", f"expected a number of seconds, got {raw.type_.name.lower()}")
        chunk_time = float(raw.value)
        if not (chunk_time == 0.0 or MIN_CHUNK_TIME <= chunk_time <= MAX_CHUNK_TIME):
            raise ParameterError(
                "chunk_time", f"must be 0 (by size only) or in [{MIN_CHUNK_TIME}, {MAX_CHUNK_TIME}] s; got {chunk_time}")
        sync = value("sync", Parameter.Type.BOOL)
        raw = self.get_parameter("batch_wait")
        if raw.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER):
            raise ParameterError("batch_wait", f"expected a number of seconds, got {raw.type_.name.lower()}")
        batch_wait = float(raw.value)
        if not 0.0 <= batch_wait <= MAX_BATCH_WAIT:
            raise ParameterError("batch_wait", f"must be in [0, {MAX_BATCH_WAIT}] s; got {batch_wait}")
        return output_dir, compression, chunk_size, chunk_time, sync, batch_wait

    @staticmethod
    def _prefixes_list() -> List[Path]:
        prefixes = prefixes_from_env()
        if Path(sys.prefix) not in prefixes:
            prefixes.append(Path(sys.prefix))  # the venv holds the wheels' share/ directories
        return prefixes

    def _recordable_topics(self) -> list:
        """Topics of the graph whose type imports and whose definition is installed."""
        specs = []
        for spec in graph_names.TOPICS.values():
            try:
                spec.msg_class()
                build_message_definition(spec.type, self._prefixes)
            except (ImportError, AttributeError, RecorderError) as exc:
                self.get_logger().error(f"not recording {spec.name} ({spec.type}): {exc}")
                continue
            specs.append(spec)
        return specs

    # -- recording -----------------------------------------------------------------------------

    def _offered_profiles(self, spec) -> List[QosProfile]:
        infos = self.get_publishers_info_by_topic(spec.name)
        profiles = [qos_from_rclpy(info.qos_profile) for info in infos]
        if profiles:
            return profiles
        d = spec.qos_dict
        return [QosProfile(history=d["history"], depth=d["depth"], reliability=d["reliability"],
                           durability=d["durability"])]

    def _on_message(self, spec, msg: bytes, info) -> None:
        """One message from the executor, then what is already waiting on *every* subscription, taken
        directly (:meth:`_take_waiting`, at most DRAIN_BATCH), all recorded in the order they were published.
        The executor's round per message (Python wait set over every subscription, task, callback) costs more
        than writing the message: at 1 kHz x 15 topics, taking only the subscription that fired left the
        recorder ~0.3-0.5 s behind a real-time graph on a loaded 2-core machine, and what DDS still
        holds for the recorder dies with it on SIGKILL. Then the thread sleeps ``batch_wait`` s, so that the
        next round finds a control step's messages (and more) waiting instead of waking for each (module
        docstring)."""
        self._take_waiting(DRAIN_BATCH, first=(spec, msg, info))
        if self.batch_wait > 0.0:
            time.sleep(self.batch_wait)

    def spinner(self, executor):
        """``run_node``'s slice of spinning: with ``executor: single_threaded`` one ``spin_once`` of the executor
        (at most ``SPIN_SLICE`` s); with ``wait_set`` :meth:`_wait_and_take` over a wait set built once
        (module docstring), plus one non-blocking executor round every ``SERVICE_PERIOD`` s."""
        from biped_sim.graph.params import SPIN_SLICE
        if self.loop == "single_threaded":
            def spin_executor() -> None:
                executor.spin_once(timeout_sec=SPIN_SLICE)
                if self.failure is None and not self._writer.finished:
                    self._release_held(time.monotonic())
            return spin_executor
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        subs = [(spec, self._subscriptions_by_topic[spec.name]) for spec in self._specs
                if spec.name in self._subscriptions_by_topic]
        handles = [sub.handle for _spec, sub in subs]
        by_pointer = {sub.handle.pointer: (spec, sub) for spec, sub in subs}
        wait_set = _rclpy.WaitSet(len(handles), 0, 0, 0, 0, 0, self.context.handle)
        timeout_ns = int(WAIT_SLICE * 1e9)
        next_round = [time.monotonic()]

        def spin() -> None:
            self._wait_and_take(wait_set, handles, by_pointer, timeout_ns)
            self._poll_chunk()
            now = time.monotonic()
            if now >= next_round[0]:
                next_round[0] = now + SERVICE_PERIOD
                executor.spin_once(timeout_sec=0.0)
        return spin

    def _wait_and_take(self, wait_set, handles, by_pointer, timeout_ns: int) -> int:
        """Wait (at most ``timeout_ns``) until a subscription has a message, then take what waits on the ready
        ones (:meth:`_take_waiting`) and record it in publication order. rcl leaves only the ready entries in
        the set after a wait, so it is cleared and refilled each time (the C wait set itself is kept).
        Returns how many messages were taken."""
        wait_set.clear_entities()
        for handle in handles:
            wait_set.add_subscription(handle)
        wait_set.wait(timeout_ns)
        ready = wait_set.get_ready_entities("subscription")
        if not ready:
            return 0
        self.wakeups += 1
        taken = self._take_waiting(DRAIN_BATCH, subs=[by_pointer[p] for p in ready if p in by_pointer])
        if self.batch_wait > 0.0:
            time.sleep(self.batch_wait)
        return taken

    def _take_waiting(self, budget: int, first=None, subs=None) -> int:
        """Take what waits in the subscriptions' DDS queues, in passes over every subscription with at most
        DRAIN_PER_TOPIC from each per pass (each topic's messages in their order; a lagging recorder's
        backlog on the first topics never starves the later ones: a pass that took everything of /clock
        before looking at /push_events left the later topics' tail unrecorded when the drain ended), until
        a pass takes nothing or ``budget`` messages are taken; then record them (with ``first``, a message the
        executor already took) sorted by their DDS source timestamp, so that each message's log time is the
        latest ``/clock`` published before it whichever topic was read first (with ``batch_wait`` a batch
        holds a step or more: read topic by topic, 707 of 928 ``/sim/state`` of a real-time run got the next
        step's ``/clock`` as log time). ``subs``: only these (spec, subscription) pairs (the ready ones of the
        wait-set loop); default every subscription. Returns how many were taken (``first`` not counted)."""
        batch = [] if first is None else [first]
        taken_total = 0
        if subs is None:
            subs = [(spec, self._subscriptions_by_topic.get(spec.name)) for spec in self._specs]
        while taken_total < budget:
            taken_pass = 0
            for other, sub in subs:
                taken_topic = 0
                while sub is not None and taken_topic < DRAIN_PER_TOPIC and taken_total < budget:
                    if self.failure is not None or self._writer.finished:
                        break
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, True)
                    if taken is None:
                        break
                    batch.append((other, taken[0], taken[1]))
                    taken_topic += 1
                    taken_total += 1
                taken_pass += taken_topic
            if taken_pass == 0:
                break
        # stable sort: equal timestamps (or none) keep the order they were taken in
        batch.sort(key=lambda item: int(item[2]["source_timestamp"]) if item[2] else 0)
        if self.taps and self.failure is None and not self._writer.finished:
            # the batch to the observers first (the co-hosted live view), then to the bag: a chunk compressed
            # and written while recording this batch does not delay its frames
            for spec, msg, _info in batch:
                for tap in self.taps:
                    tap(spec.name, msg)
        now = time.monotonic()
        for spec, msg, info in batch:
            clock_ns = self._clock_of(msg) if spec.name == graph_names.CLOCK else None
            source_ns = int(info["source_timestamp"]) if info else 0
            self._log_times.push(now, (spec, msg, info), source_ns, clock_ns)
        self.taken += len(batch)
        self._release_held(now)
        return taken_total

    def _clock_of(self, msg: bytes) -> int:
        """A ``/clock`` taken: its sim time [ns], which the node's clock follows from now on."""
        from rosgraph_msgs.msg import Clock
        clock = deserialize_message(msg, Clock).clock
        sim_ns = clock.sec * 1_000_000_000 + clock.nanosec
        self.sim_clock.set(sim_ns)
        return sim_ns

    def _release_held(self, now: float, flush: bool = False) -> None:
        """Write the messages whose log time is known or whose wait is over (all with ``flush``: the bag is being
        finished), in the order taken (``LogTimeQueue.release``)."""
        for (spec, msg, info), log_time in self._log_times.release(now, flush):
            self._record(spec, msg, info, log_time)

    def _publishers_left(self) -> int:
        """Publishers the graph still has on the recorded topics (0 once every other node has exited)."""
        return sum(self.count_publishers(spec.name) for spec in self._specs)

    def _record(self, spec, msg: bytes, info, log_time: Optional[int]) -> None:
        """Write one message at ``log_time`` [ns of sim time] (None: the node's clock, before any ``/clock``)."""
        if self.failure is not None or self._writer.finished:
            return
        publish_time = int(info["source_timestamp"]) if info else 0
        if log_time is None:
            log_time = self.get_clock().now().nanoseconds
        try:
            if not self._writer.has_topic(spec.name):
                self._writer.register_topic(spec.name, spec.type, self._offered_profiles(spec))
            self._writer.write(spec.name, spec.type, msg, log_time, publish_time)
            if spec.name == graph_names.SIM_PLANT:
                # the plant's true parameters (biped_sim.plant.perturbation) also as the bag's metadata
                # record 'biped_plant'
                from std_msgs.msg import String
                self._writer.add_metadata(PLANT_METADATA, {"yaml": deserialize_message(msg, String).data})
            elif spec.name == graph_names.CONTROLLER_INFO:
                # the run's controller, its options and its files' hashes, also as the record 'biped_controller'
                from std_msgs.msg import String
                self._writer.add_metadata(CONTROLLER_METADATA, {"yaml": deserialize_message(msg, String).data})
        except RecorderError as exc:
            self.failure = exc
            self.get_logger().error(f"recording stopped: {exc}")
            self.done = True

    def _poll_chunk(self) -> None:
        """(steady timer; the wait-set loop after every wait) Write the held messages whose wait is over, and the
        open chunk out once it is ``chunk_time`` old."""
        if self.failure is not None or self._writer.finished:
            return
        self._release_held(time.monotonic())
        try:
            self._writer.poll()
        except RecorderError as exc:
            self.failure = exc
            self.get_logger().error(f"recording stopped: {exc}")
            self.done = True

    @property
    def counts(self) -> Dict[str, int]:
        return self._writer.counts

    def finish(self):
        """Write what is held, then finish the bag (idempotent); returns its :class:`BagSummary`."""
        self._release_held(time.monotonic(), flush=True)
        summary = self._writer.finish()
        self.get_logger().info(
            f"bag {summary.bag_dir}: {summary.message_count} messages "
            f"({', '.join(f'{k} {v}' for k, v in summary.counts.items()) or 'none'})")
        return summary


    def after_spin(self, executor, _signum) -> int:
        """Drain, then finish the bag (``run_node``): a stop request can arrive while messages are still
        queued (the recorder may lag the 1 kHz lockstep on a loaded machine). Take what waits (fairly over
        the topics) until the queues are empty and either no publisher is left on the recorded topics (the
        launcher stops the recorder last, after every other node has had its messages acknowledged: then
        the queues hold everything there will ever be) or nothing new has arrived for DRAIN_IDLE s (a
        recorder stopped while the graph runs on); at most DRAIN_MAX s. Exit 1 if finishing failed."""
        status = 0
        t0 = time.monotonic()
        drained, why = 0, f"time limit {DRAIN_MAX} s"
        try:
            t_end = t0 + DRAIN_MAX
            last_change = time.monotonic()
            while rclpy.ok(context=self.context) and time.monotonic() < t_end and self.failure is None:
                taken = self._take_waiting(DRAIN_BATCH)
                drained += taken
                now = time.monotonic()
                if taken:
                    last_change = now
                    continue
                if self._publishers_left() == 0:
                    why = "queues empty, no publisher left"
                    break
                if now - last_change >= DRAIN_IDLE:
                    why = f"queues empty, nothing new for {DRAIN_IDLE} s"
                    break
                before = self.taken
                executor.spin_once(timeout_sec=0.02)   # timers; a new message wakes it (and is recorded)
                if self.taken != before:
                    drained += self.taken - before
                    last_change = time.monotonic()
        except ExternalShutdownException:
            why = "context shut down"   # finish the bag below
        finally:
            executor.remove_node(self)
            self.get_logger().info(f"drained {drained} messages in {time.monotonic() - t0:.2f} s ({why})")
            if self.loop == "wait_set":
                n = sum(self.counts.values())
                self.get_logger().info(f"wait set: {self.wakeups} wake-ups with messages, "
                                       f"{n / max(self.wakeups, 1):.2f} messages per wake-up")
            try:
                self.finish()
            except RecorderError as exc:
                print(f"recorder: finishing the bag failed: {exc}", file=sys.stderr)
                status = 1
        if self.failure is not None:
            print(f"recorder: {self.failure}", file=sys.stderr)
            status = 1
        return status


def main(args: Optional[List[str]] = None) -> int:
    return run_node("recorder", RecorderNode, args, startup_errors=(RecorderError,))


if __name__ == "__main__":
    sys.exit(main())
