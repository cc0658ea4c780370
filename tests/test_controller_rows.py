"""The controller's robust QP rows (eq. 21): the push estimate only shifts the reaction offset h_b, so the
rows without the estimate (second block of 17) equal a full evaluation of the rows with dyn instead of
dyn_c; and without an estimate the two blocks coincide."""
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
        ctrl.state.tau = tau
        ref = ctrl._reference(q, qd)
        dyn = ctrl.model.dynamics(q, qd)
        Jp = ctrl.model.torso_point_jacobian(q, c.observer_height)[0]
        F = rng.uniform(-500, 500)
        delta = dyn.B @ np.linalg.solve(dyn.A, Jp[3:] * F) - Jp[:3] * F
        dyn_c = replace(dyn, h_b=dyn.h_b + delta)
        G, h = ctrl._qp_rows(ref, dyn, dyn_c)         # blocks: with estimate, without it, ranges
        G_full0, h_full0 = ctrl._qp_rows(ref, dyn, dyn)  # both blocks from dyn
        assert np.array_equal(G[:17], G[17:34])
        assert np.max(np.abs(h[17:34] - h_full0[:17])) <= 1e-9 * (1 + np.max(np.abs(h_full0[:17])))
        assert np.array_equal(h_full0[:17], h_full0[17:34])
        if abs(F) > 1.0:   # the estimate matters: the first block differs from the no-estimate one
            assert not np.allclose(h[:17], h[17:34])
