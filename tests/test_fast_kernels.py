"""Fast engine (compiled planar kernels) against the Pinocchio reference engine.

Every kernel is compared with ``FloatingModel`` / ``FixedFootModel`` at N_STATES seeded random states to
1e-10 relative to the scale of the reference value; the one-call RK4 step with an RK4 step written here
from ``FloatingModel.contact_dynamics`` and the simulator's projection (same constant torque and push);
the impact with ``FloatingModel.impact`` and its own KKT residuals. Independent of Pinocchio: the energy
balance of integrated motions (work of constant torques and forces = change of energy) and the two
kernel paths to the kinetic energy (body sum vs v^T M v). Negative controls show that a perturbed
inertia is detected at these tolerances.
"""
from __future__ import annotations

import io
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from helpers import assert_close

from biped_model.fixed_foot import FixedFootModel
from biped_model import numba_cache
from biped_model.description import LEFT, RIGHT, load_description
from biped_model.fast_engine import (
    PX, REV, Body, FastFixedFootModel, FastFloatingModel, Joint, PlanarTree, TreeError, fixed_foot_tree,
    floating_tree, push_arrays,
)
from biped_model.floating import FloatingModel, SimulationError

N_STATES = 60
TOL = 1e-10
FEET = (LEFT, RIGHT)


@pytest.fixture(scope="module")
def desc():
    return load_description()


@pytest.fixture(scope="module")
def ref(desc) -> FloatingModel:
    return FloatingModel(desc)


@pytest.fixture(scope="module")
def fast(desc) -> FastFloatingModel:
    return FastFloatingModel(desc)


@pytest.fixture(scope="module")
def ref_ctrl(desc) -> FixedFootModel:
    return FixedFootModel(desc)


@pytest.fixture(scope="module")
def fast_ctrl(desc) -> FastFixedFootModel:
    return FastFixedFootModel(desc)


