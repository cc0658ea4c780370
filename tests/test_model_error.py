"""Model error: the momentum observer against the true generalized force of an inertia error, and the
legs' model-error estimator (``core/sensing/model_error.py``): its regressor against the plant's own dynamics, its
identification in noise-free closed loops, its compiled-pipeline twin, its settings."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from biped_model.description import load_description
from biped_model.fixed_foot import FixedFootModel
from biped_sim.plant.perturbation import PlantPerturbation

from biped_controller.core.control.config import ControllerConfigError, load_controller_config
from biped_controller.core.sensing.model_error import (LEG_PARAMETERS, LINK_JOINTS, LegModelError, LegRegressor,
                                                ModelErrorConfigError, RneaLegRegressor, _bumped,
                                                load_model_error_kernels, parameter_bumps, prior_std)
from biped_model.fixed_foot import relabel

from estimation_loop import closed_loop

DESC = load_description()
K = 200.0
INERTIAS = PlantPerturbation(torso_inertia_scale=1.3, thigh_inertia_scale=1.3, shin_inertia_scale=1.3,
                             foot_inertia_scale=1.3)
LEGS = PlantPerturbation(thigh_inertia_scale=1.3, shin_inertia_scale=0.8, thigh_mass_scale=1.1, foot_mass_scale=0.9)


def _theta_true(p: PlantPerturbation) -> np.ndarray:
    """theta (plant minus model) of a perturbation that only scales leg masses and inertias."""
    plant = p.apply(DESC)
    return np.array([getattr(getattr(plant, link), name) - getattr(getattr(DESC, link), name)
                     for link, name in LEG_PARAMETERS])


def _states(n: int, seed: int):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield (rng.uniform(-0.6, 0.6, 6) + np.array([0.0, 0.3, 0.0, 0.0, 0.3, 0.0]), rng.normal(0, 1.5, 6),
               rng.normal(0, 20.0, 6))


# ------------------------------------------------------------------------------ the regressor
def test_regressor_against_the_plants_own_dynamics():
    """Y(q, q', q'') theta = RNEA of the plant's model - RNEA of the controller's, on all 9 rows (root and
    joints), at seeded states; a torso mass error leaves the swing leg's rows at 0."""
    reg, nom = LegRegressor(DESC), FixedFootModel(DESC)
    plant = FixedFootModel(LEGS.apply(DESC))
    torso = FixedFootModel(PlantPerturbation(torso_mass_scale=0.8).apply(DESC))
    theta = _theta_true(LEGS)
    assert np.count_nonzero(theta) == 4
    worst, wrong, swing_torso = 0.0, np.inf, 0.0
    for q, qd, a in _states(20, 1):
        Y = reg(q, qd, a)
        t0, r0 = nom.inverse_dynamics(q, qd, a)
        t1, r1 = plant.inverse_dynamics(q, qd, a)
        e = np.concatenate([r1 - r0, t1 - t0])
        worst = max(worst, np.abs(Y @ theta - e).max() / np.abs(e).max())
        t2, r2 = torso.inverse_dynamics(q, qd, a)
        e2 = np.concatenate([r2 - r0, t2 - t0])
        wrong = min(wrong, np.abs(Y @ (1.1 * theta) - e).max() / np.abs(e).max())
        swing_torso = max(swing_torso, np.abs(e2[6:]).max() / np.abs(e2).max())
    assert worst < 1e-9, worst
    assert wrong > 1e-2, wrong                 # negative control: 10 % more of the same error misses
    # what the estimator rests on: a torso error (like a push on the torso) does not reach the swing leg's rows
    assert swing_torso < 1e-12, swing_torso


def _regressor_error(reg, oracle, seed: int) -> float:
    """max |Y - Y_oracle| / max |Y_oracle| over seeded states in both stances (the second as the first's
    relabelled state: the chain serves both legs through ``relabel``)."""
    worst = 0.0
    for q, qd, a in _states(20, seed):
        for s in ((q, qd, a), (relabel(q), relabel(qd), relabel(a))):
            Y0 = oracle(*s)
            worst = max(worst, np.abs(reg(*s) - Y0).max() / np.abs(Y0).max())
    return worst


