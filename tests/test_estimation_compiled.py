"""The compiled sensing pipeline: ``pipeline_kernels`` against the Python cores and Pinocchio.

Oracles: Pinocchio's A(q), B, g(q) - C(q, q')^T q' (``momentum_observer.MomentumTerms``) and torso Jacobian
for the observer's model terms; the Python pipeline (``pipeline.SensingPipeline``: ``JointStateEstimator``,
``MomentumObserver``, Pinocchio) fed the same seeded noisy run, period by period (estimate, covariance,
wrench, its covariance, the QP rows' widening); the controller on the reference engine with the Python
pipeline and Python steps, fed the same observations (torque and status of every period). A negative
control for each.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from biped_model.description import load_description
from biped_model.fast_engine import FastFixedFootModel
from biped_model.fixed_foot import contact_rows
from biped_sim.plant.perturbation import PlantPerturbation

from biped_controller.core.sensing import momentum_observer as mom
from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.sensing.pipeline_compiled import CompiledSensing, load_pipeline_kernels
from biped_controller.core.sensing.pipeline_layout import SENS
from biped_controller.core.control.controller_layout import G_

from estimation_loop import closed_loop

DESC = load_description()
NOISE = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, noise_pitch=1e-3, seed=3)
# the real-sensor profile of docs/robustness.md: estimator and momentum observer (K = 50)
REAL = dict(state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14, sensor_noise_qd=5e-2,
            sensor_noise_pitch=1e-3, momentum_observer=True, momentum_observer_gain=50.0)
T_RUN = 0.6          # [s] past the first touchdown (0.463 s): the impact map and a restart of the observer


def _rel(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.abs(a - b).max() / max(1.0, np.abs(b).max()))


# ------------------------------------------------------------------------------ the observer's model terms
def test_momentum_terms_against_pinocchio():
    """A, B, H, beta = g - C^T q' (g and the kinetic energy's gradient in closed form) and the torso wrench Jacobian
    against Pinocchio at seeded random states; negative control: g - C q' (Coriolis matrix not transposed)
    is a different vector at the same states."""
    ek = load_pipeline_kernels()
    fast = FastFixedFootModel(DESC)
    terms = mom.MomentumTerms(DESC)
    rng = np.random.default_rng(7)
    h = 0.2
    worst, gap = 0.0, 0.0
    for _ in range(20):
        q = rng.uniform(-0.8, 0.8, 6)
        qd = rng.uniform(-3.0, 3.0, 6)
        A, B, beta, J, H = np.empty((6, 6)), np.empty((3, 6)), np.empty(6), np.empty((3, 9)), np.empty(6)
        ek.momentum_terms(fast.ti, fast.tf, q, qd, h, A, B, beta, J, H)
        A_ref, beta_ref = terms.mass_beta(q, qd)
        J_ref = terms.wrench_jacobian(q, h)
        dyn = terms.ffm.dynamics(q, qd)
        worst = max(worst, _rel(A, A_ref), _rel(beta, beta_ref), _rel(J, J_ref), _rel(B, dyn.B), _rel(H, dyn.H))
        qf, vf = np.zeros(9), np.zeros(9)
        qf[3:], vf[3:] = q, qd
        C = pin.computeCoriolisMatrix(terms.model, terms.data, qf, vf)
        g = pin.computeGeneralizedGravity(terms.model, terms.data, qf)
        gap = max(gap, _rel(beta, g[3:] - C[3:, 3:] @ qd))
    assert worst < 1e-11
    assert gap > 1e-2


# ------------------------------------------------------------------------------ the pipeline, period by period
@pytest.fixture(scope="module")
def python_run():
    """The seeded noisy run (noise 5e-4 rad, 5e-2 rad/s, 14 bits, IMU 1e-3 rad) on the Python cores and the
    reference engine, one touchdown included."""
    tr = closed_loop(T_RUN, NOISE, python_sensing=True, engine="reference", **REAL)
    assert tr.fall is None and tr.records[-1].impacts >= 1
    return tr


def _replay(tr, cfg) -> tuple[float, float, float]:
    """CompiledSensing fed the run's observations and torques; returns the largest relative differences
    from the Python pipeline's (estimate, covariance; wrench W; dR, cov_dR)."""
    fast = FastFixedFootModel(DESC)
    m = tr.ctrl.model
    C, _ = contact_rows(cfg.margin_friction * m.mu, m.l_min + cfg.margin_zmp, m.l_max - cfg.margin_zmp)
    cs = CompiledSensing(cfg, DESC, fast.ti, fast.tf, C, m.torque_min, m.torque_max)
    ex = ew = er = 0.0
    res = np.empty(8)
    for (t, q, qd, st, pitch, rate), sent, est, w in zip(tr.obs, tr.sent, tr.est, tr.wrench):
        qc, qdc, _ = cs.sense(t, q, qd, st, pitch, rate)
        ex = max(ex, _rel(qc, est[0]), _rel(qdc, est[1]), _rel(cs.P, est[2]))
        wc = cs.wrench
        ew = max(ew, _rel(wc.W, w.W), _rel(wc.r, w.r), _rel(wc.cov_W, w.cov_W))
        cs.into_res(res)
        extra = cfg.estimate_confidence * np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", C, w.cov_dR, C), 0.0))
        er = max(er, _rel(wc.dR, w.dR), _rel(wc.cov_dR, w.cov_dR), _rel(res[:2], w.dR), _rel(res[2], w.W[0]),
                 _rel(res[3:], extra))
        cs.record(t, sent, st)
    return ex, ew, er


