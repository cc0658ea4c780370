"""The DCM step layer above the whole-body QP (controller ``dcm_wbc``, ``plugin/step_layer.py``).

Oracles, independent of the code under test:
- the LIP's closed forms: omega = sqrt(g / z_c) with z_c the mean CoM height of q_d(p_d, .) computed here from
  the model's centre of mass, the DCM xi = x + x'/omega from the model's CoM state, and the weighted timing's
  minimiser sigma* = (w_u xi c + w_t sigma_0) / (w_u xi^2 + w_t) (a stationary point of the cost, checked by
  its derivative, and the global minimum, checked against a grid);
- the gait family itself (``GaitFamily.evaluate`` and ``gait_family.eq11``): the reference the layer hands the
  whole-body QP is q_d(p, tau) of the family at the layer's reported p, tau, with its p', tau', p'', tau'';
- mode ``wbc`` through the same loop: with the layer's dead band infinite the controller's torques are mode
  wbc's (to round-off), pushed or not;
- the plant: a short walk stays upright on the preferred gait, and a forward push lengthens the target stride;
- the commanded reference's DCM (the adopted law, ``step_layer_commanded_dcm``): on the preferred gait it is the
  table xi_n(tau), and its velocity term is the central finite difference of the family's CoM along the
  commanded path (p + p' h, tau + tau' h).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from biped_controller.plugin import loop as plugin_loop
from biped_controller.plugin.step_layer import (DcmWholeBody, StepLayerSettings, StepLayerSettingsError,
                                                 settings_for)
from biped_model.gait_family import eq11
from biped_sim.plant.config import load_sim_config
from biped_sim.plant.push import Push

PAPER_PUSH = Push(0.2315, 0.025, 230.0)


@pytest.fixture(scope="module")
def ctrl() -> DcmWholeBody:
    return DcmWholeBody(plugin_loop.PluginLoop("none").setup)


def test_registered_under_its_name():
    from biped_controller.plugin.registry import load_controller
    assert load_controller("dcm_wbc") is DcmWholeBody


def test_omega_and_the_dcm_are_the_lip_closed_form(ctrl):
    """omega = sqrt(g / z_c), z_c the mean CoM height over the preferred step; xi = x + x'/omega; the table
    xi_n(tau) is that DCM along q_d(p_d, .) at tau' = 1."""
    ref, model, lay = ctrl.ref, ctrl.model, ctrl.layer
    taus = np.linspace(0.0, ref.T, lay.N_TABLE)
    z_c = np.mean([model.com(ref.at(ref.p_d, t).q)[1] for t in taus])
    omega = math.sqrt(model.gravity / z_c)
    assert lay.z_c == pytest.approx(z_c, rel=1e-12) and lay.omega == pytest.approx(omega, rel=1e-12)
    assert lay.dcm(0.03, -0.4) == pytest.approx(0.03 - 0.4 / omega, rel=1e-12)
    for tau in (0.0, 0.1, ref.T * 0.5, ref.T):
        g = ref.at(ref.p_d, tau)
        st = model.com_state(g.q, g.dq_dtau)
        xi = st.position[0] + st.velocity[0] / omega
        assert abs(lay.xi_n(tau) - xi) < 2e-6      # linear interpolation of the 401-point table


def test_on_the_preferred_gait_the_targets_are_the_preferred_ones(ctrl):
    """xi = xi_n(tau): p* = p_d, T_r = T - tau, tau'* = 1 (within the step-time bounds)."""
    lay, ref = ctrl.layer, ctrl.ref
    for tau in (0.0, 0.1, 0.2315, 0.3):
        tg = lay.targets(lay.xi_n(tau), tau, tau)
        assert tg.p == pytest.approx(ref.p_d, abs=1e-12)
        assert tg.time_left == pytest.approx(ref.T - tau, abs=1e-12)
        assert tg.tau_dot == pytest.approx(1.0, abs=1e-12) and not tg.timing_adapted


