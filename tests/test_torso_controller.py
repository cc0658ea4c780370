"""The torso parameter in the controller: modes ``lambda`` and ``all``.

Independent references: the QP rows against the robot's own constraint evaluation (``margins_direct``
with w = D x + v, for random x), the torso-range rows against the exact advance of lambda; the QP
answers of real controller instances (a push) against SciPy's SLSQP (active) or a direct minimisation of
the least-violation objective (infeasible), and their KKT residuals. Negative controls: a wrong third
column of D breaks the row check; mode both's answer violates what mode all's holds.
"""
from __future__ import annotations


import numpy as np
import pytest
from scipy.optimize import minimize

from biped_sim.plant.push import Push
from biped_model.gait_family import GaitFamily
from biped_controller.core.control.config import (ADAPTED, MODES, TORSO_MODES, ControllerConfigError,
                                                  load_controller_config)
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.control.controller_layout import TORSO_ROWS
from biped_controller.core.control.controller_layout import M_, QP_ROWS
from biped_controller.core.qp.problem import ACTIVE, INFEASIBLE_FALLBACK, UNCONSTRAINED, kkt_residuals
from biped_controller.closed_loop.runner import run

FAM = GaitFamily.load()


def test_modes_declared():
    assert "lambda" in MODES and "all" in MODES
    assert ADAPTED["lambda"] == (2,) and ADAPTED["all"] == (0, 1, 2)
    assert TORSO_MODES == ("lambda", "all")


@pytest.mark.parametrize("name", ["kp_lambda", "kv_lambda", "weight_lambda", "lambda_max"])
@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_bad_torso_settings_name_the_field(name, bad):
    with pytest.raises(ControllerConfigError, match=name):
        load_controller_config(mode="all", **{name: bad})


def test_rows_equal_the_robot_constraints_with_the_third_column():
    """G x - h over the first 17 rows equals -(margins of w = D x + v) + margin, for random x
    (the robot's own evaluation, ``margins_direct``); the range rows equal the exact advance of p and
    lambda over one period."""
    ctrl = AdaptiveController(load_controller_config(mode="all", disturbance_observer=False))
    c = ctrl.cfg
    rng = np.random.default_rng(2121)
    for _ in range(20):
        tau = rng.uniform(0.05, 0.95) * FAM.T
        lam = (rng.uniform(-0.2, 0.2), rng.uniform(-1, 1))
        ctrl.state.tau = tau
        g = FAM.evaluate_torso(FAM.p_d, tau, lam[0])
        q = g.q + rng.normal(scale=0.01, size=6)
        qd = g.dq_dtau + rng.normal(scale=0.1, size=6)
        ref = ctrl._reference(q, qd, None, lam)
        assert ref.D.shape == (6, 3) and ref.x_star.shape == (3,)
        assert ref.x_star[2] == pytest.approx(-c.kv_lambda * lam[1] - c.kp_lambda * lam[0])
        dyn = ctrl.model.dynamics(q, qd)
        G, h = ctrl._qp_rows(ref, dyn, dyn, None, lam)
        assert G.shape == (QP_ROWS + TORSO_ROWS, 3)
        x = rng.normal(scale=[0.5, 0.5, 5.0])
        w = ref.D @ x + ref.v
        m = ctrl.model.margins_direct(q, qd, w)            # positive = satisfied (robot's own mu, l range)
        # the QP's rows use the controller's margins: compare on the actuator rows (same limits)
        np.testing.assert_allclose((G @ x - h)[5:17], -m[5:17] + ctrl.margin[5:17], rtol=1e-9, atol=1e-6)
        # negative control: a wrong dq/dlambda (q3, q4 alike) changes the rows
        Dbad = ref.D.copy()
        Dbad[3, 2] = -Dbad[3, 2]
        wbad = Dbad @ x + ref.v
        if abs(x[2] * ref.D[3, 2]) > 1e-3:
            assert not np.allclose(-ctrl.model.margins_direct(q, qd, wbad)[5:17] + ctrl.margin[5:17],
                                   (G @ x - h)[5:17], rtol=1e-9, atol=1e-6)
        dt = c.period
        lam_next = lam[0] + lam[1] * dt + 0.5 * x[2] * dt * dt
        assert (G @ x - h)[-4] == pytest.approx(lam_next - c.lambda_max, abs=1e-12)
        assert (G @ x - h)[-3] == pytest.approx(-lam_next - c.lambda_max, abs=1e-12)
        lamd_next = lam[1] + x[2] * dt
        assert (G @ x - h)[-2] == pytest.approx(lamd_next - c.lambda_dot_max, abs=1e-12)
        assert (G @ x - h)[-1] == pytest.approx(-lamd_next - c.lambda_dot_max, abs=1e-12)


