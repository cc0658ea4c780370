"""Soak run over DDS: ``python -m biped_sim.soak [--minutes N] [--json FILE] [--seed S] [--bag DIR]``.

1. launches the node graph (``biped_sim.launch``, ``--steps 0``, simulator ``max_time`` = N minutes of
   sim time) with the bag under ``runs/soak_<timestamp>/``;
2. while it walks, requests pushes through ``/apply_push``: a seeded plan (``push_plan``) of pushes every
   ``--every`` sim seconds (uniform in [every/2, 3 every/2]), alternating random directions, magnitudes
   uniform in [--min-force, --max-forward] forward and [--min-force, --max-backward] backward,
   0.025 s each; each one is requested (absolute start) about ``--lead`` sim seconds before its onset,
   sim time being read from ``/clock`` (keep-last 1, sampled a few times per wall second);
3. samples VmRSS (``/proc/<pid>/status``) of each node process every ``--mem-every`` sim seconds;
4. after the run, checks from the MCAP alone (``analyze_bag``): the ``/sim/state`` sequence has no gap
   or repeat, every per-step topic holds exactly the states' stamps (the period-topics all but the
   final state's), every requested push appears once in ``/push_events`` and ``/push_requests``, its
   effect on the state is its impulse (whole-body horizontal momentum change minus the ground's
   horizontal impulse, within 10 % of F d; pushes with an impact inside the window are reported as not
   checkable), no fall; and that each node's resident memory grew less than 10 % between minute 1
   (or half the run when shorter) and the end.

Prints a summary, ``--json FILE`` writes it. Exit 0 when every check passed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import random
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PUSH_DURATION = 0.025
NODE_NAMES = ('simulator', 'controller', 'disturbance', 'recorder')
MEMORY_GROWTH_LIMIT = 0.10
IMPULSE_TOLERANCE = 0.10


# ----------------------------------------------------------------------------- plan
def push_plan(total_time: float, seed: int, every: float = 3.0, min_force: float = 80.0,
              max_forward: float = 150.0, max_backward: float = 200.0, first: float = 2.0,
              tail: float = 1.5) -> list[dict]:
    """Seeded pushes over [first, total_time - tail): ``[{start, duration, force}]``, starts on the
    1 us grid, consecutive starts ``every`` * U(0.5, 1.5) apart, signs random."""
    rng = random.Random(seed)
    out = []
    t = first + rng.uniform(0.0, every)
    while t < total_time - tail:
        forward = rng.random() < 0.5
        mag = rng.uniform(min_force, max_forward if forward else max_backward)
        out.append({'start': round(t, 6), 'duration': PUSH_DURATION,
                    'force': round(mag if forward else -mag, 3)})
        t += every * rng.uniform(0.5, 1.5)
    return out


# ----------------------------------------------------------------------------- processes
def descendants(pid: int) -> list[int]:
    """Every descendant process of ``pid`` (from /proc/<pid>/task/<pid>/children, recursively)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        try:
            with open(f'/proc/{p}/task/{p}/children') as fh:
                kids = [int(x) for x in fh.read().split()]
        except OSError:
            kids = []
        out += kids
        todo += kids
    return out


def node_pids(launcher_pid: int) -> dict[str, int]:
    """node name -> pid of the launcher's children running ``lib/<pkg>/<node>``."""
    found = {}
    for p in descendants(launcher_pid):
        try:
            with open(f'/proc/{p}/cmdline', 'rb') as fh:
                argv = fh.read().split(b'\0')
        except OSError:
            continue
        for a in argv[:3]:
            base = os.path.basename(a.decode(errors='replace'))
            if base in NODE_NAMES and b'/lib/' in a:
                found.setdefault(base, p)
    return found


def vm_rss_kb(pid: int) -> int | None:
    try:
        with open(f'/proc/{pid}/status') as fh:
            for line in fh:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


# ----------------------------------------------------------------------------- bag analysis
def _stamp_ns(data: bytes, offset: int = 4) -> int:
    sec, nsec = struct.unpack_from('<iI', data, offset)
    return sec * 1_000_000_000 + nsec


