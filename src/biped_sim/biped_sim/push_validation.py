"""Validation of push requests (pure: no ROS import), used by the ``disturbance`` node.

:class:`PushLimits` holds the configured bounds; :func:`validate_push_request` checks one
``/apply_push`` request against them, the current sim time and the pushes already scheduled, and
returns the resolved :class:`ValidPush` or raises :class:`Rejected` naming the field and the allowed
range. Checks, in this order (the first failure is reported):

- ``delay`` (only when ``use_delay``): finite and >= 0; the start is then ``now + delay``;
- ``force``, ``duration``, ``start``: finite numbers;
- ``duration`` in (0, max_duration] s;
- ``force`` in [-max_force, max_force] N;
- ``start`` >= ``now`` (not in the past);
- ``height``: NaN (= the default height) or within [0, torso_length] m (on the torso);
- no overlap of [start, start + duration) with any scheduled push (``start`` is named).

Nothing is changed by a validation: :class:`PushBook` adds a push only through :meth:`PushBook.add`
after :meth:`PushBook.check` passed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

__all__ = ['Rejected', 'PushLimits', 'ValidPush', 'ScheduledPush', 'validate_push_request', 'PushBook']


class Rejected(ValueError):
    """A push request is invalid; ``field`` names the request field."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class PushLimits:
    max_force: float          # N, |force| bound
    max_duration: float       # s
    torso_length: float       # m, heights must lie in [0, torso_length]
    default_height: float     # m, used when the request's height is NaN

    def __post_init__(self):
        for name in ('max_force', 'max_duration', 'torso_length'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {v!r}')
        h = self.default_height
        if not (isinstance(h, (int, float)) and math.isfinite(h) and 0.0 <= h <= self.torso_length):
            raise ValueError(f'default_height must be within [0, {self.torso_length}] m, got {h!r}')


@dataclass(frozen=True)
class ScheduledPush:
    id: int
    start: float
    end: float
    force: float
    height: float


@dataclass(frozen=True)
class ValidPush:
    start: float
    duration: float
    force: float
    height: float

    @property
    def end(self) -> float:
        return self.start + self.duration


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def validate_push_request(force: float, duration: float, start: float, height: float, now: float,
                          limits: PushLimits, scheduled: Iterable[ScheduledPush] = (), *,
                          use_delay: bool = False, delay: float = 0.0) -> ValidPush:
    """Check one request; return the resolved push or raise :class:`Rejected` (see the module doc)."""
    if use_delay:
        if not _is_number(delay) or not math.isfinite(delay):
            raise Rejected('delay', f'delay must be a finite number in [0, inf) s, got {delay}')
        if delay < 0:
            raise Rejected('delay', f'delay must be in [0, inf) s, got {delay}')
        start = now + delay
    ranges = {'force': f'[-{limits.max_force}, {limits.max_force}] N', 'duration': f'(0, {limits.max_duration}] s',
              'start': f'[{now:.6f}, inf) s (not before the current sim time)'}
    for name, v in (('force', force), ('duration', duration), ('start', start)):
        if not _is_number(v) or not math.isfinite(v):
            raise Rejected(name, f'{name} must be a finite number in {ranges[name]}, got {v}')
    if not 0.0 < duration <= limits.max_duration:
        raise Rejected('duration', f'duration must be in (0, {limits.max_duration}] s, got {duration}')
    if abs(force) > limits.max_force:
        raise Rejected('force', f'force must be in [-{limits.max_force}, {limits.max_force}] N, got {force}')
    if start < now:
        raise Rejected('start', f'start must not be in the past: in [{now:.6f}, inf) s '
                                f'(current sim time), got {start}')
    if not _is_number(height):
        raise Rejected('height', f'height must be a number, got {height!r}')
    if math.isnan(height):
        height = limits.default_height
    elif not (math.isfinite(height) and 0.0 <= height <= limits.torso_length):
        raise Rejected('height', f'height must be NaN (default {limits.default_height} m) or within '
                                 f'[0, {limits.torso_length}] m (the torso), got {height}')
    end = start + duration
    for p in scheduled:
        if start < p.end and p.start < end:
            raise Rejected('start', f'[start, start + duration) = [{start}, {end}) s overlaps push {p.id} '
                                    f'[{p.start}, {p.end}) s: must start >= {p.end} s or end <= {p.start} s')
    return ValidPush(float(start), float(duration), float(force), float(height))


class PushBook:
    """The pushes scheduled so far and the ids handed out (no ROS)."""

    def __init__(self, limits: PushLimits):
        self.limits = limits
        self.pushes: list[ScheduledPush] = []
        self.next_id = 1

    def check(self, force: float, duration: float, start: float, height: float, now: float, *,
              use_delay: bool = False, delay: float = 0.0) -> ValidPush:
        return validate_push_request(force, duration, start, height, now, self.limits, self.pushes,
                                     use_delay=use_delay, delay=delay)

    def add(self, push: ValidPush) -> int:
        pid = self.next_id
        self.next_id += 1
        self.pushes.append(ScheduledPush(pid, push.start, push.end, push.force, push.height))
        return pid
