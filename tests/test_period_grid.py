"""The control grid and a period's integration knots (biped_sim.plant.period_grid) against their compiled twin
in the closed loop (loop_kernels._knots), bit for bit, and against hand values."""
from __future__ import annotations

import math

import numpy as np
import pytest

from biped_sim.plant.period_grid import grid_end, last_grid_before, period_knots

DT = 1e-3


def test_grid_by_hand():
    assert grid_end(0.0, DT) == DT
    assert grid_end(0.0105, DT) == 11 * DT
    assert grid_end(5 * DT - 1e-12, DT) == 6 * DT          # a rounding error below a grid instant counts as on it
    assert grid_end(5 * DT - 1e-6, DT) == 5 * DT           # well below: the grid instant itself ends the period
    assert last_grid_before(0.0105, DT) == 10 * DT
    assert last_grid_before(0.0, DT) == 0.0
    for t in np.linspace(0.0, 0.5, 97):
        g = last_grid_before(float(t), DT)
        assert g <= t and grid_end(g, DT) > t - 1e-12


def test_knots_by_hand():
    assert period_knots(0.0, 1e-3, 2) == [0.0, 0.5e-3, 1e-3]
    # a push start inside the period splits it; one outside or on a knot adds nothing
    assert period_knots(0.0, 1e-3, 2, (0.2e-3, 0.5e-3, 1e-3, 2e-3)) == [0.0, 0.2e-3, 0.5e-3, 1e-3]


def _python(t_start, substeps, cuts):
    end = grid_end(t_start, DT)
    n_sub = max(1, int(math.ceil(substeps * (end - t_start) / DT - 1e-9)))
    return period_knots(t_start, end, n_sub, cuts), end


@pytest.fixture(scope="module")
def lk():
    from biped_controller.closed_loop.segment import load_loop_kernels
    return load_loop_kernels()


def test_compiled_twin_equals_the_python_home(lk):
    rng = np.random.default_rng(7)
    starts = [k * DT for k in range(0, 40)] + list(rng.uniform(0.0, 2.0, 300))
    starts += [k * DT - 1e-12 for k in range(1, 20)] + [k * DT + 3e-10 for k in range(20)]
    checked = 0
    for i, t0 in enumerate(starts):
        substeps = (1, 2, 4, 8)[i % 4]
        end = grid_end(t0, DT)
        knots0 = [t0 + j * (end - t0) / max(1, substeps) for j in range(substeps)]
        # cuts: inside, outside, on the period's bounds and exactly on a substep knot (kept once)
        cuts = [t0 + rng.uniform(0.0, 1.0) * (end - t0), end + 1e-4, t0 - 1e-4, t0, end, knots0[-1],
                t0 + rng.uniform(0.0, 1.0) * (end - t0)]
        pushes = np.zeros((len(cuts) // 2 + 1, 4))
        flat = cuts + [t0 - 1.0]
        pushes[:, 0], pushes[:, 1] = flat[0::2], flat[1::2]
        buf = np.zeros(64)
        n, g = lk._knots(float(t0), DT, substeps, pushes, buf)
        want, want_end = _python(float(t0), substeps, [c for row in pushes[:, :2] for c in row])
        assert g == want_end, (t0, g, want_end)
        assert n == len(want) and list(buf[:n]) == want, (t0, substeps, list(buf[:n]), want)
        checked += 1
    assert checked == len(starts)
    # negative control: a buffer too short is reported, not overrun
    n, _ = lk._knots(0.0, DT, 8, np.array([[0.3e-3, 0.6e-3, 0.0, 0.0]]), np.zeros(9))
    assert n == -1
