"""The Foxglove WebSocket bridge (biped_sim.live.bridge_node, biped_sim.live.bridge_core).

Pure core: schema texts against the MCAP writer's and rosidl's generated classes, /clock decoding
and service-call checks against rclpy's own CDR serializer.

Over real sockets (127.0.0.1, a free port; DDS in the isolated domain of the ``ros_domain``
fixture): a Foxglove protocol client written here (``websockets``; subprotocol ``foxglove.sdk.v1``,
JSON control messages, binary frames: 0x01 message data ``u32 subscription, u64 log time, CDR``,
0x02 time ``u64``, 0x03 service response ``u32 service, u32 call, u32 len, encoding, CDR``; client
binary 0x02 service call with the same layout) against the bridge alone and against the whole graph
started by ``biped_sim.graph.launch --live``. Every wait is bounded; nothing measures wall time.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import random
import signal
import socket
import struct
import subprocess
import threading
import time
from collections import defaultdict
from pathlib import Path

import pytest

from helpers import ROOT  # noqa: F401  (puts the project's packages on sys.path when not installed)

PY = ROOT / '.venv' / 'bin' / 'python'
SUBPROTOCOL = 'foxglove.sdk.v1'


# ------------------------------------------------------------------------------------------ pure core
def _prefixes():
    from biped_sim.graph.recorder_node import RecorderNode
    return RecorderNode._prefixes_list()


def test_flatten_matches_the_mcap_writer_for_every_topic_type():
    from biped_sim.live import bridge_core as bc
    from biped_sim.graph import names as gn
    from biped_sim.recording.mcap_recorder import build_message_definition
    prefixes = _prefixes()
    with_deps = 0
    for spec in gn.TOPICS.values():
        pkg, _, name = spec.type.split('/')
        text = bc._read_msg(pkg, name, prefixes)
        flat = bc.flatten_definition(text, pkg, prefixes)
        assert flat == build_message_definition(spec.type, prefixes), spec.type
        with_deps += 'MSG: ' in flat
    assert with_deps >= 5   # the comparison covers dependencies (Header, Time, Transform, ...)


def test_flatten_writes_each_dependency_once_depth_first(tmp_path):
    """A synthetic package: A uses B and C, both use D; B also uses pkg/msg/E of another package."""
    from biped_sim.live import bridge_core as bc
    from biped_sim.recording.mcap_recorder import SEPARATOR, RecorderError, build_message_definition
    share = tmp_path / 'share'
    files = {('p', 'A'): 'p/B b\nC[] c\nint32 x  # comment C\n', ('p', 'B'): 'D d\nq/E e\n',
             ('p', 'C'): 'D[<=3] d\nstring<=5 s\n', ('p', 'D'): 'float64 v\nuint8 K=3\n', ('q', 'E'): 'bool f\n'}
    for (pkg, name), text in files.items():
        (share / pkg / 'msg').mkdir(parents=True, exist_ok=True)
        (share / pkg / 'msg' / f'{name}.msg').write_text(text)
    flat = bc.flatten_definition(files[('p', 'A')], 'p', [tmp_path])
    sep = f'\n{SEPARATOR}\nMSG: '
    assert flat == (files[('p', 'A')] + sep + 'p/B\n' + files[('p', 'B')] + sep + 'p/D\n' + files[('p', 'D')]
                    + sep + 'q/E\n' + files[('q', 'E')] + sep + 'p/C\n' + files[('p', 'C')])
    assert flat == build_message_definition('p/msg/A', [tmp_path])
    with pytest.raises(RecorderError, match='p/msg/Z.msg'):
        bc.flatten_definition('Z z\n', 'p', [tmp_path])


def test_service_definition_of_apply_push_has_the_generated_fields():
    """Request/response texts: their field names are those of rosidl's generated classes."""
    from biped_sim.live import bridge_core as bc
    from biped_msgs_py.srv import ApplyPush
    d = bc.service_definition('biped_msgs_py/srv/ApplyPush', _prefixes())
    assert (d.request_name, d.response_name) == ('biped_msgs_py/srv/ApplyPush_Request',
                                                 'biped_msgs_py/srv/ApplyPush_Response')

    def names(text):
        return [ln.split('#')[0].split()[1] for ln in text.splitlines() if ln.split('#')[0].strip()]
    assert names(d.request_text) == list(ApplyPush.Request.get_fields_and_field_types())
    assert names(d.response_text) == list(ApplyPush.Response.get_fields_and_field_types())
    assert '---' not in d.request_text + d.response_text


