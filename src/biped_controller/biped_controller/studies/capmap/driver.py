"""The map's driver: every cell's search served on an executor, records stored as they complete."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Sequence

from biped_controller.studies.trial.record import faulted
from biped_controller.studies.trial.settings import check_settings
from biped_controller.studies.capmap.search import (Boundary, coarse_edge, edge_index, plan_cell, plan_no_fall,
                                                    remaining_estimate)
from biped_controller.studies.capmap.spec import Cell, MapError, MapSpec, SimSpec
from biped_controller.studies.capmap.store import RecordStore, fingerprint
from biped_controller.studies.capmap.task import record_key, simulate_batch
from biped_controller.closed_loop.executor import ProgressBar, SerialExecutor


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


def record_fell(rec: dict) -> bool:
    """A record's trial fell (the plant's fall; a trial that did not settle did not fall)."""
    return rec.get("fall_time") is not None


def record_ends_no_fall(rec: dict) -> bool:
    """A record's trial bounds the no-fall edge: it fell, or its controller faulted (``trial.record``: no
    torque from the fault on, so whether it would have fallen is unknown)."""
    return record_fell(rec) or faulted(rec)


def _cells_count(bounds: dict, cells: list, simulated: list[int], resumed: list[int]) -> tuple[int, int, str]:
    """The map's progress count: cells whose search (survival boundary and no-fall edge) is finished, of all
    the cells (a total that does not change during the run), with the simulations behind them."""
    return (len(bounds), len(cells), f"cells searched ({sum(simulated) + sum(resumed)} sims, {sum(resumed)} resumed)")


def run_map(spec: MapSpec, executor=None, store: RecordStore | None = None, batch: int = 1,
            progress: ProgressBar | None = None, simulate: bool = True) -> MapRun:
    """Find the boundary of every cell of ``spec``: simulations not yet in ``store`` (same fingerprint)
    are run on ``executor`` (default: in this process) in batches of ``batch``, each record appended to
    the store as soon as its batch completes. Cells are served in order, bisection steps as soon as they
    are known, at most two batches per executor slot in flight. With ``spec.neighbours`` a cell's search
    starts once its lower-phase neighbour's coarse edge is known (its islands and bisection may go on),
    bracketed from that edge (``search.plan_cell``: ``spec.bracket_check_below`` coarse steps checked under
    the bracket, ``spec.island_window`` above it), then its no-fall edge (``search.plan_no_fall``); the first phase of each (mode, direction, duration) row is searched in full.
    ``simulate=False``: nothing is run, the boundaries are those the store completes (the other cells are
    listed in ``MapRun.missing``). One map of :func:`run_maps`."""
    return run_maps([spec], executor, store, batch, progress, simulate)[0]


def run_maps(specs: Sequence[MapSpec], executor=None, store: RecordStore | None = None, batch: int = 1,
             progress: ProgressBar | None = None, simulate: bool = True) -> list[MapRun]:
    """:func:`run_map` of several maps at once on one executor and one store (each spec with its own
    settings and fingerprint; the robustness table's many one-cell maps keep every worker busy)."""
    if not (isinstance(batch, int) and batch >= 1):
        raise MapError(f"batch must be an integer >= 1, got {batch!r}")
    for spec in specs:
        check_settings(spec.settings)     # a bad override fails here, before any simulation
    ex = executor if executor is not None else SerialExecutor(simulate_batch)
    fps = [fingerprint(spec) for spec in specs]
    t0 = time.perf_counter()
    cells = [(i, c) for i, spec in enumerate(specs) for c in spec.cells()]
    index = {c: k for k, c in enumerate(cells)}
    by_key = {}
    for i, c in cells:
        by_key.setdefault((c.mode, c.direction, c.phase, c.duration), []).append((i, c))
    # the lower-phase neighbour of each cell (bracketed searches only)
    left: dict[tuple, tuple] = {}
    for i, spec in enumerate(specs):
        if spec.neighbours:
            ph = sorted(spec.phases)
            for c in spec.cells():
                k = ph.index(c.phase)
                if k > 0:
                    left[(i, c)] = (i, Cell(c.mode, c.direction, ph[k - 1], c.duration))
    right = {v: k for k, v in left.items()}
    recs: dict[tuple, dict[float, dict]] = {ic: {} for ic in cells}
    ignored = [0] * len(specs)
    loaded = store.load() if store is not None else []
    for r in loaded:
        used = False
        for ic in by_key.get(record_key(r)[:4], ()):
            if r.get("fingerprint") == fps[ic[0]] and float(r["force"]) not in recs[ic]:
                recs[ic][float(r["force"])] = r
                used = True
        if not used:
            for i in range(len(specs)):
                ignored[i] += 1
    resumed = [sum(len(recs[(j, c)]) for j, c in cells if j == i) for i in range(len(specs))]
    survived = {ic: {f: bool(r["survived"]) for f, r in recs[ic].items()} for ic in cells}
    fell = {ic: {f: record_ends_no_fall(r) for f, r in recs[ic].items()} for ic in cells}
    fault = {ic: {f: faulted(r) for f, r in recs[ic].items()} for ic in cells}
    needs: dict[tuple, list[float]] = {}
    bounds: dict[tuple, Boundary] = {}
    dirty = set(cells)
    inflight: dict = {}
    pending: set[tuple] = set()
    simulated = [0] * len(specs)
    max_inflight = 2 * max(1, ex.slots)

    edges: dict[tuple, float] = {}      # a cell's coarse edge index, known before its search ends

    def plan(ic):
        """(hint, window, below) of a cell's search, or None while its neighbour's coarse edge is unknown (the
        neighbour's islands and bisection need not be finished: they do not move its coarse edge)."""
        spec = specs[ic[0]]
        if ic not in left:
            return (None, 0, 1)
        e = edges.get(left[ic])
        if e is None:
            return None
        return (e, spec.island_window, spec.bracket_check_below)

    try:
        while True:
            while dirty:
                ic = dirty.pop()
                if ic in bounds:
                    continue
                hw = plan(ic)
                if hw is None:
                    continue
                search = specs[ic[0]].search.for_duration(ic[1].duration)
                forces, b = plan_cell(search, survived[ic], *hw)
                if ic not in edges:
                    e = edge_index(b, search.coarse) if b is not None else coarse_edge(search, survived[ic], *hw)
                    if e is not None:
                        edges[ic] = e
                        if ic in right:
                            dirty.add(right[ic])
                if b is not None:          # the survival boundary found: then the no-fall edge
                    forces, b = plan_no_fall(search, fell[ic], b, fault[ic])
                if b is not None:
                    bounds[ic] = b
                    needs.pop(ic, None)
                else:
                    needs[ic] = forces
            queue = ((ic, SimSpec(ic[1], f)) for ic in sorted(needs, key=index.__getitem__) for f in needs[ic]
                     if (ic[0],) + SimSpec(ic[1], f).key() not in pending)
            while simulate and len(inflight) < max_inflight:
                chunk = []
                for ic, s in queue:     # a batch holds simulations of one spec (one settings)
                    if chunk and ic[0] != chunk[0][0][0]:
                        break
                    chunk.append((ic, s))
                    if len(chunk) == batch:
                        break
                if not chunk:
                    break
                i = chunk[0][0][0]
                h = ex.submit(tuple(s for _, s in chunk), specs[i].settings, specs[i].height)
                inflight[h] = chunk
                pending.update((ic[0],) + s.key() for ic, s in chunk)
                queue = ((ic, SimSpec(ic[1], f)) for ic in sorted(needs, key=index.__getitem__) for f in needs[ic]
                         if (ic[0],) + SimSpec(ic[1], f).key() not in pending)
            if progress is not None:
                remaining = 0
                for ic in cells:
                    if ic in bounds:
                        continue
                    hw = plan(ic) or (math.inf, specs[ic[0]].island_window,     # waiting: a bracket's estimate
                                      specs[ic[0]].bracket_check_below)
                    remaining += remaining_estimate(specs[ic[0]].search.for_duration(ic[1].duration), survived[ic], *hw)
                progress.update(sum(simulated), sum(resumed), remaining, count=_cells_count(bounds, cells, simulated,
                                                                                              resumed))
            if not inflight:
                break
            for h, out in ex.wait(list(inflight)):
                chunk = inflight.pop(h)
                if len(out) != len(chunk) or any(record_key(r) != s.key() for r, (_, s) in zip(out, chunk)):
                    raise MapError(f"the task returned records for other simulations than it was given "
                                   f"({[record_key(r) for r in out]} for {[s.key() for _, s in chunk]})")
                i = chunk[0][0][0]
                for r in out:
                    r["fingerprint"] = fps[i]
                if store is not None:
                    store.append(out)
                for (ic, s), r in zip(chunk, out):
                    pending.discard((ic[0],) + s.key())
                    recs[ic][s.force] = r
                    survived[ic][s.force] = bool(r["survived"])
                    fell[ic][s.force] = record_ends_no_fall(r)
                    fault[ic][s.force] = faulted(r)
                    dirty.add(ic)
                simulated[i] += len(out)
    finally:
        if executor is None:
            ex.close()
    if progress is not None:
        progress.update(sum(simulated), sum(resumed), 0, force=True,
                        count=_cells_count(bounds, cells, simulated, resumed))
        progress.close()
    # a trial reads config/controller.yaml at every simulation: a file edited during the run would
    # mix settings under one fingerprint, so the fingerprint is taken again and reported
    wall = time.perf_counter() - t0
    runs = []
    for i, spec in enumerate(specs):
        fp_end = fingerprint(spec)
        if fp_end != fps[i] and progress is not None and progress.stream is not None:
            progress.stream.write(f"WARNING: the settings changed during the run (fingerprint {fps[i]} -> {fp_end}): "
                                  "records made after the change are stored under the old fingerprint\n")
        mine = spec.cells()
        runs.append(MapRun(spec, fps[i], {c: bounds[(i, c)] for c in mine if (i, c) in bounds},
                           {c: recs[(i, c)] for c in mine}, simulated[i], resumed[i], ignored[i], wall,
                           ex.name if simulate else "none (report only)", fp_end,
                           [c for c in mine if (i, c) not in bounds]))
    return runs
