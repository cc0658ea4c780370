"""A force scan's trials read for one edge: the coarse forces and the bracket they leave (pure; shared by
the studies' search, :mod:`.search`, and the plug-in trials, :mod:`.plugin_trials`)."""
from __future__ import annotations

import math



def coarse_forces(fmax: float, coarse: float) -> list[float]:
    """The coarse scan's forces [N]: coarse, 2 coarse, ... <= fmax."""
    n = int(math.floor(fmax / coarse + 1e-9))
    return [coarse * k for k in range(1, n + 1)]



def outcome(trial: dict, edge: str) -> bool:
    """A trial's outcome for ``edge``: "survival" (the survival rule met) or "no_fall" (no fall)."""
    if edge == "survival":
        return bool(trial["survived"])
    if edge == "no_fall":
        return not trial["fell"]
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
