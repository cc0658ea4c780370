"""The controller's robust QP rows (eq. 21): the push estimate only shifts the reaction offset h_b, so the
rows without the estimate (second block of 17) equal a full evaluation of the rows with dyn instead of
dyn_c; and without an estimate the two blocks coincide."""
from dataclasses import replace

import numpy as np

from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_model.gait_family import GaitFamily


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


def test_gait_optimizer_uses_the_contact_rows_of_the_model():
    """The gait optimizer's contact margins are model.contact_rows (eqs. 5-8, written once), with its own
    margins (mu, l range, R_y >= min_normal_force M g) and its row order take_off, slide_forward,
    slide_backward, zmp_heel, zmp_toe."""
    from biped_controller.gaits.optimizer import StepOptimizer
    from biped_model.fixed_foot import contact_rows
    o = StepOptimizer()
    st = o.st
    Mg = o.M * o.g
    C, e = contact_rows(st.friction_use * o.desc.mu, o.desc.foot.l_min + st.zmp_margin,
                        o.desc.foot.l_max - st.zmp_margin)
    scale = np.concatenate([[Mg] * 3, [0.1 * Mg] * 2])
    rng = np.random.default_rng(3)
    for _ in range(20):
        tau9 = rng.normal(scale=[50, 400, 20, 30, 30, 30, 30, 30, 30])
        got = (o.C @ tau9 + o.d)[:5] * scale
        want = -(C @ tau9[:2] + e * tau9[3])[[0, 2, 1, 3, 4]]
        want[0] -= st.min_normal_force * Mg
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)
