"""Tests of the compiled QP kernels (``qp.exact_kernels``, here ``qp_fast``) and of AdaptationQP's paths through them.

References: the numpy exact solver ``qp.exact`` (the oracle the kernels must reproduce), KKT residuals
(qp_types.kkt_residuals, scipy NNLS for multipliers), exact rational arithmetic (fractions) for the
feasibility decision, numpy.linalg.lstsq. Instances: seeded random ones (17 and 37 rows, feasible,
infeasible, degenerate) and the controller's own, recorded from short pushed runs (37 rows).
"""

import os
import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from biped_controller.core.qp import exact as qp_exact
from biped_controller.core.qp.solver import load_exact_kernels
from biped_controller.core.qp import problem as qp_types
from biped_controller.core.control.controller_layout import QP_ROWS
from biped_model.fixed_foot import N_CONSTRAINTS
from biped_controller.core.qp.solver import ACTIVE, INFEASIBLE_FALLBACK, SOLVER_ERROR, UNCONSTRAINED, AdaptationQP, polish
from biped_controller.core.qp.problem import constraint_values, kkt_residuals

from test_qp import rand_feasible, rand_infeasible, rand_W, scale

qp_fast = load_exact_kernels()   # the compiled kernels, loaded explicitly (numba_cache)

ROOT = Path(__file__).resolve().parents[1]
TOL = qp_types.DEFAULT_ACTIVE_TOL
IDENTICAL = 1e-12     # "identical answers": |x_fast - x_exact|_inf <= 1e-12 max(1, |x_exact|_inf)


def fast_exact(G, h, x_star, W):
    return qp_fast.solve_exact(G, h, x_star, W)


def assert_identical(a, b, what, messages=True):
    """a (compiled) gives b's (qp_exact's) answer."""
    assert a.status == b.status, (what, a, b)
    assert np.max(np.abs(a.x - b.x), initial=0.0) <= IDENTICAL * scale(b.x), (what, a.x, b.x)
    assert abs(a.max_violation - b.max_violation) <= IDENTICAL * (1.0 + abs(b.max_violation)), (what, a, b)
    assert np.array_equal(a.active, b.active), (what, a.active, b.active)
    assert (a.z is None) == (b.z is None), what
    if messages:
        assert a.message == b.message, (what, a.message, b.message)


def assert_kkt_answer(G, h, x_star, W, r, what):
    """Every ACTIVE / UNCONSTRAINED answer satisfies the KKT conditions with its own multipliers
    and with multipliers recovered by NNLS; a least-violation answer is a stationary point of
    V(x) = |max(G x - h, 0)|^2 + eps_eff |x - x*|_W^2."""
    sc_g = 1.0 + float(np.max(np.abs(G)))
    tol = 1e-9 * sc_g * scale(r.x) * scale(h) * scale(W)
    if r.status in (UNCONSTRAINED, ACTIVE):
        for z in (r.z, None):
            k = kkt_residuals(G, h, x_star, W, r.x, z)
            for key in ("primal", "dual", "complementarity", "stationarity"):
                assert k[key] <= tol, (what, key, k[key], r)
    elif r.status == INFEASIBLE_FALLBACK:
        e = qp_exact.reg_weight(G, W)
        grad = 2 * G.T @ np.maximum(G @ r.x - h, 0.0) + 2 * e * W * (r.x - x_star)
        assert np.max(np.abs(grad)) <= 1e-8 * sc_g ** 2 * scale(r.x) * scale(h), (what, grad, r)
        assert r.max_violation > 0.0
    else:
        raise AssertionError((what, r))


# ----------------------------------------------------------------------------------------
# instances
# ----------------------------------------------------------------------------------------

RUNS = (("both", 250.0), ("both", 600.0), ("p", 600.0), ("tau", 600.0))


