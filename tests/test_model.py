"""FixedFootModel (controller model, paper eqs. 1-10) against independent references: a hand-written
planar Lagrangian of the same seven bodies (tests/helpers.py), finite differences, Newton's law for the
centre of mass, energy conservation, and the geometry of a symmetric double-support posture."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from helpers import (
    assert_close,
    central_diff,
    directional_diff,
    hand_com,
    hand_kinetic_energy,
    hand_mass_matrix,
    hand_potential_energy,
    hand_swing_foot,
    rk4_step,
)

from biped_model.fixed_foot import CONSTRAINT_NAMES, N_CONSTRAINTS, FixedFootModel, relabel


@pytest.fixture(scope="module")
def fm() -> FixedFootModel:
    return FixedFootModel()


def random_states(seed: int, n: int, qs: float = 0.7, vs: float = 1.5, ws: float = 4.0):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield rng.uniform(-qs, qs, 6), rng.uniform(-vs, vs, 6), rng.uniform(-ws, ws, 6)


# ------------------------------------------------------------------------------------- A(q), eq. (1)
def test_total_mass_matches_description(fm):
    assert_close(fm.mass, fm.desc.total_mass, 1e-12, "model mass vs description total mass")
    assert_close(fm.mass, 41.0, 1e-12, "20 + 2 (6 + 4 + 0.5)")


def test_mass_matrix_spd_and_equals_kinetic_energy_hessian(fm):
    I6 = np.eye(6)
    for q, qd, _ in random_states(1, 8):
        A = fm.dynamics(q, qd).A
        assert_close(A, A.T, 1e-12, "A symmetric")
        eig = np.linalg.eigvalsh(A)
        assert eig.min() > 1e-6, f"A not positive definite: eigenvalues {eig}"
        # Hessian of the model's own kinetic energy w.r.t. q' (exact second differences: KE is quadratic).
        k = [fm.kinetic_energy(q, I6[i]) for i in range(6)]
        Hk = np.array(
            [[2 * k[i] if i == j else fm.kinetic_energy(q, I6[i] + I6[j]) - k[i] - k[j] for j in range(6)] for i in range(6)]
        )
        assert_close(A, Hk, 1e-9, "A vs Hessian of model kinetic_energy", rel=True)
        # Independent hand-written Lagrangian.
        assert_close(A, hand_mass_matrix(fm.desc, q), 1e-9, "A vs hand-written mass matrix", rel=True)
        assert_close(fm.kinetic_energy(q, qd), 0.5 * qd @ A @ qd, 1e-9, "KE = 1/2 q'^T A q'", rel=True)
        assert_close(fm.kinetic_energy(q, qd), hand_kinetic_energy(fm.desc, q, qd), 1e-10, "KE vs hand", rel=True)


def test_potential_energy_and_com_match_hand_reference(fm):
    for q, _, _ in random_states(2, 8):
        assert_close(fm.com(q), hand_com(fm.desc, q), 1e-12, "x_G vs hand centre of mass")
        # Potential energy m g z_G with the stance ankle at height 0.
        assert_close(fm.potential_energy(q), hand_potential_energy(fm.desc, q), 1e-10, "V vs hand", rel=True)


# ------------------------------------------------------------------------------------- H(q, q')
def test_H_equals_rnea_and_lagrangian(fm):
    desc = fm.desc
    for q, qd, _ in random_states(3, 6):
        d = fm.dynamics(q, qd)
        data = fm.model.createData()
        qf = np.concatenate([np.zeros(3), q])
        vf = np.concatenate([np.zeros(3), qd])
        tau = pin.rnea(fm.model, data, qf, vf, np.zeros(9))
        assert_close(d.H, tau[3:], 1e-10, "H vs RNEA(q, q', 0)", rel=True)
        assert_close(d.h_b, tau[:3], 1e-10, "h_b vs RNEA root rows", rel=True)
        g = pin.computeGeneralizedGravity(fm.model, data, qf)[3:]
        c = pin.computeCoriolisMatrix(fm.model, data, qf, vf)[3:, 3:] @ qd
        assert_close(d.H, g + c, 1e-10, "H = G + C q'", rel=True)
        # Lagrange with the hand model: H = (dA/dt) q' - dT/dq + dV/dq.
        Adot_qd = directional_diff(lambda t: hand_mass_matrix(desc, q + t * qd) @ qd, 1e-4)
        dT = central_diff(lambda x: hand_kinetic_energy(desc, x, qd), q, 1e-5)
        dV = central_diff(lambda x: hand_potential_energy(desc, x), q, 1e-5)
        assert_close(d.H, Adot_qd - dT + dV, 1e-6, "H vs Lagrangian of hand model", rel=True)
        # Gravity part alone = gradient of the model's potential energy.
        dV_model = central_diff(fm.potential_energy, q, 1e-5)
        assert_close(g, dV_model, 1e-6, "gravity torques vs grad potential_energy", rel=True)
        assert_close(fm.dynamics(q, np.zeros(6)).H, dV, 1e-6, "H(q, 0) vs grad hand V", rel=True)


def test_inverse_dynamics_consistent_with_A_and_H(fm):
    for q, qd, w in random_states(4, 6):
        d = fm.dynamics(q, qd)
        gam, r = fm.inverse_dynamics(q, qd, w)
        assert_close(gam, d.A @ w + d.H, 1e-9, "Gamma = A w + H", rel=True)
        assert_close(r, d.B @ w + d.h_b, 1e-9, "reaction = B w + h_b", rel=True)


# ------------------------------------------------------------------------------------- statics
def test_static_posture_reaction_cop_and_torques(fm):
    desc = fm.desc
    Mg = fm.mass * desc.gravity
    for q, _, _ in random_states(5, 8, qs=0.5):
        gam, r = fm.inverse_dynamics(q, np.zeros(6), np.zeros(6))
        assert_close(r[1], Mg, 1e-9, "static R_y = M g", rel=True)
        assert_close(r[0], 0.0, 1e-9, "static R_x = 0")
        l = gam[0] / r[1]
        xg = hand_com(desc, q)[0]
        assert_close(l, xg, 1e-10, "static centre of pressure = x_G (ankle at x = 0)")
        grad = central_diff(lambda x: hand_potential_energy(desc, x), q, 1e-5)
        assert_close(gam, grad, 1e-6, "static torques = grad V (hand)", rel=True)


# ------------------------------------------------------------------------------------- eq. (7)
def test_ground_moment_about_ankle_equals_gamma1(fm):
    for q, qd, w in random_states(6, 10):
        gam, r = fm.inverse_dynamics(q, qd, w)
        assert_close(r[2], gam[0], 1e-9, "eq. (7): ground moment about ankle = Gamma_1", rel=True)


def test_ground_moment_from_angular_momentum_balance(fm):
    """Independent of eq. (7): m_a = dL_ankle/dt - (moment of gravity about the ankle), L from the hand model."""
    desc = fm.desc
    M = fm.mass
    for q, qd, w in random_states(7, 5):
        _, r = fm.inverse_dynamics(q, qd, w)

        def L_ankle(t):  # ccw angular momentum about the (fixed) ankle along q(t) = q + t q' + t^2/2 w
            qt, vt = q + t * qd + 0.5 * t * t * w, qd + t * w
            # dT/dq1' with all angles relative to the foot equals the angular momentum about the ankle
            # (q1 rotates the whole chain about the ankle).
            return central_diff(lambda v: hand_kinetic_energy(desc, qt, v), vt, 1e-3)[0]

        dL = directional_diff(L_ankle, 1e-3)
        xg = hand_com(desc, q)[0]
        grav_moment = -M * desc.gravity * xg  # gravity at x_G > 0 turns clockwise
        assert_close(r[2], dL - grav_moment, 1e-6, "m_a vs angular momentum balance", rel=True)


# ------------------------------------------------------------------------------------- eq. (10)
def test_constraint_rows_equal_direct_and_newton(fm):
    Mg = fm.mass * fm.desc.gravity
    assert N_CONSTRAINTS == 17 == len(CONSTRAINT_NAMES)
    for q, qd, w in random_states(8, 10):
        cm = fm.constraints(q, qd)
        assert cm.A_q.shape == (17, 6) and cm.b_q.shape == (17,)
        vals = cm.A_q @ w + cm.b_q
        assert_close(vals, -fm.margins_direct(q, qd, w), 1e-9, "A_q w + b_q vs margins_direct", rel=True)
        # Newton's law for the centre of mass (eqs. 3-4).
        _, JG, drift = fm.com_terms(q, qd)
        Rx = fm.mass * (JG[0] @ w + drift[0])
        Ry = fm.mass * (JG[1] @ w + drift[1]) + Mg
        gam, _ = fm.inverse_dynamics(q, qd, w)
        mu, lm, lM = fm.mu, fm.l_min, fm.l_max
        ref = np.concatenate(
            [[-Ry, -mu * Ry - Rx, -mu * Ry + Rx, lm * Ry - gam[0], gam[0] - lM * Ry], gam - fm.torque_max, fm.torque_min - gam]
        )
        assert_close(vals[:5], ref[:5], 1e-9, "reaction rows vs Newton for the CoM", rel=True)
        assert_close(vals, ref, 1e-9, "all rows vs Newton + RNEA torques", rel=True)


def test_constraint_signs_in_static_posture(fm):
    """At rest the robot standing upright satisfies every constraint (negative values), with the
    documented margins: take-off row = -M g, friction rows = -mu M g."""
    Mg = fm.mass * fm.desc.gravity
    cm = fm.constraints(np.zeros(6), np.zeros(6))
    vals = cm.b_q
    assert np.all(vals < 0), dict(zip(CONSTRAINT_NAMES, vals))
    assert_close(vals[0], -Mg, 1e-9, "take-off row", rel=True)
    assert_close(vals[1:3], [-fm.mu * Mg] * 2, 1e-9, "friction rows", rel=True)


def test_com_jacobian_and_drift(fm):
    desc = fm.desc
    for q, qd, w in random_states(9, 6):
        xg, JG, drift = fm.com_terms(q, qd)
        assert_close(xg, hand_com(desc, q), 1e-12, "x_G from com_terms vs hand")
        assert_close(JG, central_diff(fm.com, q, 1e-6), 1e-8, "J_G vs FD of com(q)")
        assert_close(JG, central_diff(lambda x: hand_com(desc, x), q, 1e-6), 1e-8, "J_G vs FD of hand com")
        Jdot_qd = directional_diff(lambda t: fm.com_terms(q + t * qd, qd)[1] @ qd, 1e-4)
        assert_close(drift, Jdot_qd, 1e-7, "drift vs d/dt(J_G) q'", rel=True)
        # CoM acceleration along q(t) = q + t q' + t^2/2 w by second differences of the hand CoM.
        h = 1e-4
        c = lambda t: hand_com(desc, q + t * qd + 0.5 * t * t * w)  # noqa: E731
        acc = (c(h) - 2 * c(0.0) + c(-h)) / h**2
        assert_close(JG @ w + drift, acc, 1e-5, "J_G w + drift vs CoM second difference", rel=True)
        # the cheap pair (x_G, x_G'): the hand CoM and its directional derivative along q'
        xc, vc = fm.com_velocity(q, qd)
        assert_close(xc, hand_com(desc, q), 1e-12, "x_G from com_velocity vs hand")
        assert_close(vc, directional_diff(lambda t: hand_com(desc, q + t * qd), 1e-6), 1e-7,
                     "x_G' from com_velocity vs FD of hand com along q'", rel=True)


# ------------------------------------------------------------------------------------- energy
def test_zero_torque_motion_conserves_energy(fm):
    rng = np.random.default_rng(10)
    q0 = rng.uniform(-0.3, 0.3, 6)
    qd0 = rng.uniform(-0.5, 0.5, 6)

    def f(y):
        d = fm.dynamics(y[:6], y[6:])
        return np.concatenate([y[6:], np.linalg.solve(d.A, -d.H)])

    def energy(y):
        return fm.kinetic_energy(y[:6], y[6:]) + fm.potential_energy(y[:6])

    y = np.concatenate([q0, qd0])
    e0 = energy(y)
    dt, n = 2.5e-4, 4000
    worst = 0.0
    scale = abs(e0) + fm.mass * fm.desc.gravity * fm.desc.leg_length
    for _ in range(n):
        y = rk4_step(f, y, dt)
        worst = max(worst, abs(energy(y) - e0) / scale)
    assert np.all(np.isfinite(y))
    assert np.max(np.abs(y[6:])) > 0.5, "the motion should be non-trivial"
    assert worst < 1e-6, f"relative energy drift {worst:.3e}"


def test_energy_drifts_under_wrong_dynamics(fm):
    """The energy test can fail: dropping the Coriolis part of H breaks conservation."""
    rng = np.random.default_rng(11)
    y = np.concatenate([rng.uniform(-0.3, 0.3, 6), rng.uniform(-1.0, 1.0, 6)])

    def f(y):
        d = fm.dynamics(y[:6], y[6:])
        g = fm.dynamics(y[:6], np.zeros(6)).H
        return np.concatenate([y[6:], np.linalg.solve(d.A, -g)])

    e0 = fm.kinetic_energy(y[:6], y[6:]) + fm.potential_energy(y[:6])
    for _ in range(400):
        y = rk4_step(f, y, 1e-3)
    e1 = fm.kinetic_energy(y[:6], y[6:]) + fm.potential_energy(y[:6])
    assert abs(e1 - e0) / abs(e0) > 1e-4


# ------------------------------------------------------------------------------------- relabelling, swing foot
def test_relabel_is_an_involution():
    rng = np.random.default_rng(12)
    for _ in range(5):
        q = rng.normal(size=6)
        assert_close(relabel(relabel(q)), q, 0.0, "relabel twice")
        assert_close(relabel(q), [-q[5], -q[4], -q[3], -q[2], -q[1], -q[0]], 0.0, "relabel = -q[::-1]")
    assert_close(relabel(np.zeros(6)), np.zeros(6), 0.0, "relabel(0)")
    q = rng.normal(size=6)
    q_copy = q.copy()
    relabel(q)
    assert_close(q, q_copy, 0.0, "relabel must not modify its argument")


def test_swing_foot_at_zero_posture(fm):
    pose, vel = fm.swing_foot(np.zeros(6), np.zeros(6))
    assert_close(pose, np.zeros(3), 1e-12, "swing foot at q = 0")
    assert_close(vel, np.zeros(3), 1e-12, "swing foot velocity at rest")


@pytest.mark.parametrize("a", [-0.35, -0.1, 0.2])
def test_swing_foot_symmetric_double_support(fm, a):
    # Stance leg straight, tilted by q1 = a (ccw); torso upright (q3 = -a); swing leg straight at -a from
    # the vertical. q1 > 0 tilts the stance leg backwards (hip behind the stance ankle), so the swing
    # foot lands behind: x = -2 * 0.8 * sin(a). A forward step (swing foot ahead) needs a < 0.
    q = np.array([a, 0.0, -a, -a, 0.0, a])
    pose, _ = fm.swing_foot(q)
    L = fm.desc.leg_length
    assert_close(pose, [-2 * L * np.sin(a), 0.0, 0.0], 1e-12, f"swing foot, symmetric posture a={a}")
    assert_close(pose, hand_swing_foot(fm.desc, q), 1e-12, "swing foot vs hand kinematics")
    if a < 0:
        assert pose[0] > 0, "a < 0 must put the swing foot ahead"


def test_swing_foot_random_and_jacobian(fm):
    desc = fm.desc
    rng = np.random.default_rng(13)
    for _ in range(6):
        q, qd = rng.uniform(-0.8, 0.8, 6), rng.uniform(-2, 2, 6)
        pose, vel = fm.swing_foot(q, qd)
        assert_close(pose, hand_swing_foot(desc, q), 1e-12, "swing foot pose vs hand")
        J = fm.swing_foot_jacobian(q)
        assert_close(J, central_diff(lambda x: fm.swing_foot(x)[0], q, 1e-6), 1e-8, "swing foot Jacobian vs FD")
        assert_close(J, central_diff(lambda x: hand_swing_foot(desc, x), q, 1e-6), 1e-8, "Jacobian vs FD of hand")
        assert_close(vel, J @ qd, 1e-10, "swing foot velocity = J q'", rel=True)


def test_model_data_is_not_stale(fm):
    """Calls with different arguments must not leak state (qd from a previous call)."""
    rng = np.random.default_rng(14)
    q, qd = rng.uniform(-0.5, 0.5, 6), rng.uniform(-1, 1, 6)
    fm.kinetic_energy(q, qd)
    pose_a, _ = fm.swing_foot(q)
    fresh = FixedFootModel(fm.desc)
    pose_b, _ = fresh.swing_foot(q)
    assert_close(pose_a, pose_b, 1e-14, "swing foot independent of previous calls")
    fm.dynamics(q, qd)
    xg, _, drift = fm.com_terms(q, np.zeros(6))
    assert_close(drift, np.zeros(2), 1e-12, "drift with q' = 0")
