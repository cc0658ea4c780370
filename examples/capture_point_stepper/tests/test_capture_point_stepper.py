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
from biped_controller.studies.trial.plugin_trials import PushTrials
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
    """On q_d(p_d, .) at the preferred timing the foot goes to p_d (to the tabulation's linear
    interpolation error, 401 points over T: a few micrometres)."""
    fam = stepper.ref
    for tau in (0.0, 0.1, 0.2315, 0.35):
        g = fam.at(fam.p_d, tau)
        com = stepper.model.com_terms(g.q, g.dq_dtau)
        xi = com.position[0] + (com.jacobian @ g.dq_dtau)[0] / stepper.omega
        assert abs(stepper.stride_at(xi, tau, fam.T - tau) - fam.p_d) < 1e-5
        p, t_r, adapted = stepper._targets(xi, tau, tau)
        assert abs(p - fam.p_d) < 1e-5 and abs(t_r - (fam.T - tau)) < 1e-5
    assert math.isclose(stepper.omega, math.sqrt(9.81 / stepper.z_c), rel_tol=1e-3)


def test_a_forward_dcm_error_lengthens_the_step_and_shortens_its_time(stepper):
    """The weighted law's optimality condition w_u xi (u - p_d) + w_t (sigma - sigma_n) = 0 at its answer
    (sigma = e^{omega T_r}, xi the DCM after the dead band), and the range first for a large error."""
    fam, tau, om, s = stepper.ref, 0.2315, stepper.omega, stepper.s
    g = fam.at(fam.p_d, tau)
    com = stepper.model.com_terms(g.q, g.dq_dtau)
    xi_n = com.position[0] + (com.jacobian @ g.dq_dtau)[0] / om
    p1, t1, a1 = stepper._targets(xi_n + 0.02, tau, tau)
    assert fam.p_d < p1 < fam.p_max and t1 < fam.T - tau and a1
    xi = xi_n + 0.02 - s.dead_band
    grad = s.weight_step * xi * (p1 - fam.p_d) + s.weight_time * (math.exp(om * t1) - math.exp(om * (fam.T - tau)))
    assert abs(grad) < 1e-9
    lo = max(s.step_time_min * fam.T - tau, s.min_time_left)     # the earliest touchdown allowed
    p2, t2, a2 = stepper._targets(xi_n + 0.3, tau, tau)           # the timing at its bound, the stride inside
    assert a2 and abs(t2 - lo) < 1e-12 and p1 < p2 < fam.p_max
    p3, t3, _ = stepper._targets(xi_n + 1.0, tau, tau)            # both at their bounds
    assert abs(t3 - lo) < 1e-12 and p3 == fam.p_max
    p4, t4, _ = stepper._targets(xi_n - 0.02, tau, tau)      # backward: a shorter stride, a longer step
    assert p4 < fam.p_d and t4 > fam.T - tau


def test_the_package_needs_only_the_plug_in_package():
    """The controller's module imports nothing of the project but ``biped_controller.plugin`` (the model, the
    gains and the reference come with its ``ControllerSetup``)."""
    import ast
    from pathlib import Path

    import capture_point_stepper
    ours = ("biped_controller", "biped_model", "biped_sim")
    for path in Path(capture_point_stepper.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for n in names:
                if n.split(".")[0] in ours:
                    assert n == "biped_controller.plugin" or n.startswith("biped_controller.plugin."), (path.name, n)


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
    """50 N at the paper's cell: the step adjuster's largest survivable push (mode none: 43.75 N)."""
    trials = PushTrials("capture_point_stepper.controller:CapturePointStepper")
    r = trials.survives(50.0)
    assert r["survived"], r
    assert not trials.survives(53.125)["survived"]
    pushed = plugin_loop.run("capture_point_stepper.controller:CapturePointStepper", steps=3,
                             pushes=(Push(0.2315, 0.025, 50.0),))
    assert any(s["timing_adapted"] for s in pushed.statuses)
    assert max(s["p_target"] for s in pushed.statuses) > 0.463 and max(s["tau_dot_target"] for s in pushed.statuses) > 1