def test_torso_box_keeps_the_range_rows():
    """The hold of an infeasible answer's lambda'': inside the box it changes nothing; outside, the held
    value satisfies the four range rows (exact advance), or the position rows alone when they conflict."""
    ctrl = AdaptiveController(load_controller_config(mode="all"))
    c, dt = ctrl.cfg, ctrl.cfg.period
    rng = np.random.default_rng(5)
    for _ in range(200):
        lam = (rng.uniform(-c.lambda_max, c.lambda_max), rng.uniform(-c.lambda_dot_max, c.lambda_dot_max))
        x = rng.normal(scale=3000.0)
        held, changed = ctrl._torso_box(x, lam)
        ln, ldn = lam[0] + lam[1] * dt + 0.5 * held * dt * dt, lam[1] + held * dt
        assert abs(ln) <= c.lambda_max * (1 + 1e-12)
        assert abs(ldn) <= c.lambda_dot_max * (1 + 1e-9)
        assert changed == (held != x)
        if not changed:
            assert held == x
    # a small lambda'' inside the box is untouched (negative control of the clip)
    assert ctrl._torso_box(1.0, (0.0, 0.0)) == (1.0, False)


def _lv_objective(G, h, x_star, W, eps):
    def f(x):
        r = np.maximum(G @ x - h, 0.0)
        return float(r @ r + eps * np.sum(W * (x - x_star) ** 2))
    return f


@pytest.fixture(scope="module")
def pushed_all():
    """A forward push in mode all, every QP instance kept (the objects: the compiled loop is off with
    keep_qp, and the torso modes have none anyway)."""
    return run(4, "all", (Push(0.2315, 0.025, 500.0),), keep_qp=True)


def test_qp_instances_of_a_push_against_independent_solvers(pushed_all):
    """Active instances (500 N, survived) and infeasible ones (600 N: the robot falls; the least-violation
    answers, before the torso's range hold, which the controller applies after the QP)."""
    res = pushed_all
    falling = run(3, "all", (Push(0.2315, 0.025, 600.0),), keep_qp=True)
    assert any(i[3] == INFEASIBLE_FALLBACK for i in falling.qp_instances)
    inst = res.qp_instances + [i for i in falling.qp_instances if i[3] == INFEASIBLE_FALLBACK][:5]
    assert inst, "the push made no QP instance"
    W = np.ones(3)
    checked = {ACTIVE: 0, INFEASIBLE_FALLBACK: 0}
    ctrl = AdaptiveController(load_controller_config(mode="all"))
    constrained = [i for i in inst if i[3] != UNCONSTRAINED]
    for G, h, xs, status in constrained[:40] + constrained[-5:]:
        out = ctrl.qp.solve(G, h, xs)
        assert out.status == status
        if status == ACTIVE:
            cons = {"type": "ineq", "fun": lambda x, G=G, h=h: h - G @ x, "jac": lambda x, G=G: -G}
            ref = minimize(lambda x: 0.5 * np.sum(W * (x - xs) ** 2), xs, jac=lambda x: W * (x - xs),
                           constraints=[cons], method="SLSQP", options={"ftol": 1e-14, "maxiter": 500})
            scale = 1.0 + np.max(np.abs(xs))
            assert np.max(np.abs(out.x - ref.x)) <= 1e-5 * scale
            tol = 1e-6 * (1.0 + np.max(np.abs(h)) + np.max(np.abs(G)) * (1.0 + np.max(np.abs(out.x))))
            for z in (None, out.z):       # the solver's multipliers, and recovered by NNLS
                r = kkt_residuals(G, h, xs, W, out.x, z)
                for key in ("primal", "dual", "complementarity", "stationarity"):
                    assert r[key] <= tol, (key, r[key])
            # negative control: x* itself (infeasible here) fails primal feasibility
            assert kkt_residuals(G, h, xs, W, xs)["primal"] > tol
        else:
            from biped_controller.core.qp.exact import reg_weight
            eps = reg_weight(G, W, 1e-9)
            f = _lv_objective(G, h, xs, W, eps)
            ref = minimize(f, out.x + 1e-3, method="BFGS", options={"gtol": 1e-12, "maxiter": 2000})
            assert f(out.x) <= f(ref.x) * (1 + 1e-6) + 1e-12
        checked[status] += 1
    assert checked[ACTIVE] > 0 and checked[INFEASIBLE_FALLBACK] > 0, checked


