"""Independent checks of the reference gait family (robots/biped7/gait_family.json) and of gait_family.py.

Every optimised stride, fitted and held out, is re-checked from its own polynomial (the ``a``
coefficients of its record) with the project's models but none of the optimiser's code: periodicity
through the floating-base impact map, the 17 true constraints on a grid 10x finer than the optimisation
grid, swing-foot clearance, landing point, and the impact itself. Then the fitted family: exact at p_d,
fit error at the fitted strides and at held-out strides (optimised but not used for the fit), continuity
of a, da/dp, d2a/dp2 across the spline's breakpoints, the partial derivatives and eq. (11) against
finite differences, the true constraints, clearance and periodicity of the family between the strides,
and the JSON round trip (both representations). The spline construction is checked against SciPy's
CubicSpline. Random draws are seeded.
"""
from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest

from helpers import ROOT, assert_close

from biped_model.floating import FloatingModel, impact_paper
from biped_model.gait_family import (POLYNOMIAL, SPLINE, GaitFamily, GaitFamilyError, fit_family, fit_spline_family,
                                   spline_pieces)
from biped_model.fixed_foot import N_CONSTRAINTS, CONSTRAINT_NAMES, FixedFootModel, relabel

FAMILY_FILE = ROOT / "robots" / "biped7" / "gait_family.json"
DATA = json.loads(FAMILY_FILE.read_text(encoding="utf-8"))
FAM = GaitFamily.load(FAMILY_FILE)
RECORDS = [r for r in DATA["strides"] if r["success"]]
STRIDES = [r["stride"] for r in RECORDS]
HELD_OUT = DATA.get("held_out", [])
GRID = int(DATA["settings"]["grid_intervals"]["value"])
FINE = 10 * GRID
SETTINGS = DATA["settings"]
# The tolerances the family was generated against (robots/biped7/gait.yaml, copied into the file).
FIT_TOL_Q = float(SETTINGS["fit_tolerance_q"]["value"])
FIT_TOL_QD = float(SETTINGS["fit_tolerance_qdot"]["value"])
ALL_STEPS = RECORDS + HELD_OUT
ALL_IDS = [f"p={r['stride']}" for r in RECORDS] + [f"held-out p={r['stride']:.5f}" for r in HELD_OUT]


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


def worst_true_margin(fixed: FixedFootModel, q, qd, qdd, t) -> tuple[float, tuple]:
    """Smallest scaled margin of the 17 constraints of eq. (10) over the samples, and where."""
    worst, where = np.inf, None
    for k in range(len(t)):
        m = fixed.margins_direct(q[k], qd[k], qdd[k])
        assert m.shape == (N_CONSTRAINTS,)
        i = int(np.argmin(m / fixed.row_scale))
        if m[i] / fixed.row_scale[i] < worst:
            worst, where = m[i] / fixed.row_scale[i], (t[k], CONSTRAINT_NAMES[i], m[i])
    return worst, where


# ------------------------------------------------------------------ the optimised strides
def test_file_has_optimised_strides():
    assert len(RECORDS) >= 2 and FAM.p_d in STRIDES
    assert all(np.array(r["a"]).shape == (6, 5) for r in ALL_STEPS)
    assert FAM.p_min <= FAM.p_d <= FAM.p_max
    # every stride of the settings was optimised (none failed and was dropped silently)
    assert [r["stride"] for r in DATA["strides"]] == [float(p) for p in SETTINGS["strides"]["value"]]
    assert all(r["success"] for r in DATA["strides"]), [r["stride"] for r in DATA["strides"] if not r["success"]]


def test_held_out_strides_are_not_fitted():
    """Held-out strides lie strictly between consecutive fitted strides, one per interval of the range,
    and none of them is a fitted stride or a breakpoint of the family."""
    assert HELD_OUT, "the family file has no held-out strides"
    inside = [p for p in STRIDES if FAM.p_min <= p <= FAM.p_max]
    held = sorted(r["stride"] for r in HELD_OUT if FAM.p_min <= r["stride"] <= FAM.p_max)
    assert len(held) == len(inside) - 1
    for lo, hi, p in zip(inside[:-1], inside[1:], held):
        assert lo < p < hi
    knots = set(getattr(FAM, "breakpoints", []))
    assert not knots.intersection(held) and not set(STRIDES).intersection(held)
    assert all(r["success"] for r in HELD_OUT)


