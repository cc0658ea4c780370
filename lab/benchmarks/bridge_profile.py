"""Where the live view's time goes: CPU per process and per thread of the whole graph at real time, with and
without the bridge, and a sampling profile of the bridge's Python thread.

    .venv/bin/python -m lab.benchmarks.bridge_profile [--steps 4] [--pairs 1] [--json FILE] [--py-spy PATH]

Each run is ``benchmarks.bridge_bench.run_graph`` (the whole graph from ``biped_sim.graph.launch``, recorder
included, ``real_time_factor`` 1.0, its own ROS domain, 127.0.0.1): ``off`` = no bridge; ``layout`` =
``--live`` and a WebSocket client on the layout's three topics; ``all`` = a client on every channel; the three
alternated ``--pairs`` times. For each run: the simulator's rate (control steps / wall s), CPU seconds per
process and per thread from the first `/sim/state` (the benchmark's DDS probe) to the process's exit (``benchmarks.proc_cpu``: the scheduler's
own accounting, ``/proc/<pid>/task/<tid>/schedstat``), and the same per control step (ms). Thread names:
``python3``/``python`` = the node's Python thread (executor, callbacks), ``dds.*``/``*recv*``/``*event*``
= Fast DDS's threads, ``tokio-*`` = foxglove-sdk's server (Rust), ``numba``/``Dummy``... as they come.

With ``--py-spy PATH`` (the ``py-spy`` sampling profiler, ``pip install py-spy``; not a project dependency)
the bridge's Python thread is sampled (200 Hz, active samples only) in the ``layout`` and ``all`` runs and the
collapsed stacks are summarised: share of samples per function (self and inclusive), and per phase
(executor round, taking messages, handing them to the SDK, other).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import bridge_bench as bb  # noqa: E402
from benchmarks.proc_cpu import descendants  # noqa: E402
from biped_controller.studies import provenance

PHASES = (   # (phase, substring of a frame) checked from the leaf up: the first phase that matches a frame wins
    ('sdk log (Channel.log)', 'log (foxglove/channel.py'),
    ('take message (rclpy take_message)', 'take_message'),
    ('executor round (rclpy executors.py)', 'rclpy/executors.py'),
    ('bridge callbacks (bridge_node.py)', 'bridge_node.py'),
    ('mcap writer (mcap_recorder.py, mcap)', 'mcap'),
    ('recorder wait set (rcl wait, refill)', '_wait_and_take'),
    ('recorder take and record (recorder_node.py)', 'recorder_node.py'),
)


def summarise(collapsed: Path, top: int = 25) -> dict:
    """py-spy ``--format raw`` (collapsed stacks: ``frame;frame;... count``) -> shares of samples."""
    self_c, incl_c, phase_c = Counter(), Counter(), Counter()
    total = 0
    for line in collapsed.read_text().splitlines():
        stack, _, n = line.rpartition(' ')
        if not stack:
            continue
        n = int(n)
        frames = stack.split(';')
        total += n
        self_c[frames[-1]] += n
        for f in set(frames):
            incl_c[f] += n
        for phase, key in PHASES:
            if any(key in f for f in frames):
                phase_c[phase] += n
                break
        else:
            phase_c['other'] += n
    if not total:
        return {'samples': 0}
    return {'samples': total,
            'phases': {k: round(v / total, 3) for k, v in phase_c.most_common()},
            'self': {k: round(v / total, 3) for k, v in self_c.most_common(top)},
            'inclusive': {k: round(v / total, 3) for k, v in incl_c.most_common(top)}}


class PySpy:
    """``py-spy record`` attached to the node ``node`` (a process of this process's next launcher child), from the
    run's first ``/sim/state`` (seen by the benchmark's DDS probe: the lockstep has started) until the node exits."""

    def __init__(self, exe: str, node: str, out: Path, probes_before: int):
        self.exe, self.node, self.out, self.probes_before = exe, node, out, probes_before
        self._before = set(descendants(os.getpid()))
        self.proc = None
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _bridge_pid(self) -> int | None:
        for pid in descendants(os.getpid()):
            if pid in self._before:
                continue
            try:
                words = Path(f'/proc/{pid}/cmdline').read_text().split('\0')
            except OSError:
                continue
            if bb.node_name(words) == self.node:
                return pid
        return None

    def _run(self) -> None:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            if len(bb.PROBES) > self.probes_before and bb.PROBES[-1].first.is_set():
                pid = self._bridge_pid()
                if pid is not None:
                    self.proc = subprocess.Popen(
                        [self.exe, 'record', '--pid', str(pid), '--rate', '200', '--format', 'raw', '--nonblocking',
                         '-o', str(self.out)], stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
                    return
            time.sleep(0.02)

    def result(self) -> dict:
        self._t.join(200)
        if self.proc is None:
            return {'samples': 0, 'error': f'no {self.node} process found'}
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        return summarise(self.out) if self.out.exists() else {'samples': 0, 'error': 'py-spy wrote nothing'}


def _one(dom, tmp: Path, name: str, setting: str, kind: str, live: bool, only, a, spy) -> dict:
    d = tmp / name
    profs = {}
    if spy:
        d.mkdir(parents=True, exist_ok=True)
        for node in ('bridge', 'live_recorder', 'simulator', 'controller', 'recorder', 'disturbance') if live else (
                'simulator', 'controller', 'recorder', 'disturbance'):
            if node in a.spy_nodes:
                profs[node] = PySpy(spy, node, d / f'{node}.collapsed', len(bb.PROBES))
    load = os.getloadavg()[0]
    r = bb.run_graph(dom, d, live=live, rtf=a.rtf, steps=a.steps, only=only, params=bb.settings_params(tmp, setting),
                     probe=not live)   # one instrument per run: the client in live runs, the DDS probe otherwise
    r.update(kind=kind, setting=setting, load_average_1min_at_start=load)
    if profs:
        r['profiles'] = {node: p.result() for node, p in profs.items()}
    print(json.dumps({x: y for x, y in r.items() if x not in ('bag_counts',)}), flush=True)
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bridge_profile', description=__doc__.split('\n\n')[0])
    ap.add_argument('--steps', type=int, default=4, help='walking steps per run (~0.46 s of sim time each)')
    ap.add_argument('--pairs', type=int, default=1, help='rounds of off / layout / all')
    ap.add_argument('--settings', default='after',
                    help='comma-separated, alternated: before (bridge_bench.BEFORE), after (config/graph.yaml), lazy '
                         '(after with the bridge\'s lazy_streams)')
    ap.add_argument('--py-spy', dest='py_spy', default=None, help='path of py-spy (profile the bridge)')
    ap.add_argument('--spy-nodes', dest='spy_nodes', default='bridge',
                    help='comma-separated nodes to sample with py-spy (bridge,live_recorder,simulator,controller,recorder,disturbance)')
    ap.add_argument('--kinds', default='off,layout,all', help='runs of each round: off, layout, all')
    ap.add_argument('--rtf', type=float, default=1.0, help="the simulator's real_time_factor (0 = as fast as possible)")
    ap.add_argument('--json', type=Path, default=None)
    a = ap.parse_args(argv)
    provenance.track(a.json, argv=argv)   # record of each file written (results/README.md)
    spy = shutil.which(a.py_spy) if a.py_spy else None
    a.spy_nodes = set(a.spy_nodes.split(','))
    a.kinds = set(a.kinds.split(','))
    a.settings = a.settings.split(',')
    if a.py_spy and not spy:
        ap.error(f'--py-spy: {a.py_spy!r} is not an executable')
    runs = []
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp, bb.Domain() as dom:
        for k in range(a.pairs):
            for setting in a.settings:
                for kind, live, only in (('off', False, None), ('layout', True, bb.LAYOUT_TOPICS), ('all', True, None)):
                    if kind not in a.kinds:
                        continue
                    runs.append(_one(dom, Path(tmp), f'{setting}_{kind}_{k}', setting, kind, live, only, a, spy))
    out = {'date': time.strftime('%Y-%m-%d %H:%M:%S'), 'cpus': os.cpu_count(),
           'load_average_at_end': os.getloadavg(), 'wall_s': time.monotonic() - t0, 'runs': runs}
    print('==== CPU per control step (ms), real time ====')
    for r in runs:
        per = r.get('cpu_ms_per_step', {})
        rate = r.get('steps_per_s')
        print(f"{r['setting']:6s} {r['kind']:7s} {rate or 0:6.0f} steps/s  " + '  '.join(f'{k} {v:.3f}' for k, v in sorted(per.items())))
    print(f'load average {out["load_average_at_end"]}')
    if a.json:
        a.json.write_text(json.dumps(out, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
