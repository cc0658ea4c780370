"""What the DCM step layer of ``dcm_wbc`` compares the measured DCM with: one variant that changes only that.

Question (docs/step_layer.md, "Why it loses"): ``dcm_wbc`` falls two to three steps after a push it has
survived, with its DCM error growing from step to step. Is the cause that the layer compares the measured DCM
xi [m] with the *preferred* step's DCM xi_n(tau) (the table along q_d(p_d, .) at tau' = 1), while its own
outputs p and tau' change the reference's speed, so that the layer reads its own command as a DCM error?

:class:`CommandedDcm` is ``dcm_wbc`` with that one thing changed: the DCM it compares xi with (in the dead band,
the step location law and the reported ``dcm_error``) is the DCM of the reference it commands,

    xi_r = x_r + x_r' / omega,   x_r = x_G(q_d(p, tau)),   x_r' = J_G(q_d) (dq/dp p' + dq/dtau tau')   [m],

at the period's p [m], p' [m/s], tau [s] (held to [0, T]) and tau' [-]; with p = p_d, tau' = 1 it is xi_n(tau).
Everything else (omega, the offset law, the timing, the gains, the whole-body QP, the observer, the settings)
is ``dcm_wbc``'s. Run it by its ``module:Class`` name from the repository root, e.g.

    .venv/bin/python -m biped_controller.studies.controllers max-push lab.step_layer_causes:CommandedDcm --max 800 \\
        --json results/step_layer/causes/commanded_dcm_paper_cell_rigid.json
"""
from __future__ import annotations

from biped_controller.plugin.step_layer import DcmStepLayer, DcmWholeBody


class _CommandedLayer(DcmStepLayer):
    """The layer with xi_n(tau) replaced by the commanded reference's DCM at the controller's (p, p', tau')."""

    ctrl: "CommandedDcm"

    def xi_n(self, tau: float) -> float:
        c = self.ctrl
        g = self.ref.at(c.p, min(max(float(tau), 0.0), self.T))
        st = c.model.com_state(g.q, g.dq_dp * c.p_dot + g.dq_dtau * c.tau_dot)
        return float(st.position[0] + st.velocity[0] / self.omega)


class CommandedDcm(DcmWholeBody):
    """``dcm_wbc`` whose DCM error is measured against the commanded reference's DCM (module docstring)."""

    description = "dcm_wbc with the DCM error taken against the commanded reference's DCM (lab.step_layer_causes)"

    def __init__(self, setup):
        super().__init__(setup)
        lay = self.layer
        self.layer = _CommandedLayer.__new__(_CommandedLayer)
        self.layer.__dict__.update(lay.__dict__)
        self.layer.ctrl = self
