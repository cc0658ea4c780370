"""Real sensing: the joint state estimator, the momentum observer, the delay predictor, the sensor
model's encoder quantisation and IMU, and the command lines.

Oracles: the true state of the simulator (the estimator against it, its errors normalised by its own
covariance); the disturbance computed from the plant's own model, tau_d = A_nom q''_true + H_nom - Gamma
with q''_true = A_plant^-1 (Gamma - H_plant), and a push's J^T F (the momentum observer against them,
within the first-order lag bound max|tau_d'| (1/K + dt) that r' = K (tau_d - r) allows); the undelayed
run (the delayed run with the predictor equals it to 1e-9). A negative control for each.
"""
from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from biped_model.description import load_description
from biped_model.fixed_foot import FixedFootModel
from biped_sim.plant.perturbation import PerturbationError, PlantPerturbation, SensorModel

from biped_controller.core.sensing import momentum_observer as mom
from biped_controller.core.control.config import ControllerConfigError, load_controller_config
from biped_controller.core.sensing.estimation import EstimatorConfig, EstimatorConfigError, JointStateEstimator

from estimation_loop import closed_loop

ROOT = Path(__file__).resolve().parents[1]
DESC = load_description()
NOISE = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, noise_pitch=1e-3, seed=3)
REAL = dict(state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14, sensor_noise_qd=5e-2,
            sensor_noise_pitch=1e-3, disturbance_observer=False)
K = 200.0


# ------------------------------------------------------------------------------ sensor model
def test_encoder_quantisation_and_imu():
    q = np.array([0.1, -0.2, 0.3, 0.01, -0.02, 0.0301])
    qd = np.linspace(-1, 1, 6)
    p = PlantPerturbation(encoder_bits=14)
    step = 2 * math.pi / 2 ** 14
    assert p.encoder_step == pytest.approx(3.835e-4, rel=1e-3)
    s = SensorModel(p)
    _, qs, qds = s.sample(0, 0, q, qd, pitch=0.25)
    k = qs / step
    assert np.allclose(k, np.round(k), atol=1e-9) and np.all(np.abs(qs - q) <= step / 2 + 1e-15)
    assert np.array_equal(qds, qd)                       # the rates are the rate sensor's
    assert s.pitch_reading(0) == 0.25                    # no IMU noise: the true pitch
    # negative control: without quantisation the readings are not on the grid
    _, q0, _ = SensorModel(PlantPerturbation(noise_q=1e-9)).sample(0, 0, q, qd)
    assert not np.allclose(q0 / step, np.round(q0 / step), atol=1e-6)


def test_imu_noise_does_not_change_the_joint_noise_sequence():
    q, qd = np.zeros(6), np.zeros(6)
    a = SensorModel(PlantPerturbation(noise_q=1e-3, noise_qd=1e-2, seed=5))
    b = SensorModel(PlantPerturbation(noise_q=1e-3, noise_qd=1e-2, noise_pitch=1e-2, seed=5))
    for k in range(20):
        sa, sb = a.sample(k, 0, q, qd), b.sample(k, 0, q, qd)
        assert np.array_equal(sa[1], sb[1]) and np.array_equal(sa[2], sb[2])
    pitch = np.array([b.sample(k, 0, q, qd) and b.pitch_reading(k) for k in range(20, 2020)])
    assert abs(pitch.std() - 1e-2) < 1e-3 and abs(pitch.mean()) < 1e-3       # 2000 draws
    with pytest.raises(PerturbationError, match="encoder_bits"):
        PlantPerturbation(encoder_bits=-1)
    with pytest.raises(PerturbationError, match="noise_pitch"):
        PlantPerturbation(noise_pitch=-1e-3)


def test_imu_pitch_is_the_torso_pitch_in_the_rigid_plant():
    """The simulator's IMU reads the floating base's pitch; with the stance foot flat it is q1 + q2 + q3."""
    tr = closed_loop(0.05, PlantPerturbation(encoder_bits=30))      # sensing on, negligible quantisation
    from biped_sim.plant.rigid import Simulator
    sim = Simulator(DESC)
    for rec in tr.records[::10]:
        sim.x, sim.v, sim.stance = rec.x, rec.v, rec.stance
        assert sim.observe().pitch == pytest.approx(float(np.sum(rec.q[:3])), abs=1e-12)


