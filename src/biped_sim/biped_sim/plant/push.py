"""Pushes: the one record type from the ``/apply_push`` service to the simulator, and its one validation
(pure: no ROS import).

A :class:`Push` is a horizontal force ``force`` [N] (world x, + forward) on the torso at ``height`` [m]
above the hip along the torso axis, over the sim-time window [start, start + duration) [s]. The same type
serves as a request (``id = 0``, ``height`` NaN = the default height) and as a scheduled push (id >= 1,
height resolved).

:func:`validate_push` checks a request against :class:`PushLimits`, the current sim time and the pushes
already scheduled, and returns the resolved push or raises :class:`Rejected` naming the field and the
allowed range. Checks, in this order (the first failure is reported):

- ``delay`` (only when ``use_delay``): finite and >= 0; the start is then ``now + delay``;
- ``force``, ``duration``, ``start``: finite numbers;
- ``duration`` in (0, max_duration] s;
- ``force`` in [-max_force, max_force] N;
- ``start`` >= ``now`` (not in the past; skipped when ``now`` is None);
- ``start`` <= ``horizon`` (a push that cannot start before the run ends is refused: the field named is
  ``delay`` when the start came from a delay, else ``start``);
- ``height``: NaN (= the default height) or within [0, torso_length] m (on the torso);
- ``start + duration > start`` in floating point (a duration below start's resolution is refused, naming
  ``duration``: the window would be empty);
- no overlap of [start, start + duration) with any scheduled push (``start`` is named).

Nothing is changed by a validation: :class:`PushBook` adds a push only through :meth:`PushBook.add`
after :meth:`PushBook.check` passed. The simulator validates what it is given with the same function
(its limits: no force or duration bound, its own torso, no past check, no horizon).
"""

from __future__ import annotations

import math

import numpy as np
from dataclasses import dataclass, replace
from typing import Iterable

from biped_model.finite import finite_number

__all__ = ['Push', 'Rejected', 'PushLimits', 'validate_push', 'PushBook']


