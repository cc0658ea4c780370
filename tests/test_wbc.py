"""Whole-body QP (core/control/wbc.py) and the modes `wbc` and `hybrid` of the controller.

References independent of the code under test: quadprog and DAQP through qpsolvers (other solvers than
the PIQP the product holds), scipy's minimiser for the least-violation answer, KKT residuals with the full
(non-diagonal) weight M, and the recorded margins of closed-loop runs. Randomness is seeded.
"""
from __future__ import annotations

import numpy as np
import pytest
import qpsolvers
from scipy.optimize import minimize, nnls

from biped_model.description import load_description
from biped_model.fixed_foot import N_CONSTRAINTS, FixedFootModel, contact_rows
from biped_model.gait_family import GaitFamily
from biped_controller.core.control.config import load_controller_config
from biped_controller.core.qp.problem import ACTIVE, INFEASIBLE_FALLBACK, UNCONSTRAINED, QPShapeError
from biped_controller.core.control.wbc import (
    TORSO_PITCH_ROW,
    WBC_ROWS,
    WBCError,
    WholeBodyQP,
    rows_hold,
    rows_on_w,
    weight_matrix,
)

from helpers import assert_close


@pytest.fixture(scope="module")
def setting():
    desc = load_description()
    return desc, FixedFootModel(desc), GaitFamily.load(), load_controller_config()


def real_rows(setting, q, qd, F=0.0, height=0.3125):
    """The 34 rows at (q, q') with the controller's margins, written here from the Pinocchio model's
    constraint matrices (FixedFootModel.constraints), not from rows_on_w; F [N] a horizontal torso force
    shifting the reaction drift of the first block (as the observer does)."""
    desc, model, fam, cfg = setting
    dyn = model.dynamics(q, qd)
    mu = cfg.margin_friction * model.mu
    lm, lM = model.l_min + cfg.margin_zmp, model.l_max - cfg.margin_zmp
    margin = np.concatenate([[cfg.margin_normal_force, 0, 0, 0, 0], np.full(12, cfg.margin_torque)])
    cm0 = model.constraints(q, qd, dyn, mu=mu, l_min=lm, l_max=lM)
    Jp = model.torso_point_jacobian(q, height)[0]
    delta = dyn.B @ np.linalg.solve(dyn.A, Jp[3:] * F) - Jp[:3] * F
    from dataclasses import replace
    dync = replace(dyn, h_b=dyn.h_b + delta)
    cmc = model.constraints(q, qd, dync, mu=mu, l_min=lm, l_max=lM)
    G = np.vstack([cmc.A_q, cm0.A_q])
    h = np.concatenate([-(cmc.b_q + margin), -(cm0.b_q + margin)])
    return G, h, dyn, dync, (mu, lm, lM, margin)


def states(setting, n, seed):
    """n states near the family's gait (seeded): q, q' of a point of the step, perturbed."""
    desc, model, fam, cfg = setting
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        tau = rng.uniform(0.0, fam.T)
        g = fam.evaluate(fam.p_d, tau)
        q = g.q + rng.normal(scale=0.05, size=6)
        qd = g.dq_dtau + rng.normal(scale=0.3, size=6)
        out.append((q, qd))
    return out


def kkt_full(G, h, w_star, M, w, tol_active=1e-7):
    """KKT residuals of w for min 1/2 (w-w*)' M (w-w*) s.t. G w <= h with the full M (z by NNLS over the
    active rows): (primal, stationarity relative to |M (w - w*)|, z)."""
    v = G @ w - h
    grad = M @ (w - w_star)
    act = np.flatnonzero(v >= -tol_active * (1 + np.abs(h)))
    z = np.zeros(G.shape[0])
    if act.size:
        z[act], _ = nnls(G[act].T, -grad)
    stat = np.max(np.abs(grad + G.T @ z)) / max(1.0, np.max(np.abs(grad)))
    return float(max(np.max(v), 0.0)), float(stat), z


# ----------------------------------------------------------------------------------------
# rows, weight
# ----------------------------------------------------------------------------------------


