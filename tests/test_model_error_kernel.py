"""Cost: the legs' model-error estimator inside the compiled sensing call. Its closed-form regressor
(``model_error_kernels.regressor_into`` through ``CompiledLegRegressor``) against Pinocchio's joint torque
regressor (``LegRegressor``) and the RNEA differences of seven models (``RneaLegRegressor``); the whole
estimator in the kernel (``model_error_kernels.update`` from ``pipeline_kernels.sense_finish``) against
``LegModelError`` run in Python after the compiled call, period by period in a closed loop."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from biped_model.description import LEFT, load_description
from biped_model.fast_engine import fixed_foot_tree
from biped_model.fixed_foot import relabel
from biped_model.gait_family import GaitFamily
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.rigid import Simulator

from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.sensing.pipeline_layout import SC_
from biped_controller.core.sensing.model_error import (LEG_PARAMETERS, CompiledLegRegressor, LegRegressor,
                                                RneaLegRegressor, body_combination)

DESC = load_description()
INERTIAS = PlantPerturbation(torso_inertia_scale=1.3, thigh_inertia_scale=1.3, shin_inertia_scale=1.3,
                             foot_inertia_scale=1.3)


def _states(n: int, seed: int):
    """Seeded (q, q', q'') [rad, rad/s, rad/s^2] over a walking range (knees bent) and beyond."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield (rng.uniform(-0.6, 0.6, 6) + np.array([0.0, 0.3, 0.0, 0.0, 0.3, 0.0]), rng.normal(0, 1.5, 6),
               rng.normal(0, 20.0, 6))


def _worst(reg, oracle, seed: int, n: int = 30) -> float:
    """max |Y - Y_oracle| / max |Y_oracle| over seeded states in both stances (the second: the first's state
    relabelled, q -> -q[::-1], the chain that then carries the other leg)."""
    worst = 0.0
    for q, qd, a in _states(n, seed):
        for s in ((q, qd, a), (relabel(q), relabel(qd), relabel(a))):
            Y0 = oracle(*s)
            worst = max(worst, np.abs(reg(*s) - Y0).max() / np.abs(Y0).max())
    return worst


def test_closed_form_regressor_equals_pinocchios_and_the_rnea_differences():
    """The closed form equals Pinocchio's joint torque regressor combined by ``parameter_bumps`` and the RNEA
    differences of the seven models to 1e-12 relative on all 9 rows (root x, z, pitch and the six joints),
    at 30 seeded states in both stances; the same interface (9 x 6, float)."""
    fast = CompiledLegRegressor(DESC)
    q, qd, a = next(_states(1, 0))
    Y = fast(q, qd, a)
    assert Y.shape == (9, len(LEG_PARAMETERS)) and Y.dtype == np.float64
    assert _worst(fast, LegRegressor(DESC), 11) < 1e-12
    assert _worst(fast, RneaLegRegressor(DESC), 12) < 1e-12


def test_closed_form_regressor_negative_controls():
    """Each detected against Pinocchio's regressor (> 1e-3 relative): the tree of a thigh 1 cm longer; the
    thigh's and shin's mass columns swapped in the combination D; the swing leg's bodies left out of D."""
    oracle = LegRegressor(DESC)
    longer = dataclasses.replace(DESC, thigh=dataclasses.replace(DESC.thigh, length=DESC.thigh.length + 0.01))
    cases = {"thigh 1 cm longer": CompiledLegRegressor(longer)}
    swapped = CompiledLegRegressor(DESC)
    swapped.D = swapped.D[:, [2, 1, 0, 3, 4, 5]].copy()
    cases["thigh and shin mass columns swapped"] = swapped
    one_leg = CompiledLegRegressor(DESC)
    names = [b.name for b in fixed_foot_tree(DESC).bodies]
    nb = len(names)
    for i, n in enumerate(names):
        if n.startswith("swing_"):
            one_leg.D[i] = 0.0
            one_leg.D[nb + i] = 0.0
    cases["swing leg left out"] = one_leg
    for name, reg in cases.items():
        assert _worst(reg, oracle, 13, n=10) > 1e-3, name


def test_body_combination_names_the_missing_body():
    bodies = [b for b in fixed_foot_tree(DESC).bodies if b.name != "swing_shin"]
    with pytest.raises(ValueError, match="swing_shin"):
        body_combination(bodies)


PERFECT = dict(momentum_observer=True, momentum_observer_gain=200.0)
REAL = dict(momentum_observer=True, state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14,
            sensor_noise_qd=5e-2, sensor_noise_pitch=1e-3, momentum_observer_gain=50.0)


