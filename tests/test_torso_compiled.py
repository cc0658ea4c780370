"""The torso parameter lambda on the compiled paths: the compiled controller period
(``controller_kernels``, modes lambda and all) against the controller's own Python steps, and the compiled
closed loop (``segment`` + ``loop_kernels``) against the objects, over a walk, pushes that make the QP
active (and one whose QP has no answer: the least-violation answer and the torso's hold) and a fall."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import assert_same_fields, assert_same_run, count_compiled_periods
from biped_controller.core.control import controller as C
from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.control.controller_layout import G_, TORSO_QP_ROWS
from biped_controller.core.qp.problem import ACTIVE, INFEASIBLE_FALLBACK, UNCONSTRAINED
from biped_controller.closed_loop import runner, segment
from biped_sim.plant.push import Push
from biped_model.gait_family import torso_profile

CASES = {"walk": (), "push": (Push(0.2315, 0.025, 500.0),), "back": (Push(0.2315, 0.025, -1200.0),),
         "fall": (Push(0.2, 0.1, 1500.0),)}


def _python_steps(monkeypatch, **kw):
    """The run on the controller's Python steps (the compiled period switched off for this run only)."""
    with monkeypatch.context() as m:
        m.setattr(C.CompiledPeriod, "compute", lambda self, *a: None)
        return runner.run(compiled_loop=False, **kw)


def _compiled(monkeypatch, **kw):
    """The run on the compiled period (objects loop); asserts the compiled period served every period."""
    with monkeypatch.context() as m:
        used = count_compiled_periods(m)
        res = runner.run(compiled_loop=False, **kw)
    assert used and all(used), "the compiled period must serve every period of a finite run"
    return res


def test_compiled_torso_profile_is_the_gait_familys():
    ck = C.load_controller_kernels()
    for s in (-0.1, 0.0, 1e-9, 0.13, 0.5, 0.77, 1.0 - 1e-12, 1.0, 1.4):
        assert ck.torso_profile(s) == torso_profile(s), s


def test_torso_modes_have_a_compiled_period_and_the_compiled_loop():
    from biped_sim.plant.config import load_sim_config
    from biped_sim.plant.protocol import make_plant
    for mode in C.TORSO_MODES:
        ctrl = AdaptiveController(load_controller_config(mode=mode))
        fp = ctrl.compiled_period
        assert fp is not None and fp.G.shape == (TORSO_QP_ROWS, 3) and fp.nx == 3
        assert ctrl.gains[G_.torso] == 1.0 and ctrl.gains[G_.adapt_lam] == 1.0
        assert ctrl.gains[G_.adapt_p] == float(mode == "all")
        sim = make_plant("rigid", ctrl.desc, load_sim_config())
        assert segment.Segment.eligible(sim, ctrl)
    both = AdaptiveController(load_controller_config(mode="both"))
    assert both.gains[G_.torso] == 0.0 and both.compiled_period.G.shape[1] == 2
    # real sensing keeps the Python steps in the torso modes (no compiled sensing with lambda)
    sensed = AdaptiveController(load_controller_config(mode="all", delay_compensation=1))
    assert sensed.compiled_period is None


@pytest.mark.parametrize("mode", ["all", "lambda"])
@pytest.mark.parametrize("case", list(CASES))
def test_compiled_torso_period_matches_its_python_steps(monkeypatch, mode, case):
    """controller_kernels.step with the third column against the Python steps on the same compiled model
    terms: the same QP status every period and the same run to 1e-9 (relative), lambda fields included."""
    kw = dict(steps=2, mode=mode, pushes=CASES[case])
    fast = _compiled(monkeypatch, **kw)
    steps = _python_steps(monkeypatch, **kw)
    st = [s.qp_status for s in steps.statuses]
    assert st == [s.qp_status for s in fast.statuses]
    if case != "walk":
        assert st.count(ACTIVE) > 0, "the push must make the QP active"
        assert max(abs(s.lam) for s in steps.statuses) > 1e-3, "lambda must move"
    else:
        assert set(st) == {UNCONSTRAINED}
    assert steps.fallen == (case == "fall" or (mode == "lambda" and case in ("push", "back")))
    assert_same_run(steps, fast, tol=1e-9, skip_status=("qp_message",), relative=True)


def test_an_infeasible_qp_and_the_torso_hold_on_the_compiled_period(monkeypatch):
    """Mode lambda under a 500 N forward push: the QP has no answer (least-violation answer, then lambda''
    held to the torso's range); both paths give the same statuses, messages and run."""
    kw = dict(steps=2, mode="lambda", pushes=CASES["push"])
    fast = _compiled(monkeypatch, **kw)
    steps = _python_steps(monkeypatch, **kw)
    assert any(s.qp_status == INFEASIBLE_FALLBACK for s in steps.statuses)
    assert [s.qp_message for s in fast.statuses] == [s.qp_message for s in steps.statuses]
    assert_same_run(steps, fast, tol=1e-9, relative=True)


