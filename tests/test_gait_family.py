"""Independent checks of the reference gait family (config/gait_family.json) and of gait_family.py.

Every optimised stride is re-checked from its own polynomial (the ``a`` coefficients of its record),
with the project's models but none of the optimiser's code: periodicity through the floating-base
impact map, the 17 true constraints on a grid 10x finer than the optimisation grid, swing-foot
clearance, landing point, and the impact itself (compressive impulse in the friction cone, the old
foot lifting off). Then the fitted family b_ijk: exact at p_d, fit error at the other strides, its
partial derivatives and eq. (11) against finite differences, and ``fit_family`` on synthetic data.
Random draws are seeded.
"""
from __future__ import annotations

import json
import math
import subprocess
import time

import numpy as np
import pytest

from helpers import ROOT, assert_close

from biped_sim.floating import FloatingModel, impact_paper
from biped_sim.gait_family import GaitFamily, fit_family
from biped_controller.model import N_CONSTRAINTS, CONSTRAINT_NAMES, FixedFootModel, relabel

FAMILY_FILE = ROOT / "config" / "gait_family.json"
DATA = json.loads(FAMILY_FILE.read_text(encoding="utf-8"))
FAM = GaitFamily.load(FAMILY_FILE)
RECORDS = [r for r in DATA["strides"] if r["success"]]
STRIDES = [r["stride"] for r in RECORDS]
GRID = int(DATA["settings"]["grid_intervals"]["value"])
FINE = 10 * GRID

# Fit tolerance of the family at the optimised strides other than p_d. Read from the file when it states
# one; otherwise the project's stated tolerance (1e-3 rad on q, 1e-2 rad/s on q').
_TOL_SRC = {**DATA.get("settings", {}), **DATA.get("validation", {})}


def _tol(keys, default):
    for k in keys:
        v = _TOL_SRC.get(k)
        if isinstance(v, dict):
            v = v.get("value")
        if isinstance(v, (int, float)):
            return float(v)
    return default


FIT_TOL_Q = _tol(("fit_tolerance_q", "fit_tol_q", "fit_error_q_tolerance"), 1e-3)
FIT_TOL_QD = _tol(("fit_tolerance_qdot", "fit_tol_qdot", "fit_error_qdot_tolerance"), 1e-2)


@pytest.fixture(scope="module")
def fixed():
    return FixedFootModel()


@pytest.fixture(scope="module")
def floating():
    return FloatingModel()


def poly(a: np.ndarray, t: np.ndarray):
    """q, q', q'' of q_i(t) = sum_j a_ij t^j at the times t (arrays (len(t), 6))."""
    a = np.asarray(a, dtype=float)
    j = np.arange(a.shape[1])
    t = np.atleast_1d(t)[:, None]
    q = (t ** j) @ a.T
    qd = (np.where(j >= 1, j * t ** np.maximum(j - 1, 0), 0.0)) @ a.T
    qdd = (np.where(j >= 2, j * (j - 1) * t ** np.maximum(j - 2, 0), 0.0)) @ a.T
    return q, qd, qdd


def sole_heights(fixed: FixedFootModel, q: np.ndarray) -> tuple[float, float]:
    pose, _ = fixed.swing_foot(q)
    ft = fixed.desc.foot
    return tuple(pose[1] + l * math.sin(pose[2]) for l in (ft.l_min, ft.l_max))


# ------------------------------------------------------------------ the optimised strides
def test_file_has_optimised_strides():
    assert len(RECORDS) >= 2 and FAM.p_d in STRIDES
    assert all(np.array(r["a"]).shape == (6, 5) for r in RECORDS)
    assert FAM.p_min <= FAM.p_d <= FAM.p_max


