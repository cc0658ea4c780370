"""The torso parameter lambda of the reference family: q_d(p, tau, lambda).

Independent references: central finite differences of ``GaitFamily.evaluate_torso`` for every partial
derivative (and of q_d along a parameter path for eq. 11), Pinocchio's forward kinematics for what the
offset moves (the torso's absolute pitch by lambda phi; the stance thigh, the swing thigh and the swing
foot not at all), and the relabelling of the impact for continuity across it. Negative controls: a
wrong sign convention (q3 and q4 changed the same way) moves the swing foot; phi without its s^2 factors
makes the reference jump at the impact.
"""
from __future__ import annotations

import numpy as np
import pytest

from biped_model.fixed_foot import FixedFootModel, relabel
from biped_model.gait_family import (TORSO_DIRECTION, GaitFamily, GaitSample, eq11, eq11_torso, torso_profile,
                                         with_torso)

FAM = GaitFamily.load()
T = FAM.T
RNG = np.random.default_rng(21)
POINTS = [(FAM.p_min + (FAM.p_max - FAM.p_min) * RNG.uniform(0.05, 0.95), T * RNG.uniform(0.02, 0.98),
           RNG.uniform(-0.2, 0.2)) for _ in range(12)]


def test_profile_closed_form_and_boundaries():
    for s in np.linspace(0.01, 0.99, 25):
        phi, d1, d2 = torso_profile(s)
        assert phi == pytest.approx(16 * s**2 * (1 - s)**2, rel=1e-14)
        h = 1e-5
        assert d1 == pytest.approx((torso_profile(s + h)[0] - torso_profile(s - h)[0]) / (2 * h), rel=1e-7, abs=1e-8)
        assert d2 == pytest.approx((torso_profile(s + h)[1] - torso_profile(s - h)[1]) / (2 * h), rel=1e-6, abs=1e-6)
    assert torso_profile(0.5)[0] == 1.0
    for s in (0.0, 1.0, -0.3, 1.2):
        assert torso_profile(s) == (0.0, 0.0, 0.0)
    # C1 at the ends: the one-sided values tend to 0
    for s in (1e-7, 1 - 1e-7):
        phi, d1, _ = torso_profile(s)
        assert abs(phi) < 1e-12 and abs(d1) < 1e-5


