"""The result of one closed-loop run, whichever loop ran it: the studies' ``runner.run`` (the adaptive
controller, compiled or not) or the generic loop of any interface controller (``plugin.loop``).

``records``: the plant's ``StepRecord`` of each period kept; ``statuses``: the controller's status of each
of them (``ControllerStatusData`` from ``runner.run``, the interface's status mapping from the generic loop;
:meth:`RunResult.series` reads a key of either); ``steps_walked`` the impacts; the fall (cause, detail, time
[s]; empty / NaN without one); ``impacts``. From ``runner.run``: ``qp_instances`` (with ``keep_qp``) and
``param_range`` (the committed p [m] and tau' [-] extremes). From the generic loop: ``controller`` (its
name), ``fault`` (the controller fault that ended the run, None without one), ``periods`` (simulated, also
when records are not kept) and ``last_status`` (the last period's status mapping).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from biped_sim.plant.records import ImpactRecord, StepRecord

from biped_controller.core.control.status import ControllerStatusData
from biped_controller.plugin.interface import ControllerFault


@dataclass
class RunResult:
    """One run (module docstring)."""

    records: list[StepRecord]
    statuses: list[ControllerStatusData] | list[Mapping[str, float | int | bool]]
    steps_walked: int
    fallen: bool
    fall_cause: str
    fall_detail: str
    fall_time: float
    impacts: list[ImpactRecord]
    # with keep_qp: (G, h, x*, qp_status) of every period that built a QP instance
    qp_instances: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] = field(default_factory=list)
    # the controller's committed parameters over the run (from its reset, the walk to a restored snapshot
    # included): (smallest p, largest p [m], smallest tau', largest tau' [-]), NaN when one was NaN
    param_range: tuple[float, float, float, float] = (math.nan, math.nan, math.nan, math.nan)
    controller: str = ""
    fault: ControllerFault | None = None
    periods: int = 0
    last_status: Mapping[str, float | int | bool] = field(default_factory=dict)

    def series(self, key: str) -> np.ndarray:
        """One status field over the kept periods: an attribute of ``ControllerStatusData``, or a key of the
        status mappings (NaN where a period's mapping lacks it)."""
        if self.statuses and isinstance(self.statuses[0], Mapping):
            return np.array([float(s.get(key, math.nan)) for s in self.statuses])
        return np.array([getattr(s, key) for s in self.statuses])
