"""The one survival rule (``biped_controller.studies.trial.survival``): its verdict on pushed walks of both
plants (one that falls, one that survives without settling, one that settles), its band (never tighter
than 1 mm / 1e-3, k times the unpushed walk's excursion over the last W steps), its settings' checks, and
the search's two edges (survival boundary and no-fall edge) at the same resolution."""
from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from biped_controller.closed_loop.runner import RunResult
from biped_controller.studies.trial import runs, trials
from biped_controller.studies.trial import search as tsearch
from biped_controller.studies.trial import survival as surv
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import run_settings

P_D = context().family.p_d
RIGID = run_settings()
MUJOCO = run_settings(overrides=["plant=mujoco"])


def _walk(excursions: list[tuple[float, float, float]], impacts: list[float], fallen: bool = False) -> RunResult:
    """A synthetic unpushed walk: statuses (t, p - p_d, tau' - 1) and impact instants [s]."""
    st = [SimpleNamespace(t=t, p=P_D + dp, tau_dot=1.0 + dt) for t, dp, dt in excursions]
    return RunResult(records=[], statuses=st, steps_walked=len(impacts), fallen=fallen,
                     fall_cause="tip_toe" if fallen else "", fall_detail="", fall_time=1.0 if fallen else math.nan,
                     impacts=[SimpleNamespace(t=t) for t in impacts])


# ------------------------------------------------------------------------------------------ the band
def test_band_is_k_times_the_window_excursion_and_never_below_the_floors():
    rule = surv.SurvivalRule.of(2.0, 2)
    impacts = [0.5, 1.0, 1.5, 2.0]
    # before the window (t < 1.0, impact N - W - 1 = the 2nd): a large excursion that must not count
    big_early = [(0.2, 0.05, 0.3), (0.7, 0.02, 0.1)]
    quiet = _walk(big_early + [(1.2, 1e-5, -2e-5), (1.9, -3e-5, 1e-5)], impacts)
    b = rule.band_from_walk(quiet)
    assert (b.p_tol, b.tau_dot_tol) == (surv.P_FLOOR, surv.TAU_DOT_FLOOR) and b.is_floor
    assert b.p_excursion == pytest.approx(3e-5) and b.tau_dot_excursion == pytest.approx(2e-5)
    wide = _walk(big_early + [(1.0, -1.4e-3, 2e-3), (1.6, 1e-4, -2.5e-3)], impacts)
    b = rule.band_from_walk(wide)
    assert b.p_tol == pytest.approx(2.8e-3) and b.tau_dot_tol == pytest.approx(5e-3) and not b.is_floor
    fell = rule.band_from_walk(_walk([(0.2, 0.05, 0.3)], [0.5], fallen=True))
    assert fell.is_floor and fell.unpushed_fall.startswith("tip_toe")


def test_band_of_the_rigid_nominal_walk_is_the_floors_and_never_tighter_anywhere():
    """The rigid plant with ideal sensors settles exactly: the rule is the strict one there (every mode);
    a noisy profile's band is wider; no band is tighter than the floors."""
    rule = surv.survival_rule()
    steps = runs.trial_steps(runs.paper_push(0.0))
    for mode in ("none", "tau", "p", "both"):
        assert trials.walk_band(mode, RIGID, steps).is_floor, mode
    noisy = run_settings(profile="real-sensors", perturb=["noise_q=5e-4", "noise_qd=5e-2", "encoder_bits=14"])
    b = trials.walk_band("both", noisy, steps)
    assert b.tau_dot_tol > surv.TAU_DOT_FLOOR and b.p_tol >= surv.P_FLOOR
    assert b.tau_dot_tol == pytest.approx(rule.band_factor * b.tau_dot_excursion)


# ------------------------------------------------------------------------------------------ settings
@pytest.mark.parametrize("key,value", [("survival_band_factor", 0.5), ("survival_band_factor", ".nan"),
                                       ("survival_band_factor", "true"), ("survival_band_window", 0),
                                       ("survival_band_window", surv.SURVIVAL_STEPS + 1),
                                       ("survival_band_window", 2.5)])
def test_a_bad_rule_setting_stops_with_a_message_naming_it(tmp_path, key, value):
    good = {"survival_band_factor": 2.0, "survival_band_window": 3}
    good[key] = value
    f = tmp_path / "studies.yaml"
    f.write_text("".join(f"{k}: {{value: {v}, reason: \"r\"}}\n" for k, v in good.items()), encoding="utf-8")
    with pytest.raises(surv.SurvivalSettingsError, match=key):
        surv.SurvivalRule.load(f)


def test_the_committed_rule_loads():
    rule = surv.survival_rule()
    assert rule.steps == surv.SURVIVAL_STEPS and rule.band_factor >= 1.0 and 1 <= rule.band_window <= rule.steps


