"""How long the rest of the node graph lives after one of its nodes is killed.

    .venv/bin/python -m lab.benchmarks.launch_fault_stop [--victim recorder] [--trials 5] [--json FILE]
                                                     [--launcher-arg=--fault-stop-timeout=10 ...]

The trials go to ``--json`` (default ``results/node_graph/fault_stop_<victim>.json``; ``--json ''``: none),
with a provenance record beside it (``results/README.md``).

Each trial: the whole graph (``biped_sim.graph.launch --steps 0``: it walks until stopped) in its own ROS domain
on 127.0.0.1; once the bag's file holds ``--warmup-bytes`` bytes, SIGKILL to the victim node's process; then
the exit instant of every other node process and of the launcher, as the kernel reports them (a pidfd per
process becomes readable when that process exits). Printed per trial: each survivor's lifetime after the kill
(wall s), the launcher's exit status and its line naming the dead node, and whether the bag reads (a finished
bag; for a killed recorder, its complete chunks rewritten by ``recover_bag``). Nothing is asserted (the test is
``tests/test_faults.py::test_a_killed_recorder_stops_the_graph``).
"""
from __future__ import annotations

import argparse
import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import RESULTS_DIR  # noqa: E402
from benchmarks.domain import Domain  # noqa: E402
from biped_controller.studies import provenance  # noqa: E402

VICTIMS = ('recorder', 'controller', 'disturbance', 'simulator')
OUT_DIR = RESULTS_DIR.parent / 'node_graph'


def _wait_for(pred, proc: subprocess.Popen, timeout: float, what: str) -> None:
    t0 = time.monotonic()
    while not pred():
        if proc.poll() is not None:
            raise RuntimeError(f'the launcher exited ({proc.returncode}) while waiting for {what}')
        if time.monotonic() - t0 > timeout:
            raise RuntimeError(f'timed out after {timeout} s waiting for {what}')
        time.sleep(0.05)


def exit_times(pidfds: dict[str, int], timeout: float) -> dict[str, float]:
    """Block until every process of ``pidfds`` (name -> pidfd) has exited or ``timeout`` s passed;
    name -> ``time.monotonic()`` at which its exit was seen (absent: still running at the timeout)."""
    seen: dict[str, float] = {}
    poller = select.poll()
    by_fd = {fd: name for name, fd in pidfds.items()}
    for fd in by_fd:
        poller.register(fd, select.POLLIN)
    deadline = time.monotonic() + timeout
    while len(seen) < len(pidfds):
        left = deadline - time.monotonic()
        if left <= 0:
            break
        for fd, _ in poller.poll(left * 1000):
            now = time.monotonic()
            seen.setdefault(by_fd[fd], now)
            poller.unregister(fd)
    return seen


def trial(victim: str, warmup_bytes: int, timeout: float, launcher_args: list[str]) -> dict:
    from biped_sim.graph.soak import node_pids
    from biped_sim.recording.bag_reader import BagReadError, find_mcap, read_bag, recover_bag
    with tempfile.TemporaryDirectory() as tmp, Domain() as dom:
        bag, ready, logf = Path(tmp) / 'bag', Path(tmp) / 'ready', Path(tmp) / 'launch.log'
        cmd = [sys.executable, '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--ready-file', str(ready),
               '--steps', '0', *launcher_args]
        with open(logf, 'w') as out:
            proc = subprocess.Popen(cmd, env=dom.env, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
        pidfds: dict[str, int] = {}
        try:
            _wait_for(ready.exists, proc, 120, 'the graph')
            _wait_for(lambda: any(f.stat().st_size >= warmup_bytes for f in bag.glob('*.mcap')), proc, 120,
                      f'{warmup_bytes} bytes in the bag')
            pids = node_pids(proc.pid)
            if victim not in pids:
                raise RuntimeError(f'no {victim} process among {sorted(pids)}')
            pidfds = {name: os.pidfd_open(pid) for name, pid in pids.items() if name != victim}
            pidfds['launcher'] = os.pidfd_open(proc.pid)
            t_kill = time.monotonic()
            os.kill(pids[victim], signal.SIGKILL)
            seen = exit_times(pidfds, timeout)
            proc.wait(timeout=max(1.0, timeout - (time.monotonic() - t_kill)))
        finally:
            for fd in pidfds.values():
                os.close(fd)
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        text = logf.read_text(errors='replace')
        lines = [ln for ln in text.splitlines() if (ln.startswith('launch:') and 'died' in ln)
                 or 'not acknowledged' in ln]
        if victim == 'recorder':
            try:
                report = recover_bag(find_mcap(bag), Path(tmp) / 'recovered')
                bag_state = f'recovered: {report.message_count} messages'
            except (BagReadError, OSError) as exc:   # reported, not raised: the measurement goes on
                bag_state = f'not recovered: {type(exc).__name__}: {exc}'
        else:
            try:
                d = read_bag(bag)
                bag_state = f'finished: {sum(d["counts"].values())} messages' if d['has_summary'] else 'no summary'
            except (BagReadError, OSError) as exc:   # reported, not raised
                bag_state = f'unreadable: {type(exc).__name__}: {exc}'
        return {'victim': victim,
                'lived_s': {name: round(seen[name] - t_kill, 3) if name in seen else None for name in pidfds},
                'launcher_rc': proc.returncode, 'launcher_says': lines, 'bag': bag_state}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='launch_fault_stop', description=__doc__.split('\n\n')[0])
    ap.add_argument('--victim', choices=VICTIMS, default='recorder')
    ap.add_argument('--trials', type=int, default=5)
    ap.add_argument('--warmup-bytes', type=int, default=300_000, help='bag size before the kill')
    ap.add_argument('--timeout', type=float, default=120.0, help='s to wait for the survivors')
    ap.add_argument('--json', type=str, default=None,
                    help="write the trials here (default results/node_graph/fault_stop_<victim>.json; '': none)")
    ap.add_argument('--launcher-arg', action='append', default=[], metavar='ARG',
                    help='extra launcher argument (repeatable), e.g. --launcher-arg=--fault-stop-timeout=10')
    a = ap.parse_args(argv)
    if a.trials < 1:
        ap.error(f'--trials must be >= 1, got {a.trials}')
    out = OUT_DIR / f'fault_stop_{a.victim}.json' if a.json is None else (Path(a.json) if a.json else None)
    provenance.track(out, argv=argv)   # record of each file written (results/README.md)
    rows = []
    for k in range(a.trials):
        r = trial(a.victim, a.warmup_bytes, a.timeout, a.launcher_arg)
        rows.append(r)
        last = max((v for v in r['lived_s'].values() if v is not None), default=None)
        print(f'trial {k + 1}: {a.victim} killed; survivors gone after '
              + ', '.join(f'{n} {v} s' for n, v in r['lived_s'].items())
              + f'; all gone after {last} s; launcher exit {r["launcher_rc"]}; bag {r["bag"]}')
        for ln in r['launcher_says']:
            print(f'    {ln}')
        sys.stdout.flush()
    worst = [max(v if v is not None else float('inf') for v in r['lived_s'].values()) for r in rows]
    print(f'{a.victim} killed, {a.trials} trials: the last survivor gone after '
          + ', '.join(f'{w:.2f}' for w in worst) + ' s; load average ' + ' '.join(f'{x:.2f}' for x in os.getloadavg()))
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({'victim': a.victim, 'trials': rows}, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
