"""Tests of the adaptation QP (qp.py, solvers "piqp" and "exact") and its exact n <= 2 solver
(qp_exact.py); the compiled kernels against qp_exact are in test_qp_fast.py.

References are independent of the code under test: scipy SLSQP / BFGS / linprog, brute-force
sampling, and KKT residuals. All randomness is seeded. M = 17 rows here (random instances); the
controller's real 37-row instances are in test_qp_fast.py.
"""

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest
from biped_msgs_py.msg import ControllerStatus
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog, minimize

from biped_controller.core.qp import solver as qp
from biped_controller.core.qp import exact as qp_exact
from biped_controller.core.qp import problem as qp_types
from biped_controller.core.qp.solver import (
    ACTIVE,
    INFEASIBLE_FALLBACK,
    SOLVER_ERROR,
    UNCONSTRAINED,
    AdaptationQP,
    QPResult,
    QPShapeError,
    kkt_residuals,
    solve_with_qpsolvers,
)
from biped_controller.core.qp.exact import least_violation_exact, min_piecewise_quadratic_1d, solve_exact

M = 17
KKT_TOL = 1e-6


# ----------------------------------------------------------------------------------------
# instance generators and references
# ----------------------------------------------------------------------------------------


def rand_W(rng, n):
    return 10.0 ** rng.uniform(-1, 1, n)


def rand_feasible(rng, n, m=M, spread=5.0):
    """Feasible by construction (x0 strictly inside); x* usually outside."""
    G = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-1, 1, (m, 1))
    x0 = rng.normal(size=n)
    h = G @ x0 + rng.exponential(size=m) * np.linalg.norm(G, axis=1)
    x_star = x0 + spread * rng.normal(size=n)
    return G, h, x_star, rand_W(rng, n), x0


def rand_infeasible(rng, n, m=M):
    """Infeasible by Farkas: rows with normals c_k u_k, sum_k u_k = 0, h_k = -c_k delta_k."""
    if n == 1:
        u = np.array([[1.0], [-1.0]])
    else:
        th = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(3) / 3 + rng.uniform(-0.3, 0.3, 3)
        u = np.stack([np.cos(th), np.sin(th)], axis=1)
        # make sum_k w_k u_k = 0 with w > 0: solve for weights of the first two given w_3 = 1
        w = np.linalg.solve(u[:2].T, -u[2])
        assert np.all(w > 0)
        u = np.concatenate([u[:2] * w[:, None], u[2:]], axis=0)
    k = u.shape[0]
    c = 10.0 ** rng.uniform(-1, 1, k)
    delta = rng.uniform(0.1, 2.0, k)
    Gb = u * c[:, None]
    hb = -c * delta
    Gr = rng.normal(size=(m - k, n))
    hr = rng.normal(size=m - k) + 3.0
    G = np.concatenate([Gb, Gr])
    h = np.concatenate([hb, hr])
    perm = rng.permutation(m)
    return G[perm], h[perm], rng.normal(size=n) * 3, rand_W(rng, n)


def obj(x, x_star, W):
    return 0.5 * float(np.sum(W * (x - x_star) ** 2))


def viol_cost(G, h, x):
    return float(np.sum(np.maximum(G @ x - h, 0.0) ** 2))


def slsqp(G, h, x_star, W, x0):
    res = minimize(
        lambda x: obj(x, x_star, W),
        x0,
        jac=lambda x: W * (x - x_star),
        constraints=[{"type": "ineq", "fun": lambda x: h - G @ x, "jac": lambda x: -G}],
        method="SLSQP",
        options={"ftol": 1e-14, "maxiter": 500},
    )
    return res.x


def lp_feasible(G, h):
    n = G.shape[1]
    r = linprog(np.zeros(n), A_ub=G, b_ub=h, bounds=[(None, None)] * n, method="highs")
    return r.status == 0


def assert_kkt(G, h, x_star, W, res, tol=KKT_TOL):
    for z in (None, res.z):
        k = kkt_residuals(G, h, x_star, W, res.x, z)
        for key in ("primal", "dual", "complementarity", "stationarity"):
            assert k[key] <= tol, (key, k[key], res)


def scale(x):
    return 1.0 + float(np.max(np.abs(x)))


@pytest.fixture(scope="module")
def solvers():
    rng = np.random.default_rng(0)
    out = {n: AdaptationQP(n, M, rand_W(rng, n)) for n in (1, 2)}
    out.update({("exact", n): AdaptationQP(n, M, rand_W(rng, n), solver="exact") for n in (1, 2)})
    return out