@pytest.mark.parametrize("rec", ALL_STEPS, ids=ALL_IDS)
def test_periodicity(rec, floating):
    """q(0) = relabel(q(T)) and q'(0) = impact map of (q(T), q'(T)) (relabelled), to 1e-6."""
    T = rec["T"]
    q, qd, _ = poly(rec["a"], np.array([0.0, T]))
    qd_new, _ = impact_paper(floating, q[1], qd[1])
    res = max(float(np.max(np.abs(q[0] - relabel(q[1])))), float(np.max(np.abs(qd[0] - qd_new))))
    assert res < 1e-6, f"p = {rec['stride']}: periodicity residual {res:.3e}"


@pytest.mark.parametrize("rec", ALL_STEPS, ids=ALL_IDS)
def test_true_constraints_on_fine_grid(rec, fixed):
    """All 17 constraints of eq. (10) (no design margins) hold strictly on a grid 10x finer."""
    t = np.linspace(0.0, rec["T"], FINE + 1)
    q, qd, qdd = poly(rec["a"], t)
    worst, where = worst_true_margin(fixed, q, qd, qdd, t)
    assert worst > 0.0, f"p = {rec['stride']}: constraint {where[1]} violated at t = {where[0]:.4f} s (margin {where[2]:.4g})"


@pytest.mark.parametrize("rec", ALL_STEPS, ids=ALL_IDS)
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


@pytest.mark.parametrize("rec", ALL_STEPS, ids=ALL_IDS)
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
def test_range_is_the_widest_verified():
    """The committed family is the spline through strides optimised over the paper's 0.30-0.65 m; its
    range [p_min, p_max] ends at fitted strides and is narrower than the breakpoints only where the
    held-out stride of the next interval misses the fit tolerance (see docs/gait_family_range.md)."""
    assert FAM.representation == SPLINE
    x = FAM.breakpoints
    assert x[0] <= 0.30 + 1e-12 and x[-1] >= 0.65 - 1e-12, (x[0], x[-1])
    assert FAM.p_min in STRIDES and FAM.p_max in STRIDES
    t = np.linspace(0.0, FAM.T, 401)

    def misses(lo: float, hi: float) -> bool:
        rec = next(r for r in HELD_OUT if lo < r["stride"] < hi)
        q, qd, _ = poly(rec["a"], t)
        Q = np.array([FAM.evaluate(rec["stride"], x).q for x in t])
        QD = np.array([FAM.evaluate(rec["stride"], x).dq_dtau for x in t])
        return (not rec["success"] or float(np.max(np.abs(Q - q))) > FIT_TOL_Q
                or float(np.max(np.abs(QD - qd))) > FIT_TOL_QD)

    i, j = STRIDES.index(FAM.p_min), STRIDES.index(FAM.p_max)
    if i > 0:
        assert misses(STRIDES[i - 1], STRIDES[i]), f"range could extend below {FAM.p_min}"
    if j < len(STRIDES) - 1:
        assert misses(STRIDES[j], STRIDES[j + 1]), f"range could extend above {FAM.p_max}"
    # the range is wider than the earlier polynomial family's [0.35, 0.575]
    assert FAM.p_min <= 0.35 and FAM.p_max >= 0.65 - 1e-12


def test_family_exact_at_p_d():
    rec = next(r for r in RECORDS if r["stride"] == FAM.p_d)
    t = np.linspace(0.0, FAM.T, 201)
    q, qd, qdd = poly(rec["a"], t)
    Q = np.array([FAM.evaluate(FAM.p_d, x).q for x in t])
    QD = np.array([FAM.evaluate(FAM.p_d, x).dq_dtau for x in t])
    QDD = np.array([FAM.evaluate(FAM.p_d, x).d2q_dtau2 for x in t])
    assert_close(Q, q, 1e-9, "family q_d(p_d, t) vs the optimised preferred step")
    assert_close(QD, qd, 1e-9, "family q_d'(p_d, t) vs the optimised preferred step")
    assert_close(QDD, qdd, 1e-8, "family q_d''(p_d, t) vs the optimised preferred step")
    # p_d is a breakpoint: the time coefficients there are the optimised ones
    assert_close(FAM.coefficients(FAM.p_d)[0], np.array(rec["a"]), 1e-12, "a(p_d)")