@pytest.mark.parametrize("rec", RECORDS, ids=[f"p={p}" for p in STRIDES])
def test_periodicity(rec, floating):
    """q(0) = relabel(q(T)) and q'(0) = impact map of (q(T), q'(T)) (relabelled), to 1e-6."""
    T = rec["T"]
    q, qd, _ = poly(rec["a"], np.array([0.0, T]))
    qd_new, _ = impact_paper(floating, q[1], qd[1])
    res = max(float(np.max(np.abs(q[0] - relabel(q[1])))), float(np.max(np.abs(qd[0] - qd_new))))
    assert res < 1e-6, f"p = {rec['stride']}: periodicity residual {res:.3e}"


@pytest.mark.parametrize("rec", RECORDS, ids=[f"p={p}" for p in STRIDES])
def test_true_constraints_on_fine_grid(rec, fixed):
    """All 17 constraints of eq. (10) (no design margins) hold strictly on a grid 10x finer."""
    t = np.linspace(0.0, rec["T"], FINE + 1)
    q, qd, qdd = poly(rec["a"], t)
    worst, where = np.inf, None
    for k in range(t.size):
        m = fixed.margins_direct(q[k], qd[k], qdd[k])
        assert m.shape == (N_CONSTRAINTS,)
        i = int(np.argmin(m / fixed.row_scale))
        if m[i] / fixed.row_scale[i] < worst:
            worst, where = m[i] / fixed.row_scale[i], (t[k], CONSTRAINT_NAMES[i], m[i])
    assert worst > 0.0, f"p = {rec['stride']}: constraint {where[1]} violated at t = {where[0]:.4f} s (margin {where[2]:.4g})"


@pytest.mark.parametrize("rec", RECORDS, ids=[f"p={p}" for p in STRIDES])
def test_clearance_and_landing(rec, fixed):
    """Heel and toe of the swing foot strictly above the ground inside the step; lands flat at (p, 0)."""
    T, p = rec["T"], rec["stride"]
    t = np.linspace(0.0, T, FINE + 1)[1:-1]
    q, _, _ = poly(rec["a"], t)
    low = min(min(sole_heights(fixed, qk)) for qk in q)
    assert low > 0.0, f"p = {p}: swing foot touches the ground inside the step (min height {low:.3e} m)"
    qT, _, _ = poly(rec["a"], np.array([T]))
    pose, _ = fixed.swing_foot(qT[0])
    assert_close(pose, [p, 0.0, 0.0], 1e-6, f"p = {p}: swing ankle (x, z, angle) at touchdown")
    # the step starts in the same posture mirrored: the rear foot is at (-p, 0) flat
    q0, _, _ = poly(rec["a"], np.array([0.0]))
    pose0, _ = fixed.swing_foot(q0[0])
    assert_close(pose0, [-p, 0.0, 0.0], 1e-6, f"p = {p}: swing ankle at lift-off")


@pytest.mark.parametrize("rec", RECORDS, ids=[f"p={p}" for p in STRIDES])
def test_impact_map(rec, floating):
    """Impact at the end of the step: the ground's impulse on the landing foot is compressive and inside
    the friction cone; the former stance foot leaves the ground (vertical velocity >= 0); energy is lost."""
    mu = floating.desc.mu
    q, qd, _ = poly(rec["a"], np.array([rec["T"]]))
    _, res = impact_paper(floating, q[0], qd[0])
    lam_x, lam_z = res.impulse[0], res.impulse[1]
    assert lam_z > 0.0, f"p = {rec['stride']}: tensile impulse {lam_z}"
    assert abs(lam_x) <= mu * lam_z, f"p = {rec['stride']}: impulse outside the friction cone {res.impulse}"
    assert res.old_foot_velocity[1] >= 0.0, f"p = {rec['stride']}: old foot moves down {res.old_foot_velocity}"
    assert res.energy_loss > 0.0
    # the KKT form of the same impact agrees
    x, v = floating.state_from_paper(q[0], qd[0], 0)
    v_plus, lam = floating.impact_kkt(x, v, 1)
    assert_close(v_plus, res.v_plus, 1e-9, "impact: Schur vs KKT v+")
    assert_close(lam, res.impulse, 1e-7, "impact: Schur vs KKT impulse")


