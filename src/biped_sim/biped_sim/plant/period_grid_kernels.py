"""The compiled twin (numba) of :mod:`biped_sim.plant.period_grid`: the control grid's period end and a
period's integration knots, for the compiled closed loops (``biped_controller.closed_loop.loop_kernels`` on the
rigid plant, ``mujoco_loop_kernels`` on MuJoCo), which import it. The same operations in the same order as
the Python home (IEEE double, no fast-math), so the knots are bit-identical to it
(``tests/test_period_grid.py``).

Pure numerics, no side effects on import (it is loaded through ``numba_cache.load`` as a dependency of the
loops' kernels).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_model import numba_cache

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load


@numba.njit(cache=True, nogil=True)
def grid_end(t_start, dt_nom):  # pragma: no cover (compiled)
    """``period_grid.grid_end``: (floor(t / dt + 1e-6) + 1) * dt [s]."""
    return (math.floor(t_start / dt_nom + 1e-6) + 1) * dt_nom


@numba.njit(cache=True, nogil=True)
def knots(t_start, t_end, n_sub, pushes, out):  # pragma: no cover (compiled)
    """``period_grid.period_knots`` into ``out``: ``n_sub`` equal substeps of [t_start, t_end] [s], then t_end,
    and the push starts and ends of ``pushes`` (rows: start, end, ...) strictly inside as cuts, sorted, each
    once. Returns the count of knots, -1 when ``out`` is too short."""
    h = (t_end - t_start) / n_sub
    if n_sub + 1 > out.shape[0]:
        return -1
    n = 0
    for i in range(n_sub):
        out[n] = t_start + i * h
        n += 1
    out[n] = t_end
    n += 1
    cut = False
    for k in range(pushes.shape[0]):
        for c in (pushes[k, 0], pushes[k, 1]):
            if t_start < c < t_end:
                if n >= out.shape[0]:
                    return -1
                out[n] = c
                n += 1
                cut = True
    if not cut:
        return n
    ks = np.sort(out[:n])
    m = 0
    for i in range(n):   # set() then sorted(): exact duplicates once
        if m == 0 or ks[i] != out[m - 1]:
            out[m] = ks[i]
            m += 1
    return m
