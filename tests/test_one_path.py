"""One path for every controller: the studies resolve a controller's name once (``trial.controller.resolve``)
into the object they call; built-in modes keep the compiled path and its early stop, any other controller
runs through the generic loop under the same survival rule; ``--controller NAME`` in experiment
walk / push / probe / band, plant_compare push / pushes and the bench, an unknown name an error naming it before
any work."""
from __future__ import annotations

import json

import numpy as np
import pytest

from biped_controller.core.control.config import MODES
from biped_controller.plugin.builtin import ModeBoth
from biped_controller.plugin.interface import ControllerSetup, ControlResult, Observation
from biped_controller.plugin.registry import UnknownControllerError
from biped_controller.closed_loop import runner
from biped_controller.studies.trial import runs, trials
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.controller import (RESOLVE_ERRORS, BuiltinMode, PluginController, resolve)
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS

PUSH = runs.paper_push


class ZeroTorque:
    """A controller that applies no torque (the robot falls in its first step) and reports a stride."""

    description = "test: zero torque"

    def __init__(self, setup: ControllerSetup):
        self.p = setup.family.p_d

    def reset(self, t: float, stance: int) -> None:
        pass

    def on_touchdown(self, t: float, stance: int) -> None:
        pass

    def compute(self, obs: Observation) -> ControlResult:
        return ControlResult(np.zeros(6), {"p": self.p, "zmp": 0.0})


ZERO = f"{__name__}:ZeroTorque"


# ------------------------------------------------------------------------------------------ resolution
def test_every_mode_resolves_to_the_compiled_path_and_other_names_to_the_loop():
    for m in MODES:
        c = resolve(m)
        assert isinstance(c, BuiltinMode) and c.adaptive and c.name == m
        assert c.uses_observer == (m != "none")
    z = resolve(ZERO)
    assert isinstance(z, PluginController) and not z.adaptive and not z.uses_observer
    assert resolve(ZERO) is z            # once per process
    # the compiled path is the built-in class's own, whichever name reaches it: its module:Class is the mode
    assert resolve("biped_controller.plugin.builtin:ModeBoth") is resolve("both")
    # a subclass of a built-in may change compute: the generic loop runs it
    assert isinstance(resolve(f"{__name__}:SubclassedBoth"), PluginController)


class SubclassedBoth(ModeBoth):
    """Mode both's class subclassed by a user (its compute unchanged here): not the built-in itself."""


@pytest.mark.parametrize("name", ["no_such_controller", "no_such_module:Thing", f"{__name__}:NoSuchClass", ""])
def test_an_unusable_name_is_an_error_naming_it(name):
    with pytest.raises(RESOLVE_ERRORS) as e:
        resolve(name)
    assert (name or "non-empty") in str(e.value)


def test_builtin_trial_keeps_the_early_stop_and_the_plugin_trial_runs_in_full():
    """A survived built-in trial is decided early (the compiled path's early stop); the same force through
    the generic loop (mode both's class subclassed: a plug-in) runs in full to the same outcome."""
    push = PUSH(150.0)
    b = trials.survives(push, "both", DEFAULT_SETTINGS)
    assert b["survived"] and b["decided_at_step"] is not None and b["decided_at_step"] < runs.trial_steps(push)
    g = trials.survives(push, f"{__name__}:SubclassedBoth", DEFAULT_SETTINGS)
    assert g["survived"] and g["decided_at_step"] is None and g["fault"] is None
    assert g["steps_walked"] == runs.trial_steps(push)


def test_the_same_rule_fails_a_controller_that_falls():
    r = trials.survives(PUSH(10.0), ZERO, DEFAULT_SETTINGS)
    assert not r["survived"] and r["fell"] and r["reason"].startswith("fell")
    assert trials.walk_band(ZERO, DEFAULT_SETTINGS, 3).unpushed_fall     # its own unpushed walk fell


def test_walk_of_a_mode_is_runner_run():
    a = resolve("both").walk(2, DEFAULT_SETTINGS)
    b = runner.run(2, "both")
    assert len(a.records) == len(b.records) and [i.t for i in a.impacts] == [i.t for i in b.impacts]
    assert np.array_equal(np.array([r.torque for r in a.records]), np.array([r.torque for r in b.records]))


def test_robustness_walk_record_of_a_mode_reads_the_same_fields():
    from biped_controller.studies import robustness
    from biped_sim.plant.perturbation import PlantPerturbation
    r = robustness.walk_record(PlantPerturbation(), "both", True, steps=2)
    res = runner.run(2, "both")
    assert r["survived"] and r["steps_walked"] == 2 and r["observer"]
    assert r["max_tracking_error"] == pytest.approx(max(s.max_tracking_error for s in res.statuses), rel=0, abs=0)
    assert r["final_p"] == res.statuses[-1].p and r["final_tau_dot"] == res.statuses[-1].tau_dot
    assert r["max_force_estimate"] == max(abs(s.force_estimate) for s in res.statuses)


