"""The recorded bag is the same with the nodes publishing CDR bytes (``publish_cdr`` true, the default) and
message objects (false): two deterministic lockstep runs of the graph (``biped_sim.graph.launch --steps 1``,
no push, as fast as the lockstep allows), compared message by message: per topic, the same number of
messages and the same CDR bytes in the same order. The launcher's output shows which way each run published
(the nodes log it), so the comparison cannot pass with the parameter ignored; the comparison itself is
checked on a copy with one byte changed (negative control). Waits are bounded by the launcher's exit.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from helpers import ROOT

PY = ROOT / '.venv' / 'bin' / 'python'
#: the topics the simulator and the controller publish every control step as bytes with publish_cdr
PER_STEP = ('/clock', '/imu', '/sim/state', '/tf', '/stance', '/joint_states', '/ground_reaction',
            '/ground_reaction/cop', '/sim/push', '/controller/torque', '/controller/status')


def _bag_messages(bag: Path) -> dict[str, list[bytes]]:
    """topic -> the CDR bytes of its messages in file order (the recorder's order of receipt, per topic DDS's)."""
    from mcap.reader import make_reader
    from biped_sim.recording.bag_reader import find_mcap
    out: dict[str, list[bytes]] = {}
    with open(find_mcap(bag), 'rb') as fh:
        for _s, ch, msg in make_reader(fh).iter_messages(log_time_order=False):
            out.setdefault(ch.topic, []).append(bytes(msg.data))
    return out


def _differences(a: dict[str, list[bytes]], b: dict[str, list[bytes]]) -> list[str]:
    out = []
    for topic in sorted(set(a) | set(b)):
        x, y = a.get(topic, []), b.get(topic, [])
        if len(x) != len(y):
            out.append(f'{topic}: {len(x)} vs {len(y)} messages')
            continue
        bad = [i for i, (p, q) in enumerate(zip(x, y)) if p != q]
        if bad:
            out.append(f'{topic}: {len(bad)} of {len(x)} messages differ, first #{bad[0]}')
    return out


def _run(tmp: Path, env: dict, cdr_on: bool) -> tuple[dict[str, list[bytes]], str]:
    bag = tmp / f'bag_{cdr_on}'
    flag = 'true' if cdr_on else 'false'
    cmd = [str(PY), '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--steps', '1',
           '--sim-param', f'publish_cdr:={flag}', '--ctrl-param', f'publish_cdr:={flag}']
    p = subprocess.run(cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stdout[-3000:]
    return _bag_messages(bag), p.stdout


@pytest.mark.ros
@pytest.mark.slow
def test_bag_bytes_equal_with_publish_cdr_on_and_off(ros_env, tmp_path):
    on, out_on = _run(tmp_path, ros_env, True)
    off, out_off = _run(tmp_path, ros_env, False)
    what = 'publishing CDR bytes'
    assert out_on.count(what) == 2 and 'publishing message objects' not in out_on, out_on[-3000:]
    assert out_off.count('publishing message objects') == 2 and what not in out_off, out_off[-3000:]
    assert set(PER_STEP) <= set(on), sorted(on)
    assert len(on['/sim/state']) > 300          # one walking step: ~460 control steps
    assert _differences(on, off) == []
    # negative control: one byte of one message changed, one message dropped
    changed = {t: list(v) for t, v in on.items()}
    m = bytearray(changed['/controller/status'][100])
    m[-1] ^= 1
    changed['/controller/status'][100] = bytes(m)
    changed['/tf'] = changed['/tf'][:-1]
    assert _differences(on, changed) == ['/controller/status: 1 of %d messages differ, first #100'
                                         % len(on['/controller/status']),
                                         f'/tf: {len(on["/tf"])} vs {len(on["/tf"]) - 1} messages']