def test_rows_on_w_equal_the_model_rows(setting):
    """rows_on_w (from A, H, B, h_b and contact_rows) equals the rows written from the Pinocchio model's
    eq. (10) matrices, with and without an estimated force; and they are eq. (10) evaluated through
    inverse dynamics (RNEA) at a random w."""
    desc, model, fam, cfg = setting
    rng = np.random.default_rng(3)
    for q, qd in states(setting, 5, 11):
        G_ref, h_ref, dyn, dync, (mu, lm, lM, margin) = real_rows(setting, q, qd, F=rng.uniform(-300, 300))
        C, e = contact_rows(mu, lm, lM)
        G, h = rows_on_w(dyn.A, dyn.H, dyn.B, dyn.h_b, dync.h_b, C, e, margin, model.torque_min, model.torque_max)
        assert_close(G, G_ref, 1e-9, "G", rel=True)
        assert_close(h, h_ref, 1e-9, "h", rel=True)
        w = rng.normal(scale=20.0, size=6)
        gam, r = model.inverse_dynamics(q, qd, w)
        vals = np.concatenate([C @ r[:2] + e * gam[0], gam - model.torque_max, model.torque_min - gam]) + margin
        assert_close((G @ w - h)[N_CONSTRAINTS:], vals, 1e-7, "second block = eq. (10) by RNEA", rel=True)


def test_weight_matrix_and_its_errors():
    M = weight_matrix(1.0, 4.0)
    w = np.array([0.1, -0.2, 0.3, 1.0, 2.0, 3.0])
    assert np.isclose(w @ M @ w, w @ w + 4.0 * (TORSO_PITCH_ROW @ w) ** 2)
    for bad in ((0.0, 1.0), (-1.0, 0.0), (float("nan"), 0.0), (True, 0.0)):
        with pytest.raises(WBCError, match="wbc_weight_joint"):
            weight_matrix(*bad)
    with pytest.raises(WBCError, match="wbc_weight_torso"):
        weight_matrix(1.0, -0.5)
    with pytest.raises(QPShapeError):
        WholeBodyQP(np.eye(5))
    with pytest.raises(WBCError, match="positive definite"):
        WholeBodyQP(np.diag([1.0, 1, 1, 1, 1, -1]))


# ----------------------------------------------------------------------------------------
# the QP against independent solvers
# ----------------------------------------------------------------------------------------


def violating_instances(setting, n, seed):
    """Real rows at states near the gait, w* pushed off so that rows are violated (seeded)."""
    rng = np.random.default_rng(seed)
    out = []
    for q, qd in states(setting, n, seed):
        G, h, *_ = real_rows(setting, q, qd, F=rng.uniform(-400, 400))
        w_star = rng.normal(scale=60.0, size=6)
        out.append((G, h, w_star))
    return out


def dedupe(G, h):
    """The same feasible set without repeated rows (each G row once, with its least h): quadprog cycles on
    the torque rows, which the 34 rows state twice."""
    keep = {}
    for i, g in enumerate(G):
        k = g.tobytes()
        if k not in keep or h[i] < h[keep[k]]:
            keep[k] = i
    idx = sorted(keep.values())
    return G[idx], h[idx]


@pytest.mark.parametrize("torso", [0.0, 10.0])
def test_kkt_and_answer_against_quadprog_and_daqp(setting, torso):
    """On 30 real 34-row instances (states near the gait, w* off), the held-PIQP WBC answer has KKT
    residuals <= 1e-7 with the full M and equals quadprog's and DAQP's (through qpsolvers) to 1e-6."""
    M = weight_matrix(1.0, torso)
    wbc = WholeBodyQP(M)
    n_active = 0
    for G, h, w_star in violating_instances(setting, 30, 5):
        r = wbc.solve(G, h, w_star)
        if r.status == INFEASIBLE_FALLBACK:
            continue
        n_active += r.status == ACTIVE
        prim, stat, z = kkt_full(G, h, w_star, M, r.w)
        scale = 1e-9 * (1 + np.max(np.abs(h)))
        assert prim <= scale, f"primal {prim}"
        assert stat <= 1e-7, f"stationarity {stat}"
        Gu, hu = dedupe(G, h)
        for solver in ("quadprog", "daqp"):
            x = qpsolvers.solve_qp(M, -M @ w_star, Gu, hu, solver=solver)
            assert x is not None, solver
            assert_close(r.w, x, 1e-6, f"WBC vs {solver}", rel=True)
        assert r.deviation == pytest.approx(np.linalg.norm(r.w - w_star))
        assert np.array_equal(r.active, (G @ r.w - h >= -1e-8)[:17] | (G @ r.w - h >= -1e-8)[17:])
    assert n_active >= 20, f"only {n_active} ACTIVE instances: the test would check little"


