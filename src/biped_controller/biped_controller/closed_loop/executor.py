"""The studies' one executor and progress bar: the capability map, the robustness table and the
max-push search (``trial.search``) run their simulations through these.

An executor runs picklable module-level functions on batches of work and hands back each result as it
completes:

* :class:`SerialExecutor`: in this process, one call at a time, in submission order (``--workers 1``;
  also the tests' synthetic tasks);
* :class:`PoolExecutor`: a local pool of ``workers`` spawned processes (each loads its own models once,
  through ``initializer``);
* :class:`RayExecutor`: the same functions on Ray (a local instance or an existing cluster).

Every executor has a default ``task`` (:meth:`submit` calls it; the capability map's simulation batch)
and runs any other function through :meth:`submit_fn` / :meth:`map`. The simulator and the controller
are deterministic, so every executor gives the same results (tested on the capability map).

Pure: no ROS import.
"""
from __future__ import annotations

import concurrent.futures as cf
import math
import multiprocessing as mp
import os
import sys
import time
from typing import Any, Callable, Iterable, TextIO


class ExecutorError(ValueError):
    """An executor cannot be made (the message says what is missing) or was given a bad option."""


def _init_worker(initializer: Callable[[], Any] | None) -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if initializer is not None:
        initializer()


class _Deferred:
    """A call handed to :class:`SerialExecutor`, run when waited for."""

    def __init__(self, fn: Callable, args: tuple):
        self.fn, self.args = fn, args


class _Base:
    """What every executor shares: :meth:`submit` (the default task), :meth:`map` (ordered results with at
    most two calls per slot in flight)."""

    name = "base"
    slots = 1
    task: Callable | None = None

    def submit(self, *args):
        """Run the default ``task`` on ``args``; a handle for :meth:`wait`."""
        if self.task is None:
            raise ExecutorError("this executor has no default task: use submit_fn")
        return self.submit_fn(self.task, *args)

    def submit_fn(self, fn: Callable, *args):   # pragma: no cover - overridden
        raise NotImplementedError

    def wait(self, handles) -> list[tuple[Any, Any]]:   # pragma: no cover - overridden
        raise NotImplementedError

    def map(self, fn: Callable, items: Iterable[tuple], on_result: Callable[[Any], None] | None = None) -> list:
        """``[fn(*args) for args in items]`` on the executor, results in the order of ``items``;
        ``on_result`` is called with each result as it completes (progress, logging, storing)."""
        items = list(items)
        out: list = [None] * len(items)
        inflight: dict = {}
        nxt = 0
        cap = 2 * max(1, self.slots)
        while nxt < len(items) or inflight:
            while nxt < len(items) and len(inflight) < cap:
                inflight[self.submit_fn(fn, *items[nxt])] = nxt
                nxt += 1
            for h, r in self.wait(list(inflight)):
                out[inflight.pop(h)] = r
                if on_result is not None:
                    on_result(r)
        return out

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SerialExecutor(_Base):
    """Runs the calls in this process, one at a time, in submission order."""

    name = "serial"
    slots = 1

    def __init__(self, task: Callable | None = None):
        self.task = task

    def submit_fn(self, fn, *args):
        return _Deferred(fn, args)

    def wait(self, handles):
        h = handles[0]
        return [(h, h.fn(*h.args))]


class PoolExecutor(_Base):
    """A local pool of ``workers`` spawned processes; ``initializer`` (picklable, no arguments) runs once
    in each, after OMP_NUM_THREADS=1 (one thread per process)."""

    name = "pool"

    def __init__(self, workers: int, task: Callable | None = None, initializer: Callable[[], Any] | None = None):
        if not (isinstance(workers, int) and workers >= 1):
            raise ExecutorError(f"workers must be an integer >= 1, got {workers!r}")
        os.environ.setdefault("OMP_NUM_THREADS", "1")   # inherited by the workers: one thread each
        self.pool = cf.ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                                           initargs=(initializer,))
        self.task = task
        self.slots = workers

    def submit_fn(self, fn, *args):
        return self.pool.submit(fn, *args)

    def wait(self, handles):
        done, _ = cf.wait(handles, return_when=cf.FIRST_COMPLETED)
        return [(h, h.result()) for h in done]

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