def test_joint_torque_regressor_equals_the_rnea_differences():
    """Pinocchio's joint torque regressor combined by ``parameter_bumps`` gives the same Y (9 x 6) as the
    RNEA differences of the seven models (``RneaLegRegressor``, the first implementation) to 1e-9 relative,
    at seeded states in both stances. Negative controls, each detected: the parallel-axis term |c|^2 1 - c c^T
    of a mass bump dropped; the thigh's bumps put on the shin's joints (a wrong link: the description's thigh
    and shin have the same length and centre, so only the joints tell them apart); only one leg's body bumped."""
    oracle = RneaLegRegressor(DESC)
    assert _regressor_error(LegRegressor(DESC), oracle, 3) < 1e-9
    cases = {}
    no_c2 = LegRegressor(DESC)
    for j, (_, name) in enumerate(LEG_PARAMETERS):
        if name == "mass":
            no_c2._D[np.arange(no_c2._D.shape[0]) % 10 >= 4, j] = 0.0
    cases["c^2 dropped"] = no_c2
    wrong = LegRegressor(DESC)
    jth, jsh = (np.array([wrong._model.getJointId(n) for n in LINK_JOINTS[k]]) for k in ("thigh", "shin"))
    rows = lambda js: np.concatenate([np.arange(10 * (i - 1), 10 * i) for i in js])  # noqa: E731
    wrong._D[rows(jsh), 0:2], wrong._D[rows(jth), 0:2] = wrong._D[rows(jth), 0:2], 0.0
    cases["thigh's columns on the shin's joints"] = wrong
    one_leg = LegRegressor(DESC)
    one_leg._D[rows(jth[1:]), :] = 0.0
    cases["swing thigh left out"] = one_leg
    for name, reg in cases.items():
        assert _regressor_error(reg, oracle, 3) > 1e-3, name


def test_parameter_bumps_are_pinocchios_dynamic_parameter_differences():
    """Each column of ``parameter_bumps`` (the formula d pi / d m = [1, c, vech(|c|^2 1 - c c^T)],
    d pi / d I = vech(1)) equals, on its joints, Pinocchio's own ``Inertia.toDynamicParameters`` of the model
    with that parameter raised by one unit minus the model's, and is 0 on every other joint (the torso's,
    the root translations')."""
    base = FixedFootModel(DESC).model
    joints, D = parameter_bumps(base)
    for j, (link, name) in enumerate(LEG_PARAMETERS):
        bumped = FixedFootModel(_bumped(DESC, link, name)).model
        for i in range(1, base.njoints):
            diff = bumped.inertias[i].toDynamicParameters() - base.inertias[i].toDynamicParameters()
            mine = D[list(joints).index(i), :, j] if i in joints else np.zeros(10)
            assert np.abs(mine - diff).max() < 1e-12, (link, name, base.names[i])
    assert sorted(base.names[int(i)] for i in joints) == sorted(n for js in LINK_JOINTS.values() for n in js)


def _combine_case(rng, restarted: bool, has_prev: bool, use_cov: bool, singular: bool = False):
    """Seeded inputs of ``combine_*`` at a real model state (A, B, Y from the model and the regressor)."""
    q, qd, a = next(_states(1, int(rng.integers(1 << 30))))
    dyn = FixedFootModel(DESC).dynamics(q, qd)
    Y = LegRegressor(DESC)(q, qd, a)
    L = rng.normal(size=(6, 6))
    Jj = np.vstack([rng.normal(size=(2, 6)), [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]])
    if singular:                   # rank 2: the first row a multiple of the third (a straight stance knee's kind)
        Jj[0] = 0.7 * Jj[2]
    M = rng.normal(size=(3, 3))
    inputs = [Y, dyn.A, dyn.B, np.linalg.inv(dyn.A), rng.normal(0, 5, 6), rng.normal(size=(2, 3)), M @ M.T,
              rng.normal(0, 20, 3), Jj, 1e-4 * L @ L.T, use_cov, K, 1e-3, 0.01 * rng.uniform(), restarted, has_prev,
              0.25 * np.eye(3)]
    P = rng.normal(size=(6, 6))
    state = [rng.normal(0, 0.05, 6), 1e-3 * P @ P.T + 1e-4 * np.eye(6), rng.normal(size=(6, 6)),
             rng.normal(size=(6, 6)), rng.normal(0, 20, 3)]
    return inputs, state


