"""Push-recovery capability map: the survival boundary in force over onset phase x direction x duration,
for each adaptation mode, on a local process pool or a Ray cluster (issue 12).

Run through ``scripts/capability_map [options]`` (``--help``); e.g. the default full map (4 modes x 2
directions x 20 phases x 3 durations) on two processes, resumable, with figures and a summary::

    scripts/capability_map --workers 2 --store build/capability_map/records.jsonl \\
        --out docs/figures/capability_map --json build/capability_map/summary.json

What one simulation is (:func:`simulate`, the pure task function every executor runs): the in-process
closed loop of ``experiment.survives`` (``runner.run``: Simulator + AdaptiveController, no ROS) with one
push of magnitude ``force`` [N] on the torso (``push_height`` of config/simulator.yaml unless
``--height``), horizontal, ``+`` forward (on the back) for direction ``forward`` and ``-`` for
``backward``, acting over [start, start + duration) [s] of simulated time.

Onset phase: a fraction ``phase`` in [0, 1) of the *first* step, ``start = phase * T`` [s], with T the
period of the preferred gait (``GaitFamily.T``, 0.463 s); the walk starts at t = 0 from the family's
initial state, the beginning of that first step (just after an impact). ``--phases N`` samples
``phase = k / N``, k = 0 .. N-1, so phase 0.5 is the paper's "middle of the first step"
(``experiment.DEFAULT_START``) whenever N is even. A long push may end after the first impact; survival
then counts the steps after the push's end.

Survival is ``experiment``'s criterion (``experiment.survival``): no fall until ``SURVIVAL_STEPS``
impacts after the end of the push, and p back within ``P_TOL`` of p_d and tau' within ``TAU_DOT_TOL``
of 1 at the end.

Search per cell (mode, direction, phase, duration), as ``experiment.max_push_modes`` does it for one
cell: the coarse forces ``experiment.coarse_forces(max, coarse)`` (coarse, 2 coarse, ... <= max) are all
simulated, with ``max`` lowered to ``max_impulse / duration`` for long pushes (default 50 N s = 2000 N x
0.025 s: the same impulse range for every duration, 500 N at 0.1 s, 250 N at 0.2 s); ``experiment.analyse_coarse`` gives the last survivable force below the first failing one
(lo, 0 when the first fails), the first failing coarse force (hi) and the survivable coarse forces above
it (the islands: survival is not monotone in the force); then [lo, hi] is bisected at midpoints down to
``resolution`` [N] (the midpoints of ``experiment.bisect_edge``; tested equal). The boundary is the
largest survivable force below the lowest failing edge, known to within ``resolution``; a cell whose
coarse scan never fails is *censored* (boundary >= max). The search is a pure function of the records
of the cell (:func:`plan_cell`): it names the simulations still needed, so simulations of many cells run
in parallel and an interrupted map resumes from the records it stored.

Each boundary force F [N] of a push of duration d [s] is also reported as
  * impulse ``I = F d`` [N s] (exact in the simulator: the force is constant on each integration
    interval, split at the push's start and end);
  * the change of the centre of mass's horizontal velocity the push alone causes,
    ``delta v_com = F d / M`` [m/s], M the robot's total mass from its description (momentum theorem on
    the whole robot with the push as the only external impulse; the ground reaction during the push is
    not counted, so this is a property of the push, comparable across robots);
  * a fraction of body weight ``F / (M g)`` [-] (g from the description), the convention of humanoid
    push-recovery test suites.
The failure cause is that of the first failing force after the bisection (hi): the simulator's fall
cause (``tip_toe``, ``tip_heel``, ``slip``, ``take_off``, ``no_liftoff``, ``numerical``) or, without a
fall, ``p_not_back`` / ``tau_dot_not_back`` (not back on the preferred gait) or ``time_limit``.

Records: one JSON object per simulation, one per line (JSON Lines), appended as each simulation
completes (:class:`RecordStore`); a rerun with the same store skips every simulation already stored for
the same *fingerprint* (sha256 of the controller and simulator settings, the robot description, the gait
family file, the survival criterion and the push height; records of another fingerprint stay in the file
and are ignored). The code is not fingerprinted: after a change of the controller or the simulator that
changes results, start a new store (the summary records the git commit and the modified files). A torn last line (a run killed while writing) is cut
off. A notebook loads the file with ``load_records(path)`` or ``pandas.read_json(path, lines=True)``.

Executors: in-process (``--workers 1``), a local process pool (``--workers N``, default: all cores) or
Ray (``--ray``: a local Ray instance with ``num_cpus = --workers``; ``--ray ADDRESS``: an existing
cluster, whose nodes must have this package installed). All run the same :func:`simulate_batch` on
batches of ``--batch`` simulations (default 1 on the pool, 4 on Ray: a failing simulation takes ~0.1 s,
less than Ray's per-task overhead pays for). The simulator and the controller are deterministic, so every
executor gives the same records (tested).

Pure: no ROS import.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import hashlib
import json
import math
import multiprocessing as mp
import os
import signal
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence, TextIO

from biped_sim.robot.settings import default_config_dir

from biped_controller.studies import experiment
from biped_controller.core.controller import MODES, ControllerConfigError
from biped_controller.studies.experiment import DEFAULT_SETTINGS, OverrideError, RunSettings
from biped_sim.plant.config import SimConfigError

#: direction name -> sign of the force (+ forward: on the back)
DIRECTIONS: dict[str, float] = {"forward": 1.0, "backward": -1.0}
DEFAULT_PHASES = 20
DEFAULT_DURATIONS: tuple[float, ...] = (0.025, 0.1, 0.2)
DEFAULT_RESOLUTION = 5.0      # bisection resolution [N] (experiment's max-push default)
DEFAULT_COARSE = 50.0         # coarse scan step [N] (experiment's max-push default)
DEFAULT_MAX = 2000.0          # largest force scanned [N] (experiment's max-push default)
DEFAULT_MAX_IMPULSE = 50.0    # largest impulse scanned [N s]: 2000 N x 0.025 s, the same range for every duration
DEFAULT_BATCH = {"pool": 1, "ray": 4}
RECORD_VERSION = 1


class MapError(ValueError):
    """The map's specification, its store or its executor is unusable (the message says what)."""


class StoreError(MapError):
    """The record store cannot be read (a malformed line other than a torn last one; the line is named)."""


