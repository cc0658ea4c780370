"""FloatingModel (simulator side): impact map and contact dynamics, checked against momentum balance,
finite differences of the kinematics, the direct KKT solve, and the controller's FixedFootModel."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from helpers import assert_close, directional_diff

from biped_model.fixed_foot import FixedFootModel, relabel
from biped_model.description import LEFT, RIGHT
from biped_model.floating import FloatingModel, impact_paper, paper_from_urdf, urdf_from_paper

STANCES = (LEFT, RIGHT)


@pytest.fixture(scope="module")
def fl() -> FloatingModel:
    return FloatingModel()


@pytest.fixture(scope="module")
def ff() -> FixedFootModel:
    return FixedFootModel()


def double_support(ff: FixedFootModel, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """A posture with both feet flat on the ground, swing foot ahead at stride p > 0.

    Stance leg tilted forwards (q1 < 0) with a slightly flexed knee (q2 >= 0), torso near upright; the
    swing leg reaches the ground ahead by two-link inverse kinematics (swing knee flexed, q5 < 0), and
    q6 makes the swing foot flat."""
    d = ff.desc
    Lsh, Lth = d.shin.length, d.thigh.length
    for _ in range(1000):  # rejection sampling: the swing leg must reach the ground with a bent knee
        q = np.zeros(6)
        q[0] = rng.uniform(-0.45, -0.15)
        q[1] = rng.uniform(0.0, 0.3)
        q[2] = -(q[0] + q[1]) + rng.uniform(-0.1, 0.1)
        t1, t2, t3 = np.cumsum(q[:3])
        hip = Lsh * np.array([-np.sin(t1), np.cos(t1)]) + Lth * np.array([-np.sin(t2), np.cos(t2)])
        phi = rng.uniform(0.15, 0.45)  # swing leg (hip -> ankle) angle from the vertical, forwards
        if hip[1] / np.cos(phi) < 0.99 * (Lsh + Lth):
            break
    else:
        raise AssertionError("no double-support posture found")
    p = hip[0] + hip[1] * np.tan(phi)
    r = np.array([p, 0.0]) - hip
    c5 = (r @ r - Lth**2 - Lsh**2) / (2 * Lth * Lsh)
    q[4] = -np.arccos(c5)
    beta = np.arctan2(Lsh * np.sin(q[4]), Lth + Lsh * np.cos(q[4]))
    theta4 = np.arctan2(r[0], -r[1]) - beta  # leg direction (sin t, -cos t)
    q[3] = theta4 - t3
    q[5] = -np.sum(q[:5])
    pose, _ = ff.swing_foot(q)
    assert_close(pose, [p, 0.0, 0.0], 1e-12, "double-support posture construction")
    assert p > 0
    return q, p


def landing_velocity(ff: FixedFootModel, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random q' whose swing foot moves downwards (and a little along x / in pitch)."""
    qd = rng.uniform(-1.0, 1.0, 6)
    J = ff.swing_foot_jacobian(q)
    target = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.6, -0.1), rng.uniform(-0.3, 0.3)])
    qd = qd + np.linalg.pinv(J) @ (target - J @ qd)
    assert_close(J @ qd, target, 1e-10, "landing velocity construction")
    return qd


def momentum(fl: FloatingModel, x: np.ndarray, v: np.ndarray, point: np.ndarray) -> tuple[np.ndarray, float]:
    """(linear momentum (x, z) [N s], ccw angular momentum about world point (x, z) [N m s])."""
    data = fl.model.createData()
    hg = pin.computeCentroidalMomentum(fl.model, data, x, v)
    c = data.com[0]
    P = hg.linear
    r = np.array([c[0] - point[0], 0.0, c[2] - point[1]])
    L = hg.angular + np.cross(r, P)
    return np.array([P[0], P[2]]), -float(L[1])  # ccw = about -y


def impact_cases(ff, seed, n=4):
    rng = np.random.default_rng(seed)
    for i in range(n):
        q, p = double_support(ff, rng)
        qd = landing_velocity(ff, q, rng)
        yield STANCES[i % 2], q, qd, p