def _walk(kernel: bool, seconds: float = 1.2, steps: int = 2, tweak=None, over=PERFECT, plant=INERTIAS):
    """A closed loop on the rigid plant (default: inertias 30 % larger; perfect sensors, K = 200, the compiled
    pipeline with the legs' estimator) with the estimator in the kernel or in Python after it; per period
    theta, P, the combined wrench's W, dR, cov_dR and the torque sent."""
    fam = GaitFamily.load()
    sim = Simulator(DESC, perturbation=plant)
    ctrl = AdaptiveController(load_controller_config(mode="both", model_error_estimator=True, **over), fam, DESC)
    sens = ctrl._sensing
    sens.use_model_error_kernel(kernel)
    if tweak is not None:
        tweak(sens)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    rows = {"theta": [], "P": [], "W": [], "dR": [], "cov_dR": [], "torque": [], "stance": []}
    while sim.t < seconds and sim.fall is None and sim.impact_count < steps:
        o = sim.observe()
        out = ctrl.compute(o.t, o.q, o.qd, o.stance, o.pitch)
        w = ctrl.wrench
        for k, v in (("theta", sens.me.theta), ("P", sens.me.P), ("W", w.W), ("dR", w.dR), ("cov_dR", w.cov_dR),
                     ("torque", out.torque), ("stance", o.stance)):
            rows[k].append(np.array(v, dtype=float))
        sim.step(out.torque)
    return {k: np.array(v) for k, v in rows.items()}, sens.me.updates, sim.fall


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def test_estimator_in_the_kernel_equals_the_python_estimator_period_by_period():
    """The same walk (inertias 30 % larger, a touchdown inside) with the estimator inside the compiled call and
    with ``LegModelError`` (Pinocchio's regressor, NumPy's inverse) after it: theta, P, the torso wrench, dR,
    cov_dR and the torques equal to 1e-9 relative in every period, the same number of updates (the settling
    time after each restart of the observer, ``model_error_settle``, included). Negative controls, theta off by
    more than 1e-6 relative: the kernel's residual variance 1 % off; the kernel without the settling time."""
    fast, n_fast, fall = _walk(True)
    py, n_py, _ = _walk(False)
    assert fall is None and len(set(fast["stance"].astype(int))) == 2    # a touchdown inside
    n = len(py["theta"])
    assert len(fast["theta"]) == n and n > 900 and n_fast == n_py > 800
    assert np.abs(fast["theta"][-1]).max() > 1e-3                        # something was identified
    for k in ("theta", "P", "W", "dR", "cov_dR", "torque"):
        assert _rel(fast[k], py[k]) < 1e-9, (k, _rel(fast[k], py[k]))

    def off(sens):
        sens.conf[SC_.me_var_res] *= 1.01

    def no_settle(sens):                # the kernel without the settling time after the observer's restarts
        sens.conf[SC_.me_settle] = 0.0
    assert load_controller_config(mode="both").model_error_settle > 0
    for tweak in (off, no_settle):
        wrong, _, _ = _walk(True, tweak=tweak)
        m = min(len(wrong["theta"]), n)
        assert _rel(wrong["theta"][:m], py["theta"][:m]) > 1e-6, tweak.__name__


@pytest.mark.parametrize("profile", ["real_sensors", "delay_2"])
def test_estimator_in_the_kernel_equals_the_python_one_on_the_other_profiles(profile):
    """The same comparison on the real-sensor profile (Kalman estimator + observer K = 50 under 5e-4 rad,
    5e-2 rad/s, 14 bits, seed 0: the rate covariance from the estimator) and with a delay of 2 periods and the
    predictor (the delayed samples' bookkeeping in Python, the estimator on the sample in the kernel, legs'
    inertias 30 % larger): theta and the torques to 1e-9 relative in every period through a touchdown."""
    if profile == "real_sensors":
        over, plant = REAL, PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14)
    else:
        over = dict(momentum_observer=True, momentum_observer_gain=200.0, delay_compensation=2)
        plant = PlantPerturbation(delay=2, thigh_inertia_scale=1.3, shin_inertia_scale=1.3)
    fast, n_fast, fall = _walk(True, over=over, plant=plant)
    py, n_py, _ = _walk(False, over=over, plant=plant)
    assert fall is None and len(set(fast["stance"].astype(int))) == 2
    assert len(fast["theta"]) == len(py["theta"]) > 900 and n_fast == n_py
    assert np.abs(fast["theta"][-1]).max() > 1e-3
    for k in ("theta", "torque"):
        assert _rel(fast[k], py[k]) < 1e-9, (k, _rel(fast[k], py[k]))
