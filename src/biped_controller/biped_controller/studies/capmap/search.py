"""The force search of one cell as a pure function of its records: coarse scan, islands, bisection."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

from biped_controller.studies.trial.search import analyse_coarse
from biped_controller.studies.capmap.spec import MapError, Search


@dataclass(frozen=True)
class Boundary:
    """The outcome of one cell's search (forces [N]). ``full``: every coarse force was simulated (the
    islands are complete); False: the edge was bracketed from a neighbour (:func:`plan_cell`), the
    islands are those within the island window above the edge."""

    lo: float                 # largest survivable force below the lowest failing edge (0: none)
    hi: float | None          # lowest failing force found (after bisection); None: censored
    islands: tuple[float, ...]
    full: bool = True
    no_fall_lo: float | None = None    # the no-fall edge: largest force without a fall below the first fall
    no_fall_hi: float | None = None    # the first fall found (after bisection); None: no fall up to the scan's top
    # the lowest force that fell or faulted faulted (the controller's fault, ``trial.record``): whether it would
    # have fallen is unknown, so the no-fall edge is undefined (``no_fall_lo``, ``no_fall_hi`` None); None: defined
    no_fall_fault: float | None = None


def _bisect(search: Search, survived: Mapping[float, bool], lo: float, hi: float, islands: tuple, full: bool):
    """Bisect [lo (survives), hi (fails)] at midpoints down to the resolution: ("bisect", lo, hi) with the
    next midpoint not simulated yet, or ("done", Boundary)."""
    while hi - lo > search.resolution:
        mid = 0.5 * (lo + hi)
        if mid not in survived:
            return ("bisect", lo, hi)
        if survived[mid]:
            lo = mid
        else:
            hi = mid
    return ("done", Boundary(lo, hi, islands, full))


def _search_state(search: Search, survived: Mapping[float, bool]):
    """Where a cell's full search stands: ("coarse", missing coarse forces), ("bisect", lo, hi) with the
    midpoint of [lo, hi] not simulated yet, or ("done", Boundary)."""
    coarse = search.coarse_forces()
    missing = [f for f in coarse if f not in survived]
    if missing:
        return ("coarse", missing)
    lo, hi, islands = analyse_coarse([{"force": f, "survived": survived[f]} for f in coarse])
    if hi is None:
        return ("done", Boundary(lo, None, tuple(islands)))
    return _bisect(search, survived, lo, hi, tuple(islands), True)


def edge_index(b: Boundary, coarse: float) -> float:
    """The coarse step k (force k * coarse) of a finished cell's lowest failing coarse force, the hint its
    neighbour's search starts from; inf for a censored cell."""
    if b.hi is None:
        return math.inf
    return float(math.ceil(b.hi / coarse - 1e-9))


def _check_below(below) -> None:
    """``below`` (the bracket's check under itself, coarse steps) is an integer >= 1: the bracket's lower
    force at least."""
    if isinstance(below, bool) or not (isinstance(below, int) and below >= 1):
        raise MapError(f"bracket_check_below must be an integer >= 1 [coarse steps], got {below!r}")


def _bracket_edge(search: Search, survived: Mapping[float, bool], hint: float, below: int):
    """Step 1 of :func:`_bracket_state`, the bracket of the edge: ("coarse", forces still to simulate),
    ("full",) when the bracket reached the scan's top still surviving (the full search takes over), or
    ("edge", k) with k c the cell's lowest failing coarse force as the bracket finds it.

    With k the hint (clamped to the grid [1, n]) the coarse forces k c and the ``below`` ones under it,
    (k - 1) c ... (k - below) c (those > 0), are simulated. The bracket holds when k c fails and every one
    below it survives. A failure below moves it down to the highest failing one, (k - j) c; otherwise a
    surviving k c moves it up one coarse step (at the top, n c, the full search takes over). Every coarse
    force of a cell is below the hint, at it, or above it, so the bracket ends on the full search's edge
    whenever no failure lies more than ``below`` coarse steps under a survivable coarse force above that
    edge (``below`` = 1: only the bracket's lower force is checked)."""
    c, n = search.coarse, len(search.coarse_forces())
    k = int(min(max(hint, 1), n))
    while True:
        need = [f for f in [j * c for j in range(k - below, k + 1)] if f > 0 and f not in survived]
        if need:
            return ("coarse", need)
        failing = [j for j in range(k - 1, max(k - below, 1) - 1, -1) if not survived[j * c]]
        if failing:
            k = failing[0]
        elif survived[k * c]:
            if k == n:
                return ("full",)
            k += 1
        else:
            return ("edge", k)


