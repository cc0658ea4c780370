"""Foxglove bridge: publish-to-WebSocket-frame latency and the lockstep rate with the bridge on and off.

    .venv/bin/python -m benchmarks.bridge_bench     # = --pairs 0 --latency-pairs 3 --live-steps 4 --json results/benchmarks/bridge.json
    .venv/bin/python -m benchmarks.bridge_bench [--pairs N] [--steps 2] [--latency-pairs 3] [--live-steps 4] [--before SETTING] [--json FILE]

Every run is the whole graph from ``biped_sim.graph.launch`` (recorder included) in its own ROS domain
(``domain_coordinator``), on 127.0.0.1 only:

- **rate, off/on** (``--pairs`` pairs, alternated off, on, off, on, ... so that the machine's drift
  hits both alike): ``--steps`` walking steps as fast as possible (``real_time_factor:=0``), without
  the bridge, then with ``--live`` and a WebSocket client subscribed to every channel (what a
  Foxglove layout showing everything asks for), reading every frame. The rate is the simulator's own
  figure, from its end-of-run line (control steps / wall seconds from the first published state).
  Every run starts its lockstep ``start_delay`` 2 s after the graph is connected, time for the client
  to subscribe before the first state.
- **latency, live** (one run): ``--live`` as a user runs it (``real_time_factor`` 1.0), the same
  client. For every ``/sim/state`` (matched by ``sequence``) and ``/joint_states`` (matched by
  stamp) frame: latency = the client's ``time.time_ns()`` right after the frame was read - the
  message's DDS source timestamp (the simulator's ``publish()``), which the recorder stores as the
  MCAP ``publish_time``. Same host, same clock (CLOCK_REALTIME). The client is a Python asyncio
  ``websockets`` client: its own wake-up is part of the figure (its garbage collector is off while it reads, as
  in ``timeit``: its pauses are not the bridge's). Beside it, in a process of its own (:mod:`benchmarks.dds_probe`:
  as a thread of the client's process it held the client's reads back through the interpreter lock), a
  plain DDS subscriber (rclpy, raw, the recorder's QoS) measures publish-to-callback
  latency for ``/sim/state`` the same way: the baseline the bridge path adds to (it runs in the
  rate-off runs too, so both sides of the rate comparison carry the same subscriber). The rate-on runs
  give the same figures under the as-fast-as-possible burst (queueing).

- **latency before/after** (``--latency-pairs`` pairs, alternated): the real-time runs above
  are made once per setting, ``before`` (:data:`BEFORE`: the bridge and the disturbance node on rclpy's
  Python ``SingleThreadedExecutor``, the bridge's ``drain_batch`` 64, the recorder's ``batch_wait`` 0: main's
  settings; the code is this one in both, e.g. ``run_node``'s spin slices) and ``after`` (``config/graph.yaml`` as committed), each with a client on every channel and
  one on the layout's topics; every frame is counted against the bag. Each run also records the 1-minute load
  average at its start and the CPU time of every process and thread (:mod:`benchmarks.proc_cpu`, the
  scheduler's own accounting) from the first ``/sim/state`` (the DDS probe) to the process's exit; the summary
  gives, per setting, medians of: latency p50/p99, steps/s, the bridge's CPU per message it takes and per frame
  it sends (all its threads: Python, Fast DDS, the SDK's tokio), the graph's CPU per control step (every node)
  and each node's, and the after/before ratios (``before_after``). CPU per message or per step is far less
  load-sensitive than latency on a shared machine.

- **settings** (``SETTINGS``; ``--before NAME`` / ``--after NAME``): ``main`` = the graph as main had it before the durability changes
  part 3's last round (the recorder on rclpy's ``SingleThreadedExecutor``, the bridge in its own process) *and* the
  client as it was then (an ``asyncio.wait_for`` per frame); ``own`` = ``config/graph.yaml`` with the bridge in its
  own process (co-hosting off alone); ``stexec`` = ``config/graph.yaml`` with the recorder on the
  ``SingleThreadedExecutor`` (its wait set off alone). With the bridge co-hosted (``live_recorder``) its CPU is
  the recorder process's: the bridge's own per-message figures are NaN, ``recorder_and_bridge_ms_per_step``
  compares both hostings.

The client is the measurement instrument and runs on the same 2 cores as the graph (a user's Foxglove runs on
the user's side): it does as little as a real WebSocket client can per frame (one ``await`` of the library's
receive and a timestamp; frames are parsed after the run).

The latency before/after (the command the lead re-runs)::

    .venv/bin/python -m benchmarks.bridge_bench --before main --latency-pairs 3 --json results/benchmarks/bridge.json

Percentiles: numpy ``percentile`` (linear). Nothing is asserted; figures are printed (and --json).
"""
from __future__ import annotations