def test_split_service_text_and_bad_names(tmp_path):
    from biped_sim.live import bridge_core as bc
    from biped_sim.recording.mcap_recorder import RecorderError
    assert bc.split_service_text('int32 a\n---\nint32 b\n') == ('int32 a', 'int32 b\n')
    assert bc.split_service_text('---\n') == ('', '')
    for bad in ('int32 a\n', 'int32 a\n---\n---\n'):
        with pytest.raises(bc.BridgeRequestError, match='---'):
            bc.split_service_text(bad)
    with pytest.raises(bc.BridgeRequestError, match='pkg/srv/Type'):
        bc.service_definition('biped_msgs_py/msg/ApplyPush', _prefixes())
    with pytest.raises(RecorderError, match='nopkg/srv/X.srv'):
        bc.service_definition('nopkg/srv/X', [tmp_path])


def test_clock_ns_against_rclpy_serialization():
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from builtin_interfaces.msg import Time
    from biped_sim.live import bridge_core as bc
    rng = random.Random(15)
    cases = [(0, 0), (0, 999_999_999), (2**31 - 1, 999_999_999), (-5, 1)]
    cases += [(rng.randrange(-2**31, 2**31), rng.randrange(10**9)) for _ in range(200)]
    for sec, nsec in cases:
        data = serialize_message(Clock(clock=Time(sec=sec, nanosec=nsec)))
        assert bc.clock_ns(data) == sec * 10**9 + nsec
        # the same value written big endian
        assert bc.clock_ns(b'\x00\x00\x00\x00' + struct.pack('>iI', sec, nsec)) == sec * 10**9 + nsec
    for bad, what in ((b'', 'header'), (b'\x00\x01\x00', 'header'), (b'\x00\x01\x00\x00\x01', 'Clock'),
                      (b'\x00\x03\x00\x00' + bytes(8), 'representation'),
                      (b'\x00\x01\x00\x00' + struct.pack('<iI', 1, 10**9), 'nanosec')):
        with pytest.raises(bc.BridgeRequestError, match=what):
            bc.clock_ns(bad)


def test_check_call():
    from rclpy.serialization import serialize_message
    from biped_msgs_py.srv import ApplyPush
    from biped_sim.live import bridge_core as bc
    good = serialize_message(ApplyPush.Request(force=1.0, duration=0.1))
    bc.check_call('cdr', good)
    for enc, payload, what in (('json', good, 'encoding'), ('cdr', good[:3], 'header'),
                               ('cdr', b'\x00\x07' + good[2:], 'representation'), ('', good, 'encoding')):
        with pytest.raises(bc.BridgeRequestError, match=what):
            bc.check_call(enc, payload)


# ------------------------------------------------------------------------------------------ client
class FoxgloveClient:
    """A minimal Foxglove WebSocket protocol client (what the tests need of it)."""

    def __init__(self, ws):
        self.ws = ws
        self.server_info = None
        self.channels: dict[str, dict] = {}         # topic -> advertised channel
        self.services: dict[str, dict] = {}         # name -> advertised service
        self.topic_of_sub: dict[int, str] = {}
        self.messages: dict[str, list] = defaultdict(list)   # topic -> [(log_time, payload)]
        self.times: list[int] = []
        self.responses: dict[int, tuple] = {}       # call id -> (service id, encoding, payload)
        self.failures: dict[int, str] = {}          # call id -> message
        self.status: list[dict] = []
        self.closed = False
        self._next_sub = 1
        self._next_call = 1

    @classmethod
    async def connect(cls, url: str) -> 'FoxgloveClient':
        import websockets
        ws = await websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=30)
        assert ws.subprotocol == SUBPROTOCOL
        return cls(ws)

    def _handle(self, frame) -> None:
        if isinstance(frame, str):
            msg = json.loads(frame)
            op = msg['op']
            if op == 'serverInfo':
                self.server_info = msg
            elif op == 'advertise':
                self.channels.update({c['topic']: c for c in msg['channels']})
            elif op == 'advertiseServices':
                self.services.update({s['name']: s for s in msg['services']})
            elif op == 'serviceCallFailure':
                self.failures[msg['callId']] = msg['message']
            elif op == 'status':
                self.status.append(msg)
            return
        op = frame[0]
        if op == 0x01:
            sub, log_time = struct.unpack_from('<IQ', frame, 1)
            self.messages[self.topic_of_sub[sub]].append((log_time, bytes(frame[13:])))
        elif op == 0x02:
            self.times.append(struct.unpack_from('<Q', frame, 1)[0])
        elif op == 0x03:
            service, call, n = struct.unpack_from('<III', frame, 1)
            self.responses[call] = (service, bytes(frame[13:13 + n]).decode(), bytes(frame[13 + n:]))

    async def pump(self, until, timeout: float) -> bool:
        """Handle frames until ``until()`` holds (True), the server closes (``closed``) or ``timeout``."""
        import websockets
        deadline = time.monotonic() + timeout
        while not until():
            left = deadline - time.monotonic()
            if left <= 0 or self.closed:
                return False
            try:
                frame = await asyncio.wait_for(self.ws.recv(), timeout=min(left, 1.0))
            except asyncio.TimeoutError:
                continue
            except websockets.ConnectionClosed:
                self.closed = True
                return until()
            self._handle(frame)
        return True

    async def subscribe(self, topics) -> None:
        subs = []
        for t in topics:
            self.topic_of_sub[self._next_sub] = t
            subs.append({'id': self._next_sub, 'channelId': self.channels[t]['id']})
            self._next_sub += 1
        await self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))

    async def unsubscribe(self, topics) -> None:
        ids = [sid for sid, topic in self.topic_of_sub.items() if topic in topics]
        await self.ws.send(json.dumps({'op': 'unsubscribe', 'subscriptionIds': ids}))

    async def send_call(self, service: str, payload: bytes, encoding: str = 'cdr', service_id=None) -> int:
        call = self._next_call
        self._next_call += 1
        sid = self.services[service]['id'] if service_id is None else service_id
        enc = encoding.encode()
        await self.ws.send(bytes([0x02]) + struct.pack('<III', sid, call, len(enc)) + enc + payload)
        return call

    async def call(self, service: str, payload: bytes, encoding: str = 'cdr', timeout: float = 60.0):
        """(response payload or None, failure message or None)."""
        call = await self.send_call(service, payload, encoding)
        await self.pump(lambda: call in self.responses or call in self.failures, timeout)
        assert call in self.responses or call in self.failures, f'no answer to call {call} on {service}'
        return (self.responses[call][2] if call in self.responses else None), self.failures.get(call)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _bridge_exe() -> str:
    from biped_sim.graph.launch import find_executable
    return str(find_executable('biped_sim', 'bridge'))