def test_all_uses_lambda_under_a_push_and_returns_it(pushed_all):
    res = pushed_all
    lam = res.series("lam")
    assert not res.fallen
    assert np.max(np.abs(lam)) > 1e-3                           # the torso was used
    assert np.all(np.abs(lam) <= load_controller_config().lambda_max + 1e-9)
    # pulled back: at the end of the run lambda is far below its peak
    assert abs(lam[-1]) < 0.5 * np.max(np.abs(lam))
    # consistency: lambda advances with the held lambda'' (exact integration) within a step
    ld, ldd = res.series("lam_dot"), res.series("lam_ddot")
    dt = load_controller_config().period
    for k in range(len(lam) - 1):
        if res.statuses[k + 1].stance == res.statuses[k].stance and res.statuses[k + 1].t - res.statuses[k].t == pytest.approx(dt):
            assert lam[k + 1] == pytest.approx(lam[k] + ld[k] * dt + 0.5 * ldd[k] * dt * dt, abs=1e-12)


def test_mode_lambda_walks_without_a_push_with_lambda_zero():
    """Nothing at stake: lambda''* = 0 at lambda = lambda' = 0, so without a push lambda stays (near) 0 and
    the reference is the preferred gait's."""
    res = run(2, "lambda", ())
    assert not res.fallen and res.steps_walked == 2
    assert np.max(np.abs(res.series("lam"))) < 1e-6


def test_reset_clears_lambda():
    ctrl = AdaptiveController(load_controller_config(mode="all"))
    ctrl.memory[M_.lam] = 0.1
    ctrl.memory[M_.lam_dot] = 0.2
    ctrl.reset(0)
    assert ctrl.memory[M_.lam] == 0.0 and ctrl.memory[M_.lam_dot] == 0.0


def _msg_fields(path):
    fields = set()
    for line in path.read_text(encoding="utf-8").splitlines():
        line = line.split("#")[0].strip()
        if line and "=" not in line:
            fields.add(line.split()[1])
    return fields


def test_foxglove_layout_plots_lambda_from_real_status_fields():
    """Every /controller/status path of the Foxglove layout names a field of ControllerStatus.msg, the
    lambda plot is there and sits beside p's; the node's message carries the torso fields of the status.
    Negative control: a made-up path is caught by the same check."""
    import json
    import re
    from helpers import ROOT
    from biped_controller.core.control.status import ControllerStatusData
    import dataclasses
    fields = _msg_fields(ROOT / "src" / "biped_msgs_py" / "msg" / "ControllerStatus.msg")
    layout = json.loads((ROOT / "config" / "foxglove_layout.json").read_text(encoding="utf-8"))
    text = json.dumps(layout)
    paths = re.findall(r"/controller/status\.([A-Za-z_]+)", text)
    assert paths and all(p in fields for p in paths), [p for p in paths if p not in fields]
    assert {"lam", "lam_dot"} <= set(paths)
    assert "made_up" not in fields
    torso = {"lam", "lam_dot", "lam_ddot", "lam_ddot_star"}
    assert torso <= fields and torso <= {f.name for f in dataclasses.fields(ControllerStatusData)}
    lam_panel = [k for k, v in layout["configById"].items() if "/controller/status.lam" in json.dumps(v)]
    assert lam_panel == ["Plot!lambda"]

    def find(node, a, b):
        if isinstance(node, dict):
            if [node.get("first"), node.get("second")] in ([a, b], [b, a]):
                return True
            return any(find(v, a, b) for v in node.values())
        return False
    assert find(layout["layout"], "Plot!p", "Plot!lambda")