# ------------------------------------------------------------------------------------------ experiment
def _experiment(argv, tmp_path, capsys):
    from biped_controller.studies import experiment
    out = tmp_path / "r.json"
    assert experiment.main(argv + ["--json", str(out)]) == 0
    return json.loads(out.read_text()), capsys.readouterr().out


def test_experiment_walk_of_a_plugin(tmp_path, capsys):
    r, text = _experiment(["walk", "--controller", "capture_point", "--steps", "2"], tmp_path, capsys)
    assert r["mode"] == "capture_point" and r["integration_rate"] is None
    assert r["zoh"]["steps_walked"] == 2 and not r["zoh"]["fallen"]
    assert abs(r["zoh"]["final_tau_dot"] - 1.0) < 0.05 and r["zoh"]["force_estimate_abs_max"] is None
    assert "not run: a plug-in's torque is held" in text


def test_experiment_push_and_probe_of_a_plugin(tmp_path, capsys):
    figs = tmp_path / "figs"
    ok, _ = _experiment(["push", "--controller", "capture_point", "--force", "30", "--figures", str(figs)],
                        tmp_path, capsys)
    assert ok["survived"] and ok["mode"] == "capture_point" and ok["fault"] is None
    assert {p.name for p in figs.iterdir()} == {"fig3_l.png", "fig4_p.png", "fig5_tau.png"}
    bad, _ = _experiment(["push", "--controller", "capture_point", "--force", "400"], tmp_path, capsys)
    assert not bad["survived"]
    pr, text = _experiment(["probe", "--controller", "capture_point", "--force", "30"], tmp_path, capsys)
    assert pr["survived"] and pr["periods"] and all("p" in x["status"] for x in pr["periods"])
    assert any(x["push"] == 30.0 for x in pr["periods"]) and "tau_dot" in text


def test_experiment_probe_of_a_plugin_compares_its_predicted_l(tmp_path, capsys):
    pr, _ = _experiment(["probe", "--controller", ZERO, "--force", "10", "--start", "0.0"], tmp_path, capsys)
    assert not pr["survived"]
    assert pr["max_l_error_during_push"] == max(abs(x["l_act"]) for x in pr["periods"] if x["t"] < 0.025)


@pytest.mark.parametrize("cmd", [["walk"], ["push"], ["probe"], ["max-push"], ["table"]])
def test_experiment_unknown_controller_is_an_error_before_any_run(cmd, tmp_path, capsys):
    from biped_controller.studies import experiment
    out = tmp_path / "r.json"
    with pytest.raises(SystemExit) as e:
        experiment.main(cmd + ["--controller", "no_such_controller", "--json", str(out)])
    assert e.value.code == 2
    assert "no_such_controller" in capsys.readouterr().err and not out.exists()