import argparse
import asyncio
import gc
import json
import os
import platform
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `python benchmarks/bridge_bench.py`
    sys.path.insert(0, str(ROOT))

from benchmarks.lockstep import _LINE  # noqa: E402  the simulator's "run over: ..." line
from benchmarks.proc_cpu import TreeCpu  # noqa: E402
from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR
from benchmarks.domain import Domain

SUBPROTOCOL = 'foxglove.sdk.v1'
LAYOUT_TOPICS = ('/sim/state', '/joint_states', '/tf')
PROBES: list = []        # the DDS probe of each run, newest last (lab.benchmarks.bridge_profile starts py-spy on its first state)
CLIENT_CPU = {'s': 0.0}   # CPU s of the last client's thread (asyncio + websockets), connect to close
START_DELAY = 2.0   # s between "graph connected" and the first state: the client subscribes meanwhile


def node_name(words: list[str]) -> str | None:
    """Process name for the CPU table: the node's executable (``.venv/lib/<pkg>/<exe>``), or the launcher."""
    for w in words:
        parts = w.split('/')
        if len(parts) >= 3 and parts[-3] == 'lib' and parts[-2] in ('biped_sim', 'biped_controller'):
            return parts[-1]
    if 'biped_sim.graph.launch' in words:
        return 'launcher'
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


async def _subscribe_advertised(ws, text: str, only, topics: dict) -> None:
    """A text frame of the Foxglove WebSocket protocol: on ``advertise``, subscribe to the channels (those whose
    topic is in ``only``, or all) and remember each channel id's topic in ``topics``; other ops are ignored."""
    msg = json.loads(text)
    if msg['op'] == 'advertise':
        subs = [{'id': c['id'], 'channelId': c['id']} for c in msg['channels'] if only is None or c['topic'] in only]
        topics.update({c['id']: c['topic'] for c in msg['channels']})
        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))


def _is_state(frame: bytes, topics: dict) -> bool:
    """A message-data frame (opcode 1) of ``/sim/state`` (its subscription id is the channel id: see
    ``_subscribe_advertised``); a latched topic's message can come long before the run starts."""
    return frame[0] == 0x01 and topics.get(struct.unpack_from('<I', frame, 1)[0]) == '/sim/state'


async def _client(url: str, proc: subprocess.Popen, ready: Path, timeout: float,
                  only: tuple[str, ...] | None = None, per_frame_timeout: bool = False,
                  first=None) -> tuple[dict, list]:
    """Connect once the graph is up, subscribe to every advertised channel (or those of ``only``), read every frame until
    the server closes (the launcher stops the bridge after the run). Returns ({sub id: topic},
    [(recv ns, frame)])."""
    import websockets
    deadline = time.monotonic() + timeout
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError('the graph did not come up')
        await asyncio.sleep(0.05)
    ws = await websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=30)
    cpu0 = time.thread_time_ns()
    topics, frames = {}, []
    if per_frame_timeout:   # the client as it was before the latency changes (setting 'main'): a wait_for per frame
        try:
            while time.monotonic() < deadline:
                try:
                    frame = await asyncio.wait_for(ws.recv(), timeout=1.0)
                except asyncio.TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    break
                t = time.time_ns()
                if isinstance(frame, str):
                    await _subscribe_advertised(ws, frame, only, topics)
                else:
                    frames.append((t, frame))
                    if first is not None and _is_state(frame, topics):
                        first.set()
                        first = None
        finally:
            await ws.close()
            CLIENT_CPU['s'] = (time.thread_time_ns() - cpu0) * 1e-9
        return topics, frames
    append, now_ns = frames.append, time.time_ns
    # The collector off while the frames come in (as timeit does): a full collection of this process, whose
    # frame list grows by thousands of tuples a second, paused the read (the client's pauses are not the bridge's)
    gc_was = gc.isenabled()
    gc.disable()
    # The client is the measurement instrument and shares the 2 cores with the graph, so it does as little as a
    # real client can per frame: one await of the library's receive and a timestamp, no per-frame timeout (an
    # asyncio.wait_for per frame, as before the latency changes, wraps each receive in a task and a timer); one deadline
    # for the whole read instead. Frames are parsed after the run.
    try:
        async with asyncio.timeout_at(asyncio.get_running_loop().time() + max(0.0, deadline - time.monotonic())):
            async for frame in ws:
                t = now_ns()
                if frame.__class__ is str:
                    await _subscribe_advertised(ws, frame, only, topics)
                else:
                    append((t, frame))
                    if first is not None and _is_state(frame, topics):   # the run's first /sim/state
                        first.set()
                        first = None
    except websockets.ConnectionClosed:
        pass   # closed with an error: what arrived is reported (counted against the bag)
    except TimeoutError:
        pass   # the deadline: what arrived is reported (the run's checks count the frames against the bag)
    finally:
        if gc_was:
            gc.enable()
        await ws.close()
        CLIENT_CPU['s'] = (time.thread_time_ns() - cpu0) * 1e-9
    return topics, frames