def test_compiled_combination_equals_the_numpy_one():
    """``combine_kernel`` (Numba) = ``combine`` run by NumPy on every output and the updated state,
    to 1e-10 relative, at seeded inputs on every branch (restart or not, a previous Y or not, rate covariance
    or not, J_j of full rank or of rank 2); the torso wrench equals NumPy's SVD pseudo-inverse of J_j^T times
    r_t on both of J_j's cases; negative control: the same inputs with dt doubled differ."""
    kern = load_model_error_kernels()
    combine_numpy, combine_kernel = kern.combine, kern.combine_kernel
    rng = np.random.default_rng(4)
    for restarted, has_prev, use_cov, singular in itertools.product((False, True), repeat=4):
        inputs, state = _combine_case(rng, restarted, has_prev, use_cov, singular)
        res = []
        for fn, dt in ((combine_numpy, 1e-3), (combine_kernel, 1e-3), (combine_kernel, 2e-3)):
            st = [x.copy() for x in state]
            out = [np.empty(3), np.empty((3, 3)), np.empty(2), np.empty((2, 2))]
            args = [x.copy() if isinstance(x, np.ndarray) else x for x in inputs]
            args[12] = dt
            fn(*args, *st, *out)
            res.append(np.concatenate([x.ravel() for x in st + out]))
            # W_t = J_j^{T+} r_t against NumPy's SVD pseudo-inverse (the normal equations or the SVD inside)
            theta, _, Yf, _, Wr = st
            r_t = inputs[4] + Yf @ theta - inputs[8].T @ ((inputs[7] - Wr) * np.exp(-K * inputs[13]))
            ref = np.linalg.pinv(inputs[8].T) @ r_t
            assert np.abs(out[0] - ref).max() <= 1e-9 * np.abs(ref).max(), (singular, fn)
        scale = np.abs(res[0]).max()
        assert np.abs(res[1] - res[0]).max() <= 1e-10 * scale, (restarted, has_prev, use_cov)
        if not restarted:          # dt enters only the filter of a non-restart sample
            assert np.abs(res[2] - res[0]).max() > 1e-6 * scale, (has_prev, use_cov)


def test_translational_root_rows_are_blind_to_inertias():
    """The identity the estimator rests on: an inertia (about the centre of mass) enters the locked-root
    chain's translational root rows not at all (total force = sum m_b a_b), a mass does."""
    reg = LegRegressor(DESC)
    for q, qd, a in _states(10, 2):
        Y = reg(q, qd, a)
        inertia_cols = [j for j, (_, name) in enumerate(LEG_PARAMETERS) if name == "inertia"]
        mass_cols = [j for j, (_, name) in enumerate(LEG_PARAMETERS) if name == "mass"]
        assert np.abs(Y[:2, inertia_cols]).max() < 1e-9
        assert np.abs(Y[:2, mass_cols]).max() > 1.0


# ------------------------------------------------------------------------------ the observer under an inertia error
def _inertia_error_run(perturbation: PlantPerturbation, **extra):
    tr = closed_loop(0.40, perturbation, momentum_observer=True, momentum_observer_gain=K, **extra)
    nom, plant = FixedFootModel(DESC), FixedFootModel(perturbation.apply(DESC))
    taud = []
    for q, qd, g in zip(tr.q, tr.qd, tr.torque):
        dn, dp = nom.dynamics(q, qd), plant.dynamics(q, qd)
        a = np.linalg.solve(dp.A, g - dp.H)                   # the plant's true joint acceleration
        taud.append(dn.A @ a + dn.H - g)                      # = -(M_p q'' + h_p - (M_m q'' + h_m)), joint rows
    return tr, np.array(taud)


def _lag_bound(tau: np.ndarray, t: np.ndarray) -> np.ndarray:
    """max |tau_d'| (1/K + dt) per joint: the first-order observer's tracking bound (as test_estimation's)."""
    slope = np.abs(np.diff(tau, axis=0) / np.diff(t)[:, None])
    return slope.max(axis=0) * (1.0 / K + 1e-3) + 1e-9


