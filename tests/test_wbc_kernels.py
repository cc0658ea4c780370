"""The compiled whole-body stage (core/control/wbc_kernels.py) against the Python stage (core/control/wbc.py) and against
independent solvers.

References: the Python stage's rows (``wbc.rows_on_w``) and its held PIQP (``wbc.WholeBodyQP``), quadprog
through qpsolvers, KKT residuals with the full weight M (``test_wbc.kkt_full``: multipliers by NNLS), and
closed-loop runs replayed period by period through a controller running the Python stage. Seeded.
"""
from __future__ import annotations

import numpy as np
import pytest
import qpsolvers

from biped_sim.plant.push import Push
from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.control.controller_compiled import load_wbc_kernels
from biped_controller.core.control.controller_layout import MEMORY, R_, RES, W_, WORK
from biped_controller.core.qp.problem import ACTIVE, INFEASIBLE_FALLBACK, UNCONSTRAINED
from biped_controller.core.control.wbc import NOT_RUN, WBC_ROWS, WholeBodyQP, rows_on_w, weight_matrix
from biped_controller.closed_loop import runner

from helpers import assert_close
from test_wbc import dedupe, kkt_full, real_rows, setting, states, violating_instances  # noqa: F401  (fixture)

MID_STEP = 0.2315


@pytest.fixture(scope="module")
def wk():
    return load_wbc_kernels()


def period_arrays(dyn, dync):
    """WORK and RES rows holding the model terms the stage reads (A, H, B; h_b, h_b,c)."""
    work = np.zeros((WORK.size, 6))
    res = np.zeros(RES.size)
    work[W_.A:W_.A + 6] = dyn.A
    work[W_.H] = dyn.H
    work[W_.B:W_.B + 3] = dyn.B
    res[R_.h_b:R_.h_b + 3] = dyn.h_b
    res[R_.h_b_c:R_.h_b_c + 3] = dync.h_b
    return work, res


def test_compiled_rows_are_the_python_rows_bit_for_bit(setting, wk):  # noqa: F811  (the imported fixture)
    """wbc_kernels.rows (from the controller's CONS array and the period's WORK/RES rows) gives the very bits
    of wbc.rows_on_w, with and without an estimated force, so the two stages take the same early-out
    decision; and both equal the rows written from the Pinocchio model (test_wbc.real_rows) to 1e-9."""
    desc, model, fam, cfg = setting
    ctrl = AdaptiveController(load_controller_config(mode="wbc"))
    st = ctrl.whole_body
    rng = np.random.default_rng(17)
    for q, qd in states(setting, 8, 23):
        G_ref, h_ref, dyn, dync, _ = real_rows(setting, q, qd, F=rng.uniform(-300, 300))
        G_py, h_py = rows_on_w(dyn.A, dyn.H, dyn.B, dyn.h_b, dync.h_b, st.C, st.e, st.margin, st.torque_min,
                               st.torque_max)
        work, res = period_arrays(dyn, dync)
        G, h = np.empty((WBC_ROWS, 6)), np.empty(WBC_ROWS)
        wk.build_rows(ctrl.cons, work, res, G, h)
        assert np.array_equal(G, G_py) and np.array_equal(h, h_py)
        assert_close(G, G_ref, 1e-9, "G", rel=True)
        assert_close(h, h_ref, 1e-9, "h", rel=True)


@pytest.mark.parametrize("torso", [0.0, 1000.0])
def test_active_set_answer_is_the_qp_optimum(setting, wk, torso):  # noqa: F811  (the imported fixture)
    """On 40 real 34-row instances (states near the gait, w* off, seeded): whenever the compiled active-set
    iteration settles, its answer has KKT residuals <= 1e-9 with the full M (multipliers by NNLS) and equals
    the held PIQP's (the Python stage) and quadprog's to 1e-7 relative, with non-negative multipliers on the
    rows it holds active; it settles on every instance PIQP solves as ACTIVE and never on one where no w
    holds every row (least violation: PIQP's job). Negative control: the same iteration run with the metric
    of another weight (M^-1 of the identity) returns a w that fails the stationarity check with M."""
    M = weight_matrix(1.0, torso)
    Minv = np.linalg.inv(M)
    piqp = WholeBodyQP(M)
    settled = 0
    wrong_metric_fails = 0
    for G, h, w_star in violating_instances(setting, 40, 7):
        ref = piqp.solve(G, h, w_star)
        w, lam, S = np.empty(6), np.empty(6), np.empty(6)
        k = wk.solve(G, h, w_star, Minv, w, lam, S)
        if ref.status == INFEASIBLE_FALLBACK:
            assert k < 0, "settled on an instance where no w holds every row"
            continue
        assert ref.status == ACTIVE
        assert k >= 1, "did not settle on a feasible instance"
        settled += 1
        assert np.all(lam[:k] >= 0.0)
        prim, stat, _ = kkt_full(G, h, w_star, M, w)
        assert prim <= 1e-9 * (1 + np.max(np.abs(h))), prim
        assert stat <= 1e-9, stat
        assert_close(w, ref.w, 1e-7, "compiled vs PIQP", rel=True)
        Gu, hu = dedupe(G, h)
        x = qpsolvers.solve_qp(M, -M @ w_star, Gu, hu, solver="quadprog")
        assert_close(w, x, 1e-7, "compiled vs quadprog", rel=True)
        if torso > 0.0:
            w2 = np.empty(6)
            if wk.solve(G, h, w_star, np.eye(6), w2, lam, S) >= 0:
                wrong_metric_fails += kkt_full(G, h, w_star, M, w2)[1] > 1e-6
    assert settled >= 20, f"only {settled} ACTIVE instances: the test would check little"
    if torso > 0.0:
        assert wrong_metric_fails >= 10, "negative control: a wrong metric passed the stationarity check"


