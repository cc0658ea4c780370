"""The whole recorded graph's lockstep rate at this tree and at an earlier revision, alternated in one run.

    .venv/bin/python -m lab.benchmarks.recorder_before_after --before-rev REV [--pairs 3] [--sim-seconds 3]

Each pair runs ``biped_sim.graph.launch`` unpaced (``real_time_factor`` 0: as fast as the lockstep allows) for
``--sim-seconds`` of simulated time, once with the code at ``--before-rev`` (a temporary detached worktree, its
``src`` first on ``PYTHONPATH``, its own ``config/``; ``bridge_bench.Revision``) and once with this tree, in
alternating order (before first in even pairs), each in its own ROS domain on 127.0.0.1. The rate is the
simulator's own end-of-run line (control steps / wall seconds from its first published state), as
``scripts/bench``'s ``dds.lockstep_with_recorder_steps_per_s``. Written: per-run rates, per-pair ratios
after / before, and their medians, with the load average before and after (the machine varies; only the
ratios of runs taken side by side compare). Nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.bridge_bench import Revision  # noqa: E402
from benchmarks.domain import Domain  # noqa: E402
from benchmarks.lockstep import _LINE  # noqa: E402
from biped_controller.studies import provenance  # noqa: E402

OUT = ROOT / 'results' / 'benchmarks' / 'recorder_before_after.json'


def one_run(sim_seconds: float, revision: Revision | None, timeout: float = 600.0) -> dict:
    """One unpaced recorded run; its rate from the simulator's line, the bag's size."""
    with Domain() as dom, tempfile.TemporaryDirectory() as tmp:
        cwd, env = (ROOT, dom.env) if revision is None else (revision.path, revision.env(dom.env))
        bag = Path(tmp) / 'bag'
        p = subprocess.run([sys.executable, '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--steps', '0',
                            '--sim-param', f'max_time:={sim_seconds}', '--sim-param', 'linger:=0.0'],
                           cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
        text = p.stdout + p.stderr
        m = _LINE.search(text)
        if p.returncode != 0 or m is None:
            raise RuntimeError(f'launch exit {p.returncode}: ' + text[-400:].replace('\n', ' | '))
        steps, wall = int(m['steps']), float(m['wall'])
        size = sum(f.stat().st_size for f in bag.rglob('*') if f.is_file()) if bag.exists() else 0
        return {'steps': steps, 'wall_s': wall, 'sim_s': float(m['sim']), 'steps_per_s': steps / wall,
                'bag_bytes': size}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='recorder_before_after', description=__doc__.split('\n\n')[0])
    ap.add_argument('--before-rev', required=True, help='git revision of the "before" code')
    ap.add_argument('--pairs', type=int, default=3)
    ap.add_argument('--sim-seconds', type=float, default=3.0)
    ap.add_argument('--json', default=str(OUT), help="output file ('' none)")
    a = ap.parse_args(argv)
    if a.pairs < 1:
        ap.error(f'--pairs must be >= 1, got {a.pairs}')
    if not a.sim_seconds > 0:
        ap.error(f'--sim-seconds must be > 0, got {a.sim_seconds}')
    out = Path(a.json) if a.json else None
    provenance.track(out, argv=argv)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        rev = Revision(a.before_rev, Path(tmp))
        try:
            for k in range(a.pairs):
                order = ('before', 'after') if k % 2 == 0 else ('after', 'before')
                pair = {}
                for side in order:
                    r = one_run(a.sim_seconds, rev if side == 'before' else None)
                    pair[side] = r
                    print(f'pair {k} {side:6s} {r["steps_per_s"]:7.1f} steps/s ({r["steps"]} steps, '
                          f'{r["wall_s"]:.2f} s wall)', flush=True)
                pair['ratio_after_over_before'] = pair['after']['steps_per_s'] / pair['before']['steps_per_s']
                runs.append(pair)
        finally:
            rev.close()
    ratios = [p['ratio_after_over_before'] for p in runs]
    res = {'before_rev': rev.rev, 'pairs': runs, 'median_ratio_after_over_before': statistics.median(ratios),
           'median_steps_per_s': {s: statistics.median(p[s]['steps_per_s'] for p in runs) for s in ('before', 'after')},
           'sim_seconds': a.sim_seconds, 'load_average_before': load0, 'load_average_after': os.getloadavg(),
           'wall_s': time.perf_counter() - t0, 'cpus': os.cpu_count()}
    print(f'median after/before {res["median_ratio_after_over_before"]:.3f} '
          f'(before {res["median_steps_per_s"]["before"]:.1f}, after {res["median_steps_per_s"]["after"]:.1f} steps/s; '
          f'load {load0[0]:.2f} -> {res["load_average_after"][0]:.2f})')
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