# ------------------------------------------------------------------------------------- impact
def test_pre_impact_state_geometry(fl, ff):
    for stance, q, qd, p in impact_cases(ff, 20):
        x, v = fl.state_from_paper(q, qd, stance)
        new = 1 - stance
        assert_close(fl.foot_pose(x, stance), np.zeros(3), 1e-12, "stance foot at origin, flat")
        assert_close(fl.foot_pose(x, new), [p, 0.0, 0.0], 1e-12, "swing foot on the ground at stride p")
        assert_close(fl.foot_velocity(x, v, stance), np.zeros(3), 1e-12, "stance foot at rest")
        _, vel = ff.swing_foot(q, qd)
        assert_close(fl.foot_velocity(x, v, new), vel, 1e-10, "swing foot velocity: floating vs fixed-foot")
        assert vel[1] < 0
        # Heel and toe of both feet on the ground.
        for foot in (stance, new):
            assert_close(fl.sole_points(x, foot)[:, 1], np.zeros(2), 1e-12, "sole on the ground")


def test_impact_momentum_balance(fl, ff):
    for stance, q, qd, p in impact_cases(ff, 21, n=6):
        x, v = fl.state_from_paper(q, qd, stance)
        new = 1 - stance
        res = fl.impact(x, v, new)
        P0, L0 = momentum(fl, x, v, (p, 0.0))
        P1, L1 = momentum(fl, x, res.v_plus, (p, 0.0))
        # Linear momentum changes only by the ground's impulse on the new stance foot.
        assert_close(P1 - P0, res.impulse[:2], 1e-9, "Delta linear momentum = impulse force", rel=True)
        Mtot = fl.mass
        data = fl.model.createData()
        vg0 = (pin.jacobianCenterOfMass(fl.model, data, x) @ v)[[0, 2]]
        vg1 = (pin.jacobianCenterOfMass(fl.model, data, x) @ res.v_plus)[[0, 2]]
        assert_close(Mtot * (vg1 - vg0), res.impulse[:2], 1e-9, "M dv_G = impulse", rel=True)
        # Angular momentum about the new ankle: the impulse force passes through it, so only the
        # impulsive moment of the flat foot changes it (a point foot would conserve it exactly).
        assert_close(L1 - L0, res.impulse[2], 1e-9, "Delta L about new ankle = impulsive moment", rel=True)


def test_impact_point_foot_conserves_angular_momentum(fl, ff):
    """Same check with the moment row removed (point contact at the ankle): L about it is conserved."""
    for stance, q, qd, p in impact_cases(ff, 22):
        x, v = fl.state_from_paper(q, qd, stance)
        M = fl.mass_matrix(x)
        J = fl.contact_jacobian(x, 1 - stance)[:2]
        lam = np.linalg.solve(J @ np.linalg.solve(M, J.T), -J @ v)
        v_plus = v + np.linalg.solve(M, J.T @ lam)
        _, L0 = momentum(fl, x, v, (p, 0.0))
        _, L1 = momentum(fl, x, v_plus, (p, 0.0))
        assert_close(L1, L0, 1e-9, "point-foot impact conserves L about contact", rel=True)