# ------------------------------------------------------------------------------------------ verdicts
def _verdicts(settings, forces, steps_short):
    """The rule's verdict on three seeded pushed walks of ``settings`` (mode both): a fall, a walk
    judged ``steps_short`` steps after the push (it has not settled yet), a full trial that settles."""
    rule = surv.survival_rule()
    out = {}
    for name, force in forces.items():
        push = runs.paper_push(force)
        if name == "unsettled":
            short = surv.SurvivalRule(steps_short, rule.band_factor, rule.band_window)
            res = runs.push_run(push, "both", steps_after=steps_short, settings=settings, keep_records=False)
            band = short.band_from_walk(runs.run(runs.trial_steps(push, steps_short), "both", (), settings=settings, keep_records=True))
            out[name] = short.verdict(res, push.end, band)
        else:
            res = runs.push_run(push, "both", settings=settings, keep_records=False)
            band = trials.walk_band("both", settings, runs.trial_steps(push))
            out[name] = rule.verdict(res, push.end, band)
    return out


def _check(v):
    assert v["falls"].fell and not v["falls"].survived and v["falls"].reason.startswith("fell:")
    assert not v["unsettled"].fell and not v["unsettled"].survived and " not back " in v["unsettled"].reason
    assert v["settles"] == surv.Verdict(True, False, "survived")


def test_verdicts_on_the_rigid_plant():
    _check(_verdicts(RIGID, {"falls": 900.0, "unsettled": 500.0, "settles": 250.0}, 1))


def test_verdicts_on_mujoco():
    _check(_verdicts(MUJOCO, {"falls": 1200.0, "unsettled": 500.0, "settles": 250.0}, 1))


# ------------------------------------------------------------------------------------------ the search's two edges
def test_search_bisects_the_survival_boundary_and_the_no_fall_edge_to_the_same_resolution(monkeypatch):
    """A synthetic trial function: fails the rule (no fall) from 230 N, falls from 410 N; both edges to
    5 N, the no-fall bisection reusing nothing it cannot."""
    calls = []

    def fake(push, mode, settings=None, pool=True):
        f = abs(push.force)
        calls.append(f)
        fell = f >= 410.0
        ok = f < 230.0
        return {"force": float(push.force), "mode": mode, "survived": ok, "fell": fell,
                "reason": "survived" if ok else ("fell: tip_toe" if fell else "tau' = 0.99 not back to 1 (> 0.001)"),
                "fall_cause": "tip_toe" if fell else "", "fall_time": 1.0 if fell else None, "steps_walked": 11,
                "decided_at_step": None}
    monkeypatch.setattr(tsearch.trials, "survives", fake)
    r = tsearch.max_push("both", 5.0, 600.0, 50.0, workers=1, progress=False)
    assert r["first_failure"] - r["max_force"] <= 5.0 and r["max_force"] < 230.0 <= r["first_failure"]
    assert r["first_fall"] - r["no_fall_edge"] <= 5.0 and r["no_fall_edge"] < 410.0 <= r["first_fall"]
    assert r["fall_cause"].startswith("fell:") and "not back" in r["failure_cause"]
    assert len(calls) == len(set(calls))          # no force simulated twice


@pytest.mark.parametrize("hint", [None, 3.0])
def test_capability_map_cell_bisects_both_edges(hint):
    """The map's cell search (``capmap.search``): the survival boundary, then the no-fall edge from the
    first failing coarse force upward, both to the resolution; full and neighbour-bracketed searches."""
    from biped_controller.studies.capmap.search import plan_cell, plan_no_fall
    from biped_controller.studies.capmap.spec import Search
    search = Search(coarse=50.0, fmax=600.0, resolution=5.0)
    survived, fell = {}, {}
    b = None
    while b is None:
        forces, b = plan_cell(search, survived, hint, 2)
        if b is not None:
            forces, b = plan_no_fall(search, fell, b)
        for f in forces:
            survived[f], fell[f] = f < 230.0, f >= 410.0
    assert b.lo < 230.0 <= b.hi and b.hi - b.lo <= 5.0
    assert b.no_fall_lo < 410.0 <= b.no_fall_hi and b.no_fall_hi - b.no_fall_lo <= 5.0
    # a cell whose first failure is a fall: the no-fall edge is the boundary, no extra simulation
    survived, fell = {}, {}
    b = None
    n = 0
    while b is None:
        forces, b = plan_cell(search, survived, hint, 2)
        if b is not None:
            forces, b = plan_no_fall(search, fell, b)
            n += len(forces)            # simulations the no-fall search asks for beyond the boundary's
        for f in forces:
            survived[f] = f < 230.0
            fell[f] = not survived[f]
    assert (b.no_fall_lo, b.no_fall_hi) == (b.lo, b.hi) and n == 0


def test_a_bad_rule_setting_stops_a_study_command_in_one_line(tmp_path, monkeypatch, capsys):
    """A command line (``scripts/experiment``) with a bad rule setting in studies.yaml: exit status 2 and
    one line naming the key, before any simulation."""
    from biped_controller.studies import experiment
    (tmp_path / "studies.yaml").write_text('survival_band_factor: {value: 0.5, reason: "r"}\n'
                                           'survival_band_window: {value: 10, reason: "r"}\n', encoding="utf-8")
    monkeypatch.setattr(surv, "default_config_dir", lambda: tmp_path)
    with pytest.raises(SystemExit) as exc:
        experiment.main(["push", "--force", "100"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "survival_band_factor" in err[0]