def solve_piqp(solvers, G, h, x_star, W, kind=None):
    n = G.shape[1]
    s = solvers[n if kind is None else (kind, n)]
    s.set_weights(W)
    return s.solve(G, h, x_star)


def assert_same_as_exact(r, ex, rtol=1e-12):
    """AdaptationQP(solver="exact") gives qp_exact's answer: status, x (to rtol of its scale), and
    the least-violation answer of the same problem."""
    assert r.status == ex.status, (r, ex)
    assert np.max(np.abs(r.x - ex.x)) <= rtol * scale(ex.x), (r, ex)
    assert np.array_equal(r.active, ex.active) or r.status != UNCONSTRAINED


# ----------------------------------------------------------------------------------------
# random feasible / infeasible instances
# ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2])
def test_random_feasible_exact_vs_piqp_vs_slsqp(n, solvers):
    rng = np.random.default_rng(100 + n)
    n_active = 0
    for _ in range(200):
        G, h, x_star, W, x0 = rand_feasible(rng, n)
        ex = solve_exact(G, h, x_star, W)
        pq = solve_piqp(solvers, G, h, x_star, W)
        fx = solve_piqp(solvers, G, h, x_star, W, "exact")
        assert_same_as_exact(fx, ex)
        assert ex.status == pq.status
        assert ex.status in (UNCONSTRAINED, ACTIVE)
        if ex.status == UNCONSTRAINED:
            assert np.array_equal(ex.x, x_star) and np.array_equal(pq.x, x_star)
            continue
        n_active += 1
        assert lp_feasible(G, h)
        ref = slsqp(G, h, x_star, W, x0)
        assert np.max(G @ ref - h) <= 1e-8 * scale(h)
        # exact optimum is never worse than SLSQP's and agrees with it
        assert obj(ex.x, x_star, W) <= obj(ref, x_star, W) + 1e-10 * (1 + obj(ref, x_star, W))
        assert np.allclose(ex.x, ref, atol=1e-5 * scale(ref))
        assert np.allclose(ex.x, pq.x, rtol=0, atol=1e-7 * scale(ex.x))
        assert ex.max_violation <= 1e-12 * scale(h)
        assert_kkt(G, h, x_star, W, ex, tol=1e-9 * scale(h) * scale(W))
        assert_kkt(G, h, x_star, W, fx, tol=1e-9 * scale(h) * scale(W))
        assert_kkt(G, h, x_star, W, pq)
        assert np.any(ex.active) and np.any(pq.active)
    assert n_active > 100


@pytest.mark.parametrize("n", [1, 2])
def test_random_infeasible_reported_by_both(n, solvers):
    rng = np.random.default_rng(200 + n)
    for _ in range(100):
        G, h, x_star, W = rand_infeasible(rng, n)
        assert not lp_feasible(G, h)
        ex = solve_exact(G, h, x_star, W)
        pq = solve_piqp(solvers, G, h, x_star, W)
        assert_same_as_exact(solve_piqp(solvers, G, h, x_star, W, "exact"), ex)
        assert ex.status == INFEASIBLE_FALLBACK, ex
        assert pq.status == INFEASIBLE_FALLBACK, pq
        assert "PRIMAL_INFEASIBLE" in pq.message
        assert "violates" in ex.message and ex.max_violation > 0
        # least-violation answer: compare with BFGS on the (C^1) violation cost
        e = qp.reg_weight(G, W)
        V = lambda x: viol_cost(G, h, x) + e * float(np.sum(W * (x - x_star) ** 2))  # noqa: E731
        dV = lambda x: 2 * G.T @ np.maximum(G @ x - h, 0) + 2 * e * W * (x - x_star)  # noqa: E731
        ref = minimize(V, x_star, jac=dV, method="BFGS", options={"gtol": 1e-12}).x
        assert V(ex.x) <= V(ref) + 1e-10 * (1 + V(ref))
        assert np.allclose(ex.x, ref, atol=1e-4 * scale(ref))
        assert np.allclose(pq.x, ex.x)
        assert np.isclose(pq.max_violation, ex.max_violation)