# ------------------------------------------------------------------ the fitted family
def test_family_exact_at_p_d():
    rec = next(r for r in RECORDS if r["stride"] == FAM.p_d)
    t = np.linspace(0.0, FAM.T, 201)
    q, qd, qdd = poly(rec["a"], t)
    Q = np.array([FAM.evaluate(FAM.p_d, x).q for x in t])
    QD = np.array([FAM.evaluate(FAM.p_d, x).dq_dtau for x in t])
    assert_close(Q, q, 1e-9, "family q_d(p_d, t) vs the optimised preferred step")
    # q' is the t-derivative of the same expansion: round-off of the power basis in p (|b_ijk| up to ~1e9,
    # p^k summed with cancellation) is ~1e-9 on q and a few 1e-9 rad/s on q'
    assert_close(QD, qd, 1e-8, "family q_d'(p_d, t) vs the optimised preferred step")


def fit_errors() -> list[tuple[float, float, float]]:
    t = np.linspace(0.0, FAM.T, 401)
    out = []
    for rec in RECORDS:
        p = rec["stride"]
        if p == FAM.p_d or not (FAM.p_min <= p <= FAM.p_max):
            continue
        q, qd, _ = poly(rec["a"], t)
        Q = np.array([FAM.evaluate(p, x).q for x in t])
        QD = np.array([FAM.evaluate(p, x).dq_dtau for x in t])
        out.append((p, float(np.max(np.abs(Q - q))), float(np.max(np.abs(QD - qd)))))
    return out


def test_fit_error_at_other_strides():
    """The degree-7 fit reproduces every other optimised stride in [p_min, p_max] within the stated
    tolerance (FIT_TOL_Q rad on q, FIT_TOL_QD rad/s on q')."""
    errs = fit_errors()
    assert errs, "no optimised stride other than p_d inside the family's range"
    eq = max(errs, key=lambda e: e[1])
    ev = max(errs, key=lambda e: e[2])
    table = ", ".join(f"p={p}: {a:.2e}/{b:.2e}" for p, a, b in errs)
    assert eq[1] <= FIT_TOL_Q and ev[2] <= FIT_TOL_QD, (
        f"committed family misses the fit tolerance {FIT_TOL_Q:g} rad / {FIT_TOL_QD:g} rad/s: "
                     f"max q error {eq[1]:.3e} rad at p = {eq[0]}, max q' error {ev[2]:.3e} rad/s at p = {ev[0]} "
                     f"(range [{FAM.p_min}, {FAM.p_max}]; per stride q/q': {table})")


def test_fit_error_matches_file():
    """The validation numbers stored in the file are the ones recomputed here (no stale figures)."""
    stored = {round(r["stride"], 9): r for r in DATA["validation"]["strides"]}
    for p, eq, ev in fit_errors():
        r = stored.get(round(p, 9))
        if r is None:
            continue
        assert abs(r["fit_error_q"] - eq) <= 1e-6 + 0.01 * eq, (p, r["fit_error_q"], eq)


RNG_POINTS = np.random.default_rng(20240611).uniform([0.0, 0.0], [1.0, 1.0], size=(12, 2))