def free_state(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random floating state (no contact): base anywhere, joints over a wide range, brisk velocities."""
    x = np.concatenate([rng.uniform(-2.0, 2.0, 1), rng.uniform(0.3, 1.2, 1), rng.uniform(-1.0, 1.0, 1),
                        rng.uniform(-1.5, 1.5, 6)])
    v = rng.normal(0.0, 2.0, 9)
    return x, v


def contact_state(model, rng: np.random.Generator):
    """A random state on a stance foot's contact manifold: (x, v, stance, anchor)."""
    stance = int(rng.integers(0, 2))
    q = rng.uniform(-0.6, 0.6, 6)
    qd = rng.normal(0.0, 1.5, 6)
    anchor = np.array([rng.uniform(-1.0, 1.0), 0.0, rng.uniform(-0.05, 0.05)])
    x, v = model.state_from_paper(q, qd, stance, ankle_x=anchor[0], foot_pitch=anchor[2])
    return x, v, stance, anchor


def random_pushes(rng: np.random.Generator, torso_length: float) -> tuple[tuple[float, float], ...]:
    n = int(rng.integers(0, 3))  # none, one, or two simultaneous pushes
    return tuple((float(rng.uniform(-150.0, 150.0)), float(rng.uniform(0.0, torso_length))) for _ in range(n))


# ------------------------------------------------------------------------------------------ reference RK4
def ref_accel(ref: FloatingModel, x, v, tau_j, pushes, foot):
    tau = np.zeros(9)
    tau[3:] = tau_j
    for f, height in pushes:
        tau += ref.push_jacobian(x, height).T @ np.array([f, 0.0])
    sol = ref.contact_dynamics(x, v, tau, foot)
    return sol.a, sol.wrench


def ref_project(ref: FloatingModel, x, v, foot, anchor):
    """The simulator's projection: foot pitch through x[2], then the ankle position through x[0], x[1];
    v <- v - M^-1 J^T (J M^-1 J^T)^-1 J v."""
    x = x.copy()
    pose = ref.foot_pose(x, foot)
    x[2] += anchor[2] - pose[2]
    pose = ref.foot_pose(x, foot)
    x[0] += anchor[0] - pose[0]
    x[1] += anchor[1] - pose[1]
    J = ref.contact_jacobian(x, foot)
    MiJt = ref.inverse_mass_matrix(x) @ J.T
    return x, v - MiJt @ np.linalg.solve(J @ MiJt, J @ v)


def ref_rk4(ref: FloatingModel, x, v, tau_j, pushes, foot, anchor, h):
    """Classical RK4 with torque and pushes constant over the step, then the projection; also returns the
    wrench at the step start."""
    k1x, (k1v, w1) = v, ref_accel(ref, x, v, tau_j, pushes, foot)
    k2x = v + 0.5 * h * k1v
    k2v, _ = ref_accel(ref, x + 0.5 * h * k1x, k2x, tau_j, pushes, foot)
    k3x = v + 0.5 * h * k2v
    k3v, _ = ref_accel(ref, x + 0.5 * h * k2x, k3x, tau_j, pushes, foot)
    k4x = v + h * k3v
    k4v, _ = ref_accel(ref, x + h * k3x, k4x, tau_j, pushes, foot)
    xn = x + (h / 6.0) * (k1x + 2 * k2x + 2 * k3x + k4x)
    vn = v + (h / 6.0) * (k1v + 2 * k2v + 2 * k3v + k4v)
    xp, vp = ref_project(ref, xn, vn, foot, anchor)
    return xp, vp, w1


def ref_probe(ref: FloatingModel, x, v, foot, sole):
    """Lowest sole point height, ankle z rate and that point's z rate (the simulator's touchdown test)."""
    pts = ref.sole_points(x, foot)
    i = int(np.argmin(pts[:, 1]))
    fv = ref.foot_velocity(x, v, foot)
    th = ref.foot_pose(x, foot)[2]
    return np.array([pts[i, 1], fv[1], fv[1] + sole[i] * np.cos(th) * fv[2]])


# ------------------------------------------------------------------------------------------ floating model
def test_mass_matrix_and_bias(ref, fast):
    checked = 0
    for seed in range(N_STATES):
        x, v = free_state(np.random.default_rng(seed))
        M, h = fast.mass_bias(x, v)
        assert_close(M, ref.mass_matrix(x), TOL, f"seed {seed}: M", rel=True)
        assert_close(h, pin.nonLinearEffects(ref.model, ref.data, x, v), TOL, f"seed {seed}: h", rel=True)
        assert_close(fast.mass_matrix(x), M, 0.0, f"seed {seed}: mass_matrix = mass_bias[0]")
        assert_close(fast.inverse_mass_matrix(x) @ M, np.eye(9), 1e-9, f"seed {seed}: M^-1 M")
        checked += 1
    assert checked == N_STATES


def test_kinematics_of_feet_and_push_point(ref, fast, desc):
    checked = 0
    for seed in range(N_STATES):
        rng = np.random.default_rng(1000 + seed)
        x, v = free_state(rng)
        for foot in FEET:
            assert_close(fast.foot_pose(x, foot), ref.foot_pose(x, foot), TOL, f"seed {seed}: foot pose {foot}", rel=True)
            assert_close(fast.sole_points(x, foot), ref.sole_points(x, foot), TOL, f"seed {seed}: soles {foot}", rel=True)
            assert_close(fast.contact_jacobian(x, foot), ref.contact_jacobian(x, foot), TOL,
                         f"seed {seed}: contact Jacobian {foot}", rel=True)
            assert_close(fast.contact_drift(x, v, foot), ref.contact_drift(x, v, foot), TOL,
                         f"seed {seed}: contact drift {foot}", rel=True)
            assert_close(fast.foot_velocity(x, v, foot), ref.foot_velocity(x, v, foot), TOL,
                         f"seed {seed}: foot velocity {foot}", rel=True)
            assert_close(fast.swing_probe(x, v, foot), ref_probe(ref, x, v, foot, (desc.foot.l_min, desc.foot.l_max)),
                         TOL, f"seed {seed}: swing probe {foot}", rel=True)
        height = float(rng.uniform(0.0, desc.torso.length))
        assert_close(fast.push_jacobian(x, height), ref.push_jacobian(x, height), TOL, f"seed {seed}: push Jacobian",
                     rel=True)
        checked += 1
    assert checked == N_STATES


def test_contact_and_free_dynamics(ref, fast):
    checked = 0
    for seed in range(N_STATES):
        rng = np.random.default_rng(2000 + seed)
        x, v = free_state(rng)
        tau = rng.normal(0.0, 30.0, 9)
        for foot in FEET:
            got = fast.contact_dynamics(x, v, tau, foot)
            want = ref.contact_dynamics(x, v, tau, foot)
            assert_close(got.a, want.a, TOL, f"seed {seed}: contact acceleration {foot}", rel=True)
            assert_close(got.wrench, want.wrench, TOL, f"seed {seed}: contact wrench {foot}", rel=True)
        assert_close(fast.free_dynamics(x, v, tau), ref.free_dynamics(x, v, tau), TOL, f"seed {seed}: flight", rel=True)
        checked += 1
    assert checked == N_STATES


def test_impact_matches_reference_and_its_kkt_conditions(ref, fast):
    checked = 0
    for seed in range(N_STATES):
        rng = np.random.default_rng(3000 + seed)
        x, v = free_state(rng)
        foot = int(rng.integers(0, 2))
        got = fast.impact(x, v, foot)
        want = ref.impact(x, v, foot)
        assert_close(got.v_plus, want.v_plus, TOL, f"seed {seed}: v+", rel=True)
        assert_close(got.impulse, want.impulse, TOL, f"seed {seed}: impulse", rel=True)
        assert_close(got.old_foot_velocity, want.old_foot_velocity, TOL, f"seed {seed}: old foot velocity", rel=True)
        assert_close(got.energy_loss, want.energy_loss, TOL, f"seed {seed}: energy loss", rel=True)
        # its own conditions, with the fast model's M and J: M (v+ - v-) = J^T Lambda, J v+ = 0, loss >= 0
        M = fast.mass_matrix(x)
        J = fast.contact_jacobian(x, foot)
        assert_close(M @ (got.v_plus - v), J.T @ got.impulse, 1e-9, f"seed {seed}: momentum jump", rel=True)
        assert_close(J @ got.v_plus, np.zeros(3), 1e-9 * max(1.0, float(np.max(np.abs(v)))), f"seed {seed}: J v+")
        assert got.energy_loss >= -1e-9
        v_kkt, lam_kkt = ref.impact_kkt(x, v, foot)
        assert_close(got.v_plus, v_kkt, 1e-9, f"seed {seed}: v+ vs direct KKT solve", rel=True)
        checked += 1
    assert checked == N_STATES


def test_energies_and_centre_of_mass(ref, fast):
    checked = 0
    for seed in range(N_STATES):
        x, v = free_state(np.random.default_rng(4000 + seed))
        ke = fast.kinetic_energy(x, v)
        assert_close(ke, ref.kinetic_energy(x, v), TOL, f"seed {seed}: kinetic energy", rel=True)
        # two code paths of the kernels: the sum over bodies and the quadratic form of M
        assert_close(ke, 0.5 * v @ fast.mass_matrix(x) @ v, TOL, f"seed {seed}: KE = v'Mv/2", rel=True)
        assert_close(fast.potential_energy(x), ref.potential_energy(x), TOL, f"seed {seed}: potential energy", rel=True)
        assert_close(fast.com(x), ref.com(x), TOL, f"seed {seed}: centre of mass", rel=True)
        checked += 1
    assert checked == N_STATES
    assert fast.mass == pytest.approx(ref.mass, rel=1e-15)


def test_state_from_paper_matches(ref, fast):
    for seed in range(N_STATES):
        rng = np.random.default_rng(5000 + seed)
        q, qd = rng.uniform(-0.6, 0.6, 6), rng.normal(0.0, 1.5, 6)
        stance, ax, pitch = int(rng.integers(0, 2)), float(rng.uniform(-1, 1)), float(rng.uniform(-0.05, 0.05))
        xf, vf = fast.state_from_paper(q, qd, stance, ax, pitch)
        xr, vr = ref.state_from_paper(q, qd, stance, ax, pitch)
        assert_close(xf, xr, TOL, f"seed {seed}: x from paper", rel=True)
        assert_close(vf, vr, TOL, f"seed {seed}: v from paper", rel=True)


# ------------------------------------------------------------------------------------------ integration
def test_projection_matches_reference(ref, fast):
    checked = 0
    for seed in range(N_STATES):
        rng = np.random.default_rng(6000 + seed)
        x, v, stance, anchor = contact_state(ref, rng)
        # off the manifold, as after an integration step
        x = x + rng.normal(0.0, 1e-3, 9)
        v = v + rng.normal(0.0, 1e-1, 9)
        xf, vf = fast.project(x, v, stance, anchor)
        xr, vr = ref_project(ref, x, v, stance, anchor)
        assert_close(xf, xr, TOL, f"seed {seed}: projected x", rel=True)
        assert_close(vf, vr, TOL, f"seed {seed}: projected v", rel=True)
        assert_close(fast.foot_pose(xf, stance), anchor, 1e-12, f"seed {seed}: foot on its anchor")
        checked += 1
    assert checked == N_STATES


def test_rk4_step_matches_reference(ref, fast, desc):
    checked = 0
    for seed in range(N_STATES):
        rng = np.random.default_rng(7000 + seed)
        x, v, stance, anchor = contact_state(ref, rng)
        tau_j = rng.normal(0.0, 40.0, 6)
        pushes = random_pushes(rng, desc.torso.length)
        h = float(rng.choice([1e-4, 2.5e-4, 5e-4, 1e-3]))
        xf, vf, wf = fast.rk4_step(x, v, tau_j, pushes, stance, anchor, h)
        xr, vr, wr = ref_rk4(ref, x, v, tau_j, pushes, stance, anchor, h)
        assert_close(xf, xr, TOL, f"seed {seed}: RK4 x", rel=True)
        assert_close(vf, vr, TOL, f"seed {seed}: RK4 v", rel=True)
        assert_close(wf, wr, TOL, f"seed {seed}: wrench at the step start", rel=True)
        checked += 1
    assert checked == N_STATES


def test_rk4_steps_batch_matches_reference(ref, fast, desc):
    sole = (desc.foot.l_min, desc.foot.l_max)
    checked = 0
    for seed in range(N_STATES):
        rng = np.random.default_rng(8000 + seed)
        x, v, stance, anchor = contact_state(ref, rng)
        tau_j = rng.normal(0.0, 40.0, 6)
        pushes = random_pushes(rng, desc.torso.length)
        h = 5e-4
        batch = fast.rk4_steps(x, v, tau_j, pushes, stance, anchor, h, 3)
        assert batch.completed == 3
        xr, vr = x, v
        for i in range(3):
            xn, vn, w = ref_rk4(ref, xr, vr, tau_j, pushes, stance, anchor, h)
            assert_close(batch.wrench[i], w, TOL, f"seed {seed} step {i}: wrench", rel=True)
            assert_close(batch.X[i], xn, TOL, f"seed {seed} step {i}: x", rel=True)
            assert_close(batch.V[i], vn, TOL, f"seed {seed} step {i}: v", rel=True)
            assert_close(batch.probe[i], ref_probe(ref, xn, vn, 1 - stance, sole), TOL,
                         f"seed {seed} step {i}: swing probe", rel=True)
            xr, vr = xn, vn
        checked += 1
    assert checked == N_STATES


def test_energy_balance_of_integrated_motion(fast, desc):
    """Independent of Pinocchio: the stance foot is held (its reaction does no work), so over any motion
    E(t) - E(0) = tau_j . (q_j(t) - q_j(0)) + sum_i F_i (x_i(t) - x_i(0)) exactly for constant joint
    torques and constant horizontal forces F_i at torso points x_i; RK4 at h = 1e-4 s leaves a tiny
    residual (about 2e-12 of the energy scale here). Checked over 50 ms from 50 states."""
    checked = 0
    for seed in range(50):
        rng = np.random.default_rng(9000 + seed)
        x, v, stance, anchor = contact_state(fast, rng)
        tau_j = rng.normal(0.0, 20.0, 6)
        pushes = random_pushes(rng, desc.torso.length)
        forces, heights = push_arrays(pushes)

        def energy(xx, vv):
            return fast.kinetic_energy(xx, vv) + fast.potential_energy(xx)

        def push_points(xx):  # x of the torso points: hip + height * (-sin, cos)(torso pitch)
            return xx[0] - heights * np.sin(xx[2])

        batch = fast.rk4_steps(x, v, tau_j, pushes, stance, anchor, 1e-4, 500)
        assert batch.completed == 500
        x1, v1 = batch.X[-1], batch.V[-1]
        work = float(tau_j @ (x1[3:] - x[3:]) + forces @ (push_points(x1) - push_points(x)))
        change = energy(x1, v1) - energy(x, v)
        scale = max(1.0, abs(work), fast.kinetic_energy(x, v))
        assert abs(change - work) <= 1e-9 * scale, f"seed {seed}: dE = {change:.9f} J, work = {work:.9f} J"
        # and the motion did something: the check is not vacuous
        assert abs(work) + abs(change) > 1e-3
        checked += 1
    assert checked == 50


def test_singular_state_raises(fast):
    x = np.full(9, np.nan)
    with pytest.raises(SimulationError):
        fast.contact_dynamics(x, np.zeros(9), np.zeros(9), LEFT)
    with pytest.raises(SimulationError):
        fast.rk4_step(x, np.zeros(9), np.zeros(6), (), LEFT, np.zeros(3), 1e-3)
    batch = fast.rk4_steps(x, np.zeros(9), np.zeros(6), (), LEFT, np.zeros(3), 1e-3, 2)
    assert batch.completed == 0


def test_kernels_reject_wrong_dtypes(fast):
    """Explicit signatures: a float32 state is refused instead of silently compiling a slow variant."""
    M = np.empty((9, 9))
    h = np.empty(9)
    with pytest.raises(TypeError):
        fast.pk.mass_bias(fast.ti, fast.tf, np.zeros(9, dtype=np.float32), np.zeros(9), M, h)


# ------------------------------------------------------------------------------------------ controller side
def test_controller_terms_match_fixed_foot_model(ref_ctrl, fast_ctrl, desc):
    checked = 0
    for seed in range(N_STATES):
        rng = np.random.default_rng(10000 + seed)
        q, qd = rng.uniform(-1.0, 1.0, 6), rng.normal(0.0, 2.0, 6)
        height = float(rng.uniform(0.0, desc.torso.length))
        A, H, B, hb, jp = fast_ctrl.terms(q, qd, height)
        d = ref_ctrl.dynamics(q, qd)
        assert_close(A, d.A, TOL, f"seed {seed}: A", rel=True)
        assert_close(H, d.H, TOL, f"seed {seed}: H", rel=True)
        assert_close(B, d.B, TOL, f"seed {seed}: B", rel=True)
        assert_close(hb, d.h_b, TOL, f"seed {seed}: h_b", rel=True)
        assert_close(jp, ref_ctrl.torso_point_jacobian(q, height)[0], TOL, f"seed {seed}: torso x row", rel=True)
        outs = tuple(np.full_like(a, np.nan) for a in (A, H, B, hb, jp))
        fast_ctrl.terms_into(q, qd, height, *outs)
        for got, want, name in zip(outs, (A, H, B, hb, jp), ("A", "H", "B", "h_b", "jp")):
            assert_close(got, want, 0.0, f"seed {seed}: terms_into {name}")
        assert_close(fast_ctrl.com(q), ref_ctrl.com(q), TOL, f"seed {seed}: com", rel=True)
        assert_close(fast_ctrl.kinetic_energy(q, qd), ref_ctrl.kinetic_energy(q, qd), TOL, f"seed {seed}: KE", rel=True)
        assert_close(fast_ctrl.potential_energy(q), ref_ctrl.potential_energy(q), TOL, f"seed {seed}: PE", rel=True)
        checked += 1
    assert checked == N_STATES


# ------------------------------------------------------------------------------------------ generic trees
def other_robot(desc):
    """A different robot: other lengths, masses, inertias, a foot centre of mass ahead of the ankle and
    another gravity (the validation of parse_description is bypassed on purpose for com_forward)."""
    return replace(
        desc, gravity=9.5,
        torso=replace(desc.torso, length=0.7, mass=23.0, com=0.25, inertia=0.9),
        thigh=replace(desc.thigh, length=0.43, mass=7.0, com=0.17, inertia=0.1),
        shin=replace(desc.shin, length=0.38, mass=3.5, com=0.15, inertia=0.04),
        foot=replace(desc.foot, mass=0.8, inertia=0.003, com_forward=0.03),
    )


def test_kernels_follow_the_description(desc):
    """Nothing is typed in the kernels: another description gives the other robot's dynamics."""
    d2 = other_robot(desc)
    ref2, fast2 = FloatingModel(d2), FastFloatingModel(d2)
    ctrl2, fctrl2 = FixedFootModel(d2), FastFixedFootModel(d2)
    for seed in range(N_STATES):
        rng = np.random.default_rng(11000 + seed)
        x, v = free_state(rng)
        M, h = fast2.mass_bias(x, v)
        assert_close(M, ref2.mass_matrix(x), TOL, f"seed {seed}: other robot M", rel=True)
        assert_close(h, pin.nonLinearEffects(ref2.model, ref2.data, x, v), TOL, f"seed {seed}: other robot h", rel=True)
        tau = rng.normal(0.0, 30.0, 9)
        assert_close(fast2.contact_dynamics(x, v, tau, RIGHT).wrench, ref2.contact_dynamics(x, v, tau, RIGHT).wrench,
                     TOL, f"seed {seed}: other robot wrench", rel=True)
        q, qd = rng.uniform(-1.0, 1.0, 6), rng.normal(0.0, 2.0, 6)
        A, H, B, hb, _ = fctrl2.terms(q, qd, 0.2)
        dd = ctrl2.dynamics(q, qd)
        assert_close(np.concatenate([A.ravel(), H, B.ravel(), hb]),
                     np.concatenate([dd.A.ravel(), dd.H, dd.B.ravel(), dd.h_b]), TOL, f"seed {seed}: other ctrl", rel=True)
    # and it differs from the configured robot, so the comparison above is not vacuous
    x, v = free_state(np.random.default_rng(0))
    assert np.max(np.abs(fast2.mass_matrix(x) - FastFloatingModel(desc).mass_matrix(x))) > 1e-2


def test_negative_control_perturbed_inertia_is_detected(desc, ref, ref_ctrl):
    """A torso inertia wrong by one part in a million must fail the comparisons used above."""
    bad = replace(desc, torso=replace(desc.torso, inertia=desc.torso.inertia * (1 + 1e-6)))
    fast_bad, ctrl_bad = FastFloatingModel(bad), FastFixedFootModel(bad)
    x, v = free_state(np.random.default_rng(1))
    with pytest.raises(AssertionError, match="M"):
        assert_close(fast_bad.mass_matrix(x), ref.mass_matrix(x), TOL, "M", rel=True)
    tau = np.random.default_rng(2).normal(0.0, 30.0, 9)
    with pytest.raises(AssertionError, match="wrench"):
        assert_close(fast_bad.contact_dynamics(x, v, tau, LEFT).wrench, ref.contact_dynamics(x, v, tau, LEFT).wrench,
                     TOL, "wrench", rel=True)
    q, qd = np.random.default_rng(3).uniform(-1, 1, 6), np.zeros(6)
    with pytest.raises(AssertionError, match="A"):
        assert_close(ctrl_bad.terms(q, qd)[0], ref_ctrl.dynamics(q, qd).A, TOL, "A", rel=True)


def test_negative_control_wrong_torque_changes_the_step(ref, fast):
    """The RK4 comparison is sensitive to the torque: 1e-6 N m on one joint is visible at 1e-10."""
    rng = np.random.default_rng(12)
    x, v, stance, anchor = contact_state(ref, rng)
    tau_j = rng.normal(0.0, 40.0, 6)
    xr, vr, _ = ref_rk4(ref, x, v, tau_j, (), stance, anchor, 1e-3)
    _, vf, _ = fast.rk4_step(x, v, tau_j + np.array([0, 0, 0, 1e-6, 0, 0]), (), stance, anchor, 1e-3)
    with pytest.raises(AssertionError):
        assert_close(vf, vr, TOL, "v", rel=True)


def test_tree_validation_names_the_problem(desc):
    tree = floating_tree(desc)
    with pytest.raises(TreeError, match="parent"):
        replace(tree, joints=tree.joints[:4] + (Joint("bad", 7, REV),) + tree.joints[5:]).validate()
    with pytest.raises(TreeError, match="mass"):
        replace(tree, bodies=(Body("b", 2, -1.0, (0.0, 0.0), 0.1),) + tree.bodies[1:]).validate()
    with pytest.raises(TreeError, match="floating root"):
        replace(tree, joints=(Joint("x", -1, PX, (0.1, 0.0)),) + tree.joints[1:]).validate()
    with pytest.raises(TreeError, match="feet"):
        replace(tree, feet=(5, 42)).validate()
    assert isinstance(fixed_foot_tree(desc), PlanarTree)
    ti, tf = tree.arrays()
    assert ti.dtype == np.int64 and tf.dtype == np.float64 and ti[0] == 9 and ti[1] == 7


# ------------------------------------------------------------------------------------------ compile notice
def test_compile_notice_only_without_a_matching_stamp(tmp_path):
    stamp = tmp_path / "cache" / "planar_kernels.stamp"
    nc = numba_cache
    key = nc.cache_key(nc.source_of("biped_model.planar_kernels"))
    out = io.StringIO()
    assert nc.announce_compile(stamp, key, out) is True
    assert out.getvalue().strip() == nc.COMPILE_NOTICE
    nc.write_stamp(stamp, key)
    out = io.StringIO()
    assert nc.announce_compile(stamp, key, out) is False
    assert out.getvalue() == ""
    nc.write_stamp(stamp, "an older key")
    assert nc.announce_compile(stamp, key, io.StringIO()) is True
    import numba
    assert nc.configure() == nc.cache_dir() and numba.config.CACHE_DIR == str(nc.cache_dir())


def test_stale_cache_of_a_dependent_module_is_dropped(tmp_path):
    """A module compiled against another module's kernels: its cache files go when a dependency's source
    changes (numba itself only watches the module's own source), and stay otherwise."""
    from biped_model.numba_cache import drop_stale_cache
    dep = tmp_path / "dep.py"
    dep.write_text("x = 1\n")
    cache = tmp_path / "cache" / "pkg_hash"
    cache.mkdir(parents=True)
    files = [cache / "mymod.run-12.py311.nbi", cache / "mymod.run-12.py311.1.nbc"]
    other = cache / "othermod.run-3.py311.nbi"

    def fill():
        for f in files + [other]:
            f.write_bytes(b"compiled")

    fill()
    assert drop_stale_cache("mymod", [dep], str(tmp_path / "cache")) is True     # first sight: no stamp
    assert not any(f.exists() for f in files) and other.exists()
    fill()
    assert drop_stale_cache("mymod", [dep], str(tmp_path / "cache")) is False    # unchanged: kept
    assert all(f.exists() for f in files)
    dep.write_text("x = 2\n")
    assert drop_stale_cache("mymod", [dep], str(tmp_path / "cache")) is True     # dependency changed
    assert not any(f.exists() for f in files) and other.exists()