def test_feasible_target_is_returned_bit_for_bit(setting):
    """w* inside every row: w = w* (same bits), UNCONSTRAINED, no solver call."""
    M = weight_matrix(1.0, 1.0)
    wbc = WholeBodyQP(M)
    desc, model, fam, cfg = setting
    q, qd = fam.initial_state()
    G, h, *_ = real_rows(setting, q, qd)
    # the tracking law's acceleration of the nominal gait: feasible with the controller's margins
    w_star = fam.evaluate(fam.p_d, 0.0).d2q_dtau2.copy()
    assert rows_hold(G, h, w_star)
    calls = wbc.qp.calls
    r = wbc.solve(G, h, w_star)
    assert r.status == UNCONSTRAINED and np.array_equal(r.w, w_star) and r.deviation == 0.0
    assert wbc.qp.calls == calls


def test_least_violation_when_rows_cannot_all_hold(setting):
    """Torque limits shrunk to +-5 N m: no w holds every row (gravity alone needs more); the answer is the
    least-violation one, argmin sum max(G w - h, 0)^2 + eps (w-w*)' M (w-w*), checked against scipy's
    minimiser of that function (eps -> 0 limit: equal violation cost, w within 1e-4 relative)."""
    desc, model, fam, cfg = setting
    q, qd = fam.initial_state()
    dyn = model.dynamics(q, qd)
    mu = cfg.margin_friction * model.mu
    C, e = contact_rows(mu, model.l_min + cfg.margin_zmp, model.l_max - cfg.margin_zmp)
    margin = np.concatenate([[cfg.margin_normal_force, 0, 0, 0, 0], np.zeros(12)])
    G, h = rows_on_w(dyn.A, dyn.H, dyn.B, dyn.h_b, dyn.h_b, C, e, margin, np.full(6, -5.0), np.full(6, 5.0))
    M = weight_matrix(1.0, 2.0)
    w_star = np.zeros(6)
    r = WholeBodyQP(M).solve(G, h, w_star)
    assert r.status == INFEASIBLE_FALLBACK and r.max_violation > 1.0

    def V(w):
        return float(np.sum(np.maximum(G @ w - h, 0.0) ** 2))

    def grad(w):
        return 2.0 * G.T @ np.maximum(G @ w - h, 0.0)

    ref = minimize(V, r.w + 1.0, jac=grad, method="BFGS", options={"gtol": 1e-10, "maxiter": 10000})
    assert V(r.w) <= ref.fun * (1 + 1e-6) + 1e-9, (V(r.w), ref.fun)
    # the regulariser picks the M-closest minimiser: a gradient step of V cannot improve it
    assert np.linalg.norm(grad(r.w)) <= 1e-5 * max(1.0, np.linalg.norm(G.T @ np.abs(G @ r.w - h)))


