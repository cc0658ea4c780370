"""The fast engine (compiled kernels) against the reference engine (Pinocchio), whole closed-loop runs
record for record: walking with impacts, a push, a fall. Model terms are compared state by state in
tests/test_fast_kernels.py; here the whole simulator + controller loop must agree to 1e-9."""
from __future__ import annotations

import pytest

from helpers import assert_same_fields, assert_same_run, count_compiled_periods
from biped_controller.closed_loop import runner
from biped_controller.core.control.config import load_controller_config
from biped_sim.plant.push import Push
from biped_sim.plant.config import load_sim_config


def _run(engine: str, steps: int, pushes=(), mode: str = "both"):
    return runner.run(steps=steps, mode=mode, pushes=pushes, sim_config=load_sim_config(engine=engine),
                      ctrl_config=load_controller_config(mode=mode, engine=engine))


@pytest.mark.parametrize("case", ["walk", "push", "fall"])
def test_fast_engine_matches_reference_record_for_record(case):
    args = {"walk": dict(steps=2),
            "push": dict(steps=2, pushes=(Push(0.2003217, 0.025, 300.0),)),
            "fall": dict(steps=2, pushes=(Push(0.2, 0.1, 1500.0),))}[case]
    ref = _run("reference", **args)
    fast = _run("fast", **args)
    assert fast.steps_walked >= (0 if case == "fall" else 2)
    assert fast.fallen == (case == "fall")
    assert_same_run(ref, fast, tol=1e-9, skip_status=("qp_message",))


def test_engines_are_really_different_code():
    """The two engines are selected: the fast simulator holds the compiled model."""
    from biped_model.fast_engine import FastFloatingModel
    from biped_model.floating import FloatingModel
    from biped_sim.plant.rigid import Simulator
    assert isinstance(Simulator(config=load_sim_config(engine="fast")).fm, FastFloatingModel)
    assert type(Simulator(config=load_sim_config(engine="reference")).fm) is FloatingModel


def test_exact_qp_solver_option_gives_the_same_run():
    """qp_solver: exact (dedicated solver) vs piqp (the product's): same decisions to solver tolerance."""
    push = (Push(0.2003217, 0.025, 400.0),)
    a = runner.run(steps=1, mode="both", pushes=push, ctrl_config=load_controller_config(mode="both", qp_solver="piqp"))
    b = runner.run(steps=1, mode="both", pushes=push, ctrl_config=load_controller_config(mode="both", qp_solver="exact"))
    assert sum(s.qp_status == 1 for s in a.statuses) > 0, "the push must make the QP active"
    assert [s.qp_status for s in a.statuses] == [s.qp_status for s in b.statuses]
    assert_same_run(a, b, tol=1e-6, skip_status=("qp_message",))


def _without(monkeypatch, cls, name):
    monkeypatch.setattr(cls, name, lambda self, *a, **k: None)


@pytest.mark.parametrize("mode", ["both", "p", "none"])
def test_compiled_controller_period_matches_its_python_steps(monkeypatch, mode):
    """control_kernels.step (one compiled call per period, fast engine) against the controller's own
    Python steps on the same compiled model terms: same run to 1e-9, QP decisions included."""
    from biped_controller.core.control import controller as C
    push = (Push(0.2003217, 0.025, 400.0),)
    used = count_compiled_periods(monkeypatch)
    fast = runner.run(steps=2, mode=mode, pushes=push, compiled_loop=False)
    assert used and all(used), "the compiled period must serve every period of a finite run"
    _without(monkeypatch, C.CompiledPeriod, "compute")
    steps = runner.run(steps=2, mode=mode, pushes=push, compiled_loop=False)
    if mode != "none":
        assert sum(s.qp_status == 1 for s in steps.statuses) > 0, "the push must make the QP active"
    assert [s.qp_status for s in fast.statuses] == [s.qp_status for s in steps.statuses]
    assert_same_run(steps, fast, tol=1e-9, skip_status=("qp_message",), relative=True)


