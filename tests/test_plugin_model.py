"""What a plug-in gets of the robot with its ``ControllerSetup`` (``biped_controller.plugin.model``): the
controller-side model, the gains and the reference with named fields.

Oracles, independent of the code under test:
- the reference's partial derivatives against central finite differences of q_d(p, tau) in p and tau
  (the family's own q only), and the reference motion of eq. (11) against finite differences in time of
  q_d(p(t), tau(t)) along p(t) = p + p' t + p'' t^2 / 2, tau(t) likewise;
- the model's terms against Pinocchio called directly on the fixed-stance-foot model (CRBA, non-linear
  effects, centre of mass and its Jacobian), and against the mechanics they stand for: H(q, 0) = dV/dq with
  V = m g y_G, J_G = dx_G/dq, and the drift = d^2 x_G / ds^2 along q + q' s (finite differences);
- the gains against ``config/controller.yaml`` read by the settings reader.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from biped_controller.plugin.interface import ControllerSetup
from biped_controller.plugin.model import Gains, Reference, RobotModel
from biped_model.description import load_description
from biped_model.fixed_foot import build_fixed_foot_model
from biped_model.gait_family import GaitFamily
from biped_model.settings import default_config_dir, read_settings


@pytest.fixture(scope="module")
def setup() -> ControllerSetup:
    return ControllerSetup(load_description(), GaitFamily.load(), 0.001)


def _states(n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Joint states near the family's gait: q_d(p_d, tau) plus a perturbation, rates of a few rad/s."""
    fam = GaitFamily.load()
    rng = np.random.default_rng(seed)
    out = []
    for tau in np.linspace(0.0, fam.T, n):
        g = fam.evaluate(fam.p_d, tau)
        out.append((g.q + rng.normal(0.0, 0.05, 6), g.dq_dtau + rng.normal(0.0, 1.0, 6)))
    return out


def test_the_setup_gives_model_gains_and_reference(setup):
    assert isinstance(setup.model, RobotModel) and setup.model is setup.model     # built once
    assert isinstance(setup.reference, Reference) and setup.reference.family is setup.family
    cfg = read_settings(default_config_dir() / "controller.yaml", ["Kp", "Kv"])
    assert setup.gains == Gains(Kp=float(cfg["Kp"]), Kv=float(cfg["Kv"]))
    ref = setup.reference
    assert (ref.T, ref.p_d, ref.p_min, ref.p_max) == (setup.family.T, setup.family.p_d, setup.family.p_min,
                                                      setup.family.p_max)


