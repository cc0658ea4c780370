"""Whole-body QP (core/wbc.py) and the modes `wbc` and `hybrid` of the controller (issue 26).

References independent of the code under test: quadprog and DAQP through qpsolvers (other solvers than
the PIQP the product holds), scipy's minimiser for the least-violation answer, KKT residuals with the full
(non-diagonal) weight M, and the recorded margins of closed-loop runs. Randomness is seeded.
"""
from __future__ import annotations

import numpy as np
import pytest
import qpsolvers
from scipy.optimize import minimize, nnls

from biped_sim.robot.description import load_description
from biped_sim.robot.fixed_foot import N_CONSTRAINTS, FixedFootModel, contact_rows
from biped_sim.robot.gait_family import GaitFamily
from biped_controller.core.controller import load_controller_config
from biped_controller.core.qp_types import ACTIVE, INFEASIBLE_FALLBACK, UNCONSTRAINED, QPShapeError
from biped_controller.core.wbc import (
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