@pytest.mark.parametrize("u", RNG_POINTS, ids=[f"pt{i}" for i in range(len(RNG_POINTS))])
def test_partial_derivatives(u):
    """dq/dp, dq/dtau, d2q/dp2, d2q/dtau2, d2q/dp dtau against central finite differences."""
    p = FAM.p_min + u[0] * (FAM.p_max - FAM.p_min)
    tau = u[1] * FAM.T
    g = FAM.evaluate(p, tau)
    hp, ht = 1e-3, 1e-3
    E = lambda pp, tt: FAM.evaluate(pp, tt)  # noqa: E731

    def d1(f, h):  # 4th-order central difference of f(s) at s = 0
        return (8 * (f(h) - f(-h)) - (f(2 * h) - f(-2 * h))) / (12 * h)

    fd_p = d1(lambda e: E(p + e, tau).q, hp)
    fd_t = d1(lambda e: E(p, tau + e).q, ht)
    fd_pp2 = d1(lambda e: E(p + e, tau).dq_dp, hp)
    fd_tt2 = d1(lambda e: E(p, tau + e).dq_dtau, ht)
    fd_pt2 = d1(lambda e: E(p, tau + e).dq_dp, ht)
    fd_tp2 = d1(lambda e: E(p + e, tau).dq_dtau, hp)
    h2 = 1e-4
    fd_pp = (E(p + h2, tau).q - 2 * g.q + E(p - h2, tau).q) / h2**2
    fd_tt = (E(p, tau + h2).q - 2 * g.q + E(p, tau - h2).q) / h2**2
    fd_pt = (E(p + h2, tau + h2).q - E(p + h2, tau - h2).q - E(p - h2, tau + h2).q + E(p - h2, tau - h2).q) / (4 * h2 * h2)
    assert_close(g.dq_dp, fd_p, 1e-6, "dq/dp", rel=True)
    assert_close(g.dq_dtau, fd_t, 1e-7, "dq/dtau", rel=True)
    assert_close(g.d2q_dp2, fd_pp2, 1e-6, "d2q/dp2 (FD of dq/dp)", rel=True)
    assert_close(g.d2q_dtau2, fd_tt2, 1e-7, "d2q/dtau2 (FD of dq/dtau)", rel=True)
    assert_close(g.d2q_dp_dtau, fd_pt2, 1e-7, "d2q/dp dtau (FD in tau of dq/dp)", rel=True)
    assert_close(g.d2q_dp_dtau, fd_tp2, 1e-6, "d2q/dp dtau (FD in p of dq/dtau)", rel=True)
    assert_close(g.d2q_dp2, fd_pp, 2e-2, "d2q/dp2 (second difference of q)", rel=True)
    assert_close(g.d2q_dtau2, fd_tt, 1e-3, "d2q/dtau2 (second difference of q)", rel=True)
    assert_close(g.d2q_dp_dtau, fd_pt, 1e-3, "d2q/dp dtau (mixed difference of q)", rel=True)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_reference_is_eq_11(seed):
    """q_d' and q_d'' returned by GaitFamily.reference are the time derivatives of q_d(p(t), tau(t)) along a
    smooth random (p(t), tau(t)) (4th-order central differences in t)."""
    rng = np.random.default_rng(seed)
    amp_p, w_p, ph_p = rng.uniform(0.01, 0.04), rng.uniform(3, 12), rng.uniform(0, 2 * np.pi)
    amp_t, w_t, ph_t = rng.uniform(0.005, 0.02), rng.uniform(3, 12), rng.uniform(0, 2 * np.pi)
    p_c = 0.5 * (FAM.p_min + FAM.p_max)

    def P(t):
        return p_c + amp_p * np.sin(w_p * t + ph_p), amp_p * w_p * np.cos(w_p * t + ph_p), -amp_p * w_p**2 * np.sin(w_p * t + ph_p)

    def TAU(t):  # tau' = 1 + amp w cos > 0
        return 0.9 * t + amp_t * np.sin(w_t * t + ph_t), 0.9 + amp_t * w_t * np.cos(w_t * t + ph_t), -amp_t * w_t**2 * np.sin(w_t * t + ph_t)

    def Q(t):
        return FAM.evaluate(P(t)[0], TAU(t)[0]).q

    def REF(t):
        (p, pd, pdd), (tau, td, tdd) = P(t), TAU(t)
        return FAM.reference(p, pd, tau, td, pdd, tdd)

    def d1(f, t, h):
        return (8 * (f(t + h) - f(t - h)) - (f(t + 2 * h) - f(t - 2 * h))) / (12 * h)

    for t in np.linspace(0.02, 0.4, 7):
        q, qd, qdd = REF(t)
        assert_close(q, Q(t), 0.0, "reference q_d")
        # h = 1e-3: the power basis in p (|b_ijk| up to ~1e9) leaves ~1e-10 of round-off in q_d, which a
        # smaller step would amplify; the 4th-order truncation error at this step is ~1e-8
        assert_close(qd, d1(Q, t, 1e-3), 1e-6, f"q_d' vs d/dt q_d at t = {t:.3f}", rel=True)
        assert_close(qdd, d1(lambda s: REF(s)[1], t, 1e-3), 1e-6, f"q_d'' vs d/dt q_d' at t = {t:.3f}", rel=True)
        # and straight from q_d: 4th-order second difference (h large enough for the power basis' round-off)
        h = 2e-3
        fd2 = (-(Q(t + 2 * h) + Q(t - 2 * h)) + 16 * (Q(t + h) + Q(t - h)) - 30 * Q(t)) / (12 * h * h)
        assert_close(qdd, fd2, 1e-4, f"q_d'' vs d2/dt2 q_d at t = {t:.3f}", rel=True)


