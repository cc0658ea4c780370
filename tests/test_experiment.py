"""scripts/experiment settings: the observer switch and ``--set`` overrides reach the closed loop, bad
overrides are rejected naming the key, and a cheap max-push search returns a consistent structure.

Oracles, independent of the experiment's bookkeeping:
- the observer switch: the controller's own ``force_estimate`` during a push (0 when off, the push's
  size when on), and the simulator's actual ground reaction against the controller's prediction (the
  observer exists to close that gap);
- the probe loop against ``runner.run`` (bit-identical records: the probe adds a recording, not a
  different loop);
- a simulator override against the same run with the value given explicitly;
- a search result against a trial recomputed in this process with the same settings.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

import helpers
from biped_controller.studies import experiment as ex
from biped_controller.studies import single_runs
from biped_controller.studies.trial import context as tcontext
from biped_controller.studies.trial import runs, trials
from biped_controller.studies.trial import settings as ts
from biped_controller.closed_loop import runner
from biped_controller.core.control.config import ControllerConfigError, load_controller_config
from biped_sim.plant.push import Push
from biped_sim.plant.config import SimConfigError, load_sim_config

START, DURATION, FORCE = runs.DEFAULT_START, runs.DEFAULT_DURATION, 250.0


def _in_push(t: float) -> bool:
    return START <= t < START + DURATION


# ------------------------------------------------------------------------------------------ parsing
def test_overrides_reach_both_configs_and_leave_the_rest_as_the_files():
    s = ts.parse_overrides(["Kp=900", "margin_zmp=0.0", "push_height=0.0", "disturbance_observer=true"])
    c = s.ctrl_config("p")
    file_c = load_controller_config(mode="p")
    assert (c.Kp, c.margin_zmp, c.disturbance_observer, c.mode) == (900, 0.0, True, "p")
    for k in ts.CONTROLLER_KEYS:
        if k not in ("Kp", "margin_zmp", "disturbance_observer"):
            assert getattr(c, k) == getattr(file_c, k), k
    sim, file_s = s.sim_config(), load_sim_config()
    assert sim.push_height == 0.0 and file_s.push_height != 0.0
    assert c.period == sim.control_period
    d = s.describe()
    assert d["overrides"] == {"Kp": 900, "margin_zmp": 0.0, "push_height": 0.0, "disturbance_observer": True}
    assert d["controller"]["Kp"] == 900 and d["simulator"]["push_height"] == 0.0
    assert ts.parse_overrides([], "off").ctrl_config("both").disturbance_observer is False
    assert ts.parse_overrides([], "on").ctrl_config("both").disturbance_observer is True
    assert ts.parse_overrides([], None) == ts.DEFAULT_SETTINGS


@pytest.mark.parametrize("item, observer, needle", [
    (["no_such_key=1"], None, "no_such_key"),
    (["Kp"], None, "KEY=VALUE"),
    (["mode=p"], None, "mode"),
    (["Kp=1", "Kp=2"], None, "Kp: given twice"),
    (["Kp=[1, 2]"], None, "Kp"),
    (["disturbance_observer=true"], "off", "disturbance_observer"),
    ([], "maybe", "--observer"),
])
def test_bad_overrides_are_rejected_naming_the_key(item, observer, needle):
    with pytest.raises(ts.OverrideError, match=needle):
        ts.parse_overrides(item, observer)


def test_out_of_range_values_are_rejected_by_the_configs_naming_the_key():
    with pytest.raises(ControllerConfigError, match="Kp"):
        ts.check_settings(ts.parse_overrides(["Kp=-1"]))
    with pytest.raises(SimConfigError, match="substeps"):
        ts.check_settings(ts.parse_overrides(["substeps=0"]))
    with pytest.raises(SimConfigError, match="push_height"):
        ts.check_settings(ts.parse_overrides(["push_height=abc"]))


def test_cli_rejects_an_unknown_key_with_its_name(capsys):
    with pytest.raises(SystemExit) as e:
        ex.main(["table", "--set", "no_such_key=1"])
    assert e.value.code == 2
    assert "no_such_key" in capsys.readouterr().err


def test_cli_rejects_a_json_path_in_a_missing_directory_before_running(capsys, tmp_path):
    out = tmp_path / "no_such_dir" / "walk.json"
    with pytest.raises(SystemExit) as e:
        ex.main(["walk", "--steps", "1", "--json", str(out)])
    assert e.value.code == 2
    assert f"--json {out}: its directory" in capsys.readouterr().err
    assert not (tmp_path / "no_such_dir").exists()


# ------------------------------------------------------------------------------------------ closed loop
def test_probe_loop_is_the_runner_loop():
    s = ts.parse_overrides([], "on")
    until = START + DURATION + 0.005
    pr = single_runs.probe_run(runs.paper_push(FORCE), "both", settings=s, until=until)
    ref = runner.run(steps=11, mode="both", pushes=(Push(START, DURATION, FORCE),), sim_config=s.sim_config(),
                     ctrl_config=s.ctrl_config("both"), family=tcontext.context().family, desc=tcontext.context().desc,
                     max_time=until)
    helpers.assert_same_run(pr.result, ref)
    assert len(pr.force_estimate) == len(pr.result.records)


def test_observer_switch_reaches_the_controller():
    """Off: the controller's estimate is exactly 0 throughout the push, and its predicted vertical reaction
    misses the simulator's by more than 5 N. On: after the first period of the push (one period of lag)
    the estimate is within 10 % of the push and the prediction within 1 N of the simulator's reaction."""
    until = START + DURATION
    off = single_runs.probe_run(runs.paper_push(FORCE), "both", settings=ts.parse_overrides([], "off"), until=until)
    on = single_runs.probe_run(runs.paper_push(FORCE), "both", settings=ts.parse_overrides([], "on"), until=until)
    for pr, label in ((off, "off"), (on, "on")):
        t = np.array([r.t for r in pr.result.records])
        assert np.count_nonzero([_in_push(x) for x in t]) >= 15, f"observer {label}: the push must be observed"
    t_off = np.array([r.t for r in off.result.records])
    assert np.all(off.force_estimate == 0.0)
    gap_off = [abs(s.predicted_reaction[1] - r.wrench[1])
               for s, r in zip(off.result.statuses, off.result.records) if _in_push(r.t) and r.t >= START + 0.002]
    assert gap_off and min(gap_off) > 5.0, gap_off
    est_on = [f for f, r in zip(on.force_estimate, on.result.records) if _in_push(r.t) and r.t >= START + 0.002]
    assert est_on
    helpers.assert_close(est_on, np.full(len(est_on), FORCE), 0.1 * FORCE, "observer estimate during the push")
    gap_on = [abs(s.predicted_reaction[1] - r.wrench[1])
              for s, r in zip(on.result.statuses, on.result.records) if _in_push(r.t) and r.t >= START + 0.002]
    assert max(gap_on) < 1.0, gap_on
    # before the push both runs are the same run (the observer sees a zero residual up to round-off)
    before = t_off < START
    assert np.count_nonzero(before) > 100
    helpers.assert_close([r.q for r, b in zip(off.result.records, before) if b],
                         [r.q for r, b in zip(on.result.records, before) if b], 1e-9, "q before the push")


