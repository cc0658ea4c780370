"""The predicted touchdown's k-sigma band and the torque admissible in both stances (
``core/sensing/touchdown_band.py``).

Oracles: the sole height's standard deviation against a seeded Monte Carlo of the swing sole over
q ~ N(q0, P); the propagated covariance against the estimator's own time update; the lift-off rows'
heel and toe accelerations against second differences in time of the sole points' heights; the torque's
rows against inverse dynamics (RNEA, ``FixedFootModel.margins_direct``) in both stances; the compiled
pipeline's band against the Python cores' (the same samples); and the closed
loop on the rigid plant with the delay row of the issue (real sensors, delay 2, touchdown delayed, seed 0),
on the compiled pipeline and on the Python cores. Negative controls: a diagonal covariance, the sole
acceleration without its drift, the controller's torque before the projection, and the loop without the
band (k = 0), which falls at the first touchdown.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from biped_sim.plant.perturbation import PlantPerturbation
from biped_model.description import load_description
from biped_model.fixed_foot import FixedFootModel, relabel
from biped_model.floating import FloatingModel

from biped_controller.core.control.config import load_controller_config
from biped_controller.core.sensing.estimation import EstimatorConfig, JointStateEstimator
from biped_controller.core.sensing.predictor import flat_foot_impact
from biped_controller.core.sensing.touchdown_band import (BothStancesTorque, TouchdownBand, in_band,
                                                  propagated_position_cov, sole_height_std, sole_rate)

DESC = load_description()
REAL = dict(momentum_observer=True, state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14,
            sensor_noise_qd=5e-2, sensor_noise_pitch=1e-3, momentum_observer_gain=50.0)
# the delay row with real sensors: delay 2 periods, the touchdown in the delayed sample, noise
DELAY_ROW = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, delay=2, touchdown_delayed=True, seed=0)


@pytest.fixture(scope="module")
def before_impact():
    """The true (q, q') and applied torque of the last period before the first touchdown of a perfect-sensor
    walk (stance 0), and the model's flat-foot impact of that state."""
    from biped_controller.closed_loop import runner
    r = runner.run(steps=1, mode="both", ctrl_config=load_controller_config(mode="both"))
    recs = [rec for rec in r.records if rec.t < r.impacts[0].t and rec.stance == 0]
    rec = recs[-1]
    qn, qdn = flat_foot_impact(FloatingModel(DESC), rec.q, rec.qd, 0)
    return rec.q.copy(), rec.qd.copy(), rec.torque.copy(), qn, qdn


def _lowest_sole(model: FixedFootModel):
    foot = DESC.foot

    def z(q):
        pose, _ = model.swing_foot(np.asarray(q, dtype=float))
        return float(pose[1] + min(foot.l_min * math.sin(pose[2]), foot.l_max * math.sin(pose[2])))
    return z


def test_sole_height_std_against_monte_carlo(before_impact):
    """sigma_z = sqrt(g^T P g) against the standard deviation of the swing sole's height over 20000 seeded draws
    q ~ N(q0, P) (P of the estimator's size, 1e-4 rad, dominated by a direction along which the height does not
    change to first order): within 3 %. Negative control: the diagonal of the same P gives a sigma_z off by
    more than 10 % (the correlations matter)."""
    q0 = before_impact[0]
    z = _lowest_sole(FixedFootModel(DESC))
    rng = np.random.default_rng(11)
    h = 1e-6
    g = np.array([(z(q0 + h * e) - z(q0 - h * e)) / (2 * h) for e in np.eye(6)])
    v = rng.normal(size=6)
    v -= (v @ g) / (g @ g) * g                          # the dominant direction leaves the sole's height alone
    P = 1e-8 * (4.0 * np.outer(v, v) / (v @ v) + 0.05 * np.eye(6))
    s = sole_height_std(z, q0, P)
    draws = rng.multivariate_normal(q0, P, size=20000)
    mc = float(np.std([z(q) for q in draws]))
    assert abs(s / mc - 1.0) < 0.03, (s, mc)
    sd = sole_height_std(z, q0, np.diag(np.diag(P)))
    assert abs(sd / mc - 1.0) > 0.10, (sd, mc)


def test_sigma_bound_is_an_upper_bound():
    """The prefilter's bound R sqrt(6 trace P) (``sigma_bound``, R = ``lever_bound``) is never below sigma_z, and
    every |dz_s/dq_i| is at most R, over seeded random states and covariances; the bound is not vacuous either
    (within a factor 100 of sigma_z for an isotropic P)."""
    from biped_controller.core.sensing.touchdown_band import lever_bound, sigma_bound
    z = _lowest_sole(FixedFootModel(DESC))
    R = lever_bound(DESC)
    rng = np.random.default_rng(9)
    h = 1e-6
    for _ in range(20):
        q = rng.uniform(-0.8, 0.8, 6)
        g = np.array([(z(q + h * e) - z(q - h * e)) / (2 * h) for e in np.eye(6)])
        assert np.abs(g).max() <= R
        L = rng.normal(size=(6, 6))
        P = 1e-8 * (L @ L.T)
        assert sole_height_std(z, q, P) <= sigma_bound(R, P)
        assert sigma_bound(R, 1e-8 * np.eye(6)) < 100 * sole_height_std(z, q, 1e-8 * np.eye(6))


def test_propagated_covariance_is_the_filters_time_update():
    """P_qq(t + dt) of ``propagated_position_cov`` equals the position block of the estimator's own time
    update over dt (``JointStateEstimator.predict``) to round-off, for a seeded full covariance."""
    cfg = EstimatorConfig(sigma_q=5e-4, encoder_bits=14, sigma_qd=5e-2, sigma_pitch=1e-3, sigma_acc=5.0,
                          sigma_impact=0.05)
    est = JointStateEstimator(cfg)
    rng = np.random.default_rng(5)
    L = rng.normal(size=(12, 12))
    est.P = 1e-6 * (L @ L.T)
    P0 = est.P.copy()
    dt = 0.002
    est.predict(dt, np.zeros(6))
    assert np.abs(propagated_position_cov(P0, dt, cfg.sigma_acc) - est.P[:6, :6]).max() < 1e-18
    assert np.abs(propagated_position_cov(P0, 2 * dt, cfg.sigma_acc) - est.P[:6, :6]).max() > 1e-10


def test_liftoff_rows_against_second_differences(before_impact):
    """The heel's and toe's vertical accelerations a_p = J_p w + d_p of ``liftoff_rows`` at the post-impact
    state (the foot the touchdown released) against (z_p(t+h) - 2 z_p(t) + z_p(t-h)) / h^2 along
    q(t) = q + q' t + w t^2 / 2 (h = 1e-4 s), for seeded w: within 1e-4 relative. Negative control: without
    the drift d_p the acceleration is off by more than 1 %."""
    _, _, _, qn, qdn = before_impact
    model = FixedFootModel(DESC)
    bt = BothStancesTorque(model, np.zeros(17), DESC.mu, DESC.foot.l_min, DESC.foot.l_max)
    Jp, dp = bt.liftoff_rows(qn, qdn)
    foot = DESC.foot

    def zp(q):
        pose, _ = model.swing_foot(q)
        return np.array([pose[1] + foot.l_min * math.sin(pose[2]), pose[1] + foot.l_max * math.sin(pose[2])])
    rng = np.random.default_rng(3)
    h = 1e-4
    for _ in range(3):
        w = rng.normal(scale=20.0, size=6)
        fd = (zp(qn + qdn * h + 0.5 * w * h * h) - 2 * zp(qn) + zp(qn - qdn * h + 0.5 * w * h * h)) / h ** 2
        a = Jp @ w + dp
        assert np.abs(a - fd).max() < 1e-4 * max(1.0, np.abs(fd).max()), (a, fd)
        assert np.abs(Jp @ w - fd).max() > 1e-2 * np.abs(fd).max()


def test_band_torque_holds_both_stances(before_impact):
    """At the state just before a touchdown, the old stance's torque (the walk's own) is projected onto the
    rows of both hypotheses: the result holds, by inverse dynamics (RNEA) in each stance, the contact rows
    (F_z > 0, friction, centre of pressure on the sole) and the torque limits, and the released foot's heel
    and toe do not accelerate into the ground. Negative control: the torque before the projection breaks
    a row of the new stance (the old law on the landed foot)."""
    q, qd, tq, qn, qdn = before_impact
    cfg = load_controller_config(mode="both")
    model = FixedFootModel(DESC)
    margin = np.concatenate([[cfg.margin_normal_force, 0, 0, 0, 0], np.full(12, cfg.margin_torque)])
    bt = BothStancesTorque(model, margin, cfg.margin_friction * DESC.mu, DESC.foot.l_min + cfg.margin_zmp,
                           DESC.foot.l_max - cfg.margin_zmp)
    band = TouchdownBand(z=0.0, sigma_z=1e-4, q_old=q, qd_old=qd, stance_old=0, q_new=qn, qd_new=qdn, stance_new=1)

    def check(gamma):
        """smallest margin of the old stance's and the new stance's rows (RNEA), and the released foot's
        smallest sole acceleration [m/s^2]"""
        out = []
        for qq, vv, g in ((q, qd, gamma), (qn, qdn, relabel(gamma))):
            dyn = model.dynamics(qq, vv)
            w = np.linalg.solve(dyn.A, g - dyn.H)
            out.append(float(model.margins_direct(qq, vv, w).min()))
        dyn = model.dynamics(qn, qdn)
        w = np.linalg.solve(dyn.A, relabel(gamma) - dyn.H)
        Jp, dp = bt.liftoff_rows(qn, qdn)
        return out[0], out[1], float((Jp @ w + dp).min())
    m_old, m_new, lift = check(tq)
    assert m_old > 0 and min(m_new, lift) < 0          # the old law holds the old stance only
    g, changed = bt.torque(band, tq, told=0)
    assert changed
    m_old, m_new, lift = check(g)
    # (the least-violation answer holds an active row to its regularisation: 1e-4 m/s^2 sinks the foot
    # 5e-11 m over a 1 ms period, against the plant's 1 mm)
    assert m_old > 0 and m_new > 0 and lift > -1e-4, (m_old, m_new, lift)
    assert bt.torque(band, tq, told=1)[0].shape == (6,)    # the torque in the other stance's order is accepted


def test_band_is_empty_without_a_spread():
    """No covariance, no band: in_band is False for sigma_z = 0 (the perfect-sensor predictor stays exact) and
    for k = 0; the descent test is the sole's rate along q'."""
    assert not in_band(0.0, 0.0, 5.0) and not in_band(0.0, 1e-4, 0.0)
    assert in_band(4e-4, 1e-4, 5.0) and not in_band(6e-4, 1e-4, 5.0) and in_band(-4e-4, 1e-4, 5.0)
    z = _lowest_sole(FixedFootModel(DESC))
    q0 = np.array([0.1, -0.3, 0.5, -0.2, -0.4, 0.3])
    qd0 = np.array([0.5, -1.0, 2.0, 1.0, -2.0, 3.0])
    h = 1e-6
    assert sole_rate(z, q0, qd0) == pytest.approx((z(q0 + h * qd0) - z(q0 - h * qd0)) / (2 * h), rel=1e-5)


@pytest.mark.parametrize("engine", ["fast", "reference"])
def test_delayed_touchdown_walks_with_real_sensors(engine):
    """The issue's delay row with real sensors (noise 5e-4 rad, 5e-2 rad/s, 14 bits, seed 0; delay 2 periods, the
    touchdown delayed), the predictor d = 2 and the band (k = 5): the walk passes its touchdowns (3 on the
    compiled pipeline, the first on the Python cores), with band periods at each. Negative control: the same
    loop without the band (k = 0) falls at the first touchdown (take_off at 0.465 s, the controller in the
    new stance before the impact, docs/robustness.md)."""
    from biped_controller.core.control.controller import AdaptiveController
    from biped_controller.core.sensing.pipeline_compiled import CompiledSensing
    from biped_controller.core.sensing.pipeline import SensingPipeline
    from biped_controller.closed_loop import runner
    steps = 3 if engine == "fast" else 1
    cfg = load_controller_config(mode="both", engine=engine, delay_compensation=2, **REAL)
    assert cfg.touchdown_band_sigmas > 0
    ctrl = AdaptiveController(cfg)
    assert isinstance(ctrl._sensing, CompiledSensing if engine == "fast" else SensingPipeline)
    loop = runner.ClosedLoop(_sim_cfg(), cfg, _family(), DESC, DELAY_ROW)
    loop.reset()
    r = loop.run(steps, limit=0.5 + 0.47 * steps)
    assert not r.fallen and r.steps_walked == steps, (r.fall_cause, r.fall_time)
    assert loop.ctrl.band_periods >= steps and loop.ctrl.band_changed >= 1
    if engine == "fast":
        from dataclasses import replace
        bad = runner.run(steps=1, mode="both", ctrl_config=replace(cfg, touchdown_band_sigmas=0.0),
                         perturbation=DELAY_ROW, max_time=1.0)
        assert bad.fallen and bad.steps_walked == 0 and bad.fall_cause == "take_off"


def test_compiled_band_equals_the_python_band():
    """The delay row through the first touchdown on the Python cores (reference engine): the compiled pipeline
    fed the same samples and torques gives a band in the same periods, with the same z and sigma_z (1e-9
    relative) and the same hypotheses' states (1e-9). Negative controls: the replay with k = 1 instead of 5
    puts a band in fewer periods; with the estimator's process noise 1 % larger sigma_z differs."""
    from dataclasses import replace
    from biped_model.fast_engine import FastFixedFootModel
    from biped_model.fixed_foot import contact_rows
    from biped_controller.core.sensing.pipeline_compiled import CompiledSensing
    from estimation_loop import closed_loop
    tr = closed_loop(0.5, DELAY_ROW, python_sensing=True, engine="reference", delay_compensation=2, **REAL)
    assert tr.fall is None and tr.records[-1].impacts == 1
    cfg = load_controller_config(mode="both", delay_compensation=2, **REAL)

    def replay(cfg):
        fast = FastFixedFootModel(DESC)
        m = tr.ctrl.model
        C, _ = contact_rows(cfg.margin_friction * m.mu, m.l_min + cfg.margin_zmp, m.l_max - cfg.margin_zmp)
        cs = CompiledSensing(cfg, DESC, fast.ti, fast.tf, C, m.torque_min, m.torque_max)
        out = []
        for (t, q, qd, st, pitch, rate), sent in zip(tr.obs, tr.sent):
            cs.sense(t, q, qd, st, pitch, rate)
            out.append(cs.band)
            cs.record(t, sent, st)
        return out
    bands = replay(cfg)
    n_py = sum(b is not None for b in tr.band)
    assert n_py >= 2 and [b is None for b in bands] == [b is None for b in tr.band]
    worst = 0.0
    for a, b in zip(bands, tr.band):
        if b is None:
            continue
        assert a.stance_old == b.stance_old and a.stance_new == b.stance_new
        worst = max(worst, abs(a.z - b.z) / abs(b.sigma_z), abs(a.sigma_z / b.sigma_z - 1.0),
                    *(float(np.abs(x - y).max()) for x, y in ((a.q_old, b.q_old), (a.qd_old, b.qd_old),
                                                             (a.q_new, b.q_new), (a.qd_new, b.qd_new))))
    assert worst < 1e-9, worst
    narrow = replay(replace(cfg, touchdown_band_sigmas=1.0))
    assert sum(b is not None for b in narrow) < n_py
    other = replay(replace(cfg, estimator_accel_std=5.05))     # the estimator's process noise 1 % larger
    assert max(abs(a.sigma_z / b.sigma_z - 1.0) for a, b in zip(other, tr.band)
               if a is not None and b is not None) > 1e-6


def _sim_cfg():
    from biped_sim.plant.config import load_sim_config
    return load_sim_config()


def _family():
    from biped_model.gait_family import GaitFamily
    return GaitFamily.load()