# ------------------------------------------------------------------------------ estimator
def _normalised_errors(tr):
    e = []
    for est, q, qd, st, told in zip(tr.est, tr.q, tr.qd, tr.stance, tr.told):
        if est is None or st != told:
            continue
        xq, xqd, P = est
        e.append(np.r_[xq - q, xqd - qd] / np.sqrt(np.diag(P)))
    return np.array(e)


def test_estimator_against_the_true_state_under_seeded_noise():
    """A noisy walk through a touchdown: the estimate's errors, divided by the standard deviations of the
    filter's own covariance, are of unit size (rms in [0.4, 1.5] per state, 99 % within 3 sigma), and the
    rate error is well below the rate sensor's noise (the raw sample's error)."""
    tr = closed_loop(0.6, NOISE, **REAL)
    assert tr.fall is None and any(s != tr.stance[0] for s in tr.stance)   # a touchdown is in the run
    z = _normalised_errors(tr)
    rms = np.sqrt((z ** 2).mean(axis=0))
    assert np.all(rms > 0.4) and np.all(rms < 1.5), rms
    assert (np.abs(z) < 3).mean() > 0.99
    err_qd = np.array([est[1] - qd for est, qd in zip(tr.est, tr.qd) if est is not None])
    assert np.sqrt((err_qd ** 2).mean()) < 0.5 * NOISE.noise_qd


def test_estimator_negative_control_overconfident_filter():
    """The same check fails for a filter told its encoders are 100 x better than they are."""
    tr = closed_loop(0.2, NOISE, **{**REAL, "sensor_noise_q": 5e-6, "sensor_encoder_bits": 0})
    z = _normalised_errors(tr)
    rms = np.sqrt((z ** 2).mean(axis=0))
    assert not (np.all(rms < 1.5) and (np.abs(z) < 3).mean() > 0.99)


def test_estimator_steady_state_against_the_closed_form():
    """Position-only filter, one joint at rest: the steady-state gain of the discrete filter with
    piecewise-constant white acceleration is the alpha-beta tracker's; its position variance solves the
    Riccati equation. Check the converged P against an independent iteration of the scalar Riccati
    recursion on the 2x2 block."""
    cfg = EstimatorConfig(sigma_q=1e-3, encoder_bits=0, sigma_qd=math.inf, sigma_pitch=math.inf,
                          sigma_acc=10.0, sigma_impact=0.0)
    est = JointStateEstimator(cfg)
    est.reset(np.zeros(6))
    dt = 1e-3
    for _ in range(3000):
        est.predict(dt, np.zeros(6))
        est.update(np.zeros(6))
    F = np.array([[1, dt], [0, 1]])
    Q = 100.0 * np.array([[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]])
    P = np.diag([1e-6, 1e2])
    Hm = np.array([[1.0, 0.0]])
    for _ in range(3000):
        P = F @ P @ F.T + Q
        S = Hm @ P @ Hm.T + 1e-6
        Kg = P @ Hm.T / S
        P = (np.eye(2) - Kg @ Hm) @ P
    blk = est.P[np.ix_([0, 6], [0, 6])]
    assert np.allclose(blk, P, rtol=1e-6)
    assert cfg.bandwidth == pytest.approx(100.0, rel=1e-12)          # (10 / 1e-3)^(1/2)
    with pytest.raises(EstimatorConfigError, match="sigma_acc"):
        EstimatorConfig(1e-3, 0, 1.0, 1.0, 0.0, 0.0).validate()


