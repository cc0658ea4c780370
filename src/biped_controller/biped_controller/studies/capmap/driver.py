"""The map's driver: every cell's search served on an executor, records stored as they complete."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

from biped_controller.studies import experiment
from biped_controller.studies.capmap.search import Boundary, plan_cell, remaining_estimate
from biped_controller.studies.capmap.spec import Cell, MapError, MapSpec, SimSpec
from biped_controller.studies.capmap.store import RecordStore, fingerprint
from biped_controller.studies.capmap.task import record_key, simulate_batch
from biped_controller.studies.executor import ProgressBar, SerialExecutor


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
    ex = executor if executor is not None else SerialExecutor(simulate_batch)
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