def test_the_timing_is_the_weighted_cost_minimiser(ctrl):
    """A forward DCM error beyond the dead band: sigma = e^{omega T_r} is the closed-form minimiser of
    w_u (u - p_d)^2 + w_t (sigma - sigma_0)^2 with u = p_d + xi sigma - c, c = xi_n sigma_n: the foot goes
    further and lands sooner; a backward error: a shorter stride, a later touchdown."""
    lay, ref, s = ctrl.layer, ctrl.ref, ctrl.s
    tau = 0.2315
    om, xn = lay.omega, lay.xi_n(tau)
    c = xn * math.exp(om * (ref.T - tau))
    sig0 = math.exp(om * (ref.T - tau))
    for err, longer in ((0.01, True), (-0.01, False)):
        tg = lay.targets(xn + err, tau, tau)
        xi = xn + math.copysign(abs(err) - s.dead_band, err)
        sig_star = (s.weight_step * xi * c + s.weight_time * sig0) / (s.weight_step * xi * xi + s.weight_time)

        def cost(sig):
            return s.weight_step * (xi * sig - c) ** 2 + s.weight_time * (sig - sig0) ** 2
        grid = np.linspace(0.5 * sig_star, 1.5 * sig_star, 2001)
        assert cost(sig_star) <= min(cost(g) for g in grid) + 1e-12
        assert tg.time_left == pytest.approx(math.log(sig_star) / om, rel=1e-12)
        assert tg.p == pytest.approx(ref.p_d + xi * sig_star - c, rel=1e-12)
        assert (tg.p > ref.p_d and tg.time_left < ref.T - tau) if longer else \
            (tg.p < ref.p_d and tg.time_left > ref.T - tau)
        assert tg.tau_dot == pytest.approx((ref.T - tau) / tg.time_left, rel=1e-12)
    inside = lay.targets(xn + 0.5 * s.dead_band, tau, tau)        # inside the dead band: no change
    assert inside.p == pytest.approx(ref.p_d, abs=1e-12) and inside.tau_dot == pytest.approx(1.0, abs=1e-12)
    far = lay.targets(xn + 1.0, tau, tau)                           # the range and the bounds hold
    assert far.p == ref.p_max and far.time_left == pytest.approx(max(s.step_time_min * ref.T - tau, s.min_time_left),
                                                                 abs=1e-12)


def _records(ctrl_or_name, steps, pushes=(), **options):
    return plugin_loop.run(ctrl_or_name, steps, pushes, options=options or None)


def test_the_reference_handed_to_the_qp_is_q_d_of_the_family(monkeypatch):
    """w* handed to the whole-body QP = q_d'' + Kv (q_d' - q') + Kp (q_d - q), with q_d(p, tau) and its rates
    from the family (``GaitFamily.evaluate``, eq. 11) at the p, p', p'', tau, tau', tau'' the controller
    reports, in every period of a pushed step, the step layer moving p and tau'."""
    L = plugin_loop.PluginLoop("dcm_wbc")
    inner = L.ctrl.inner
    assert isinstance(inner, DcmWholeBody)
    seen, states = [], []
    decide, dynamics = inner.stage.decide, inner._ff.dynamics

    def spy_decide(w_star, *a):
        seen.append(np.array(w_star))
        return decide(w_star, *a)

    def spy_dynamics(q, qd):
        states.append((np.array(q), np.array(qd)))
        return dynamics(q, qd)
    monkeypatch.setattr(inner.stage, "decide", spy_decide)
    monkeypatch.setattr(inner._ff, "dynamics", spy_dynamics)
    res = L.run(1, (Push(0.2315, 0.025, 200.0),))
    fam, g = L.family, inner.gains
    assert len(seen) == len(states) == len(res.statuses) > 400
    moved = 0
    for k, st in enumerate(res.statuses):
        q, qd = states[k]
        qr, qdr, qddr = eq11(fam.evaluate(st["p"], st["tau"]), st["p_dot"], st["tau_dot"], st["p_ddot"],
                             st["tau_ddot"])
        w = qddr + g.Kv * (qdr - qd) + g.Kp * (qr - q)
        assert np.allclose(seen[k], w, rtol=0, atol=1e-9), k
        moved += abs(st["p"] - fam.p_d) > 1e-4 and abs(st["tau_dot"] - 1.0) > 1e-4
    assert moved > 50          # the layer moved both parameters: the check covers the p, tau terms


def test_without_the_step_layer_it_is_mode_wbc():
    """Dead band 1e9 m: p* = p_d and tau'* = 1 always, so x = mode wbc's x*, and the torques are mode wbc's
    (same loop, same plant) to round-off over a step with the paper's push at wbc's own boundary."""
    a = _records("dcm_wbc", 2, (PAPER_PUSH,), dead_band=1e9)
    b = _records("wbc", 2, (PAPER_PUSH,))
    assert len(a.records) == len(b.records) > 800 and not a.fallen and not b.fallen
    d = max(float(np.max(np.abs(np.asarray(x.torque) - np.asarray(y.torque)))) for x, y in zip(a.records, b.records))
    assert d < 1e-7
    assert any(st["wbc_status"] != 0 for st in a.statuses)      # the QP acted in the push
    c = _records("dcm_wbc", 2, (PAPER_PUSH,))                    # and the layer, on, changes the run
    assert max(abs(st["p"] - 0.463) for st in c.statuses) > 1e-4
    assert max(abs(st["tau_dot"] - 1.0) for st in c.statuses) > 1e-3


def test_a_short_walk_stays_upright_on_the_preferred_gait():
    r = _records("dcm_wbc", 3)
    assert not r.fallen and r.fault is None and r.steps_walked == 3
    assert all(st["p"] == r.statuses[0]["p"] and st["tau_dot"] == 1.0 for st in r.statuses)
    assert max(abs(st["dcm_error"]) for st in r.statuses) < settings_for().dead_band