def test_negative_control_a_wbc_that_ignores_a_row_fails_the_row_check(setting):
    """The check used above (every row G w <= h at the answer) catches a WBC that drops a row: solved
    without zmp_toe (rows 4 and 21), the answer violates it on an instance where that row binds."""
    M = weight_matrix(1.0, 0.0)
    found = 0
    for G, h, w_star in violating_instances(setting, 30, 5):
        full = WholeBodyQP(M).solve(G, h, w_star)
        if full.status != ACTIVE or not full.active[4]:
            continue
        keep = np.ones(WBC_ROWS, bool)
        keep[[4, 4 + N_CONSTRAINTS]] = False
        lame = WholeBodyQP(M, m=WBC_ROWS - 2).solve(G[keep], h[keep], w_star)
        assert rows_hold(G[keep], h[keep] + 1e-9 * (1 + np.abs(h[keep])), lame.w)
        prim, _, _ = kkt_full(G, h, w_star, M, lame.w)
        assert prim > 1e-6, "dropping the active zmp_toe row changed nothing: the check could not fail"
        found += 1
    assert found >= 1, "no instance with zmp_toe active: the negative control checked nothing"


# ----------------------------------------------------------------------------------------
# the modes in closed loop (rigid plant, in process)
# ----------------------------------------------------------------------------------------
from biped_controller.core.control.wbc import NOT_RUN  # noqa: E402
from biped_controller.closed_loop import runner  # noqa: E402
from biped_sim.plant.push import Push  # noqa: E402
from biped_controller.core.qp.problem import SOLVER_ERROR  # noqa: E402

MID_STEP = 0.2315   # the paper's cell: mid first step, 25 ms


def closed_loop(mode, force=0.0, steps=3, **overrides):
    cfg = load_controller_config(mode=mode, **overrides)
    pushes = (Push(MID_STEP, 0.025, force, None),) if force else ()
    return runner.run(steps=steps, mode=mode, pushes=pushes, ctrl_config=cfg)


def same_records(a, b, n=None):
    """Bit-identical plant records (time, q, q', torque) and controller decisions over the first n periods."""
    n = min(len(a.records), len(b.records)) if n is None else n
    for k in range(n):
        ra, rb = a.records[k], b.records[k]
        for f in ("t", "q", "qd", "torque"):
            if not np.array_equal(np.asarray(getattr(ra, f)), np.asarray(getattr(rb, f))):
                return False, k, f
        sa, sb = a.statuses[k], b.statuses[k]
        for f in ("p", "p_dot", "tau", "tau_dot", "p_ddot", "tau_ddot", "margins", "zmp", "predicted_reaction",
                  "force_estimate"):
            if not np.array_equal(np.asarray(getattr(sa, f)), np.asarray(getattr(sb, f))):
                return False, k, f
    return True, n, ""


def test_wbc_equals_none_bit_for_bit_when_no_row_binds():
    """Undisturbed walk, 3 steps: the tracking law's w holds every row in every period (UNCONSTRAINED), and
    the records of mode wbc (Python objects) are those of mode none (compiled loop) bit for bit. Negative
    control: with the controller's ZMP margin at 80 mm (l within +-2 cm) the rows bind, and the same
    comparison fails."""
    none, wbc = closed_loop("none"), closed_loop("wbc")
    assert not wbc.fallen and wbc.steps_walked == 3
    assert len(wbc.records) == len(none.records) > 1000
    assert all(s.wbc_status == UNCONSTRAINED for s in wbc.statuses)
    ok, k, f = same_records(wbc, none)
    assert ok, f"wbc differs from none at period {k} in {f}"
    tight = closed_loop("wbc", steps=1, margin_zmp=0.08)
    assert any(s.wbc_status == ACTIVE for s in tight.statuses)
    ok, k, f = same_records(tight, none)
    assert not ok, "negative control: binding rows left the records unchanged"