# ------------------------------------------------------------------------------------------ plant comparison
def test_plant_compare_push_of_a_plugin(tmp_path):
    from biped_controller.studies import plant_compare
    out = tmp_path / "p.json"
    assert plant_compare.main(["push", "--controller", "capture_point", "--force", "30", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["plant"] for r in rows] == list(plant_compare.PLANTS)
    assert all(r["mode"] == "capture_point" and r["fall"] is None and r["observer"] is False for r in rows)
    assert all(r["final_p"] is not None for r in rows) and "contact" in rows[-1]


def test_plant_compare_pushes_passes_the_controller_to_each_table(tmp_path, monkeypatch):
    from biped_controller.studies import experiment, plant_compare
    calls = []

    def fake(argv):
        calls.append(argv)
        names = ["none", "tau", "p", "both"] + [argv[i + 1] for i, a in enumerate(argv) if a == "--controller"]
        row = {"max_force": 40.0, "failure_cause": "fell", "islands": [], "no_fall_edge": 40.0, "first_fall": 45.0,
               "fall_cause": "fell", "paper": None}
        path = argv[argv.index("--json") + 1]
        with open(path, "w", encoding="utf-8") as f:
            json.dump({"modes": {n: row for n in names}}, f)
        return 0
    monkeypatch.setattr(experiment, "main", fake)
    table, rows = plant_compare.pushes_table(tmp_path, reuse=True, controllers=("capture_point",))
    assert len(calls) == 4 and all(c[-2:] == ["--controller", "capture_point"] for c in calls)
    assert "| on | capture_point |" in table and "rigid/off/capture_point" in rows
    calls.clear()
    plant_compare.pushes_table(tmp_path, reuse=True, controllers=("capture_point",))
    assert calls == []                   # every row asked for is in the files: read, not run
    plant_compare.pushes_table(tmp_path, reuse=True, controllers=(ZERO,))
    assert len(calls) == 4               # a row missing from the files: run again


def test_plant_compare_unknown_controller_is_an_error(capsys):
    from biped_controller.studies import plant_compare
    for argv in (["push", "--force", "30"], ["pushes"]):
        with pytest.raises(SystemExit) as e:
            plant_compare.main(argv + ["--controller", "no_such_controller"])
        assert e.value.code == 2 and "no_such_controller" in capsys.readouterr().err


def test_resolve_refuses_a_non_string():
    with pytest.raises(UnknownControllerError):
        resolve(None)


def test_one_result_type_reads_a_status_key_of_either_loop():
    a = resolve("both").walk(1, DEFAULT_SETTINGS)
    b = resolve("capture_point").walk(1, DEFAULT_SETTINGS)
    assert type(a) is type(b) is runner.RunResult
    assert np.array_equal(a.series("p"), np.array([s.p for s in a.statuses]))
    assert np.array_equal(b.series("p"), np.array([s["p"] for s in b.statuses]))
    assert np.all(np.isnan(b.series("no_such_key"))) and len(b.series("no_such_key")) == len(b.statuses) > 0
    assert b.controller == "capture_point" and b.fault is None and b.periods == len(b.records)


def test_experiment_walk_of_a_faulting_plugin_prints_the_fault(tmp_path, capsys):
    r, text = _experiment(["walk", "--controller", f"{__name__}:NaNTorque", "--steps", "1"], tmp_path, capsys)
    assert r["zoh"]["fault"] and "non-finite torque" in r["zoh"]["fault"] and r["zoh"]["steps_walked"] == 0
    assert "controller fault (ZOH 1 ms)" in text and "force estimate" not in text


class NaNTorque(ZeroTorque):
    """A NaN torque (a controller fault in the first period)."""

    def compute(self, obs: Observation) -> ControlResult:
        return ControlResult(np.full(6, np.nan), {})


# ------------------------------------------------------------------------------------------ band --controller
def _per_step_maxima(t, values, impacts):
    """Per step (between consecutive impacts, from t = 0) the largest |value| of the periods starting in it."""
    out, a = [], 0.0
    for b in impacts:
        w = [abs(v) for ti, v in zip(t, values) if a <= ti < b]
        if w:
            out.append(max(w))
        a = b
    return out


def test_experiment_band_of_a_plugin_is_the_band_its_trials_use(tmp_path, capsys):
    r, text = _experiment(["band", "--controller", "capture_point"], tmp_path, capsys)
    ctl = resolve("capture_point")
    steps = runs.trial_steps(PUSH(0.0))
    assert r["mode"] == "capture_point" and r["steps"] == steps and not r["fallen"]
    assert r["band"] == ctl.band(DEFAULT_SETTINGS, steps).as_dict()
    walk = ctl.walk(steps, DEFAULT_SETTINGS, (), keep_records=True)
    t = [rec.t for rec in walk.records]
    imp = [i.t for i in walk.impacts]
    p_d = context().family.p_d
    assert [x["p"] for x in r["per_step"]] == _per_step_maxima(t, [s["p"] - p_d for s in walk.statuses], imp)
    assert [x["tau_dot"] for x in r["per_step"]] == _per_step_maxima(t, [s["tau_dot"] - 1.0 for s in walk.statuses],
                                                                      imp)
    assert "controller capture_point" in text and "survival:" in text


def test_experiment_band_of_a_plugin_without_tau_dot_says_so(tmp_path, capsys):
    r, text = _experiment(["band", "--controller", ZERO], tmp_path, capsys)
    assert r["fallen"] and r["band"]["unpushed_fall"]            # falls unpushed: the rule's floors
    assert all(x["tau_dot"] is None for x in r["per_step"]) and r["end"]["tau_dot"] is None
    assert all(x["p"] is not None for x in r["per_step"])        # it reports p
    assert "not reported" in text


def test_experiment_band_of_a_mode_is_its_walk(tmp_path, capsys):
    r, _ = _experiment(["band", "--mode", "both"], tmp_path, capsys)
    steps = runs.trial_steps(PUSH(0.0))
    res = runner.run(steps=steps, mode="both")
    p_d = context().family.p_d
    t = [s.t for s in res.statuses]
    imp = [i.t for i in res.impacts]
    assert [x["p"] for x in r["per_step"]] == _per_step_maxima(t, [s.p - p_d for s in res.statuses], imp)
    assert r["band"] == resolve("both").band(DEFAULT_SETTINGS, steps).as_dict()


def test_experiment_band_of_an_unknown_controller_is_an_error_naming_it(capsys):
    from biped_controller.studies import experiment
    with pytest.raises(SystemExit):
        experiment.main(["band", "--controller", "no_such_controller"])
    assert "no_such_controller" in capsys.readouterr().err
