"""CPU per ``Publisher.publish`` of each per-step message: the message object built as the nodes build it vs.
pre-serialised bytes from ``biped_sim.graph.cdr``.

    .venv/bin/python -m benchmarks.publish_cost [--n 2000] [--pairs 3] [--lockstep-pairs 0] [--json results/benchmarks/publish_cost.json]

For each message type the simulator and the controller publish every control step (/clock, /imu, /sim/state,
/tf, /stance, /joint_states, /ground_reaction, /ground_reaction/cop, /sim/push; /controller/torque,
/controller/status), ``--n`` publications of

- ``object``: the message object filled from Python values as the node does (the /tf and /imu objects reused
  and updated in place, as ``TransformBuilder`` and ``ImuBuilder`` do; the others built per message), then
  ``publish(msg)``;
- ``bytes``: the same values encoded by ``biped_sim.graph.cdr`` (layouts cached), then ``publish(bytes)``;

once with no subscriber and once with one subscriber process (a raw subscription per topic on a
``SingleThreadedExecutor``, like the recorder; the publisher waits until every topic is matched). The CPU is
the publishing process's (``time.process_time``: every thread of it, so Fast DDS's own threads too) over the
``n`` publications, per message in us; the subscriber's CPU is not counted. The two variants alternate
within each of ``--pairs`` rounds (object first in even rounds, bytes first in odd ones). The message
contents are seeded (``random.Random(SEED)``), the same for both variants. Printed: per type and condition
the median over the rounds of each variant, the ratio object / bytes, the load average before and after.

``--lockstep-pairs N`` (default 0): then N alternated pairs of the simulator and controller nodes alone in lockstep
as fast as possible (``benchmarks.lockstep.measure``, 2 s of sim time, no recorder), ``publish_cdr`` false then
true in both nodes (true first in odd pairs): control steps per wall second from the simulator's own line, with
the 1-minute load average at each run's start. Nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import statistics
import subprocess
import sys
import time
from pathlib import Path

from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR

ROOT = Path(__file__).resolve().parents[1]
SEED = 20_3
TOPICS = ['/bench/clock', '/bench/imu', '/bench/sim_state', '/bench/tf', '/bench/stance', '/bench/joint_states',
          '/bench/ground_reaction', '/bench/cop', '/bench/sim_push', '/bench/torque', '/bench/status']


def _types():
    from geometry_msgs.msg import PointStamped, WrenchStamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, JointState
    from std_msgs.msg import UInt8
    from tf2_msgs.msg import TFMessage
    from biped_msgs_py.msg import AppliedPush, ControllerStatus, SimState
    return dict(zip(TOPICS, [Clock, Imu, SimState, TFMessage, UInt8, JointState, WrenchStamped, PointStamped,
                             AppliedPush, JointState, ControllerStatus]))


def _subscriber() -> None:
    """The subscriber process: raw subscriptions on every topic, spun until stdin closes."""
    import threading
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from biped_sim.graph import names as gn
    rclpy.init()
    node = rclpy.create_node('publish_cost_sub')
    for topic, typ in _types().items():
        node.create_subscription(typ, topic, lambda _b: None, gn.QOS_SENSOR, raw=True)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    print('ready', flush=True)
    while not stop.is_set():
        ex.spin_once(timeout_sec=0.05)
    rclpy.shutdown()


def _makers(rng: random.Random):
    """topic -> (build-and-publish-object, encode-and-publish-bytes) closures over seeded values."""
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import PointStamped, WrenchStamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import UInt8
    from biped_msgs_py.msg import AppliedPush, ControllerStatus, SimState
    from biped_sim.graph import cdr
    from biped_sim.graph.imu import ImuBuilder
    from biped_sim.graph.simulator_node import TransformBuilder
    from biped_model.description import PAPER_JOINTS, URDF_JOINTS, load_description, make_urdf
    from biped_controller.graph.controller_node import STATUS_FIELDS

    urdf = make_urdf(load_description())
    tfb, imub = TransformBuilder(urdf), ImuBuilder(0.0, 0.0)
    x = [rng.uniform(-1, 1) for _ in range(9)]
    q6 = [rng.uniform(-1, 1) for _ in range(6)]
    sec, ns = 3, 141_000_000
    ss_enc, js_enc, st_enc = cdr.SimState(), cdr.JointState(), cdr.ControllerStatus()
    wr_enc, pt_enc = cdr.Stamped('WrenchStamped', 6), cdr.Stamped('PointStamped', 3)
    imu_enc = cdr.Imu('torso')
    tf_frames = [('world', 'torso')] + [tfb.joints[n][:2] for n in URDF_JOINTS]
    tf_enc = cdr.TfMessage(tf_frames)
    import numpy as np
    xa = np.array(x)

    def o_state():
        m = SimState()
        m.stamp, m.step, m.stance = Time(sec=sec, nanosec=ns), 7, 1
        m.q, m.q_dot, m.base, m.base_dot = q6, q6, x[:3], x[:3]
        m.fallen, m.fall_cause, m.sequence = False, '', 8
        return m

    def o_js(names, n):
        m = JointState()
        m.header.stamp = Time(sec=sec, nanosec=ns)
        m.name = list(names)
        if n:
            m.position, m.velocity = q6, q6
        m.effort = q6
        return m

    def o_wrench():
        w = WrenchStamped()
        w.header.stamp, w.header.frame_id = Time(sec=sec, nanosec=ns), 'left_foot'
        w.wrench.force.x, w.wrench.force.z, w.wrench.torque.y = x[0], x[1], -x[2]
        return w

    def o_cop():
        c = PointStamped()
        c.header.stamp, c.header.frame_id = Time(sec=sec, nanosec=ns), 'world'
        c.point.x = x[3]
        return c

    class S:   # a ControllerStatusData stand-in with every field
        pass
    s = S()
    for name, conv in STATUS_FIELDS:
        setattr(s, name, {str: 'both', int: 1}.get(conv, 0.25) if conv in (str, int, float) else [0.5] * (17 if name == 'margins' else 2))
    s.qp_message = ''

    def o_status():
        m = ControllerStatus()
        m.stamp = Time(sec=sec, nanosec=ns)
        for name, conv in STATUS_FIELDS:
            setattr(m, name, conv(getattr(s, name)))
        return m

    def b_status():
        return st_enc.encode(sec, ns, int(s.step), s.mode, (s.p, s.p_dot, s.tau, s.tau_dot, s.p_ddot, s.tau_ddot,
                                                           s.p_ddot_star, s.tau_ddot_star), int(s.qp_status),
                             s.qp_message, s.margins, int(s.tightest), s.zmp, int(s.stance), s.max_tracking_error,
                             s.predicted_reaction, s.force_estimate, int(s.wbc_status), int(s.wbc_active),
                             (s.wbc_deviation, s.lam, s.lam_dot, s.lam_ddot, s.lam_ddot_star))

    def b_tf():
        poses = [(x[0], 0.0, x[1], *_q(x[2]))]
        for k, name in enumerate(URDF_JOINTS):
            poses.append((*tfb.joints[name][2], *_q(x[3 + k])))
        return tf_enc.encode(sec, ns, poses)

    def _q(a):
        return 0.0, -math.sin(0.5 * a), 0.0, math.cos(0.5 * a)

    def b_imu():
        p, r = x[2], x[5]
        return imu_enc.encode(sec, ns, (0.0, -math.sin(0.5 * p), 0.0, math.cos(0.5 * p), 0.0, 0.0, 0.0, 0.0, 0.0,
                                        0.0, 0.0, 0.0, 0.0, 0.0, -r, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                        0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))

    return {
        '/bench/clock': (lambda: Clock(clock=Time(sec=sec, nanosec=ns)), lambda: cdr.clock(sec, ns)),
        '/bench/imu': (lambda: imub.message(Time(sec=sec, nanosec=ns), x[2], x[5]), b_imu),
        '/bench/sim_state': (o_state, lambda: ss_enc.encode(sec, ns, 7, 1, q6, q6, x[:3], x[:3], False, '', 8)),
        '/bench/tf': (lambda: tfb.message(Time(sec=sec, nanosec=ns), xa), b_tf),
        '/bench/stance': (lambda: UInt8(data=1), lambda: cdr.uint8(1)),
        '/bench/joint_states': (lambda: o_js(URDF_JOINTS, True),
                                lambda: js_enc.encode(sec, ns, '', URDF_JOINTS, q6, q6, q6)),
        '/bench/ground_reaction': (o_wrench, lambda: wr_enc.encode(sec, ns, 'left_foot',
                                                                   (x[0], 0.0, x[1], 0.0, -x[2], 0.0))),
        '/bench/cop': (o_cop, lambda: pt_enc.encode(sec, ns, 'world', (x[3], 0.0, 0.0))),
        '/bench/sim_push': (lambda: AppliedPush(stamp=Time(sec=sec, nanosec=ns), period=0.001, force=0.0,
                                                impulse=0.0, mean_force=0.0, height=math.nan),
                            lambda: cdr.applied_push(sec, ns, 0.001, 0.0, 0.0, 0.0, math.nan)),
        '/bench/torque': (lambda: o_js(PAPER_JOINTS, False), lambda: js_enc.encode(sec, ns, '', PAPER_JOINTS, (), (), q6)),
        '/bench/status': (o_status, b_status),
    }


def _run(pubs, makers, n: int, variant: int) -> dict[str, float]:
    out = {}
    for topic, pub in pubs.items():
        make = makers[topic][variant]
        publish = pub.publish
        t0 = time.process_time()
        for _ in range(n):
            publish(make())
        out[topic] = (time.process_time() - t0) / n * 1e6
    return out


def main(argv=None) -> int:
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == '--subscriber':
        _subscriber()
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--n', type=int, default=2000)
    ap.add_argument('--pairs', type=int, default=3)
    ap.add_argument('--lockstep-pairs', type=int, default=0)
    ap.add_argument('--lockstep-only', action='store_true', help='skip the per-type publish figures')
    ap.add_argument('--json', default=str(RESULTS_DIR / 'publish_cost.json'), help="'' = no file")
    a = ap.parse_args(argv)
    provenance.track(a.json or None, argv=argv)   # record of each file written (results/README.md)
    summary: dict = {'n': a.n, 'pairs': a.pairs}
    if not a.lockstep_only:
        _per_type(a, summary)
    if a.lockstep_pairs:
        from benchmarks.domain import Domain
        from benchmarks.lockstep import measure
        runs = []
        for k in range(a.lockstep_pairs):
            for flag in (('false', 'true') if k % 2 == 0 else ('true', 'false')):
                load = os.getloadavg()[0]
                p = (f'publish_cdr:={flag}',)
                r = measure(2.0, Domain, ctrl_params=p, sim_params=p)
                r.update(publish_cdr=flag == 'true', load_average_1min_at_start=load)
                runs.append(r)
                print(f"lockstep publish_cdr {flag:5s}: {r.get('steps_per_s', float('nan')):.0f} steps/s "
                      f"(load {load:.1f})", flush=True)
        summary['lockstep'] = runs
        for flag in (False, True):
            rates = [r['steps_per_s'] for r in runs if r['publish_cdr'] is flag and r.get('available')]
            if rates:
                print(f'lockstep publish_cdr {str(flag).lower():5s}: median {statistics.median(rates):.0f} steps/s '
                      f'of {len(rates)} runs')
    if a.json:
        Path(a.json).write_text(json.dumps(summary, indent=2) + '\n')
    return 0


def _per_type(a, summary: dict) -> None:
    import rclpy
    from biped_sim.graph import names as gn
    rclpy.init()
    node = rclpy.create_node('publish_cost')
    types = _types()
    pubs = {t: node.create_publisher(types[t], t, gn.QOS_SENSOR) for t in TOPICS}
    makers = _makers(random.Random(SEED))
    load0 = os.getloadavg()
    rows: dict[str, dict[str, dict[str, list[float]]]] = {}
    for cond in ('no subscriber', '1 subscriber'):
        sub = None
        if cond == '1 subscriber':
            sub = subprocess.Popen([sys.executable, '-m', 'benchmarks.publish_cost', '--subscriber'], cwd=ROOT,
                                   stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            assert sub.stdout.readline().strip() == 'ready'
            deadline = time.monotonic() + 30
            while any(p.get_subscription_count() < 1 for p in pubs.values()):
                if time.monotonic() > deadline:
                    raise RuntimeError('the subscriber did not match every topic within 30 s')
                time.sleep(0.05)
        try:
            _run(pubs, makers, 200, 0), _run(pubs, makers, 200, 1)      # warm-up (layouts, pools)
            res = {t: {'object': [], 'bytes': []} for t in TOPICS}
            for r in range(a.pairs):
                order = (0, 1) if r % 2 == 0 else (1, 0)
                for variant in order:
                    for t, us in _run(pubs, makers, a.n, variant).items():
                        res[t][('object', 'bytes')[variant]].append(us)
            rows[cond] = res
        finally:
            if sub is not None:
                sub.stdin.close()
                sub.wait(timeout=30)
    load1 = os.getloadavg()
    summary.update({'load_average_start': load0, 'load_average_end': load1, 'cpu_us_per_publish': {}})
    print(f'load average start {load0}, end {load1}; n {a.n}, pairs {a.pairs}; CPU us per publish (median)')
    print(f'{"topic":26s} {"condition":14s} {"object":>8s} {"bytes":>8s} {"ratio":>6s}')
    for cond, res in rows.items():
        tot_o = tot_b = 0.0
        for t in TOPICS:
            o, b = statistics.median(res[t]['object']), statistics.median(res[t]['bytes'])
            tot_o, tot_b = tot_o + o, tot_b + b
            summary['cpu_us_per_publish'].setdefault(cond, {})[t] = {
                'object': o, 'bytes': b, 'ratio': o / b, 'object_runs': res[t]['object'], 'bytes_runs': res[t]['bytes']}
            print(f'{t:26s} {cond:14s} {o:8.1f} {b:8.1f} {o / b:6.2f}')
        summary['cpu_us_per_publish'][cond]['all 11 (one control step)'] = {'object': tot_o, 'bytes': tot_b,
                                                                           'ratio': tot_o / tot_b}
        print(f'{"all 11 (one control step)":26s} {cond:14s} {tot_o:8.1f} {tot_b:8.1f} {tot_o / tot_b:6.2f}')
    node.destroy_node()
    rclpy.shutdown()


if __name__ == '__main__':
    sys.exit(main())
