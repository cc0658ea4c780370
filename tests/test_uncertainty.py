"""The pure pieces of survival over seeds (studies.trial.uncertainty): the Wilson interval against its
closed form computed here and against a published table, the seed of a trial, and the adaptive crossing
search against a dense grid on a synthetic survival curve (a known logistic, seeded Bernoulli draws)."""
import math

import numpy as np
import pytest

from biped_controller.studies.trial import uncertainty as U


def _closed_form(k, n, z=1.959963984540054):
    # the score test's quadratic in p solved directly: (1 + z^2/n) p^2 - (2 p^ + z^2/n) p + p^2 = 0
    ph = k / n
    a = 1.0 + z * z / n
    b = -(2.0 * ph + z * z / n)
    c = ph * ph
    disc = math.sqrt(b * b - 4.0 * a * c)
    return (-b - disc) / (2.0 * a), (-b + disc) / (2.0 * a)


@pytest.mark.parametrize("k,n", [(0, 1), (1, 1), (0, 8), (3, 8), (8, 8), (5, 32), (16, 32), (31, 32), (81, 263)])
def test_wilson_equals_the_closed_form(k, n):
    lo, hi = U.wilson(k, n)
    elo, ehi = _closed_form(k, n)
    assert lo == pytest.approx(max(elo, 0.0), abs=1e-12)
    assert hi == pytest.approx(min(ehi, 1.0), abs=1e-12)
    assert 0.0 <= lo <= k / n <= hi <= 1.0


# Newcombe R. G. (1998), "Two-sided confidence intervals for the single proportion: comparison of seven
# methods", Statistics in Medicine 17:857-872, Table I, method 3 (score method without continuity
# correction, i.e. Wilson), 95 % limits to 4 decimals. The first two rows are the paper's examples as the
# test suite of the R package propint (github.com/m-Py/propint, tests/testthat/test_Single_Proportion_CI.R,
# "the results reported in Newcombe1998") states them; the last two were typed from memory and are
# checked only by scipy below (no retrieved copy of the table held them).
NEWCOMBE_1998_TABLE_I_WILSON = {
    (81, 263): (0.2553, 0.3662),
    (15, 148): (0.0624, 0.1605),
    (0, 20): (0.0, 0.1611),
    (1, 29): (0.0061, 0.1718),
}


@pytest.mark.parametrize("kn", sorted(NEWCOMBE_1998_TABLE_I_WILSON))
def test_wilson_matches_newcombe_table_I(kn):
    lo, hi = U.wilson(*kn)
    tlo, thi = NEWCOMBE_1998_TABLE_I_WILSON[kn]
    assert round(lo, 4) == tlo and round(hi, 4) == thi


@pytest.mark.parametrize("k,n", [(0, 1), (3, 8), (8, 8), (5, 32), (31, 32), (0, 20), (1, 29), (81, 263)])
def test_wilson_equals_scipy(k, n):
    """An independent implementation: scipy.stats.binomtest(k, n).proportion_ci(method='wilson')."""
    from scipy.stats import binomtest
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    assert U.wilson(k, n) == pytest.approx((ci.low, ci.high), abs=1e-12)


# Newcombe R. G. (1998), "Improved confidence intervals for the difference between binomial proportions
# based on paired data", Stat. Med. 17:2635-2650, method 10, 95 % limits of the paper's four examples
# (a, b, c, d) = (both, first only, second only, neither), as propint's tests state them
# (tests/testthat/test_Two_Dependent_Props_CI.R, "the results reported in Newcombe1998").
NEWCOMBE_1998_PAIRED = {(36, 12, 2, 0): (0.0569, 0.3404), (18, 12, 2, 18): (0.0562, 0.3290),
                        (53, 0, 0, 1): (-0.0729, 0.0729), (0, 30, 0, 0): (0.8395, 1.0)}
# Newcombe R. G. (1998), "Interval estimation for the difference between independent proportions:
# comparison of eleven methods", Stat. Med. 17:873-890, method 10, as propint's
# tests/testthat/test_Two_Independent_Props_CI.R states them: (k1, n1, k2, n2) -> limits.
NEWCOMBE_1998_INDEPENDENT = {(56, 70, 48, 80): (0.0524, 0.3339), (9, 10, 3, 10): (0.1705, 0.8090)}


@pytest.mark.parametrize("abcd", sorted(NEWCOMBE_1998_PAIRED))
def test_paired_difference_matches_newcombe(abcd):
    r = U.paired_difference(*abcd)
    a, b, c, d = abcd
    assert r["difference"] == (b - c) / sum(abcd)
    assert (round(r["lo"], 4), round(r["hi"], 4)) == NEWCOMBE_1998_PAIRED[abcd]


