"""Summaries of a recorded run, read from its MCAP alone (used by the demo and the soak).

Pure (no ROS import): topic names from ``topics``; the bag is read with ``bag_reader`` / ``mcap``.
:func:`summarize_bag`: outcome, excursions, message counts (the demo's summary). :func:`analyze_bag`:
the soak's checks (sequence gaps, every push applied once, momentum change of each push, and from
``/sim/push`` the impulse of every period: F x its overlap with a push window, zero outside every window).
"""
from __future__ import annotations

import math
import os
import struct
from pathlib import Path

import numpy as np

from biped_sim.recording import topics as gn

# relative tolerance of a push's impulse recovered from the recorded ground reaction (soak check)
IMPULSE_TOLERANCE = 0.10
# relative tolerance of the impulse /sim/push reports against F x overlap (exact up to round-off)
APPLIED_IMPULSE_TOLERANCE = 1e-9


def summarize_bag(bag: Path, expected_steps: int | None = None) -> dict:
    """Summary of a recorded run (pure: reads the MCAP with bag_reader, decodes with mcap_ros2)."""
    from biped_sim.recording.bag_reader import read_bag
    data = read_bag(bag, decode=True)
    msgs = data['messages']
    states = [m for (t, _lt, _pt, m) in msgs if t == gn.SIM_STATE]
    state_pub = [pt for (t, _lt, pt, _m) in msgs if t == gn.SIM_STATE]
    status = [m for (t, _lt, _pt, m) in msgs if t == gn.CONTROLLER_STATUS]
    wrenches = [m for (t, _lt, _pt, m) in msgs if t == gn.GROUND_REACTION]
    falls = [m for (t, _lt, _pt, m) in msgs if t == gn.FALL]
    pushes = [m for (t, _lt, _pt, m) in msgs if t == gn.PUSH_EVENTS]
    import yaml
    last = states[-1] if states else None
    fall = yaml.safe_load(falls[-1].data) if falls else None
    ls = [-w.wrench.torque.y / w.wrench.force.z for w in wrenches if w.wrench.force.z > 0]
    impacts = sum(1 for a, b in zip(states, states[1:]) if a.stance != b.stance)
    sim_t = (last.stamp.sec + 1e-9 * last.stamp.nanosec) if last else 0.0
    pub_span = (max(state_pub) - min(state_pub)) * 1e-9 if len(state_pub) > 1 else 0.0
    size = os.path.getsize(data['path'])

    def rng(name):
        v = [getattr(s, name) for s in status]
        return [min(v), max(v)] if v else None

    return {
        'outcome': 'fell' if fall else 'survived',
        'fall_cause': fall['cause'] if fall else '',
        'fall_detail': fall['detail'] if fall else '',
        'fall_time': fall['time'] if fall else None,
        'steps_walked': impacts,
        'control_steps': len(states),
        'sim_time': sim_t,
        'max_abs_cop_l': max((abs(x) for x in ls), default=None),
        'max_abs_zmp_controller': max((abs(s.zmp) for s in status if math.isfinite(s.zmp)), default=None),
        'p_range': rng('p'),
        'p_dot_range': rng('p_dot'),
        'tau_range': rng('tau'),
        'tau_dot_range': rng('tau_dot'),
        'max_tracking_error': max((s.max_tracking_error for s in status), default=None),
        'last_qp_status': int(status[-1].qp_status) if status else None,
        'last_qp_message': status[-1].qp_message if status else '',
        'qp_fallback_steps': sum(1 for s in status if s.qp_status in (2, 3)),
        'final_state_fall_cause': last.fall_cause if last is not None else '',
        'pushes': [dict(id=p.id, start=p.start, duration=p.duration, force=p.force, height=p.height) for p in pushes],
        'counts': dict(sorted(data['counts'].items())),
        'message_count': data['message_count'],
        'mcap_path': str(data['path']),
        'mcap_bytes': size,
        'mcap_bytes_per_sim_second': size / sim_t if sim_t > 0 else None,
        'log_time_range': [data['start_ns'] * 1e-9 if data['start_ns'] is not None else None,
                           data['end_ns'] * 1e-9 if data['end_ns'] is not None else None],
        'lockstep_wall_time': pub_span,
        'lockstep_steps_per_second': (len(state_pub) - 1) / pub_span if pub_span > 0 else None,
    }


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

    from biped_sim.recording.bag_reader import find_mcap
    from biped_model.floating import FloatingModel, urdf_from_paper

    path = find_mcap(bag)
    decode_topics = {gn.SIM_STATE, gn.GROUND_REACTION, gn.PUSH_EVENTS, gn.PUSH_REQUESTS, gn.FALL,
                     gn.CONTROLLER_STATUS, gn.SIM_PUSH, gn.ROBOT_DESCRIPTION}
    stamp_topics = {gn.CLOCK: 4, gn.IMU: 4, gn.CONTROLLER_TORQUE: 4, gn.JOINT_STATES: 4, gn.GROUND_REACTION_COP: 4,
                    gn.TF: 8}
    counts: dict[str, int] = {}
    stamps: dict[str, list[int]] = {t: [] for t in stamp_topics}
    seq, steps, st_stamp, stance, q, qd, base, base_dot, fallen = [], [], [], [], [], [], [], [], []
    wrench_t, wrench_fx = [], []
    events, requests, falls, applied = [], [], [], []
    qp_counts: dict[int, int] = {}
    last_status = None
    urdf = None            # the bag's /robot_description: the robot the graph walked (any robot, not only the default)
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
            if topic == gn.SIM_STATE:
                seq.append(m.sequence)
                steps.append(m.step)
                st_stamp.append(m.stamp.sec * 1_000_000_000 + m.stamp.nanosec)
                stance.append(m.stance)
                q.append(m.q)
                qd.append(m.q_dot)
                base.append(m.base)
                base_dot.append(m.base_dot)
                fallen.append(bool(m.fallen))
            elif topic == gn.GROUND_REACTION:
                wrench_t.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)
                wrench_fx.append(m.wrench.force.x)
            elif topic == gn.ROBOT_DESCRIPTION:
                urdf = m.data
            elif topic == gn.PUSH_EVENTS:
                events.append(dict(id=int(m.id), start=m.start, duration=m.duration, force=m.force, height=m.height))
            elif topic == gn.PUSH_REQUESTS:
                requests.append(yaml.safe_load(m.data))
            elif topic == gn.FALL:
                falls.append(yaml.safe_load(m.data))
            elif topic == gn.CONTROLLER_STATUS:
                qp_counts[int(m.qp_status)] = qp_counts.get(int(m.qp_status), 0) + 1
                last_status = m
            elif topic == gn.SIM_PUSH:
                applied.append((m.stamp.sec * 1_000_000_000 + m.stamp.nanosec, m.period, m.impulse))
    problems: list[str] = []
    n = len(seq)
    seq_a = np.array(seq, dtype=np.int64)
    order = np.argsort(seq_a, kind='stable')
    seq_sorted = seq_a[order]
    gaps = int(np.sum(np.diff(seq_sorted) > 1)) if n > 1 else 0
    repeats = int(np.sum(np.diff(seq_sorted) == 0)) if n > 1 else 0
    if n == 0:
        problems.append(f'no {gn.SIM_STATE}')
    else:
        if seq_sorted[0] != 1 or seq_sorted[-1] != n or gaps or repeats:
            problems.append(f'{gn.SIM_STATE} sequence: first {seq_sorted[0]}, last {seq_sorted[-1]}, {n} messages, '
                            f'{gaps} gaps, {repeats} repeats')
        if not np.array_equal(np.array(steps, dtype=np.int64)[order], np.arange(n)):
            problems.append(f'{gn.SIM_STATE} step is not 0..n-1 in sequence order')
    st_stamp_a = np.array(st_stamp, dtype=np.int64)[order]
    state_set = set(st_stamp_a.tolist())
    period_set = set(st_stamp_a[:-1].tolist())
    topic_report = {}
    expected = {gn.CLOCK: state_set, gn.IMU: state_set, gn.CONTROLLER_TORQUE: state_set, gn.TF: state_set,
                gn.JOINT_STATES: period_set, gn.GROUND_REACTION_COP: period_set}
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
    topic_report[gn.GROUND_REACTION] = gr
    if gr['missing'] or gr['duplicates'] or len(set(wrench_t) - period_set):
        problems.append(f'{gn.GROUND_REACTION}: {gr}')
    for topic, exp in ((gn.STANCE, n), (gn.CONTROLLER_STATUS, n)):
        topic_report[topic] = dict(count=counts.get(topic, 0), expected=exp)
        if counts.get(topic, 0) != exp:
            problems.append(f'{topic}: {counts.get(topic, 0)} messages, expected {exp}')

    # ---- pushes
    ids = [e['id'] for e in events]
    if sorted(ids) != list(range(1, len(ids) + 1)):
        problems.append(f'{gn.PUSH_EVENTS} ids are not 1..{len(ids)} once each: {sorted(ids)}')
    accepted = [r for r in requests if r['response']['accepted']]
    if len(accepted) != len(events):
        problems.append(f'{len(accepted)} accepted requests in {gn.PUSH_REQUESTS} vs {len(events)} on {gn.PUSH_EVENTS}')
    if planned is not None:
        by_id = {e['id']: e for e in events}
        for p in planned:
            e = by_id.get(p['id'])
            if e is None or e['start'] != p['start'] or e['force'] != p['force'] or e['duration'] != p['duration']:
                problems.append(f'requested push {p} not found as such in /push_events ({e})')
    # effect: impulse from the whole-body horizontal momentum and the ground's horizontal impulse
    fm = FloatingModel(urdf=urdf)
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
    # the applied impulse of every period (/sim/push) against the windows of /push_events
    windows = [(e['id'], e['start'], e['start'] + e['duration'], e['force']) for e in events]
    applied_by_id = {e['id']: 0.0 for e in events}
    outside, wrong = 0, 0
    for t_ns, period, impulse in applied:
        t0 = t_ns * 1e-9
        share = {i: f * max(0.0, min(t0 + period, t1) - max(t0, s)) for i, s, t1, f in windows}
        expected = sum(share.values())
        if expected == 0.0:
            # round-off only: at a window's edge the simulator's float period start and the stamp's integer ns
            # can differ by an ulp (an onset from the service's delay form, now + delay, is off the 1 us grid),
            # leaving a sliver of F x ~1e-16 s, which the tolerance of the 'wrong' check below allows as well
            fmax = max((abs(f) for _, _, _, f in windows), default=0.0)
            outside += abs(impulse) > APPLIED_IMPULSE_TOLERANCE * fmax * max(period, 1e-3)
            continue
        scale = max(abs(f) for _, _, _, f in windows) * max(period, 1e-3)
        wrong += abs(impulse - expected) > APPLIED_IMPULSE_TOLERANCE * scale
        for i, part in share.items():
            applied_by_id[i] += impulse * part / expected
    if outside:
        problems.append(f'{gn.SIM_PUSH}: {outside} period(s) with an impulse outside every push window')
    if wrong:
        problems.append(f'{gn.SIM_PUSH}: {wrong} period(s) whose impulse is not F x the overlap with the window')
    if applied and len(applied) != len(period_set):
        problems.append(f'{gn.SIM_PUSH}: {len(applied)} messages, expected one per period ({len(period_set)})')
    t_last = float(st_stamp_a[-1]) * 1e-9 if n else 0.0
    for rec in push_effects:
        e = next(e for e in events if e['id'] == rec['id'])
        acted = max(0.0, min(e['start'] + e['duration'], t_last) - e['start'])   # cut by the recording's end
        rec['applied_impulse'] = applied_by_id[rec['id']]
        if applied and abs(rec['applied_impulse'] - e['force'] * acted) > \
                APPLIED_IMPULSE_TOLERANCE * abs(e['force'] * e['duration']):
            problems.append(f"push {e['id']}: {gn.SIM_PUSH} impulse {rec['applied_impulse']!r} N s, "
                            f"expected F x {acted} s = {e['force'] * acted!r} N s")
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
        'applied_push_periods': len(applied),
        'applied_impulse_outside_windows': outside,
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