@pytest.fixture(scope="module")
def real_instances(tmp_path_factory):
    """{(mode, force): [(G, h, x_star, status)]} of 2-step runs with a push at t = 0.2315 s for
    25 ms (cached in the session's tmp directory)."""
    path = tmp_path_factory.getbasetemp() / "qp_real_instances.npz"
    if not path.exists():
        from biped_controller.closed_loop.runner import run
        from biped_sim.plant.push import Push

        arrays = {}
        for mode, force in RUNS:
            r = run(steps=2, mode=mode, pushes=(Push(0.2315, 0.025, force),), keep_qp=True)
            for i, (G, h, xs, st) in enumerate(r.qp_instances):
                key = f"{mode}_{force:g}_{i}"
                arrays[key + "_G"], arrays[key + "_h"], arrays[key + "_x"] = G, h, xs
                arrays[key + "_s"] = np.array(st)
        np.savez(path, **arrays)
    out = {}
    with np.load(path) as f:
        for mode, force in RUNS:
            pre = f"{mode}_{force:g}_"
            n_inst = len([k for k in f.files if k.startswith(pre) and k.endswith("_s")])
            out[(mode, force)] = [(f[f"{pre}{i}_G"], f[f"{pre}{i}_h"], f[f"{pre}{i}_x"], int(f[f"{pre}{i}_s"]))
                                  for i in range(n_inst)]
    return out


def all_real(real_instances):
    return [(key, *inst) for key, lst in real_instances.items() for inst in lst]


def answer_kind(r) -> str:
    """'x* feasible', 'projection', 'vertex', 'n=1' or 'infeasible' from qp_exact's message."""
    for kind in ("x* feasible", "projection", "vertex", "n=1", "infeasible"):
        if kind in r.message:
            return kind
    raise AssertionError(r.message)


def test_real_instances_cover_every_case(real_instances):
    """The recorded instances hold every kind of answer, so the loops below cannot pass vacuously."""
    kinds = {}
    for (mode, _force), G, h, xs, _st in all_real(real_instances):
        assert G.shape == (QP_ROWS, 2 if mode == "both" else 1)
        kind = answer_kind(qp_exact.solve_exact(G, h, xs, np.ones(G.shape[1])))
        kinds[kind] = kinds.get(kind, 0) + 1
    assert kinds["x* feasible"] > 1000 and kinds["projection"] > 100 and kinds["vertex"] >= 1
    assert kinds["n=1"] > 50 and kinds["infeasible"] >= 3, kinds


def random_instances(seed, count, m):
    """Seeded mix of feasible (x* near / far), infeasible and row-rescaled instances, n = 1 and 2."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        n = 1 + k % 2
        if k % 7 == 6:
            G, h, xs, W = rand_infeasible(rng, n, m)
        else:
            G, h, xs, W, _ = rand_feasible(rng, n, m, spread=(0.1, 5.0, 50.0)[k % 3])
        if k % 5 == 4:  # rows rescaled over six decades: the same problem, harder numerics
            sc = 10.0 ** rng.uniform(-3, 3, m)
            G, h = G * sc[:, None], h * sc
        out.append((G, h, xs, W))
    return out


def degenerate_instances():
    """Hand-made corner cases, padded with loose rows (as in test_qp)."""
    rng = np.random.default_rng(42)

    def pad(G, h, m=17):
        G = np.asarray(G, float)
        Gr = rng.normal(size=(m - len(G), G.shape[1]))
        return np.concatenate([G, Gr]), np.concatenate([np.asarray(h, float), np.linalg.norm(Gr, axis=1) * 100])

    one = np.ones(2)
    cases = [
        (*pad([[1, 1]], [1]), np.array([2.0, 2.0]), one),                                   # one row
        (*pad([[1, 0], [0, 1]], [1, -1]), np.array([3.0, 3.0]), np.array([1.0, 2.0])),      # vertex
        (*pad([[1, 0], [0, 1], [1, 1]], [1, 1, 2]), np.array([3.0, 4.0]), one),             # 3 rows, 1 vertex
        (*pad([[1, 2], [1, 2], [1, 2], [2, 4]], [1, 1, 1, 2]), np.array([3.0, 3.0]), one),  # duplicates
        (*pad([[1, 1], [-1, -1]], [1, 0]), np.array([-2.0, 0.0]), one),                     # strip
        (*pad([[1, 1], [-1, -1]], [-1, -1]), np.array([0.0, 0.0]), one),                    # empty strip
        (*pad([[1, 1e-6], [1, -1e-6]], [0, 0]), np.array([1.0, 0.0]), one),                 # narrow wedge
        (*pad([[0, 0], [0, 0], [1, 0]], [0, 5, 1]), np.array([2.0, 7.0]), one),            # zero rows
        (*pad([[0, 0], [1, 0]], [-1, 1]), np.array([2.0, 7.0]), one),                       # 0 <= -1
        (*pad([[1, 1], [-1, -1], [1, -1], [-1, 1]], [0, 0, 0, 0]), np.array([1.0, 3.0]), one),  # a point
        (*pad([[1, 1], [1, -1]], [1, 0]), np.array([0.5, 0.5]), one),                       # x* on 2 rows
        (*pad([[1], [-2], [4]], [3, 2, 8]), np.array([5.0]), np.array([2.0])),              # n = 1 interval
        (*pad([[1], [-1]], [-1, -1]), np.array([5.0]), np.array([2.0])),                    # n = 1 empty
        (*pad([[0], [2]], [0, 1]), np.array([3.0]), np.array([1.0])),                       # n = 1 zero row
        (np.zeros((17, 2)), np.where(np.arange(17) == 3, -1.0, 0.0), np.array([1.0, 2.0]), one),  # G = 0
    ]
    # the controller's structure: every row twice, h of the copy shifted (the push estimate)
    for k in range(20):
        G0 = rng.normal(size=(17, 2)) * 10.0 ** rng.uniform(-1, 1, (17, 1))
        x0 = rng.normal(size=2)
        h0 = G0 @ x0 + rng.exponential(size=17)
        shift = rng.normal(size=17) * (0.0 if k % 4 == 0 else 0.3)
        cases.append((np.concatenate([G0, G0]), np.concatenate([h0, h0 + shift]),
                      x0 + 5 * rng.normal(size=2), rand_W(rng, 2)))
    return cases


# ----------------------------------------------------------------------------------------
# early-out decision
# ----------------------------------------------------------------------------------------


def reference_decision(G, h, x):
    v = constraint_values(G, x, h)
    return bool(np.all(v <= 0.0)), v >= -TOL


def ulp_boundary_instances(seed=3, count=400, m=QP_ROWS):
    """Rows with g x* - h exactly 0 in the reference expression, or one ulp of h either side:
    any other evaluation order, or a fused multiply-add, flips some of these decisions."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        n = 1 + k % 2
        G = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-2, 2, (m, 1))
        x = rng.normal(size=n) * 10.0 ** rng.uniform(-2, 2)
        h = constraint_values(G, x, np.zeros(m))                  # v = 0 on every row
        h = h + np.abs(h) * 1e-3 * (rng.random(m) < 0.7)           # most rows comfortably feasible
        i = rng.integers(m)
        h[i] = constraint_values(G[i:i + 1], x, np.zeros(1))[0]
        h[i] = (h[i], np.nextafter(h[i], -np.inf), np.nextafter(h[i], np.inf))[k % 3]
        out.append((G, h, x))
    return out