def test_momentum_observer_recovers_an_inertia_error():
    """Noise-free, inertias 30 % larger, no push, no touchdown in 0.4 s: once settled (t > 10 / K) the
    observer's r follows the true generalized force of the error (computed from the plant's own model) within
    the first-order lag bound max |tau_d'| (1/K + dt) on every joint; the error of 15 % larger inertias misses
    that bound on the same run (negative control)."""
    tr, taud = _inertia_error_run(INERTIAS)
    assert tr.fall is None and not any(rec.impacts for rec in tr.records)
    t, r = np.array(tr.t), np.array(tr.r)
    assert np.abs(taud[:, :5]).max(axis=0).min() > 1.0     # every joint but the swing ankle: an error worth seeing
    m = t[1:] > 10.0 / K
    err = np.abs(r[1:] - taud[:-1])[m]                       # r_k saw the torque of period k - 1
    bound = _lag_bound(taud, t)
    assert np.all(err.max(axis=0) <= bound), (err.max(axis=0), bound)
    # the error of 15 % larger inertias, at the same states and torques: not what the observer saw
    half = PlantPerturbation(torso_inertia_scale=1.15, thigh_inertia_scale=1.15, shin_inertia_scale=1.15,
                             foot_inertia_scale=1.15)
    nom, plant = FixedFootModel(DESC), FixedFootModel(half.apply(DESC))
    other = []
    for q, qd, g in zip(tr.q, tr.qd, tr.torque):
        dn, dp = nom.dynamics(q, qd), plant.dynamics(q, qd)
        other.append(dn.A @ np.linalg.solve(dp.A, g - dp.H) + dn.H - g)
    other = np.array(other)
    assert not np.all(np.abs(r[1:] - other[:-1])[m].max(axis=0) <= bound)


# ------------------------------------------------------------------------------ identification
def _identify(perturbation, pushes=(), steps=2, python_sensing=True, **extra):
    tr = closed_loop(1.2, perturbation, pushes=pushes, steps=steps, python_sensing=python_sensing,
                     momentum_observer=True, momentum_observer_gain=K, model_error_estimator=True, **extra)
    return tr, tr.ctrl._sensing.me


CHI2_6_999 = 22.458     # chi-square quantile, 6 degrees of freedom, 0.999


def _mahalanobis(x: np.ndarray, P: np.ndarray) -> float:
    return float(x @ np.linalg.solve(P, x))


def test_leg_error_identified_in_a_noise_free_walk():
    """Two steps, noise-free, the legs' masses and inertias off (LEGS): the estimate is consistent with the
    truth by its own covariance ((theta - truth)' P^-1 (theta - truth) under the 0.999 chi-square quantile, 6
    degrees of freedom), the thigh's and shin's uncertainties shrank below the prior, and the estimate is not
    consistent with "no error" (negative control); on the nominal plant it is consistent with 0."""
    tr, me = _identify(LEGS)
    assert tr.fall is None and me.updates > 500
    truth = _theta_true(LEGS)
    cfg = load_controller_config(mode="both")
    sd = np.sqrt(np.diag(me.P))
    assert np.all(sd[:4] < prior_std(DESC, cfg.model_mass_uncertainty, cfg.model_inertia_uncertainty)[:4])
    assert _mahalanobis(me.theta - truth, me.P) < CHI2_6_999, (me.theta, truth, sd)
    assert _mahalanobis(me.theta, me.P) > CHI2_6_999, (me.theta, sd)
    assert np.sign(me.theta[1]) == np.sign(truth[1]) and np.sign(me.theta[3]) == np.sign(truth[3])
    tr0, me0 = _identify(None)
    assert tr0.fall is None
    assert _mahalanobis(me0.theta, me0.P) < CHI2_6_999, me0.theta


def test_a_push_on_the_torso_does_not_leak_into_the_legs():
    """Nominal plant, a 200 N push on the torso for 50 ms in the first step: the swing leg's rows do not
    see it, so theta stays consistent with 0 by its own covariance, and the torso wrench carries the push
    (F_x within 5 % of it once the observer has settled)."""
    tr, me = _identify(None, pushes=[(0.20, 0.05, 200.0)], steps=2)
    assert tr.fall is None
    assert _mahalanobis(me.theta, me.P) < CHI2_6_999, me.theta
    t = np.array(tr.t)
    Fx = np.array([w.W[0] for w in tr.wrench])
    inside = (t > 0.20 + 10.0 / K) & (t < 0.25)
    assert np.all(np.abs(Fx[inside] - 200.0) < 10.0), Fx[inside]