def test_paired_difference_closed_form_by_hand():
    """(18, 12, 2, 18), n = 50: phi^ from the corrected numerator 18*18 - 12*2 - 25 = 275 over
    sqrt(30*20*20*30) = 600; the limits from scipy's Wilson limits of 30/50 and 20/50."""
    from scipy.stats import binomtest
    w1 = binomtest(30, 50).proportion_ci(method="wilson")
    w2 = binomtest(20, 50).proportion_ci(method="wilson")
    phi = 275.0 / 600.0
    d1, e2 = 0.6 - w1.low, w2.high - 0.4
    e1, d2 = w1.high - 0.6, 0.4 - w2.low
    r = U.paired_difference(18, 12, 2, 18)
    assert r["phi"] == pytest.approx(phi, abs=1e-15)
    assert r["lo"] == pytest.approx(0.2 - math.sqrt(d1 * d1 - 2 * phi * d1 * e2 + e2 * e2), abs=1e-12)
    assert r["hi"] == pytest.approx(0.2 + math.sqrt(e1 * e1 - 2 * phi * e1 * d2 + d2 * d2), abs=1e-12)
    # with no correlation the paired interval is the independent one of the same margins
    ind = U.independent_difference(30, 50, 20, 50)
    none = U.paired_difference(12, 18, 8, 12)        # a d = b c: phi^ = 0, margins 30/50 and 20/50
    assert none["phi"] == 0.0 and (none["lo"], none["hi"]) == pytest.approx(ind[1:], abs=1e-12)
    assert r["hi"] - r["lo"] < ind[2] - ind[1]      # correlated pairs: a narrower interval
    with pytest.raises(U.UncertaintyError):
        U.paired_difference(0, 0, 0, 0)
    with pytest.raises(U.UncertaintyError):
        U.paired_difference(1, -1, 0, 0)


@pytest.mark.parametrize("kk", sorted(NEWCOMBE_1998_INDEPENDENT))
def test_independent_difference_matches_newcombe(kk):
    d, lo, hi = U.independent_difference(*kk)
    assert (round(lo, 4), round(hi, 4)) == NEWCOMBE_1998_INDEPENDENT[kk]


def test_wilson_edges_and_bad_counts():
    assert U.wilson(0, 10)[0] == 0.0 and U.wilson(10, 10)[1] == 1.0
    assert U.wilson(0, 10)[1] < 0.5 and U.wilson(10, 10)[0] > 0.5
    assert U.wilson(0, 10)[1] == pytest.approx(1.0 - U.wilson(10, 10)[0], abs=1e-15)   # symmetry k <-> n - k
    for k, n in ((1, 0), (-1, 3), (4, 3), (1.5, 3), (True, 3)):
        with pytest.raises(U.UncertaintyError):
            U.wilson(k, n)


def test_trial_seed_is_deterministic_63_bit_and_cell_dependent():
    cell = {"plant": "rigid", "profile": "real-sensors", "mode": "both", "start": 0.2315, "duration": 0.025,
            "direction": "forward", "height": None}
    s = [U.trial_seed(cell, i) for i in range(64)]
    assert s == [U.trial_seed(dict(reversed(list(cell.items()))), i) for i in range(64)]   # key order irrelevant
    assert len(set(s)) == 64 and all(0 <= x < 2 ** 63 for x in s)
    assert U.trial_seed(dict(cell, mode="tau"), 0) != s[0]
    assert U.trial_seed(dict(cell, direction="backward"), 0) != s[0]
    with pytest.raises(U.UncertaintyError):
        U.trial_seed(cell, -1)


@pytest.mark.parametrize("level", [0.0, 1.0, -0.1, 1.5, float("nan")])
def test_bad_levels(level):
    with pytest.raises(U.UncertaintyError):
        U.check_level(level)


def _synthetic(seeds=32, f50=400.0, width=30.0):
    """Survival s(F) = 1 / (1 + exp((F - f50) / width)); seed i at force F survives iff its uniform draw
    u_i(F) from default_rng([i, round(F * 1000)]) is below s(F) (a seeded Bernoulli draw)."""
    def s(f):
        return 1.0 / (1.0 + math.exp((f - f50) / width))

    calls = []

    def batch(f):
        calls.append(f)
        k = sum(np.random.default_rng([i, int(round(f * 1000))]).random() < s(f) for i in range(seeds))
        return int(k), seeds
    return s, batch, calls


@pytest.mark.parametrize("level", [0.9, 0.5])
def test_adaptive_search_agrees_with_a_dense_grid(level):
    s, batch, calls = _synthetic()
    resolution = 10.0
    coarse = {f: batch(f) for f in np.arange(0.0, 1001.0, 100.0).tolist()}
    lo, hi = U.first_bracket(coarse, level)
    n_coarse = len(calls)
    out = U.crossing_search(batch, level, lo, hi, resolution, rates=dict(coarse))
    # the dense grid: every force on a resolution grid over the same range, the first whose rate is below the level
    grid = np.arange(0.0, 1000.0 + resolution, resolution).tolist()
    dense = {f: batch(f) for f in grid}
    first_below = next(f for f in grid if dense[f][0] / dense[f][1] < level)
    assert out["bracket"][1] - out["bracket"][0] <= resolution
    assert abs(out["estimate"] - first_below) <= resolution
    true = 400.0 + 30.0 * math.log((1.0 - level) / level)
    assert abs(out["estimate"] - true) <= 3 * resolution
    lo_i, hi_i = out["interval"]
    assert hi_i is not None and true <= hi_i
    if level == 0.5:
        assert lo_i is not None and lo_i <= true
    else:   # 32 of 32 has Wilson lower limit 0.893 < 0.9: no force tried can bound a 90 % crossing from below
        assert U.wilson(32, 32)[0] < 0.9 and lo_i is None
    assert len(out["tried"]) == len(calls) - n_coarse - len(grid) and len(out["tried"]) <= 4   # near the crossing only
    assert all(abs(f - out["estimate"]) <= 100.0 for f in out["tried"])


def test_search_is_order_free_and_refuses_bad_resolution():
    _, batch, _ = _synthetic()
    a = U.crossing_search(batch, 0.5, 300.0, 500.0, 5.0)
    b = U.crossing_search(batch, 0.5, 300.0, 500.0, 5.0)
    assert a == b
    for r in (0.0, -1.0, float("nan")):
        with pytest.raises(U.UncertaintyError):
            U.crossing_search(batch, 0.5, 300.0, 500.0, r)
