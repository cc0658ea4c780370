"""How many of a real-time run's ``/sim/state`` messages carry another step's ``/clock`` as their bag log time.

    .venv/bin/python -m lab.benchmarks.recorder_logtime [--steps 2] [--batch-waits 0,0.002]

For each recorder ``batch_wait`` given: the whole graph (``biped_sim.graph.launch``, its own ROS domain,
127.0.0.1) walks ``--steps`` steps at ``real_time_factor`` 1.0; the bag's ``/sim/state`` messages whose log time
differs from their own stamp are counted (the recorder's log time is the latest ``/clock`` published before the
message, looked up by DDS source timestamp among those received; the simulator
publishes ``/clock`` k just before ``/sim/state`` k). Nothing is asserted (the test
is ``tests/test_recorder.py::test_node_log_time_is_the_clock_published_before_each_message``).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.domain import Domain  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='recorder_logtime', description=__doc__.split('\n\n')[0])
    ap.add_argument('--steps', type=int, default=2)
    ap.add_argument('--batch-waits', default='0,0.002', help='comma-separated recorder batch_wait values (s)')
    a = ap.parse_args(argv)
    import yaml
    from biped_sim.recording.bag_reader import read_bag
    status = 0
    for bw in (float(x) for x in a.batch_waits.split(',')):
        with tempfile.TemporaryDirectory() as tmp, Domain() as dom:
            tree = yaml.safe_load((ROOT / 'config' / 'graph.yaml').read_text())
            tree['recorder']['ros__parameters']['batch_wait'] = bw
            params = Path(tmp) / 'graph.yaml'
            params.write_text(yaml.safe_dump(tree))
            bag = Path(tmp) / 'bag'
            r = subprocess.run([sys.executable, '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--steps',
                                str(a.steps), '--params', str(params), '--sim-param', 'real_time_factor:=1.0'],
                               cwd=ROOT, env=dom.env, capture_output=True, text=True, timeout=600)
            status |= r.returncode
            d = read_bag(bag, decode=True)
            states = [(lt, m) for t, lt, _, m in d['messages'] if t == '/sim/state']
            other = sum(lt != m.stamp.sec * 10**9 + m.stamp.nanosec for lt, m in states)
            print(f'batch_wait {bw} s: launch exit {r.returncode}, /sim/state {len(states)}, '
                  f'log time != own stamp {other}', flush=True)
    return status


if __name__ == '__main__':
    sys.exit(main())
