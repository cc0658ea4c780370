"""The control grid and a period's integration knots: the one home of both formulas (pure Python; the
compiled twin is ``period_grid_kernels``, which both compiled closed loops call; tested equal bit for bit).

Control periods end on the grid t_k = k * dt [s] (k integer, dt the control period): a period that starts at
t ends at the next grid instant after t, with a tolerance of 1e-6 periods so that a start a rounding error
below a grid instant counts as on it. A period cut short by an impact starts off the grid and ends at the
next grid instant. Within a period [t_start, t_end] the plant integrates over ``n_sub`` equal substeps,
split exactly at every push start and end inside the period (a push acts over whole intervals only).
"""
from __future__ import annotations

import math
from typing import Iterable

__all__ = ["grid_end", "last_grid_before", "period_knots"]


def grid_end(t: float, dt: float) -> float:
    """The end [s] of the control period that starts at ``t`` [s]: (floor(t / dt + 1e-6) + 1) * dt."""
    return (math.floor(t / dt + 1e-6) + 1) * dt


def last_grid_before(t: float, dt: float) -> float:
    """The largest grid instant k * dt <= ``t`` [s] (k integer >= 0), with the grid of :func:`grid_end`."""
    k = max(0, math.floor(t / dt + 1e-6))
    while k > 0 and k * dt > t:
        k -= 1
    return k * dt


def period_knots(t_start: float, t_end: float, n_sub: int, cuts: Iterable[float] = ()) -> list[float]:
    """The integration knots [s] of the period [t_start, t_end]: ``n_sub`` equal substeps
    (t_start + i (t_end - t_start) / n_sub, i < n_sub, then t_end) and every time of ``cuts`` (push starts
    and ends) strictly inside the period, sorted, each once."""
    h = (t_end - t_start) / n_sub
    knots = [t_start + i * h for i in range(n_sub)] + [t_end]
    inside = {c for c in cuts if t_start < c < t_end}
    return sorted(set(knots) | inside) if inside else knots
