"""The hand-written CDR encoders (biped_sim.graph.cdr) against the middleware's own serialisation, byte for byte.

Reference: the bytes a raw subscription receives when the ordinary message object is published through rclpy
and Fast DDS (the bytes the recorder stores), and rclpy's deserialiser reading the encoder's bytes back.
(``rclpy.serialization.serialize_message`` is not usable byte for byte: it returns the typesupport's estimated
size with uninitialised alignment gaps and tail, ``cdr``'s docstring.) Contents: seeded random values with
NaN (also with a payload), +-inf, -0.0, subnormals, extreme stamps and integers, empty and non-empty
strings (also non-ASCII) and sequences, for every message type the simulator and the controller publish each
step. Negative controls: a layout without one alignment pad, and a string length without its NUL, are told
apart by the same comparison. Every wait is bounded by a message count (60 s at most), none measures time.
"""
from __future__ import annotations

import math
import random
import struct
import time

import pytest

from helpers import ROOT  # noqa: F401  (the project's packages on sys.path)

from biped_sim.graph import cdr

SEED = 20_2003
PER_TYPE = 40

_SPECIAL = [math.nan, math.inf, -math.inf, -0.0, 0.0, 5e-324, -1.7e308, 1.7e308,
            struct.unpack('<d', struct.pack('<Q', 0x7FF8_0000_0000_0001))[0]]
_STRINGS = ['', 'a', 'ab', 'abc', 'abcd', 'left_foot', 'torso', 'ünï', 'x' * 13]


def _f(rng: random.Random) -> float:
    return rng.choice(_SPECIAL) if rng.random() < 0.3 else rng.uniform(-1e3, 1e3)


def _fs(rng, n):
    return [_f(rng) for _ in range(n)]


def _s(rng: random.Random) -> str:
    return rng.choice(_STRINGS) if rng.random() < 0.6 else ''.join(rng.choice('abcXYZ_/') for _ in range(rng.randrange(0, 17)))


def _stamp(rng):
    return rng.choice([0, -1, 2**31 - 1, -2**31, rng.randrange(-2**31, 2**31)]), rng.randrange(0, 10**9)