def fit_errors(records) -> list[tuple[float, float, float]]:
    t = np.linspace(0.0, FAM.T, 401)
    out = []
    for rec in records:
        p = rec["stride"]
        if p == FAM.p_d or not (FAM.p_min <= p <= FAM.p_max):
            continue
        q, qd, _ = poly(rec["a"], t)
        Q = np.array([FAM.evaluate(p, x).q for x in t])
        QD = np.array([FAM.evaluate(p, x).dq_dtau for x in t])
        out.append((p, float(np.max(np.abs(Q - q))), float(np.max(np.abs(QD - qd)))))
    return out


@pytest.mark.parametrize("which", ["fitted", "held_out"])
def test_fit_error(which):
    """The family reproduces every optimised stride in [p_min, p_max] within the stated tolerance
    (FIT_TOL_Q rad on q, FIT_TOL_QD rad/s on q'): the strides used for the fit and the held-out
    strides (optimised at the midpoints, not used for the fit)."""
    errs = fit_errors(RECORDS if which == "fitted" else HELD_OUT)
    assert len(errs) >= 2, f"no {which} stride other than p_d inside the family's range"
    eq = max(errs, key=lambda e: e[1])
    ev = max(errs, key=lambda e: e[2])
    table = ", ".join(f"p={p:.5f}: {a:.2e}/{b:.2e}" for p, a, b in errs)
    assert eq[1] <= FIT_TOL_Q and ev[2] <= FIT_TOL_QD, (
        f"{which} strides: family misses the fit tolerance {FIT_TOL_Q:g} rad / {FIT_TOL_QD:g} rad/s: "
        f"max q error {eq[1]:.3e} rad at p = {eq[0]}, max q' error {ev[2]:.3e} rad/s at p = {ev[0]} "
        f"(range [{FAM.p_min}, {FAM.p_max}]; per stride q/q': {table})")


def test_fit_error_matches_file():
    """The validation numbers stored in the file are the ones recomputed here (no stale figures)."""
    for key, recs in (("strides", RECORDS), ("held_out", HELD_OUT)):
        stored = {round(r["stride"], 9): r for r in DATA["validation"][key]}
        errs = fit_errors(recs)
        assert errs
        for p, eq, ev in errs:
            r = stored[round(p, 9)]
            assert abs(r["fit_error_q"] - eq) <= 1e-9 + 0.01 * eq, (key, p, r["fit_error_q"], eq)
            assert abs(r["fit_error_qdot"] - ev) <= 1e-9 + 0.01 * ev, (key, p, r["fit_error_qdot"], ev)


def test_continuity_across_breakpoints():
    """a, da/dp and d2a/dp2 of the two pieces meeting at every interior breakpoint agree to round-off
    (C2); the third derivative does jump somewhere (so the comparison can tell pieces apart)."""
    x = FAM.breakpoints
    assert FAM.n_pieces == x.size - 1 >= 3
    jumps3 = []
    for k in range(1, x.size - 1):
        left = FAM.piece_coefficients(k - 1, x[k])
        right = FAM.piece_coefficients(k, x[k])
        h = min(x[k] - x[k - 1], x[k + 1] - x[k])
        for d, what in enumerate(("a", "da/dp", "d2a/dp2")):
            # round-off of a cubic piece evaluated at its far end: eps * sum_m |c_m| h^(m - d) m!/(m-d)!
            scale = max(float(np.max(np.abs(left[d]))), float(np.max(np.abs(right[d]))), 1.0)
            assert_close(left[d], right[d], 1e-11 * scale / h ** d, f"{what} at breakpoint {x[k]}")
        jumps3.append(float(np.max(np.abs(left[3] - right[3]))))
    # not-a-knot: no jump of the third derivative at the first and last interior breakpoints
    assert jumps3[0] < 1e-6 * max(jumps3) and jumps3[-1] < 1e-6 * max(jumps3)
    assert max(jumps3) > 1.0, "third derivative continuous everywhere: the family is one cubic"
    # and evaluate() switches pieces there: just left of a breakpoint it uses the left piece
    for k in range(1, x.size - 1):
        e = 1e-9
        assert_close(FAM.coefficients(x[k] - e)[0], FAM.piece_coefficients(k - 1, x[k] - e)[0], 1e-13, "left piece")
        assert_close(FAM.coefficients(x[k])[0], FAM.piece_coefficients(k, x[k])[0], 0.0, "right piece")