# ------------------------------------------------------------------ fit_family on synthetic data
@pytest.mark.parametrize("degree", [0, 3, 7])
def test_fit_family_recovers_polynomials(degree):
    """a_ij(p) polynomial of degree <= 7 in p, sampled at the file's strides: the fit is exact."""
    rng = np.random.default_rng(100 + degree)
    strides = np.array(DATA["settings"]["strides"]["value"], dtype=float)
    p_d = FAM.p_d
    coef_u = rng.normal(size=(6, 5, degree + 1)) * 0.5 ** np.arange(degree + 1)  # in powers of u = p - p_d
    def a_true(p):
        u = p - p_d
        return coef_u @ (u ** np.arange(degree + 1))
    a = np.array([a_true(p) for p in strides])
    b = fit_family(strides, a, p_d, 7)
    fam = GaitFamily(b, FAM.T, p_d, float(strides.min()), float(strides.max()))
    for p in np.linspace(strides.min(), strides.max(), 23):
        a_fit, _, _ = fam.coefficients(p)
        assert_close(a_fit, a_true(p), 1e-8, f"degree {degree}: a(p) at p = {p:.4f}")
    a_fit, _, _ = fam.coefficients(p_d)
    assert_close(a_fit, a_true(p_d), 1e-12, "fit at p_d")


def test_fit_family_passes_through_p_d_exactly():
    """With data that no degree-7 polynomial fits (noise), the fit still passes through p_d exactly."""
    rng = np.random.default_rng(7)
    strides = np.array(DATA["settings"]["strides"]["value"], dtype=float)
    a = rng.normal(size=(strides.size, 6, 5))
    b = fit_family(strides, a, FAM.p_d, 7)
    fam = GaitFamily(b, FAM.T, FAM.p_d, float(strides.min()), float(strides.max()))
    i = int(np.flatnonzero(strides == FAM.p_d)[0])
    a_fit, _, _ = fam.coefficients(FAM.p_d)
    # exact up to the round-off of evaluating sum_k b_k p^k: eps * sum_k |b_k| p_d^k
    roundoff = np.finfo(float).eps * float(np.max(np.abs(b) @ (FAM.p_d ** np.arange(b.shape[2]))))
    assert_close(a_fit, a[i], 100 * roundoff, "fit at p_d with noisy data")
    others = np.array([fam.coefficients(p)[0] for p in strides])
    assert float(np.max(np.abs(others - a))) > 1e-3  # the noisy data is not interpolated elsewhere
    with pytest.raises(ValueError):
        fit_family(strides[strides != FAM.p_d], a[strides != FAM.p_d], FAM.p_d, 7)


# ------------------------------------------------------------------ the generator's own check
def test_generate_gait_family_check(tmp_path):
    out = tmp_path / "validation.json"
    t0 = time.perf_counter()
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "generate_gait_family"), "--check", "--json", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    elapsed = time.perf_counter() - t0
    assert proc.returncode == 0, f"exit {proc.returncode} after {elapsed:.1f} s\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    v = json.loads(out.read_text())
    assert v["fitted_min_margin"] > 0 and v["fitted_min_clearance"] > 0
    # how long --check takes is not asserted here (machines vary up to 3x): speed lives in benchmarks/