def test_compiled_pipeline_equals_the_python_cores(python_run):
    """Every period of the noisy run (one touchdown): estimate and covariance, the observer's r, W and
    cov_W, dR, cov_dR and the rows' widening to round-off (relative 1e-9)."""
    cfg = load_controller_config(mode="both", **REAL)
    ex, ew, er = _replay(python_run, cfg)
    assert max(ex, ew, er) < 1e-9, (ex, ew, er)


def test_compiled_pipeline_negative_control(python_run):
    """The same replay with the process noise 1 % larger, or the observer's gain 1 % larger, misses the
    tolerance (the comparison sees each part)."""
    ex, _, _ = _replay(python_run, load_controller_config(mode="both", **{**REAL, "estimator_accel_std": 5.05}))
    assert ex > 1e-6
    _, ew, _ = _replay(python_run, load_controller_config(mode="both", **{**REAL, "momentum_observer_gain": 50.5}))
    assert ew > 1e-6


# ------------------------------------------------------------------------------ the whole controller step
def _drive(tr, ctrl) -> tuple[float, float, int]:
    """The controller fed the run's observations: the largest torque difference [N m] and force estimate
    difference [N] from the run's controller, and the number of periods whose QP status differs."""
    ctrl.reset(tr.obs[0][3])
    dtq = dF = 0.0
    nst = 0
    for (t, q, qd, st, pitch, rate), sent, s_ref in zip(tr.obs, tr.sent, tr.statuses):
        out = ctrl.compute(t, q, qd, st, pitch, rate)
        dtq = max(dtq, float(np.abs(out.torque - sent).max()))
        dF = max(dF, abs(out.status.force_estimate - s_ref.force_estimate))
        nst += out.status.qp_status != s_ref.qp_status
    return dtq, dF, nst


def test_compiled_step_with_estimation_equals_the_reference(python_run):
    """The controller's compiled step with estimation (fast engine: compiled pipeline, compiled period, the
    QP when x* is infeasible) against the reference engine's Python pipeline and Python steps, on the
    same observations: torques within 1e-6 N m, force estimates within 1e-6 N, the same QP status in
    every period. Negative control: the compiled step without the estimate in the QP rows (GAINS.momentum
    0, the acceleration-residual observer instead) differs."""
    cfg = load_controller_config(mode="both", engine="fast", **REAL)
    ctrl = AdaptiveController(cfg, desc=DESC)
    assert ctrl.compiled_period is not None and isinstance(ctrl._sensing, CompiledSensing)
    dtq, dF, nst = _drive(python_run, ctrl)
    assert dtq < 1e-6 and dF < 1e-6 and nst == 0, (dtq, dF, nst)
    bad = AdaptiveController(cfg, desc=DESC)
    bad.gains[G_.momentum] = 0.0
    dtq_b, dF_b, _ = _drive(python_run, bad)
    assert dF_b > 1.0


def test_state_layout_fields():
    """The state array holds the estimate at offset 0 (the tests' trace reads it there)."""
    assert SENS.at.x == 0 and SENS.sizes["x"] == 12


# ------------------------------------------------------------------------------ the predictor
def test_predictor_pieces_against_python():
    """The swing sole's lowest height and the flat-foot impact map (on the fixed-foot tree, root at the
    stance ankle) against ``DelayPredictor.lowest_sole`` and ``predictor.flat_foot_impact`` (Pinocchio's
    floating model, root at the torso) at seeded random states, to round-off; negative control: the
    relabelling without laying the landing foot flat differs."""
    from biped_model.floating import FloatingModel
    from biped_model.fixed_foot import relabel
    from biped_controller.core.sensing.predictor import DelayPredictor, flat_foot_impact
    ek = load_pipeline_kernels()
    fast = FastFixedFootModel(DESC)
    fm = FloatingModel(DESC)
    dp = DelayPredictor(DESC, 2, 2, 1e-3, 1e-8, 1e-4, 1e-9)
    rng = np.random.default_rng(11)
    worst, gap = 0.0, 0.0
    qo, qdo = np.empty(6), np.empty(6)
    for _ in range(10):
        q = np.array([0.15, 0.3, -0.4, -0.2, 0.6, -0.3]) + rng.uniform(-0.1, 0.1, 6)
        qd = rng.uniform(-1.0, 1.0, 6)
        worst = max(worst, abs(ek.lowest_sole(fast.ti, fast.tf, q) - dp.lowest_sole(q)))
        assert ek.flat_foot_impact(fast.ti, fast.tf, q, qd, qo, qdo)
        qn, qdn = flat_foot_impact(fm, q, qd, 0)
        worst = max(worst, _rel(qo, qn), _rel(qdo, qdn))
        gap = max(gap, _rel(qo, relabel(q)))
    assert worst < 1e-10, worst
    assert gap > 1e-3