def test_early_out_decision_is_the_reference_one_bit_for_bit(real_instances):
    cases = [(G, h, xs) for _k, G, h, xs, _s in all_real(real_instances)]
    cases += [(G, h, xs) for G, h, xs, _W in random_instances(11, 600, 17)]
    cases += ulp_boundary_instances()
    n_feasible = 0
    for G, h, xs in cases:
        feasible, active = reference_decision(G, h, xs)
        for Gl in (G, np.asfortranarray(G), np.ascontiguousarray(G)):
            act = np.zeros(len(h), dtype=bool)
            code = qp_fast.early_out(Gl, h, xs, TOL, act)
            assert code == (qp_fast.EARLY_FEASIBLE if feasible else qp_fast.EARLY_NOT_FEASIBLE)
            if feasible:
                assert np.array_equal(act, active)
        n_feasible += feasible
    assert 0.2 * len(cases) < n_feasible < 0.9 * len(cases)
    # negative control: the ulp-boundary set does separate evaluation orders -- numpy's matmul
    # (BLAS, fused multiply-adds) decides some of them differently
    flips = sum(bool(np.all(G @ xs - h <= 0.0)) != reference_decision(G, h, xs)[0]
                for G, h, xs in ulp_boundary_instances())
    assert flips > 0


def test_early_out_agrees_with_exact_arithmetic_away_from_rounding(real_instances):
    """Where |fl(g x - h)| exceeds its rounding bound, the float sign is the sign of the exact
    rational value (fractions.Fraction holds every double exactly)."""
    checked = 0
    for _k, G, h, xs, _s in all_real(real_instances)[::7]:
        v = constraint_values(G, xs, h)
        bound = 8 * np.finfo(float).eps * (np.abs(G) @ np.abs(xs) + np.abs(h))
        for i in np.flatnonzero(np.abs(v) > bound):
            exact = sum(Fraction(float(g)) * Fraction(float(x)) for g, x in zip(G[i], xs)) - Fraction(float(h[i]))
            assert (exact > 0) == (v[i] > 0)
            checked += 1
    assert checked > 5000