def replay(mode, records, python_stage):
    """A fresh controller of ``mode`` (compiled period) fed the recorded (t, q, q', stance) of a run, period by
    period; ``python_stage`` selects the Python stage (wbc.WholeBodyStage) instead of the compiled one."""
    ctrl = AdaptiveController(load_controller_config(mode=mode))
    ctrl.compiled_period.python_stage = python_stage
    ctrl.reset(records[0].stance)
    return [ctrl.compute(r.t, r.q, r.qd, r.stance) for r in records], ctrl


@pytest.mark.parametrize("mode,force", [("wbc", 250.0), ("hybrid", 600.0)])
def test_compiled_stage_equals_python_stage_period_by_period(mode, force):
    """The states of one closed-loop run (compiled loop, compiled stage), fed to two fresh controllers, one
    with the compiled stage and one with the Python stage: in every period the same stage status and the same
    active rows; bit-identical torques, margins and statuses up to the first period where the stage changes
    w (the same compiled period, the same rows to the bit, the same early-out); from there on equal to
    round-off (1e-9 relative: PIQP + polish and the compiled active set reach the same active set's
    optimum by different arithmetic, and the observer carries that w into the next periods). And the run
    itself equals the replay through the compiled stage bit for bit (compiled loop = objects)."""
    run = runner.run(steps=2, mode=mode, pushes=(Push(MID_STEP, 0.025, force, None),))
    recs = [r for r in run.records]
    comp, ctrl = replay(mode, recs, python_stage=False)
    py, _ = replay(mode, recs, python_stage=True)
    first = next(k for k, o in enumerate(py) if o.status.wbc_status not in (UNCONSTRAINED, NOT_RUN))
    changed = sum(o.status.wbc_status not in (UNCONSTRAINED, NOT_RUN) for o in py)
    assert changed >= 2, "the stage changed w in fewer than 2 periods: little compared"
    for k, (a, b) in enumerate(zip(comp, py)):
        sa, sb = a.status, b.status
        assert (sa.wbc_status, sa.wbc_active) == (sb.wbc_status, sb.wbc_active), (k, sa.t)
        assert sa.qp_status == sb.qp_status, (k, sa.t)
        if k < first:
            assert np.array_equal(a.torque, b.torque) and np.array_equal(sa.margins, sb.margins), k
        else:
            assert_close(a.torque, b.torque, 1e-9, f"torque, period {k}", rel=True)
            assert_close(np.asarray(sa.margins), np.asarray(sb.margins), 1e-9 * 1e3, f"margins, period {k}")
            assert sa.wbc_deviation == pytest.approx(sb.wbc_deviation, rel=1e-7, abs=1e-9)
    for k, (o, r, s) in enumerate(zip(comp, run.records, run.statuses)):
        assert np.array_equal(np.clip(o.torque, ctrl.model.torque_min, ctrl.model.torque_max), r.torque), k
        assert (o.status.wbc_status, o.status.wbc_active, o.status.wbc_deviation) == \
            (s.wbc_status, s.wbc_active, s.wbc_deviation), k


