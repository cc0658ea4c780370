"""The controller interface (``biped_controller.plugin``): a controller written only against it, the
registry, the fault wrapper and the in-process loop on both plants.

Oracles, independent of the code under test:
- the built-in modes through ``runner.run`` (the studies' loop, its object path): the same controller
  object through the plug-in loop gives the same records bit for bit (the loop adds nothing);
- a classical computed-torque controller written here from the paper's equations (11), (15)-(16) on the
  fixed reference q_d(p_d, t - t_touchdown), against mode ``none`` (the project's compiled controller):
  the same walk and the same push outcome up to round-off;
- the studies' max-push figure of mode none at the paper's cell (43.75 N: survives 43.75 N, falls at
  46.875 N, the last two bisection points of the search from coarse 50 N at 5 N resolution).
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import helpers
from biped_controller.core.control.config import MODES, load_controller_config
from biped_controller.plugin import loop as plugin_loop
from biped_controller.plugin.builtin import BUILTIN, ModeNone
from biped_controller.plugin.interface import (ControllerFault, ControllerSetup, ControlResult, GuardedController,
                                               InterfaceError, Observation, check_controller_class,
                                               stamp_time)
from biped_controller.plugin.registry import (ControllerLoadError, UnknownControllerError, load_controller,
                                              registered)
from biped_controller.studies.trial.plugin_trials import PushTrials
from biped_controller.studies.trial import runs as trial_runs, trials as trial_trials
from biped_controller.closed_loop import runner
from biped_sim.plant.config import load_sim_config
from biped_sim.plant.push import Push

START, DURATION = trial_runs.DEFAULT_START, trial_runs.DEFAULT_DURATION


class ClassicalComputedTorque:
    """Written against the interface only (its setup's gains, reference and model): q_d = q_d(p_d, tau),
    tau = time since the step began (tau' = 1), w = q_d'' + K_v (q_d' - q') + K_p (q_d - q),
    Gamma = A(q) w + H(q, q')."""

    description = "test: classical computed torque on the fixed reference"

    def __init__(self, setup: ControllerSetup):
        self.Kp, self.Kv = setup.gains.Kp, setup.gains.Kv
        self.ref = setup.reference
        self.model = setup.model
        self.t0 = 0.0

    def reset(self, t: float, stance: int) -> None:
        self.t0 = t

    def on_touchdown(self, t: float, stance: int) -> None:
        self.t0 = t

    def compute(self, obs: Observation) -> ControlResult:
        tau = (round(obs.t * 1e9) - round(self.t0 * 1e9)) * 1e-9     # whole nanoseconds, as the plant's clock
        g = self.ref.at(self.ref.p_d, tau)
        w = g.d2q_dtau2 + self.Kv * (g.dq_dtau - obs.qd) + self.Kp * (g.q - obs.q)
        dyn = self.model.dynamics(obs.q, obs.qd)
        return ControlResult(dyn.A @ w + dyn.H, {"p": self.ref.p_d, "tau": tau, "tau_dot": 1.0})


def _records(recs):
    return {k: np.array([getattr(r, k) for r in recs]) for k in ("t", "stance", "q", "qd", "torque", "t_end")}


def _same_bits(a, b):
    assert len(a.records) == len(b.records)
    ra, rb = _records(a.records), _records(b.records)
    for k in ra:
        assert np.array_equal(ra[k], rb[k]), k
    assert [i.t for i in a.impacts] == [i.t for i in b.impacts]
    assert (a.fallen, a.fall_cause) == (b.fallen, b.fall_cause)


# ------------------------------------------------------------------------------------------ built-ins
@pytest.mark.parametrize("mode, force", [("none", 0.0), ("both", 300.0)])
def test_builtin_mode_through_the_plugin_loop_is_the_runner_bit_for_bit(mode, force):
    pushes = (Push(START, DURATION, force),) if force else ()
    ref = runner.run(steps=3, mode=mode, pushes=pushes, compiled_loop=False)
    got = plugin_loop.run(mode, steps=3, pushes=pushes)
    assert got.fault is None and got.steps_walked == 3
    _same_bits(got, ref)
    assert [s["p"] for s in got.statuses] == [s.p for s in ref.statuses]
    assert [s["qp_status"] for s in got.statuses] == [s.qp_status for s in ref.statuses]


def test_builtin_mode_on_mujoco_is_the_runner_bit_for_bit():
    pytest.importorskip("mujoco")
    mj = load_sim_config(plant="mujoco")
    ref = runner.run(steps=2, mode="both", sim_config=mj, compiled_loop=False)
    got = plugin_loop.run("both", steps=2, sim_config=mj)
    assert got.steps_walked == 2 and not got.fallen
    _same_bits(got, ref)


# ------------------------------------------------------------------------------------------ a written controller
def _close_to_mode_none(got, ref, tol_q=1e-12, tol_torque=1e-8):
    """Round-off apart (Pinocchio here, the compiled model terms in mode none; measured: 3e-15 rad, 9e-11 N m on
    the rigid plant, 1e-11 rad, 5e-9 N m on MuJoCo)."""
    assert got.fault is None
    assert len(got.records) == len(ref.records)
    a, b = _records(got.records), _records(ref.records)
    assert np.array_equal(a["stance"], b["stance"])
    helpers.assert_close(a["t"], b["t"], 1e-9, "period start times")
    helpers.assert_close(a["q"], b["q"], tol_q, "q")
    helpers.assert_close(a["qd"], b["qd"], 1000 * tol_q, "q'")
    helpers.assert_close(a["torque"], b["torque"], tol_torque, "torque")
    helpers.assert_close([i.t for i in got.impacts], [i.t for i in ref.impacts], 1e-9, "touchdown times")


def test_interface_computed_torque_equals_mode_none_walking():
    ref = runner.run(steps=3, mode="none")
    got = plugin_loop.run(ClassicalComputedTorque(plugin_loop.PluginLoop("none").setup), steps=3)
    assert got.steps_walked == ref.steps_walked == 3 and not got.fallen
    _close_to_mode_none(got, ref)


def test_interface_computed_torque_equals_mode_none_pushed():
    push = (Push(START, DURATION, 30.0),)
    ref = runner.run(steps=4, mode="none", pushes=push)
    got = plugin_loop.run(f"{__name__}:ClassicalComputedTorque", steps=4, pushes=push)
    assert got.steps_walked == ref.steps_walked == 4 and not got.fallen and not ref.fallen
    _close_to_mode_none(got, ref)


def test_interface_computed_torque_has_mode_none_max_push_at_the_paper_cell():
    """43.75 N: the studies' mode-none figure (the search's last bisection points 43.75 / 46.875 N)."""
    trials = PushTrials(f"{__name__}:ClassicalComputedTorque")
    ok = trials.survives(43.75)
    bad = trials.survives(46.875)
    assert ok["survived"], ok
    assert not bad["survived"] and bad["reason"].startswith("fell"), bad
    assert trial_trials.survives(trial_runs.paper_push(43.75), "none", pool=False)["survived"]
    assert not trial_trials.survives(trial_runs.paper_push(46.875), "none", pool=False)["survived"]


def test_interface_computed_torque_equals_mode_none_on_mujoco():
    """The same records as mode none on the MuJoCo plant, whatever its outcome (two steps asked)."""
    pytest.importorskip("mujoco")
    mj = load_sim_config(plant="mujoco")
    ref = runner.run(steps=2, mode="none", sim_config=mj)
    got = plugin_loop.run(f"{__name__}:ClassicalComputedTorque", steps=2, sim_config=mj)
    _close_to_mode_none(got, ref, tol_q=1e-9, tol_torque=1e-6)
    assert (got.steps_walked, got.fallen, got.fall_cause) == (ref.steps_walked, ref.fallen, ref.fall_cause)
    assert got.fall_time == ref.fall_time or (np.isnan(got.fall_time) and np.isnan(ref.fall_time))


# ------------------------------------------------------------------------------------------ observations
class _Spy(ClassicalComputedTorque):
    def __init__(self, setup):
        super().__init__(setup)
        self.seen, self.touchdowns = [], []

    def on_touchdown(self, t, stance):
        super().on_touchdown(t, stance)
        self.touchdowns.append((t, stance))

    def compute(self, obs):
        self.seen.append(obs)
        return super().compute(obs)


def test_observation_carries_the_last_applied_torque_and_touchdowns():
    lp = plugin_loop.PluginLoop("none")
    spy = _Spy(lp.setup)
    res = plugin_loop.run(spy, steps=2)
    assert res.steps_walked == 2
    # every touchdown followed by a period is told, before that period (the run stops at the second one), at
    # the touchdown instant as a stamp carries it (rounded to the nanosecond)
    assert spy.touchdowns == [(stamp_time(i.t), i.new_stance) for i in res.impacts[:1]]
    assert [o.t for o in spy.seen if o.stance != o.last_stance] == [stamp_time(res.impacts[0].t)]
    assert abs(stamp_time(res.impacts[0].t) - res.impacts[0].t) <= 0.5e-9
    assert np.array_equal(spy.seen[0].last_torque, np.zeros(6))
    for obs, prev in zip(spy.seen[1:], res.records[:-1]):
        assert np.array_equal(obs.last_torque, prev.torque) and obs.last_stance == prev.stance
    assert not spy.seen[0].q.flags.writeable      # the controller cannot write into the loop's arrays
    with pytest.raises(ValueError):
        spy.seen[0].q[0] = 1.0


def test_observation_is_the_sensor_model_output_not_the_truth():
    """With a delayed, noisy sensor the controller sees the plant's sensor reading (the same seed gives the
    same reading), never the true state of the record."""
    from biped_sim.plant.perturbation import PlantPerturbation
    pert = PlantPerturbation(noise_q=1e-3, delay=2, seed=7)
    lp = plugin_loop.PluginLoop("none", perturbation=pert)
    spy = _Spy(lp.setup)
    res = plugin_loop.run(spy, steps=1, perturbation=pert, limit=0.05)
    twin = plugin_loop.PluginLoop("none", perturbation=pert).sim      # the same plant, its own sensor
    q0, qd0 = lp.family.initial_state()
    twin.reset(q0, qd0, 0)
    for obs, rec in zip(spy.seen, res.records):
        reading = twin.observe()
        assert np.array_equal(obs.q, reading.q) and not np.array_equal(obs.q, rec.q)
        twin.step(rec.torque)


# ------------------------------------------------------------------------------------------ registry
def test_unknown_name_lists_the_registered_controllers():
    with pytest.raises(UnknownControllerError) as e:
        load_controller("no_such_controller")
    msg = str(e.value)
    assert "no_such_controller" in msg
    for m in MODES:
        assert m in msg


def test_builtin_names_load_adapters():
    assert [r.name for r in registered()][:len(MODES)] == list(MODES)
    assert set(BUILTIN) == set(MODES)
    assert load_controller("none") is ModeNone
    for m in MODES:
        assert load_controller(m).mode == m


def test_module_class_strings_and_their_errors():
    assert load_controller(f"{__name__}:ClassicalComputedTorque") is ClassicalComputedTorque
    with pytest.raises(ControllerLoadError, match="no_such_module"):
        load_controller("no_such_module:Thing")
    with pytest.raises(ControllerLoadError, match="NoSuchClass"):
        load_controller(f"{__name__}:NoSuchClass")


class NoCompute:
    def __init__(self, setup):
        pass

    def reset(self, t, stance):
        pass

    def on_touchdown(self, t, stance):
        pass


class BadTouchdown(ClassicalComputedTorque):
    def on_touchdown(self):          # the wrong signature, on purpose
        pass


class NoSetup(ClassicalComputedTorque):
    def __init__(self):
        pass


class OldOrderReset(ClassicalComputedTorque):
    def reset(self, stance, t):      # the order before the time came first in every call
        self.t0 = t


@pytest.mark.parametrize("cls, needle", [(NoCompute, "compute"), (BadTouchdown, "on_touchdown"),
                                         (NoSetup, "constructor"), (OldOrderReset, "reset")])
def test_a_class_that_does_not_satisfy_the_interface_is_named(cls, needle):
    with pytest.raises(InterfaceError) as e:
        load_controller(f"{__name__}:{cls.__name__}")
    assert cls.__qualname__ in str(e.value) and needle in str(e.value)
    with pytest.raises(InterfaceError):
        check_controller_class(cls)
    assert check_controller_class(ClassicalComputedTorque) is ClassicalComputedTorque
    with pytest.raises(InterfaceError, match="not a class"):
        check_controller_class(ClassicalComputedTorque.compute)


def test_cli_lists_one_line_per_controller():
    out = subprocess.run([sys.executable, "-m", "biped_controller.studies.controllers", "list"], capture_output=True, text=True,
                         check=True).stdout.splitlines()
    names = [line.split()[0] for line in out]
    assert names == [r.name for r in registered()]
    assert names[:len(MODES)] == list(MODES)
    bad = subprocess.run([sys.executable, "-m", "biped_controller.studies.controllers", "check", "no_such_controller"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "no_such_controller" in bad.stderr and "both" in bad.stderr


# ------------------------------------------------------------------------------------------ faults
class Faulty(ClassicalComputedTorque):
    """Returns ``bad`` from the period starting at or after ``at`` [s]."""

    at = 0.1
    bad: object = None

    def compute(self, obs):
        out = super().compute(obs)
        return out if obs.t < self.at else self.bad(out)


class NaNTorque(Faulty):
    bad = staticmethod(lambda out: ControlResult(np.where(np.arange(6) == 2, np.nan, out.torque), out.status))


class ShortTorque(Faulty):
    bad = staticmethod(lambda out: ControlResult(out.torque[:5], out.status))


class TextStatus(Faulty):
    bad = staticmethod(lambda out: ControlResult(out.torque, {"p": "far"}))


class TupleResult(Faulty):
    bad = staticmethod(lambda out: (out.torque, out.status))


@pytest.mark.parametrize("cls, kind", [(NaNTorque, "non-finite torque"), (ShortTorque, "wrong torque shape"),
                                       (TextStatus, "malformed status"), (TupleResult, "wrong result type")])
def test_a_faulty_result_is_a_fault_naming_the_controller(cls, kind):
    name = f"{__name__}:{cls.__name__}"
    res = plugin_loop.run(name, steps=3)
    assert res.fault is not None and res.fault.kind == kind and res.fault.controller == name
    assert name in str(res.fault) and kind in str(res.fault)
    assert abs(res.fault.t - cls.at) < 2e-3 and not res.fallen
    assert res.records[-1].t < cls.at <= res.fault.t          # no torque of the faulty period reached the plant
    trial = PushTrials(name).survives(10.0)
    assert not trial["survived"] and trial["fault"] == kind and trial["reason"].startswith("controller fault")


def test_guard_passes_a_good_result_and_converts_numpy_status():
    lp = plugin_loop.PluginLoop("none")
    inner = ClassicalComputedTorque(lp.setup)
    guard = GuardedController(inner, "ct")
    q0, qd0 = lp.family.initial_state()
    obs = Observation.frozen(0.0, 0, 0, q0, qd0, np.nan, np.nan, np.zeros(6), 0)
    out = guard.compute(obs)
    assert out.torque.shape == (6,) and type(out.status["p"]) is float
    bad = GuardedController(NaNTorque(lp.setup), "nan-one")
    with pytest.raises(ControllerFault, match="nan-one"):
        bad.compute(Observation.frozen(1.0, 1000, 0, q0, qd0, np.nan, np.nan, np.zeros(6), 0))


def test_cli_max_push_runs_the_search(tmp_path):
    """A coarse search (50 N steps to 100 N, 25 N resolution) of the written controller: 25 N survives,
    50 N does not (mode none: 43.75 N)."""
    import json
    import os
    out = tmp_path / "mp.json"
    env = dict(os.environ, PYTHONPATH=str(helpers.ROOT / "tests"))
    run = subprocess.run([sys.executable, "-m", "biped_controller.studies.controllers", "max-push",
                          "test_plugin:ClassicalComputedTorque", "--max", "100", "--coarse", "50", "--resolution", "25",
                          "--json", str(out)], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr
    r = json.loads(out.read_text())
    assert (r["max_force"], r["first_failure"], r["plant"]) == (25.0, 50.0, "rigid")
    assert (r["first_fall"], r["no_fall_edge"]) == (50.0, 25.0)
    assert [t["force"] for t in r["trials"]] == [25.0, 50.0, 100.0]
    assert r["options"] == {}
    assert "max push 25 N" in run.stdout
    from biped_controller.studies.provenance import read_records
    rec = read_records(tmp_path)["mp.json"]
    assert rec["plant"] == "rigid" and "max-push" in rec["command"]


def test_cli_max_push_at_another_cell(tmp_path, capsys):
    """--start/--backward move the search off the paper's cell: backward at onset 0 the written controller
    survives 50 N and 100 N (mode none's map: 125 N there), where forward at the paper's cell 50 N fails; a
    push of no duration is refused."""
    import json
    import os
    out = tmp_path / "mp.json"
    env = dict(os.environ, PYTHONPATH=str(helpers.ROOT / "tests"))
    run = subprocess.run([sys.executable, "-m", "biped_controller.studies.controllers", "max-push",
                          "test_plugin:ClassicalComputedTorque", "--max", "100", "--coarse", "50", "--resolution", "25",
                          "--start", "0", "--backward", "--json", str(out)], capture_output=True, text=True, env=env,
                         timeout=600)
    assert run.returncode == 0, run.stderr
    r = json.loads(out.read_text())
    assert (r["direction"], r["start"], r["duration"]) == ("backward", 0.0, 0.025)
    assert [(t["force"], t["survived"]) for t in r["trials"]] == [(50.0, True), (100.0, True)]
    assert r["max_force"] == 100.0 and r["first_failure"] is None
    from biped_controller.studies.controllers import main
    assert main(["max-push", "none", "--duration", "0"]) == 2
    assert "--duration" in capsys.readouterr().err


def test_cli_max_push_on_a_perturbed_plant(tmp_path, capsys):
    """--perturb reaches the plant: at the cell where the written controller survives 50 N on the nominal
    plant (backward, onset 0), with the torso 20 % lighter it falls (tip_toe at the end of the first step,
    as mode none's walk does there: docs/robustness.md); a bad field is refused naming it."""
    import json
    import os
    out = tmp_path / "mp.json"
    env = dict(os.environ, PYTHONPATH=str(helpers.ROOT / "tests"))
    run = subprocess.run([sys.executable, "-m", "biped_controller.studies.controllers", "max-push",
                          "test_plugin:ClassicalComputedTorque", "--max", "50", "--coarse", "50", "--resolution", "50",
                          "--start", "0", "--backward", "--perturb", "torso_mass_scale=0.8", "--json", str(out)],
                         capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr
    r = json.loads(out.read_text())
    assert r["perturbation"]["torso_mass_scale"] == 0.8
    assert [(t["force"], t["survived"]) for t in r["trials"]] == [(50.0, False)]
    assert r["trials"][0]["fall_cause"] == "tip_toe"
    from biped_controller.studies.controllers import main
    assert main(["max-push", "none", "--perturb", "nope=1"]) == 2
    assert "'nope'" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------ the controller node
def test_the_node_builds_every_controller_through_the_interface():
    """The controller node's one route: a built-in mode is the registry's class built with the node's controller
    settings as its options (the adaptive controller inside has exactly those settings) and returns its whole
    status as the result's record; a plug-in given no options gets none and its result has no record."""
    pytest.importorskip("rclpy")
    from dataclasses import replace

    from biped_controller.core.control.status import ControllerStatusData
    from biped_controller.graph.controller_node import build_controller
    lp = plugin_loop.PluginLoop("none")
    cfg = replace(load_controller_config(mode="both", period=lp.scfg.control_period), margin_torque=2.5, Kp=410.0)
    c = build_controller("both", lp.desc, lp.family, cfg)
    assert isinstance(c, GuardedController) and type(c.inner).__name__ == "ModeBoth"
    assert c.inner.ctrl.cfg == cfg
    q0, qd0 = lp.family.initial_state()
    out = c.compute(Observation.frozen(0.0, 0, 0, q0, qd0, np.nan, np.nan, np.zeros(6), 0))
    assert isinstance(out.record, ControllerStatusData) and out.record.mode == "both"
    assert out.status["p"] == out.record.p and out.status["qp_status"] == out.record.qp_status
    ct = build_controller(f"{__name__}:ClassicalComputedTorque", lp.desc, lp.family, cfg)
    assert isinstance(ct.inner, ClassicalComputedTorque)
    assert ct.compute(Observation.frozen(0.0, 0, 0, q0, qd0, np.nan, np.nan, np.zeros(6), 0)).record is None


class _OptionsProbe(ClassicalComputedTorque):
    """ClassicalComputedTorque keeping its setup's options (for the node's controller_options)."""

    def __init__(self, setup: ControllerSetup):
        super().__init__(setup)
        self.options = dict(setup.options)
        if setup.options.get("refuse"):
            raise ValueError("refused by the plug-in")


def test_node_controller_options_reach_a_plug_in_and_bad_ones_name_the_parameter(tmp_path):
    """``controller_options`` parsed by the study commands' parser (``plugin.options``) reach a plug-in's
    setup as they are; a malformed item, a repeated key, options for a built-in mode and options the plug-in
    refuses raise ParameterError naming ``controller_options``; the node's provenance gives an option's file
    with hashlib's SHA-256 of it."""
    pytest.importorskip("rclpy")
    import hashlib
    from biped_sim.graph.params import ParameterError
    from biped_controller.graph.controller_node import build_controller
    from biped_controller.plugin.options import ControllerOptionError, parse_options
    from biped_controller.plugin.provenance import controller_provenance
    from biped_controller.studies.controllers import _option
    f = tmp_path / "gains.txt"
    f.write_text("not a policy\n")
    opts = parse_options(["gain=2.5", f"file={f}", "label=a=b", "switch=False"], "controller_options")
    assert opts == {"gain": 2.5, "file": str(f), "label": "a=b", "switch": False}
    assert [_option(t) for t in ("gain=2.5", f"file={f}")] == list(opts.items())[:2]   # the --option parser's
    for bad, what in ((["gain"], "takes KEY=VALUE"), (["=1"], "takes KEY=VALUE"), (["gain="], "value is empty"),
                      (["a=1", "a=2"], "given twice")):
        with pytest.raises(ControllerOptionError, match=what):
            parse_options(bad, "controller_options")
    lp = plugin_loop.PluginLoop("none")
    cfg = load_controller_config(mode="both", period=lp.scfg.control_period)
    c = build_controller(f"{__name__}:_OptionsProbe", lp.desc, lp.family, cfg, opts)
    assert c.inner.options == opts
    for name, options in (("both", {"gain": 1.0}), (f"{__name__}:_OptionsProbe", {"refuse": 1.0}),
                          ("onnx_policy", {}), ("onnx_policy", {"file": str(tmp_path / "none.onnx")})):
        with pytest.raises(ParameterError, match="'controller_options'"):
            build_controller(name, lp.desc, lp.family, cfg, options)
    info = controller_provenance("probe", opts, c)
    assert info["controller"] == "probe" and info["options"] == opts
    assert info["files"] == {"file": {"path": str(f.resolve()), "sha256": hashlib.sha256(f.read_bytes()).hexdigest()}}