def _bracket_state(search: Search, survived: Mapping[float, bool], hint: float, window: int, below: int):
    """The search bracketed from a neighbour's edge ``hint`` (a coarse step index, inf: censored).

    1. Edge (:func:`_bracket_edge`): from the hint k, the coarse force k c must fail and the ``below``
       coarse forces under it, (k - 1) c ... (k - below) c (those > 0), must survive; a failure among them
       moves the bracket down to it, a surviving k c moves it up one coarse step, until it holds (the
       edge is then k c, the bracket [(k - 1) c (0 N when k = 1), k c]). A bracket that reaches the scan's
       maximum still surviving falls back to the full search (a cell is censored only when every coarse
       force survives: islands high up must not pass for a censored cell). The coarse forces more than
       ``below`` steps under the edge are not simulated: the bracket assumes they survive. It checks
       ``below`` steps under itself as the island window checks ``window`` steps above: a failure under a
       survivable coarse force, at most ``below`` - 1 survivable ones between them, is found (the depth
       measured on MuJoCo: ``bracket_check_below`` in config/studies.yaml).
    2. Islands: above the edge, coarse forces are simulated upward until ``window`` consecutive ones
       fail (or the scan's maximum); every survivable one is an island (a survivable one found moves
       the window up).
    3. The edge's coarse interval is bisected at the midpoints of the full search: the same boundary,
       first failure and cause whenever the edge's coarse interval is the same."""
    st = _bracket_edge(search, survived, hint, below)
    if st[0] == "coarse":
        return st
    if st[0] == "full":      # survives at the scan's top: censored only if every coarse force survives
        return _search_state(search, survived)
    c, n, k = search.coarse, len(search.coarse_forces()), st[1]
    hi, lo = k * c, (k - 1) * c if k > 1 else 0.0
    j, fails = k, 0
    while j < n and fails < window:
        j += 1
        f = j * c
        if f not in survived:
            return ("coarse", [f])
        fails = 0 if survived[f] else fails + 1
    islands = tuple(f for f in search.coarse_forces() if f > hi and survived.get(f, False))
    return _bisect(search, survived, lo, hi, islands, False)


def coarse_edge(search: Search, survived: Mapping[float, bool], hint: float | None = None,
                window: int = 0, below: int = 1) -> float | None:
    """The coarse step index of the cell's lowest failing coarse force (inf: censored) as soon as its search
    knows it -- the value :func:`edge_index` gives for the finished boundary (bisection keeps the edge
    inside its coarse interval) -- or None while the coarse scan or the bracket is unfinished. A neighbour
    bracketed from this cell can start from it while this cell's islands and bisection go on. ``hint``
    None: the full search's coarse scan; else the bracket of :func:`_bracket_state` (``below`` coarse
    steps checked under it, the same function :func:`_bracket_edge`)."""
    _check_below(below)
    c = search.coarse
    if hint is not None:
        st = _bracket_edge(search, survived, hint, below)
        if st[0] == "coarse":
            return None
        if st[0] == "edge":
            return float(st[1])
    coarse = search.coarse_forces()             # the full search (or the bracket's fallback to it)
    if any(f not in survived for f in coarse):
        return None
    _, hi, _ = analyse_coarse([{"force": f, "survived": survived[f]} for f in coarse])
    return math.inf if hi is None else float(math.ceil(hi / c - 1e-9))