def test_impact_new_foot_stops_and_matches_kkt(fl, ff):
    for stance, q, qd, p in impact_cases(ff, 23, n=6):
        x, v = fl.state_from_paper(q, qd, stance)
        new = 1 - stance
        res = fl.impact(x, v, new)
        # Post-impact velocity of the new foot by finite differences of its pose (not via contact_jacobian).
        fd_new = directional_diff(lambda t: fl.foot_pose(x + t * res.v_plus, new), 1e-5)
        assert_close(fd_new, np.zeros(3), 1e-8, "new stance foot at rest after impact")
        fd_old = directional_diff(lambda t: fl.foot_pose(x + t * res.v_plus, stance), 1e-5)
        assert_close(res.old_foot_velocity, fd_old, 1e-8, "old foot velocity after impact", rel=True)
        v_kkt, lam_kkt = fl.impact_kkt(x, v, new)
        assert_close(res.v_plus, v_kkt, 1e-10, "Schur v+ vs KKT", rel=True)
        assert_close(res.impulse, lam_kkt, 1e-10, "Schur impulse vs KKT", rel=True)
        ke0, ke1 = fl.kinetic_energy(x, v), fl.kinetic_energy(x, res.v_plus)
        assert res.energy_loss >= 0.0, res.energy_loss
        assert_close(res.energy_loss, ke0 - ke1, 1e-9, "energy loss = KE- - KE+", rel=True)
        assert res.energy_loss > 1e-6, "a downward landing must dissipate energy"


def test_impact_paper_relabels_consistently(fl, ff):
    for stance, q, qd, p in impact_cases(ff, 24):
        qd_new, res = impact_paper(fl, q, qd, stance)
        new = 1 - stance
        x, _ = fl.state_from_paper(q, qd, stance)
        q_new = paper_from_urdf(x[3:], new)
        assert_close(q_new, relabel(q), 1e-15, "new-stance paper coordinates = relabel(q)")
        assert_close(qd_new, paper_from_urdf(res.v_plus[3:], new), 1e-15, "q'+ in the new labels")
        # The controller model in the new labels sees the former stance foot as the swing foot.
        pose, vel = ff.swing_foot(q_new, qd_new)
        assert_close(pose, [-p, 0.0, 0.0], 1e-12, "old stance foot behind the new one")
        assert_close(vel, res.old_foot_velocity, 1e-9, "old foot velocity: fixed-foot vs floating", rel=True)
        assert_close(ff.kinetic_energy(q_new, qd_new), fl.kinetic_energy(x, res.v_plus), 1e-9,
                     "post-impact KE: fixed-foot (new labels) vs floating", rel=True)


# ------------------------------------------------------------------------------------- contact dynamics
def contact_cases(seed, n=6):
    rng = np.random.default_rng(seed)
    for i in range(n):
        q = rng.uniform(-0.6, 0.6, 6)
        yield STANCES[i % 2], q, rng.uniform(-1.5, 1.5, 6), rng.uniform(-60, 60, 6)


def test_contact_dynamics_holds_the_foot(fl):
    for stance, q, qd, gam in contact_cases(30):
        x, v = fl.state_from_paper(q, qd, stance)
        tau = np.concatenate([np.zeros(3), urdf_from_paper(gam, stance)])
        sol = fl.contact_dynamics(x, v, tau, stance)
        J = fl.contact_jacobian(x, stance)
        assert_close(J @ sol.a + fl.contact_drift(x, v, stance), np.zeros(3), 1e-9, "J a + J' v = 0", rel=True)
        # Independently: the foot's pose along x(t) = x + t v + t^2/2 a has zero second derivative.
        h = 1e-3
        f = lambda t: fl.foot_pose(x + t * v + 0.5 * t * t * sol.a, stance)  # noqa: E731
        acc = (16 * (f(h) + f(-h)) - (f(2 * h) + f(-2 * h)) - 30 * f(0.0)) / (12 * h**2)
        scale = max(1.0, float(np.max(np.abs(sol.a))))
        assert_close(acc, np.zeros(3), 1e-7 * scale, "foot acceleration by second differences")
        # Equations of motion hold with the returned wrench.
        M = fl.mass_matrix(x)
        h_nl = pin.rnea(fl.model, fl.model.createData(), x, v, np.zeros(9))
        assert_close(M @ sol.a + h_nl, tau + J.T @ sol.wrench, 1e-9, "M a + h = tau + J^T lambda", rel=True)