class Rejected(ValueError):
    """A push request is invalid; ``field`` names the request field."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class Push:
    """Force ``force`` [N] (+ forward) at ``height`` [m] above the hip over [start, start + duration) [s].
    ``id`` 0 = not scheduled yet; ``height`` NaN = the default height (resolved when validated)."""

    start: float
    duration: float
    force: float
    height: float = math.nan
    id: int = 0

    @property
    def end(self) -> float:
        return self.start + self.duration


@dataclass(frozen=True)
class PushLimits:
    max_force: float          # N, |force| bound (inf: none)
    max_duration: float       # s (inf: none)
    torso_length: float       # m, heights must lie in [0, torso_length]
    default_height: float     # m, used when the request's height is NaN
    horizon: float = math.inf  # s, latest sim time a push may start (the end of the run)

    def __post_init__(self):
        for name in ('max_force', 'max_duration', 'torso_length', 'horizon'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isnan(v) and v > 0):
                raise ValueError(f'{name} must be a number > 0, got {v!r}')
        finite_number(self.torso_length, 'torso_length', message=f'torso_length must be finite, got {self.torso_length!r}')
        h = self.default_height
        finite_number(h, 'default_height', at_least=0.0, at_most=self.torso_length,
                      message=f'default_height must be within [0, {self.torso_length}] m, got {h!r}')


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def validate_push(force: float, duration: float, start: float, height: float, *, limits: PushLimits,
                  now: float | None = None, scheduled: Iterable[Push] = (), use_delay: bool = False,
                  delay: float = 0.0) -> Push:
    """Check one request; return the resolved :class:`Push` (id 0) or raise :class:`Rejected`."""
    if use_delay:
        finite_number(delay, 'delay', error=lambda m: Rejected('delay', m),
                      message=f'delay must be a finite number in [0, inf) s, got {delay}')
        if delay < 0:
            raise Rejected('delay', f'delay must be in [0, inf) s, got {delay}')
        start = (0.0 if now is None else now) + delay
    lo = -math.inf if now is None else now
    ranges = {'force': f'[-{limits.max_force}, {limits.max_force}] N', 'duration': f'(0, {limits.max_duration}] s',
              'start': f'[{lo:.6f}, {limits.horizon}] s'}
    for name, v in (('force', force), ('duration', duration), ('start', start)):
        finite_number(v, name, error=lambda m, name=name: Rejected(name, m),
                      message=f'{name} must be a finite number in {ranges[name]}, got {v}')
    if not 0.0 < duration <= limits.max_duration:
        raise Rejected('duration', f'duration must be in (0, {limits.max_duration}] s, got {duration}')
    if abs(force) > limits.max_force:
        raise Rejected('force', f'force must be in [-{limits.max_force}, {limits.max_force}] N, got {force}')
    if now is not None and start < now:
        raise Rejected('start', f'start must not be in the past: in [{now:.6f}, {limits.horizon}] s '
                                f'(current sim time), got {start}')
    if start > limits.horizon:
        field = 'delay' if use_delay else 'start'
        raise Rejected(field, f'{field}: the push would start at {start} s, after the end of the run '
                              f'(horizon {limits.horizon} s sim time): it could never act')
    if not _is_number(height):
        raise Rejected('height', f'height must be a number, got {height!r}')
    if math.isnan(height):
        height = limits.default_height
    elif not (math.isfinite(height) and 0.0 <= height <= limits.torso_length):
        raise Rejected('height', f'height must be NaN (default {limits.default_height} m) or within '
                                 f'[0, {limits.torso_length}] m (the torso), got {height}')
    end = start + duration
    if not end > start:   # a duration below start's float resolution: the window [start, start) is empty
        raise Rejected('duration', f'duration {duration} s is below the resolution of start {start} s '
                                   f'(start + duration == start): the push would act for no time')
    for p in scheduled:
        if start < p.end and p.start < end:
            raise Rejected('start', f'[start, start + duration) = [{start}, {end}) s overlaps push {p.id} '
                                    f'[{p.start}, {p.end}) s: must start >= {p.end} s or end <= {p.start} s')
    return Push(float(start), float(duration), float(force), float(height))


class PushBook:
    """The pushes scheduled so far and the ids handed out (no ROS)."""

    def __init__(self, limits: PushLimits):
        self.limits = limits
        self.pushes: list[Push] = []
        self.next_id = 1

    def check(self, force: float, duration: float, start: float, height: float, now: float | None, *,
              use_delay: bool = False, delay: float = 0.0) -> Push:
        return validate_push(force, duration, start, height, limits=self.limits, now=now, scheduled=self.pushes,
                             use_delay=use_delay, delay=delay)

    def add(self, push: Push, push_id: int | None = None) -> Push:
        """Schedule a checked push under ``push_id`` (default: the next id); returns it with its id."""
        pid = self.next_id if push_id is None else int(push_id)
        self.next_id = max(self.next_id, pid) + 1
        scheduled = replace(push, id=pid)
        self.pushes.append(scheduled)
        return scheduled


class ScheduledPushes:
    """The push schedule of a plant engine (a mixin of every engine; no ROS): ``self.book`` holds the pushes,
    validated by :func:`validate_push` with physical limits only (any force and duration, a point on the
    torso ``self.desc.torso.length``, no overlap; default height ``self.cfg.push_height``); the service adds
    its own bounds upstream."""

    def _new_book(self) -> PushBook:
        return PushBook(PushLimits(math.inf, math.inf, self.desc.torso.length, self.cfg.push_height))

    @property
    def pushes(self) -> list[Push]:
        return self.book.pushes

    def push_rows(self) -> np.ndarray:
        """The scheduled pushes as rows (start, end [s], force [N], height [m] above the hip) in the book's
        order, shape (n, 4): what the compiled steps and the compiled closed loops take; rebuilt only when
        the schedule changes."""
        ps = tuple(self.book.pushes)
        if ps != getattr(self, "_push_key", None):
            self._push_array = np.array([[p.start, p.end, p.force, p.height] for p in ps],
                                        dtype=float).reshape(len(ps), 4)
            self._push_key = ps
        return self._push_array

    def schedule_push(self, start: float, duration: float, force: float, height: float | None = None,
                      push_id: int | None = None) -> Push:
        """Schedule a push (raises :class:`Rejected` naming the field, nothing changed); ``height`` None/NaN =
        the default."""
        h = math.nan if height is None else height
        return self.book.add(self.book.check(force, duration, start, h, None), push_id)

    def interval_pushes(self, t0: float, t1: float) -> tuple[tuple[float, float], ...]:
        """The pushes acting over the integration interval [t0, t1], as (force [N], height [m]).

        Intervals are split exactly at every push start and end, so a push either covers an interval
        entirely or not at all; the test uses the interval's midpoint, which is robust to the rounding of
        the boundaries. The force is then constant over the interval, at every integration stage."""
        tm = 0.5 * (t0 + t1)
        return tuple((p.force, p.height) for p in self.pushes if p.start <= tm < p.end)