@pytest.mark.parametrize("push", [Push(0.2003217, 0.025, 300.0), Push(0.2, 0.1, 1500.0), Push(0.1003, 0.1, -150.0)])
def test_compiled_simulator_period_is_the_event_path_bit_for_bit(monkeypatch, push):
    """planar_kernels.period (the whole period in one call when nothing happens in it) against the
    simulator's interval-by-interval path: identical records (np.array_equal), impacts and falls."""
    import numpy as np
    from biped_sim.plant.rigid import Simulator
    calls = []
    orig = Simulator._fast_period

    def counting(self, *a):
        out = orig(self, *a)
        calls.append(out is not None)
        return out
    monkeypatch.setattr(Simulator, "_fast_period", counting)
    fast = runner.run(steps=2, mode="both", pushes=(push,), compiled_loop=False)
    assert sum(calls) > 0.9 * len(calls), "the compiled period serves the periods with no event"
    assert not all(calls), "impacts and falls go through the event path"
    _without(monkeypatch, Simulator, "_fast_period")
    slow = runner.run(steps=2, mode="both", pushes=(push,), compiled_loop=False)
    assert len(fast.records) == len(slow.records) and fast.fall_cause == slow.fall_cause
    for a, b in zip(slow.records, fast.records):
        for name in ("x", "v", "q", "qd", "torque", "wrench"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), (a.step, name)
        assert (a.t, a.t_end, a.push_force, a.push_impulse, a.stance) == (b.t, b.t_end, b.push_force, b.push_impulse,
                                                                           b.stance), a.step


@pytest.mark.parametrize("mode,push,extra", [
    ("both", None, 0.0), ("none", None, 0.0), ("both", Push(0.2003217, 0.025, 400.0), 0.0),
    ("p", Push(0.1003, 0.1, -150.0), 0.0), ("tau", Push(0.2, 0.1, 1500.0), 0.0), ("both", None, 0.3)])
def test_compiled_loop_is_the_objects_period_by_period(monkeypatch, mode, push, extra):
    """loop_kernels.run_segment (segment.Segment: many periods in one call while nothing needs Python)
    against the objects (ctrl.compute + sim.step every period): bit-identical records, statuses and
    impacts; the outcome-only mode (keep_records=False) ends the same way with the same last status."""
    from biped_controller.closed_loop import segment
    runs = []
    orig = segment.Segment.run

    def counting(self, *a, **k):
        out = orig(self, *a, **k)
        runs.append(len(out[0]))
        return out
    monkeypatch.setattr(segment.Segment, "run", counting)
    kw = dict(steps=2, mode=mode, pushes=(push,) if push else (), extra_time_after_steps=extra)
    loop = runner.run(**kw)
    assert sum(runs) > 0.5 * len(loop.records), "the compiled loop must run most periods"
    objects = runner.run(compiled_loop=False, **kw)
    assert_same_run(objects, loop)          # tol 0: bit for bit
    lean = runner.run(keep_records=False, **kw)
    assert len(lean.records) < len(loop.records)
    assert (lean.fallen, lean.fall_cause, lean.fall_time, lean.steps_walked) == \
        (objects.fallen, objects.fall_cause, objects.fall_time, objects.steps_walked)
    assert_same_fields(lean.statuses[-1], objects.statuses[-1], "last status")
    assert_same_fields(lean.records[-1], objects.records[-1], "last record")
    assert [i.t for i in lean.impacts] == [i.t for i in objects.impacts]


def test_compiled_loop_is_off_where_python_must_see_every_period():
    """Perturbed sensors, a torque function (integration rate), the reference engine: no compiled loop."""
    from biped_controller.closed_loop.segment import Segment
    from biped_controller.core.control.controller import AdaptiveController
    from biped_sim.plant.perturbation import PlantPerturbation
    from biped_sim.plant.rigid import Simulator
    ctrl = AdaptiveController(load_controller_config(mode="both"))
    assert Segment.eligible(Simulator(), ctrl)
    assert not Segment.eligible(Simulator(perturbation=PlantPerturbation(noise_q=1e-4, seed=1)), ctrl)
    assert not Segment.eligible(Simulator(config=load_sim_config(engine="reference")), ctrl)
    assert not Segment.eligible(Simulator(), AdaptiveController(load_controller_config(mode="both", engine="reference")))