def analyze_bag(bag, planned: list[dict] | None = None) -> dict:
    """Checks of a soak bag, from the MCAP alone (see the module doc). ``planned``: the pushes that
    were requested and accepted (``{start, duration, force, id}``); None = those of /push_events."""
    import pinocchio as pin
    import yaml
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from biped_sim.bag_reader import find_mcap
    from biped_sim.floating import FloatingModel, urdf_from_paper

    path = find_mcap(bag)
    decode_topics = {'/sim/state', '/ground_reaction', '/push_events', '/push_requests', '/fall',
                     '/controller/status'}
    stamp_topics = {'/clock': 4, '/controller/torque': 4, '/joint_states': 4, '/ground_reaction/cop': 4,
                    '/tf': 8}
    counts: dict[str, int] = {}
    stamps: dict[str, list[int]] = {t: [] for t in stamp_topics}
    seq, steps, st_stamp, stance, q, qd, base, base_dot, fallen = [], [], [], [], [], [], [], [], []
    wrench_t, wrench_fx = [], []
    events, requests, falls = [], [], []
    qp_counts: dict[int, int] = {}
    last_status = None
    factory = DecoderFactory()
    decoders = {}
    with open(path, 'rb') as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            if topic in stamp_topics:
                stamps[topic].append(_stamp_ns(message.data, stamp_topics[topic]))
                continue
            if topic not in decode_topics:
                continue
            dec = decoders.get(channel.id)
            if dec is None:
                dec = decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
            m = dec(message.data)
            if topic == '/sim/state':
                seq.append(m.sequence)
                steps.append(m.step)
                st_stamp.append(m.stamp.sec * 1_000_000_000 + m.stamp.nanosec)
                stance.append(m.stance)
                q.append(m.q)
                qd.append(m.q_dot)
                base.append(m.base)
                base_dot.append(m.base_dot)
                fallen.append(bool(m.fallen))
            elif topic == '/ground_reaction':
                wrench_t.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)
                wrench_fx.append(m.wrench.force.x)
            elif topic == '/push_events':
                events.append(dict(id=int(m.id), start=m.start, duration=m.duration, force=m.force, height=m.height))
            elif topic == '/push_requests':
                requests.append(yaml.safe_load(m.data))
            elif topic == '/fall':
                falls.append(yaml.safe_load(m.data))
            elif topic == '/controller/status':
                qp_counts[int(m.qp_status)] = qp_counts.get(int(m.qp_status), 0) + 1
                last_status = m
    problems: list[str] = []
    n = len(seq)
    seq_a = np.array(seq, dtype=np.int64)
    order = np.argsort(seq_a, kind='stable')
    seq_sorted = seq_a[order]
    gaps = int(np.sum(np.diff(seq_sorted) > 1)) if n > 1 else 0
    repeats = int(np.sum(np.diff(seq_sorted) == 0)) if n > 1 else 0
    if n == 0:
        problems.append('no /sim/state')
    else:
        if seq_sorted[0] != 1 or seq_sorted[-1] != n or gaps or repeats:
            problems.append(f'/sim/state sequence: first {seq_sorted[0]}, last {seq_sorted[-1]}, {n} messages, '
                            f'{gaps} gaps, {repeats} repeats')
        if not np.array_equal(np.array(steps, dtype=np.int64)[order], np.arange(n)):
            problems.append('/sim/state step is not 0..n-1 in sequence order')
    st_stamp_a = np.array(st_stamp, dtype=np.int64)[order]
    state_set = set(st_stamp_a.tolist())
    period_set = set(st_stamp_a[:-1].tolist())
    topic_report = {}
    expected = {'/clock': state_set, '/controller/torque': state_set, '/tf': state_set,
                '/joint_states': period_set, '/ground_reaction/cop': period_set}
    for topic, exp in expected.items():
        got = stamps[topic]
        missing = len(exp - set(got))
        dup = len(got) - len(set(got))
        extra = len(set(got) - exp)
        topic_report[topic] = dict(count=len(got), expected=len(exp), missing=missing, duplicates=dup, extra=extra)
        if missing or dup or extra:
            problems.append(f'{topic}: {missing} missing, {dup} duplicated, {extra} unexpected stamps')
    gr = dict(count=len(wrench_t), expected=len(period_set), missing=len(period_set - set(wrench_t)),
              duplicates=len(wrench_t) - len(set(wrench_t)))
    topic_report['/ground_reaction'] = gr
    if gr['missing'] or gr['duplicates'] or len(set(wrench_t) - period_set):
        problems.append(f'/ground_reaction: {gr}')
    for topic, exp in (('/stance', n), ('/controller/status', n)):
        topic_report[topic] = dict(count=counts.get(topic, 0), expected=exp)
        if counts.get(topic, 0) != exp:
            problems.append(f'{topic}: {counts.get(topic, 0)} messages, expected {exp}')

    # ---- pushes
    ids = [e['id'] for e in events]
    if sorted(ids) != list(range(1, len(ids) + 1)):
        problems.append(f'/push_events ids are not 1..{len(ids)} once each: {sorted(ids)}')
    accepted = [r for r in requests if r['response']['accepted']]
    if len(accepted) != len(events):
        problems.append(f'{len(accepted)} accepted requests in /push_requests vs {len(events)} PushEvents')
    if planned is not None:
        by_id = {e['id']: e for e in events}
        for p in planned:
            e = by_id.get(p['id'])
            if e is None or e['start'] != p['start'] or e['force'] != p['force'] or e['duration'] != p['duration']:
                problems.append(f'requested push {p} not found as such in /push_events ({e})')
    # effect: impulse from the whole-body horizontal momentum and the ground's horizontal impulse
    fm = FloatingModel()
    t_state = st_stamp_a * 1e-9
    q_a = np.array(q)[order] if n else np.zeros((0, 6))
    qd_a = np.array(qd)[order] if n else np.zeros((0, 6))
    base_a = np.array(base)[order] if n else np.zeros((0, 3))
    bd_a = np.array(base_dot)[order] if n else np.zeros((0, 3))
    stance_a = np.array(stance)[order] if n else np.zeros(0, int)
    fx_by_stamp = dict(zip(wrench_t, wrench_fx))

    def vcom(k):
        x = np.concatenate([base_a[k], urdf_from_paper(q_a[k], int(stance_a[k]))])
        v = np.concatenate([bd_a[k], urdf_from_paper(qd_a[k], int(stance_a[k]))])
        pin.centerOfMass(fm.model, fm.data, x, v)
        return float(fm.data.vcom[0][0])

    push_effects = []
    for e in sorted(events, key=lambda e: e['start']):
        k0 = int(np.searchsorted(t_state, e['start'], side='right')) - 3
        k1 = int(np.searchsorted(t_state, e['start'] + e['duration'], side='left')) + 2
        rec = dict(id=e['id'], force=e['force'], start=e['start'], expected_impulse=e['force'] * e['duration'])
        if k0 < 0 or k1 >= n:
            rec['status'] = 'outside the recorded states'
            problems.append(f"push {e['id']}: outside the recorded states")
        elif stance_a[k0] != stance_a[k1]:
            rec['status'] = 'not checkable (impact inside the window)'
        else:
            ground = sum(fx_by_stamp.get(int(st_stamp_a[k]), math.nan) * (t_state[k + 1] - t_state[k])
                         for k in range(k0, k1))
            imp = fm.mass * (vcom(k1) - vcom(k0)) - ground
            rec['measured_impulse'] = imp
            ok = abs(imp - rec['expected_impulse']) <= IMPULSE_TOLERANCE * abs(rec['expected_impulse'])
            rec['status'] = 'applied once' if ok else 'WRONG'
            if not ok:
                problems.append(f"push {e['id']}: impulse {imp:.4f} N s, expected {rec['expected_impulse']:.4f}")
        push_effects.append(rec)
    survived = not falls and not any(fallen)
    if not survived:
        problems.append(f'fall: {falls[-1] if falls else "state fallen"}')
    return {
        'mcap_path': str(path),
        'mcap_bytes': os.path.getsize(path),
        'has_summary': summary is not None,
        'message_count': sum(counts.values()),
        'counts': dict(sorted(counts.items())),
        'states': n,
        'sim_time': float(t_state[-1]) if n else 0.0,
        'sequence_gaps': gaps,
        'sequence_repeats': repeats,
        'topics': topic_report,
        'push_events': len(events),
        'push_requests': len(requests),
        'pushes_checked': sum(1 for r in push_effects if r['status'] == 'applied once'),
        'pushes_not_checkable': sum(1 for r in push_effects if r['status'].startswith('not checkable')),
        'push_effects': push_effects,
        'forward_pushes': sum(1 for e in events if e['force'] > 0),
        'backward_pushes': sum(1 for e in events if e['force'] < 0),
        'survived': survived,
        'falls': falls,
        'qp_status_counts': {str(k): v for k, v in sorted(qp_counts.items())},
        'last_qp_status': int(last_status.qp_status) if last_status is not None else None,
        'problems': problems,
    }