@pytest.mark.parametrize("bad", ["G", "h", "x_star"])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_early_out_non_finite(bad, value):
    rng = np.random.default_rng(1)
    G, h, xs, W, _ = rand_feasible(rng, 2)
    data = {"G": G.copy(), "h": h.copy(), "x_star": xs.copy()}
    data[bad].flat[-1] = value
    active = np.zeros(len(h), dtype=bool)
    assert qp_fast.early_out(data["G"], data["h"], data["x_star"], TOL, active) == qp_fast.EARLY_NONFINITE
    for solver in ("piqp", "exact"):
        r = AdaptationQP(2, 17, W, solver=solver).solve(data["G"], data["h"], data["x_star"])
        assert r.status == SOLVER_ERROR and bad in r.message


def test_kernels_reject_other_types_instead_of_compiling():
    G, h, x = np.ones((3, 2)), np.ones(3), np.ones(2)
    with pytest.raises(TypeError):
        qp_fast.early_out(G.astype(np.float32), h, x, TOL, np.zeros(3, dtype=bool))
    with pytest.raises(TypeError):
        qp_fast.solve_small(G, h.astype(np.int64), x, np.ones(2), TOL, 1e-9, 1e-10, 1e-10, 1e-13,
                            np.zeros(2), np.zeros(3), np.zeros(3, dtype=bool))
    # AdaptationQP converts what numpy can convert, any layout
    s = AdaptationQP(2, 3, [1.0, 1.0])
    r1 = s.solve([[1, 0], [0, 1], [1, 1]], [1, 1, 1], [2, 2])
    big = np.zeros((3, 4))
    big[:, ::2] = [[1, 0], [0, 1], [1, 1]]
    r2 = s.solve(big[:, ::2], np.ones(6)[::2], np.array([2.0, 0.0, 2.0])[::2])
    assert r1.status == r2.status == ACTIVE and np.array_equal(r1.x, r2.x)


# ----------------------------------------------------------------------------------------
# compiled exact solver == qp_exact
# ----------------------------------------------------------------------------------------


def test_compiled_exact_equals_qp_exact_on_real_instances(real_instances):
    counts = {}
    for key, G, h, xs, _s in all_real(real_instances):
        for W in (np.ones(G.shape[1]), np.array([1.0, 4.0])[:G.shape[1]]):
            a, b = fast_exact(G, h, xs, W), qp_exact.solve_exact(G, h, xs, W)
            assert_identical(a, b, key)
            if a.status == ACTIVE:
                assert np.max(np.abs(a.z - b.z)) <= IDENTICAL * scale(b.z)
            if a.status != UNCONSTRAINED:
                assert_kkt_answer(G, h, xs, W, a, key)
            counts[a.status] = counts.get(a.status, 0) + 1
    assert counts[ACTIVE] > 500 and counts[INFEASIBLE_FALLBACK] >= 6 and counts[UNCONSTRAINED] > 2000


@pytest.mark.parametrize("m", [17, QP_ROWS])
def test_compiled_exact_equals_qp_exact_on_random_instances(m):
    counts = {}
    for i, (G, h, xs, W) in enumerate(random_instances(100 + m, 1200, m)):
        a, b = fast_exact(G, h, xs, W), qp_exact.solve_exact(G, h, xs, W)
        assert_identical(a, b, i)
        if a.status != UNCONSTRAINED:
            assert_kkt_answer(G, h, xs, W, a, i)
        counts[a.status] = counts.get(a.status, 0) + 1
    assert min(counts.get(s, 0) for s in (UNCONSTRAINED, ACTIVE, INFEASIBLE_FALLBACK)) > 100, counts


def test_compiled_exact_equals_qp_exact_on_degenerate_instances():
    for i, (G, h, xs, W) in enumerate(degenerate_instances()):
        a, b = fast_exact(G, h, xs, W), qp_exact.solve_exact(G, h, xs, W)
        # ties between equivalent candidates (3 rows through one vertex, duplicates) may name
        # other rows and split z otherwise; x, the status and the KKT conditions may not differ
        assert_identical(a, b, i, messages=False)
        if a.status != UNCONSTRAINED:
            assert_kkt_answer(G, h, xs, W, a, i)