RNG_POINTS = np.random.default_rng(20240611).uniform([0.0, 0.0], [1.0, 1.0], size=(12, 2))


def _away_from_breakpoints(p: float, margin: float) -> float:
    """p moved (if needed) so that [p - margin, p + margin] holds no breakpoint: the difference
    stencils below assume one polynomial piece (across a breakpoint the third derivative jumps)."""
    x = getattr(FAM, "breakpoints", np.array([FAM.p_min, FAM.p_max]))
    k = int(np.clip(np.searchsorted(x, p) - 1, 0, x.size - 2))
    lo, hi = x[k] + margin, x[k + 1] - margin
    assert lo < hi
    return float(min(max(p, lo), hi))


@pytest.mark.parametrize("u", RNG_POINTS, ids=[f"pt{i}" for i in range(len(RNG_POINTS))])
def test_partial_derivatives(u):
    """dq/dp, dq/dtau, d2q/dp2, d2q/dtau2, d2q/dp dtau against central finite differences."""
    hp, ht = 1e-4, 1e-3
    p = _away_from_breakpoints(FAM.p_min + u[0] * (FAM.p_max - FAM.p_min), 3 * hp)
    tau = u[1] * FAM.T
    g = FAM.evaluate(p, tau)
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
    assert_close(g.dq_dp, fd_p, 1e-7, "dq/dp", rel=True)
    assert_close(g.dq_dtau, fd_t, 1e-7, "dq/dtau", rel=True)
    assert_close(g.d2q_dp2, fd_pp2, 1e-6, "d2q/dp2 (FD of dq/dp)", rel=True)
    assert_close(g.d2q_dtau2, fd_tt2, 1e-7, "d2q/dtau2 (FD of dq/dtau)", rel=True)
    assert_close(g.d2q_dp_dtau, fd_pt2, 1e-7, "d2q/dp dtau (FD in tau of dq/dp)", rel=True)
    assert_close(g.d2q_dp_dtau, fd_tp2, 1e-7, "d2q/dp dtau (FD in p of dq/dtau)", rel=True)
    assert_close(g.d2q_dp2, fd_pp, 1e-4, "d2q/dp2 (second difference of q)", rel=True)
    assert_close(g.d2q_dtau2, fd_tt, 1e-4, "d2q/dtau2 (second difference of q)", rel=True)
    assert_close(g.d2q_dp_dtau, fd_pt, 1e-4, "d2q/dp dtau (mixed difference of q)", rel=True)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_reference_is_eq_11(seed):
    """q_d' and q_d'' returned by GaitFamily.reference are the time derivatives of q_d(p(t), tau(t)) along a
    smooth random (p(t), tau(t)) inside one piece of the family (4th-order central differences in t)."""
    rng = np.random.default_rng(seed)
    x = getattr(FAM, "breakpoints", np.array([FAM.p_min, FAM.p_max]))
    k = int(rng.integers(0, x.size - 1))
    p_c, half = 0.5 * (x[k] + x[k + 1]), 0.5 * (x[k + 1] - x[k])
    amp_p, w_p, ph_p = rng.uniform(0.3, 0.8) * half, rng.uniform(3, 12), rng.uniform(0, 2 * np.pi)
    amp_t, w_t, ph_t = rng.uniform(0.005, 0.02), rng.uniform(3, 12), rng.uniform(0, 2 * np.pi)

    def P(t):
        return p_c + amp_p * np.sin(w_p * t + ph_p), amp_p * w_p * np.cos(w_p * t + ph_p), -amp_p * w_p**2 * np.sin(w_p * t + ph_p)

    def TAU(t):  # tau' = 0.9 + amp w cos > 0
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
        assert_close(qd, d1(Q, t, 1e-3), 1e-7, f"q_d' vs d/dt q_d at t = {t:.3f}", rel=True)
        assert_close(qdd, d1(lambda s: REF(s)[1], t, 1e-3), 1e-7, f"q_d'' vs d/dt q_d' at t = {t:.3f}", rel=True)
        h = 2e-3
        fd2 = (-(Q(t + 2 * h) + Q(t - 2 * h)) + 16 * (Q(t + h) + Q(t - h)) - 30 * Q(t)) / (12 * h * h)
        assert_close(qdd, fd2, 1e-5, f"q_d'' vs d2/dt2 q_d at t = {t:.3f}", rel=True)