def test_a_forward_push_lengthens_the_target_stride_and_hastens_the_step(ctrl):
    """And the error it answers is measured against the commanded reference's DCM at the reported p, p', tau,
    tau' (the adopted law); with ``commanded_dcm`` off, against the preferred step's xi_n(tau) (the first law)."""
    lay = ctrl.layer
    for commanded in (True, False):
        r = _records("dcm_wbc", 2, (Push(0.2315, 0.025, 150.0),), commanded_dcm=commanded)
        assert not r.fallen
        pushed = [st for st in r.statuses if not st["step_frozen"] and st["dcm_error"] > 0.01]
        assert pushed and all(st["p_target"] > 0.463 and st["tau_dot_target"] > 1.0 for st in pushed)
        for st in r.statuses[::7]:
            ref = (lay.reference_dcm(st["p"], st["p_dot"], st["tau"], st["tau_dot"]) if commanded
                   else lay.xi_n(st["tau"]))
            assert st["dcm_error"] == pytest.approx(st["dcm"] - ref, abs=1e-12)
        if commanded:
            moved = [st for st in r.statuses if abs(st["tau_dot"] - 1.0) > 0.01]
            assert moved and max(abs(lay.reference_dcm(st["p"], st["p_dot"], st["tau"], st["tau_dot"])
                                     - lay.xi_n(st["tau"])) for st in moved) > 1e-3   # the two laws differ here


def test_the_commanded_reference_dcm_is_the_family_com_s(ctrl):
    """xi_r(p_d, 0, tau, 1) = xi_n(tau) (the table, to its interpolation); off the preferred gait
    xi_r = x_G + x_G' / omega with x_G' the central difference of the family's CoM along (p + p' h, tau + tau' h)."""
    lay, ref, model = ctrl.layer, ctrl.ref, ctrl.model
    for tau in (0.0, 0.1, 0.2315, ref.T):
        assert abs(lay.reference_dcm(ref.p_d, 0.0, tau, 1.0) - lay.xi_n(tau)) < 2e-6
    h = 1e-6
    for p, p_dot, tau, tau_dot in ((0.48, 0.3, 0.12, 1.4), (0.44, -0.2, 0.3, 0.8)):
        x = model.com(ref.at(p, tau).q)[0]
        dx = (model.com(ref.at(p + p_dot * h, tau + tau_dot * h).q)[0]
              - model.com(ref.at(p - p_dot * h, tau - tau_dot * h).q)[0]) / (2 * h)
        assert lay.reference_dcm(p, p_dot, tau, tau_dot) == pytest.approx(x + dx / lay.omega, abs=1e-7)


def test_the_command_line_reads_switches_and_numbers(capsys):
    """``--option whole_body=false`` is a switch (the run without the whole-body QP), a number stays a number,
    another word is passed on as text (a plug-in's file name), which the step layer refuses naming its key."""
    from biped_controller.plugin.step_layer import StepLayerSettingsError
    from biped_controller.studies.controllers import _option, main
    assert _option("whole_body=false") == ("whole_body", False) and _option("commanded_dcm=True") == ("commanded_dcm", True)
    assert _option("dead_band=1e9") == ("dead_band", 1e9)
    assert _option("whole_body=maybe") == ("whole_body", "maybe")
    assert StepLayerSettings.load({"whole_body": False}).whole_body is False
    with pytest.raises(StepLayerSettingsError, match="step_layer_whole_body"):
        StepLayerSettings.load({"whole_body": "maybe"})
    assert main(["check", "dcm_wbc", "--option", "whole_body=false"]) == 0
    capsys.readouterr()
    assert main(["check", "dcm_wbc", "--option", "whole_body=maybe"]) == 1
    assert "step_layer_whole_body must be true or false, got 'maybe'" in capsys.readouterr().out


@pytest.mark.parametrize("key,value,words", [
    ("dead_band", -0.001, "step_layer_dead_band"),
    ("freeze_phase", 0.0, "step_layer_freeze_phase"),
    ("freeze_phase", 1.5, "step_layer_freeze_phase"),
    ("step_time_max", 0.5, "step_layer_step_time_max"),
    ("min_time_left", 0.0, "step_layer_min_time_left"),
    ("weight_step", math.nan, "step_layer_weight_step"),
    ("whole_body", "maybe", "step_layer_whole_body"),
    ("commanded_dcm", 1.0, "step_layer_commanded_dcm"),
    ("dead_bandd", 1.0, "dead_bandd"),
])
def test_bad_settings_are_refused_naming_the_key(key, value, words):
    with pytest.raises(StepLayerSettingsError, match=words):
        StepLayerSettings.load({key: value})


def test_every_setting_is_in_the_config_file_with_a_reason():
    from biped_model.settings import default_config_dir, load_yaml_tree
    tree = load_yaml_tree(default_config_dir() / "controller.yaml")
    for k in StepLayerSettings.keys():
        assert isinstance(tree[k], dict) and tree[k]["reason"].strip() and "value" in tree[k], k


def test_a_bad_option_is_a_fault_of_the_run_naming_it():
    with pytest.raises(StepLayerSettingsError, match="step_layer_freeze_phase"):
        plugin_loop.PluginLoop("dcm_wbc", sim_config=load_sim_config(), options={"freeze_phase": 2})