@pytest.mark.parametrize("p,tau,lam", POINTS)
def test_partial_derivatives_against_finite_differences(p, tau, lam):
    g = FAM.evaluate_torso(p, tau, lam)
    hp, ht, hl = 1e-6, 1e-6, 1e-5

    def q(pp, tt, ll):
        return FAM.evaluate_torso(pp, tt, ll).q

    np.testing.assert_allclose(g.dq_dlam, (q(p, tau, lam + hl) - q(p, tau, lam - hl)) / (2 * hl), atol=1e-9)
    np.testing.assert_allclose(g.dq_dtau, (q(p, tau + ht, lam) - q(p, tau - ht, lam)) / (2 * ht), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(g.dq_dp, (q(p + hp, tau, lam) - q(p - hp, tau, lam)) / (2 * hp), rtol=1e-6, atol=1e-5)

    def dtau(pp, tt, ll):
        return FAM.evaluate_torso(pp, tt, ll).dq_dtau

    np.testing.assert_allclose(g.d2q_dtau2, (dtau(p, tau + ht, lam) - dtau(p, tau - ht, lam)) / (2 * ht),
                               rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(g.d2q_dtau_dlam, (dtau(p, tau, lam + hl) - dtau(p, tau, lam - hl)) / (2 * hl), atol=1e-8)
    dl = (FAM.evaluate_torso(p, tau + ht, lam).dq_dlam - FAM.evaluate_torso(p, tau - ht, lam).dq_dlam) / (2 * ht)
    np.testing.assert_allclose(g.d2q_dtau_dlam, dl, atol=1e-6)
    # affine in lambda, and lambda does not touch the p-dependence
    np.testing.assert_allclose(FAM.evaluate_torso(p, tau, 2 * lam).q - g.q, g.q - FAM.evaluate(p, tau).q, atol=1e-15)
    assert np.array_equal(g.dq_dp, FAM.evaluate(p, tau).dq_dp)


def test_eq11_torso_against_finite_differences_along_a_path():
    """q_d(t) = q_d(p(t), tau(t), lambda(t)) for quadratic parameter paths: its first and second time
    derivatives by central differences against eq. (11) with the third parameter."""
    p0, pd, pdd = FAM.p_d, 0.05, -0.4
    t0, td, tdd = 0.3 * T, 0.9, 0.7
    l0, ld, ldd = 0.08, -0.3, 2.0

    def q_at(t):
        return FAM.evaluate_torso(p0 + pd * t + 0.5 * pdd * t * t, t0 + td * t + 0.5 * tdd * t * t,
                                  l0 + ld * t + 0.5 * ldd * t * t).q

    h = 1e-4
    q, qd, qdd = FAM.reference_torso(p0, pd, t0, td, l0, ld, pdd, tdd, ldd)
    np.testing.assert_allclose(qd, (q_at(h) - q_at(-h)) / (2 * h), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(qdd, (q_at(h) - 2 * q_at(0) + q_at(-h)) / h**2, rtol=1e-4, atol=1e-3)
    # the lambda terms matter here (negative control: eq. 11 without them is far off)
    _, qd2, qdd2 = eq11(FAM.evaluate(p0, t0), pd, td, pdd, tdd)
    assert np.max(np.abs(qdd2 - qdd)) > 1.0 and np.max(np.abs(qd2 - qd)) > 0.1


def test_lambda_zero_is_the_two_parameter_family_bit_for_bit():
    for p, tau, _ in POINTS:
        g2 = FAM.evaluate(p, tau)
        g3 = FAM.evaluate_torso(p, tau, 0.0)
        for name in ("q", "dq_dp", "dq_dtau", "d2q_dp2", "d2q_dtau2", "d2q_dp_dtau"):
            assert np.array_equal(getattr(g2, name), getattr(g3, name)), name
        a, b = eq11(g2, 0.1, 1.1, 0.2, 0.3), eq11_torso(g3, 0.1, 1.1, 0.0, 0.2, 0.3, 0.0)
        for x, y in zip(a, b):
            assert np.array_equal(x, y)


def _pose(model: FixedFootModel, q):
    """(stance thigh rotation, torso rotation, swing foot pose) by Pinocchio's forward kinematics."""
    import pinocchio as pin
    model._full(q)
    pin.forwardKinematics(model.model, model.data, model._q)
    jid = model.model.frames[model.hip_frame].parentJoint
    hip_parent = model.model.parents[jid]
    return model.data.oMi[hip_parent].rotation.copy(), model.data.oMi[jid].rotation.copy(), model.swing_foot(q)[0]


def _angle(R1, R0):
    """Signed pitch of R1 relative to R0 in the sagittal convention (axes (0, -1, 0): counter-clockwise
    positive): R1 R0^T = R_y(-theta)."""
    Rr = R1 @ R0.T
    return -float(np.arctan2(Rr[0, 2], Rr[0, 0]))


def test_offset_turns_the_torso_only_forward_kinematics():
    """By Pinocchio: lambda phi turns the torso by lambda phi (counter-clockwise positive) and moves neither the swing foot nor the
    stance leg. Negative control: q3 and q4 changed alike (the wrong sign) moves the swing foot."""
    model = FixedFootModel()
    for p, tau, lam in POINTS[:6]:
        q0 = FAM.evaluate(p, tau).q
        q1 = FAM.evaluate_torso(p, tau, lam).q
        th0, to0, f0 = _pose(model, q0)
        th1, to1, f1 = _pose(model, q1)
        phi = torso_profile(tau / T)[0]
        assert _angle(to1, to0) == pytest.approx(lam * phi, abs=1e-12)
        assert abs(_angle(th1, th0)) < 1e-12
        np.testing.assert_allclose(f1, f0, atol=1e-12)
        # torso absolute angle = q1 + q2 + q3 (counter-clockwise positive)
        assert (q1[0] + q1[1] + q1[2]) - (q0[0] + q0[1] + q0[2]) == pytest.approx(lam * phi, abs=1e-14)
        wrong = q0 + lam * phi * np.array([0, 0, 1.0, 1.0, 0, 0])
        if abs(lam * phi) > 1e-3:
            assert np.max(np.abs(_pose(model, wrong)[2][:2] - f0[:2])) > 1e-4


@pytest.mark.parametrize("lam", [0.15, -0.2])
def test_reference_continuous_across_the_impact(lam):
    """At tau = T (the family's impact) the relabelled end of a step with lambda != 0 equals the start of
    the next (tau = 0, same p and lambda) exactly as it does with lambda = 0: q_d and q_d' (any p', tau',
    lambda'). Negative control: a profile without the s^2 (1-s)^2 factors' zeros would jump."""
    p, pd, td, ld = FAM.p_d, 0.02, 1.05, 0.4
    end0 = FAM.reference_torso(p, pd, T, td, 0.0, 0.0)
    start0 = FAM.reference_torso(p, pd, 0.0, td, 0.0, 0.0)
    endl = FAM.reference_torso(p, pd, T, td, lam, ld)
    startl = FAM.reference_torso(p, pd, 0.0, td, lam, ld)
    for k in (0, 1):
        gap0 = relabel(end0[k]) - start0[k]
        gapl = relabel(endl[k]) - startl[k]
        np.testing.assert_allclose(gapl, gap0, atol=1e-12)
    # just before the end the offset is still (barely) there, and it vanishes continuously
    near = FAM.evaluate_torso(p, T * (1 - 1e-6), lam)
    assert np.max(np.abs(near.q - FAM.evaluate(p, T * (1 - 1e-6)).q)) < 1e-10
    # negative control: a profile sin(pi s) (phi(1) = 0, phi'(1) = -pi != 0) makes q_d' jump by
    # lambda phi'(1) tau' / T in q3, q4: the check above would catch it
    bad_end = endl[1] + lam * (-np.pi) * td / T * TORSO_DIRECTION
    bad_start = startl[1] + lam * np.pi * td / T * TORSO_DIRECTION
    assert not np.allclose(relabel(bad_end) - bad_start, relabel(end0[1]) - start0[1], atol=1e-12)


def test_with_torso_uses_the_direction():
    g = FAM.evaluate(FAM.p_d, 0.5 * T)
    z = np.zeros(6)
    fake = GaitSample(q=z, dq_dp=z, dq_dtau=z, d2q_dp2=z, d2q_dtau2=z, d2q_dp_dtau=z)
    t = with_torso(fake, 0.5 * T, 0.1, T)
    np.testing.assert_array_equal(t.q, 0.1 * TORSO_DIRECTION)
    np.testing.assert_array_equal(t.dq_dlam, TORSO_DIRECTION)
    np.testing.assert_allclose(t.dq_dtau, 0.0, atol=1e-15)       # phi'(1/2) = 0
    assert g is not None