def _push_request(force, duration, start, height=math.nan) -> bytes:
    from rclpy.serialization import serialize_message
    from biped_msgs_py.srv import ApplyPush
    return serialize_message(ApplyPush.Request(force=float(force), duration=float(duration), start=float(start),
                                               use_delay=False, delay=0.0, height=float(height)))


def _response(payload: bytes):
    from rclpy.serialization import deserialize_message
    from biped_msgs_py.srv import ApplyPush
    return deserialize_message(payload, ApplyPush.Response)


async def _garbage(url: str, service_id: int) -> dict:
    """A client that sends every kind of bad input, then drops the TCP connection without a close
    frame. Returns the failures and status messages it got back."""
    c = await FoxgloveClient.connect(url)
    await c.pump(lambda: c.server_info is not None and c.services, 30)
    short_cdr = b'\x00\x01\x00\x00' + b'\x01\x02\x03'
    calls = {'json encoding': await c.send_call('', b'{"force": 1}', 'json', service_id=service_id),
             'short cdr': await c.send_call('', short_cdr, 'cdr', service_id=service_id),
             'no header': await c.send_call('', b'\x01', 'cdr', service_id=service_id)}
    await c.pump(lambda: all(k in c.failures for k in calls.values()), 30)
    for frame in ('not json {', json.dumps({'op': 'nonsense'}), json.dumps({'op': 'subscribe'}),
                  json.dumps({'op': 'subscribe', 'subscriptions': [{'id': 1, 'channelId': 999_999}]}),
                  json.dumps({'op': 'unsubscribe', 'subscriptionIds': [424_242]}),
                  json.dumps({'op': 'advertise', 'channels': [{'id': 1, 'topic': '/sim/state', 'encoding': 'cdr',
                                                               'schemaName': 'biped_msgs_py/msg/SimState'}]}),
                  b'\x01' + struct.pack('<I', 1) + b'payload', b'\xff\x00\x01', b'\x02\x01\x00', b'',
                  b'\x02' + struct.pack('<III', 4242, 99, 3) + b'cdr' + short_cdr):
        try:
            await c.ws.send(frame)
        except Exception:  # noqa: BLE001 - the server may drop this client at any point: allowed
            break
    await c.pump(lambda: False, 1.0)
    if not c.closed:
        c.ws.transport.abort()     # no close frame: a client that vanishes
    return {'failures': {k: c.failures.get(v) for k, v in calls.items()}, 'status': c.status}


def _descendants(pid: int) -> list[int]:
    from biped_sim.graph.soak import descendants
    return descendants(pid)