def test_compiled_pipeline_with_the_estimator_equals_the_python_one():
    """The same closed loop (inertias 30 % larger, one touchdown) with the compiled pipeline and with the
    Python cores: the same theta and torques to round-off; the compiled run without the estimator differs
    (negative control)."""
    py, me_py = _identify(INERTIAS, steps=2, python_sensing=True)
    fast, me_fast = _identify(INERTIAS, steps=2, python_sensing=False)
    assert len(set(py.stance)) == 2                 # a touchdown inside
    n = min(len(py.sent), len(fast.sent))
    assert n > 400
    d = max(np.abs(a - b).max() for a, b in zip(py.sent[:n], fast.sent[:n]))
    assert d < 1e-6, d
    assert np.abs(me_py.theta - me_fast.theta).max() < 1e-8 * max(1.0, np.abs(me_py.theta).max())
    off = closed_loop(1.2, INERTIAS, steps=2, python_sensing=False, momentum_observer=True, momentum_observer_gain=K)
    m = min(n, len(off.sent))
    assert max(np.abs(a - b).max() for a, b in zip(fast.sent[:m], off.sent[:m])) > 1e-3


# ------------------------------------------------------------------------------ settings
def test_settings_rejected_by_name():
    with pytest.raises(ControllerConfigError, match="model_error_estimator needs"):
        load_controller_config(mode="both", model_error_estimator=True, momentum_observer=False)
    for name in ("model_mass_uncertainty", "model_inertia_uncertainty", "model_error_residual_std"):
        with pytest.raises(ControllerConfigError, match=name):
            load_controller_config(mode="both", model_error_estimator=True, momentum_observer=True, **{name: 0.0})
        with pytest.raises(ModelErrorConfigError, match=name):
            LegModelError(DESC, K, regressor_input="measured", settle=3.0,
                          **{"mass_uncertainty": 0.2, "inertia_uncertainty": 0.2, "residual_std": 0.5,
                                      {"model_mass_uncertainty": "mass_uncertainty",
                                       "model_inertia_uncertainty": "inertia_uncertainty",
                                       "model_error_residual_std": "residual_std"}[name]: float("nan")})
    # off (the default): the value of these settings does not matter and is not checked
    cfg = load_controller_config(mode="both", model_mass_uncertainty=0.0)
    assert cfg.model_error_estimator is False


# ------------------------------------------------------------------------------ survival under model error
def test_survival_under_model_error_takes_the_band_of_the_unpushed_walk():
    """The survival rule (trial.survival): a run ending 1.3 mm short of p_d is back when the unpushed walk
    of the same settings settles 1.2 mm short (its band: k x 1.2 mm), and not when the unpushed walk
    settles at p_d (the floors: negative control). No rule of its own for model error."""
    from types import SimpleNamespace
    from biped_controller.studies.trial import context as tcontext
    from biped_controller.studies.trial import survival as surv
    from biped_controller.closed_loop.runner import RunResult
    p_d = tcontext.context().family.p_d
    impacts = [SimpleNamespace(t=0.3 + 0.46 * k) for k in range(11)]

    def result(dp):
        return RunResult(records=[], statuses=[SimpleNamespace(t=5.0, p=p_d + dp, tau_dot=1.0)], steps_walked=11,
                         fallen=False, fall_cause="", fall_detail="", fall_time=float("nan"), impacts=impacts)
    rule = surv.SurvivalRule.of(2.0, 3)
    short = rule.band_from_walk(result(-1.2e-3))
    assert rule.verdict(result(-1.3e-3), 0.2565, short) == surv.Verdict(True, False, "survived")
    at_p_d = rule.band_from_walk(result(0.0))
    v = rule.verdict(result(-1.3e-3), 0.2565, at_p_d)
    assert not v.survived and not v.fell and v.reason.startswith("p =")


# ------------------------------------------------------------------------------ under sensor noise (mebias)
REAL = dict(momentum_observer=True, state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14,
            sensor_noise_qd=5e-2, sensor_noise_pitch=1e-3, momentum_observer_gain=50.0, model_error_estimator=True)