def _cases(rng: random.Random):
    """(message type, topic, message object, encoder bytes) per random case, PER_TYPE of each type."""
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import PointStamped, TransformStamped, WrenchStamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, JointState
    from std_msgs.msg import UInt8
    from tf2_msgs.msg import TFMessage
    from biped_msgs_py.msg import AppliedPush, ControllerStatus, SimState

    js_enc, st_enc, ss_enc = cdr.JointState(), cdr.ControllerStatus(), cdr.SimState()
    wr_enc, pt_enc = cdr.Stamped('WrenchStamped', 6), cdr.Stamped('PointStamped', 3)
    out = []
    for _ in range(PER_TYPE):
        sec, ns = _stamp(rng)
        t = Time(sec=sec, nanosec=ns)
        out.append((Clock, '/t/clock', Clock(clock=t), cdr.clock(sec, ns)))
        d = rng.randrange(256)
        out.append((UInt8, '/t/u8', UInt8(data=d), cdr.uint8(d)))

        frame = _s(rng)
        v = _fs(rng, 37)
        m = Imu()
        m.header.stamp, m.header.frame_id = t, frame
        o = m.orientation
        o.x, o.y, o.z, o.w = v[0:4]
        m.orientation_covariance = v[4:13]
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = v[13:16]
        m.angular_velocity_covariance = v[16:25]
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = v[25:28]
        m.linear_acceleration_covariance = v[28:37]
        out.append((Imu, '/t/imu', m, cdr.Imu(frame).encode(sec, ns, v)))

        s = SimState()
        s.stamp, s.step, s.stance = t, rng.choice([0, 2**64 - 1, rng.randrange(2**64)]), rng.randrange(256)
        s.q, s.q_dot, s.base, s.base_dot = _fs(rng, 6), _fs(rng, 6), _fs(rng, 3), _fs(rng, 3)
        s.fallen, s.fall_cause, s.sequence = rng.random() < 0.5, _s(rng), rng.randrange(2**32)
        out.append((SimState, '/t/state', s, ss_enc.encode(sec, ns, s.step, s.stance, list(s.q), list(s.q_dot),
                                                            list(s.base), list(s.base_dot), s.fallen,
                                                            s.fall_cause, s.sequence)))

        frames = [(_s(rng), _s(rng)) for _ in range(rng.randrange(0, 9))]
        poses = [_fs(rng, 7) for _ in frames]
        tfs = []
        for (p, c), pose in zip(frames, poses):
            ts = TransformStamped()
            ts.header.stamp, ts.header.frame_id, ts.child_frame_id = t, p, c
            tr, r = ts.transform.translation, ts.transform.rotation
            tr.x, tr.y, tr.z, r.x, r.y, r.z, r.w = pose
            tfs.append(ts)
        out.append((TFMessage, '/t/tf', TFMessage(transforms=tfs), cdr.TfMessage(frames).encode(sec, ns, poses)))

        j = JointState()
        j.header.stamp, j.header.frame_id = t, _s(rng)
        j.name = [_s(rng) for _ in range(rng.randrange(0, 8))]
        j.position, j.velocity, j.effort = (_fs(rng, rng.randrange(0, 8)) for _ in range(3))
        out.append((JointState, '/t/js', j, js_enc.encode(sec, ns, j.header.frame_id, list(j.name), list(j.position),
                                                          list(j.velocity), list(j.effort))))

        w = WrenchStamped()
        w.header.stamp, w.header.frame_id = t, _s(rng)
        v = _fs(rng, 6)
        w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = v[:3]
        w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = v[3:]
        out.append((WrenchStamped, '/t/wrench', w, wr_enc.encode(sec, ns, w.header.frame_id, v)))

        pm = PointStamped()
        pm.header.stamp, pm.header.frame_id = t, _s(rng)
        v = _fs(rng, 3)
        pm.point.x, pm.point.y, pm.point.z = v
        out.append((PointStamped, '/t/point', pm, pt_enc.encode(sec, ns, pm.header.frame_id, v)))

        v = _fs(rng, 5)
        ap = AppliedPush(stamp=t, period=v[0], force=v[1], impulse=v[2], mean_force=v[3], height=v[4])
        out.append((AppliedPush, '/t/push', ap, cdr.applied_push(sec, ns, *v)))

        cs = ControllerStatus()
        cs.stamp, cs.step, cs.mode = t, rng.randrange(2**64), _s(rng)
        pt = _fs(rng, 8)
        (cs.p, cs.p_dot, cs.tau, cs.tau_dot, cs.p_ddot, cs.tau_ddot, cs.p_ddot_star, cs.tau_ddot_star) = pt
        cs.qp_status, cs.qp_message, cs.margins = rng.randrange(256), _s(rng), _fs(rng, 17)
        cs.tightest, cs.zmp, cs.stance, cs.max_tracking_error = rng.randrange(256), _f(rng), rng.randrange(256), _f(rng)
        cs.predicted_reaction, cs.force_estimate = _fs(rng, 2), _f(rng)
        cs.wbc_status, cs.wbc_active = rng.randrange(256), rng.randrange(2**32)
        last = _fs(rng, 5)
        cs.wbc_deviation, cs.lam, cs.lam_dot, cs.lam_ddot, cs.lam_ddot_star = last
        out.append((ControllerStatus, '/t/status', cs,
                    st_enc.encode(sec, ns, cs.step, cs.mode, pt, cs.qp_status, cs.qp_message, list(cs.margins),
                                  cs.tightest, cs.zmp, cs.stance, cs.max_tracking_error,
                                  list(cs.predicted_reaction), cs.force_estimate, cs.wbc_status, cs.wbc_active,
                                  last)))
    return out