def test_simulator_override_is_the_same_as_the_explicit_value():
    """--set push_height=0.0 (push at the hip) gives the run with the push height given explicitly, and a
    different run from the default height (the override is not ignored)."""
    until = START + 0.010
    over = single_runs.probe_run(runs.paper_push(FORCE), "both", settings=ts.parse_overrides(["push_height=0.0"]), until=until)
    explicit = single_runs.probe_run(runs.paper_push(FORCE, height=0.0), "both", until=until)
    default = single_runs.probe_run(runs.paper_push(FORCE), "both", until=until)
    helpers.assert_same_run(over.result, explicit.result)
    diff = max(float(np.max(np.abs(a.q - b.q))) for a, b in zip(over.result.records, default.result.records))
    assert diff > 1e-6


# ------------------------------------------------------------------------------------------ search
def test_cheap_search_is_consistent_and_says_what_it_ran(tmp_path, capsys):
    out = tmp_path / "mp.json"
    rc = ex.main(["max-push", "--mode", "none", "--max", "50", "--coarse", "50", "--resolution", "25",
                  "--observer", "off", "--set", "Kp=900", "--set", "Kv=60", "--workers", "2", "--json", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "Kp=900" in printed and "disturbance_observer=False" in printed
    data = json.loads(out.read_text())
    assert data["settings"] == {"profile": "default", "differs": {"Kp": 900, "Kv": 60, "disturbance_observer": False}}
    r = data["modes"]["none"]
    assert r["settings"]["differs"]["Kp"] == 900 and r["settings"]["differs"]["disturbance_observer"] is False
    tried = r["trials"]
    assert tried and [x["force"] for x in tried] == sorted(x["force"] for x in tried)
    by_force = {x["force"]: x for x in tried}
    assert set(by_force) >= {50.0}
    if r["first_failure"] is None:           # survived everything scanned
        assert all(x["survived"] for x in tried) and r["max_force"] == 50.0
    else:
        assert not by_force[r["first_failure"]]["survived"]
        assert 0 < r["first_failure"] - r["max_force"] <= 25.0
        assert r["max_force"] == 0.0 or by_force[r["max_force"]]["survived"]
    for x in tried:
        assert x["survived"] == (x["reason"] == "survived")
        assert x["survived"] or x["reason"]
    # a trial recomputed here with the same settings gives the same verdict (the settings reached the workers)
    s = ts.parse_overrides(["Kp=900", "Kv=60"], "off")
    again = trials.survives(runs.paper_push(50.0), "none", settings=s)
    assert (again["survived"], again["reason"]) == (by_force[50.0]["survived"], by_force[50.0]["reason"])


# ------------------------------------------------------------------------------------------ probe
def test_probe_shows_the_paper_controller_tipping_on_its_reaction_prediction():
    """The mechanism docs/paper_method.md reports, checked on the probe's own numbers: without the observer
    the QP holds the predicted l at l_M - margin_zmp (ZMP row active) while the applied ankle torque is the
    same for both l's (l_act F_z = Gamma_1 = l_pred R_y,pred: the foot's weight acts at the ankle), so the
    robot tips at the toe once R_y,pred / F_z reaches l_M / (l_M - margin_zmp)."""
    s = ts.parse_overrides([], "off")
    c = s.ctrl_config("both")
    l_max = tcontext.context().desc.foot.l_max
    r = single_runs.probe(runs.paper_push(300.0), "both", settings=s, after=0.0)
    assert not r["survived"] and r["fall_cause"] == "tip_toe"
    during = [x for x in r["periods"] if _in_push(x["t"])]
    assert len(during) >= 10
    for x in during:
        helpers.assert_close(x["l_act"] * x["R_act"][1], x["l_pred"] * x["R_pred"][1], 1e-6, f"Gamma_1 at t = {x['t']}",
                             rel=True)
    active = [x for x in during if x["qp_status"] == "ACTIVE"]
    assert active and all(x["tightest"] == "zmp_toe" for x in active)
    helpers.assert_close([x["l_pred"] for x in active], np.full(len(active), l_max - c.margin_zmp), 1e-6,
                         "predicted l held on the QP's limit")
    last = during[-1]
    assert last["R_pred"][1] / last["R_act"][1] > l_max / (l_max - c.margin_zmp) - 2e-3
    assert all(x["R_act"][1] < x["R_pred"][1] for x in during[1:])   # the push lowers the real R_y here
