"""The push acts exactly over its window [start, start + duration), with a constant force on every
integration interval (issue: the force used to be sampled at RK4 stage times, so the sub-step that ended
at the onset already carried 1/6 of it).

Checks, each against something computed independently of the simulator's bookkeeping:
- before the onset the run is bit-identical to the same run without the push (nothing acts early);
- every RK4 step that the integrator takes lies either inside the window (force on) or outside it
  (force off): none straddles a switch;
- the impulse delivered per period equals F x |[t, t_end) intersected with the window| computed from the
  request, and the total equals F x duration to 1e-9 relative: for a push on the grid, off the grid, and
  one cut short by a fall (then F x (t_fall - start)).
"""
from __future__ import annotations

import numpy as np
import pytest

from biped_controller.closed_loop import runner
from biped_sim.plant.push import Push
from biped_sim.plant.rigid import Simulator


def _overlap(a0: float, a1: float, b0: float, b1: float) -> float:
    return max(0.0, min(a1, b1) - max(a0, b0))


def _check_impulses(result: runner.RunResult, push: Push, expected_total: float) -> None:
    end = push.start + push.duration
    total = 0.0
    touched = 0
    for rec in result.records:
        want = push.force * _overlap(rec.t, rec.t_end, push.start, end)
        assert rec.push_impulse == pytest.approx(want, rel=1e-12, abs=1e-12), (rec.t, rec.t_end)
        if rec.t_end <= push.start or rec.t >= end:
            assert rec.push_impulse == 0.0, (rec.t, rec.t_end)
        touched += want > 0
        total += rec.push_impulse
    assert touched > 0
    assert total == pytest.approx(expected_total, rel=1e-9)


@pytest.mark.parametrize("start", [0.2, 0.2003217])   # on the 1 ms grid, and off it (inside a substep)
def test_impulse_is_force_times_duration(start):
    push = Push(start, 0.025, 250.0)
    r = runner.run(steps=1, mode="both", pushes=(push,))
    assert not r.fallen
    _check_impulses(r, push, push.force * push.duration)


def test_push_cut_short_by_a_fall_delivers_force_times_elapsed():
    push = Push(0.2, 0.2, 1500.0)
    r = runner.run(steps=2, mode="both", pushes=(push,))
    assert r.fallen
    t_fall = r.records[-1].t_end
    assert push.start < t_fall < push.start + push.duration, "the fall must cut the push for this test"
    _check_impulses(r, push, push.force * (t_fall - push.start))


def test_nothing_acts_before_the_onset():
    start = 0.2003217
    a = runner.run(steps=1, mode="both", pushes=(Push(start, 0.025, 400.0),))
    b = runner.run(steps=1, mode="both")
    before = [i for i, rec in enumerate(a.records) if rec.t_end <= start]
    assert len(before) > 150
    for i in before:
        assert np.array_equal(a.records[i].x, b.records[i].x) and np.array_equal(a.records[i].v, b.records[i].v)
        assert np.array_equal(a.records[i].wrench, b.records[i].wrench)
    # the first period that contains the onset: the states at its start agree, the next ones differ
    k = before[-1] + 1
    assert np.array_equal(a.records[k].x, b.records[k].x)
    assert not np.array_equal(a.records[k + 1].v, b.records[k + 1].v)


def test_no_integration_step_straddles_a_switch(monkeypatch):
    start, duration = 0.2003217, 0.0251
    calls = []
    original = Simulator._rk4

    def spy(self, x, v, tau_src, t, h, pushes):
        calls.append((t, h, pushes))
        return original(self, x, v, tau_src, t, h, pushes)

    monkeypatch.setattr(Simulator, "_rk4", spy)
    # the interval-by-interval path (the compiled period is checked on the same intervals below, and
    # bit for bit against this path in test_engines)
    monkeypatch.setattr(Simulator, "_fast_period", lambda self, *a: None)
    runner.run(steps=1, mode="both", pushes=(Push(start, duration, 300.0),), compiled_loop=False)
    end = start + duration
    on = [c for c in calls if c[2]]
    assert len(on) >= 2 * 25 - 2
    for t, h, pushes in calls:
        inside = start - 1e-12 <= t and t + h <= end + 1e-12
        outside = t + h <= start + 1e-12 or t >= end - 1e-12
        assert inside or outside, f"RK4 step [{t}, {t + h}] straddles the window [{start}, {end})"
        assert bool(pushes) == inside, (t, h, pushes)
        assert all(f == 300.0 for f, _ in pushes)


def test_compiled_period_gets_intervals_split_at_the_switches(monkeypatch):
    """The intervals and per-interval pushes handed to planar_kernels.period: none straddles the window,
    the force is on exactly inside it."""
    import math
    from biped_model.fast_engine import planar_kernels
    pk = planar_kernels()
    start, duration = 0.2003217, 0.0251
    end = start + duration
    seen = []
    original = pk.period

    def spy(ti, tf, x, v, tau_j, knots, forces, heights, *rest):
        seen.append((knots.copy(), forces.copy(), heights.copy()))
        return original(ti, tf, x, v, tau_j, knots, forces, heights, *rest)

    monkeypatch.setattr(pk, "period", spy)
    runner.run(steps=1, mode="both", pushes=(Push(start, duration, 300.0),), compiled_loop=False)
    n_on = 0
    for knots, forces, heights in seen:
        for t0, t1, f, h in zip(knots[:-1], knots[1:], forces, heights):
            inside = start - 1e-12 <= t0 and t1 <= end + 1e-12
            outside = t1 <= start + 1e-12 or t0 >= end - 1e-12
            assert inside or outside, f"interval [{t0}, {t1}] straddles the window [{start}, {end})"
            assert (not math.isnan(h)) == inside and f == (300.0 if inside else 0.0), (t0, t1, f, h)
            n_on += inside
    assert n_on >= 2 * 25 - 4
