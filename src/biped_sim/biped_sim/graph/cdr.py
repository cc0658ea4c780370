"""Hand-written CDR encoders of the messages the simulator and the controller publish every control step (pure:
imports no ROS), for ``Publisher.publish(bytes)`` (rclpy then hands the bytes to the middleware as they are:
no Python message object, no Python -> C conversion, no serialisation).

Format: what rclpy + Fast DDS (rmw_fastrtps_cpp, ROS 2 Jazzy) put on the wire and the recorder stores,
i.e. plain CDR version 1 (XCDR1), little-endian:

- a 4-byte encapsulation header ``00 01 00 00`` (representation identifier CDR_LE, options 0);
- then the fields in the order of the ``.msg`` file, nested messages inlined (no member headers);
- every primitive aligned to its own size (1, 4 or 8 bytes; ``float64`` / ``uint64`` to 8) counted from the
  first byte *after* the encapsulation header, the gap filled with zero bytes;
- ``bool``, ``uint8``: 1 byte; ``int32`` (``Time.sec``), ``uint32``: 4; ``uint64``, ``float64``: 8 (IEEE 754
  binary64 as is: NaN payloads, infinities and the sign of zero are kept);
- ``string``: a ``uint32`` length counting the terminating NUL, the UTF-8 bytes, the NUL (no alignment of the
  bytes themselves);
- a fixed-size array ``T[n]``: n elements, no length; a sequence ``T[]``: a ``uint32`` element count then the
  elements (the first element aligned as T; an empty sequence is its count only);
- no padding after the last field (a ``std_msgs/UInt8`` is 5 bytes on the wire).

(``rclpy.serialization.serialize_message`` is *not* that reference byte for byte: it returns the typesupport's
estimated size, with bytes past the end of the message and alignment gaps left as they were in its buffer;
the test compares with what a raw subscription receives, the recorder's bytes, and with its deserialisation.)

Each encoder compiles a ``struct.Struct`` once per layout: the layout is fixed by the lengths of the strings
and sequences only, so it is cached by those lengths (frames, joint names and the mode are the same every
step: one ``Struct`` per node in practice). A value of the wrong type, an integer out of its field's range or
an array of the wrong size raises :class:`CdrEncodeError` naming the message. Stamps are given as
``(sec, nanosec)`` integers of ``builtin_interfaces/Time`` (:func:`stamp_parts`).
"""
from __future__ import annotations

import struct
from typing import Iterable, Sequence

#: encapsulation header of CDR little-endian, options 0
ENCAPSULATION = b'\x00\x01\x00\x00'

_SIZES = {'?': 1, 'B': 1, 'i': 4, 'I': 4, 'Q': 8, 'd': 8}


class CdrEncodeError(ValueError):
    """A value does not fit the message's CDR layout (the message says which message)."""