@pytest.mark.parametrize("n", [1, 2])
def test_piqp_slack_fallback_matches_exact(n):
    rng = np.random.default_rng(300 + n)
    s = AdaptationQP(n, M, np.ones(n), fallback="piqp")
    for _ in range(30):
        G, h, x_star, W = rand_infeasible(rng, n)
        s.set_weights(W)
        r = s.solve(G, h, x_star)
        ex = solve_exact(G, h, x_star, W)
        assert r.status == INFEASIBLE_FALLBACK
        assert viol_cost(G, h, r.x) <= viol_cost(G, h, ex.x) * (1 + 1e-6) + 1e-12
        assert np.allclose(r.x, ex.x, atol=1e-4 * scale(ex.x))


def test_least_violation_general_n_piqp():
    """n = 3 goes through the slack QP (PIQP); compare with BFGS."""
    rng = np.random.default_rng(7)
    G = rng.normal(size=(M, 3))
    h = rng.normal(size=M)
    G = np.concatenate([G, [[1, 0, 0], [-1, 0, 0]]])
    h = np.concatenate([h, [-1.0, -1.0]])  # x0 <= -1 and x0 >= 1
    x_star, W = np.zeros(3), np.array([1.0, 2.0, 3.0])
    r = qp.least_violation(G, h, x_star, W)
    assert r.status == INFEASIBLE_FALLBACK
    ref = minimize(lambda x: viol_cost(G, h, x), x_star, method="BFGS").x
    assert viol_cost(G, h, r.x) <= viol_cost(G, h, ref) + 1e-6
    s = AdaptationQP(3, M + 2, W)
    assert s.fallback == "piqp"
    r2 = s.solve(G, h, x_star)
    assert r2.status == INFEASIBLE_FALLBACK and np.allclose(r2.x, r.x, atol=1e-5)


def test_general_n_active_matches_slsqp():
    rng = np.random.default_rng(8)
    s = AdaptationQP(3, M, np.ones(3))
    for _ in range(20):
        G, h, x_star, W, x0 = rand_feasible(rng, 3)
        s.set_weights(W)
        r = s.solve(G, h, x_star)
        if r.status == UNCONSTRAINED:
            continue
        assert r.status == ACTIVE
        assert np.allclose(r.x, slsqp(G, h, x_star, W, x0), atol=1e-5 * scale(r.x))
        assert_kkt(G, h, x_star, W, r)


# ----------------------------------------------------------------------------------------
# degenerate instances
# ----------------------------------------------------------------------------------------


def check_all(G, h, x_star, W, solvers, expect_status, expect_x=None, atol=1e-9):
    G, h, x_star, W = (np.asarray(a, float) for a in (G, h, x_star, W))
    n = G.shape[1]
    s = AdaptationQP(n, G.shape[0], W)
    out = [solve_exact(G, h, x_star, W), s.solve(G, h, x_star), solve_with_qpsolvers(G, h, x_star, W),
           AdaptationQP(n, G.shape[0], W, polish=False).solve(G, h, x_star),
           AdaptationQP(n, G.shape[0], W, solver="exact").solve(G, h, x_star)]
    assert_same_as_exact(out[-1], out[0])
    for r in out:
        assert isinstance(r, QPResult)
        assert r.status == expect_status, r
        if expect_x is not None:
            assert np.allclose(r.x, expect_x, atol=atol * scale(expect_x)), (r, expect_x)
        if r.status == ACTIVE:
            assert_kkt(G, h, x_star, W, r)
    return out


def pad(G, h, m=M, seed=0):
    """Pad with loose random rows far from the region of interest."""
    rng = np.random.default_rng(seed)
    n = np.shape(G)[1]
    Gr = rng.normal(size=(m - len(G), n))
    hr = np.linalg.norm(Gr, axis=1) * 100.0
    return np.concatenate([G, Gr]), np.concatenate([h, hr])


def test_single_active_row(solvers):
    G, h = pad(np.array([[1.0, 1.0]]), np.array([1.0]))
    W = np.array([1.0, 1.0])
    ex = check_all(G, h, [2.0, 2.0], W, solvers, ACTIVE, [0.5, 0.5])[0]
    assert ex.active[0] and ex.active.sum() == 1
    assert np.isclose(ex.z[0], 1.5)


def test_single_active_row_weighted(solvers):
    # W-projection: x = x* - (g x* - h) W^-1 g / (g W^-1 g)
    G, h = pad(np.array([[1.0, 1.0]]), np.array([1.0]))
    W = np.array([1.0, 3.0])
    x_star = np.array([2.0, 2.0])
    winv = 1 / W
    x = x_star - (3.0 / (winv.sum())) * winv
    check_all(G, h, x_star, W, solvers, ACTIVE, x)


