"""The controller's robust QP rows: the push estimate only shifts the reaction offset h_b, so the
rows without the estimate equal a full re-evaluation of the constraints without it."""
from dataclasses import replace

import numpy as np

import helpers  # noqa: F401  (puts src/ on the path when the packages are not installed)
from biped_controller.controller import AdaptiveController, load_controller_config
from biped_sim.gait_family import GaitFamily


def test_rows_without_estimate_equal_full_evaluation():
    ctrl = AdaptiveController(load_controller_config(mode="both"))
    fam = GaitFamily.load()
    rng = np.random.default_rng(7)
    c = ctrl.cfg
    for _ in range(50):
        tau = rng.uniform(0, fam.T)
        g = fam.evaluate(fam.p_d, tau)
        q = g.q + rng.normal(scale=0.02, size=6)
        qd = g.dq_dtau + rng.normal(scale=0.2, size=6)
        dyn = ctrl.model.dynamics(q, qd)
        Jp = ctrl.model.torso_point_jacobian(q, c.observer_height)[0]
        F = rng.uniform(-500, 500)
        delta = dyn.B @ np.linalg.solve(dyn.A, Jp[3:] * F) - Jp[:3] * F
        dyn_c = replace(dyn, h_b=dyn.h_b + delta)
        A, b, _ = ctrl._constraint_rows(q, qd, dyn_c)
        A0, b0_full, _ = ctrl._constraint_rows(q, qd, dyn)
        b0 = ctrl._offsets_without_estimate(b, dyn, dyn_c)
        assert np.array_equal(A, A0)
        assert np.max(np.abs(b0 - b0_full)) <= 1e-9 * (1 + np.max(np.abs(b0_full)))