# ----------------------------------------------------------------------------- the run
def _log(msg: str) -> None:
    print(f'soak: {msg}', file=sys.stderr, flush=True)


def run_soak(minutes: float, bag: Path, seed: int = 1, every: float = 3.0, min_force: float = 80.0,
             max_forward: float = 150.0, max_backward: float = 200.0, lead: float = 1.0,
             mem_every: float = 10.0, timeout: float | None = None) -> dict:
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy, HistoryPolicy
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock

    from biped_msgs_py.srv import ApplyPush
    from biped_sim import graph_names as gn

    total = 60.0 * minutes
    plan = push_plan(total, seed, every, min_force, max_forward, max_backward)
    mem_first_at = min(60.0, total / 2)
    wall_timeout = timeout if timeout is not None else 600.0 + total * 30.0
    t0 = time.monotonic()
    result: dict = {'minutes': minutes, 'sim_seconds': total, 'seed': seed, 'bag': str(bag),
                    'plan': plan, 'requested': [], 'memory': [], 'problems': []}
    with tempfile.TemporaryDirectory() as tmp:
        ready = Path(tmp) / 'ready'
        cmd = [sys.executable, '-m', 'biped_sim.launch', '--bag', str(bag), '--steps', '0',
               '--sim-param', f'max_time:={total}', '--sim-param', 'linger:=1.0', '--ready-file', str(ready)]
        launcher = subprocess.Popen(cmd)
        ctx = rclpy.Context()
        rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node('soak_probe', context=ctx, start_parameter_services=False)
        latest = {'t': -1.0}
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
        node.create_subscription(Clock, gn.CLOCK, lambda m: latest.__setitem__(
            't', m.clock.sec + 1e-9 * m.clock.nanosec), qos)
        client = node.create_client(ApplyPush, gn.APPLY_PUSH)
        from rclpy.executors import SingleThreadedExecutor
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        stop = {'sig': None}
        prev = {s: signal.signal(s, lambda signum, _f: stop.__setitem__('sig', signum))
                for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            while not ready.exists():
                if launcher.poll() is not None or time.monotonic() - t0 > 180 or stop['sig']:
                    raise RuntimeError('the graph did not come up')
                time.sleep(0.05)
            if not client.wait_for_service(timeout_sec=60):
                raise RuntimeError(f'{gn.APPLY_PUSH} not available')
            next_push = 0
            next_mem = mem_first_at
            final_sampled = False
            while launcher.poll() is None:
                if stop['sig'] is not None:
                    raise RuntimeError(f'stopped by signal {stop["sig"]}')
                if time.monotonic() - t0 > wall_timeout:
                    raise RuntimeError(f'soak longer than {wall_timeout} s wall')
                # take the latest /clock (keep-last 1): a few spins, no busy loop
                for _ in range(3):
                    ex.spin_once(timeout_sec=0.0)
                now = latest['t']
                if next_push < len(plan) and now >= plan[next_push]['start'] - lead:
                    p = plan[next_push]
                    req = ApplyPush.Request(force=float(p['force']), duration=float(p['duration']),
                                            start=float(p['start']), use_delay=False, delay=0.0, height=math.nan)
                    fut = client.call_async(req)
                    ex.spin_until_future_complete(fut, timeout_sec=30.0)
                    res = fut.result() if fut.done() else None
                    entry = dict(p, requested_at_sim=now, accepted=bool(res and res.accepted),
                                 id=int(res.push_id) if res else 0, message=res.message if res else 'no answer')
                    result['requested'].append(entry)
                    if not entry['accepted']:
                        result['problems'].append(f'push {p} not accepted: {entry["message"]}')
                    next_push += 1
                if (now >= next_mem or (not final_sampled and now >= total - 1.0)):
                    pids = node_pids(launcher.pid)
                    sample = {'sim_time': now, 'wall': time.monotonic() - t0,
                              'rss_kb': {k: vm_rss_kb(v) for k, v in sorted(pids.items())}}
                    result['memory'].append(sample)
                    _log(f"sim {now:.1f} s / {total:.0f} s, wall {sample['wall']:.0f} s, "
                         f"pushes requested {next_push}/{len(plan)}, RSS kB {sample['rss_kb']}")
                    if now >= total - 1.0:
                        final_sampled = True
                    while next_mem <= now:
                        next_mem += mem_every
                time.sleep(0.2)
            result['launcher_exit_code'] = launcher.returncode
        except RuntimeError as exc:
            result['problems'].append(str(exc))
            if launcher.poll() is None:
                launcher.send_signal(signal.SIGINT)
            try:
                launcher.wait(120)
            except subprocess.TimeoutExpired:
                launcher.kill()
                launcher.wait()
            result['launcher_exit_code'] = launcher.returncode
        finally:
            for s, h in prev.items():
                signal.signal(s, h)
            node.destroy_node()
            rclpy.shutdown(context=ctx)
    result['wall_time'] = time.monotonic() - t0
    if result['launcher_exit_code'] != 0:
        result['problems'].append(f"launcher exited with {result['launcher_exit_code']}")
    # memory: minute 1 (or half the run) vs the end
    mem = result['memory']
    first = next((s for s in mem if s['sim_time'] >= mem_first_at), None)
    last = mem[-1] if mem else None
    growth = {}
    if first is None or last is None or last is first:
        result['problems'].append('memory: not enough samples')
    else:
        for name in NODE_NAMES:
            a, b = first['rss_kb'].get(name), last['rss_kb'].get(name)
            if a is None or b is None:
                result['problems'].append(f'memory: no sample of {name}')
                continue
            growth[name] = {'first_kb': a, 'last_kb': b, 'first_sim_time': first['sim_time'],
                            'last_sim_time': last['sim_time'], 'growth': (b - a) / a}
            if (b - a) / a >= MEMORY_GROWTH_LIMIT:
                result['problems'].append(f'memory: {name} grew {100 * (b - a) / a:.1f} % '
                                          f'({a} -> {b} kB)')
    result['memory_growth'] = growth
    try:
        accepted = [r for r in result['requested'] if r['accepted']]
        result['bag_check'] = analyze_bag(bag, accepted)
        result['problems'] += result['bag_check']['problems']
        if len(accepted) != len(plan):
            result['problems'].append(f'{len(accepted)} of {len(plan)} planned pushes accepted')
    except Exception as exc:  # noqa: BLE001 - report any reading problem plainly
        result['problems'].append(f'cannot check the bag: {exc!r}')
    result['ok'] = not result['problems']
    return result


def print_summary(r: dict) -> None:
    b = r.get('bag_check', {})
    print('==== soak summary ====')
    print(f"{r['minutes']} sim min, seed {r['seed']}, wall {r['wall_time']:.0f} s, launcher exit {r.get('launcher_exit_code')}")
    if b:
        print(f"messages {b['message_count']} ({b['mcap_bytes'] / 1e6:.1f} MB), states {b['states']}, sim time "
              f"{b['sim_time']:.3f} s, sequence gaps {b['sequence_gaps']}, repeats {b['sequence_repeats']}")
        print(f"pushes planned {len(r['plan'])}, accepted {sum(1 for x in r['requested'] if x['accepted'])}, "
              f"events {b['push_events']} ({b['forward_pushes']} forward, {b['backward_pushes']} backward), "
              f"impulse checked {b['pushes_checked']}, not checkable (impact in window) {b['pushes_not_checkable']}")
        print(f"survived: {b['survived']}; qp_status counts {b['qp_status_counts']}")
    for name, g in r.get('memory_growth', {}).items():
        print(f"RSS {name:11s} {g['first_kb']} kB at {g['first_sim_time']:.0f} s -> {g['last_kb']} kB at "
              f"{g['last_sim_time']:.0f} s ({100 * g['growth']:+.1f} %)")
    print('OK' if r['ok'] else 'PROBLEMS:\n  ' + '\n  '.join(r['problems']))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='soak', description='Soak run over DDS with pushes.')
    ap.add_argument('--minutes', type=float, default=10.0, help='simulated minutes')
    ap.add_argument('--json', type=Path, default=None)
    ap.add_argument('--bag', type=Path, default=None)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--every', type=float, default=3.0, help='mean sim s between pushes')
    ap.add_argument('--min-force', type=float, default=80.0)
    ap.add_argument('--max-forward', type=float, default=150.0)
    ap.add_argument('--max-backward', type=float, default=200.0)
    ap.add_argument('--timeout', type=float, default=None, help='wall s (default 600 + 30 per sim s)')
    a = ap.parse_args(argv)
    if not a.minutes > 0:
        ap.error('--minutes must be > 0')
    for name in ('max_forward', 'max_backward'):
        if not 0 < getattr(a, name) <= 250:
            ap.error(f'--{name.replace("_", "-")} must be in (0, 250] N')
    from biped_sim.settings import repo_root
    bag = (a.bag or repo_root() / 'runs' / f'soak_{_dt.datetime.now().strftime("%Y%m%d_%H%M%S")}').resolve()
    bag.parent.mkdir(parents=True, exist_ok=True)
    r = run_soak(a.minutes, bag, seed=a.seed, every=a.every, min_force=a.min_force, max_forward=a.max_forward,
                 max_backward=a.max_backward, timeout=a.timeout)
    print_summary(r)
    if a.json:
        a.json.write_text(json.dumps(r, indent=2, default=float) + '\n')
        print(f'summary written to {a.json}')
    return 0 if r['ok'] else 1


if __name__ == '__main__':
    sys.exit(main())
