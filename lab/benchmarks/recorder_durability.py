"""Recorder durability: what a SIGKILL of the recorder loses at real time, and what syncing costs.

    .venv/bin/python -m lab.benchmarks.recorder_durability [--kills 10] [--before 3] [--seed 20] [--json FILE]

**Kills** (the whole graph from ``biped_sim.graph.launch``, ``--steps 0``, paced at ``real_time_factor`` 1.0,
each launch in its own ROS domain from ``domain_coordinator``, 127.0.0.1 only). Per run: once ``/clock``
runs, wait a seeded random wall time (uniform in ``[--min-wait, --max-wait]`` s, ``random.Random(seed)``),
note the wall time (``time.time_ns()``, CLOCK_REALTIME, the clock DDS source timestamps use) and SIGKILL
the recorder; the launcher stops the graph. A plain DDS subscriber in this process (raw, keep-last 5000,
its own thread) keeps every ``/clock`` with its source timestamp; the **sim time at the kill** is the
latest ``/clock`` published before the kill instant (by source timestamp, so this probe's own lag under
load does not count). From the bag alone (``bag_reader.read_truncated``: the messages of its complete
chunks): **lost = sim time at the kill - the last recorded log time** (sim s), and in wall terms the kill
instant - the latest recorded ``publish_time``. ``bag_reader.recover_bag`` rewrites the bag into a
finished one that ``read_bag`` must open with the same message count. Configurations, interleaved so the machine's drift hits both alike:
``after`` = ``config/graph.yaml`` as committed (chunks closed by size or by ``chunk_time``), ``before`` =
the same with ``chunk_time: 0`` (by size only, the behaviour before the durability changes), ``--before`` runs of it.

**Sync cost** (the writer alone, no ROS): the messages of the first recovered bag replayed through
``Rosbag2McapWriter`` into a fresh bag as fast as possible, ``sync`` off and on alternately (``--sync-reps``
pairs), chunks closed every 15 topics x 50 messages (what ``chunk_time`` 0.05 s gives at 1 kHz; the
writer's clock is the replayed log time): wall time per message, and per ``fdatasync`` of a chunk.

Nothing is asserted; figures are printed (and ``--json``). The machine is shared: read ratios beside
the absolute figures.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # `python lab/benchmarks/recorder_durability.py`
    sys.path.insert(0, str(ROOT))

from benchmarks.domain import Domain  # noqa: E402
from biped_controller.studies import provenance


class ClockProbe:
    """Every ``/clock`` as (DDS source timestamp ns, sim time ns), spun in its own thread."""

    def __init__(self, domain: int):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from biped_sim.graph import names as gn
        from biped_sim.graph.recorder_node import recording_qos
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node('durability_probe', context=self.ctx)
        self.rows: list[tuple[int, int]] = []
        spec = gn.TOPICS[gn.CLOCK]
        self.node.create_subscription(spec.msg_class(), gn.CLOCK, self._on, recording_qos(spec.qos_profile), raw=True)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on(self, msg: bytes, info) -> None:
        from biped_sim.live.bridge_core import clock_ns
        self.rows.append((int(info['source_timestamp']), clock_ns(msg)))

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def sim_time_before(self, wall_ns: int) -> float | None:
        """The latest sim time [s] published at or before ``wall_ns`` (source timestamp)."""
        times = [sim for src, sim in self.rows if src <= wall_ns]
        return max(times) * 1e-9 if times else None

    def close(self) -> None:
        import rclpy
        self._stop.set()
        self._thread.join(10)
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


def params_file(tmp: Path, chunk_time: float | None) -> Path:
    """config/graph.yaml, with the recorder's chunk_time replaced when given."""
    tree = yaml.safe_load((ROOT / 'config' / 'graph.yaml').read_text())
    if chunk_time is not None:
        tree['recorder']['ros__parameters']['chunk_time'] = chunk_time
    path = tmp / f'graph_{chunk_time}.yaml'
    path.write_text(yaml.safe_dump(tree))
    return path