def _wire_bytes(context, cases) -> dict[str, list[bytes]]:
    """Publish every case's message object (in order) and take what raw subscriptions of the same process receive."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
    node = Node('cdr_reference', context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    got: dict[str, list[bytes]] = {}
    pubs = {}
    try:
        for typ, topic, _m, _b in cases:
            if topic not in pubs:
                got[topic] = []
                node.create_subscription(typ, topic, got[topic].append, qos, raw=True)
                pubs[topic] = node.create_publisher(typ, topic, qos)
        deadline = time.monotonic() + 60.0
        while any(p.get_subscription_count() < 1 for p in pubs.values()) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        for typ, topic, m, _b in cases:
            pubs[topic].publish(m)
        while sum(map(len, got.values())) < len(cases) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
    finally:
        ex.shutdown()
        node.destroy_node()
    assert sum(map(len, got.values())) == len(cases), {k: len(v) for k, v in got.items()}
    return got


def _first_difference(a: bytes, b: bytes):
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return i
    return None if len(a) == len(b) else min(len(a), len(b))


@pytest.mark.ros
def test_encoders_equal_the_middleware_bytes(rclpy_context):
    from rclpy.serialization import deserialize_message

    cases = _cases(random.Random(SEED))
    wire = _wire_bytes(rclpy_context, cases)
    index = {k: 0 for k in wire}
    bad = []
    for typ, topic, m, enc in cases:
        ref = wire[topic][index[topic]]
        index[topic] += 1
        if enc != ref:
            bad.append((typ.__name__, _first_difference(enc, ref), enc.hex(), ref.hex()))
        # rclpy's deserialiser reads the encoder's bytes back to the same wire bytes' message
        back = deserialize_message(enc, typ)
        assert type(back) is typ
    assert not bad, bad[:3]
    types = {typ.__name__ for typ, *_ in cases}
    assert types == {'Clock', 'UInt8', 'Imu', 'SimState', 'TFMessage', 'JointState', 'WrenchStamped',
                     'PointStamped', 'AppliedPush', 'ControllerStatus'}


def test_round_trip_through_rclpy_deserializer():
    """Field values (bits: NaN payloads, -0.0) read back by rclpy's deserialiser from the encoder's bytes."""
    from rclpy.serialization import deserialize_message
    from biped_msgs_py.msg import SimState

    bits = lambda v: struct.pack('<d', v)  # noqa: E731
    rng = random.Random(SEED + 1)
    enc = cdr.SimState()
    for _ in range(200):
        q, qd, b, bd = _fs(rng, 6), _fs(rng, 6), _fs(rng, 3), _fs(rng, 3)
        cause, seq, step = _s(rng), rng.randrange(2**32), rng.randrange(2**64)
        m = deserialize_message(enc.encode(7, 5, step, 1, q, qd, b, bd, True, cause, seq), SimState)
        assert (m.stamp.sec, m.stamp.nanosec, m.step, m.stance, m.fallen, m.fall_cause, m.sequence) == \
            (7, 5, step, 1, True, cause, seq)
        assert [bits(v) for v in (*m.q, *m.q_dot, *m.base, *m.base_dot)] == [bits(v) for v in (*q, *qd, *b, *bd)]


def test_negative_controls_a_missing_pad_or_nul_is_detected():
    """The comparison above tells a layout one alignment pad short, or a string length without the NUL,
    from the right one: checked against the right encoder's bytes (themselves checked against the wire)."""
    good = cdr.SimState().encode(1, 2, 3, 1, [0.5] * 6, [0.25] * 6, [1.0] * 3, [2.0] * 3, False, 'ab', 9)

    class NoPadOnce(cdr.Layout):
        skipped = False

        def align(self, size):
            if size == 8 and self.offset % 8 and not NoPadOnce.skipped:
                NoPadOnce.skipped = True       # the pad before q (after uint8 stance) is left out
                return
            super().align(size)

    lay = NoPadOnce().prim('i').prim('I').prim('Q').prim('B').prim('d', 6).prim('d', 6).prim('d', 3).prim('d', 3)
    lay.prim('?').string(2).prim('I')
    no_pad = lay.compile().pack(cdr.ENCAPSULATION, 1, 2, 3, 1, *[0.5] * 6, *[0.25] * 6, *[1.0] * 3, *[2.0] * 3,
                                False, 3, b'ab', 9)
    assert NoPadOnce.skipped
    # q[0] starts 7 bytes early (offset 17 instead of 24): the bytes differ from there to q[0]'s last byte
    assert no_pad != good and 4 + 17 <= _first_difference(no_pad, good) < 4 + 32

    no_nul = bytearray(good)
    at = good.index(b'ab\x00') - 4
    struct.pack_into('<I', no_nul, at, 2)          # length 2 instead of 3 (the NUL not counted)
    assert bytes(no_nul) != good and _first_difference(bytes(no_nul), good) == at


def test_bad_values_raise_cdr_encode_error():
    with pytest.raises(cdr.CdrEncodeError, match='UInt8'):
        cdr.uint8(256)
    with pytest.raises(cdr.CdrEncodeError, match='SimState'):
        cdr.SimState().encode(0, 0, 0, 0, [0.0] * 5, [0.0] * 6, [0.0] * 3, [0.0] * 3, False, '', 0)
    with pytest.raises(cdr.CdrEncodeError, match='Clock'):
        cdr.clock(0, -1)
    with pytest.raises(cdr.CdrEncodeError, match='TFMessage'):
        cdr.TfMessage([('a', 'b')]).encode(0, 0, [[0.0] * 6])
