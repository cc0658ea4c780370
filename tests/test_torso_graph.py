"""Mode ``all`` over the real node graph: Fast DDS on loopback, isolated domain (``ros_domain``).

The launcher starts the graph with the controller node's parameter ``mode:=all``, one push goes through
/apply_push, and the MCAP bag (read back by ``bag_reader``) must hold the in-process run's trajectory bit
for bit and the torso parameter's status fields (lam, lam_dot, lam_ddot, lam_ddot_star) equal to the
in-process statuses, with lambda moved by the push (negative control: mode both's run differs).
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PY = ROOT / '.venv' / 'bin' / 'python'
STEPS = 1
PUSH = dict(force=400.0, duration=0.025, start=0.2315)

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_mode_all_over_dds_equals_the_in_process_run(ros_domain, rclpy_context, tmp_path):
    from biped_sim.graph.push_client import call_apply_push
    from biped_sim.plant.push import Push
    from biped_sim.recording.bag_reader import read_bag
    from biped_controller.closed_loop import runner

    bag, ready = tmp_path / 'bag', tmp_path / 'ready'
    cmd = [str(PY), '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--ready-file', str(ready),
           '--steps', str(STEPS), '--sim-param', 'wait_for_pushes:=1', '--ctrl-param', 'mode:=all']
    proc = subprocess.Popen(cmd, env=dict(os.environ), cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        import time
        t0 = time.monotonic()
        while not ready.exists():
            assert proc.poll() is None, f'launcher died: {proc.communicate()[0][-3000:]}'
            assert time.monotonic() - t0 < 120, 'graph did not come up'
            time.sleep(0.05)
        res = call_apply_push(PUSH['force'], PUSH['duration'], start=PUSH['start'], timeout=60,
                              context=rclpy_context)
        assert res.accepted, res
        out, _ = proc.communicate(timeout=300)
        assert proc.returncode == 0, out[-3000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    ref = runner.run(steps=STEPS, mode='all', pushes=(Push(PUSH['start'], PUSH['duration'], PUSH['force']),))
    d = read_bag(bag, decode=True)
    states = [m for t, _, _, m in d['messages'] if t == '/sim/state']
    status = [m for t, _, _, m in d['messages'] if t == '/controller/status']
    assert len(states) == len(ref.records) + 1
    for k, rec in enumerate(ref.records):
        assert np.array_equal(np.array(states[k].q), rec.q), k
        assert np.array_equal(np.array(states[k].q_dot), rec.qd), k
    by_step = {int(m.step): m for m in status}
    # the node also answers the final state (after the last impact), which the in-process run does not ask
    assert {s.step for s in ref.statuses} <= set(by_step) and len(by_step) <= len(ref.statuses) + 1
    for s in ref.statuses:
        m = by_step[s.step]
        assert m.mode == 'all'
        assert (m.lam, m.lam_dot, m.lam_ddot, m.lam_ddot_star) == (s.lam, s.lam_dot, s.lam_ddot, s.lam_ddot_star), s.step
    assert max(abs(m.lam) for m in status) > 1e-4
    # negative control: mode both's in-process trajectory is another one
    other = runner.run(steps=STEPS, mode='both', pushes=(Push(PUSH['start'], PUSH['duration'], PUSH['force']),))
    assert any(not np.array_equal(a.q, b.q) for a, b in zip(other.records, ref.records))