# ------------------------------------------------------------------------------ momentum observer
def _lag_bound(tau: np.ndarray, t: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """max |tau_d'| (1/K + dt) per joint over the masked periods: the first-order tracking bound."""
    slope = np.abs(np.diff(tau, axis=0) / np.diff(t)[:, None])
    return slope[mask[:-1]].max(axis=0) * (1.0 / K + 1e-3) + 1e-9


def test_momentum_observer_recovers_a_constant_push():
    F, t0, dur = 60.0, 0.10, 0.20
    tr = closed_loop(0.32, pushes=[(t0, dur, F)], momentum_observer=True, momentum_observer_gain=K)
    assert tr.fall is None
    terms = mom.MomentumTerms(DESC)
    t = np.array(tr.t)
    on = (t >= t0) & (t < t0 + dur)
    tau = np.array([terms.wrench_jacobian(q, 0.3125)[:, 3:].T @ np.array([F * o, 0.0, 0.0])
                    for q, o in zip(tr.q, on)])
    r = np.array(tr.r)
    m = (t > t0 + 10.0 / K) & (t < t0 + dur)               # settled, inside the push
    inside = m & np.r_[m[1:], False]
    # the discrete observer's own floor (trapezoid on beta over a period): twice its |r| before the push
    floor = 2.0 * np.abs(r[(t > 10.0 / K) & (t < t0)]).max(axis=0)
    bound = _lag_bound(tau, t, inside) + floor
    # the stance leg carries the push (J^T F); the swing leg's rows of J^T are zero, there r is the
    # discrete observer's integration error only: a few 1e-4 N m against the push's 66 N m
    assert np.all(np.abs(r[m][:, :3] - tau[m][:, :3]) <= bound[:3]), (np.abs(r[m] - tau[m]).max(axis=0), bound)
    assert np.abs(r[m][:, 3:]).max() < 1e-3 * np.abs(tau[m]).max()
    W = np.array(tr.W)[m]
    assert np.all(np.abs(W[:, 0] - F) < 0.01 * F)           # the horizontal force
    assert np.all(np.abs(W[:, 1]) < 0.05 * F) and np.all(np.abs(W[:, 2]) < 0.5)
    before = t < t0
    assert np.abs(np.array(tr.W)[before]).max() < 0.1       # no push, exact model: no force
    # negative control: the same estimate is not the push of another magnitude
    assert not np.all(np.abs(W[:, 0] - 1.1 * F) < 0.01 * F)


def _mass_error_run(K_gain=K):
    P = PlantPerturbation(torso_mass_scale=0.8)
    tr = closed_loop(0.40, P, momentum_observer=True, momentum_observer_gain=K_gain)
    nom, plant = FixedFootModel(DESC), FixedFootModel(P.apply(DESC))
    taud = []
    for q, qd, g in zip(tr.q, tr.qd, tr.torque):
        dn, dp = nom.dynamics(q, qd), plant.dynamics(q, qd)
        a = np.linalg.solve(dp.A, g - dp.H)                   # the plant's true joint acceleration
        taud.append(dn.A @ a + dn.H - g)                      # what the nominal model misses
    taud, r, t = np.array(taud), np.array(tr.r), np.array(tr.t)
    m = t[1:] > 10.0 / K
    err = np.abs(r[1:] - taud[:-1])[m]                        # r_k saw the torque of period k - 1
    bound = _lag_bound(taud, t, np.ones(len(t), bool))
    return tr, err, bound, taud


def test_momentum_observer_recovers_a_mass_error():
    tr, err, bound, taud = _mass_error_run()
    assert tr.fall is None
    assert np.abs(taud[:, :3]).max() > 5.0                   # a disturbance worth estimating
    assert np.all(err.max(axis=0)[:3] <= bound[:3]), (err.max(axis=0), bound)
    # the torso's mass does not enter the swing leg's rows: there r is the integration error only
    assert np.abs(taud[:, 3:]).max() < 1e-9 and err[:, 3:].max() < 1e-3 * np.abs(taud).max()
    # the missing torso weight reads as an upward force at the torso (4 kg x 9.81 m/s^2 = 39 N, plus the
    # missing mass's vertical acceleration)
    Wz = np.array([w[1] for w in tr.W if w is not None])[100:]
    assert 20.0 < np.median(Wz) < 70.0


def test_momentum_observer_negative_control_without_coriolis(monkeypatch):
    """An observer that leaves out C^T q' (beta = g) misses the bound on the same run."""
    orig = mom.MomentumTerms.mass_beta

    def gravity_only(self, q, qd):
        A, _ = orig(self, q, qd)
        self._q[3:] = q
        return A, pin.computeGeneralizedGravity(self.model, self.data, self._q)[3:].copy()
    monkeypatch.setattr(mom.MomentumTerms, "mass_beta", gravity_only)
    _, err, bound, _ = _mass_error_run()
    assert not np.all(err.max(axis=0)[:3] <= bound[:3])


# ------------------------------------------------------------------------------ predictor
def _max_diff(a, b):
    n = min(len(a.records), len(b.records))
    assert n > 0
    return max(max(np.abs(x.q - y.q).max(), np.abs(x.qd - y.qd).max()) for x, y in zip(a.records[:n], b.records[:n]))


@pytest.fixture(scope="module")
def undelayed():
    from biped_controller.closed_loop import runner
    return runner.run(steps=2, mode="both", ctrl_config=load_controller_config(mode="both"))


def test_predictor_exact_when_the_model_is_exact(undelayed):
    """Delay of 2 periods, touchdown delayed too: with the Smith predictor the run is the undelayed one
    (every true state to 1e-9, through two touchdowns); the controller acts in the true stance at every
    period, i.e. it predicted each touchdown 2 periods before it was sensed."""
    from biped_controller.closed_loop import runner
    d = 2
    r = runner.run(steps=2, mode="both", ctrl_config=load_controller_config(mode="both", delay_compensation=d),
                   perturbation=PlantPerturbation(delay=d))
    assert not r.fallen and r.steps_walked == 2 and len(r.records) == len(undelayed.records)
    assert _max_diff(r, undelayed) < 1e-9
    assert all(s.stance == rec.stance for s, rec in zip(r.statuses, r.records))
    # the first touchdown is inside the records (the second ends the run): for the 2 periods after it
    # the sensors still reported the old stance while the controller acted in the new one
    assert sum(1 for k, rec in enumerate(r.records[1:], 1) if rec.stance != r.records[k - 1].stance) == 1


def test_predictor_negative_controls(undelayed):
    """The wrong delay (1 for 2) is not exact; without the predictor the walk falls within 5 ms of the
    first touchdown (docs/robustness.md: the old stance's law on the new stance)."""
    from biped_controller.closed_loop import runner
    wrong = runner.run(steps=1, mode="both", ctrl_config=load_controller_config(mode="both", delay_compensation=1),
                       perturbation=PlantPerturbation(delay=2), max_time=0.3)
    assert _max_diff(wrong, undelayed) > 1e-6
    none = runner.run(steps=2, mode="both", ctrl_config=load_controller_config(mode="both"),
                      perturbation=PlantPerturbation(delay=2))
    assert none.fallen and none.steps_walked == 1 and none.fall_time - none.impacts[0].t < 0.005


@pytest.mark.parametrize("engine", ["fast", "reference"])
def test_predictor_reconciles_a_touchdown_sensed_at_once(undelayed, engine):
    """Delay of 2 periods with the touchdown reported at once (plant ``touchdown_delayed`` False): the first
    sample of the new stance is fresh while the predictor still runs from an old-stance sample of 2 periods
    ago; with ``predictor_touchdown_at_once`` the pipeline takes it as of its own period and predicts through
    the decisions since it only (0, then 1, 2 as the held sample ages), so the run is the undelayed one to
    1e-9 through two touchdowns, on both paths: the compiled pipeline (fast engine) and the Python cores
    (reference engine, against its own undelayed run). Negative controls: the same plant with the old
    assumption (every sample 2 periods old) falls at the first touchdown; so does the setting on a plant whose
    touchdown is delayed (a mismatch: no touchdown is predicted, none is reported for 2 periods)."""
    from biped_controller.core.control.controller import AdaptiveController
    from biped_controller.core.sensing.pipeline_compiled import CompiledSensing
    from biped_controller.core.sensing.pipeline import SensingPipeline
    from biped_controller.closed_loop import runner
    at_once = PlantPerturbation(delay=2, touchdown_delayed=False)
    cfg = load_controller_config(mode="both", engine=engine, delay_compensation=2, predictor_touchdown_at_once=True)
    kind = CompiledSensing if engine == "fast" else SensingPipeline
    assert isinstance(AdaptiveController(cfg)._sensing, kind)          # the path under test
    ref = undelayed if engine == "fast" else runner.run(
        steps=2, mode="both", ctrl_config=load_controller_config(mode="both", engine=engine))
    r = runner.run(steps=2, mode="both", ctrl_config=cfg, perturbation=at_once)
    assert not r.fallen and r.steps_walked == 2 and len(r.records) == len(ref.records)
    assert _max_diff(r, ref) < 1e-9
    assert all(s.stance == rec.stance for s, rec in zip(r.statuses, r.records))
    old = runner.run(steps=2, mode="both", ctrl_config=replace(cfg, predictor_touchdown_at_once=False),
                     perturbation=at_once)
    assert old.fallen and old.steps_walked == 1 and old.fall_time - old.impacts[0].t < 0.005
    if engine == "fast":
        mismatch = runner.run(steps=2, mode="both", ctrl_config=cfg, perturbation=PlantPerturbation(delay=2))
        assert mismatch.fallen and mismatch.steps_walked == 1 and mismatch.fall_time - mismatch.impacts[0].t < 0.005


REAL_PROFILE = dict(momentum_observer=True, state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14,
                    sensor_noise_qd=5e-2, sensor_noise_pitch=1e-3, momentum_observer_gain=50.0)


@pytest.mark.parametrize("engine", ["fast", "reference"])
def test_no_touchdown_is_predicted_when_it_is_reported_at_once(engine):
    """Real-sensor profile (5e-4 rad, 5e-2 rad/s, 14 bits, IMU 1e-3 rad; seed 0), delay of 1 period, the
    touchdown reported at once: with ``predictor_touchdown_at_once`` the predictor integrates in the sensed
    stance only (a touchdown before t_k is in the sample of period k), and the controller acts in the true
    stance in every period through three touchdowns, on both paths. Negative control (Python cores): the
    same pipeline with the predictor's touchdown detection on takes the noisy estimate's sole for landed
    before the impact, acts in the new stance too early and falls (take_off at the first touchdown)."""
    from biped_sim.plant.config import load_sim_config
    from biped_model.gait_family import GaitFamily
    from biped_controller.closed_loop import runner
    plant = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, noise_pitch=1e-3, delay=1,
                              touchdown_delayed=False)
    cfg = load_controller_config(mode="both", engine=engine, delay_compensation=1, predictor_touchdown_at_once=True,
                                 **REAL_PROFILE)
    r = runner.run(steps=3, mode="both", ctrl_config=cfg, perturbation=plant)
    assert not r.fallen and r.steps_walked == 3
    assert all(s.stance == rec.stance for s, rec in zip(r.statuses, r.records))
    if engine == "reference":
        loop = runner.ClosedLoop(load_sim_config(), cfg, GaitFamily.load(), load_description(), plant)
        loop.reset()
        loop.ctrl._sensing.pred.touchdowns = True           # the predictor of before: it predicts touchdowns
        bad = loop.run(3, limit=2.0)
        assert bad.fallen and bad.fall_cause == "take_off" and bad.steps_walked == 0
        assert any(s.stance != rec.stance for s, rec in zip(bad.statuses, bad.records))


