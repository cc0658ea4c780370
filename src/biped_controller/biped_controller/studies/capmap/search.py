"""The force search of one cell as a pure function of its records: coarse scan, islands, bisection."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

from biped_controller.studies import experiment
from biped_controller.studies.capmap.spec import Search


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