def kill_run(dom: Domain, tmp: Path, params: Path, wait: float, timeout: float = 180.0) -> dict:
    """One launch; SIGKILL of the recorder ``wait`` wall s after /clock started; what the bag kept."""
    from biped_sim.graph.soak import node_pids
    from biped_sim.recording.bag_reader import read_bag, read_truncated, recover_bag
    tmp.mkdir(parents=True, exist_ok=True)
    bag, ready, log = tmp / 'bag', tmp / 'ready', tmp / 'launch.log'
    cmd = [sys.executable, '-m', 'biped_sim.graph.launch', '--params', str(params), '--bag', str(bag),
           '--ready-file', str(ready), '--steps', '0', '--sim-param', 'real_time_factor:=1.0',
           '--sim-param', 'max_time:=600.0']
    probe = ClockProbe(dom.id)
    out: dict = {'wait_s': wait}
    try:
        with open(log, 'w') as fh:
            proc = subprocess.Popen(cmd, cwd=ROOT, env=dom.env, stdout=fh, stderr=subprocess.STDOUT)
        try:
            t0 = time.monotonic()
            while not probe.rows:
                if proc.poll() is not None or time.monotonic() - t0 > timeout:
                    raise RuntimeError('the graph did not start: ' + log.read_text(errors='replace')[-1500:])
                time.sleep(0.01)
            first_src = probe.rows[0][0]
            time.sleep(wait)
            pid = node_pids(proc.pid)['recorder']
            kill_ns = time.time_ns()
            os.kill(pid, signal.SIGKILL)
            proc.wait(timeout)
            out['launcher_exit_code'] = proc.returncode
            time.sleep(0.5)   # the probe takes what is still queued for it
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    finally:
        probe.close()
    out['sim_time_at_kill'] = probe.sim_time_before(kill_ns)
    # sim s per wall s from the first /clock to the kill: below 1 on a loaded machine, where a wall-clock
    # chunk_time holds fewer sim seconds of messages
    out['real_time_factor_reached'] = out['sim_time_at_kill'] / ((kill_ns - first_src) * 1e-9)
    d = read_truncated(bag)
    last = (d['end_ns'] or 0) * 1e-9
    last_pub = max((m[2] for m in d['messages']), default=0)
    out.update(complete_chunks=d['complete_chunks'], bad_chunks=d['bad_chunks'], messages=d['message_count'],
               last_recorded_sim_time=last, lost_s=out['sim_time_at_kill'] - last,
               lost_wall_s=(kill_ns - last_pub) * 1e-9, mcap_bytes=os.path.getsize(next(bag.glob('*.mcap'))))
    rep = recover_bag(bag, tmp / 'recovered')
    back = read_bag(tmp / 'recovered')
    out['recovered_messages'] = rep.message_count
    out['recovered_readable'] = bool(back['has_summary'] and back['message_count'] == d['message_count'])
    from mcap.reader import make_reader
    with open(rep.mcap_path, 'rb') as f:   # how much sim time a chunk of a given size holds
        summary = make_reader(f).get_summary()
    span = (back['end_ns'] - back['start_ns']) * 1e-9 if back['end_ns'] else 0.0
    out['uncompressed_bytes_per_sim_s'] = (sum(ci.uncompressed_size for ci in summary.chunk_indexes) / span
                                           if span > 0 else None)
    out['recovered_bag'] = str(tmp / 'recovered')
    return out