def test_two_active_rows_at_vertex(solvers):
    G, h = pad(np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([1.0, -1.0]))
    out = check_all(G, h, [3.0, 3.0], [1.0, 2.0], solvers, ACTIVE, [1.0, -1.0])
    assert out[0].active[:2].all()
    assert np.allclose(out[0].z[:2], [2.0, 8.0])


def test_three_rows_through_one_vertex(solvers):
    G, h = pad(np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]), np.array([1.0, 1.0, 2.0]))
    check_all(G, h, [3.0, 4.0], [1.0, 1.0], solvers, ACTIVE, [1.0, 1.0])


def test_duplicated_rows(solvers):
    g = np.array([[1.0, 2.0]])
    G, h = pad(np.concatenate([g, g, g, 2 * g]), np.array([1.0, 1.0, 1.0, 2.0]))
    x_star = np.array([3.0, 3.0])
    x = x_star - (9.0 - 1.0) / 5.0 * np.array([1.0, 2.0])
    check_all(G, h, x_star, [1.0, 1.0], solvers, ACTIVE, x)


def test_parallel_rows_strip(solvers):
    # 0 <= x0 + x1 <= 1 (two parallel rows, opposite normals)
    G, h = pad(np.array([[1.0, 1.0], [-1.0, -1.0]]), np.array([1.0, 0.0]))
    check_all(G, h, [-2.0, 0.0], [1.0, 1.0], solvers, ACTIVE, [-1.0, 1.0])
    check_all(G, h, [0.3, 0.3], [1.0, 1.0], solvers, UNCONSTRAINED, [0.3, 0.3], atol=0)


def test_parallel_rows_infeasible_and_nearly_parallel(solvers):
    G, h = pad(np.array([[1.0, 1.0], [-1.0, -1.0]]), np.array([-1.0, -1.0]))  # x0+x1 <= -1 and >= 1
    out = check_all(G, h, [0.0, 0.0], [1.0, 1.0], solvers, INFEASIBLE_FALLBACK)
    for r in out:  # least violation: x0 + x1 = 0, closest to x* -> (0, 0)
        assert np.allclose(r.x, [0.0, 0.0], atol=1e-6)
        assert np.isclose(r.max_violation, 1.0)
    # nearly parallel wedge: vertex far away but well defined
    d = 1e-6
    G, h = pad(np.array([[1.0, d], [1.0, -d]]), np.array([0.0, 0.0]))
    check_all(G, h, [1.0, 0.0], [1.0, 1.0], solvers, ACTIVE, [0.0, 0.0], atol=1e-7)


def test_zero_norm_rows(solvers):
    G, h = pad(np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]]), np.array([0.0, 5.0, 1.0]))
    check_all(G, h, [2.0, 7.0], [1.0, 1.0], solvers, ACTIVE, [1.0, 7.0])
    G, h = pad(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([-1.0, 1.0]))  # 0 <= -1
    out = check_all(G, h, [2.0, 7.0], [1.0, 1.0], solvers, INFEASIBLE_FALLBACK)
    assert "row 0" in out[0].message
    assert np.allclose(out[0].x, [1.0, 7.0])  # the other rows are still satisfied
    # n = 1 as well
    G1, h1 = pad(np.array([[0.0], [2.0]]), np.array([0.0, 1.0]))
    check_all(G1, h1, [3.0], [1.0], solvers, ACTIVE, [0.5])


def test_all_zero_matrix():
    G = np.zeros((M, 2))
    assert solve_exact(G, np.zeros(M), [1.0, 2.0], [1.0, 1.0]).status == UNCONSTRAINED
    h = np.zeros(M)
    h[3] = -1.0
    r = solve_exact(G, h, [1.0, 2.0], [1.0, 1.0])
    assert r.status == INFEASIBLE_FALLBACK and np.array_equal(r.x, [1.0, 2.0])
    assert r.max_violation == 1.0


def test_x_star_exactly_on_boundary(solvers):
    G, h = pad(np.array([[1.0, 1.0], [1.0, -1.0]]), np.array([1.0, 0.0]))
    x_star = np.array([0.5, 0.5])  # on both lines
    out = check_all(G, h, x_star, [1.0, 1.0], solvers, UNCONSTRAINED, x_star, atol=0)
    for r in out:
        assert r.x.tobytes() == x_star.tobytes()
        assert r.active[:2].all() and r.max_violation == 0.0