@pytest.mark.parametrize("mode,force", [("wbc", 250.0), ("hybrid", 600.0)])
def test_compiled_loop_equals_objects(mode, force):
    """runner.run with the compiled loop (segments with the compiled stage, PIQP periods to the objects)
    and without it (the objects every period): every record and status bit-identical, the stage active in
    some periods. Negative control: the Python stage in the objects (python_stage) gives records that are
    not bit-identical (so the comparison sees a different arithmetic)."""
    pushes = (Push(MID_STEP, 0.025, force, None),)
    a = runner.run(steps=2, mode=mode, pushes=pushes)
    b = runner.run(steps=2, mode=mode, pushes=pushes, compiled_loop=False)
    assert len(a.records) == len(b.records)
    assert sum(s.wbc_status == ACTIVE for s in a.statuses) >= 2
    for ra, rb in zip(a.records, b.records):
        assert np.array_equal(ra.x, rb.x) and np.array_equal(ra.torque, rb.torque), ra.t
    for sa, sb in zip(a.statuses, b.statuses):
        for f in ("wbc_status", "wbc_active", "wbc_deviation", "qp_status", "qp_message", "zmp", "tightest"):
            assert getattr(sa, f) == getattr(sb, f) or (f == "zmp" and np.isnan(sa.zmp) and np.isnan(sb.zmp)), \
                (sa.t, f)
        assert np.array_equal(sa.margins, sb.margins)
    orig = AdaptiveController.__init__

    def python_stage_init(self, *args, **kw):
        orig(self, *args, **kw)
        if self.compiled_period is not None:
            self.compiled_period.python_stage = True
    AdaptiveController.__init__ = python_stage_init
    try:
        c = runner.run(steps=2, mode=mode, pushes=pushes, compiled_loop=False)
    finally:
        AdaptiveController.__init__ = orig
    assert any(not np.array_equal(ra.x, rc.x) for ra, rc in zip(a.records, c.records)), \
        "negative control: the Python stage gave the same bits"


def test_stage_does_not_run_in_hybrid_while_the_adaptation_holds(wk):
    """The kernel's switch: hybrid with a p/tau answer that holds its rows -> NOT_RUN, nothing written
    but the status fields (w, torque, memory unchanged); mode wbc with the same arrays -> the rows are
    checked (UNCONSTRAINED or a change)."""
    ctrl = AdaptiveController(load_controller_config(mode="hybrid"))
    q, qd = ctrl.family.initial_state()
    ctrl.compute(0.0, q, qd, 0)
    work = np.zeros((WORK.size, 6))
    res = np.zeros(RES.size)
    fam = ctrl.family
    dyn = ctrl.model.dynamics(q, qd)
    work[W_.A:W_.A + 6], work[W_.H], work[W_.B:W_.B + 3] = dyn.A, dyn.H, dyn.B
    res[R_.h_b:R_.h_b + 3] = res[R_.h_b_c:R_.h_b_c + 3] = dyn.h_b
    work[W_.w] = fam.evaluate(fam.p_d, 0.0).d2q_dtau2 + 1e4      # far outside the rows
    mem0, work0 = ctrl.memory.copy(), work.copy()
    G, h = np.empty((WBC_ROWS, 6)), np.empty(WBC_ROWS)
    code = wk.stage(ctrl.wbc, ctrl.cons, ctrl.memory, work, res, G, h, False)
    assert code == wk.UNCHANGED and res[R_.wbc_status] == NOT_RUN
    assert np.array_equal(ctrl.memory, mem0) and np.array_equal(work, work0)
    code = wk.stage(ctrl.wbc, ctrl.cons, ctrl.memory, work, res, G, h, True)
    assert code in (wk.SOLVED, wk.NEEDS_PIQP)
    if code == wk.SOLVED:
        assert res[R_.wbc_status] == ACTIVE and not np.array_equal(work[W_.w], work0[W_.w])
        assert np.array_equal(ctrl.memory[MEMORY.slice("prev_w")], work[W_.w])
    else:
        assert np.array_equal(ctrl.memory, mem0) and np.array_equal(work, work0)


def test_piqp_answers_when_no_w_holds_every_row():
    """Torque limits shrunk to +-5 N m (gravity alone needs more): no w holds every row, the compiled active
    set does not settle, the held PIQP gives the least-violation answer (INFEASIBLE_FALLBACK) and
    wbc_kernels.apply takes it: the same status, active rows and torque (to round-off) as the Python stage
    on the same period, and the counter says PIQP answered. Negative control: with the real limits the same
    period is answered by the compiled stage without PIQP."""
    def shrunk(python_stage):
        ctrl = AdaptiveController(load_controller_config(mode="wbc"))
        ctrl.compiled_period.python_stage = python_stage
        from biped_controller.core.control.controller_layout import CONS
        ctrl.cons[CONS.slice("torque_min")] = -5.0
        ctrl.cons[CONS.slice("torque_max")] = 5.0
        ctrl.whole_body.torque_min = np.full(6, -5.0)
        ctrl.whole_body.torque_max = np.full(6, 5.0)
        return ctrl
    fam = AdaptiveController(load_controller_config(mode="wbc")).family
    q, qd = fam.initial_state()
    a, b = shrunk(False), shrunk(True)
    oa, ob = a.compute(0.0, q, qd, 0), b.compute(0.0, q, qd, 0)
    assert oa.status.wbc_status == ob.status.wbc_status == INFEASIBLE_FALLBACK
    assert oa.status.wbc_active == ob.status.wbc_active
    assert_close(oa.torque, ob.torque, 1e-9, "torque", rel=True)
    assert a.compiled_period.stage_counts["piqp"] == 1 and a.compiled_period.stage_counts["solved"] == 0
    c = AdaptiveController(load_controller_config(mode="wbc"))
    c.compute(0.0, q, qd, 0)
    assert c.compiled_period.stage_counts["piqp"] == 0
