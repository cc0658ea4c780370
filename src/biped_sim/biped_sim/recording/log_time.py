"""The recorder's log time: each message's is the sim time of the latest ``/clock`` *published* before it.

Pure logic (no ROS): :class:`LogTimeQueue` is fed the messages as they are taken from DDS, each with its DDS
source timestamp (the publisher's wall clock at publication, ns), and hands them back, in the order they were
fed, with their log time [ns of sim time].

- The log time of a ``/clock`` is its own sim time. Any other message's is the sim time of the ``/clock`` with
  the largest source timestamp at or before its own, among the last ``history`` ``/clock`` kept (looked up, not
  "the newest taken": topics among themselves are not ordered by DDS, and a message repaired after a loss can be
  taken after many later ``/clock``).
- A ``/clock`` can be repaired late too. A reliable reader delivers each writer's messages in order, so once a
  ``/clock`` published at or after a message has been taken, every ``/clock`` published before it has been: a
  message is *held* until then, or until it has waited ``wait`` s (the graph's last messages, or a paused
  graph's), and released in the order fed (a ``/clock`` waits only behind an earlier held message).
- Without a ``/clock`` at or before it: the newest ``/clock`` taken, else ``None`` (the caller's own clock).
- A message without a source timestamp (0) is not held and gets the newest ``/clock`` taken.
"""

from __future__ import annotations

import bisect
import collections
from dataclasses import dataclass
from typing import Any, Deque, List, Optional, Tuple

CLOCK_HISTORY = 5000   # /clock messages kept for the lookup at least (5 s at 1 kHz, the topics' DDS depth)
CLOCK_WAIT = 5.0       # s (wall) a message waits at most for a /clock published after it: above a reliable
                       # writer's repair time; what a SIGKILL can lose beyond the chunk's while the graph is paused


class LogTimeError(ValueError):
    """A setting of :class:`LogTimeQueue` out of range."""


@dataclass
class _Held:
    taken_at: float            # s, the caller's monotonic clock when taken
    item: Any                  # the caller's message (opaque)
    source_ns: int             # DDS source timestamp [ns]; 0 = none
    clock_ns: Optional[int]    # sim time [ns] if the message is a /clock, else None


class LogTimeQueue:
    """Messages in, (message, log time) out in the same order (module docstring).

    :param history: ``/clock`` messages kept for the lookup (at least; up to twice as many).
    :param wait: s a message is held at most for a ``/clock`` published after it.
    """

    def __init__(self, history: int = CLOCK_HISTORY, wait: float = CLOCK_WAIT) -> None:
        if int(history) < 1:
            raise LogTimeError(f"history must be at least 1 /clock; got {history!r}")
        if not wait >= 0.0:
            raise LogTimeError(f"wait must be >= 0 s; got {wait!r}")
        self.history = int(history)
        self.wait = float(wait)
        self._clock_src: List[int] = []    # source timestamps [ns] of the /clock kept, sorted
        self._clock_sim: List[int] = []    # their sim times [ns]
        self._held: Deque[_Held] = collections.deque()
        self.newest_sim_ns: Optional[int] = None   # sim time of the newest /clock taken
        self._newest_clock_src = 0

    def __len__(self) -> int:
        """Messages held."""
        return len(self._held)

    def push(self, taken_at: float, item: Any, source_ns: int, clock_ns: Optional[int] = None) -> None:
        """Feed one message taken at ``taken_at`` [s], published at ``source_ns``; ``clock_ns``: its sim time
        if it is a ``/clock`` (then it serves the lookup at once)."""
        source_ns = int(source_ns)
        if clock_ns is not None:
            self.newest_sim_ns = int(clock_ns)
            if source_ns:
                self._remember(source_ns, int(clock_ns))
                self._newest_clock_src = max(self._newest_clock_src, source_ns)
        self._held.append(_Held(float(taken_at), item, source_ns, None if clock_ns is None else int(clock_ns)))

    def release(self, now: float, flush: bool = False) -> List[Tuple[Any, Optional[int]]]:
        """The messages whose log time is known (or whose wait is over at ``now`` [s]), from the oldest fed on,
        as (message, log time [ns] or None); with ``flush`` all of them."""
        out = []
        held = self._held
        while held:
            h = held[0]
            ready = (flush or h.clock_ns is not None or not h.source_ns
                     or h.source_ns <= self._newest_clock_src or now - h.taken_at >= self.wait)
            if not ready:
                break
            held.popleft()
            out.append((h.item, h.clock_ns if h.clock_ns is not None else self.log_time(h.source_ns)))
        return out

    def log_time(self, source_ns: int) -> Optional[int]:
        """The sim time [ns] of the latest ``/clock`` published at or before ``source_ns`` among those kept;
        without one, the newest ``/clock`` taken, else None."""
        i = bisect.bisect_right(self._clock_src, source_ns) if source_ns else 0
        if i:
            return self._clock_sim[i - 1]
        return self.newest_sim_ns

    def _remember(self, source_ns: int, sim_ns: int) -> None:
        src = self._clock_src
        if not src or source_ns >= src[-1]:
            src.append(source_ns)
            self._clock_sim.append(sim_ns)
        else:   # a repaired /clock taken late
            i = bisect.bisect_right(src, source_ns)
            src.insert(i, source_ns)
            self._clock_sim.insert(i, sim_ns)
        if len(src) > 2 * self.history:
            del src[:self.history]
            del self._clock_sim[:self.history]