def test_n1_interval(solvers):
    G, h = pad(np.array([[1.0], [-2.0], [4.0]]), np.array([3.0, 2.0, 8.0]))  # -1 <= x <= 2
    check_all(G, h, [5.0], [2.0], solvers, ACTIVE, [2.0])
    check_all(G, h, [-5.0], [2.0], solvers, ACTIVE, [-1.0])
    check_all(G, h, [0.0], [2.0], solvers, UNCONSTRAINED, [0.0], atol=0)
    G, h = pad(np.array([[1.0], [-1.0]]), np.array([-1.0, -1.0]))  # x <= -1, x >= 1
    out = check_all(G, h, [5.0], [2.0], solvers, INFEASIBLE_FALLBACK, [0.0], atol=1e-6)
    assert "row 0" in out[0].message and "row 1" in out[0].message


def test_projection_onto_a_row_through_the_origin(solvers):
    """Found by hypothesis: the projection of x* = (0, 1) onto 0.05 x1 <= 0 lands 1e-16 off the
    row; the feasibility tolerance must scale with |x*| (the rounding of the formula), not with
    |x| = 0, or the candidate is refused (wrongly "infeasible", or a worse vertex chosen)."""
    G = np.zeros((M, 2))
    G[M - 1] = [0.0, 0.05]
    h = np.zeros(M)
    for _ in range(2):
        out = check_all(G, h, [0.0, 1.0], [1.0, 1.0], solvers, ACTIVE, [0.0, 0.0], atol=1e-8)
        for r in (out[0], out[1], out[4]):  # qp_exact, AdaptationQP piqp (polished) and exact
            assert np.max(np.abs(r.x)) <= 1e-15, r
        G[1], h[1] = [1.0, 0.0], 1.0    # and with a second row whose vertex is worse


def test_point_feasible_set(solvers):
    # x0 + x1 <= 0, -x0 - x1 <= 0, x0 - x1 <= 0, -x0 + x1 <= 0 -> only (0, 0)
    G, h = pad(np.array([[1.0, 1.0], [-1.0, -1.0], [1.0, -1.0], [-1.0, 1.0]]), np.zeros(4))
    r = solve_exact(G, h, [1.0, 3.0], [1.0, 1.0])
    assert r.status == ACTIVE and np.allclose(r.x, 0.0, atol=1e-12)


# ----------------------------------------------------------------------------------------
# API behaviour
# ----------------------------------------------------------------------------------------


def test_unconstrained_bit_exact_and_no_solver_call():
    rng = np.random.default_rng(5)
    s = AdaptationQP(2, M, [1.0, 1.0])
    for _ in range(50):
        G = rng.normal(size=(M, 2))
        x_star = rng.normal(size=2) * np.array([1e-7, 1e7])
        h = G @ x_star + rng.exponential(size=M)
        before = s.calls
        r = s.solve(G, h, x_star)
        assert s.calls == before
        assert r.status == UNCONSTRAINED and r.iterations == 0
        assert r.x.tobytes() == x_star.tobytes() and r.x is not x_star
        assert r.max_violation == 0.0 and not r.active.any()
        r2 = solve_exact(G, h, x_star, [1.0, 1.0])
        assert r2.status == UNCONSTRAINED and r2.x.tobytes() == x_star.tobytes()


def test_shape_errors_name_the_array():
    s = AdaptationQP(2, M, [1.0, 1.0])
    G, h, x = np.ones((M, 2)), np.ones(M), np.ones(2)
    with pytest.raises(QPShapeError, match="G"):
        s.solve(np.ones((M, 3)), h, x)
    with pytest.raises(QPShapeError, match="G"):
        s.solve(np.ones((M - 1, 2)), h[:-1], x)
    with pytest.raises(QPShapeError, match="h"):
        s.solve(G, np.ones(M + 1), x)
    with pytest.raises(QPShapeError, match="x_star"):
        s.solve(G, h, np.ones(3))
    with pytest.raises(QPShapeError, match="W"):
        solve_exact(G, h, x, np.ones(3))
    with pytest.raises(QPShapeError, match="G"):
        solve_exact(np.ones(M), h, x, np.ones(2))
    with pytest.raises(QPShapeError, match="W"):
        AdaptationQP(2, M, [1.0])
    assert issubclass(QPShapeError, ValueError)