def test_compiled_exact_error_results_equal_qp_exact():
    rng = np.random.default_rng(2)
    G, h, xs, W, _ = rand_feasible(rng, 2)
    for bad in ("G", "h", "x_star", "W"):
        data = {"G": G.copy(), "h": h.copy(), "x_star": xs.copy(), "W": W.copy()}
        data[bad].flat[0] = np.nan
        a = fast_exact(data["G"], data["h"], data["x_star"], data["W"])
        b = qp_exact.solve_exact(data["G"], data["h"], data["x_star"], data["W"])
        assert a.status == b.status == SOLVER_ERROR and a.message == b.message
        assert np.array_equal(a.x, b.x, equal_nan=True)
    a = fast_exact(G, h, xs, np.array([1.0, -1.0]))
    assert a.status == SOLVER_ERROR and a.message == qp_exact.solve_exact(G, h, xs, np.array([1.0, -1.0])).message


def test_symmetric_pseudo_inverse_matches_lstsq():
    """The min-norm solve of the least-violation Newton step on singular pieces."""
    rng = np.random.default_rng(9)
    for k in range(300):
        u = rng.normal(size=2)
        u /= np.linalg.norm(u)
        lam = 10.0 ** rng.uniform(-3, 3, 2)
        if k % 3 == 0:
            lam[1] = lam[0] * 1e-15      # numerically singular
        if k % 5 == 0:
            lam[1] = 0.0
        V = np.array([[u[0], -u[1]], [u[1], u[0]]])
        H = V @ np.diag(lam) @ V.T
        H = 0.5 * (H + H.T)
        g = rng.normal(size=2)
        ref = np.linalg.lstsq(H, g, rcond=1e-13)[0]
        got = np.array(qp_fast._sym2_pinv_solve(H[0, 0], H[0, 1], H[1, 1], g[0], g[1], 1e-13))
        assert np.allclose(got, ref, rtol=1e-9, atol=1e-12 * np.linalg.norm(ref)), (H, g, got, ref)


# ----------------------------------------------------------------------------------------
# presolve and polish (the PIQP path)
# ----------------------------------------------------------------------------------------


def test_presolve_drops_duplicates_keeping_the_tightest_row():
    rng = np.random.default_rng(4)
    feasible_seen = 0
    for k in range(200):
        n = 1 + k % 2
        base = rng.normal(size=(6, n))
        pick = rng.integers(6, size=25)
        G = base[pick]
        xs = rng.normal(size=n)
        # half feasible by construction (duplicates with different slacks), half random
        h = G @ rng.normal(size=n) + rng.exponential(size=25) if k % 2 else rng.normal(size=25)
        W = rand_W(rng, n)
        gb, hb, c, rows = np.zeros(25 * n), np.zeros(25), np.zeros(n), np.zeros(25, np.int64)
        kk = qp_fast.load_piqp(G, h, xs, W, gb, hb, c, rows)
        kept = rows[:kk]
        # reference: per distinct row, the first index of its least h
        ref = []
        for u in dict.fromkeys(map(tuple, G)):        # first-occurrence order
            idx = [i for i in range(25) if tuple(G[i]) == u]
            ref.append(min(idx, key=lambda i: (h[i], i)))
        assert list(kept) == ref
        assert np.array_equal(gb[:kk * n].reshape(n, kk).T, G[kept])
        assert np.array_equal(hb[:kk], h[kept]) and np.array_equal(c, -W * xs)
        # the reduced problem is feasible iff the full one is, with the same optimum (the
        # least-violation answer of an infeasible one does count duplicates: it is computed on
        # the full problem)
        a, b = qp_exact.solve_exact(G[kept], h[kept], xs, W), qp_exact.solve_exact(G, h, xs, W)
        assert a.status == b.status
        if b.status != INFEASIBLE_FALLBACK:
            assert np.max(np.abs(a.x - b.x)) <= IDENTICAL * scale(b.x)
            feasible_seen += 1
    assert feasible_seen > 50


def test_polish_recovers_the_optimum_from_perturbed_answers():
    rng = np.random.default_rng(5)
    done = 0
    for G, h, xs, W in random_instances(6, 400, 17):
        ex = qp_exact.solve_exact(G, h, xs, W)
        if ex.status != ACTIVE:
            continue
        # an interior-point-like answer: x slightly inside, z blurred, inactive rows small
        x = ex.x - 1e-7 * scale(ex.x) * rng.normal(size=xs.size)
        z = ex.z * (1 + 1e-3 * rng.normal(size=ex.z.size)) + 1e-9 * np.max(ex.z) * rng.random(ex.z.size)
        out = polish(G, h, xs, W, z, x)
        assert out is not None
        assert np.max(np.abs(out[0] - ex.x)) <= 1e-9 * scale(ex.x)
        k = kkt_residuals(G, h, xs, W, out[0], out[1])
        assert max(k[key] for key in ("primal", "dual", "complementarity", "stationarity")) <= 1e-8 * scale(h) ** 2
        done += 1
    assert done > 100