def test_predictor_sample_age_checked():
    """``DelayPredictor.predict``'s ``periods`` (the sample's age): 0 returns the sample; an age beyond the
    decisions recorded is refused naming it."""
    from biped_controller.core.sensing.predictor import DelayPredictor, PredictorError
    from biped_model.description import load_description
    dp = DelayPredictor(load_description(), 2, 2, 1e-3, 1e-8, 1e-4, 1e-9)
    q, qd = np.array([0.15, 0.3, -0.4, -0.2, 0.6, -0.3]), np.array([0.5, -0.2, 0.1, 0.3, -0.4, 0.2])
    dp.record(0.0, np.zeros(6), 0)
    p0 = dp.predict(0.001, q, qd, 0, periods=0)
    assert np.array_equal(p0.q, q) and np.array_equal(p0.qd, qd) and p0.stance == 0
    assert not np.array_equal(dp.predict(0.001, q, qd, 0, periods=1).q, q)   # control: one period integrated
    with pytest.raises(PredictorError, match="periods"):
        dp.predict(0.001, q, qd, 0, periods=2)


# ------------------------------------------------------------------------------ settings and command lines
def test_controller_settings_rejected_by_name():
    for key, val in (("momentum_observer_gain", -1.0), ("delay_compensation", 1.5), ("sensor_encoder_bits", -2),
                     ("state_estimator", "yes"), ("estimate_confidence", math.nan),
                     ("predictor_touchdown_at_once", 1)):
        with pytest.raises(ControllerConfigError, match=key):
            load_controller_config(**{key: val})
    with pytest.raises(ControllerConfigError, match="estimator_accel_std"):
        load_controller_config(state_estimator=True, estimator_accel_std=0.0, sensor_noise_q=1e-3)
    assert load_controller_config(delay_compensation=2.0).delay_compensation == 2     # a ROS float parameter
    assert not load_controller_config().real_sensing          # the config files: the controller of before