class _FileFlag:
    """``is_set()`` once a file exists (a flag another process raises)."""

    def __init__(self, path: Path):
        self.path = path

    def is_set(self) -> bool:
        return self.path.exists()


class Marker:
    """A run's start flag (``first.is_set()``): the probe's first ``/sim/state``, or the client's first message
    frame in a run without the probe. ``PROBES`` holds one per run (``lab.benchmarks.bridge_profile`` starts py-spy then)."""

    def __init__(self, first):
        self.first = first


class DdsProbe:
    """A raw ``/sim/state`` subscriber in a process of its own (:mod:`benchmarks.dds_probe`): (receive ns, source
    timestamp ns) per message. Started before the graph and waited for until its subscription exists; ``first`` is
    raised at its first message. It used to be a thread of this process, where it held the WebSocket client's reads
    back (the interpreter lock; module docstring of ``benchmarks.dds_probe``)."""

    def __init__(self, env: dict, tmp: Path, timeout: float = 60.0):
        tmp.mkdir(parents=True, exist_ok=True)
        self.ready, self.out = tmp / 'probe_ready', tmp / 'probe_rows.json'
        self.first = _FileFlag(tmp / 'probe_first')
        self.proc = subprocess.Popen([sys.executable, '-m', 'benchmarks.dds_probe', '--ready', str(self.ready),
                                      '--first', str(self.first.path), '--out', str(self.out)], cwd=ROOT, env=env)
        deadline = time.monotonic() + timeout
        while not self.ready.exists():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.proc.kill()
                raise RuntimeError('the DDS probe did not come up')
            time.sleep(0.02)

    def close(self) -> list:
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            return []
        if not self.out.exists():
            return []
        return [(recv, src, None) for recv, src in json.loads(self.out.read_text())]


def _stats(values) -> dict:
    a = np.asarray(values, dtype=float)
    if not a.size:
        return {'n': 0}
    return {'n': int(a.size), 'p50': float(np.percentile(a, 50)), 'p99': float(np.percentile(a, 99)),
            'max': float(a.max())}


# The graph's settings before the latency changes (the bridge, the disturbance node and the recorder on rclpy's Python
# SingleThreadedExecutor; the bridge taking up to 64 waiting messages per callback, as part 2 left it; the recorder
# without batch_wait): settings only, the code is the same in both. "after" = config/graph.yaml as committed.
BEFORE = {'bridge': {'executor': 'single_threaded', 'drain_batch': 64, 'host_process': 'own'},
          'disturbance': {'executor': 'single_threaded'},
          'recorder': {'batch_wait': 0.0, 'executor': 'single_threaded'}}