def sync_cost(bag: Path, tmp: Path, reps: int) -> dict:
    """Replay a bag's messages through the writer, sync off / on alternately (see the module doc)."""
    from biped_sim.recording import mcap_recorder
    from biped_sim.recording.bag_reader import read_bag
    from biped_sim.recording.mcap_recorder import Rosbag2McapWriter
    from mcap.reader import make_reader
    d = read_bag(bag)
    with open(next(bag.glob('*.mcap')), 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        types = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        rows = [(c.topic, m.data, m.log_time, m.publish_time) for _, c, m in reader.iter_messages()]
    per_chunk = 15 * 50
    res = {'messages': len(rows), 'source_messages': d['message_count'], 'off': [], 'on': [], 'fdatasync_ms': []}
    real_sync = os.fdatasync

    def timed_sync(fd):
        t = time.perf_counter()
        real_sync(fd)
        res['fdatasync_ms'].append((time.perf_counter() - t) * 1e3)

    for i in range(reps):
        for sync in (False, True):
            out = tmp / f'sync_{i}_{int(sync)}'
            fake = {'t': 0.0}
            w = Rosbag2McapWriter(out, prefixes=[], compression='zstd', chunk_size=1 << 24, chunk_time=0.05,
                                  sync=sync, clock=lambda: fake['t'])
            for topic in types:
                w.register_topic(topic, types[topic], definition=summary.schemas[
                    next(c.schema_id for c in summary.channels.values() if c.topic == topic)].data.decode())
            mcap_recorder.os.fdatasync = timed_sync
            try:
                t = time.perf_counter()
                for k, (topic, data, lt, pt) in enumerate(rows):
                    fake['t'] = (k // per_chunk) * 0.05   # a new chunk every per_chunk messages
                    w.write(topic, types[topic], data, lt, pt)
                w.finish()
                wall = time.perf_counter() - t
            finally:
                mcap_recorder.os.fdatasync = real_sync
            res['on' if sync else 'off'].append({'wall_s': wall, 'us_per_message': 1e6 * wall / len(rows),
                                                 'chunks': w.chunks_written, 'syncs': w.syncs})
            shutil.rmtree(out)
    return res


def _stats(values) -> dict:
    a = np.asarray(values, dtype=float)
    if not a.size:
        return {'n': 0}
    return {'n': int(a.size), 'p50': float(np.percentile(a, 50)), 'p99': float(np.percentile(a, 99)),
            'max': float(a.max()), 'mean': float(a.mean())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='recorder_durability', description=__doc__.split('\n\n')[0])
    ap.add_argument('--kills', type=int, default=10, help='kills with the committed settings')
    ap.add_argument('--before', type=int, default=3, help='kills with chunk_time 0 (size only), interleaved')
    ap.add_argument('--seed', type=int, default=20)
    ap.add_argument('--min-wait', type=float, default=2.0, help='wall s after /clock starts, at least')
    ap.add_argument('--max-wait', type=float, default=8.0, help='wall s after /clock starts, at most')
    ap.add_argument('--sync-reps', type=int, default=3)
    ap.add_argument('--json', type=Path, default=None)
    a = ap.parse_args(argv)
    provenance.track(a.json, argv=argv)   # record of each file written (results/README.md)
    rng = random.Random(a.seed)
    t0 = time.monotonic()
    plan = ['after'] * a.kills
    for k in range(a.before):   # spread the before-runs among the after-runs
        plan.insert(min(len(plan), (k * (a.kills + a.before)) // max(1, a.before) + 1), 'before')
    waits = [rng.uniform(a.min_wait, a.max_wait) for _ in plan]
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        params = {'after': params_file(tmp, None), 'before': params_file(tmp, 0.0)}
        for i, (kind, wait) in enumerate(zip(plan, waits)):
            with Domain() as dom:
                try:
                    r = kill_run(dom, tmp / f'{kind}_{i}', params[kind], wait)
                except (RuntimeError, KeyError, subprocess.TimeoutExpired) as exc:
                    r = {'wait_s': wait, 'error': repr(exc)}
            r['kind'] = kind
            runs.append(r)
            print(json.dumps({k: v for k, v in r.items() if k != 'recovered_bag'}), flush=True)
        first = next((r for r in runs if r['kind'] == 'after' and 'recovered_bag' in r), None)
        sync = sync_cost(Path(first['recovered_bag']), tmp, a.sync_reps) if first else None
    for r in runs:
        r.pop('recovered_bag', None)
    summary = {'date': time.strftime('%Y-%m-%d %H:%M:%S'), 'cpus': os.cpu_count(), 'machine': platform.machine(),
               'seed': a.seed, 'load_average_at_end': os.getloadavg(), 'wall_s': time.monotonic() - t0,
               'chunk_time_after': yaml.safe_load((ROOT / 'config' / 'graph.yaml').read_text())
               ['recorder']['ros__parameters'].get('chunk_time'),
               'lost_s': {k: _stats([r['lost_s'] for r in runs if r['kind'] == k and 'lost_s' in r])
                          for k in ('after', 'before')},
               'lost_wall_s': {k: _stats([r['lost_wall_s'] for r in runs if r['kind'] == k and 'lost_wall_s' in r])
                               for k in ('after', 'before')},
               'real_time_factor_reached': _stats([r['real_time_factor_reached'] for r in runs
                                                   if r.get('real_time_factor_reached')]),
               'runs': runs}
    if sync:
        off = [x['us_per_message'] for x in sync['off']]
        on = [x['us_per_message'] for x in sync['on']]
        summary['sync'] = {**sync, 'fdatasync_ms': _stats(sync['fdatasync_ms']),
                           'us_per_message_off': off, 'us_per_message_on': on,
                           'on_over_off': float(np.mean(on) / np.mean(off))}
    print('==== recorder durability ====')
    for k in ('after', 'before'):
        s, w = summary['lost_s'][k], summary['lost_wall_s'][k]
        if s['n']:
            print(f"{k:6s} ({'chunk_time ' + str(summary['chunk_time_after']) + ' s' if k == 'after' else 'size only'}): "
                  f"{s['n']} kills, lost p50 {1e3 * s['p50']:.0f} ms, max {1e3 * s['max']:.0f} ms of sim time "
                  f"(wall: p50 {1e3 * w['p50']:.0f} ms, max {1e3 * w['max']:.0f} ms), "
                  f"all recovered readable: {all(r.get('recovered_readable') for r in runs if r['kind'] == k)}")
    rt = summary['real_time_factor_reached']
    if rt['n']:
        print(f"real-time factor reached before the kills (sim s / wall s): p50 {rt['p50']:.2f}, "
              f"min {min(r['real_time_factor_reached'] for r in runs if r.get('real_time_factor_reached')):.2f}")
    if sync:
        s = summary['sync']
        print(f"sync cost: {s['messages']} messages, us/message off {', '.join(f'{x:.1f}' for x in s['us_per_message_off'])}"
              f", on {', '.join(f'{x:.1f}' for x in s['us_per_message_on'])} (on/off {s['on_over_off']:.2f}); "
              f"fdatasync p50 {s['fdatasync_ms']['p50']:.2f} ms, p99 {s['fdatasync_ms']['p99']:.2f} ms "
              f"({s['fdatasync_ms']['n']} syncs)")
    print(f"load average {summary['load_average_at_end']}, {summary['wall_s']:.0f} s")
    if a.json:
        a.json.write_text(json.dumps(summary, indent=2) + '\n')
    return 0 if all('error' not in r for r in runs) else 1


if __name__ == '__main__':
    sys.exit(main())