def test_wbc_holds_every_row_while_feasible_under_a_push():
    """200 N for 25 ms at mid-step: in every period where the whole-body QP was feasible (UNCONSTRAINED or
    ACTIVE) the recorded margins of the 17 rows (robot's own rows, predicted for the chosen w) are >= the
    controller's margins (>= 0), and the recorded l stays within the controller's foot range. Some periods
    are ACTIVE (the check is not vacuous). Negative control: mode none under the same push records
    violated rows (the check can fail)."""
    cfg = load_controller_config()
    res = closed_loop("wbc", 200.0, steps=2)
    feas = [s for s in res.statuses if s.wbc_status in (UNCONSTRAINED, ACTIVE)]
    assert sum(s.wbc_status == ACTIVE for s in feas) >= 20
    tol = 1e-6
    lim = 0.1 - cfg.margin_zmp
    for s in feas:
        m = np.asarray(s.margins)
        assert np.all(m[:1] >= cfg.margin_normal_force - tol), (s.t, m)
        assert np.all(m >= -tol), (s.t, m)
        assert abs(s.zmp) <= lim + 1e-9, (s.t, s.zmp)
    none = closed_loop("none", 200.0, steps=2)
    worst = min(float(np.min(np.asarray(s.margins))) for s in none.statuses)
    assert worst < -1.0, "negative control: mode none kept every row under the push"


@pytest.mark.parametrize("force", [600.0])
def test_hybrid_equals_both_while_the_adaptation_holds_the_rows(force):
    """A push beyond mode both's limit: hybrid and both are bit-identical up to the first period where the
    p/tau QP did not hold its rows (INFEASIBLE_FALLBACK or SOLVER_ERROR), and the whole-body stage ran in
    exactly those periods. Negative control: after the stage has changed w the records differ (the
    comparison is able to fail)."""
    both, hyb = closed_loop("both", force, steps=3), closed_loop("hybrid", force, steps=3)
    first = next((k for k, s in enumerate(hyb.statuses) if s.qp_status in (INFEASIBLE_FALLBACK, SOLVER_ERROR)), None)
    assert first is not None, "the p/tau QP stayed feasible: the test would compare identical modes only"
    ok, k, f = same_records(hyb, both, first + 1 if hyb.statuses[first].wbc_status == UNCONSTRAINED else first)
    assert ok, f"hybrid differs from both at period {k} ({f}) before the p/tau QP failed at {first}"
    assert all(s.wbc_status == NOT_RUN for s in hyb.statuses if s.qp_status not in (INFEASIBLE_FALLBACK, SOLVER_ERROR))
    assert all(s.wbc_status != NOT_RUN for s in hyb.statuses if s.qp_status in (INFEASIBLE_FALLBACK, SOLVER_ERROR))
    changed = next((k for k, s in enumerate(hyb.statuses) if s.wbc_status not in (NOT_RUN, UNCONSTRAINED)), None)
    assert changed is not None, "the whole-body stage never changed w"
    ok, k, f = same_records(hyb, both)
    assert not ok and k >= changed, "negative control: records equal after the stage changed w"


def test_status_message_carries_the_whole_body_fields():
    """The node's ControllerStatus carries every ControllerStatusData field, the whole-body ones included
    (the live view and the Foxglove layout plot them); a status without them would fail here."""
    import dataclasses
    from biped_msgs_py.msg import ControllerStatus
    from builtin_interfaces.msg import Time
    from biped_controller.core.control.status import ControllerStatusData
    from biped_controller.graph.controller_node import status_message
    fields = set(ControllerStatus.get_fields_and_field_types())
    data_fields = {f.name for f in dataclasses.fields(ControllerStatusData)} - {"t"}
    assert data_fields <= fields, data_fields - fields
    res = closed_loop("wbc", 200.0, steps=1)
    s = next(s for s in res.statuses if s.wbc_status == ACTIVE)
    m = status_message(s, Time())
    assert m.wbc_status == ACTIVE and m.wbc_active == s.wbc_active != 0
    assert m.wbc_deviation == s.wbc_deviation > 0.0
    assert m.mode == "wbc"


def test_table_modes_option():
    """``scripts/experiment table --modes``: any distinct known modes; unknown, repeated or empty -> the
    option's error (argparse names it)."""
    import argparse
    from biped_controller.studies.experiment import TABLE_MODES
    from biped_controller.studies.trial.args import modes_arg as _modes_arg
    assert _modes_arg("none,wbc,both,hybrid") == ("none", "wbc", "both", "hybrid")
    assert TABLE_MODES == ("none", "tau", "p", "both")
    for bad in ("none,bogus", "wbc,wbc", ",", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="modes"):
            _modes_arg(bad)