# ------------------------------------------------------------------ the family between the strides
PROBES_PER_INTERVAL = 6      # finer than the generator's own check (4 per interval)
_inside = [p for p in STRIDES if FAM.p_min <= p <= FAM.p_max]
BETWEEN = [a + (b - a) * m / PROBES_PER_INTERVAL for a, b in zip(_inside[:-1], _inside[1:])
           for m in range(1, PROBES_PER_INTERVAL)]


def test_family_between_strides(fixed, floating):
    """The fitted family at 5 strides inside every interval of optimised strides (p' = 0, tau' = 1): all
    17 true constraints hold on 201 instants, the swing foot stays above the ground inside the step, and
    the step is periodic through the impact map up to the stored bound of the generator's check."""
    assert len(BETWEEN) >= 5 * (len(_inside) - 1)
    t = np.linspace(0.0, FAM.T, 201)
    bound = float(DATA["validation"]["fitted_max_periodicity_residual"])
    worst_per, failures = 0.0, []
    for p in BETWEEN:
        ref = [FAM.reference(p, 0.0, x, 1.0) for x in t]
        q = np.array([r[0] for r in ref]); qd = np.array([r[1] for r in ref]); qdd = np.array([r[2] for r in ref])
        worst, where = worst_true_margin(fixed, q, qd, qdd, t)
        low = min(min(sole_heights(fixed, qk)) for qk in q[1:-1])
        if not (worst > 0.0 and low > 0.0):
            failures.append(f"p = {p:.5f}: margin {worst:.3g} ({where[1]} at t = {where[0]:.4f}), clearance {low:.3g} m")
        qd_new, _ = impact_paper(floating, q[-1], qd[-1])
        worst_per = max(worst_per, float(np.max(np.abs(q[0] - relabel(q[-1])))), float(np.max(np.abs(qd[0] - qd_new))))
    assert not failures, "\n".join(failures)
    # the generator checked 4 probes per interval; 6 per interval may find slightly more
    assert worst_per <= 2.0 * bound + 1e-9, f"periodicity residual between strides {worst_per:.3e} > 2 x {bound:.3e}"
    assert bound < 5e-2


# ------------------------------------------------------------------ the spline and its fit
def test_spline_pieces_match_scipy():
    """spline_pieces (own tridiagonal algebra) against scipy.interpolate.CubicSpline (not-a-knot)."""
    from scipy.interpolate import CubicSpline
    rng = np.random.default_rng(11)
    x = np.sort(rng.uniform(0.3, 0.65, 9))
    Y = rng.normal(size=(9, 6, 5))
    ref = CubicSpline(x, Y, axis=0, bc_type="not-a-knot")
    fam = GaitFamily.spline(x, Y, 0.463, float(x[4]))
    for p in np.concatenate([np.linspace(x[0], x[-1], 37), x]):
        a, da, dda = fam.coefficients(p)
        assert_close(a, ref(p), 1e-12, f"a at p = {p:.4f}", rel=True)
        assert_close(da, ref(p, 1), 1e-10, f"da/dp at p = {p:.4f}", rel=True)
        assert_close(dda, ref(p, 2), 1e-8, f"d2a/dp2 at p = {p:.4f}", rel=True)
    c = spline_pieces(x, Y)
    assert_close(c[:, :, :, 0], Y[:-1], 0.0, "c_k0 = Y_k bitwise")


SMOOTHING_BP = np.array(SETTINGS["smoothing_breakpoints"]["value"], dtype=float)