# "lazy": config/graph.yaml with the bridge's lazy_streams on (it reads a per-step stream only while a client
# watches it): what the layout's client costs when the bridge does not take the streams nobody shows.
# "objects": config/graph.yaml with the simulator and the controller publishing message objects instead of CDR
# bytes (publish_cdr false): the before of raw publishing (--before objects).
# "main": the graph as main had it before its last latency change (the recorder on rclpy's Python
# SingleThreadedExecutor, the bridge in its own process) and the benchmark's client as it was then (an asyncio.wait_for
# per frame; key '_client'): the before of --before main. "own": config/graph.yaml with the bridge in its own
# process (the co-hosting alone, A/B); "stexec": config/graph.yaml with the recorder on the SingleThreadedExecutor
# (the wait set alone, A/B); "nagle": config/graph.yaml with the bridge's tcp_nodelay false (the SDK's default: Nagle's
# algorithm on the server's sockets, A/B).
MAIN = {'recorder': {'executor': 'single_threaded'}, 'bridge': {'host_process': 'own'}, '_client': 'per_frame_timeout'}
SETTINGS = {'before': BEFORE, 'after': None, 'lazy': {'bridge': {'lazy_streams': True, 'host_process': 'own'}},
            'objects': {'simulator': {'publish_cdr': False}, 'controller': {'publish_cdr': False}},
            'main': MAIN, 'own': {'bridge': {'host_process': 'own'}},
            'stexec': {'recorder': {'executor': 'single_threaded'}},
            'nagle': {'bridge': {'tcp_nodelay': False}},
            'batch2': {'recorder': {'batch_wait': 0.002}}}


def legacy_client(setting: str) -> bool:
    """Whether a setting runs the benchmark's client as it was before the latency changes (a timeout per frame)."""
    return (SETTINGS.get(setting) or {}).get('_client') == 'per_frame_timeout'



def settings_params(tmp: Path, setting: str, root: Path | None = None) -> Path | None:
    """config/graph.yaml (of ``root``, default this tree) with a setting's overrides (``SETTINGS``) written to a
    file; None for ``after`` (the file as committed)."""
    if setting not in SETTINGS:
        raise ValueError(f'setting must be one of {", ".join(SETTINGS)}, got {setting!r}')
    if SETTINGS[setting] is None:
        return None
    import yaml
    tree = yaml.safe_load(((root or ROOT) / 'config' / 'graph.yaml').read_text())
    for node, values in SETTINGS[setting].items():
        if not node.startswith('_'):
            tree[node]['ros__parameters'].update(values)
    path = tmp / f'graph_{setting}.yaml'
    path.write_text(yaml.safe_dump(tree))
    return path


class Revision:
    """The project's code at a git revision, checked out (detached) in a temporary worktree for the 'before' runs of
    ``--before-rev``: the graph is then started from that tree (its ``src`` first on ``PYTHONPATH``, ahead of the
    venv's editable install of this tree; its own ``config/``), with this tree's venv and generated interfaces."""

    def __init__(self, rev: str, parent: Path):
        self.rev = subprocess.run(['git', 'rev-parse', '--short', rev], cwd=ROOT, check=True, capture_output=True,
                                  text=True).stdout.strip()
        self.path = parent / f'rev_{self.rev}'
        subprocess.run(['git', 'worktree', 'add', '--detach', str(self.path), self.rev], cwd=ROOT, check=True,
                       capture_output=True)

    def env(self, base: dict) -> dict:
        src = [str(self.path / 'src' / pkg) for pkg in ('biped_sim', 'biped_controller')]
        return dict(base, PYTHONPATH=os.pathsep.join(src + ([base['PYTHONPATH']] if base.get('PYTHONPATH') else [])))

    def close(self) -> None:
        subprocess.run(['git', 'worktree', 'remove', '--force', str(self.path)], cwd=ROOT, capture_output=True)