def test_polish_rejects_a_wrong_active_set():
    # optimum of min |x - (3, 0)|^2 s.t. x0 <= 1, x1 <= 5 is (1, 0) on row 0; claim row 1 instead
    G = np.array([[1.0, 0.0], [0.0, 1.0]])
    h = np.array([1.0, 5.0])
    xs, W = np.array([3.0, 0.0]), np.ones(2)
    assert polish(G, h, xs, W, np.array([0.0, 1.0]), np.array([1.0, 4.9])) is None
    good = polish(G, h, xs, W, np.array([2.0, 0.0]), np.array([1.0 - 1e-7, 0.0]))
    assert np.array_equal(good[0], [1.0, 0.0]) and np.array_equal(good[1], [2.0, 0.0])


# ----------------------------------------------------------------------------------------
# AdaptationQP on the controller's instances: both solvers
# ----------------------------------------------------------------------------------------


def test_adaptation_qp_solvers_on_real_instances(real_instances):
    """solver="piqp" (the product's) and solver="exact" against qp_exact on every recorded step."""
    for (mode, force), inst in real_instances.items():
        n = inst[0][0].shape[1]
        W = np.array([1.0, 2.5])[:n]
        piqp_qp = AdaptationQP(n, QP_ROWS, W)
        exact_qp = AdaptationQP(n, QP_ROWS, W, solver="exact")
        polished = active = 0
        for i, (G, h, xs, _s) in enumerate(inst):
            what = (mode, force, i)
            ref = qp_exact.solve_exact(G, h, xs, W)
            r_p, r_e = piqp_qp.solve(G, h, xs), exact_qp.solve(G, h, xs)
            assert r_p.status == ref.status, (what, r_p, ref)
            assert_identical(r_e, ref, what)
            if ref.status == UNCONSTRAINED:
                for r in (r_p, r_e):
                    assert r.x.tobytes() == xs.tobytes() and r.x is not xs
                    assert not r.z.any() and not r.z.flags.writeable
                continue
            for r in (r_p, r_e):
                assert_kkt_answer(G, h, xs, W, r, what)
            if ref.status == ACTIVE:
                active += 1
                polished += "polished" in r_p.message
                assert np.max(np.abs(r_p.x - ref.x)) <= 1e-9 * scale(ref.x), (what, r_p, ref)
            else:  # PIQP reports infeasibility, the exact fallback answers
                assert "PRIMAL_INFEASIBLE" in r_p.message
                assert np.max(np.abs(r_p.x - ref.x)) <= IDENTICAL * scale(ref.x)
        assert active > 10 and polished >= 0.95 * active, (mode, force, polished, active)
        # the presolve: each contact/actuator row appears twice in G, PIQP sees it once (20 rows;
        # 19 in mode tau, where the two p-range rows become equal zero rows)
        assert set(piqp_qp.piqp_solvers) <= {QP_ROWS, N_CONSTRAINTS + 3, N_CONSTRAINTS + 2}


# ----------------------------------------------------------------------------------------
# compilation cache
# ----------------------------------------------------------------------------------------


def _import_exact_kernels(env):
    code = ("import numba; from biped_controller.core.qp.solver import load_exact_kernels; load_exact_kernels(); "
            "print(numba.config.CACHE_DIR)")
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=900)


def test_cache_lives_in_the_build_area():
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    out = _import_exact_kernels(env)
    assert out.returncode == 0, out.stderr
    assert Path(out.stdout.strip()) == ROOT / "build" / "numba-cache"


@pytest.mark.slow
def test_first_import_says_it_compiles_then_loads_silently(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    first = _import_exact_kernels(env)
    assert first.returncode == 0, first.stderr
    from biped_model.numba_cache import COMPILE_NOTICE
    assert COMPILE_NOTICE in first.stderr and "compiled in" in first.stderr
    assert list(tmp_path.rglob("exact_kernels.early_out-*.nbi"))
    second = _import_exact_kernels(env)
    assert second.returncode == 0, second.stderr
    assert "compiling" not in second.stderr