# ------------------------------------------------------------------------------------------ specification
@dataclass(frozen=True, order=True)
class Cell:
    """One boundary to find: adaptation mode, push direction, onset phase (fraction of the first step),
    push duration [s]."""

    mode: str
    direction: str
    phase: float
    duration: float


@dataclass(frozen=True)
class SimSpec:
    """One simulation: a cell and a force magnitude [N] (>= 0; the direction gives the sign)."""

    cell: Cell
    force: float

    def key(self) -> tuple:
        c = self.cell
        return (c.mode, c.direction, c.phase, c.duration, self.force)


@dataclass(frozen=True)
class Search:
    """The force search of a cell: coarse step and largest force [N], bisection resolution [N]; and the
    largest impulse scanned [N s] (inf: no bound), which lowers the largest force of long pushes to
    ``max_impulse / duration`` (never below one coarse step): :meth:`for_duration`."""

    coarse: float = DEFAULT_COARSE
    fmax: float = DEFAULT_MAX
    resolution: float = DEFAULT_RESOLUTION
    max_impulse: float = DEFAULT_MAX_IMPULSE

    def __post_init__(self):
        for name in ("coarse", "fmax", "resolution"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise MapError(f"{name} must be a finite number > 0 [N], got {v!r}")
        if self.fmax < self.coarse:
            raise MapError(f"max ({self.fmax} N) must be >= the coarse step ({self.coarse} N)")
        if not (isinstance(self.max_impulse, (int, float)) and self.max_impulse > 0):
            raise MapError(f"max_impulse must be > 0 [N s] (inf: no bound), got {self.max_impulse!r}")

    def coarse_forces(self) -> tuple[float, ...]:
        return tuple(experiment.coarse_forces(self.fmax, self.coarse))

    def for_duration(self, duration: float) -> "Search":
        """The search of a push of ``duration`` [s]: largest force min(max, max_impulse / duration), at
        least one coarse step. Its coarse forces are a prefix of the unbounded ones, so records serve
        searches of any bound."""
        fmax = max(self.coarse, min(self.fmax, self.max_impulse / duration))
        return Search(self.coarse, fmax, self.resolution)


@dataclass(frozen=True)
class MapSpec:
    """A whole map: the cells are the product modes x directions x phases x durations."""

    modes: tuple[str, ...] = MODES
    directions: tuple[str, ...] = tuple(DIRECTIONS)
    phases: tuple[float, ...] = tuple(k / DEFAULT_PHASES for k in range(DEFAULT_PHASES))
    durations: tuple[float, ...] = DEFAULT_DURATIONS
    search: Search = field(default_factory=Search)
    height: float | None = None          # push point above the hip [m]; None: push_height of the config
    settings: RunSettings = DEFAULT_SETTINGS

    def __post_init__(self):
        def nonempty_unique(name, seq):
            if not seq:
                raise MapError(f"{name}: at least one is needed")
            if len(set(seq)) != len(seq):
                raise MapError(f"{name}: repeated values in {list(seq)}")
        for name in ("modes", "directions", "phases", "durations"):
            nonempty_unique(name, getattr(self, name))
        for m in self.modes:
            if m not in MODES:
                raise MapError(f"modes: unknown mode {m!r}; choose from {', '.join(MODES)}")
        for d in self.directions:
            if d not in DIRECTIONS:
                raise MapError(f"directions: unknown direction {d!r}; choose from {', '.join(DIRECTIONS)}")
        for ph in self.phases:
            if not (isinstance(ph, float) and 0.0 <= ph < 1.0):
                raise MapError(f"phases: each must be a float in [0, 1) (a fraction of the step), got {ph!r}")
        for d in self.durations:
            if not (isinstance(d, float) and math.isfinite(d) and d > 0):
                raise MapError(f"durations: each must be a float > 0 [s], got {d!r}")
        if self.height is not None and not (math.isfinite(self.height) and self.height >= 0):
            raise MapError(f"height must be >= 0 [m] above the hip, got {self.height!r}")

    def cells(self) -> list[Cell]:
        return [Cell(m, d, ph, du) for m in self.modes for d in self.directions for ph in self.phases
                for du in self.durations]


def phases_of(n: int) -> tuple[float, ...]:
    """``n`` onset phases k / n, k = 0 .. n - 1 (fractions of the step)."""
    if not (isinstance(n, int) and n >= 1):
        raise MapError(f"--phases must be an integer >= 1, got {n!r}")
    return tuple(k / n for k in range(n))


def onset_time(phase: float, T: float) -> float:
    """Push start [s] for an onset ``phase`` of the first step of period ``T`` [s]: ``phase * T``."""
    return phase * T


# ------------------------------------------------------------------------------------------ conversions
def impulse(force: float, duration: float) -> float:
    """Impulse of a constant force [N] over ``duration`` [s]: F d [N s]."""
    return force * duration


def com_velocity_change(force: float, duration: float, mass: float) -> float:
    """Change of the centre of mass's horizontal velocity [m/s] that the push alone causes on a robot of
    total mass ``mass`` [kg]: F d / M (momentum theorem, the push as the only external impulse)."""
    return force * duration / mass


def body_weight_fraction(force: float, mass: float, gravity: float) -> float:
    """Force as a fraction of body weight: F / (M g) [-]."""
    return force / (mass * gravity)


# ------------------------------------------------------------------------------------------ the task
def failure_cause(trial: Mapping) -> str:
    """The cause of a failed trial of ``experiment.survives``: the simulator's fall cause when it fell,
    otherwise which part of ``experiment.survival`` failed (``p_not_back``, ``tau_dot_not_back``,
    ``time_limit``); ``""`` when it survived."""
    if trial["survived"]:
        return ""
    if trial.get("fall_cause"):
        return str(trial["fall_cause"])
    reason = str(trial["reason"])
    if reason.startswith("p ="):
        return "p_not_back"
    if reason.startswith("tau'"):
        return "tau_dot_not_back"
    if reason.startswith("only"):
        return "time_limit"
    raise MapError(f"unrecognised failure reason from experiment.survival: {reason!r}")


def simulate(spec: SimSpec, settings: RunSettings = DEFAULT_SETTINGS, height: float | None = None) -> dict:
    """One simulation (the pure task function): ``experiment.survives`` with the push of ``spec``; the
    record (JSON-ready, deterministic: the same spec gives the same record in any process)."""
    c = spec.cell
    T = experiment.context().family.T
    start = onset_time(c.phase, T)
    signed = DIRECTIONS[c.direction] * spec.force
    trial = experiment.survives(signed, c.mode, c.duration, start, height, settings)
    return {
        "mode": c.mode, "direction": c.direction, "phase": c.phase, "duration": c.duration,
        "force": spec.force, "start": start, "signed_force": signed, "height": height,
        "survived": bool(trial["survived"]), "reason": trial["reason"], "cause": failure_cause(trial),
        "fall_time": trial["fall_time"], "steps_walked": int(trial["steps_walked"]),
    }


def simulate_batch(batch: Sequence[SimSpec], settings: RunSettings = DEFAULT_SETTINGS,
                   height: float | None = None) -> list[dict]:
    """The unit of work of every executor: :func:`simulate` on each spec, in order."""
    return [simulate(s, settings, height) for s in batch]


TaskFn = Callable[[Sequence[SimSpec], RunSettings, "float | None"], list]


def record_key(rec: Mapping) -> tuple:
    return (rec["mode"], rec["direction"], float(rec["phase"]), float(rec["duration"]), float(rec["force"]))


# ------------------------------------------------------------------------------------------ fingerprint
def fingerprint(spec: MapSpec) -> str:
    """sha256 (16 hex digits) of everything a record depends on besides its own key and the code: the
    effective controller and simulator settings, the robot description, the gait family file, the
    survival criterion and the push height. The code is not in it (the tree is edited by many hands, and
    a comment must not void a map): after a change of the controller or the simulator that changes
    results, use a new store; every summary records the git commit and the modified files."""
    ctx = experiment.context()
    h = hashlib.sha256()
    inputs = {
        "version": RECORD_VERSION,
        "settings": experiment.check_settings(spec.settings),
        "description": {k: v for k, v in asdict(ctx.desc).items() if k != "source"},
        "survival": {"steps": experiment.SURVIVAL_STEPS, "p_tol": experiment.P_TOL,
                     "tau_dot_tol": experiment.TAU_DOT_TOL},
        "height": spec.height,
    }
    h.update(json.dumps(inputs, sort_keys=True, default=str).encode())
    h.update((default_config_dir() / "gait_family.json").read_bytes())
    return h.hexdigest()[:16]


# ------------------------------------------------------------------------------------------ store
class RecordStore:
    """JSON Lines file of simulation records, appended one line per record (flushed at once)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.repaired_bytes = 0

    def load(self) -> list[dict]:
        """Every record in the file (none if it does not exist). A last line without its newline that
        does not parse (a write cut short) is removed from the file; any other malformed line raises
        :class:`StoreError`."""
        if not self.path.exists():
            return []
        data = self.path.read_bytes()
        out = []
        pos = 0
        lineno = 0
        while pos < len(data):
            nl = data.find(b"\n", pos)
            end = len(data) if nl < 0 else nl
            line = data[pos:end]
            lineno += 1
            if line.strip():
                try:
                    rec = json.loads(line)
                    if not isinstance(rec, dict):
                        raise ValueError("not a JSON object")
                except ValueError as exc:
                    if nl < 0:   # torn last line: cut it off so that appends start on a fresh line
                        with open(self.path, "r+b") as fh:
                            fh.truncate(pos)
                        self.repaired_bytes = len(data) - pos
                        break
                    raise StoreError(f"{self.path}:{lineno}: not a JSON record ({exc})") from exc
                if nl < 0:       # a complete record without its newline: add it before appending
                    with open(self.path, "ab") as fh:
                        fh.write(b"\n")
                out.append(rec)
            pos = end + 1
        return out

    def append(self, records: Iterable[dict]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a", encoding="utf-8") as fh:
            for r in records:
                fh.write(json.dumps(r, sort_keys=True, allow_nan=False) + "\n")
            fh.flush()


def load_records(path: str | os.PathLike, fingerprint_: str | None = None) -> list[dict]:
    """The records of a store (for notebooks), optionally only those of one fingerprint."""
    recs = RecordStore(path).load()
    return [r for r in recs if fingerprint_ is None or r.get("fingerprint") == fingerprint_]


# ------------------------------------------------------------------------------------------ search
@dataclass(frozen=True)
class Boundary:
    """The outcome of one cell's search (forces [N])."""

    lo: float                 # largest survivable force below the lowest failing edge (0: none)
    hi: float | None          # lowest failing force found (after bisection); None: censored
    islands: tuple[float, ...]


def _search_state(search: Search, survived: Mapping[float, bool]):
    """Where a cell's search stands: ("coarse", missing coarse forces), ("bisect", lo, hi) with the
    midpoint of [lo, hi] not simulated yet, or ("done", Boundary)."""
    coarse = search.coarse_forces()
    missing = [f for f in coarse if f not in survived]
    if missing:
        return ("coarse", missing)
    lo, hi, islands = experiment.analyse_coarse([{"force": f, "survived": survived[f]} for f in coarse])
    if hi is None:
        return ("done", Boundary(lo, None, tuple(islands)))
    while hi - lo > search.resolution:
        mid = 0.5 * (lo + hi)
        if mid not in survived:
            return ("bisect", lo, hi)
        if survived[mid]:
            lo = mid
        else:
            hi = mid
    return ("done", Boundary(lo, hi, tuple(islands)))


def plan_cell(search: Search, survived: Mapping[float, bool]) -> tuple[list[float], Boundary | None]:
    """The search of one cell as a pure function of its trials so far (force [N] -> survived): either the
    forces still to simulate (all missing coarse forces, else the next bisection midpoint) and None, or
    [] and the :class:`Boundary`."""
    st = _search_state(search, survived)
    if st[0] == "coarse":
        return st[1], None
    if st[0] == "bisect":
        return [0.5 * (st[1] + st[2])], None
    return [], st[1]


def bisection_steps(width: float, resolution: float) -> int:
    """Halvings of an interval of ``width`` [N] until it is <= ``resolution`` [N]."""
    n = 0
    while width > resolution:
        width *= 0.5
        n += 1
    return n


def remaining_estimate(search: Search, survived: Mapping[float, bool]) -> int:
    """Simulations a cell still needs, estimated (for the progress bar): the missing coarse forces plus
    the bisection of one coarse step, or the bisection steps left."""
    st = _search_state(search, survived)
    if st[0] == "coarse":
        return len(st[1]) + bisection_steps(search.coarse, search.resolution)
    if st[0] == "bisect":
        return bisection_steps(st[2] - st[1], search.resolution)
    return 0


def island_ranges(islands: Sequence[float], step: float) -> list[list[float]]:
    """Group survivable coarse forces above the edge into [first, last] runs of consecutive steps."""
    out: list[list[float]] = []
    for f in sorted(islands):
        if out and abs(f - out[-1][1] - step) <= 1e-9 * max(1.0, f):
            out[-1][1] = f
        else:
            out.append([f, f])
    return out


# ------------------------------------------------------------------------------------------ executors
def _worker_init() -> None:
    experiment.context()   # each process loads its own description, family and settings once


class _Deferred:
    """A batch handed to :class:`SerialExecutor`, run when waited for."""

    def __init__(self, task: TaskFn, args: tuple):
        self.task, self.args = task, args


class SerialExecutor:
    """Runs the batches in this process, one at a time, in submission order (workers = 1; also the tests'
    synthetic tasks)."""

    name = "serial"
    slots = 1

    def __init__(self, task: TaskFn = simulate_batch):
        self.task = task

    def submit(self, batch, settings, height):
        return _Deferred(self.task, (batch, settings, height))

    def wait(self, handles):
        h = handles[0]
        return [(h, h.task(*h.args))]

    def close(self) -> None:
        pass


class PoolExecutor:
    """A local pool of ``workers`` spawned processes (each loads its own models)."""

    name = "pool"

    def __init__(self, workers: int, task: TaskFn = simulate_batch):
        os.environ.setdefault("OMP_NUM_THREADS", "1")   # inherited by the workers: one thread each
        self.pool = cf.ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_worker_init)
        self.task = task
        self.slots = workers

    def submit(self, batch, settings, height):
        return self.pool.submit(self.task, batch, settings, height)

    def wait(self, handles):
        done, _ = cf.wait(handles, return_when=cf.FIRST_COMPLETED)
        return [(h, h.result()) for h in done]

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