def plan_cell(search: Search, survived: Mapping[float, bool], hint: float | None = None,
              window: int = 0, below: int = 1) -> tuple[list[float], Boundary | None]:
    """The search of one cell as a pure function of its trials so far (force [N] -> survived): either the
    forces still to simulate and None, or [] and the :class:`Boundary`. ``hint`` None: the full search
    (every coarse force, then the bisection midpoint); else the coarse step index of a neighbour's edge
    (:func:`edge_index`) and the search is bracketed from it (:func:`_bracket_state`, island ``window``
    and bracket check ``below`` in coarse steps)."""
    _check_below(below)
    st = _search_state(search, survived) if hint is None else _bracket_state(search, survived, hint, window, below)
    if st[0] == "coarse":
        return st[1], None
    if st[0] == "bisect":
        return [0.5 * (st[1] + st[2])], None
    return [], st[1]


def plan_no_fall(search: Search, fell: Mapping[float, bool], b: Boundary,
                 faulted: Mapping[float, bool] | None = None) -> tuple[list[float], Boundary | None]:
    """The no-fall edge of a cell whose survival search ended in ``b``, as a pure function of its trials
    (force [N] -> fell; ``faulted``: force -> the controller faulted, a trial that counts as fallen in
    ``fell`` too, since whether it would have fallen is unknown): either the forces still to simulate and
    None, or [] and ``b`` with the edge. When the lowest force that fell or faulted faulted, the edge is
    undefined: ``no_fall_lo`` and ``no_fall_hi`` None, ``no_fall_fault`` that force.

    A fall fails the survival rule, so no force below the survival boundary's first failing coarse force
    k0 c fell (the coarse scan found them survived; the bracket those it simulated, and assumes the
    others survive). From k0 c upward the coarse forces are
    simulated until the first that fell, k c (none up to the scan's top: the edge is censored there,
    ``no_fall_hi`` None); then [(k - 1) c (or 0), k c] is bisected at midpoints to the resolution, as the
    survival boundary is: where the first failure is a fall the two bisections share their trials."""
    if b.hi is None:                      # nothing failed: nothing fell either
        return [], replace(b, no_fall_lo=b.lo, no_fall_hi=None)
    coarse = search.coarse_forces()
    c = search.coarse
    k0 = int(edge_index(b, c))
    lo = (k0 - 1) * c if k0 > 1 else 0.0
    hi = None
    for f in coarse[k0 - 1:]:
        if f not in fell:
            return [f], None
        if fell[f]:
            hi = f
            break
        lo = f
    if hi is None:
        return [], replace(b, no_fall_lo=lo, no_fall_hi=None)
    while hi - lo > search.resolution:
        mid = 0.5 * (lo + hi)
        if mid not in fell:
            return [mid], None
        if fell[mid]:
            hi = mid
        else:
            lo = mid
    if faulted is not None and faulted.get(hi, False):
        return [], replace(b, no_fall_lo=None, no_fall_hi=None, no_fall_fault=hi)
    return [], replace(b, no_fall_lo=lo, no_fall_hi=hi)


def bisection_steps(width: float, resolution: float) -> int:
    """Halvings of an interval of ``width`` [N] until it is <= ``resolution`` [N]."""
    n = 0
    while width > resolution:
        width *= 0.5
        n += 1
    return n


def remaining_estimate(search: Search, survived: Mapping[float, bool], hint: float | None = None,
                       window: int = 0, below: int = 1) -> int:
    """Simulations a cell still needs, estimated (for the progress bar): the missing coarse forces plus
    the bisection of one coarse step, or the bisection steps left (bracketed: the bracket's upper force
    and the ``below`` under it, the window and the bisection)."""
    _check_below(below)
    st = _search_state(search, survived) if hint is None else _bracket_state(search, survived, hint, window, below)
    if st[0] == "coarse":
        extra = len(st[1]) if hint is None else 1 + below + window
        return extra + bisection_steps(search.coarse, search.resolution)
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
