"""The node graph over real DDS (Fast DDS on loopback, isolated domain from the ros_domain fixture).

One short walk (2 steps, a push through /apply_push) is launched once per module and shared by
(a)-(d); (e) launches its own graph and interrupts it.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PY = ROOT / '.venv' / 'bin' / 'python'
STEPS = 2
PUSH = dict(force=250.0, duration=0.025, start=0.2315)

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def _descendants(pid: int) -> set[int]:
    from biped_sim.graph.soak import descendants
    return set(descendants(pid))


def _alive(pids) -> list[int]:
    alive = []
    for p in pids:
        try:
            with open(f'/proc/{p}/stat') as fh:
                if fh.read().split(')')[-1].split()[0] != 'Z':
                    alive.append(p)
        except OSError:
            pass
    return alive


def _kill_tree(proc: subprocess.Popen, pids: set[int]) -> None:
    for p in _alive(pids | {proc.pid}):
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        pass


def _launch(tmp: Path, env: dict, *extra: str) -> tuple[subprocess.Popen, Path, Path]:
    bag = tmp / 'bag'
    ready = tmp / 'ready'
    cmd = [str(PY), '-m', 'biped_sim.graph.launch', '--bag', str(bag), '--ready-file', str(ready), *extra]
    proc = subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, bag, ready


def _wait_ready(proc, ready: Path, timeout=90.0):
    t0 = time.monotonic()
    while not ready.exists():
        assert proc.poll() is None, f'launcher died: {proc.communicate()[0][-3000:]}'
        assert time.monotonic() - t0 < timeout, 'graph did not come up'
        time.sleep(0.05)


@pytest.fixture(scope='module')
def walk(tmp_path_factory):
    """Launch the graph (2 steps, simulator paused until one push), probe the graph, push, wait."""
    import rclpy
    from biped_sim.graph import names as gn
    from biped_sim.graph.push_client import call_apply_push

    mp = pytest.MonkeyPatch()
    try:
        from domain_coordinator import domain_id
        dom_cm = domain_id()
        did = dom_cm.__enter__()
    except ImportError:  # pragma: no cover
        dom_cm, did = None, 1 + os.getpid() % 100
    mp.setenv('ROS_DOMAIN_ID', str(did))
    mp.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env = dict(os.environ)
    tmp = tmp_path_factory.mktemp('walk')
    proc, bag, ready = _launch(tmp, env, '--steps', str(STEPS), '--sim-param', 'wait_for_pushes:=1')
    pids: set[int] = set()
    result = {'bag': bag, 'domain': did}
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        _wait_ready(proc, ready)
        node = rclpy.create_node('test_probe', context=ctx)
        # (a) every topic has a publisher and a subscriber (the recorder subscribes to all)
        deadline = time.monotonic() + 60
        while True:
            pids |= _descendants(proc.pid)
            topics = {}
            for t in gn.TOPICS:
                topics[t] = (len(node.get_publishers_info_by_topic(t)), len(node.get_subscriptions_info_by_topic(t)))
            missing_pub = [t for t, (p, s) in topics.items() if p == 0 and t != gn.FALL]
            missing_sub = [t for t, (p, s) in topics.items() if s == 0]
            nodes = set(node.get_node_names())
            missing_node = {'simulator', 'controller', 'disturbance', 'recorder'} - nodes
            services = dict(node.get_service_names_and_types())
            if (not (missing_pub or missing_sub or missing_node) and gn.APPLY_PUSH in services) \
                    or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        result['topics'] = topics
        result['services'] = services
        result['nodes'] = nodes
        node.destroy_node()
        # (b) a NaN force is rejected naming 'force'; then the real push
        bad = call_apply_push(math.nan, 0.025, start=0.3, timeout=30, context=ctx)
        result['rejected'] = bad
        res = call_apply_push(PUSH['force'], PUSH['duration'], start=PUSH['start'], timeout=30, context=ctx)
        result['accepted'] = res
        out, _ = proc.communicate(timeout=240)
        result['launcher_rc'] = proc.returncode
        result['launcher_out'] = out
        result['orphans'] = _alive(pids)
        yield result
    finally:
        if proc.poll() is None:
            _kill_tree(proc, pids | _descendants(proc.pid))
        else:
            _kill_tree(proc, pids)
        if ctx.ok():
            rclpy.shutdown(context=ctx)
        if dom_cm is not None:
            dom_cm.__exit__(None, None, None)
        mp.undo()


def _decoded(bag):
    from biped_sim.recording.bag_reader import read_bag
    return read_bag(bag, decode=True)


def test_a_graph_comes_up(walk):
    from biped_sim.graph import names as gn
    for name in ('simulator', 'controller', 'disturbance', 'recorder'):
        assert name in walk['nodes'], walk['nodes']
    for topic, (pubs, subs) in walk['topics'].items():
        assert subs >= 1, f'{topic} has no subscriber'
        if topic != gn.FALL:  # /fall is published only on a fall (latched); its publisher exists anyway
            assert pubs >= 1, f'{topic} has no publisher'
    assert gn.APPLY_PUSH in walk['services']
    assert walk['launcher_rc'] == 0, walk['launcher_out'][-3000:]
    assert walk['orphans'] == []


def test_b_push_applied_at_requested_time_and_nan_rejected(walk):
    bad = walk['rejected']
    assert not bad.accepted and 'force' in bad.message and bad.push_id == 0
    ok = walk['accepted']
    assert ok.accepted and ok.push_id == 1, ok.message
    assert ok.scheduled_start == PUSH['start'] and ok.scheduled_end == PUSH['start'] + PUSH['duration']
    d = _decoded(walk['bag'])
    msgs = d['messages']
    events = [m for t, _, _, m in msgs if t == '/push_events']
    assert len(events) == 1 and events[0].start == PUSH['start'] and events[0].force == PUSH['force']
    reqs = [m.data for t, _, _, m in msgs if t == '/push_requests']
    assert len(reqs) == 2 and 'accepted: false' in reqs[0] and 'accepted: true' in reqs[1]
    # the effect: compare with the same walk without a push, in process
    from biped_controller.closed_loop import runner
    free = runner.run(steps=STEPS)
    states = [m for t, _, _, m in msgs if t == '/sim/state']
    k0 = int(math.floor(PUSH['start'] / 1e-3))   # last state before the onset (no impact before it)
    dev = [np.max(np.abs(np.array(states[k].q_dot) - free.records[k].qd)) for k in range(k0 + 3)]
    assert max(dev[:k0 + 1]) < 1e-9        # same as the push-free walk up to the onset (see test_c)
    assert dev[k0 + 2] > 1e-3               # the push changes the velocities right after it starts


def test_c_dds_run_equals_in_process_run(walk):
    from biped_controller.closed_loop import runner
    from biped_sim.plant.push import Push
    ref = runner.run(steps=STEPS, pushes=(Push(PUSH['start'], PUSH['duration'], PUSH['force']),))
    d = _decoded(walk['bag'])
    states = [m for t, _, _, m in d['messages'] if t == '/sim/state']
    torques = [m for t, _, _, m in d['messages'] if t == '/controller/torque']
    assert len(states) == len(ref.records) + 1   # + the final state
    for k, rec in enumerate(ref.records):
        s = states[k]
        assert s.step == rec.step == k
        assert s.stance == rec.stance
        # Bit-identical: the controller core takes time differences in integer nanoseconds, so the
        # time that travels through a ROS stamp gives the same arithmetic as the in-process float time
        # (before that, 1-ulp differences from the elapsed time grew to 1e-8 rad over 10 steps).
        assert np.array_equal(np.array(s.q), rec.q), (k, np.max(np.abs(np.array(s.q) - rec.q)))
        assert np.array_equal(np.array(s.q_dot), rec.qd), (k, np.max(np.abs(np.array(s.q_dot) - rec.qd)))
        assert (torques[k].header.stamp.sec, torques[k].header.stamp.nanosec) == (s.stamp.sec, s.stamp.nanosec)
        # the simulator applies the clipped torque: the same as in process
        assert np.max(np.abs(np.clip(np.array(torques[k].effort), -150.0, 150.0) - rec.torque)) < 1e-4, k
    assert sum(1 for a, b in zip(states, states[1:]) if a.stance != b.stance) == STEPS


def test_d_bag_reads_and_decodes_counts_and_time_range(walk):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from biped_sim.recording.bag_reader import find_mcap
    path = find_mcap(walk['bag'])
    per_channel = {}
    with open(path, 'rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        for _s, ch, msg, dec in reader.iter_decoded_messages():
            assert dec is not None
            per_channel[ch.topic] = per_channel.get(ch.topic, 0) + 1
    assert set(per_channel) == set(summary.channels[c].topic for c in summary.channels)
    n = per_channel['/sim/state']
    steps = n - 1   # control steps simulated (the last state is the final one)
    for topic in ('/clock', '/tf', '/stance', '/controller/torque', '/controller/status'):
        assert per_channel[topic] == n, (topic, per_channel)
    for topic in ('/joint_states', '/ground_reaction', '/ground_reaction/cop'):
        assert per_channel[topic] == steps, (topic, per_channel)
    assert per_channel['/robot_description'] == 1 and per_channel['/push_events'] == 1
    d = _decoded(walk['bag'])
    states = [(lt, m) for t, lt, _, m in d['messages'] if t == '/sim/state']
    stamps = np.array([m.stamp.sec + 1e-9 * m.stamp.nanosec for _, m in states])
    last_t = stamps[-1]
    inc = np.diff(stamps)
    # one state per control period: k * dt, except a period cut short by an impact (simulator.step)
    assert np.all(inc > 0) and np.all(inc <= 1e-3 + 1e-9)
    assert steps * 1e-3 - STEPS * 1e-3 <= last_t <= steps * 1e-3 + 1e-9
    # log time = sim time (recorder on /clock): the range covers [0, t_final] within one period
    assert d['start_ns'] <= 1_000_000
    assert abs(d['end_ns'] * 1e-9 - last_t) <= 1e-3 + 1e-9


def test_f_bag_passes_an_independent_physics_check(walk):
    """From the bag and robots/biped7/description.yaml alone (tests/bag_physics: own kinematics, no project code):
    the push (off the 1 ms grid) acts exactly over its window, the momentum of every period balances the
    recorded ground reaction, push and impact impulses, and every recorded impact is consistent."""
    import bag_physics as bp
    B = bp.load_bag(walk['bag'])
    model = bp.PlanarBiped()
    # the model's conventions hold on the recording: stance ankle on the ground and at rest, joints as
    # /joint_states reports them
    assert bp.ankle_check(B, model) < 1e-9
    assert bp.joint_states_check(B) == 0.0
    # (a) /sim/push: F x overlap in every period, nothing outside [start, start + duration), total F x duration
    p = bp.push_report(B)
    assert (p['start'], p['duration'], p['force']) == (PUSH['start'], PUSH['duration'], PUSH['force'])
    assert p['impulse_outside'] == []
    assert p['periods_touched'] == 26          # 0.2315 is off the grid: 24 whole periods and two halves
    assert p['worst_period_error'] <= 1e-12 * abs(p['force'] * PUSH['duration'])
    assert p['total'] == pytest.approx(PUSH['force'] * PUSH['duration'], rel=1e-9)
    # (b) linear momentum per period; left-rectangle rule on the ground reaction: a few 1e-3 N s at most
    # where it changes fastest (after an impact, at the push's switches) against 0.25 N s of push per period
    r = bp.momentum_residuals(B, model)
    assert len(r) == len(bp.states(B)) - 1
    assert np.max(np.abs(r[:, 2:4])) < 0.02, r[np.argmax(np.max(np.abs(r[:, 2:4]), axis=1))]
    window = (r[:, 0] >= PUSH['start'] - 0.01) & (r[:, 0] < PUSH['start'] + PUSH['duration'] + 0.01)
    recovered = np.sum(r[window, 2]) + p['total']      # push impulse seen in the momentum, not in R or impacts
    assert recovered == pytest.approx(PUSH['force'] * PUSH['duration'], rel=1e-2)
    # (c) every impact: momentum jump = ground impulse, energy lost, foot re-pose, the next state
    imps = bp.impact_reports(B, model)
    assert len(imps) == STEPS and sum(r[:, 5]) == STEPS
    for i in imps:
        assert i['momentum_error'] < 1e-9, i
        assert i['energy_loss'] > 0 and i['energy_loss_model'] == pytest.approx(i['energy_loss'], rel=1e-9), i
        assert i['repose_error'] == 0.0 and i['landing_ankle_speed'] < 1e-9, i
        assert i['landing_ankle_height_after'] < 1e-9 and i['next_state_error'] < 1e-12, i
    # negative control: a push recorded one period early (as the old stage-time sampling leaked it) is
    # caught by the window check and by the momentum of both periods
    from types import SimpleNamespace
    pushes = sorted(B['/sim/push'], key=lambda m: bp.ns(m.stamp))
    k = next(i for i, m in enumerate(pushes) if m.impulse != 0.0)
    moved = [SimpleNamespace(stamp=m.stamp, period=m.period, impulse=m.impulse) for m in pushes]
    moved[k - 1].impulse, moved[k].impulse = moved[k].impulse, 0.0
    bad = dict(B, **{'/sim/push': moved})
    assert bp.push_report(bad)['impulse_outside'] != []
    rb = bp.momentum_residuals(bad, model)
    assert np.max(np.abs(rb[:, 2])) > 0.1
    # the soak's checks (bag_summary) agree: nothing outside the window, F x duration applied
    from biped_sim.recording.bag_summary import analyze_bag
    a = analyze_bag(walk['bag'])
    assert a['problems'] == [] and a['applied_impulse_outside_windows'] == 0, a['problems']
    assert a['push_effects'][0]['applied_impulse'] == pytest.approx(p['total'], rel=1e-12)


def test_e_sigint_leaves_finished_bag_and_no_orphans(ros_domain, tmp_path):
    env = dict(os.environ)
    proc, bag, ready = _launch(tmp_path, env, '--steps', '0')   # walk until stopped
    pids: set[int] = set()
    try:
        _wait_ready(proc, ready)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 30:
            pids |= _descendants(proc.pid)
            if list(bag.glob('*.mcap')) and len(pids) >= 4:
                break
            time.sleep(0.1)
        # let it walk until the recorder has flushed at least one chunk (robust to a loaded machine,
        # where the lockstep run may start seconds after the graph is up)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 90:
            files = list(bag.glob('*.mcap'))
            if files and files[0].stat().st_size > 300_000:
                break
            time.sleep(0.2)
        pids |= _descendants(proc.pid)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
        assert proc.returncode == 128 + signal.SIGINT, out[-3000:]
        assert _alive(pids) == [], out[-3000:]
        from biped_sim.recording.bag_reader import read_bag
        d = read_bag(bag)
        assert d['has_summary'] and d['chunk_count'] >= 1
        assert d['counts']['/sim/state'] > 10
        assert (bag / 'metadata.yaml').is_file()
    finally:
        if proc.poll() is None:
            _kill_tree(proc, pids | _descendants(proc.pid))
        else:
            _kill_tree(proc, pids)