def run_graph(dom: Domain, tmp: Path, *, live: bool, rtf: float, steps: int, timeout: float = 600.0,
              only: tuple[str, ...] | None = None, params: Path | None = None, per_frame_timeout: bool = False,
              revision: Revision | None = None, client: bool = True, probe: bool = True) -> dict:
    """One launch; the simulator's rate, and with ``live`` (and ``client``) the client's latencies (ms), with ``probe``
    the plain DDS subscriber's. ``revision``: the graph's code from that checkout instead of this tree. The CPU is
    counted from the probe's first ``/sim/state``, without a probe from the client's first message frame."""
    tmp.mkdir(parents=True, exist_ok=True)
    bag, ready, log = tmp / 'bag', tmp / 'ready', tmp / 'launch.log'
    port = free_port()
    cmd = [sys.executable, '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--ready-file', str(ready),
           '--steps', str(steps)]
    if params is not None:
        cmd += ['--params', str(params)]
    if live:
        cmd += ['--live', '--port', str(port)]
    cmd += ['--sim-param', f'real_time_factor:={rtf}', '--sim-param', f'start_delay:={START_DELAY}']
    cwd, env = (ROOT, dom.env) if revision is None else (revision.path, revision.env(dom.env))
    client = client and live
    if not (client or probe):
        raise ValueError('a run needs the client or the probe (the CPU is counted from their first message)')
    dds = DdsProbe(dom.env, tmp) if probe else None   # subscribed before the graph starts
    marker = Marker(dds.first if dds is not None else threading.Event())
    with open(log, 'w') as fh:
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=fh, stderr=subprocess.STDOUT)
    cpu = TreeCpu(proc.pid, node_name, mark_when=marker.first.is_set, period=0.05)
    PROBES.append(marker)
    CLIENT_CPU['s'] = 0.0
    dds_rows = []
    try:
        topics, frames = {}, []
        if client:
            topics, frames = asyncio.run(_client(f'ws://127.0.0.1:{port}', proc, ready, timeout, only,
                                                   per_frame_timeout, None if dds is not None else marker.first))
        proc.wait(timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if dds is not None:
            dds_rows = dds.close()
        cpu_table = cpu.stop()
    text = log.read_text(errors='replace')
    m = _LINE.search(text)
    out = {'live': live, 'real_time_factor': rtf, 'exit_code': proc.returncode,
           'client_topics': 'all' if only is None else list(only),
           'steps': int(m['steps']) if m else None, 'wall_s': float(m['wall']) if m else None,
           'steps_per_s': int(m['steps']) / float(m['wall']) if m and float(m['wall']) > 0 else None}
    if client:
        cpu_table['client'] = {'cpu_s': round(CLIENT_CPU['s'], 4)}
    out['cpu_s'] = cpu_table
    if m:
        out['cpu_ms_per_step'] = {k: round(v['cpu_s'] / int(m['steps']) * 1e3, 4) for k, v in cpu_table.items()
                                  if int(m['steps'])}
    if proc.returncode != 0 or m is None:
        out['log_tail'] = text[-1500:]
        return out
    out['client'], out['probe'] = client, probe
    if client:
        out.update(latencies(bag, topics, frames))
    if probe:
        out['latency_ms dds /sim/state'] = _stats([(recv - src) * 1e-6 for recv, src, _ in dds_rows])
    return out


def latencies(bag: Path, topics: dict, frames: list) -> dict:
    """Frame receive time - DDS publish time (ms), per topic, matched against the bag."""
    from rclpy.serialization import deserialize_message
    from biped_msgs_py.msg import SimState
    from sensor_msgs.msg import JointState
    from biped_sim.recording.bag_reader import read_bag
    d = read_bag(bag, decode=True)
    pub_state = {m.sequence: pt for t, _, pt, m in d['messages'] if t == '/sim/state'}
    pub_joint = {(m.header.stamp.sec, m.header.stamp.nanosec): pt for t, _, pt, m in d['messages']
                 if t == '/joint_states'}
    lat = {'/sim/state': [], '/joint_states': []}
    counts: dict[str, int] = {}
    for recv, frame in frames:
        if frame[0] != 0x01:
            continue
        sub = struct.unpack_from('<I', frame, 1)[0]
        topic = topics.get(sub)
        counts[topic] = counts.get(topic, 0) + 1
        if topic == '/sim/state':
            s = deserialize_message(bytes(frame[13:]), SimState)
            if s.sequence in pub_state:
                lat[topic].append((recv - pub_state[s.sequence]) * 1e-6)
        elif topic == '/joint_states':
            j = deserialize_message(bytes(frame[13:]), JointState)
            key = (j.header.stamp.sec, j.header.stamp.nanosec)
            if key in pub_joint:
                lat[topic].append((recv - pub_joint[key]) * 1e-6)
    out = {'frames_per_topic': dict(sorted((k, v) for k, v in counts.items() if k)),
           'bag_states': len(pub_state), 'bag_counts': dict(d['counts'])}
    # every frame delivered: each watched topic's frames = its messages in the bag
    out['every_frame_delivered'] = all(counts.get(t, 0) == d['counts'].get(t, 0)
                                       for t in set(topics.values()) if t in counts)
    for topic, v in lat.items():
        out[f'latency_ms {topic}'] = _stats(v)
    return out


def cpu_figures(r: dict) -> dict:
    """CPU figures of one live run: the bridge's CPU (all its threads: Python, Fast DDS, the SDK's tokio) per
    message it took (every message of the bag: it subscribes to every topic) and per frame it sent to the client,
    and the graph's (every node, not the benchmark's client) and the client's CPU per control step."""
    cpu = r.get('cpu_s', {})
    steps = r.get('steps') or 0
    messages = sum(r.get('bag_counts', {}).values())
    frames = sum(r.get('frames_per_topic', {}).values())
    own = 'bridge' in cpu   # a bridge process of its own; co-hosted (live_recorder) its CPU is the recorder's
    bridge = cpu.get('bridge', {}).get('cpu_s', 0.0)
    graph = sum(v['cpu_s'] for k, v in cpu.items() if k not in ('client', 'launcher'))
    rec_bridge = sum(cpu.get(k, {}).get('cpu_s', 0.0) for k in ('recorder', 'bridge', 'live_recorder'))
    return {'bridge_us_per_message': bridge / messages * 1e6 if messages and own else float('nan'),
            'bridge_us_per_frame': bridge / frames * 1e6 if frames and own else float('nan'),
            'recorder_and_bridge_ms_per_step': rec_bridge / steps * 1e3 if steps else float('nan'),
            'graph_cpu_ms_per_step': graph / steps * 1e3 if steps else float('nan'),
            'client_cpu_ms_per_step': cpu.get('client', {}).get('cpu_s', 0.0) / steps * 1e3 if steps else float('nan')}


def before_after(runs: list) -> dict:
    """Per client kind: medians over the runs of each setting, and after/before ratios of those medians."""
    out: dict = {}
    for kind in ('latency', 'latency_layout', 'latency_dds'):
        rows: dict = {}
        for setting in ('before', 'after'):
            sel = [r for r in runs if r['kind'] == kind and r.get('bridge') == setting and r.get('steps_per_s')]
            if not sel:
                continue
            figs = [cpu_figures(r) for r in sel]
            # the WebSocket client's /sim/state, or (latency_dds: no client) the plain DDS subscriber's
            key = 'latency_ms dds /sim/state' if kind == 'latency_dds' else 'latency_ms /sim/state'
            rows[setting] = {
                'runs': len(sel),
                'p50_ms': float(np.median([r[key]['p50'] for r in sel])),
                'p99_ms': float(np.median([r[key]['p99'] for r in sel])),
                'steps_per_s': float(np.median([r['steps_per_s'] for r in sel])),
                'p50_ms_runs': [round(r[key]['p50'], 2) for r in sel],
                'p99_ms_runs': [round(r[key]['p99'], 2) for r in sel],
                'dds_p99_ms_runs': [round(r.get('latency_ms dds /sim/state', {}).get('p99', float('nan')), 2)
                                    for r in sel],
                'steps_per_s_runs': [round(r['steps_per_s']) for r in sel],
                'load_average_1min': [round(r.get('load_average_1min_at_start', float('nan')), 2) for r in sel],
                'every_frame_delivered': all(r.get('every_frame_delivered', True) for r in sel),
                **{k: float(np.median([f[k] for f in figs])) for k in figs[0]},
                'cpu_ms_per_step_median': {
                    node: float(np.median([r['cpu_ms_per_step'].get(node, float('nan')) for r in sel]))
                    for node in sorted({n for r in sel for n in r.get('cpu_ms_per_step', {})})}}
        if 'before' in rows and 'after' in rows:
            rows['ratio_after_over_before'] = {
                k: rows['after'][k] / rows['before'][k] for k in
                ('p50_ms', 'p99_ms', 'steps_per_s', 'bridge_us_per_message', 'graph_cpu_ms_per_step',
                 'recorder_and_bridge_ms_per_step', 'client_cpu_ms_per_step')
                if rows['before'][k]}
        out[kind] = rows
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bridge_bench', description=__doc__.split('\n\n')[0])
    ap.add_argument('--pairs', type=int, default=0, help='off/on pairs of as-fast-as-possible runs')
    ap.add_argument('--steps', type=int, default=2, help='walking steps per rate run')
    ap.add_argument('--live-steps', type=int, default=4, help='walking steps of each real-time latency run')
    ap.add_argument('--latency-pairs', type=int, default=3,
                    help='before (BEFORE) / after (config/graph.yaml) pairs of real-time latency runs, alternated')
    ap.add_argument('--before', default='before', choices=sorted(SETTINGS),
                    help="the setting of the 'before' runs (default BEFORE; objects: publish_cdr false)")
    ap.add_argument('--after', default='after', choices=sorted(SETTINGS),
                    help="the setting of the 'after' runs (default: config/graph.yaml as committed)")
    ap.add_argument('--dds-pairs', type=int, default=1,
                    help='before/after pairs of real-time runs with the plain DDS subscriber and no WebSocket client')
    ap.add_argument('--before-rev', default=None, metavar='REV',
                    help="the 'before' runs with the code (and config/) of git revision REV, checked out in a temporary "
                         "worktree, with --before's setting applied to that tree's config/graph.yaml")
    ap.add_argument('--layout-only', action='store_true',
                    help="real-time runs with the layout's client only (no client on every channel)")
    ap.add_argument('--json', type=Path, default=RESULTS_DIR / 'bridge.json',
                    help='results file (default results/benchmarks/bridge.json)')
    a = ap.parse_args(argv)
    provenance.track(a.json, argv=argv)   # record of each file written (results/README.md)
    t0 = time.monotonic()
    runs = []
    with tempfile.TemporaryDirectory() as tmp, Domain() as dom:
        revision = Revision(a.before_rev, Path(tmp)) if a.before_rev else None
        try:
            for i in range(a.pairs):
                for live in (False, True):
                    r = run_graph(dom, Path(tmp) / f'rate_{i}_{int(live)}', live=live, rtf=0.0, steps=a.steps)
                    r['kind'] = 'rate'
                    runs.append(r)
                    print(json.dumps(r), flush=True)
            # real time: a client on every channel (15 topics x 1 kHz through one Python client), then one
            # showing what a 3D + plot layout shows (/sim/state, /joint_states, /tf); before (BEFORE) and after
            # (config/graph.yaml), alternated
            for k in range(a.latency_pairs):
                for setting in ('before', 'after'):
                    for i, only in enumerate((None, LAYOUT_TOPICS)):
                        if a.layout_only and only is None:
                            continue
                        load = os.getloadavg()[0]
                        name = a.before if setting == 'before' else a.after
                        rev = revision if setting == 'before' else None
                        r = run_graph(dom, Path(tmp) / f'live_{k}_{setting}_{i}', live=True, rtf=1.0,
                                      steps=a.live_steps, only=only,
                                      params=settings_params(Path(tmp), name, None if rev is None else rev.path),
                                      per_frame_timeout=legacy_client(name), revision=rev, probe=False)
                        if rev is not None:
                            r['revision'] = rev.rev
                        r['load_average_1min_at_start'] = load
                        r['kind'] = 'latency' if only is None else 'latency_layout'
                        r['bridge'] = setting
                        r['setting'] = name
                        runs.append(r)
                        print(json.dumps({k2: v for k2, v in r.items() if k2 != 'bag_counts'}), flush=True)
            # the plain DDS subscriber's baseline: the same live graph (bridge up) without a WebSocket client, one
            # instrument per run (a second one is load on the same 2 cores)
            for k in range(a.dds_pairs):
                for setting in ('before', 'after'):
                    load = os.getloadavg()[0]
                    name = a.before if setting == 'before' else a.after
                    rev = revision if setting == 'before' else None
                    r = run_graph(dom, Path(tmp) / f'dds_{k}_{setting}', live=True, rtf=1.0, steps=a.live_steps,
                                  params=settings_params(Path(tmp), name, None if rev is None else rev.path),
                                  revision=rev, client=False, probe=True)
                    r.update(load_average_1min_at_start=load, kind='latency_dds', bridge=setting, setting=name)
                    if rev is not None:
                        r['revision'] = rev.rev
                    runs.append(r)
                    print(json.dumps({k2: v for k2, v in r.items() if k2 != 'bag_counts'}), flush=True)
        finally:
            if revision is not None:
                revision.close()
    off = [r['steps_per_s'] for r in runs if r['kind'] == 'rate' and not r['live'] and r['steps_per_s']]
    on = [r['steps_per_s'] for r in runs if r['kind'] == 'rate' and r['live'] and r['steps_per_s']]
    summary = {'date': time.strftime('%Y-%m-%d %H:%M:%S'), 'cpus': os.cpu_count(), 'machine': platform.machine(),
               'load_average_at_end': os.getloadavg(), 'wall_s': time.monotonic() - t0, 'before_setting': a.before,
               'after_setting': a.after, 'before_rev': a.before_rev, 'argv': sys.argv[1:],
               'rate_off_steps_per_s': off, 'rate_on_steps_per_s': on,
               'rate_on_over_off': (float(np.mean(on)) / float(np.mean(off))) if on and off else None,
               'runs': runs}
    print('==== bridge benchmark ====')
    print(f"lockstep rate, bridge off: {', '.join(f'{x:.0f}' for x in off)} steps/s; "
          f"on (client subscribed to every channel): {', '.join(f'{x:.0f}' for x in on)} steps/s; "
          f"on/off {summary['rate_on_over_off']:.2f}" if on and off else 'rate: not available')
    for r in runs:
        if r.get('steps_per_s'):
            for key in ('/sim/state', '/joint_states', 'dds /sim/state'):
                s = r.get(f'latency_ms {key}', {'n': 0})
                if s['n']:
                    path = 'DDS only ' if key.startswith('dds') else 'WebSocket'
                    print(f"latency {r['kind']:14s} {r.get('bridge', ''):6s} bridge {'on ' if r['live'] else 'off'} "
                          f"rtf {r['real_time_factor']:.0f} {path} {key.split()[-1]:14s}: "
                          f"n {s['n']}, p50 {s['p50']:.2f} ms, p99 {s['p99']:.2f} ms, max {s['max']:.2f} ms"
                          + (f", every frame: {r.get('every_frame_delivered')}, {r['steps_per_s']:.0f} steps/s"
                             if key == '/sim/state' else ''))
    summary['before_after'] = before_after(runs)
    if a.json:
        a.json.write_text(json.dumps(summary, indent=2) + '\n')
    for kind, rows in summary['before_after'].items():
        for setting in ('before', 'after'):
            m = rows.get(setting)
            if m:
                print(f"{kind:14s} {setting:6s} (medians of {m['runs']} runs): /sim/state p50 {m['p50_ms']:.2f} ms, "
                      f"p99 {m['p99_ms']:.2f} ms; {m['steps_per_s']:.0f} steps/s; bridge CPU {m['bridge_us_per_message']:.1f} us "
                      f"per message it takes, {m['bridge_us_per_frame']:.1f} us per frame sent; graph CPU "
                      f"{m['graph_cpu_ms_per_step']:.3f} ms per control step (recorder+bridge "
                      f"{m['recorder_and_bridge_ms_per_step']:.3f}, client {m['client_cpu_ms_per_step']:.3f}); "
                      f"runs: p50 {m['p50_ms_runs']} ms, p99 {m['p99_ms_runs']} ms, {m['steps_per_s_runs']} steps/s, "
                      f"load {m['load_average_1min']}; "
                      f"every frame in every run: {m['every_frame_delivered']}; per node (ms per step): "
                      + ', '.join(f'{n} {v:.3f}' for n, v in m['cpu_ms_per_step_median'].items()))
        if 'ratio_after_over_before' in rows:
            print(f"{kind:14s} after/before: " + ', '.join(f'{k} {v:.2f}' for k, v in rows['ratio_after_over_before'].items()))
    print(f"load average {summary['load_average_at_end']}, {summary['wall_s']:.0f} s")
    return 0 if all(r['exit_code'] == 0 for r in runs) else 1


if __name__ == '__main__':
    sys.exit(main())