def test_spline_fit_recovers_a_spline():
    """Data sampled at the family's strides from a not-a-knot spline on the smoothing breakpoints (the
    generator's smoothing target): the least-squares fit returns that spline's values."""
    rng = np.random.default_rng(5)
    x = SMOOTHING_BP
    Y = rng.normal(size=(x.size, 6, 5))
    k = int(np.flatnonzero(x == FAM.p_d)[0])
    truth = GaitFamily.spline(x, Y, FAM.T, FAM.p_d)
    strides = np.array(STRIDES)
    a = np.array([truth.coefficients(p)[0] for p in strides])
    Yfit = fit_spline_family(strides, a, FAM.p_d, x)
    assert_close(Yfit, Y, 1e-9, "fitted spline values", rel=True)
    assert_close(Yfit[k], Y[k], 0.0, "value at p_d")


def test_spline_fit_exact_at_p_d_with_noise():
    """With data that no spline on the smoothing breakpoints fits (noise), the fit still passes through
    p_d exactly and is not an interpolant elsewhere; with the strides as breakpoints (the family) it
    interpolates every stride."""
    rng = np.random.default_rng(7)
    x = SMOOTHING_BP
    strides = np.array(STRIDES)
    a = rng.normal(size=(strides.size, 6, 5))
    Y = fit_spline_family(strides, a, FAM.p_d, x)
    fam = GaitFamily.spline(x, Y, FAM.T, FAM.p_d)
    i = int(np.flatnonzero(strides == FAM.p_d)[0])
    assert_close(fam.coefficients(FAM.p_d)[0], a[i], 0.0, "fit at p_d with noisy data")
    others = np.array([fam.coefficients(p)[0] for p in strides])
    assert float(np.max(np.abs(others - a))) > 1e-3
    Yi = fit_spline_family(strides, a, FAM.p_d, strides)
    interp = GaitFamily.spline(strides, Yi, FAM.T, FAM.p_d)
    assert_close(np.array([interp.coefficients(p)[0] for p in strides]), a, 1e-9, "interpolating fit", rel=True)
    with pytest.raises(GaitFamilyError):
        fit_spline_family(strides[strides != FAM.p_d], a[strides != FAM.p_d], FAM.p_d, x)
    with pytest.raises(GaitFamilyError):
        GaitFamily.spline(x, Y, FAM.T, FAM.p_d + 1e-3)   # p_d must be a breakpoint


# ------------------------------------------------------------------ JSON round trip, both formats
def _same_family(a: GaitFamily, b: GaitFamily, points) -> None:
    for p, tau in points:
        ga, gb = a.evaluate(p, tau), b.evaluate(p, tau)
        for f in ("q", "dq_dp", "dq_dtau", "d2q_dp2", "d2q_dtau2", "d2q_dp_dtau"):
            assert_close(getattr(ga, f), getattr(gb, f), 0.0, f"round trip: {f} at ({p:.4f}, {tau:.4f})")
    assert (a.T, a.p_d, a.p_min, a.p_max, a.representation) == (b.T, b.p_d, b.p_min, b.p_max, b.representation)


PTS = np.random.default_rng(3).uniform(0, 1, size=(15, 2))


def _points(fam):
    return [(fam.p_min + u * (fam.p_max - fam.p_min), v * fam.T) for u, v in PTS] + [(fam.p_d, 0.1)]


def test_json_round_trip(tmp_path):
    """to_dict -> JSON text -> load gives the same family (bitwise), with its representation tag."""
    d = FAM.to_dict()
    assert d["representation"] == SPLINE and "note" in d
    path = tmp_path / "family.json"
    path.write_text(json.dumps({"family": d}))
    back = GaitFamily.load(path)
    _same_family(FAM, back, _points(FAM))
    # the committed file's own family block is what to_dict writes (no stale family)
    assert_close(np.array(DATA["family"]["values"]), FAM.values, 0.0, "stored values")
    assert DATA["family"]["representation"] == SPLINE
    # per-piece paper b_ijk (powers of p) reproduce the pieces
    pb = FAM.paper_b
    assert pb.shape == (FAM.n_pieces, 6, 5, 4)
    for p, _ in _points(FAM):
        k = int(np.clip(np.searchsorted(FAM.breakpoints, p, side="right") - 1, 0, FAM.n_pieces - 1))
        assert_close(pb[k] @ (p ** np.arange(4)), FAM.coefficients(p)[0], 1e-9, "paper_b per piece", rel=True)


