"""``lab.noisy_early_stop``'s summary on synthetic logs (a survivor the criterion decides, a failing trial it would
decide: counted as the criterion's error, a failing trial never inside: its closest distance), and
``lab.seeded_store_compare --outcomes`` on two small stores (an early-stopped store against a full one: equal when
only the stopped trials' walked impacts and excursions differ, unequal when a verdict does)."""
from __future__ import annotations

import json

from biped_controller.studies.trial import stop

from lab import noisy_early_stop, seeded_store_compare

BAND = {"p_tol": 2e-3, "tau_dot_tol": 8e-3}


def _row(impact: int, scale: float, after_push: bool = True) -> dict:
    """Distances at ``scale`` times every tolerance of the criterion with :data:`BAND`."""
    from lab.sweep_check import orbit_tolerances
    tol = orbit_tolerances(stop.mujoco_early_stop(), BAND)
    return {"impact": impact, "after_push": after_push, "qd": 9.0, "delay": 1e-3, **{k: scale * v for k, v in tol.items()}}


def _log(key, survived, scales, steps=11):
    return {"key": key, "survived_full": survived, "reason_full": "", "band": BAND, "steps": steps,
            "impacts": [_row(i + 2, s, after_push=i > 0) for i, s in enumerate(scales)],
            "reproduced": {"survived": True}, "full_equals_record": True}


def test_the_summary_counts_decisions_savings_and_errors():
    es = stop.mujoco_early_stop()
    logs = [_log(["both", "forward", 0.0, 500.0, 0], True, [0.5, 2.0, 0.9, 0.5]),     # decided at impact 4
            _log(["both", "forward", 0.0, 550.0, 1], False, [0.1, 3.0, 0.8]),        # decided at 4, yet fell
            _log(["wbc", "forward", 0.0, 550.0, 2], False, [0.1, 12.0, 30.0])]       # never inside: closest 12
    out = noisy_early_stop.summarize(logs, es)
    assert out["survived_in_full"] == 1 and out["survivors_decided"] == 1 and out["decided"] == 2
    assert out["per_trial"][0]["decided_at"] == 4 and out["impacts_saved"] == (11 - 4) + (11 - 4)
    assert out["decided_but_not_survived_in_full"] == [["both", "forward", 0.0, 550.0, 1]]
    assert abs(out["failing_closest_over_tolerance"] - 12.0) < 1e-9
    assert out["reproduced"] == 3


def _store(path, trials_by_mode, key_extra=None):
    key = {"direction": "forward", "phase": 0.0, "duration": 0.025, "modes": list(trials_by_mode), "seeds": 2,
           **(key_extra or {})}
    res = {m: {"seeds": 2, "rates": [{"force": 0.0, "survived": 2}], "trials": ts} for m, ts in trials_by_mode.items()}
    path.write_text(json.dumps({"key": key, "result": res}) + "\n")


def _trial(i, survived, steps, excursion):
    return {"force": 0.0, "mode": "both", "seed_index": i, "seed": 7 + i, "survived": survived, "fell": not survived,
            "reason": "survived" if survived else "fell", "fall_cause": "", "fall_time": None, "counted": True,
            "unpushed_fall": "", "fault_kind": None, "steps_walked": steps, "max_p": excursion,
            "decided_at_step": steps if survived and steps < 11 else None}


def test_outcome_comparison_ignores_what_a_stopped_trial_cannot_share(tmp_path):
    full, fast, wrong = tmp_path / "full.jsonl", tmp_path / "fast.jsonl", tmp_path / "wrong.jsonl"
    _store(full, {"both": [_trial(0, True, 11, 0.47), _trial(1, False, 3, 0.5)]})
    _store(fast, {"both": [_trial(0, True, 5, 0.46), _trial(1, False, 3, 0.5)]}, {"early_stop": {"sensors": True}})
    _store(wrong, {"both": [_trial(0, False, 5, 0.46), _trial(1, False, 3, 0.5)]}, {"early_stop": {"sensors": True}})
    out = tmp_path / "c.json"
    assert seeded_store_compare.main([str(full), str(fast), "--outcomes", "--json", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["equal_cells"] == 1 and got["cells"][0]["stopped_early"] == {"a": 0, "b": 1}
    assert seeded_store_compare.main([str(full), str(wrong), "--outcomes", "--json", str(out)]) == 1
    got = json.loads(out.read_text())
    assert "survived" in got["cells"][0]["differences"][0] and got["trials_differing"] == 1
    assert got["crossing_estimates_differing"] == 0 and got["stopped_early"] == {"a": 0, "b": 0}
    # without --outcomes the keys differ (early_stop) and so do the trials' walked impacts: no common cell
    assert seeded_store_compare.main([str(full), str(fast), "--json", str(out)]) == 0
    assert json.loads(out.read_text())["common_cells"] == 0


def test_two_tables_compare_on_the_trials_both_ran(tmp_path):
    """``--tables``: two max-push tables over seeds as one cell each; where one search ran a force the other did
    not, those trials are counted apart and the common ones still compared."""
    def table(path, trials):
        path.write_text(json.dumps({"seeds": 2, "modes": {"both": {"seeds": 2, "rates": [], "trials": trials}}}))
    a, b, out = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "c.json"
    table(a, [_trial(0, True, 11, 0.47), _trial(1, False, 3, 0.5)])
    table(b, [_trial(0, True, 5, 0.47), _trial(1, True, 5, 0.5), dict(_trial(0, False, 3, 0.5), force=50.0)])
    assert seeded_store_compare.main([str(a), str(b), "--tables", "--outcomes", "--json", str(out)]) == 1
    got = json.loads(out.read_text())
    d = got["cells"][0]["differences"]
    assert "0 trials only in a, 1 only in b" in d[0] and got["trials_differing"] == 1 and "seed index 1" in d[1]