class RayExecutor:
    """The same task on Ray: the Ray this process is already connected to (then left running), else a
    local instance (``address`` None: ``ray.init(num_cpus=workers, include_dashboard=False)``) or an
    existing cluster (``address``, e.g. ``ray://host:10001`` or ``auto``), shut down by :meth:`close`."""

    name = "ray"

    def __init__(self, address: str | None, workers: int, task: TaskFn = simulate_batch):
        try:
            import ray
        except ImportError as exc:
            raise MapError("--ray needs the ray package (requirements.txt; run scripts/setup)") from exc
        self.ray = ray
        self.owned = not ray.is_initialized()
        if self.owned and address is None:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        elif self.owned:
            ray.init(address=address, log_to_driver=False)
        self.slots = max(1, int(ray.cluster_resources().get("CPU", workers)))
        self.remote = ray.remote(num_cpus=1)(task)

    def submit(self, batch, settings, height):
        return self.remote.remote(list(batch), settings, height)

    def wait(self, handles):
        done, _ = self.ray.wait(list(handles), num_returns=1)
        return [(h, self.ray.get(h)) for h in done]

    def close(self) -> None:
        if self.owned:
            self.ray.shutdown()


# ------------------------------------------------------------------------------------------ progress
def _hms(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--:--:--"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class ProgressBar:
    """``[####....] done/total sims (R resumed), rate sims/s, time left`` on a terminal (redrawn in
    place), or one line every ``interval`` seconds otherwise (log files). The total is an estimate
    (bisection steps are counted before they are known); the rate counts this run's simulations."""

    def __init__(self, stream: TextIO | None = sys.stderr, interval: float = 30.0, width: int = 28):
        self.stream = stream
        self.tty = bool(stream is not None and hasattr(stream, "isatty") and stream.isatty())
        self.interval = 0.2 if self.tty else interval
        self.width = width
        self.t0 = time.perf_counter()
        self.last = -math.inf
        self.line = ""

    def update(self, run: int, resumed: int, remaining: int, force: bool = False) -> None:
        now = time.perf_counter()
        el = now - self.t0
        rate = run / el if el > 0 else 0.0
        total = run + resumed + remaining
        k = int(self.width * (run + resumed) / max(total, 1))
        left = remaining / rate if rate > 0 else math.inf
        self.line = (f"capability map [{'#' * k}{'.' * (self.width - k)}] {run + resumed}/{total} sims "
                     f"({resumed} resumed) {rate:.2f} sims/s, elapsed {_hms(el)}, left ~{_hms(left)}")
        if self.stream is None or (not force and now - self.last < self.interval):
            return
        self.last = now
        self.stream.write(("\r" + self.line) if self.tty else (self.line + "\n"))
        self.stream.flush()

    def close(self) -> None:
        if self.stream is not None and self.tty:
            self.stream.write("\n")
            self.stream.flush()


# ------------------------------------------------------------------------------------------ driver
@dataclass
class MapRun:
    """A finished map: the boundary of every cell, the records it rests on, and what this run did."""

    spec: MapSpec
    fingerprint: str
    boundaries: dict[Cell, Boundary]
    records: dict[Cell, dict[float, dict]]      # cell -> force -> record
    simulated: int                              # simulations run by this call
    resumed: int                                # simulations of the map found in the store
    ignored: int                                # store records of another fingerprint or another map
    wall_time: float                            # [s]
    executor: str
    fingerprint_at_end: str = ""                # differs from ``fingerprint`` if a config file changed meanwhile
    missing: list[Cell] = field(default_factory=list)   # cells whose search is incomplete (report only)


def run_map(spec: MapSpec, executor=None, store: RecordStore | None = None, batch: int = 1,
            progress: ProgressBar | None = None, simulate: bool = True) -> MapRun:
    """Find the boundary of every cell of ``spec``: simulations not yet in ``store`` (same fingerprint)
    are run on ``executor`` (default: in this process) in batches of ``batch``, each record appended to
    the store as soon as its batch completes. Cells are served in order, bisection steps as soon as they
    are known, at most two batches per executor slot in flight. ``simulate=False``: nothing is run, the
    boundaries are those the store completes (the other cells are listed in ``MapRun.missing``)."""
    if not (isinstance(batch, int) and batch >= 1):
        raise MapError(f"batch must be an integer >= 1, got {batch!r}")
    experiment.check_settings(spec.settings)     # a bad override fails here, before any simulation
    ex = executor if executor is not None else SerialExecutor()
    fp = fingerprint(spec)
    t0 = time.perf_counter()
    cells = spec.cells()
    index = {c: i for i, c in enumerate(cells)}
    by_key = {(c.mode, c.direction, c.phase, c.duration): c for c in cells}
    recs: dict[Cell, dict[float, dict]] = {c: {} for c in cells}
    ignored = 0
    for r in (store.load() if store is not None else []):
        c = by_key.get(record_key(r)[:4])
        if r.get("fingerprint") != fp or c is None or float(r["force"]) in recs[c]:
            ignored += 1
            continue
        recs[c][float(r["force"])] = r
    resumed = sum(len(v) for v in recs.values())
    survived = {c: {f: bool(r["survived"]) for f, r in recs[c].items()} for c in cells}
    needs: dict[Cell, list[float]] = {}
    bounds: dict[Cell, Boundary] = {}
    dirty = set(cells)
    inflight: dict = {}
    pending: set[tuple] = set()
    simulated = 0
    max_inflight = 2 * max(1, ex.slots)
    try:
        while True:
            for c in dirty:
                forces, b = plan_cell(spec.search.for_duration(c.duration), survived[c])
                if b is not None:
                    bounds[c] = b
                    needs.pop(c, None)
                else:
                    needs[c] = forces
            dirty.clear()
            queue = (SimSpec(c, f) for c in sorted(needs, key=index.__getitem__) for f in needs[c]
                     if SimSpec(c, f).key() not in pending)
            while simulate and len(inflight) < max_inflight:
                chunk = [s for _, s in zip(range(batch), queue)]
                if not chunk:
                    break
                h = ex.submit(tuple(chunk), spec.settings, spec.height)
                inflight[h] = chunk
                pending.update(s.key() for s in chunk)
            if progress is not None:
                remaining = sum(remaining_estimate(spec.search.for_duration(c.duration), survived[c]) for c in needs)
                progress.update(simulated, resumed, remaining)
            if not inflight:
                break
            for h, out in ex.wait(list(inflight)):
                chunk = inflight.pop(h)
                if len(out) != len(chunk) or any(record_key(r) != s.key() for r, s in zip(out, chunk)):
                    raise MapError(f"the task returned records for other simulations than it was given "
                                   f"({[record_key(r) for r in out]} for {[s.key() for s in chunk]})")
                for r in out:
                    r["fingerprint"] = fp
                if store is not None:
                    store.append(out)
                for s, r in zip(chunk, out):
                    pending.discard(s.key())
                    recs[s.cell][s.force] = r
                    survived[s.cell][s.force] = bool(r["survived"])
                    dirty.add(s.cell)
                simulated += len(out)
    finally:
        if executor is None:
            ex.close()
    if progress is not None:
        progress.update(simulated, resumed, 0, force=True)
        progress.close()
    # experiment reads config/controller.yaml at every simulation: a file edited during the run would
    # mix settings under one fingerprint, so the fingerprint is taken again and reported
    fp_end = fingerprint(spec)
    if fp_end != fp and progress is not None and progress.stream is not None:
        progress.stream.write(f"WARNING: the settings changed during the run (fingerprint {fp} -> {fp_end}): "
                              "records made after the change are stored under the old fingerprint\n")
    return MapRun(spec, fp, {c: bounds[c] for c in cells if c in bounds}, recs, simulated, resumed, ignored,
                  time.perf_counter() - t0, ex.name if simulate else "none (report only)", fp_end,
                  [c for c in cells if c not in bounds])


# ------------------------------------------------------------------------------------------ summary
def cell_summary(run: MapRun, cell: Cell) -> dict:
    """One boundary, JSON-ready, with its conversions, failure cause and islands."""
    ctx = experiment.context()
    M, g = ctx.desc.total_mass, ctx.desc.gravity
    b = run.boundaries[cell]
    d = cell.duration
    first = run.records[cell].get(b.hi) if b.hi is not None else None
    return {
        "mode": cell.mode, "direction": cell.direction, "phase": cell.phase,
        "start": onset_time(cell.phase, ctx.family.T), "duration": d,
        "force": b.lo, "first_failure": b.hi, "censored": b.hi is None,
        "scan_max": run.spec.search.for_duration(d).fmax,
        "impulse": impulse(b.lo, d), "delta_v_com": com_velocity_change(b.lo, d, M),
        "body_weight_fraction": body_weight_fraction(b.lo, M, g),
        "cause": first["cause"] if first else None, "reason": first["reason"] if first else None,
        "fall_time": first["fall_time"] if first else None,
        "islands": list(b.islands), "island_ranges": island_ranges(b.islands, run.spec.search.coarse),
        "island_impulses": [impulse(f, d) for f in b.islands],
        "simulations": len(run.records[cell]),
    }


def _fmt_phases(phases: Sequence[float]) -> str:
    return ", ".join(f"{p:g}" for p in phases) if phases else "none"


def findings(boundaries: Sequence[dict], resolution: float) -> dict:
    """What the map shows, computed from the boundaries: per (mode, direction, duration) the weakest and
    strongest phases; per (direction, duration) where p beats tau and the reverse (a difference larger
    than the bisection resolution); per (mode, duration) backward vs forward; islands and causes per
    mode. Also the cross-check cell (phase 0.5, forward, 0.025 s) against the paper's numbers."""
    def key(b):
        return (b["mode"], b["direction"], b["duration"])
    groups: dict[tuple, list[dict]] = {}
    for b in boundaries:
        groups.setdefault(key(b), []).append(b)
    out: dict = {"weakest": [], "p_vs_tau": [], "backward_vs_forward": [], "islands": {}, "causes": {},
                 "paper_cell": []}
    for (m, dr, du), bs in sorted(groups.items()):
        bs = sorted(bs, key=lambda b: b["phase"])
        fs = [b["force"] for b in bs]
        lo, hi = min(fs), max(fs)
        out["weakest"].append({
            "mode": m, "direction": dr, "duration": du, "min_force": lo, "mean_force": sum(fs) / len(fs),
            "max_force": hi, "weakest_phases": [b["phase"] for b in bs if b["force"] == lo],
            "strongest_phases": [b["phase"] for b in bs if b["force"] == hi],
            "censored_phases": [b["phase"] for b in bs if b["censored"]],
            "min_impulse": impulse(lo, du), "min_delta_v_com": bs[fs.index(lo)]["delta_v_com"]})
    dirs = sorted({b["direction"] for b in boundaries})
    durs = sorted({b["duration"] for b in boundaries})
    modes = [m for m in MODES if any(b["mode"] == m for b in boundaries)]
    if "p" in modes and "tau" in modes:
        for dr in dirs:
            for du in durs:
                p = {b["phase"]: b["force"] for b in groups.get(("p", dr, du), [])}
                t = {b["phase"]: b["force"] for b in groups.get(("tau", dr, du), [])}
                common = sorted(set(p) & set(t))
                out["p_vs_tau"].append({
                    "direction": dr, "duration": du,
                    "p_better": [ph for ph in common if p[ph] - t[ph] > resolution],
                    "tau_better": [ph for ph in common if t[ph] - p[ph] > resolution],
                    "tied": [ph for ph in common if abs(p[ph] - t[ph]) <= resolution],
                    "mean_p": sum(p[x] for x in common) / len(common) if common else None,
                    "mean_tau": sum(t[x] for x in common) / len(common) if common else None})
    if set(dirs) == {"forward", "backward"}:
        for m in modes:
            for du in durs:
                f = {b["phase"]: b["force"] for b in groups.get((m, "forward", du), [])}
                bw = {b["phase"]: b["force"] for b in groups.get((m, "backward", du), [])}
                common = sorted(set(f) & set(bw))
                if not common:
                    continue
                mf = sum(f[x] for x in common) / len(common)
                mb = sum(bw[x] for x in common) / len(common)
                out["backward_vs_forward"].append({
                    "mode": m, "duration": du, "mean_forward": mf, "mean_backward": mb,
                    "ratio_backward_forward": mb / mf if mf > 0 else None,
                    "backward_weaker_phases": [x for x in common if f[x] - bw[x] > resolution],
                    "backward_stronger_phases": [x for x in common if bw[x] - f[x] > resolution]})
    for m in modes:
        mine = [b for b in boundaries if b["mode"] == m]
        out["islands"][m] = [{"direction": b["direction"], "phase": b["phase"], "duration": b["duration"],
                              "edge": b["first_failure"], "islands": b["island_ranges"]}
                             for b in mine if b["islands"]]
        causes: dict[str, int] = {}
        for b in mine:
            k = b["cause"] or "censored"
            causes[k] = causes.get(k, 0) + 1
        out["causes"][m] = causes
    for b in boundaries:
        if b["phase"] == 0.5 and b["direction"] == "forward" and b["duration"] == experiment.DEFAULT_DURATION:
            out["paper_cell"].append({"mode": b["mode"], "force": b["force"],
                                      "paper": experiment.PAPER_MAX_PUSH.get(b["mode"])})
    return out


def findings_text(f: dict) -> list[str]:
    lines = ["weakest / strongest onset phases (boundary force [N]):"]
    for w in f["weakest"]:
        cens = f", censored (>= max) at {_fmt_phases(w['censored_phases'])}" if w["censored_phases"] else ""
        lines.append(f"  {w['mode']:<4} {w['direction']:<8} {w['duration']:g} s: min {w['min_force']:g} N at phase "
                     f"{_fmt_phases(w['weakest_phases'])} ({w['min_impulse']:.3g} N s, dv_com {w['min_delta_v_com']:.3g} m/s), "
                     f"mean {w['mean_force']:.1f}, max {w['max_force']:g} at {_fmt_phases(w['strongest_phases'])}{cens}")
    if f["p_vs_tau"]:
        lines.append("p vs tau (difference > resolution):")
        for x in f["p_vs_tau"]:
            lines.append(f"  {x['direction']:<8} {x['duration']:g} s: p beats tau at {_fmt_phases(x['p_better'])}; "
                         f"tau beats p at {_fmt_phases(x['tau_better'])}; tied at {_fmt_phases(x['tied'])} "
                         + ("" if x["mean_p"] is None else f"(means p {x['mean_p']:.1f} N, tau {x['mean_tau']:.1f} N)"))
    if f["backward_vs_forward"]:
        lines.append("backward vs forward (mean boundary over the phases):")
        for x in f["backward_vs_forward"]:
            r = "-" if x["ratio_backward_forward"] is None else f"{x['ratio_backward_forward']:.2f}"
            lines.append(f"  {x['mode']:<4} {x['duration']:g} s: forward {x['mean_forward']:.1f} N, backward "
                         f"{x['mean_backward']:.1f} N (ratio {r}); backward weaker at "
                         f"{_fmt_phases(x['backward_weaker_phases'])}, stronger at {_fmt_phases(x['backward_stronger_phases'])}")
    lines.append("islands (survivable coarse forces above the lowest failing edge):")
    for m, isl in f["islands"].items():
        lines.append(f"  {m:<4} {len(isl)} cells" + ("" if not isl else ": " + "; ".join(
            f"{x['direction']} {x['duration']:g} s phase {x['phase']:g}: edge {x['edge']:g} N, islands "
            + ", ".join(f"{a:g}-{b:g}" if a != b else f"{a:g}" for a, b in x["islands"]) for x in isl[:6])
            + (" ..." if len(isl) > 6 else "")))
    lines.append("causes of the first failure: " + "; ".join(
        f"{m}: " + ", ".join(f"{k} {v}" for k, v in sorted(c.items())) for m, c in f["causes"].items()))
    for x in f["paper_cell"]:
        paper = "-" if x["paper"] is None else f"{x['paper']:g} N"
        lines.append(f"cross-check (phase 0.5, forward, 0.025 s = experiment's max-push cell): {x['mode']} "
                     f"{x['force']:g} N (paper {paper})")
    return lines


def summary(run: MapRun, figures: Sequence[Path] = ()) -> dict:
    """The summary JSON: the map, the robot's mass and weight, what the run did, every boundary, the
    findings and the figures."""
    ctx = experiment.context()
    M, g = ctx.desc.total_mass, ctx.desc.gravity
    s = run.spec
    bs = [cell_summary(run, c) for c in s.cells() if c in run.boundaries]
    total = sum(len(v) for v in run.records.values())
    return {
        "map": {"modes": list(s.modes), "directions": list(s.directions), "phases": list(s.phases),
                "durations": list(s.durations), "coarse": s.search.coarse, "max": s.search.fmax,
                "max_impulse": s.search.max_impulse if math.isfinite(s.search.max_impulse) else None,
                "scan_max_per_duration": {f"{d:g}": s.search.for_duration(d).fmax for d in s.durations},
                "resolution": s.search.resolution, "height": s.height,
                "onset": f"start = phase * T of the first step, T = {ctx.family.T:g} s (walk starts at t = 0)",
                "direction_sign": "forward = + force (on the back), backward = - force",
                "survival": f"no fall for {experiment.SURVIVAL_STEPS} steps after the push end, "
                            f"|p - p_d| <= {experiment.P_TOL} m and |tau' - 1| <= {experiment.TAU_DOT_TOL} at the end"},
        "fingerprint": run.fingerprint,
        "settings": experiment.check_settings(s.settings),
        "robot": {"mass": M, "gravity": g, "weight": M * g},
        "units": {"force": "N", "impulse": "N s", "delta_v_com": "m/s", "body_weight_fraction": "-",
                  "phase": "fraction of the step", "start": "s", "duration": "s"},
        "run": {"executor": run.executor, "wall_time": run.wall_time, "simulations_run": run.simulated,
                "simulations_resumed": run.resumed, "simulations_in_map": total,
                "store_records_ignored": run.ignored,
                "settings_changed_during_run": run.fingerprint_at_end != run.fingerprint,
                "rate": run.simulated / run.wall_time if run.wall_time > 0 else None},
        "incomplete_cells": [asdict(c) for c in run.missing],
        "boundaries": bs,
        "findings": findings(bs, s.search.resolution),
        "figures": [str(p) for p in figures],
    }


# ------------------------------------------------------------------------------------------ figures
_DIR_STYLE = {"forward": "-", "backward": "--"}
_MODE_COLOR = {"none": "0.4", "tau": "tab:blue", "p": "tab:orange", "both": "tab:green"}


def figures(run: MapRun, outdir: str | os.PathLike) -> list[Path]:
    """PNG figures: per mode the boundary vs onset phase (one panel per duration, both directions, right
    axis in N s), per mode a heat map of survival over (phase, force) on the coarse grid with the
    bisected boundary, and the four modes compared (one panel per direction and duration)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    s = run.spec
    paths: list[Path] = []

    def save(fig, name):
        p = out / name
        fig.tight_layout()
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)

    nan = Boundary(math.nan, math.nan, ())

    def series(m, dr, du):
        ph = np.array(s.phases)
        bs = [run.boundaries.get(Cell(m, dr, x, du), nan) for x in s.phases]   # NaN: search incomplete
        return ph, np.array([b.lo for b in bs]), bs

    nd = len(s.durations)
    for m in s.modes:
        fig, axes = plt.subplots(1, nd, figsize=(max(4.2 * nd, 6.5), 3.6), squeeze=False)
        for ax, du in zip(axes[0], s.durations):
            for dr in s.directions:
                ph, f, bs = series(m, dr, du)
                ax.plot(ph, f, _DIR_STYLE[dr], marker="o", ms=3, label=dr)
                isl = [(x, y) for x, b in zip(ph, bs) for y in b.islands]
                if isl:
                    ax.plot(*zip(*isl), "x", color=ax.lines[-1].get_color(), ms=5, label=f"{dr} islands")
                cen = [(x, y) for x, y, b in zip(ph, f, bs) if b.hi is None]
                if cen:
                    ax.plot(*zip(*cen), "^", color=ax.lines[-1].get_color(), ms=6, label=f"{dr} censored")
            ax.set_title(f"{du:g} s push", fontsize=9)
            ax.set_xlabel("onset phase [fraction of the step]")
            ax.set_ylabel("largest survivable force [N]")
            sec = ax.secondary_yaxis("right", functions=(lambda F, d=du: F * d, lambda I, d=du: I / d))
            sec.set_ylabel("impulse [N s]")
            ax.set_xlim(-0.02, 1.0)
            ax.set_ylim(bottom=0)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.suptitle(f"mode {m}: survival boundary vs onset phase", fontsize=10)
        save(fig, f"boundary_{m}.png")

    nr = len(s.directions)
    dph = (s.phases[1] - s.phases[0]) if len(s.phases) > 1 else 1.0
    for m in s.modes:
        fig, axes = plt.subplots(nr, nd, figsize=(max(4.2 * nd, 6.5), 3.4 * nr), squeeze=False)
        for i, dr in enumerate(s.directions):
            for j, du in enumerate(s.durations):
                ax = axes[i][j]
                coarse = np.array(s.search.for_duration(du).coarse_forces())
                grid = np.full((len(coarse), len(s.phases)), np.nan)
                for k, x in enumerate(s.phases):
                    rc = run.records[Cell(m, dr, x, du)]
                    for r_i, F in enumerate(coarse):
                        if float(F) in rc:
                            grid[r_i, k] = 1.0 if rc[float(F)]["survived"] else 0.0
                ax.imshow(grid, origin="lower", aspect="auto", cmap="RdYlGn", vmin=0, vmax=1,
                          extent=(s.phases[0] - dph / 2, s.phases[-1] + dph / 2,
                                  coarse[0] - s.search.coarse / 2, coarse[-1] + s.search.coarse / 2),
                          interpolation="nearest")
                ph, f, _ = series(m, dr, du)
                ax.plot(ph, f, "k.-", lw=1, ms=3, label="boundary (bisected)")
                isl_top = max((y for x in s.phases for y in run.boundaries.get(Cell(m, dr, x, du), nan).islands),
                              default=0.0)
                top = max(float(np.nanmax(f, initial=0.0)) * 2.0, isl_top + 2 * s.search.coarse, 4 * s.search.coarse)
                ax.set_ylim(0, min(coarse[-1] + s.search.coarse / 2, top))
                ax.set_title(f"{dr}, {du:g} s", fontsize=9)
                ax.set_xlabel("onset phase")
                ax.set_ylabel("force [N]")
                ax.legend(fontsize=7, loc="upper right")
        fig.suptitle(f"mode {m}: survival (green) / failure (red) on the coarse grid", fontsize=10)
        save(fig, f"heatmap_{m}.png")

    fig, axes = plt.subplots(nr, nd, figsize=(max(4.2 * nd, 6.5), 3.4 * nr), squeeze=False)
    for i, dr in enumerate(s.directions):
        for j, du in enumerate(s.durations):
            ax = axes[i][j]
            for m in s.modes:
                ph, f, _ = series(m, dr, du)
                ax.plot(ph, f, marker="o", ms=3, color=_MODE_COLOR[m], label=m)
            ax.set_title(f"{dr}, {du:g} s", fontsize=9)
            ax.set_xlabel("onset phase")
            ax.set_ylabel("largest survivable force [N]")
            ax.set_ylim(bottom=0)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle("adaptation modes compared: survival boundary vs onset phase", fontsize=10)
    save(fig, "modes.png")
    return paths


# ------------------------------------------------------------------------------------------ CLI
def _split(values: Sequence[str]) -> list[str]:
    return [x for v in values for x in v.split(",") if x]


def _dump(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, allow_nan=False) + "\n", encoding="utf-8")


def git_state() -> dict:
    """The commit and the modified/untracked files of the repository (provenance of a summary); empty
    when git is not available."""
    import subprocess
    from biped_sim.robot.settings import repo_root
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo_root(), capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "src", "config"], cwd=repo_root(),
                               capture_output=True, text=True, check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        return {}
    return {"commit": head, "modified": [x.strip() for x in dirty]}


def _terminate(signum, frame):
    raise SystemExit(128 + signum)


def make_executor(workers: int, ray: str | None):
    if ray is not None:
        return RayExecutor(None if ray == "local" else ray, workers)
    return SerialExecutor() if workers == 1 else PoolExecutor(workers)


def main(argv: list[str] | None = None) -> int:
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    ap = argparse.ArgumentParser(prog="scripts/capability_map", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--modes", nargs="+", default=list(MODES), help=f"any of {' '.join(MODES)} (default all)")
    ap.add_argument("--directions", nargs="+", default=list(DIRECTIONS), help="forward backward (default both)")
    ap.add_argument("--phases", type=int, default=DEFAULT_PHASES, help="onsets k/N of the first step, k < N")
    ap.add_argument("--durations", nargs="+", type=float, default=list(DEFAULT_DURATIONS), help="push durations [s]")
    ap.add_argument("--resolution", type=float, default=DEFAULT_RESOLUTION, help="bisection resolution [N]")
    ap.add_argument("--coarse", type=float, default=DEFAULT_COARSE, help="coarse scan step [N]")
    ap.add_argument("--max", type=float, default=DEFAULT_MAX, help="largest force scanned [N]")
    ap.add_argument("--max-impulse", type=float, default=DEFAULT_MAX_IMPULSE,
                    help="largest impulse scanned [N s] (inf: none): long pushes scan up to this / duration")
    ap.add_argument("--height", type=float, default=None,
                    help="push point above the hip [m] (default: push_height of config/simulator.yaml)")
    ap.add_argument("--workers", type=int, default=cores, help=f"processes (default: all cores, {cores}); 1 = in process")
    ap.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                    help="run on Ray: a local instance (num_cpus = --workers) or the cluster at ADDRESS")
    ap.add_argument("--batch", type=int, default=None, help="simulations per task (default 1, 4 on Ray)")
    ap.add_argument("--store", type=Path, default=Path("build/capability_map/records.jsonl"),
                    help="per-simulation records (JSON Lines), resumed by a rerun")
    ap.add_argument("--out", type=Path, default=None, help="directory for the PNG figures")
    ap.add_argument("--json", type=Path, default=None, help="summary JSON")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--report-only", action="store_true",
                    help="run nothing: summary and figures from the store (incomplete cells are left out)")
    experiment._add_settings_args(ap)
    args = ap.parse_args(argv)
    try:
        settings = experiment.parse_overrides(args.overrides, args.observer)
        experiment.check_settings(settings)
        if args.workers < 1:
            raise MapError(f"--workers must be >= 1, got {args.workers}")
        spec = MapSpec(tuple(_split(args.modes)), tuple(_split(args.directions)), phases_of(args.phases),
                       tuple(float(d) for d in args.durations), Search(args.coarse, args.max, args.resolution, args.max_impulse),
                       args.height, settings)
    except (MapError, OverrideError, ControllerConfigError, SimConfigError) as exc:
        ap.error(str(exc))
    batch = args.batch if args.batch is not None else DEFAULT_BATCH["ray" if args.ray else "pool"]
    print(f"scripts/capability_map {' '.join(sys.argv[1:] if argv is None else argv)}")
    print(f"{len(spec.cells())} cells: modes {','.join(spec.modes)} x directions {','.join(spec.directions)} x "
          f"{len(spec.phases)} phases x durations {','.join(f'{d:g}' for d in spec.durations)} s; coarse "
          f"{spec.search.coarse:g} N to " + ", ".join(f"{spec.search.for_duration(d).fmax:g} N ({d:g} s)" for d in spec.durations)
          + f", bisection to {spec.search.resolution:g} N; store {args.store}")
    ex = SerialExecutor() if args.report_only else make_executor(args.workers, args.ray)
    # a kill (SIGTERM) unwinds like Ctrl-C: the executor is closed (no orphaned workers) and every record
    # stored so far stays for the next run
    signal.signal(signal.SIGTERM, _terminate)
    try:
        run = run_map(spec, ex, RecordStore(args.store), batch, None if args.no_progress else ProgressBar(),
                      simulate=not args.report_only)
    finally:
        ex.close()
    figs = figures(run, args.out) if args.out is not None else []
    summ = summary(run, figs)
    summ["run"]["argv"] = list(sys.argv[1:] if argv is None else argv)
    summ["run"]["workers"] = args.workers
    summ["run"]["batch"] = batch
    summ["run"]["store"] = str(args.store)
    summ["run"]["git"] = git_state()
    r = summ["run"]
    print(f"{r['simulations_in_map']} simulations in the map: {r['simulations_run']} run now, "
          f"{r['simulations_resumed']} resumed from the store ({r['store_records_ignored']} store records of "
          f"other settings/code/cells ignored); wall time {r['wall_time']:.1f} s, "
          + (f"{r['rate']:.3f} sims/s ({r['executor']}, {args.workers} workers, batch {batch})" if r["rate"] else "nothing run"))
    print(f"{'mode':<5} {'dir':<8} {'dur':>5} " + " ".join(f"{p:>8g}" for p in spec.phases))
    for m in spec.modes:
        for dr in spec.directions:
            for du in spec.durations:
                row = []
                for ph in spec.phases:
                    b = run.boundaries.get(Cell(m, dr, ph, du))
                    if b is None:
                        row.append(f"{'?':>8}")
                        continue
                    row.append(f"{b.lo:>7.2f}{'+' if b.hi is None else ('*' if b.islands else ' ')}")
                print(f"{m:<5} {dr:<8} {du:>5g} " + " ".join(row))
    print("(boundary force [N] per onset phase; * = islands above the edge, + = censored: survived up to the scan's max"
          + (f"; ? = search incomplete: {len(run.missing)} cells)" if run.missing else ")"))
    for line in findings_text(summ["findings"]):
        print(line)
    for p in figs:
        print(f"figure: {p}")
    if args.json is not None:
        _dump(args.json, summ)
        print(f"summary: {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