def stamp_parts(t: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of sim time ``t`` [s], rounded to the nanosecond: the simulator's ``stamp_of``."""
    ns = int(round(t * 1e9))
    return ns // 1_000_000_000, ns % 1_000_000_000


class Layout:
    """A CDR body's ``struct`` format built field by field. ``offset`` counts bytes after the encapsulation
    header (CDR's alignment origin); the format starts with ``4s`` for the header itself."""

    def __init__(self) -> None:
        self.parts: list[str] = ['<4s']
        self.offset = 0

    def align(self, size: int) -> None:
        pad = (-self.offset) % size
        if pad:
            self.parts.append(f'{pad}x')
            self.offset += pad

    def prim(self, code: str, count: int = 1) -> 'Layout':
        """``count`` primitives ``code`` (struct codes ``? B i I Q d``), the first aligned to its size (none
        and no alignment for ``count`` 0)."""
        size = _SIZES[code]
        if count:                 # an empty sequence is its count only: no alignment for absent elements
            self.align(size)
            self.parts.append(f'{count}{code}')
            self.offset += size * count
        return self

    def string(self, nbytes: int) -> 'Layout':
        """A string of ``nbytes`` UTF-8 bytes: ``uint32`` length nbytes + 1, the bytes, the NUL (``s`` pads)."""
        self.prim('I')
        self.parts.append(f'{nbytes + 1}s')
        self.offset += nbytes + 1
        return self

    def header(self, frame_nbytes: int) -> 'Layout':
        """``std_msgs/Header``: ``Time`` (int32 sec, uint32 nanosec) then the frame id string."""
        return self.prim('i').prim('I').string(frame_nbytes)

    def compile(self) -> struct.Struct:
        return struct.Struct(''.join(self.parts))


def _pack(s: struct.Struct, what: str, args: Sequence) -> bytes:
    try:
        return s.pack(ENCAPSULATION, *args)
    except struct.error as exc:
        raise CdrEncodeError(f'{what}: {exc}') from exc


def _utf8(s: str) -> bytes:
    return s.encode('utf-8')


# ----------------------------------------------------------------------------------------------- per type
_CLOCK = Layout().prim('i').prim('I').compile()


def clock(sec: int, nanosec: int) -> bytes:
    """``rosgraph_msgs/Clock``: clock (Time)."""
    return _pack(_CLOCK, 'Clock', (sec, nanosec))


_UINT8 = Layout().prim('B').compile()


def uint8(data: int) -> bytes:
    """``std_msgs/UInt8``: data."""
    return _pack(_UINT8, 'UInt8', (data,))


class Imu:
    """``sensor_msgs/Imu`` with a fixed ``frame_id``: header, orientation (x, y, z, w), orientation_covariance
    [9], angular_velocity (x, y, z), angular_velocity_covariance [9], linear_acceleration (x, y, z),
    linear_acceleration_covariance [9], every number float64."""

    def __init__(self, frame_id: str) -> None:
        self.frame = _utf8(frame_id)
        self.struct = (Layout().header(len(self.frame)).prim('d', 4).prim('d', 9).prim('d', 3).prim('d', 9)
                       .prim('d', 3).prim('d', 9).compile())

    def encode(self, sec: int, nanosec: int, values: Sequence[float]) -> bytes:
        """``values``: the 37 float64 after the header, in message order."""
        return _pack(self.struct, 'Imu', (sec, nanosec, len(self.frame) + 1, self.frame, *values))


class SimState:
    """``biped_msgs_py/SimState``: stamp, uint64 step, uint8 stance, float64 q[6], q_dot[6], base[3],
    base_dot[3], bool fallen, string fall_cause, uint32 sequence."""

    def __init__(self) -> None:
        self._by_len: dict[int, struct.Struct] = {}

    def encode(self, sec: int, nanosec: int, step: int, stance: int, q: Sequence[float], q_dot: Sequence[float],
               base: Sequence[float], base_dot: Sequence[float], fallen: bool, fall_cause: str,
               sequence: int) -> bytes:
        cause = _utf8(fall_cause)
        s = self._by_len.get(len(cause))
        if s is None:
            s = self._by_len[len(cause)] = (Layout().prim('i').prim('I').prim('Q').prim('B').prim('d', 6)
                                            .prim('d', 6).prim('d', 3).prim('d', 3).prim('?')
                                            .string(len(cause)).prim('I').compile())
        if not (len(q) == len(q_dot) == 6 and len(base) == len(base_dot) == 3):
            raise CdrEncodeError(f'SimState: q, q_dot need 6 values, base, base_dot 3, got {len(q)}, {len(q_dot)}, '
                                 f'{len(base)}, {len(base_dot)}')
        return _pack(s, 'SimState', (sec, nanosec, step, stance, *q, *q_dot, *base, *base_dot, fallen,
                                     len(cause) + 1, cause, sequence))


class TfMessage:
    """``tf2_msgs/TFMessage`` of a fixed list of (parent frame, child frame) transforms, all with one stamp:
    uint32 count, then per ``geometry_msgs/TransformStamped``: header (stamp, parent), child_frame_id,
    translation (x, y, z), rotation (x, y, z, w), float64."""

    def __init__(self, frames: Iterable[tuple[str, str]]) -> None:
        self.frames = [(_utf8(p), _utf8(c)) for p, c in frames]
        lay = Layout().prim('I')
        for p, c in self.frames:
            lay.header(len(p)).string(len(c)).prim('d', 7)
        self.struct = lay.compile()

    def encode(self, sec: int, nanosec: int, poses: Sequence[Sequence[float]]) -> bytes:
        """``poses``: per transform (tx, ty, tz, rx, ry, rz, rw), in the order of ``frames``."""
        if len(poses) != len(self.frames):
            raise CdrEncodeError(f'TFMessage: {len(self.frames)} transforms, got {len(poses)} poses')
        args: list = [len(self.frames)]
        for (p, c), pose in zip(self.frames, poses):
            if len(pose) != 7:
                raise CdrEncodeError(f'TFMessage: a pose has 7 numbers, got {len(pose)}')
            args += (sec, nanosec, len(p) + 1, p, len(c) + 1, c, *pose)
        return _pack(self.struct, 'TFMessage', args)


class JointState:
    """``sensor_msgs/JointState``: header, string[] name, float64[] position, velocity, effort. The layout is
    cached by (frame, names, the three lengths)."""

    def __init__(self) -> None:
        self._cache: dict[tuple, tuple[struct.Struct, tuple]] = {}

    def encode(self, sec: int, nanosec: int, frame_id: str, names: Sequence[str], position: Sequence[float],
               velocity: Sequence[float], effort: Sequence[float]) -> bytes:
        key = (frame_id, tuple(names), len(position), len(velocity), len(effort))
        hit = self._cache.get(key)
        if hit is None:
            frame = _utf8(frame_id)
            enc = [_utf8(n) for n in names]
            lay = Layout().header(len(frame)).prim('I')
            fixed: list = [len(enc)]
            for n in enc:
                lay.string(len(n))
                fixed += (len(n) + 1, n)
            for seq in (position, velocity, effort):
                lay.prim('I').prim('d', len(seq))
            hit = self._cache[key] = (lay.compile(), (len(frame) + 1, frame, *fixed))
        s, fixed = hit
        return _pack(s, 'JointState', (sec, nanosec, *fixed, len(position), *position, len(velocity), *velocity,
                                       len(effort), *effort))


class Stamped:
    """A ``std_msgs/Header`` then ``n`` float64: ``geometry_msgs/WrenchStamped`` (n = 6: force x, y, z, torque
    x, y, z), ``geometry_msgs/PointStamped`` (n = 3: x, y, z). Cached by frame."""

    def __init__(self, name: str, n: int) -> None:
        self.name, self.n = name, n
        self._by_frame: dict[str, tuple[struct.Struct, bytes]] = {}

    def encode(self, sec: int, nanosec: int, frame_id: str, values: Sequence[float]) -> bytes:
        hit = self._by_frame.get(frame_id)
        if hit is None:
            frame = _utf8(frame_id)
            hit = self._by_frame[frame_id] = (Layout().header(len(frame)).prim('d', self.n).compile(), frame)
        s, frame = hit
        return _pack(s, self.name, (sec, nanosec, len(frame) + 1, frame, *values))


_APPLIED_PUSH = Layout().prim('i').prim('I').prim('d', 5).compile()


def applied_push(sec: int, nanosec: int, period: float, force: float, impulse: float, mean_force: float,
                 height: float) -> bytes:
    """``biped_msgs_py/AppliedPush``: stamp, float64 period, force, impulse, mean_force, height."""
    return _pack(_APPLIED_PUSH, 'AppliedPush', (sec, nanosec, period, force, impulse, mean_force, height))


class ControllerStatus:
    """``biped_msgs_py/ControllerStatus``: stamp; uint64 step; string mode; float64 p, p_dot, tau, tau_dot,
    p_ddot, tau_ddot, p_ddot_star, tau_ddot_star; uint8 qp_status; string qp_message; float64 margins[17];
    uint8 tightest; float64 zmp; uint8 stance; float64 max_tracking_error; float64 predicted_reaction[2];
    float64 force_estimate; uint8 wbc_status; uint32 wbc_active; float64 wbc_deviation, lam, lam_dot, lam_ddot,
    lam_ddot_star. Cached by the two strings' byte lengths."""

    def __init__(self) -> None:
        self._by_len: dict[tuple[int, int], struct.Struct] = {}

    def encode(self, sec: int, nanosec: int, step: int, mode: str, pt: Sequence[float], qp_status: int,
               qp_message: str, margins: Sequence[float], tightest: int, zmp: float, stance: int,
               max_tracking_error: float, predicted_reaction: Sequence[float], force_estimate: float,
               wbc_status: int, wbc_active: int, lam: Sequence[float]) -> bytes:
        """``pt``: (p, p_dot, tau, tau_dot, p_ddot, tau_ddot, p_ddot_star, tau_ddot_star); ``lam``:
        (wbc_deviation, lam, lam_dot, lam_ddot, lam_ddot_star), the message's last five float64."""
        m, qm = _utf8(mode), _utf8(qp_message)
        key = (len(m), len(qm))
        s = self._by_len.get(key)
        if s is None:
            s = self._by_len[key] = (Layout().prim('i').prim('I').prim('Q').string(len(m)).prim('d', 8)
                                     .prim('B').string(len(qm)).prim('d', 17).prim('B').prim('d').prim('B')
                                     .prim('d').prim('d', 2).prim('d').prim('B').prim('I').prim('d', 5).compile())
        if len(pt) != 8 or len(margins) != 17 or len(predicted_reaction) != 2 or len(lam) != 5:
            raise CdrEncodeError(f'ControllerStatus: 8 p/tau values, 17 margins, 2 reactions, 5 last values; got '
                                 f'{len(pt)}, {len(margins)}, {len(predicted_reaction)}, {len(lam)}')
        return _pack(s, 'ControllerStatus', (sec, nanosec, step, len(m) + 1, m, *pt, qp_status, len(qm) + 1, qm,
                                             *margins, tightest, zmp, stance, max_tracking_error,
                                             *predicted_reaction, force_estimate, wbc_status, wbc_active, *lam))