@pytest.mark.parametrize("bad", ["G", "h", "x_star"])
def test_non_finite_inputs_give_solver_error(bad):
    s = AdaptationQP(2, M, [1.0, 1.0])
    rng = np.random.default_rng(1)
    G, h, x_star, W, _ = rand_feasible(rng, 2)
    data = {"G": G.copy(), "h": h.copy(), "x_star": x_star.copy()}
    data[bad].flat[0] = np.nan
    for r in (s.solve(data["G"], data["h"], data["x_star"]), solve_exact(data["G"], data["h"], data["x_star"], W),
              solve_with_qpsolvers(data["G"], data["h"], data["x_star"], W)):
        assert r.status == SOLVER_ERROR and bad in r.message
        assert np.array_equal(r.x, data["x_star"], equal_nan=True)
    # the solver object is still fine afterwards
    r = s.solve(G, h, x_star)
    assert r.status == solve_exact(G, h, x_star, [1.0, 1.0]).status


@pytest.mark.parametrize("solver", ["piqp", "quadprog", "daqp", "osqp"])
def test_qpsolvers_backends_agree(solver):
    rng = np.random.default_rng(11)
    kw = {"osqp": {"eps_abs": 1e-10, "eps_rel": 1e-10, "polish": True}, "proxqp": {"eps_abs": 1e-10}}.get(solver, {})
    for _ in range(20):
        G, h, x_star, W, _ = rand_feasible(rng, 2)
        ex = solve_exact(G, h, x_star, W)
        r = solve_with_qpsolvers(G, h, x_star, W, solver=solver, **kw)
        assert r.status == ex.status
        assert np.allclose(r.x, ex.x, atol=1e-6 * scale(ex.x))
    G, h, x_star, W = rand_infeasible(rng, 2)
    r = solve_with_qpsolvers(G, h, x_star, W, solver=solver, **kw)
    assert r.status == INFEASIBLE_FALLBACK


def test_kkt_residuals_detects_non_optimal_point():
    G = np.array([[1.0, 0.0]])
    h = np.array([1.0])
    W = np.array([1.0, 1.0])
    x_star = np.array([2.0, 0.0])
    good = kkt_residuals(G, h, x_star, W, np.array([1.0, 0.0]))
    assert good["stationarity"] < 1e-14 and np.isclose(good["z"][0], 1.0)
    bad = kkt_residuals(G, h, x_star, W, np.array([1.0, 0.5]))
    assert bad["stationarity"] > 0.1
    outside = kkt_residuals(G, h, x_star, W, np.array([1.5, 0.0]))
    assert outside["primal"] == pytest.approx(0.5)
    neg = kkt_residuals(G, h, x_star, W, np.array([1.0, 0.0]), z=np.array([-1.0]))
    assert neg["dual"] == 1.0


def test_min_piecewise_quadratic_1d_vs_grid():
    rng = np.random.default_rng(3)
    for _ in range(200):
        k = rng.integers(1, 8)
        a = rng.normal(size=k)
        a[rng.random(k) < 0.1] = 0.0
        b = rng.normal(size=k)
        q = 10.0 ** rng.uniform(-6, 1)
        t0 = rng.normal() * 3
        phi = lambda t: np.sum(np.maximum(np.multiply.outer(t, a) - b, 0) ** 2, axis=-1) + q * (t - t0) ** 2  # noqa: E731
        t = min_piecewise_quadratic_1d(a, b, q, t0)
        grid = np.linspace(t - 5, t + 5, 20001)
        assert phi(np.array(t)) <= phi(grid).min() + 1e-12
        dphi = 2 * np.sum(a * np.maximum(a * t - b, 0)) + 2 * q * (t - t0)
        assert abs(dphi) <= 1e-9 * (1 + np.sum(np.abs(a) * np.abs(b)) + q * abs(t0))


def test_least_violation_n2_newton_vs_bfgs():
    rng = np.random.default_rng(4)
    for _ in range(100):
        G = rng.normal(size=(M, 2)) * 10.0 ** rng.uniform(-1, 1, (M, 1))
        h = rng.normal(size=M) - 1.0
        x_star = rng.normal(size=2) * 3
        W = rand_W(rng, 2)
        x, it = least_violation_exact(G, h, x_star, W)
        assert it < 50
        e = qp.reg_weight(G, W)
        dV = 2 * G.T @ np.maximum(G @ x - h, 0) + 2 * e * W * (x - x_star)
        assert np.linalg.norm(dV) <= 1e-9 * (1 + np.linalg.norm(G) ** 2 * scale(x))
        V = lambda y: viol_cost(G, h, y) + e * np.sum(W * (y - x_star) ** 2)  # noqa: E731
        ref = minimize(V, x_star, method="BFGS", options={"gtol": 1e-10}).x
        assert V(x) <= V(ref) + 1e-12 * (1 + V(ref))


