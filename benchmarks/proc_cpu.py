"""CPU time of a process tree, per process and per thread, read from Linux ``/proc`` while it runs.

``/proc/<pid>/task/<tid>/schedstat``'s first field is the thread's time on a CPU (ns, the scheduler's own
accounting: user + system, no 10 ms tick granularity). :class:`TreeCpu` polls every descendant of a root
pid every ``period`` s in a thread of its own and keeps, per thread, the first and the last value seen
after :meth:`mark` (a thread that exits between two polls loses at most ``period`` s of its time), so
``cpu = last - first`` is the CPU the thread used from the mark until it was last seen. Processes are
named by a caller's function of their command line (e.g. the node's executable).
"""
from __future__ import annotations

import os
import threading
from collections import defaultdict
from typing import Callable


def _read(path: str) -> str | None:
    try:
        with open(path) as fh:
            return fh.read()
    except OSError:
        return None


def children(pid: int) -> list[int]:
    """Direct children of ``pid`` (``/proc/<pid>/task/*/children``)."""
    out: list[int] = []
    try:
        tids = os.listdir(f'/proc/{pid}/task')
    except OSError:      # the process is gone
        return out
    for tid in tids:
        text = _read(f'/proc/{pid}/task/{tid}/children')
        if text:
            out += [int(x) for x in text.split()]
    return out


def descendants(pid: int) -> list[int]:
    todo, seen = [pid], []
    while todo:
        p = todo.pop()
        for c in children(p):
            if c not in seen:
                seen.append(c)
                todo.append(c)
    return seen


def thread_cpu_ns(pid: int) -> dict[int, tuple[str, int]]:
    """{tid: (thread name, CPU ns so far)} of every thread of ``pid`` now."""
    out = {}
    try:
        tids = os.listdir(f'/proc/{pid}/task')
    except OSError:
        return out
    for tid in tids:
        sched = _read(f'/proc/{pid}/task/{tid}/schedstat')
        comm = _read(f'/proc/{pid}/task/{tid}/comm')
        if sched and comm is not None:
            out[int(tid)] = (comm.strip(), int(sched.split()[0]))
    return out


class TreeCpu:
    """Poll a process tree's per-thread CPU (module docstring). ``name_of(cmdline words) -> name or None``
    (None: not counted)."""

    def __init__(self, root: int, name_of: Callable[[list[str]], str | None], period: float = 0.1,
                 mark_when: Callable[[], bool] | None = None):
        self.root, self.name_of, self.period, self.mark_when = root, name_of, period, mark_when
        self._names: dict[int, str | None] = {}
        self._first: dict[tuple[int, int], int] = {}
        self._last: dict[tuple[int, int], tuple[str, int]] = {}
        self._marked = False
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _name(self, pid: int) -> str | None:
        """Read at every poll (a child is the launcher's fork until it execs, and the ROS wheels re-exec the
        interpreter once): the name last seen wins."""
        raw = _read(f'/proc/{pid}/cmdline')
        name = self.name_of(raw.split('\0')) if raw else None
        if name is not None:
            self._names[pid] = name
        return self._names.get(pid)

    def _snapshot(self) -> dict[tuple[int, int], tuple[str, int]]:
        snap = {}
        for pid in descendants(self.root):
            if self._name(pid) is None:
                continue
            for tid, value in thread_cpu_ns(pid).items():
                snap[(pid, tid)] = value
        return snap

    def poll(self) -> None:
        snap = self._snapshot()
        with self._lock:
            for key, value in snap.items():
                if self._marked and key not in self._first:
                    self._first[key] = 0          # a thread born after the mark
                self._last[key] = value

    def mark(self) -> None:
        """Start counting now (the values seen at this instant are the baseline)."""
        snap = self._snapshot()
        with self._lock:
            self._first = {key: ns for key, (_, ns) in snap.items()}
            self._last.update(snap)
            self._marked = True

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            try:
                if not self._marked and self.mark_when is not None and self.mark_when():
                    self.mark()
                else:
                    self.poll()
            except (OSError, ValueError, IndexError):   # a process or thread vanished mid-read: next poll
                continue

    def stop(self) -> dict:
        """Stop polling; {process name: {'cpu_s': total, 'threads': {thread name: cpu_s}}} since the mark."""
        self._stop.set()
        self._thread.join(5)
        out: dict = {}
        with self._lock:
            for (pid, tid), (comm, ns) in self._last.items():
                if (pid, tid) not in self._first:
                    continue
                name = self._names.get(pid)
                cpu = (ns - self._first[(pid, tid)]) * 1e-9
                entry = out.setdefault(name, {'cpu_s': 0.0, 'threads': defaultdict(float)})
                entry['cpu_s'] += cpu
                entry['threads'][comm] += cpu
        for entry in out.values():
            entry['threads'] = {k: round(v, 4) for k, v in sorted(entry['threads'].items(), key=lambda kv: -kv[1])
                                if v >= 0.0005}
            entry['cpu_s'] = round(entry['cpu_s'], 4)
        return out


def self_threads_cpu_ns() -> dict[int, tuple[str, int]]:
    """This process's threads (as :func:`thread_cpu_ns`)."""
    return thread_cpu_ns(os.getpid())
