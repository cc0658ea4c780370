"""The capture-point step adjuster: its registration, its law, and its walk on the rigid plant.

Oracles: the LIP identities of the module docstring evaluated here from the preferred gait (the law puts
the foot at p_d on it), the registry (the entry point installed with the package), and the plant (the
walk's touchdowns and its return to p_d, tau' = 1).
"""
from __future__ import annotations

import importlib.metadata as md
import math

import numpy as np
import pytest

from biped_controller.plugin import loop as plugin_loop
from biped_controller.plugin.registry import ENTRY_POINT_GROUP, load_controller
from biped_controller.plugin.study import PushTrials
from biped_sim.plant.push import Push

from capture_point_stepper import CapturePointStepper
from capture_point_stepper.controller import StepperSettingsError


def _installed() -> bool:
    return any(ep.name == "capture_point" for ep in md.entry_points(group=ENTRY_POINT_GROUP))


@pytest.fixture(scope="module")
def stepper():
    return CapturePointStepper(plugin_loop.PluginLoop("none").setup)


@pytest.mark.skipif(not _installed(), reason="the package is not pip-installed (pip install -e examples/capture_point_stepper)")
def test_registered_through_the_entry_point():
    assert load_controller("capture_point") is CapturePointStepper


def test_the_law_lands_on_p_d_on_the_preferred_gait(stepper):
    fam = stepper.family
    for tau in (0.0, 0.1, 0.2315, 0.35):
        g = fam.evaluate(fam.p_d, tau)
        c, J, _ = stepper.model.com_terms(g.q, g.dq_dtau)
        xi = c[0] + (J @ g.dq_dtau)[0] / stepper.omega
        assert abs(stepper.stride_at(xi, tau, fam.T - tau) - fam.p_d) < 1e-6
        p, t_r, adapted = stepper._targets(xi, tau, tau)
        assert (p, t_r, adapted) == (fam.p_d, fam.T - tau, False)
    assert math.isclose(stepper.omega, math.sqrt(9.81 / stepper.z_c), rel_tol=1e-3)


def test_a_forward_dcm_error_lengthens_the_step_then_shortens_its_time(stepper):
    fam, tau = stepper.family, 0.2315
    g = fam.evaluate(fam.p_d, tau)
    c, J, _ = stepper.model.com_terms(g.q, g.dq_dtau)
    xi = c[0] + (J @ g.dq_dtau)[0] / stepper.omega
    p1, t1, a1 = stepper._targets(xi + 0.02, tau, tau)
    assert fam.p_d < p1 < fam.p_max and not a1
    assert math.isclose(p1 - fam.p_d, 0.02 * math.exp(stepper.omega * (fam.T - tau)) - stepper.s.dead_band, rel_tol=1e-9)
    p2, t2, a2 = stepper._targets(xi + 0.2, tau, tau)     # beyond the range at the preferred timing
    assert a2 and t2 < fam.T - tau and p2 <= fam.p_max


def test_unknown_option_is_named():
    setup = plugin_loop.PluginLoop("none").setup
    from dataclasses import replace
    with pytest.raises(StepperSettingsError, match="no_such"):
        CapturePointStepper(replace(setup, options={"no_such": 1.0}))


def test_walks_undisturbed_on_the_rigid_plant():
    res = plugin_loop.run("capture_point_stepper.controller:CapturePointStepper", steps=6)
    assert res.fault is None and not res.fallen and res.steps_walked == 6
    T = res.impacts[0].t
    durations = np.diff([0.0] + [i.t for i in res.impacts])
    assert np.all(np.abs(durations - durations[0]) < 0.02 * T)
    last = res.statuses[-1]
    assert abs(last["p"] - 0.463) <= 1e-3 and abs(last["tau_dot"] - 1.0) <= 1e-3


def test_survives_a_push_mode_none_does_not():
    trials = PushTrials("capture_point_stepper.controller:CapturePointStepper")
    r = trials.survives(100.0)
    assert r["survived"], r
    pushed = plugin_loop.run("capture_point_stepper.controller:CapturePointStepper", steps=4,
                             pushes=(Push(0.2315, 0.025, 100.0),))
    assert max(s["p_target"] for s in pushed.statuses) > 0.463 + 0.01     # it stepped further