def test_reference_fields_are_the_partial_derivatives_of_q_d(setup):
    """Each named field against central differences of ``at(p, tau).q`` (h = 1e-5 in both), at strides inside
    the family's spline pieces (a piece's end, where the third derivative in p jumps, would add h/6 of that
    jump to the second difference); the tolerances are far below a swapped or missing term."""
    ref = setup.reference
    h = 1e-5

    def q(p, tau):
        return ref.at(p, tau).q

    _, inner, _ = setup.family.piece_arrays()
    mids = [0.5 * (a + b) for a, b in zip(inner[:-1], inner[1:]) if ref.p_min < a and b < ref.p_max]
    for p in (mids[0], mids[len(mids) // 2], mids[-1]):
        for tau in (0.05, 0.2315, 0.8 * ref.T):
            g = ref.at(p, tau)
            assert g.p == p and g.tau == tau
            fd = {
                "dq_dp": (q(p + h, tau) - q(p - h, tau)) / (2 * h),
                "dq_dtau": (q(p, tau + h) - q(p, tau - h)) / (2 * h),
                "d2q_dp2": (q(p + h, tau) - 2 * q(p, tau) + q(p - h, tau)) / h**2,
                "d2q_dtau2": (q(p, tau + h) - 2 * q(p, tau) + q(p, tau - h)) / h**2,
                "d2q_dp_dtau": (q(p + h, tau + h) - q(p + h, tau - h) - q(p - h, tau + h) + q(p - h, tau - h))
                / (4 * h * h),
            }
            for name, want in fd.items():
                got = getattr(g, name)
                tol = 1e-4 * (1.0 + np.max(np.abs(want))) if name.startswith("d2") else 1e-6 * (1.0 + np.max(np.abs(want)))
                assert np.max(np.abs(got - want)) < tol, (name, p, tau, got, want)


def test_reference_motion_is_the_time_derivative_along_p_and_tau(setup):
    """Eq. (11): q_d' and q_d'' against differences in time of q_d(p(t), tau(t)) with constant p'', tau''."""
    ref = setup.reference
    p0, pd, pdd, t0, td, tdd = ref.p_d - 0.02, 0.15, -0.8, 0.18, 1.2, 0.6
    h = 1e-5

    def q_at(s):
        return ref.at(p0 + pd * s + 0.5 * pdd * s * s, t0 + td * s + 0.5 * tdd * s * s).q

    m = ref.at(p0, t0).motion(pd, td, pdd, tdd)
    assert np.array_equal(m.q, ref.at(p0, t0).q)
    qd_fd = (q_at(h) - q_at(-h)) / (2 * h)
    qdd_fd = (q_at(h) - 2 * q_at(0.0) + q_at(-h)) / h**2
    assert np.max(np.abs(m.qd - qd_fd)) < 1e-6 * (1 + np.max(np.abs(qd_fd)))
    assert np.max(np.abs(m.qdd - qdd_fd)) < 1e-4 * (1 + np.max(np.abs(qdd_fd)))
    same = ref.motion(p0, t0, pd, td, pdd, tdd)
    assert all(np.array_equal(getattr(same, k), getattr(m, k)) for k in ("q", "qd", "qdd"))
    q0, qd0 = ref.initial_state()
    g0 = ref.at(ref.p_d, 0.0)
    assert np.array_equal(q0, g0.q) and np.array_equal(qd0, g0.dq_dtau)


def test_model_terms_are_pinocchio_s(setup):
    """A, H, B, h_b, x_G, J_G and the drift against Pinocchio on the fixed-foot model (root: the stance
    foot's planar joint, three coordinates before the six joints)."""
    model = setup.model
    pm = build_fixed_foot_model(setup.desc)
    pd = pm.createData()
    for q, qd in _states(5, seed=3):
        x, v = np.zeros(9), np.zeros(9)
        x[3:], v[3:] = q, qd
        M = pin.crba(pm, pd, x)
        M = np.triu(M) + np.triu(M, 1).T
        nle = pin.nonLinearEffects(pm, pd, x, v)
        dyn = model.dynamics(q, qd)
        assert np.allclose(dyn.A, M[3:, 3:], rtol=0, atol=1e-12)
        assert np.allclose(dyn.B, M[:3, 3:], rtol=0, atol=1e-12)
        assert np.allclose(dyn.H, nle[3:], rtol=0, atol=1e-10)
        assert np.allclose(dyn.h_b, nle[:3], rtol=0, atol=1e-10)
        Jc = pin.jacobianCenterOfMass(pm, pd, x)
        c = pin.centerOfMass(pm, pd, x)
        terms = model.com_terms(q, qd)
        assert np.allclose(terms.position, c[[0, 2]], rtol=0, atol=1e-14)
        assert np.allclose(terms.jacobian, Jc[[0, 2], 3:], rtol=0, atol=1e-14)
        pin.centerOfMass(pm, pd, x, v, np.zeros(9))
        assert np.allclose(terms.drift, pd.acom[0][[0, 2]], rtol=0, atol=1e-12)
        state = model.com_state(q, qd)
        assert np.allclose(state.position, c[[0, 2]], rtol=0, atol=1e-14)
        assert np.allclose(state.velocity, Jc[[0, 2], 3:] @ qd, rtol=0, atol=1e-12)
        assert np.allclose(model.com(q), c[[0, 2]], rtol=0, atol=1e-14)
    assert model.mass == pytest.approx(sum(i.mass for i in pm.inertias), rel=1e-14)
    assert model.gravity == setup.desc.gravity
    lo, hi = setup.desc.torque_limits()
    assert np.array_equal(model.torque_min, lo) and np.array_equal(model.torque_max, hi)


def test_model_terms_are_the_mechanics_they_stand_for(setup):
    """H(q, 0) is the gradient of V = m g y_G, J_G the derivative of x_G, the drift the second derivative of
    x_G along q + q' s, and (A(q + q' s) - A(q - q' s)) / 2s q' - 1/2 d(q'^T A q')/dq is H(q, q') - H(q, 0)
    (Lagrange: the Coriolis and centrifugal torques); all by central differences."""
    model = setup.model
    m, g = model.mass, model.gravity
    h = 1e-6
    for q, qd in _states(4, seed=11):
        eye = np.eye(6)
        grad_V = np.array([(m * g * (model.com(q + h * e)[1] - model.com(q - h * e)[1])) / (2 * h) for e in eye])
        assert np.allclose(model.dynamics(q, np.zeros(6)).H, grad_V, rtol=0, atol=1e-6 * m * g)
        J_fd = np.column_stack([(model.com(q + h * e) - model.com(q - h * e)) / (2 * h) for e in eye])
        assert np.allclose(model.com_terms(q, qd).jacobian, J_fd, rtol=0, atol=1e-8)
        hs = 1e-4
        drift_fd = (model.com(q + hs * qd) - 2 * model.com(q) + model.com(q - hs * qd)) / hs**2
        assert np.allclose(model.com_terms(q, qd).drift, drift_fd, rtol=0, atol=1e-5 * (1 + np.max(np.abs(drift_fd))))

        def A(x):
            return model.dynamics(x, np.zeros(6)).A

        dA_dt = (A(q + h * qd) - A(q - h * qd)) / (2 * h)
        dT_dq = np.array([0.5 * qd @ (A(q + h * e) - A(q - h * e)) @ qd / (2 * h) for e in eye])
        coriolis = dA_dt @ qd - dT_dq
        H = model.dynamics(q, qd).H - model.dynamics(q, np.zeros(6)).H
        assert np.allclose(H, coriolis, rtol=0, atol=1e-5 * (1 + np.max(np.abs(coriolis))))