NOISE = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, seed=0)


def _theta_track(monkeypatch, t_end, perturbation, **extra):
    """A closed loop (compiled pipeline) keeping the estimator's (theta, P) after every sample: from
    ``LegModelError.update`` when the estimator runs in Python after the compiled call (the reference
    regressor), from the pipeline's state after each sample when it runs inside the call (the measured one)."""
    from biped_controller.core.sensing.pipeline_compiled import CompiledSensing
    hist = []
    orig, orig_sense = LegModelError.update, CompiledSensing.sense

    def update(self, *a, **k):
        w = orig(self, *a, **k)
        hist.append((self.theta.copy(), self.P.copy()))
        return w

    def sense(self, *a, **k):
        out = orig_sense(self, *a, **k)
        if self.me_on and not self._me_python:
            hist.append((self.me.theta, self.me.P))
        return out

    monkeypatch.setattr(LegModelError, "update", update)
    monkeypatch.setattr(CompiledSensing, "sense", sense)
    tr = closed_loop(t_end, perturbation, python_sensing=False, **{**REAL, **extra})
    monkeypatch.setattr(LegModelError, "update", orig)
    monkeypatch.setattr(CompiledSensing, "sense", orig_sense)
    return tr, hist


def test_theta_unbiased_under_noise_on_the_nominal_plant(monkeypatch):
    """Nominal plant, real-sensor profile (5e-4 rad, 5e-2 rad/s, 14 bits, K = 50), seed 0, the first step
    (0.35 s): with the settling time after the observer's start (``model_error_settle``, the default) theta
    stays consistent with 0 by its own covariance in every period (theta' P^-1 theta under the 0.999
    chi-square quantile, 6 degrees of freedom); the previous update (settle 0) leaves that bound in the same
    run (negative control: the start transient read as a leg error, 8 posterior std on the thigh's mass at
    0.1 s). Both with the measured regressor (the default) and with the reference one."""
    cfg = load_controller_config(mode="both")
    assert cfg.model_error_settle > 0 and cfg.model_error_regressor == "measured"
    worst = {}
    for name, extra in (("new", {}), ("new, reference", {"model_error_regressor": "reference"}),
                        ("old", {"model_error_settle": 0.0})):
        tr, hist = _theta_track(monkeypatch, 0.35, NOISE, **extra)
        assert tr.fall is None and len(hist) > 300
        worst[name] = max(_mahalanobis(th, P) for th, P in hist)
    assert worst["new"] < CHI2_6_999, worst
    assert worst["new, reference"] < CHI2_6_999, worst
    assert worst["old"] > CHI2_6_999, worst


def test_a_held_sample_leaves_theta_and_P_unchanged():
    """Within the settling time the RLS gets a residual variance of HOLD_VARIANCE: theta and P stay bit for bit
    while the filtered regressor still runs; the first sample after it updates them (negative control)."""
    from biped_controller.core.sensing.momentum_observer import Wrench
    me = LegModelError(DESC, 50.0, 0.2, 0.2, 0.5, regressor_input="measured", settle=3.0)
    rng = np.random.default_rng(7)
    q, qd, a = next(_states(1, 5))
    obs = lambda: Wrench(r=rng.normal(0, 1.0, 6), W=np.zeros(3), cov_W=np.eye(3), dR=np.zeros(2),  # noqa: E731
                         cov_dR=np.eye(2), S=np.hstack([np.eye(2), np.zeros((2, 1))]))
    Jj = np.hstack([np.eye(3), np.eye(3)])
    me.update(q, qd, None, True, 1e-3, obs(), np.zeros(3), 0.0, Jj, None)          # the restart
    th0, P0 = me.theta.copy(), me.P.copy()
    for k in range(1, 60):                                                          # since < 3 / K = 0.06 s
        me.update(q, qd, rng.normal(0, 5, 6), False, 1e-3, obs(), np.zeros(3), k * 1e-3, Jj, None)
    assert np.array_equal(me.theta, th0) and np.array_equal(me.P, P0) and me.updates == 0
    assert np.abs(me._Yf).max() > 0
    me.update(q, qd, rng.normal(0, 5, 6), False, 1e-3, obs(), np.zeros(3), 0.061, Jj, None)
    assert me.updates == 1 and not np.array_equal(me.theta, th0)