def test_legacy_polynomial_file_loads(tmp_path):
    """A file of the earlier format (no representation tag, b and b_centered of eq. 13) still loads as
    the polynomial family; to_dict tags it and round-trips."""
    rng = np.random.default_rng(9)
    b = rng.normal(size=(6, 5, 8)) * 0.5 ** np.arange(8)
    poly_fam = GaitFamily(b, 0.463, 0.463, 0.35, 0.575, center=0.463)
    d = poly_fam.to_dict()
    assert d["representation"] == POLYNOMIAL
    legacy = {k: v for k, v in d.items() if k != "representation"}
    path = tmp_path / "legacy.json"
    path.write_text(json.dumps({"family": legacy}))
    back = GaitFamily.load(path)
    assert back.representation == POLYNOMIAL and back.n_pieces == 1
    _same_family(poly_fam, back, _points(poly_fam))
    only_b = {k: v for k, v in legacy.items() if k not in ("b_centered", "center")}
    path.write_text(json.dumps({"family": only_b}))
    back2 = GaitFamily.load(path)
    for p, tau in _points(poly_fam):
        assert_close(back2.evaluate(p, tau).q, poly_fam.evaluate(p, tau).q, 1e-6, "from the paper's b_ijk")


def test_load_rejects_inconsistent_files(tmp_path):
    d = FAM.to_dict()
    bad = json.loads(json.dumps(d))
    bad["pieces"][0][0][0][1] += 1e-3
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"family": bad}))
    with pytest.raises(GaitFamilyError, match="disagree"):
        GaitFamily.load(path)
    bad = dict(d, representation="chebyshev")
    path.write_text(json.dumps({"family": bad}))
    with pytest.raises(GaitFamilyError, match="unknown representation"):
        GaitFamily.load(path)
    bad = {k: v for k, v in d.items() if k != "values"}
    path.write_text(json.dumps({"family": bad}))
    with pytest.raises(GaitFamilyError, match="malformed"):
        GaitFamily.load(path)


# ------------------------------------------------------------------ the polynomial fit (eq. 13)
@pytest.mark.parametrize("degree", [0, 3, 7])
def test_fit_family_recovers_polynomials(degree):
    """a_ij(p) polynomial of degree <= 7 in p, sampled at the file's strides: the fit is exact."""
    rng = np.random.default_rng(100 + degree)
    strides = np.array(SETTINGS["strides"]["value"], dtype=float)
    p_d = FAM.p_d
    coef_u = rng.normal(size=(6, 5, degree + 1)) * 0.5 ** np.arange(degree + 1)  # in powers of u = p - p_d

    def a_true(p):
        u = p - p_d
        return coef_u @ (u ** np.arange(degree + 1))
    a = np.array([a_true(p) for p in strides])
    b = fit_family(strides, a, p_d, 7, centered=True)
    fam = GaitFamily(b, FAM.T, p_d, float(strides.min()), float(strides.max()), center=p_d)
    for p in np.linspace(strides.min(), strides.max(), 23):
        a_fit, _, _ = fam.coefficients(p)
        assert_close(a_fit, a_true(p), 1e-8, f"degree {degree}: a(p) at p = {p:.4f}")
    assert_close(fam.coefficients(p_d)[0], a_true(p_d), 1e-12, "fit at p_d")
    # the paper's b_ijk (powers of p) describe the same polynomials
    b_paper = fit_family(strides, a, p_d, 7)
    fam_paper = GaitFamily(b_paper, FAM.T, p_d, float(strides.min()), float(strides.max()))
    assert_close(fam_paper.coefficients(0.5)[0], a_true(0.5), 1e-6, "paper b_ijk at p = 0.5")


# ------------------------------------------------------------------ the generator's own check
def test_generate_gait_family_check(tmp_path):
    """``scripts/generate_gait_family --check`` accepts the committed file (exit 0) and its figures are
    the file's."""
    out = tmp_path / "validation.json"
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "generate_gait_family"), "--check", "--json", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    v = json.loads(out.read_text())
    assert v["fitted_min_margin"] > 0 and v["fitted_min_clearance"] > 0
    assert v["held_out_fit_error_q_max"] <= FIT_TOL_Q and v["held_out_fit_error_qdot_max"] <= FIT_TOL_QD
    assert v["fitted_min_margin"] == pytest.approx(DATA["validation"]["fitted_min_margin"], rel=1e-9)