@pytest.fixture(scope="module")
def delayed_run():
    """A delay of 2 periods (touchdown delayed too) with the momentum observer and the predictor, on the Python
    cores and the reference engine, one touchdown (predicted 2 periods before it is sensed) included."""
    tr = closed_loop(T_RUN, PlantPerturbation(delay=2), python_sensing=True, engine="reference",
                     momentum_observer=True, delay_compensation=2)
    assert tr.fall is None and tr.records[-1].impacts >= 1
    assert any(s.stance != o[3] for s, o in zip(tr.statuses, tr.obs))     # acted in a predicted stance
    return tr


def test_compiled_step_with_the_predictor_equals_the_reference(delayed_run):
    """The compiled step with the compiled predictor against the Python pipeline and steps on the same
    delayed observations: torques within 1e-6 N m (the stance acted in included: a wrong predicted touchdown
    would relabel the torque); negative control: the compiled step predicting 1 period for the 2 differs."""
    cfg = load_controller_config(mode="both", engine="fast", momentum_observer=True, delay_compensation=2)
    ctrl = AdaptiveController(cfg, desc=DESC)
    assert ctrl.compiled_period is not None and isinstance(ctrl._sensing, CompiledSensing)
    dtq, dF, nst = _drive(delayed_run, ctrl)
    assert dtq < 1e-6 and dF < 1e-6 and nst == 0, (dtq, dF, nst)
    wrong = AdaptiveController(load_controller_config(mode="both", engine="fast", momentum_observer=True,
                                                      delay_compensation=1), desc=DESC)
    assert _drive(delayed_run, wrong)[0] > 1.0


# ------------------------------------------------------------------------------ the MuJoCo plant's IMU
def test_imu_pitch_in_the_mujoco_plant():
    """MuJoCo's encoders measure q1 against the ground (ankle encoder + the stance foot's pitch), so its
    IMU's torso pitch is q1 + q2 + q3 even while the foot tips (half a step of walking with the compiled
    step and the real-sensor profile); negative control: with the ankle encoder alone as q1 the sum misses
    the pitch by the foot's tilt."""
    from biped_model.description import LEFT
    from biped_model.gait_family import GaitFamily
    from biped_model.floating import paper_from_urdf
    from biped_sim.plant.config import load_sim_config
    from biped_sim.plant.protocol import make_plant
    fam = GaitFamily.load()
    sim = make_plant("mujoco", DESC, load_sim_config(plant="mujoco"))
    ctrl = AdaptiveController(load_controller_config(mode="both", engine="fast", **REAL), fam, DESC)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    worst, tilt = 0.0, 0.0
    while sim.t < 0.25 and sim.fall is None:
        obs = sim.observe()
        worst = max(worst, abs(obs.pitch - float(np.sum(obs.q[:3]))))
        ankle = paper_from_urdf(sim.x[3:], sim.stance)[0]
        tilt = max(tilt, abs(obs.pitch - (ankle + obs.q[1] + obs.q[2])))
        sim.step(ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch).torque)
    assert sim.fall is None
    assert worst < 1e-12, worst
    assert tilt > 1e-3, tilt          # measured 7.1e-3 rad


# ------------------------------------------------------------------------------ the IMU gyro
# the same noisy run with the gyro on the plant (5e-3 rad/s, its own generator) and fused by the estimator
GYRO_NOISE = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, noise_pitch=1e-3, noise_pitch_rate=5e-3,
                               seed=3)
GYRO = {**REAL, "estimator_gyro": True, "sensor_noise_pitch_rate": 5e-3}


@pytest.fixture(scope="module")
def python_gyro_run():
    """The seeded noisy run with the gyro fused, on the Python cores and the reference engine (one touchdown)."""
    tr = closed_loop(T_RUN, GYRO_NOISE, python_sensing=True, engine="reference", **GYRO)
    assert tr.fall is None and tr.records[-1].impacts >= 1
    assert all(np.isfinite(o[5]) for o in tr.obs)                # the gyro's rate reached the controller
    return tr


def test_compiled_gyro_fusion_equals_the_python_cores(python_gyro_run):
    """The compiled estimator's scalar update of the gyro row (h = [0 | 1 1 1 0 0 0]) against the Python core's
    batch Kalman update, every period of the run: estimate and covariance to 1e-9 (relative). Negative controls:
    the replay without the gyro (estimator_gyro off), or with its variance 2 % larger, misses it."""
    ex, ew, er = _replay(python_gyro_run, load_controller_config(mode="both", **GYRO))
    assert max(ex, ew, er) < 1e-9, (ex, ew, er)
    off, _, _ = _replay(python_gyro_run, load_controller_config(mode="both", **{**GYRO, "estimator_gyro": False}))
    assert off > 1e-6
    wide, _, _ = _replay(python_gyro_run, load_controller_config(mode="both",
                                                                   **{**GYRO, "sensor_noise_pitch_rate": 5.05e-3}))
    assert wide > 1e-6
