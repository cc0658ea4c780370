"""Closed loop (runner.run: Simulator + AdaptiveController) and the simulator's own checks.

(a) undisturbed, controller at the integration rate: the simulator's contact force equals the
    controller's predicted reaction, and the tracking error stays tiny through impacts;
(b) a push the classical computed torque (mode none) cannot survive makes the simulator report the
    physically right cause (forward push -> the centre of pressure runs to the toe; backward -> heel);
(c) the adaptation QP's answers recorded in a hard run satisfy the KKT conditions, and the infeasible
    instances (checked independently with scipy's linprog) are exactly those reported INFEASIBLE_FALLBACK;
(d) the same inputs give bit-identical records;
(e) the simulator's push validation, fall checks on synthetic wrenches, and the relabelling at impact.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog

from helpers import assert_close, assert_same_run

from biped_model.description import LEFT, RIGHT, load_description
from biped_sim.plant.push import Rejected
from biped_sim.plant.config import load_sim_config
from biped_sim.plant.rigid import Simulator
from biped_controller.closed_loop import runner
from biped_controller.core.control.config import load_controller_config
from biped_model.gait_family import GaitFamily
from biped_model.fixed_foot import relabel
from biped_controller.core.qp.solver import ACTIVE, INFEASIBLE_FALLBACK, SOLVER_ERROR, UNCONSTRAINED, kkt_residuals
from biped_sim.plant.push import Push

FAM = GaitFamily.load()
PUSH_START = 0.5 * FAM.T        # the middle of the first step (paper)
PUSH_DURATION = 0.025           # paper
FOOT = load_description().foot
FAM_L_MIN, FAM_L_MAX = FOOT.l_min, FOOT.l_max   # the sole: heel and toe [m] from the ankle


@pytest.fixture(scope="module")
def ideal_run():
    """3 undisturbed steps, controller at the integration rate. The disturbance observer is OFF here: at
    the integration rate the torque changes inside a period, so the observer's one-period residual
    A (a_measured - w_commanded) is not exactly zero and it reports a spurious force of a few 0.01 N,
    which moves the predicted reaction away from the simulator's (measured: 1.5e-2 N with the observer
    on, 9e-12 N with it off)."""
    cfg = load_controller_config(mode="both", disturbance_observer=False)
    # 50 ms past the third impact, so that every impact is followed by an observation
    return runner.run(steps=3, mode="both", integration_rate=True, ctrl_config=cfg, extra_time_after_steps=0.05)


# ------------------------------------------------------------------ (a)
def test_reaction_matches_prediction(ideal_run):
    r = ideal_run
    assert not r.fallen and r.steps_walked == 3, (r.fall_cause, r.fall_detail)
    d = np.array([np.max(np.abs(rec.wrench[:2] - st.predicted_reaction)) for rec, st in zip(r.records, r.statuses)])
    k = int(np.argmax(d))
    assert d[k] < 1e-6, (f"simulator contact force vs controller's predicted reaction: {d[k]:.3e} N at "
                         f"t = {r.records[k].t:.4f} s ({r.records[k].wrench[:2]} vs {r.statuses[k].predicted_reaction})")


def test_tracking_error_through_impacts(ideal_run):
    r = ideal_run
    assert len(r.impacts) == 3
    err = np.array([s.max_tracking_error for s in r.statuses])
    k = int(np.argmax(err))
    # measured 1.6e-8 rad (after the impacts; 9e-11 rad before the first one)
    assert err[k] < 1e-6, f"tracking error {err[k]:.3e} rad at t = {r.records[k].t:.4f} s"
    # the controller never had to adapt: the preferred gait satisfies every constraint
    assert {s.qp_status for s in r.statuses} == {UNCONSTRAINED}
    assert all(s.p == FAM.p_d and s.tau_dot == 1.0 for s in r.statuses)


# ------------------------------------------------------------------ (b)
@pytest.mark.parametrize("force", [400.0, -400.0], ids=["forward", "backward"])
def test_push_fall_cause_is_physical(force):
    """Mode none tracks the preferred gait whatever the push: the joint accelerations (hence the centre of
    mass acceleration and the angular momentum rate about the stance ankle) are imposed, so the ground must
    supply the moment that cancels the push's. A push +F (forward) at height H above the ankle adds
    -F H (clockwise, forward-tipping) to the moment about the ankle; the ground's moment m = l R_y must grow
    by +F H: l moves toward the toe. A backward push moves it toward the heel. With 400 N at ~1.1 m and
    R_y ~ 400 N, l shifts by ~1 m >> 0.1 m: the foot tips over within the push, over the toe (forward) or the
    heel (backward). (The horizontal force shifts by -F too, but |F_x| stays below mu R_y for longer.)"""
    r = runner.run(steps=2, mode="none", pushes=(Push(PUSH_START, PUSH_DURATION, force),))
    assert r.fallen
    assert PUSH_START <= r.fall_time <= PUSH_START + PUSH_DURATION, r.fall_time
    last = r.records[-1]
    assert last.fallen and last.fall_cause == r.fall_cause
    l_before = next(rec.cop for rec in reversed(r.records) if rec.t < PUSH_START)
    during = [rec.cop for rec in r.records if PUSH_START <= rec.t]
    l = last.wrench[2] / last.wrench[1]
    assert last.wrench[1] > 0
    if force > 0:
        assert r.fall_cause == "tip_toe", (r.fall_cause, r.fall_detail)
        assert l > FAM_L_MAX and max(during) > l_before
    else:
        assert r.fall_cause == "tip_heel", (r.fall_cause, r.fall_detail)
        assert l < FAM_L_MIN and min(during) < l_before
    assert last.push_force == force


# ------------------------------------------------------------------ (c)
@pytest.fixture(scope="module")
def hard_run():
    """Mode both, a push beyond what it survives (600 N forward): the QP is active for many periods and
    infeasible at the end."""
    return runner.run(steps=2, mode="both", pushes=(Push(PUSH_START, PUSH_DURATION, 600.0),), keep_qp=True)


def test_qp_answers_satisfy_kkt(hard_run):
    r = hard_run
    assert len(r.qp_instances) == len(r.statuses)  # mode both: one QP per period
    cfg = load_controller_config(mode="both")
    W = np.array([cfg.weight_p, cfg.weight_tau])
    counts = {}
    worst = 0.0
    for (G, h, xs, status), st in zip(r.qp_instances, r.statuses):
        assert status == st.qp_status
        counts[status] = counts.get(status, 0) + 1
        assert status != SOLVER_ERROR, st.qp_message
        x = np.array([st.p_ddot, st.tau_ddot])
        if status == UNCONSTRAINED:
            assert np.array_equal(x, xs)
        if status in (UNCONSTRAINED, ACTIVE):
            k = kkt_residuals(G, h, xs, W, x)
            worst = max(worst, k["primal"], k["dual"], k["complementarity"], k["stationarity"])
            assert max(k["primal"], k["dual"], k["complementarity"], k["stationarity"]) < 1e-6, (st.t, k)
    assert counts.get(ACTIVE, 0) > 0, counts


def test_qp_infeasible_instances_reported(hard_run):
    r = hard_run
    n_inf = 0
    for (G, h, xs, status), st in zip(r.qp_instances, r.statuses):
        lp = linprog(np.zeros(G.shape[1]), A_ub=G, b_ub=h, bounds=[(None, None)] * G.shape[1], method="highs")
        assert lp.status in (0, 2), lp.message
        infeasible = lp.status == 2
        n_inf += infeasible
        assert infeasible == (status == INFEASIBLE_FALLBACK), (
            f"t = {st.t:.4f}: linprog {'infeasible' if infeasible else 'feasible'} but status {status} ({st.qp_message})")
    assert n_inf >= 1, "the hard run never made the QP infeasible (choose a harder push)"


# ------------------------------------------------------------------ (d)
def test_bit_identical_runs():
    args = dict(steps=1, mode="both", pushes=(Push(PUSH_START, PUSH_DURATION, 250.0),))
    a = runner.run(**args)
    b = runner.run(**args)
    assert a.steps_walked == 1 and not a.fallen
    assert_same_run(a, b)


# ------------------------------------------------------------------ (e)
@pytest.fixture
def sim():
    s = Simulator(config=load_sim_config())
    q0, qd0 = FAM.initial_state()
    s.reset(q0, qd0, LEFT)
    return s


@pytest.mark.parametrize("kw,field", [
    (dict(start=0.1, duration=0.02, force=math.nan), "force"),
    (dict(start=0.1, duration=0.02, force=math.inf), "force"),
    (dict(start=math.nan, duration=0.02, force=100.0), "start"),
    (dict(start=0.1, duration=-0.01, force=100.0), "duration"),
    (dict(start=0.1, duration=0.0, force=100.0), "duration"),
    (dict(start=0.1, duration=math.nan, force=100.0), "duration"),
    (dict(start=0.1, duration=0.02, force=100.0, height=1.0), "height"),
    (dict(start=0.1, duration=0.02, force=100.0, height=-0.05), "height"),
    (dict(start=0.1, duration=0.02, force=100.0, height=math.inf), "height"),
])
def test_bad_push_rejected(sim, kw, field):
    good = sim.schedule_push(0.05, 0.01, 50.0)
    before = list(sim.pushes)
    next_id = sim.book.next_id
    with pytest.raises(Rejected) as exc:
        sim.schedule_push(**kw)
    assert field in str(exc.value), str(exc.value)
    assert sim.pushes == before and sim.pushes[0] is good and sim.book.next_id == next_id


def test_good_push_scheduled(sim):
    p = sim.schedule_push(0.1, 0.02, 120.0)
    assert p.height == sim.cfg.push_height and p.end == pytest.approx(0.12)
    q = sim.schedule_push(0.2, 0.02, -80.0, height=0.6)
    assert sim.pushes == [p, q] and q.id > p.id
    assert sim.push_force_at(0.11) == [(120.0, sim.cfg.push_height)] and sim.push_force_at(0.1201) == []


@pytest.mark.parametrize("w,cause", [
    ([0.0, -1.0, 0.0], "take_off"),
    ([0.0, 0.0, 0.0], "take_off"),
    ([80.0, 100.0, 0.0], "slip"),        # mu = 0.7: |F_x| = 80 > 70
    ([-80.0, 100.0, 0.0], "slip"),
    ([0.0, 100.0, -10.5], "tip_heel"),   # l = -0.105 < -0.1
    ([0.0, 100.0, 10.5], "tip_toe"),     # l = 0.105 > 0.1
    ([math.nan, 100.0, 0.0], "numerical"),
    ([69.0, 100.0, 9.9], None),          # inside the cone, l = 0.099
    ([-69.0, 100.0, -9.9], None),
])
def test_check_wrench(sim, w, cause):
    f = sim._check_wrench(np.array(w), 0.5)
    if cause is None:
        assert f is None
    else:
        assert f is not None and f.cause == cause and f.t == 0.5, f
    if cause == "slip":
        assert ("forward" in f.detail) == (w[0] > 0)


def test_relabel_at_impact(ideal_run):
    """At every impact the controller sees the new stance in the very next observation, resets tau to 0,
    and the relabelled measured state is the start of the preferred step (tracking error ~ 0)."""
    r = ideal_run
    idx = [k for k in range(1, len(r.records)) if r.records[k].stance != r.records[k - 1].stance]
    assert len(idx) == 3
    for n, k in enumerate(idx):
        rec, st, prev = r.records[k], r.statuses[k], r.statuses[k - 1]
        assert rec.stance == st.stance == (RIGHT if n % 2 == 0 else LEFT)
        assert r.impacts[n].new_stance == rec.stance and rec.impacts == n + 1
        assert st.tau == 0.0 and prev.tau > 0.9 * FAM.T
        assert rec.t == pytest.approx(r.impacts[n].t, abs=1e-12)   # event-triggered update at the impact
        g = FAM.evaluate(st.p, 0.0)
        assert_close(rec.q, g.q, 1e-6, f"impact {n}: relabelled q vs q_d(p, 0)")
        assert_close(rec.qd, g.dq_dtau, 1e-5, f"impact {n}: post-impact q' vs q_d'(p, 0)")
        # the posture is continuous through the impact: q+ = relabel(q-) with q- the pre-impact posture
        q_pre = FAM.evaluate(FAM.p_d, FAM.T).q
        assert_close(rec.q, relabel(q_pre), 1e-6, f"impact {n}: q+ vs relabel(q_d(p_d, T))")


def test_no_liftoff_fall_ends_the_period_at_its_instant():
    """A released foot driven into the ground before it clears: the no_liftoff fall is dated at the end
    of the integration interval where it sank too deep, and the period (and the state) stop there."""
    from biped_model.gait_family import GaitFamily
    from biped_sim.plant.rigid import Simulator
    q, qd = GaitFamily.load().initial_state()
    sim = Simulator()
    qd2 = qd.copy()
    qd2[3] += 20.0          # the swing hip swung forward hard right after the impact: the released toe digs in
    sim.reset(q, qd2, 0)
    rec = sim.step(np.zeros(6))
    assert sim.fall is not None and sim.fall.cause == "no_liftoff", sim.fall
    assert rec.fallen and rec.fall_cause == "no_liftoff"
    assert rec.t_end == sim.fall.t == sim.t
    assert 0.0 < rec.t_end < sim.cfg.control_period   # the first interval, not the grid end