def test_node_message_carries_lambda():
    from biped_controller.graph.controller_node import status_message
    from builtin_interfaces.msg import Time
    res = run(1, "all", (Push(0.3, 0.025, 400.0),), max_time=0.4)
    s = max(res.statuses, key=lambda s: abs(s.lam))
    assert abs(s.lam) > 0
    m = status_message(s, Time())
    assert (m.lam, m.lam_dot, m.lam_ddot, m.lam_ddot_star) == (s.lam, s.lam_dot, s.lam_ddot, s.lam_ddot_star)
    assert m.mode == "all"


def test_studies_accept_the_torso_modes():
    from biped_controller.studies.capmap.spec import MapError, MapSpec
    from biped_controller.studies.robustness import SEARCHES
    from biped_controller.studies.trial.args import modes_arg as _modes_arg
    import argparse
    assert MapSpec(modes=("lambda", "all", "both")).modes == ("lambda", "all", "both")
    with pytest.raises(MapError, match="torso"):
        MapSpec(modes=("torso",))
    assert set(TORSO_MODES) <= set(SEARCHES)
    assert _modes_arg("none,tau,p,both,lambda,all")[-2:] == ("lambda", "all")
    with pytest.raises(argparse.ArgumentTypeError):
        _modes_arg("both,lamda")


def test_torso_cost_sums_over_the_common_horizon():
    """studies/torso.costs: every mode's sums stop at the shortest run's end; recomputed here from the
    records period by period (work = sum |Gamma_i q'_i| dt, torque^2 = sum |Gamma|^2 dt), and a run
    compared with itself gives equal numbers (negative control: the longer run's full sum differs)."""
    from biped_controller.studies.torso import costs
    long = run(2, "both", ())
    short = run(1, "both", ())
    out = costs({"both": long, "all": short}, push_end=0.0)
    hz = short.records[-1].t_end
    assert out["horizon_s"] == hz
    work = sq = 0.0
    for r in long.records:
        if r.t >= hz:
            break
        dt = min(r.t_end, hz) - r.t
        work += float(np.sum(np.abs(np.asarray(r.torque) * np.asarray(r.qd)))) * dt
        sq += float(np.sum(np.asarray(r.torque) ** 2)) * dt
    assert out["modes"]["both"]["abs_work_J"] == pytest.approx(work, rel=1e-12)
    assert out["modes"]["both"]["torque_sq_integral"] == pytest.approx(sq, rel=1e-12)
    assert out["modes"]["all"]["abs_work_J"] == pytest.approx(out["modes"]["both"]["abs_work_J"], rel=1e-12)
    full = sum(float(np.sum(np.abs(np.asarray(r.torque) * np.asarray(r.qd)))) * (r.t_end - r.t) for r in long.records)
    assert full > 1.2 * work


def test_torque_within_period_starts_at_the_period_torque_with_lambda():
    """The integration-rate law (torque_within_period) at s = 0 is the period's own torque: the same
    reference (with lambda, lambda', lambda'') and the same decision, once lambda != 0. Negative control:
    with the torso terms dropped (lambda'' = 0 in the memory) the torque differs."""
    from biped_model.description import LEFT
    rec = run(2, "both", (Push(0.2315, 0.025, 500.0),))
    ctrl = AdaptiveController(load_controller_config(mode="all"))
    ctrl.reset(LEFT)
    checked = 0
    for r in rec.records:
        out = ctrl.compute(r.t, r.q, r.qd, r.stance)
        if abs(out.status.lam) > 1e-4 and abs(out.status.lam_ddot) > 1e-2:
            tw = ctrl.torque_within_period(0.0, r.q, r.qd, r.stance)
            np.testing.assert_allclose(tw, out.torque, rtol=1e-9, atol=1e-9)
            saved = ctrl.memory[M_.lam_ddot]
            ctrl.memory[M_.lam_ddot] = 0.0
            assert not np.allclose(ctrl.torque_within_period(0.0, r.q, r.qd, r.stance), out.torque, rtol=1e-6, atol=1e-6)
            ctrl.memory[M_.lam_ddot] = saved
            checked += 1
            if checked >= 5:
                break
    assert checked >= 1