# ----------------------------------------------------------------------------------------
# solver reuse
# ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2])
def test_solver_reused_1000_calls(n):
    rng = np.random.default_rng(500 + n)
    s = AdaptationQP(n, M, np.ones(n))
    fx = AdaptationQP(n, M, np.ones(n), solver="exact")
    held = dict(s.piqp_solvers)      # the PIQP objects for m rows, made by the constructor
    counts = {UNCONSTRAINED: 0, ACTIVE: 0, INFEASIBLE_FALLBACK: 0}
    polished = 0
    for i in range(1000):
        if i % 10 == 9:
            G, h, x_star, W = rand_infeasible(rng, n)
        else:
            G, h, x_star, W, _ = rand_feasible(rng, n, spread=5.0 if i % 3 else 0.1)
        if i % 100 == 0:
            s.set_weights(W)
        W = s.W
        r = s.solve(G, h, x_star)
        ex = solve_exact(G, h, x_star, W)
        for k, objs in s.piqp_solvers.items():  # created once per row count, then only updated
            first = held.setdefault(k, objs)
            assert all(a is b for a, b in zip(first, objs))
        assert r.status == ex.status, (i, r, ex)
        assert np.allclose(r.x, ex.x, atol=1e-6 * scale(ex.x)), (i, r, ex)
        if "polished" in r.message:  # verified KKT on an active set: the exact optimum up to rounding
            assert np.max(np.abs(r.x - ex.x)) <= 1e-9 * scale(ex.x), (i, r, ex)
            polished += 1
        if r.status == ACTIVE:
            assert_kkt(G, h, x_star, W, r)
        counts[r.status] += 1
        fx.set_weights(W)
        assert_same_as_exact(fx.solve(G, h, x_star), ex)
    assert min(counts.values()) > 50, counts
    assert polished > 0.9 * counts[ACTIVE]
    assert s.calls == counts[ACTIVE] + s.tight_calls + counts[INFEASIBLE_FALLBACK]


# ----------------------------------------------------------------------------------------
# hypothesis properties
# ----------------------------------------------------------------------------------------

finite = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False, allow_infinity=False)
positive = st.floats(min_value=0.05, max_value=20.0)


@st.composite
def feasible_instances(draw, n):
    G = np.array(draw(st.lists(st.lists(finite, min_size=n, max_size=n), min_size=M, max_size=M)))
    x0 = np.array(draw(st.lists(finite, min_size=n, max_size=n)))
    slack = np.array(draw(st.lists(st.floats(0.0, 10.0), min_size=M, max_size=M)))
    x_star = np.array(draw(st.lists(finite, min_size=n, max_size=n)))
    W = np.array(draw(st.lists(positive, min_size=n, max_size=n)))
    return G, G @ x0 + slack, x_star, W, x0