class RayExecutor(_Base):
    """The same calls on Ray: the Ray this process is already connected to (then left running), else a
    local instance (``address`` None: ``ray.init(num_cpus=workers, include_dashboard=False)``) or an
    existing cluster (``address``, e.g. ``ray://host:10001`` or ``auto``), shut down by :meth:`close`."""

    name = "ray"

    def __init__(self, address: str | None, workers: int, task: Callable | None = None):
        try:
            import ray
        except ImportError as exc:
            raise ExecutorError("--ray needs the ray package (requirements.txt; run scripts/setup)") from exc
        self.ray = ray
        self.owned = not ray.is_initialized()
        if self.owned and address is None:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        elif self.owned:
            ray.init(address=address, log_to_driver=False)
        self.slots = max(1, int(ray.cluster_resources().get("CPU", workers)))
        self.task = task
        self._remote: dict = {}

    def submit_fn(self, fn, *args):
        r = self._remote.get(fn)
        if r is None:
            r = self._remote[fn] = self.ray.remote(num_cpus=1)(fn)
        return r.remote(*args)

    def wait(self, handles):
        done, _ = self.ray.wait(list(handles), num_returns=1)
        return [(h, self.ray.get(h)) for h in done]

    def close(self) -> None:
        if self.owned:
            self.ray.shutdown()


def make_executor(workers: int, ray: str | None = None, task: Callable | None = None,
                  initializer: Callable[[], Any] | None = None):
    """``ray`` "local" or an address: :class:`RayExecutor`; else a pool of ``workers`` processes, or this
    process when ``workers`` is 1."""
    if ray is not None:
        return RayExecutor(None if ray == "local" else ray, workers, task)
    return SerialExecutor(task) if workers == 1 else PoolExecutor(workers, task, initializer)


# ------------------------------------------------------------------------------------------ progress
def _hms(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--:--:--"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class ProgressBar:
    """``label [####....] done/total sims (R resumed), rate sims/s, time left`` on a terminal (redrawn in
    place), or one line every ``interval`` seconds otherwise (log files); ``stream`` None: silent. The rate
    counts this run's simulations; the time left is the remaining simulations (an estimate where bisection
    steps are counted before they are known) over that rate.

    What the bar is drawn over: with ``count`` = (done, total, words) given to :meth:`update`, a count whose
    total does not change during the run (the capability map's cells; the max-push search's simulations
    against the most its search can need), written ``done/total words``; without it, the simulations
    against their estimated total (run + resumed + remaining), which moves as bisections are found
    shorter or longer than estimated."""

    def __init__(self, stream: TextIO | None = sys.stderr, interval: float = 30.0, width: int = 28,
                 label: str = "capability map"):
        self.stream = stream
        self.tty = bool(stream is not None and hasattr(stream, "isatty") and stream.isatty())
        self.interval = 0.2 if self.tty else interval
        self.width = width
        self.label = label
        self.t0 = time.perf_counter()
        self.last = -math.inf
        self.line = ""

    def update(self, run: int, resumed: int, remaining: int, force: bool = False,
               count: tuple[int, int, str] | None = None) -> None:
        """``run`` simulations run now, ``resumed`` found stored, ``remaining`` still to run (estimated);
        ``count``: (done, total, words), the stable count the bar is drawn over (class docstring)."""
        now = time.perf_counter()
        el = now - self.t0
        rate = run / el if el > 0 else 0.0
        left = remaining / rate if rate > 0 else math.inf
        if count is None:
            done, total = run + resumed, run + resumed + remaining
            what = f"sims ({resumed} resumed)"
        else:
            done, total, what = count
        k = int(self.width * min(done, total) / max(total, 1))
        self.line = (f"{self.label} [{'#' * k}{'.' * (self.width - k)}] {done}/{total} {what} "
                     f"{rate:.2f} sims/s, elapsed {_hms(el)}, left ~{_hms(left)}")
        if self.stream is None or (not force and now - self.last < self.interval):
            return
        self.last = now
        self.stream.write(("\r" + self.line) if self.tty else (self.line + "\n"))
        self.stream.flush()

    def close(self) -> None:
        if self.stream is not None and self.tty:
            self.stream.write("\n")
            self.stream.flush()


class CountingBar:
    """A progress bar over simulations counted against a fixed ``total``, the most the work can need (its
    ``why``, e.g. "80 coarse + at most 16 bisection", is shown beside it): ``counter()`` after each one
    (``n`` at once). The total does not change during the run, so the bar may end short of it (the steps
    that were not needed); ``counter.add(k)`` raises it when more work becomes known."""

    def __init__(self, total: int, bar: ProgressBar, why: str = ""):
        self.total, self.done, self.bar, self.why = total, 0, bar, why

    def _count(self) -> tuple[int, int, str]:
        return (self.done, self.total, "sims" + (f" (at most {self.total}: {self.why})" if self.why else ""))

    def __call__(self, n: int = 1) -> None:
        self.done += n
        self.bar.update(self.done, 0, max(self.total - self.done, 0), count=self._count())

    def add(self, k: int) -> None:
        self.total += k

    def close(self) -> None:
        self.bar.update(self.done, 0, 0, force=True, count=self._count())
        self.bar.close()
