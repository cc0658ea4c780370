"""Push-recovery capability map: the public API of ``studies.capmap`` in one namespace, and
``python -m biped_controller.studies.capability_map`` (``scripts/capability_map --help``). Everything is
defined once, in the modules of ``studies.capmap`` (its docstring describes the map)."""
from __future__ import annotations

import sys

from biped_controller.studies.capmap.driver import MapRun, record_ends_no_fall, record_fell, run_map, run_maps
from biped_controller.studies.capmap.executors import (DEFAULT_BATCH, PoolExecutor, RayExecutor, SerialExecutor,
                                                       make_executor)
from biped_controller.studies.capmap.figures import figures
from biped_controller.studies.capmap.findings import cell_summary, findings, findings_text, summary
from biped_controller.studies.capmap.metrics import body_weight_fraction, com_velocity_change, impulse
from biped_controller.studies.capmap.search import (Boundary, bisection_steps, edge_index, island_ranges, plan_cell,
                                                    plan_no_fall, remaining_estimate)
from biped_controller.studies.capmap.spec import (DEFAULT_COARSE, DEFAULT_DURATIONS, DEFAULT_MAX, DEFAULT_MAX_IMPULSE,
                                                  DEFAULT_PHASES, DEFAULT_RESOLUTION, DIRECTIONS, Cell, MapError,
                                                  MapSpec, Search, SimSpec, onset_time, phases_of,
                                                  search_settings)
from biped_controller.studies.capmap.store import RECORD_VERSION, RecordStore, StoreError, fingerprint, load_records
from biped_controller.studies.capmap.task import failure_cause, record_key, simulate, simulate_batch
from biped_controller.studies.capmap.cli import main
from biped_controller.closed_loop.executor import ProgressBar
from biped_controller.studies.provenance import git_state

__all__ = [
    "MapRun", "record_fell", "record_ends_no_fall", "plan_no_fall", "run_map", "run_maps", "edge_index", "search_settings", "DEFAULT_BATCH", "PoolExecutor", "RayExecutor", "SerialExecutor", "make_executor",
    "figures", "cell_summary", "findings", "findings_text", "summary", "body_weight_fraction",
    "com_velocity_change", "impulse", "Boundary", "bisection_steps", "island_ranges", "plan_cell",
    "remaining_estimate", "DEFAULT_COARSE", "DEFAULT_DURATIONS", "DEFAULT_MAX", "DEFAULT_MAX_IMPULSE",
    "DEFAULT_PHASES", "DEFAULT_RESOLUTION", "DIRECTIONS", "Cell", "MapError", "MapSpec", "Search", "SimSpec",
    "onset_time", "phases_of", "RECORD_VERSION", "RecordStore", "StoreError", "fingerprint", "load_records",
    "failure_cause", "record_key", "simulate", "simulate_batch", "main", "ProgressBar", "git_state",
]

if __name__ == "__main__":
    sys.exit(main())