def test_experiment_perturb_option():
    from biped_controller.studies.trial import settings as ts
    p = ts.parse_perturbation(["noise_q=5e-4", "encoder_bits=14", "delay=2", "touchdown_delayed=false"])
    assert p == PlantPerturbation(noise_q=5e-4, encoder_bits=14, delay=2, touchdown_delayed=False)
    with pytest.raises(PerturbationError, match="torso_mas"):
        ts.parse_perturbation(["torso_mas_scale=0.8"])
    with pytest.raises(ts.OverrideError, match="twice"):
        ts.parse_perturbation(["delay=1", "delay=2"])
    out = subprocess.run([sys.executable, "-m", "biped_controller.studies.experiment", "walk", "--steps", "1",
                          "--perturb", "torso_mass_scale=0.8", "--perturb", "noise_q=1e-4", "--perturb", "encoder_bits=16"],
                         capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert out.returncode == 0, out.stderr
    assert "plant perturbation: torso_mass_scale=0.8, noise_q=0.0001, encoder_bits=16" in out.stdout
    assert "not run: the sensor model needs held torques" in out.stdout
    bad = subprocess.run([sys.executable, "-m", "biped_controller.studies.experiment", "walk", "--perturb", "mu=-1"],
                         capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert bad.returncode == 2 and "perturbation 'mu'" in bad.stderr and "Traceback" not in bad.stderr


def test_robustness_help_and_level_keys():
    from biped_controller.studies import robustness as rb
    out = subprocess.run([sys.executable, "-m", "biped_controller.studies.robustness", "--help"],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0 and "Traceback" not in out.stderr and "torso_mass-20" in out.stdout
    assert rb._levels(["torso_mass-20", "noise5e-4_14bit"])[1].perturbation.encoder_bits == 14
    assert rb._levels(["torso mass -20 %"])[0].key == "torso_mass-20"        # the table's text still works
    with pytest.raises(rb.RobustnessError, match="unknown level"):
        rb._levels(["torso_mass-25"])


def test_qp_rows_carry_the_wrench_and_its_spread():
    """The momentum observer's estimate enters the 17 'with estimate' rows as C dR on the five contact
    offsets plus estimate_confidence x sqrt(C_i Sigma_dR C_i^T); the 17 rows without it are the nominal
    ones; the matrix G is the same for both sets (checked against the rows built with no estimate)."""
    from biped_model.fixed_foot import contact_rows
    from biped_model.gait_family import GaitFamily
    from biped_controller.core.control.controller import AdaptiveController
    fam = GaitFamily.load()
    q0, qd0 = fam.initial_state()
    cfg = load_controller_config(mode="both", momentum_observer=True, engine="reference")
    ctrl = AdaptiveController(cfg, fam, DESC)
    ctrl.reset(0)
    res = ctrl._begin(0.0, 0)
    ref = ctrl._reference(q0, qd0, res)
    dyn, jp = ctrl._model_terms(q0, qd0)
    G0, h0 = ctrl._qp_rows(ref, dyn, dyn, res)                  # no estimate
    S = np.array([[0.9, 0.1, 0.3], [0.2, -1.1, 0.05]])
    W = np.array([50.0, -20.0, 3.0])
    covW = np.diag([4.0, 9.0, 1.0])
    ctrl.wrench = mom.Wrench(r=np.zeros(6), W=W, cov_W=covW, dR=S @ W, cov_dR=S @ covW @ S.T, S=S)
    dyn_c, F = ctrl._observe(res, qd0, dyn, jp)
    assert F == 50.0
    G, h = ctrl._qp_rows(ref, dyn, dyn_c, res)
    assert np.array_equal(G, G0)
    C, _ = contact_rows(cfg.margin_friction * DESC.mu, DESC.foot.l_min + cfg.margin_zmp, DESC.foot.l_max - cfg.margin_zmp)
    spread = cfg.estimate_confidence * np.sqrt(np.einsum("ij,jk,ik->i", C, S @ covW @ S.T, C))
    assert np.allclose(h[:5], h0[:5] - C @ (S @ W) - spread, rtol=0, atol=1e-9)
    assert np.array_equal(h[5:17], h0[5:17])                     # torque rows: the estimate does not enter
    assert np.allclose(h[17:34], h0[17:34], rtol=0, atol=1e-12)  # the rows without the estimate
    # negative control: a wrong sign of the shift is seen
    assert not np.allclose(h[:5], h0[:5] + C @ (S @ W) - spread, rtol=0, atol=1e-9)


# ------------------------------------------------------------------------------ the IMU gyro
GYRO_NOISE = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, noise_pitch=1e-3, noise_pitch_rate=5e-3,
                               seed=1)


def _torso_rate_errors(tr):
    """Per period (estimate in the true stance): the torso pitch rate's error e = 1^T (x_q' - q')[:3] [rad/s] and
    e / sigma, sigma^2 = 1^T P_q'q'[:3, :3] 1 (the filter's own variance of q1' + q2' + q3')."""
    e, z = [], []
    for est, qd, st, told in zip(tr.est, tr.qd, tr.stance, tr.told):
        if est is None or st != told:
            continue
        _, xqd, P = est
        err = float(np.sum(xqd[:3]) - np.sum(qd[:3]))
        e.append(err)
        z.append(err / math.sqrt(float(P[6:9, 6:9].sum())))
    return np.array(e), np.array(z)


def test_gyro_shrinks_the_velocity_error():
    """The same seeded noisy walk through a touchdown (compiled pipeline; the plant's gyro 5e-3 rad/s), the
    estimator with and without the gyro fused: with it the torso pitch rate's rms error is below half the
    one without and below the gyro's own noise, the joint rates' rms error is smaller, and the errors
    divided by the filter's standard deviations stay of unit size (torso rate: rms in [0.4, 1.5], 99 %
    within 3 sigma; every state as the test above). Negative control: a filter told the gyro is 100 x better
    than it is fails the unit-size check."""
    with_gyro = closed_loop(0.6, GYRO_NOISE, python_sensing=False, estimator_gyro=True,
                            sensor_noise_pitch_rate=5e-3, **REAL)
    without = closed_loop(0.6, GYRO_NOISE, python_sensing=False, **REAL)
    for tr in (with_gyro, without):
        assert tr.fall is None and any(s != tr.stance[0] for s in tr.stance)
    e1, z1 = _torso_rate_errors(with_gyro)
    e0, _ = _torso_rate_errors(without)
    rms1, rms0 = float(np.sqrt((e1 ** 2).mean())), float(np.sqrt((e0 ** 2).mean()))
    assert rms1 < 0.5 * rms0 and rms1 < GYRO_NOISE.noise_pitch_rate, (rms1, rms0)
    rz = float(np.sqrt((z1 ** 2).mean()))
    assert 0.4 < rz < 1.5 and (np.abs(z1) < 3).mean() > 0.99, rz

    def qd_rms(tr):
        err = np.array([est[1] - qd for est, qd, st, told in zip(tr.est, tr.qd, tr.stance, tr.told)
                        if est is not None and st == told])
        return np.sqrt((err ** 2).mean(axis=0))
    assert qd_rms(with_gyro).mean() < qd_rms(without).mean()
    z = _normalised_errors(with_gyro)
    rms = np.sqrt((z ** 2).mean(axis=0))
    assert np.all(rms > 0.4) and np.all(rms < 1.5), rms
    print(f"\ntorso rate rms error: {rms1:.3g} rad/s with the gyro, {rms0:.3g} without; normalised rms {rz:.3f}; "
          f"joint rates rms (mean of 6): {qd_rms(with_gyro).mean():.3g} with, {qd_rms(without).mean():.3g} without")
    bad = closed_loop(0.6, GYRO_NOISE, python_sensing=False, estimator_gyro=True, sensor_noise_pitch_rate=5e-5, **REAL)
    _, zb = _torso_rate_errors(bad)
    assert not (np.sqrt((zb ** 2).mean()) < 1.5 and (np.abs(zb) < 3).mean() > 0.99)