def _bridge_pid(launcher_pid: int):
    for p in _descendants(launcher_pid):
        try:
            argv = Path(f'/proc/{p}/cmdline').read_bytes().split(b'\0')
        except OSError:
            continue
        if any(a.endswith(b'/lib/biped_sim/bridge') for a in argv[:3]):
            return p
    return None


def _kill_tree(proc: subprocess.Popen) -> None:
    for p in [*_descendants(proc.pid), proc.pid]:
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        pass


def _launch(tmp: Path, port: int, *extra: str) -> tuple[subprocess.Popen, Path, Path]:
    """The launcher with --live; its output (and its children's) goes to ``tmp/launch.log`` (a pipe
    nobody reads during the run could fill up and block the nodes' logging)."""
    bag, ready = tmp / 'bag', tmp / 'ready'
    cmd = [str(PY), '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--ready-file', str(ready),
           '--live', '--port', str(port), *extra]
    with open(tmp / 'launch.log', 'w') as log:
        proc = subprocess.Popen(cmd, env=dict(os.environ), cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    return proc, bag, ready


def _params_with(tmp: Path, **bridge) -> Path:
    """config/graph.yaml with the bridge's parameters ``bridge`` changed, written to ``tmp``."""
    import yaml
    tree = yaml.safe_load((ROOT / 'config' / 'graph.yaml').read_text())
    tree['bridge']['ros__parameters'].update(bridge)
    path = tmp / 'graph.yaml'
    path.write_text(yaml.safe_dump(tree))
    return path


def _interrupt(proc: subprocess.Popen, timeout: float = 30.0) -> str:
    """SIGINT, wait (bounded; then SIGKILL); return the output."""
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out


def _finish(proc: subprocess.Popen, tmp: Path, timeout: float = 300.0) -> str:
    """Wait (bounded) for the launcher; kill what is left; return its output."""
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        pass
    finally:
        _kill_tree(proc)
    return (tmp / 'launch.log').read_text(errors='replace')


async def _wait_ready(proc, ready: Path, timeout=120.0) -> None:
    deadline = time.monotonic() + timeout
    while not ready.exists():
        assert proc.poll() is None, 'the launcher exited before the graph was up'
        assert time.monotonic() < deadline, 'graph did not come up'
        await asyncio.sleep(0.1)


# ------------------------------------------------------------------------------------------ bridge alone
@pytest.mark.ros
@pytest.mark.parametrize('param,named', [('port:=70000', 'port'), ("host:=''", 'host'),
                                         ('service_timeout:=0.0', 'service_timeout'),
                                         ('message_backlog:=1', 'message_backlog'),
                                         ('drain_batch:=-1', 'drain_batch'), ('executor:=asyncio', 'executor'),
                                         ('reconcile_period:=0.0', 'reconcile_period'),
                                         ('host_process:=both', 'host_process')])
def test_bad_parameter_exits_2_naming_it(ros_domain, param, named):
    r = subprocess.run([_bridge_exe(), '--ros-args', '-p', param], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert f"invalid parameter '{named}'" in r.stderr, r.stderr[-2000:]


@pytest.mark.ros
def test_port_in_use_exits_2(ros_domain):
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        s.listen(1)
        port = s.getsockname()[1]
        r = subprocess.run([_bridge_exe(), '--ros-args', '-p', f'port:={port}'], capture_output=True, text=True,
                           timeout=120)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert f'cannot serve on 127.0.0.1:{port}' in r.stderr, r.stderr[-2000:]


def _live_recorder(*params: str, timeout: float = 120) -> subprocess.CompletedProcess:
    from biped_sim.graph.launch import find_executable
    cmd = [str(find_executable('biped_sim', 'live_recorder')), '--ros-args']
    for p in params:
        cmd += ['-p', p]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


@pytest.mark.ros
@pytest.mark.parametrize('param,named', [('port:=70000', 'port'), ('lazy_streams:=true', 'lazy_streams'),
                                         ('chunk_size:=12', 'chunk_size')])
def test_live_recorder_bad_parameter_exits_2_naming_it_and_creates_no_bag(ros_domain, tmp_path, param, named):
    """The co-hosted recorder + bridge: a bad bridge (port, lazy_streams: the recorder reads every topic) or recorder
    (chunk_size) parameter exits 2 naming it, before any file is created."""
    bag = tmp_path / 'bag'
    r = _live_recorder(f'output_dir:={bag}', param)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert f"'{named}'" in r.stderr, r.stderr[-2000:]
    assert not bag.exists()


@pytest.mark.ros
def test_live_recorder_records_without_the_live_view_when_the_port_is_taken(ros_domain, tmp_path):
    """Co-hosted, a server that cannot start costs the live view, not the recording: the recorder logs it, records,
    finishes its bag on SIGINT and exits 0 (negative control: the bridge's own executable exits 2 on the same port,
    test_port_in_use_exits_2)."""
    from biped_sim.graph.launch import find_executable
    from biped_sim.recording.bag_reader import read_bag
    bag = tmp_path / 'bag'
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        s.listen(1)
        port = s.getsockname()[1]
        proc = subprocess.Popen([str(find_executable('biped_sim', 'live_recorder')), '--ros-args', '-p',
                                 f'output_dir:={bag}', '-p', f'port:={port}'],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines: list[str] = []
        up = threading.Event()

        def read() -> None:   # the node's log; its last line of start-up says the live view is off
            for line in proc.stdout:
                lines.append(line)
                if 'recording without the live view' in line:
                    up.set()
        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            assert up.wait(120), ''.join(lines)[-3000:]
            proc.send_signal(signal.SIGINT)
            proc.wait(60)
            reader.join(30)
            out = ''.join(lines)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert proc.returncode == 0, out[-3000:]
    assert f'cannot serve on 127.0.0.1:{port}' in out and 'recording without the live view' in out, out[-3000:]
    read_bag(bag)   # a finished, readable bag


@pytest.mark.ros
@pytest.mark.slow
async def _connect_when_up(url: str, proc, timeout: float = 60.0) -> 'FoxgloveClient':
    """A client, once the bridge's server accepts a connection (the bridge process must stay up)."""
    import websockets
    deadline = time.monotonic() + timeout
    while True:
        assert proc.poll() is None, 'the bridge exited'
        try:
            return await FoxgloveClient.connect(url)
        except (OSError, websockets.InvalidHandshake):
            assert time.monotonic() < deadline, 'bridge server not up'
            await asyncio.sleep(0.2)


def test_bridge_alone_latched_time_and_unavailable_service(rclpy_context):
    """The bridge with a test publisher instead of the graph: schemas as the MCAP's, a late joiner gets
    the latched /robot_description, /clock becomes the server time, a push without /apply_push fails."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from builtin_interfaces.msg import Time
    from std_msgs.msg import String
    from biped_sim.live import bridge_core as bc
    from biped_sim.graph import names as gn
    from biped_sim.recording.mcap_recorder import build_message_definition

    port = _free_port()
    proc = subprocess.Popen([_bridge_exe(), '--ros-args', '-p', f'port:={port}', '-p', 'service_timeout:=1.0'],
                            env=dict(os.environ),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    node = rclpy.create_node('bridge_test_pub', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    pub_desc = node.create_publisher(String, gn.ROBOT_DESCRIPTION, gn.QOS_LATCHED)
    pub_clock = node.create_publisher(Clock, gn.CLOCK, gn.QOS_CLOCK)
    urdf = String(data='<robot name="bridge_test"/>')
    pub_desc.publish(urdf)
    url = f'ws://127.0.0.1:{port}'

    async def scenario():
        first = await _connect_when_up(url, proc)
        await first.pump(lambda: len(first.channels) == len(gn.TOPICS) and gn.APPLY_PUSH in first.services, 30)
        await first.subscribe([gn.ROBOT_DESCRIPTION])
        # the bridge's subscription has to match the latched publisher first: bounded retries
        await first.pump(lambda: first.messages[gn.ROBOT_DESCRIPTION], 60)
        late = await FoxgloveClient.connect(url)
        await late.pump(lambda: gn.ROBOT_DESCRIPTION in late.channels, 30)
        await late.subscribe([gn.ROBOT_DESCRIPTION])
        await late.pump(lambda: late.messages[gn.ROBOT_DESCRIPTION], 30)
        ok = False
        for k in range(1, 200):         # the bridge's /clock reader matches at some point: keep publishing
            pub_clock.publish(Clock(clock=Time(sec=k, nanosec=500)))
            executor.spin_once(timeout_sec=0.0)
            ok = await first.pump(lambda: first.times, 0.2)
            if ok:
                break
        failure = await first.call(gn.APPLY_PUSH, _push_request(100.0, 0.02, 0.5))
        return first, late, failure

    try:
        first, late, (resp, failure) = asyncio.run(scenario())
    finally:
        out = _interrupt(proc)
        node.destroy_node()
    assert proc.returncode == 0, out[-3000:]
    prefixes = _prefixes()
    for t, spec in gn.TOPICS.items():
        ch = first.channels[t]
        assert (ch['encoding'], ch['schemaName'], ch['schemaEncoding']) == ('cdr', spec.type, 'ros2msg'), ch
        assert ch['schema'] == build_message_definition(spec.type, prefixes), t
    srv = first.services[gn.APPLY_PUSH]
    d = bc.service_definition(gn.APPLY_PUSH_TYPE, prefixes)
    assert srv['type'] == gn.APPLY_PUSH_TYPE
    assert (srv['request']['schemaName'], srv['request']['schema'], srv['request']['encoding']) == \
        (d.request_name, d.request_text, 'cdr')
    assert (srv['response']['schemaName'], srv['response']['schema']) == (d.response_name, d.response_text)
    assert set(first.server_info['capabilities']) >= {'time', 'services'}
    assert 'clientPublish' not in first.server_info['capabilities']
    assert first.messages[gn.ROBOT_DESCRIPTION][0][1] == serialize_message(urdf)
    assert late.messages[gn.ROBOT_DESCRIPTION][0][1] == serialize_message(urdf)    # late joiner
    assert first.times and first.times[-1] % 10**9 == 500 and first.times[-1] >= 10**9
    assert resp is None and 'not available' in failure, failure


def test_bridge_subscribes_to_a_stream_only_while_a_client_watches_it(rclpy_context):
    """lazy_streams: /clock, latched and event topics always; a per-step stream (/tf here) once a client
    subscribes to its channel, dropped when the last one unsubscribes (checked on the ROS graph)."""
    import rclpy
    from biped_sim.graph import names as gn
    port = _free_port()
    proc = subprocess.Popen([_bridge_exe(), '--ros-args', '-p', f'port:={port}', '-p', 'lazy_streams:=true'],
                            env=dict(os.environ),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    node = rclpy.create_node('bridge_sub_probe', context=rclpy_context)
    url = f'ws://127.0.0.1:{port}'

    def bridge_on(topic):
        return 'bridge' in {i.node_name for i in node.get_subscriptions_info_by_topic(topic)}

    async def until(cond, timeout=30.0):
        deadline = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > deadline:
                return False
            await asyncio.sleep(0.05)
        return True

    async def scenario():
        client = await _connect_when_up(url, proc)
        await client.pump(lambda: gn.TF in client.channels, 30)
        always = await until(lambda: bridge_on(gn.CLOCK) and bridge_on(gn.ROBOT_DESCRIPTION) and bridge_on(gn.FALL))
        before = bridge_on(gn.TF) or bridge_on(gn.SIM_STATE)
        await client.subscribe([gn.TF])
        during = await until(lambda: bridge_on(gn.TF))
        still_off = bridge_on(gn.SIM_STATE)
        await client.unsubscribe([gn.TF])
        after = await until(lambda: not bridge_on(gn.TF))
        return always, before, during, still_off, after

    try:
        always, before, during, still_off, after = asyncio.run(scenario())
    finally:
        _interrupt(proc)
        node.destroy_node()
    assert always, 'the bridge must always read /clock, latched and event topics'
    assert not before, 'no stream before a client watches it'
    assert during and not still_off, 'the watched stream only'
    assert after, 'dropped after the last unsubscribe'


@pytest.mark.parametrize('executor,drain_batch', [('events', 0), ('single_threaded', 0), ('single_threaded', 64)])
def test_bridge_passes_a_burst_on_in_order(rclpy_context, executor, drain_batch):
    """A burst of 3000 /joint_states published at once (the bridge's queue fills): on rclpy's EventsExecutor
    (config/graph.yaml: one message per callback, taken in C++), and on the SingleThreadedExecutor with messages
    taken drain_batch at a time after the executor's one (64 in an earlier design) or one per executor round
    (0), the client gets every one, once, in publication order."""
    import rclpy
    from sensor_msgs.msg import JointState
    from biped_sim.graph import names as gn
    port = _free_port()
    proc = subprocess.Popen([_bridge_exe(), '--ros-args', '-p', f'port:={port}', '-p', f'drain_batch:={drain_batch}',
                             '-p', f'executor:={executor}'],
                            env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    node = rclpy.create_node('burst_pub', context=rclpy_context)
    pub = node.create_publisher(JointState, gn.JOINT_STATES, gn.TOPICS[gn.JOINT_STATES].qos_profile)
    n = 3000
    burst = []
    for k in range(n):
        m = JointState()
        m.header.stamp.sec, m.header.stamp.nanosec = k, 7
        m.name = ['a']
        m.position = [0.001 * k]
        burst.append(m)
    url = f'ws://127.0.0.1:{port}'
    WARM_SEC = 1_000_000

    def last_sec(client):
        from rclpy.serialization import deserialize_message
        got = client.messages[gn.JOINT_STATES]
        return deserialize_message(got[-1][1], JointState).header.stamp.sec if got else None

    def burst_of(client):
        from rclpy.serialization import deserialize_message
        msgs = [deserialize_message(payload, JointState) for _, payload in client.messages[gn.JOINT_STATES]]
        return [m for m in msgs if m.header.stamp.sec != WARM_SEC]

    async def scenario():
        client = await _connect_when_up(url, proc)
        await client.pump(lambda: gn.JOINT_STATES in client.channels, 30)
        await client.subscribe([gn.JOINT_STATES])
        # the path is open end to end once a warm-up message reached the client (the writer can see the
        # bridge's reader before that reader has matched the writer, and a sample sent then is not taken)
        warm = JointState()
        warm.header.stamp.sec = WARM_SEC
        for _ in range(600):
            pub.publish(warm)
            if await client.pump(lambda: client.messages[gn.JOINT_STATES], 0.1):
                break
        else:
            raise AssertionError('no warm-up message reached the client through the bridge')
        for m in burst:
            pub.publish(m)
        await client.pump(lambda: last_sec(client) == n - 1, 120)   # the burst's last message arrived
        await client.pump(lambda: False, 0.5)        # nothing more (no duplicates)
        return client

    try:
        client = asyncio.run(scenario())
    finally:
        out = _interrupt(proc)
        node.destroy_node()
    assert proc.returncode == 0, out[-3000:]
    got = burst_of(client)
    assert len(got) == n
    assert [(m.header.stamp.sec, list(m.position)) for m in got] == [(k, [0.001 * k]) for k in range(n)]


# ------------------------------------------------------------------------------------------ whole graph
@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('host_process', ['recorder', 'own'])
def test_live_graph_through_the_bridge(ros_domain, tmp_path, host_process):
    """launch --live (2 steps, simulator paused until a push): subscribe, push through the bridge
    (a rejected request first), bad clients before and during the run; compare with the bag. Both ways of
    hosting the bridge: in the recorder's process (fed by its readers) and in its own."""
    import websockets
    from rclpy.serialization import deserialize_message
    from biped_msgs_py.msg import PushEvent, SimState
    from sensor_msgs.msg import JointState
    from biped_sim.graph import names as gn

    port = _free_port()
    url = f'ws://127.0.0.1:{port}'
    proc, bag, ready = _launch(tmp_path, port, '--steps', '2', '--sim-param', 'wait_for_pushes:=1',
                               '--params', str(_params_with(tmp_path, host_process=host_process)))
    topics = [gn.JOINT_STATES, gn.SIM_STATE, gn.PUSH_EVENTS]

    async def scenario():
        await _wait_ready(proc, ready)
        # the server negotiates foxglove.sdk.v1 only
        with pytest.raises(websockets.InvalidStatus) as refused:
            await websockets.connect(url, subprotocols=['foxglove.websocket.v1'], open_timeout=30)
        a = await FoxgloveClient.connect(url)
        await a.pump(lambda: len(a.channels) == len(gn.TOPICS) and gn.APPLY_PUSH in a.services, 30)
        await a.subscribe(topics)
        sid = a.services[gn.APPLY_PUSH]['id']
        before = await _garbage(url, sid)
        rejected = await a.call(gn.APPLY_PUSH, _push_request(math.nan, 0.025, 0.3))
        assert rejected[1] is None, rejected[1]
        accepted = await a.call(gn.APPLY_PUSH, _push_request(250.0, 0.025, 0.2315))
        assert accepted[1] is None and _response(accepted[0]).accepted, accepted
        await a.pump(lambda: len(a.messages[gn.SIM_STATE]) >= 20, 120)
        during = await _garbage(url, sid)
        # a client that subscribes and vanishes mid-stream
        c = await FoxgloveClient.connect(url)
        await c.pump(lambda: gn.JOINT_STATES in c.channels, 30)
        await c.subscribe([gn.JOINT_STATES])
        await c.pump(lambda: c.messages[gn.JOINT_STATES], 30)
        c.ws.transport.abort()
        # until the launcher stops the bridge after the run (the server closes the connection)
        await a.pump(lambda: False, 400)
        return refused.value, a, before, during, rejected, accepted

    try:
        refused, a, before, during, rejected, accepted = asyncio.run(scenario())
    except BaseException:
        _kill_tree(proc)
        print(_finish(proc, tmp_path, 0)[-6000:])
        raise
    out = _finish(proc, tmp_path)
    assert proc.returncode == 0, out[-4000:]
    assert a.closed, 'the bridge did not close the connection at the end of the run'
    assert refused.response.status_code == 400

    # service calls: the rejected request names the field, the accepted one is the push on /push_events
    resp_rej, fail = rejected
    assert fail is None and not _response(resp_rej).accepted and 'force' in _response(resp_rej).message
    resp_ok, fail = accepted
    ok = _response(resp_ok)
    assert fail is None and ok.accepted, ok.message
    events = [deserialize_message(p, PushEvent) for _, p in a.messages[gn.PUSH_EVENTS]]
    assert [(e.id, e.force, e.duration, e.start) for e in events] == [(ok.push_id, 250.0, 0.025, 0.2315)]
    for bad in (before, during):
        f = bad['failures']
        assert 'encoding' in f['json encoding'] and 'not a CDR' in f['short cdr'] and 'header' in f['no header'], bad

    # the stream: no gap, and the same messages as the bag
    from biped_sim.recording.bag_reader import read_bag
    d = read_bag(bag, decode=True)
    states = [deserialize_message(p, SimState) for _, p in a.messages[gn.SIM_STATE]]
    seqs = [s.sequence for s in states]
    assert seqs == list(range(1, len(seqs) + 1)), f'gaps or repeats: {seqs[:5]}..{seqs[-5:]} ({len(seqs)})'
    bag_states = sorted((m for t, _, _, m in d['messages'] if t == gn.SIM_STATE), key=lambda m: m.sequence)
    assert seqs == [m.sequence for m in bag_states]
    for s, m in zip(states, bag_states):
        assert list(s.q) == list(m.q) and list(s.q_dot) == list(m.q_dot) and list(s.base) == list(m.base)
    joints = [deserialize_message(p, JointState) for _, p in a.messages[gn.JOINT_STATES]]
    bag_joints = sorted((m for t, _, _, m in d['messages'] if t == gn.JOINT_STATES),
                        key=lambda m: (m.header.stamp.sec, m.header.stamp.nanosec))
    assert len(joints) == len(bag_joints) == len(states) - 1
    for j, m in zip(joints, bag_joints):
        assert (j.header.stamp.sec, j.header.stamp.nanosec) == (m.header.stamp.sec, m.header.stamp.nanosec)
        assert list(j.position) == list(m.position) and list(j.effort) == list(m.effort)
    # garbage never reached ROS: the disturbance node saw the two real requests only
    assert d['counts'][gn.PUSH_REQUESTS] == 2 and d['counts'][gn.PUSH_EVENTS] == 1
    # sim time: one time frame per /clock, increasing, the last one the final state's stamp
    last = bag_states[-1].stamp
    assert a.times == sorted(set(a.times)) and a.times[-1] == last.sec * 10**9 + last.nanosec
    assert len(a.times) == d['counts'][gn.CLOCK]
    assert 'steps walked' in out and "node 'bridge' died" not in out
    # where the bridge ran: in the recorder's process (no bridge process, the recorder's log says so) or its own
    assert ('(the live bridge in its process)' in out) == (host_process == 'recorder'), out[-4000:]
    assert ('bridge subscribed (Foxglove WebSocket)' in out) == (host_process == 'own'), out[-4000:]


@pytest.mark.ros
@pytest.mark.slow
def test_bridge_killed_mid_run_does_not_stop_it(ros_domain, tmp_path):
    from biped_sim.graph import names as gn
    port = _free_port()
    proc, bag, ready = _launch(tmp_path, port, '--steps', '1', '--params', str(_params_with(tmp_path, host_process='own')))

    async def scenario():
        await _wait_ready(proc, ready)
        a = await FoxgloveClient.connect(f'ws://127.0.0.1:{port}')
        await a.pump(lambda: gn.SIM_STATE in a.channels, 30)
        await a.subscribe([gn.SIM_STATE])
        assert await a.pump(lambda: len(a.messages[gn.SIM_STATE]) >= 10, 120), 'no states through the bridge'
        pid = _bridge_pid(proc.pid)
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        await a.pump(lambda: False, 30)     # the connection drops with the bridge
        return a

    try:
        a = asyncio.run(scenario())
    except BaseException:
        _kill_tree(proc)
        print(_finish(proc, tmp_path, 0)[-6000:])
        raise
    out = _finish(proc, tmp_path)
    assert a.closed
    assert proc.returncode == 0, out[-4000:]
    assert "node 'bridge' died unexpectedly" in out and 'the run goes on without the live view' in out, out[-4000:]
    assert '1 steps walked' in out, out[-4000:]
    from biped_sim.recording.bag_reader import read_bag
    d = read_bag(bag, decode=True)
    seqs = sorted(m.sequence for t, _, _, m in d['messages'] if t == gn.SIM_STATE)
    assert seqs == list(range(1, len(seqs) + 1)) and len(seqs) > len(a.messages[gn.SIM_STATE])
