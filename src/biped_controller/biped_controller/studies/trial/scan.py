"""A force scan's trials read for one edge: the coarse forces and the bracket they leave (pure; shared by
the studies' search, :mod:`.search`, and the plug-in trials, :mod:`.plugin_trials`).

A trial whose controller faulted (``trial.record``: ``fault_kind`` not None) is a failure of both edges: it
did not survive, and from the fault on no torque was applied, so whether it would have fallen is unknown.
When the lowest force that fell or faulted faulted, the no-fall edge is undefined
(:func:`no_fall_undefined` says why)."""
from __future__ import annotations

import math
from typing import Mapping

from biped_controller.studies.trial.record import faulted

def coarse_forces(fmax: float, coarse: float) -> list[float]:
    """The coarse scan's forces [N]: coarse, 2 coarse, ... <= fmax."""
    n = int(math.floor(fmax / coarse + 1e-9))
    return [coarse * k for k in range(1, n + 1)]



def outcome(trial: dict, edge: str) -> bool:
    """A trial's outcome for ``edge``: "survival" (the survival rule met) or "no_fall" (no fall and no
    controller fault: a faulted trial's fall is unknown)."""
    if edge == "survival":
        return bool(trial["survived"])
    if edge == "no_fall":
        return not trial["fell"] and not faulted(trial)
    raise ValueError(f"edge must be 'survival' or 'no_fall', got {edge!r}")


def analyse_coarse(trials: list[dict], edge: str = "survival") -> tuple[float, float | None, list[float]]:
    """For ``edge`` (:func:`outcome`): (last passing force below the first failure (0 if the first fails),
    first failing force or None, passing coarse forces above the first failure)."""
    trials = sorted(trials, key=lambda r: r["force"])
    lo, hi = 0.0, None
    for r in trials:
        if outcome(r, edge):
            lo = r["force"]
        else:
            hi = r["force"]
            break
    islands = [r["force"] for r in trials if hi is not None and r["force"] > hi and outcome(r, edge)]
    return lo, hi, islands


def no_fall_undefined(first: Mapping | None) -> str | None:
    """Why the no-fall edge is undefined, or None when it is defined: ``first`` is the trial at the lowest
    force that fell or faulted (None: none did, the edge is the scan's top); when its controller faulted,
    no fall was seen below a force the controller could not be judged at."""
    if first is None or not faulted(first):
        return None
    kind = first.get("fault_kind") or first.get("fault")
    return (f"undefined: the controller faulted ({kind}) at {first['force']:g} N before any fall "
            f"(a faulted trial is neither a survival nor a fall)")