def test_contact_wrench_equals_controller_prediction(fl, ff):
    for stance, q, qd, gam in contact_cases(31, n=8):
        x, v = fl.state_from_paper(q, qd, stance)
        tau = np.concatenate([np.zeros(3), urdf_from_paper(gam, stance)])
        sol = fl.contact_dynamics(x, v, tau, stance)
        w = paper_from_urdf(sol.a[3:], stance)
        gam_ff, reaction = ff.inverse_dynamics(q, qd, w)
        assert_close(gam_ff, gam, 1e-8, f"torques: controller inverse dynamics, stance {stance}", rel=True)
        assert_close(sol.wrench, reaction, 1e-8, f"ground wrench: floating vs controller, stance {stance}", rel=True)
        # And the controller's forward dynamics gives the same joint accelerations.
        d = ff.dynamics(q, qd)
        assert_close(np.linalg.solve(d.A, gam - d.H), w, 1e-8, "joint accelerations", rel=True)


def test_energies_match_controller_model(fl, ff):
    for stance, q, qd, _ in contact_cases(32, n=8):
        x, v = fl.state_from_paper(q, qd, stance)
        assert_close(fl.kinetic_energy(x, v), ff.kinetic_energy(q, qd), 1e-10, f"KE stance {stance}", rel=True)
        assert_close(fl.potential_energy(x), ff.potential_energy(q), 1e-10, f"PE stance {stance}", rel=True)
        assert_close(fl.com(x), ff.com(q), 1e-12, f"CoM stance {stance}")
    assert_close(fl.mass, ff.mass, 1e-12, "total mass floating vs fixed")


# ------------------------------------------------------------------------------------- coordinate maps
def test_paper_urdf_maps_are_inverse_and_match_design():
    rng = np.random.default_rng(40)
    for _ in range(5):
        qj = rng.normal(size=6)
        q = rng.normal(size=6)
        for s in STANCES:
            assert_close(urdf_from_paper(paper_from_urdf(qj, s), s), qj, 1e-15, "urdf(paper(qj))")
            assert_close(paper_from_urdf(urdf_from_paper(q, s), s), q, 1e-15, "paper(urdf(q))")
            # The other leg's view is the relabelled one.
            assert_close(paper_from_urdf(urdf_from_paper(q, s), 1 - s), relabel(q), 1e-15, "relabel via maps")
        lh, lk, la, rh, rk, ra = qj
        assert_close(paper_from_urdf(qj, LEFT), [-la, -lk, -lh, rh, rk, ra], 0.0, "DESIGN.md left-stance map")
        assert_close(paper_from_urdf(qj, RIGHT), [-ra, -rk, -rh, lh, lk, la], 0.0, "right-stance map")


def test_state_from_paper_round_trip(fl):
    rng = np.random.default_rng(41)
    for s in STANCES:
        q, qd = rng.uniform(-0.6, 0.6, 6), rng.normal(size=6)
        x, v = fl.state_from_paper(q, qd, s, ankle_x=0.37, foot_pitch=0.05)
        assert_close(fl.foot_pose(x, s), [0.37, 0.0, 0.05], 1e-12, "stance foot target pose")
        assert_close(fl.foot_velocity(x, v, s), np.zeros(3), 1e-12, "stance foot at rest")
        qb, qdb = fl.paper_from_state(x, v, s)
        assert_close(qb, q, 1e-15, "paper q round trip")
        assert_close(qdb, qd, 1e-15, "paper q' round trip")


def test_push_jacobian_matches_finite_differences(fl):
    """Velocity of a torso point at height h above the hip: J_push v vs the derivative of its position."""
    rng = np.random.default_rng(42)
    for _ in range(4):
        x = np.concatenate([rng.normal(size=2), rng.uniform(-0.5, 0.5, 7)])
        v = rng.normal(size=9)
        h = rng.uniform(0.1, 0.6)

        def point(t):
            xt = x + t * v
            return np.array([xt[0] - h * np.sin(xt[2]), xt[1] + h * np.cos(xt[2])])

        assert_close(fl.push_jacobian(x, h) @ v, directional_diff(point, 1e-5), 1e-9, "push Jacobian", rel=True)