def test_reference_at_is_the_controllers_reference():
    """``AdaptiveController.reference_at`` (what the reference regressor is fed), noise-free walk through a
    touchdown: q_d' is the central difference of q_d over +-0.05 ms (to 1e-6 of |q_d'|), q_d'' that of q_d'
    (to 1e-4 of its size), and q_d is within 5e-3 rad of the true state at every period (the tracking error),
    while the reference 20 ms later is not (negative control)."""
    tr = closed_loop(0.6, None, steps=2, python_sensing=False, momentum_observer=True, momentum_observer_gain=K,
                     model_error_estimator=True, model_error_regressor="reference")
    ctrl = tr.ctrl
    assert ctrl._sensing.reference_source is not None and len(set(tr.stance)) == 2
    h = 5e-5
    qd_d = ctrl.reference_at(tr.t[-1] + 5e-4, tr.stance[-1])
    lo, hi = (ctrl.reference_at(tr.t[-1] + 5e-4 + s, tr.stance[-1]) for s in (-h, h))
    assert np.abs((hi[0] - lo[0]) / (2 * h) - qd_d[1]).max() < 1e-6 * np.abs(qd_d[1]).max()
    assert np.abs((hi[1] - lo[1]) / (2 * h) - qd_d[2]).max() < 1e-4 * np.abs(qd_d[2]).max()
    # the live run: the sample's instant against the true state (the log keeps the last decisions only, so
    # replay a fresh controller step by step)
    from biped_controller.core.control.controller import AdaptiveController
    from biped_model.gait_family import GaitFamily
    from biped_sim.plant.rigid import Simulator
    from biped_model.description import LEFT
    fam = GaitFamily.load()
    sim = Simulator(DESC)
    c = AdaptiveController(load_controller_config(mode="both", momentum_observer=True, momentum_observer_gain=K,
                                                  model_error_estimator=True, model_error_regressor="reference"),
                           fam, DESC)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    c.reset(LEFT)
    err, late = 0.0, 0.0
    while sim.impact_count < 1 and sim.fall is None:
        obs = sim.observe()
        ref = c.reference_at(obs.t, obs.stance)
        err = max(err, np.abs(ref[0] - obs.q).max())
        late = max(late, np.abs(c.reference_at(obs.t + 0.02, obs.stance)[0] - obs.q).max())
        sim.step(c.compute(obs.t, obs.q, obs.qd, obs.stance).torque)
    assert err < 5e-3, err
    assert late > 5e-3, late


def test_regressor_choice_and_settle_rejected_by_name():
    for name, bad in (("model_error_regressor", "smoothed"), ("model_error_settle", -1.0),
                      ("model_error_settle", float("nan"))):
        with pytest.raises(ControllerConfigError, match=name):
            load_controller_config(mode="both", model_error_estimator=True, momentum_observer=True, **{name: bad})
    with pytest.raises(ControllerConfigError, match="model_error_regressor"):
        load_controller_config(mode="lambda", model_error_estimator=True, momentum_observer=True,
                               model_error_regressor="reference")
    with pytest.raises(ModelErrorConfigError, match="model_error_regressor"):
        LegModelError(DESC, K, 0.2, 0.2, 0.5, regressor_input="smoothed", settle=3.0)
    with pytest.raises(ModelErrorConfigError, match="model_error_settle"):
        LegModelError(DESC, K, 0.2, 0.2, 0.5, regressor_input="measured", settle=-1.0)


def test_reference_regressor_identifies_the_legs_error_noise_free():
    """The reference regressor (the instrument) on the noise-free LEGS walk of
    ``test_leg_error_identified_in_a_noise_free_walk``: consistent with the truth by its own covariance (0.999
    chi-square, 6 dof) and not with "no error" (negative control); the tracking error it neglects costs less
    than the bound."""
    tr, me = _identify(LEGS, model_error_regressor="reference")
    assert tr.fall is None and me.regressor_input == "reference" and me.updates > 500
    truth = _theta_true(LEGS)
    assert _mahalanobis(me.theta - truth, me.P) < CHI2_6_999, (me.theta, truth)
    assert _mahalanobis(me.theta, me.P) > CHI2_6_999, me.theta