def test_negative_control_a_wrong_lambda_gain_in_the_kernel_is_seen(monkeypatch):
    """The comparison above can fail: the compiled period with kp_lambda changed in its GAINS array only
    (the Python steps keep the config's) gives another run."""
    orig = AdaptiveController._gains

    def wrong(self):
        g = orig(self)
        g[G_.kp_lam] *= 1.5
        return g
    kw = dict(steps=2, mode="all", pushes=CASES["back"])
    steps = _python_steps(monkeypatch, **kw)
    with monkeypatch.context() as m:
        m.setattr(AdaptiveController, "_gains", wrong)
        fast = _compiled(monkeypatch, **kw)
    with pytest.raises(AssertionError):
        assert_same_run(steps, fast, tol=1e-9, skip_status=("qp_message",), relative=True)


@pytest.mark.parametrize("mode", ["all", "lambda"])
@pytest.mark.parametrize("case", ["walk", "back", "fall"])
def test_compiled_loop_takes_the_torso_modes_bit_for_bit(monkeypatch, mode, case):
    """loop_kernels.run_segment in modes lambda and all against the objects (ctrl.compute + sim.step every
    period): identical records, statuses (lambda fields included) and impacts; the compiled loop runs most
    periods, the QP periods included (decided between two calls)."""
    runs, decided = [], []
    orig_run, orig_decide = segment.Segment.run, segment.Segment.decide

    def counting(self, *a, **k):
        out = orig_run(self, *a, **k)
        runs.append(len(out[0]))
        return out

    def deciding(self):
        out = orig_decide(self)
        decided.append(out is not None)
        return out
    kw = dict(steps=2, mode=mode, pushes=CASES[case])
    with monkeypatch.context() as m:
        m.setattr(segment.Segment, "run", counting)
        m.setattr(segment.Segment, "decide", deciding)
        loop = runner.run(**kw)
    objects = runner.run(compiled_loop=False, **kw)
    assert sum(runs) > 0.5 * len(loop.records), "the compiled loop must run most periods"
    if case != "walk":
        assert sum(decided) > 0, "QP periods decided for the compiled loop"
        assert max(abs(s.lam) for s in loop.statuses) > 1e-3
    assert_same_run(objects, loop)          # tol 0: bit for bit
    lean = runner.run(keep_records=False, **kw)     # outcome only (the sweeps' setting): same end, same last status
    assert len(lean.records) < len(loop.records)
    assert (lean.fallen, lean.fall_cause, lean.fall_time, lean.steps_walked) == \
        (objects.fallen, objects.fall_cause, objects.fall_time, objects.steps_walked)
    assert_same_fields(lean.statuses[-1], objects.statuses[-1], "last status")
    assert_same_fields(lean.records[-1], objects.records[-1], "last record")


def test_negative_control_the_loop_comparison_sees_a_different_push():
    """The bit-for-bit comparison above can fail: the same run with a push 1e-6 N stronger differs."""
    a = runner.run(steps=2, mode="all", pushes=(Push(0.2315, 0.025, -1200.0),))
    b = runner.run(steps=2, mode="all", pushes=(Push(0.2315, 0.025, -1200.000001),), compiled_loop=False)
    with pytest.raises(AssertionError):
        assert_same_run(a, b)



def test_begin_advances_lambda_exactly_and_commit_keeps_it():
    """period_start: lambda(h) = lambda + lambda' h + lambda'' h^2 / 2, lambda'(h) = lambda' + lambda'' h over the
    elapsed integer nanoseconds, against exact rational arithmetic, carried over an impact (tau restarts,
    lambda does not); lambda'' and lambda''* of the new period start at 0; period_commit stores lambda, lambda'
    and the period's lambda''. Negative control: before any decision nothing advances."""
    from fractions import Fraction
    from biped_controller.core.control.controller_layout import M_, MEMORY, R_, RES, WORK
    ck = C.load_controller_kernels()
    mem = MEMORY.new()
    mem[M_.p:M_.p + 6] = (0.4, 0.0, 0.2, 1.0, 0.0, 0.0)
    mem[M_.lam], mem[M_.lam_dot], mem[M_.lam_ddot] = 0.0123, -0.456, 7.89
    mem[M_.decided], mem[M_.t_last], mem[M_.stance] = 1.0, 1.0, 0
    t = 1.0 + 987654e-9
    gains = AdaptiveController(load_controller_config(mode="all")).gains
    for stance in (0, 1):
        res = np.full(RES.size, np.nan)
        ck.begin(mem, gains, t, stance, res)
        h = Fraction(round(t * 1e9) - round(1.0 * 1e9), 10**9)
        lam, ld, ldd = (Fraction(float(v)) for v in (mem[M_.lam], mem[M_.lam_dot], mem[M_.lam_ddot]))
        for got, want in ((res[R_.lam], lam + ld * h + ldd * h * h / 2), (res[R_.lam + 1], ld + ldd * h)):
            assert abs(Fraction(float(got)) - want) <= Fraction(1, 10**15) * max(1, abs(want))
        assert res[R_.x + 2] == 0.0 and res[R_.x_star + 2] == 0.0
        assert (res[R_.tau] == 0.0) == (stance == 1)
    res[R_.x + 2] = -3.5
    mem2 = mem.copy()
    ck.commit(mem2, res, np.zeros((WORK.size, 6)), np.zeros(6), t, 1)
    assert (mem2[M_.lam], mem2[M_.lam_dot], mem2[M_.lam_ddot]) == (res[R_.lam], res[R_.lam + 1], -3.5)
    mem[M_.decided] = 0.0
    ck.begin(mem, gains, t, 0, res)
    assert (res[R_.lam], res[R_.lam + 1]) == (mem[M_.lam], mem[M_.lam_dot])