HYP = settings(max_examples=150, derandomize=True, deadline=None,
               suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _check_property(G, h, x_star, W, x0, solvers):
    rng = np.random.default_rng(0)
    n = G.shape[1]
    ex = solve_exact(G, h, x_star, W)
    assert_same_as_exact(solve_piqp(solvers, G, h, x_star, W, "exact"), ex)
    for r in (ex, solve_piqp(solvers, G, h, x_star, W)):
        assert r.status in (UNCONSTRAINED, ACTIVE), r
        tol = 1e-7 * (1 + np.abs(G).sum(1) * scale(r.x) + np.abs(h))
        assert np.all(G @ r.x - h <= tol)
        f = obj(r.x, x_star, W)
        # random feasible points (around x*, x0 and the answer): none is better
        P = np.concatenate([x_star + rng.normal(size=(300, n)) * 3, x0 + rng.normal(size=(300, n)),
                            r.x + rng.normal(size=(300, n)) * 1e-3, x0[None, :]])
        ok = np.all(P @ G.T <= h, axis=1)
        fs = 0.5 * np.sum(W * (P - x_star) ** 2, axis=1)[ok]
        assert np.all(fs >= f - 1e-7 * (1 + f))


@HYP
@given(feasible_instances(2))
def test_property_n2(inst):
    _check_property(*inst, solvers=_HYP_SOLVERS)


@HYP
@given(feasible_instances(1))
def test_property_n1(inst):
    _check_property(*inst, solvers=_HYP_SOLVERS)


_HYP_SOLVERS = {n: AdaptationQP(n, M, np.ones(n)) for n in (1, 2)}
_HYP_SOLVERS.update({("exact", n): AdaptationQP(n, M, np.ones(n), solver="exact") for n in (1, 2)})


def test_status_constants_equal_the_message_constants():
    assert UNCONSTRAINED == ControllerStatus.QP_UNCONSTRAINED
    assert ACTIVE == ControllerStatus.QP_ACTIVE
    assert INFEASIBLE_FALLBACK == ControllerStatus.QP_INFEASIBLE_FALLBACK
    assert SOLVER_ERROR == ControllerStatus.QP_SOLVER_ERROR
    assert ControllerStatus.NO_ADAPTATION not in qp.STATUS_NAMES
    assert {qp.STATUS_NAMES[getattr(ControllerStatus, "QP_" + name)] for name in
            ("UNCONSTRAINED", "ACTIVE", "INFEASIBLE_FALLBACK", "SOLVER_ERROR")} == set(qp.STATUS_NAMES.values())
    # one definition, re-exported (qp keeps the names the controller and the experiment import)
    assert qp.QPResult is qp_types.QPResult and qp.STATUS_NAMES is qp_types.STATUS_NAMES
    assert qp.reg_weight is qp_exact.reg_weight and not hasattr(qp_types, "least_violation_exact")


def _imported_modules(path: Path) -> set:
    """Modules a source file imports (relative imports resolved inside biped_controller.core.qp; ``from
    package import module`` counts the module)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = "biped_controller.core.qp." if node.level else ""
            if node.module and node.module not in ("biped_controller.core.qp",):
                out.add(base + node.module)
            else:
                pkg = base.rstrip(".") if not node.module else node.module
                out.update(f"{pkg}.{a.name}" for a in node.names)
    return out


def test_qp_modules_import_in_one_direction(tmp_path):
    """problem <- exact <- solver, problem <- exact_kernels (loaded by solver through numba_cache, by name): no
    module imports one that imports it back, and none imports another room of the core."""
    pkg = Path(qp.__file__).parent
    deps = {name: {m for m in _imported_modules(pkg / f"{name}.py") if m.startswith("biped_controller.core")}
            for name in ("problem", "exact", "exact_kernels", "solver")}
    assert deps["problem"] == set()
    assert deps["exact"] == {"biped_controller.core.qp.problem"}
    assert deps["exact_kernels"] == {"biped_controller.core.qp.problem"}
    assert deps["solver"] == {"biped_controller.core.qp.problem", "biped_controller.core.qp.exact"}
    # negative control: the checker sees a relative import at the bottom of a module
    probe = tmp_path / "probe.py"
    probe.write_text("import numpy as np\n\n\ndef f():\n    pass\n\n\nfrom . import exact as _exact  # noqa\n")
    assert _imported_modules(probe) == {"numpy", "biped_controller.core.qp.exact"}


def test_fast_result_constructor_equals_the_dataclass():
    x, a, z = np.array([1.0, 2.0]), np.array([True, False]), np.array([0.5, 0.0])
    r1 = qp_types.make_result(x, ACTIVE, "m", 0.25, a, 3, z)
    r2 = QPResult(x, ACTIVE, "m", 0.25, a, 3, z)
    assert type(r1) is QPResult
    for f in dataclasses.fields(QPResult):
        assert getattr(r1, f.name) is getattr(r2, f.name)
    assert repr(r1) == repr(r2)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r1.status = 0


def test_solver_option():
    with pytest.raises(ValueError, match="solver"):
        AdaptationQP(2, M, [1.0, 1.0], solver="quadprog")
    with pytest.raises(ValueError, match="n <= 2"):
        AdaptationQP(3, M, [1.0, 1.0, 1.0], solver="exact")
    s = AdaptationQP(2, M, [1.0, 1.0], solver="exact")
    assert s.piqp_solvers == {} and s.solver_name == "exact"
    assert AdaptationQP(2, M, [1.0, 1.0]).solver_name == "piqp"
