"""Plug-in controllers that fault, run the way a new user runs them (docs/controllers.md): a controller
whose torques turn NaN at t = 0.3 s and one that returns five torques, through the max-push table, the
capability map, a single run, the survival band, ``controllers check``; and the trial record's ``seed`` and
``fault_kind``; one ``--modes`` syntax; a progress bar whose total does not move.

Oracles: a faulted trial applies no torque from the fault on, so it is neither a survival nor a fall
(docs/experiments.md, "Survival"); where the lowest force that fell or faulted faulted, nothing bounds the
no-fall edge: it is undefined, never the scan's top. The survival rule's text for the adaptive controller
is the one committed in the results (compared as a string).
"""
from __future__ import annotations

import json
from io import StringIO
from pathlib import Path

import numpy as np
import pytest

from biped_controller.core.control.config import load_controller_config
from biped_controller.plugin.interface import ControllerSetup, ControlResult, Observation
from biped_controller.studies import capability_map as cm
from biped_controller.studies import controllers as controllers_cli
from biped_controller.studies import experiment, robustness, single_runs
from biped_controller.studies.trial import record, scan, search, survival, trials
from biped_controller.studies.trial.runs import paper_push
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings
from biped_controller.closed_loop.executor import CountingBar, ProgressBar
from biped_model.fixed_foot import FixedFootModel
from biped_sim.plant.perturbation import PlantPerturbation

NAN_AT = 0.3        # [s] the NaN controller's first NaN period


class NaNLater:
    """Computed torque on q_d(p_d, t - t_touchdown) (the paper's eqs. 15-16 on the fixed reference),
    reporting no status; six NaN torques from t = ``NAN_AT``."""

    def __init__(self, setup: ControllerSetup):
        cfg = load_controller_config()
        self.Kp, self.Kv, self.family = cfg.Kp, cfg.Kv, setup.family
        self.model = FixedFootModel(setup.desc)
        self.t0 = 0.0

    def reset(self, t, stance):
        self.t0 = t

    def on_touchdown(self, t, stance):
        self.t0 = t

    def compute(self, obs: Observation) -> ControlResult:
        if obs.t >= NAN_AT:
            return ControlResult(np.full(6, np.nan))
        g = self.family.evaluate(self.family.p_d, obs.t - self.t0)
        w = g.d2q_dtau2 + self.Kv * (g.dq_dtau - obs.qd) + self.Kp * (g.q - obs.q)
        d = self.model.dynamics(obs.q, obs.qd)
        return ControlResult(d.A @ w + d.H)


class FiveTorques(NaNLater):
    """Five torques from the first period."""

    def compute(self, obs):
        return ControlResult(np.zeros(5))


class BadInit(NaNLater):
    """Its constructor raises."""

    def __init__(self, setup):
        raise ValueError("no gains given")


NAN = f"{__name__}:NaNLater"
FIVE = f"{__name__}:FiveTorques"


# ------------------------------------------------------------------------------------------ the table
def test_table_of_a_faulting_controller_has_no_no_fall_edge(capsys):
    """Every trial of the five-torque controller faults: the survival boundary is 0 N (a fault fails the
    rule), the no-fall edge is undefined (was: the scan's top, 100 N here, "first fall none")."""
    res = search.max_push_modes((FIVE,), resolution=25.0, fmax=100.0, coarse=50.0, progress=False)
    r = res[FIVE]
    assert r["max_force"] == 0.0 and r["failure_cause"].startswith("controller fault")
    assert r["no_fall_edge"] is None and r["first_fall"] is None
    assert "undefined" in r["no_fall_undefined"] and "wrong torque shape" in r["no_fall_undefined"]
    assert all(t["fault_kind"] == "wrong torque shape" and not t["survived"] and not t["fell"] for t in r["trials"])
    search.print_max_push(res)
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith(FIVE[:6]))
    assert "undefined" in row and "100" not in row.split()[3:5] and " none " not in row
    assert f"no-fall edge, {FIVE}: undefined" in out


def _trial(force, survived, fell, fault=None):
    return {"force": force, "survived": survived, "fell": fell, "fault_kind": fault, "reason": ""}


def test_no_fall_edge_is_undefined_only_below_the_first_fall():
    """The scan's reading (pure): a fault below the first fall leaves the edge undefined; a fault above
    it does not move the edge; a fault is a failure of the survival boundary either way."""
    fault_first = [_trial(50, True, False), _trial(100, False, False, "raised"), _trial(150, False, True)]
    lo, hi, _ = scan.analyse_coarse(fault_first, "no_fall")
    assert (lo, hi) == (50, 100) and scan.no_fall_undefined(fault_first[1]) is not None
    fall_first = [_trial(50, True, False), _trial(100, False, True), _trial(150, False, False, "raised")]
    lo, hi, _ = scan.analyse_coarse(fall_first, "no_fall")
    assert (lo, hi) == (50, 100) and scan.no_fall_undefined(fall_first[1]) is None
    assert scan.analyse_coarse(fault_first, "survival")[:2] == (50, 100)
    # the map's search: the same rule on its records (force -> fell or faulted, force -> faulted)
    s = cm.Search(coarse=50.0, fmax=150.0, resolution=50.0)
    b = cm.Boundary(50.0, 100.0, ())
    got = cm.plan_no_fall(s, {50.0: False, 100.0: True, 150.0: True}, b, {50.0: False, 100.0: True, 150.0: False})
    assert got == ([], cm.Boundary(50.0, 100.0, (), no_fall_lo=None, no_fall_hi=None, no_fall_fault=100.0))
    got = cm.plan_no_fall(s, {50.0: False, 100.0: True, 150.0: True}, b, {50.0: False, 100.0: False, 150.0: True})
    assert got == ([], cm.Boundary(50.0, 100.0, (), no_fall_lo=50.0, no_fall_hi=100.0))


# ------------------------------------------------------------------------------------------ the map
def test_map_of_a_faulting_controller(tmp_path):
    """The map's summary names the no-fall edge undefined (was: "no-fall edge: mean 100.0 N", the scan's
    top); its records carry fault_kind and seed; the bar counts cells against a fixed total."""
    spec = cm.MapSpec(modes=(FIVE,), directions=("forward",), phases=cm.phases_of(2), durations=(0.025,),
                      search=cm.Search(coarse=50.0, fmax=100.0, resolution=25.0))
    buf = StringIO()
    run = cm.run_map(spec, cm.SerialExecutor(), cm.RecordStore(tmp_path / "r.jsonl"), progress=ProgressBar(buf, interval=0.0))
    summ = cm.summary(run, [])
    w = summ["findings"]["weakest"][0]
    assert "mean_no_fall_edge" not in w and w["phases_no_fall_undefined"] == [0.0, 0.5]
    cells = summ["boundaries"]
    assert all(c["no_fall_edge"] is None and c["first_fall"] is None and "faulted" in c["no_fall_undefined"]
               for c in cells)
    rule = summ["map"]["survival_by_mode"][FIVE]
    assert "reports neither p nor tau'" in rule and "|p - p_d|" not in rule
    text = "\n".join(cm.findings_text(summ["findings"]))
    assert "no-fall edge: mean" not in text and "no-fall edge: undefined at phase 0, 0.5" in text
    from biped_controller.studies.capmap.compare import compare, markdown
    table = markdown(compare([("faulting", json.loads(json.dumps(summ)))], 0.025, "rigid"))
    assert "| undefined in 2 (controller fault before any fall) |" in table and "not searched" not in table
    recs = cm.RecordStore(tmp_path / "r.jsonl").load()
    assert recs and all(r["cause"] == "controller_fault" and r["fault_kind"] == "wrong torque shape"
                        and r["seed"] is None for r in recs)
    lines = [x for x in buf.getvalue().splitlines() if x]
    assert len(lines) >= 2 and all("/2 cells searched" in x for x in lines) and lines[-1].count("2/2 cells")


# ------------------------------------------------------------------------------------------ a single run
def test_single_run_and_band_name_the_fault(capsys):
    """The headline says CONTROLLER FAULT (was "FAILED (no fall, not back on the gait)"), the band line
    says the unpushed walk faulted (was "fell"), the fault's message has plain numbers (was "joints
    [np.int64(1), ...]"), and the rule's text states no |p - p_d| / |tau' - 1| check for a controller that
    reports neither."""
    r = single_runs.push_experiment(paper_push(10.0), NAN)     # 10 N: no fall before the NaN at 0.3 s
    single_runs.print_push(r)
    out = capsys.readouterr().out
    assert "result: CONTROLLER FAULT (controller" in out and "non-finite torque" in out
    assert "FAILED" not in out and "no fall, not back" not in out
    assert "fell (controller fault" not in out and "the unpushed walk faulted (controller" in out
    assert "joints 1, 2, 3, 4, 5, 6)" in out and "np." not in out and "int64" not in out
    assert "|p - p_d|" not in r["survival"] and "|tau' - 1|" not in r["survival"]
    assert "reports neither p nor tau'" in r["survival"]
    band = single_runs.band_walk(paper_push(0.0), NAN)
    single_runs.print_band_walk(band)
    out = capsys.readouterr().out
    assert "CONTROLLER FAULT (controller" in out and "FELL" not in out and "reports neither" in out


def test_rule_text_of_the_adaptive_controller_is_unchanged():
    rule = survival.survival_rule()
    assert rule.text(survival.FLOOR_BAND) == (
        "no fall for 10 steps after the push, then |p - p_d| <= 0.001 m and |tau' - 1| <= 0.001 (the floors)")
    one = survival.Band(0.001, 0.001, 0.0, 0.0, checks_tau_dot=False)
    assert rule.text(one).endswith("(the floors) (the controller does not report tau': not checked)")
    assert "|tau' - 1|" not in rule.text(one) and "|p - p_d| <= 0.001 m" in rule.text(one)


# ------------------------------------------------------------------------------------------ controllers check
def test_check_runs_one_period(capsys):
    """``controllers check`` fails the five-torque controller (it passed before: the class has the three
    methods); the NaN one passes at t = 0, where its fault does not show, says what the check cannot
    catch, and fails at --time 0.3."""
    assert controllers_cli.main(["check", FIVE]) == 1
    out = capsys.readouterr().out
    assert "FAILED" in out and "wrong torque shape" in out and "(5,)" in out
    assert controllers_cli.main(["check", NAN]) == 0
    out = capsys.readouterr().out
    assert "six finite torques [" in out and "not caught here" in out and "np." not in out
    assert controllers_cli.main(["check", NAN, "--time", "0.3"]) == 1
    assert "non-finite torque" in capsys.readouterr().out
    assert controllers_cli.main(["check", f"{__name__}:BadInit"]) == 1
    assert "the constructor raised ValueError: no gains given" in capsys.readouterr().out
    assert controllers_cli.main(["check", "none"]) == 0
    assert controllers_cli.main(["check", NAN, "--time", "nan"]) == 2


# ------------------------------------------------------------------------------------------ command lines
def test_capability_map_help_lists_controller_fault(capsys):
    with pytest.raises(SystemExit) as ex:
        cm.main(["--help"])
    assert ex.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "controller_fault" in out and "or none with" not in out
    assert "without --controller; with --controller, only the controllers given" in out


def _modes(argv):
    return experiment.parser().parse_args(["table", *argv]).modes


def test_modes_one_syntax_everywhere(tmp_path, capsys):
    """Comma-separated (documented) and space-separated words mean the same in experiment (was: comma
    only), robustness (was: space only) and capability_map; a repeated or unknown mode is one error."""
    assert _modes(["--modes", "none,both"]) == _modes(["--modes", "none", "both"]) == ("none", "both")
    assert _modes(["--modes", "none,both", "wbc"]) == ("none", "both", "wbc")
    assert _modes([]) == experiment.TABLE_MODES
    for bad, needle in ((["none", "none"], "more than once"), (["none,wbc", "wbc"], "more than once"),
                        (["bogus"], "modes")):
        with pytest.raises(SystemExit):
            _modes(["--modes", *bad])
        assert needle in capsys.readouterr().err
    store = tmp_path / "rob"
    for argv in (["--modes", "both,none"], ["--modes", "both", "none"]):
        assert robustness.main([*argv, "--report-only", "--what", "walk", "--levels", "nominal", "--store", str(store)]) == 0
        head = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("| perturbation"))
        assert head.index("both obs on") < head.index("none [N]")
    with pytest.raises(SystemExit) as ex:
        robustness.main(["--modes", "both,both", "--report-only"])
    assert ex.value.code == 2
    from biped_controller.studies import plant_compare, torso
    for main, argv in ((plant_compare.main, ["walk", "--modes", "none,tau", "tau"]),
                       (torso.main, ["cost", "--modes", "both", "all,both"])):
        with pytest.raises(SystemExit) as ex:
            main(argv)
        assert ex.value.code == 2 and "given more than once" in capsys.readouterr().err
    for argv in (["--modes", "none,tau"], ["--modes", "none", "tau"]):
        assert cm.main([*argv, "--report-only", "--phases", "2", "--durations", "0.025", "--no-progress",
                        "--store", str(tmp_path / "none.jsonl"), "--json", str(tmp_path / "m.json")]) == 0
        assert json.loads((tmp_path / "m.json").read_text())["map"]["modes"] == ["none", "tau"]


def test_counting_bar_total_does_not_shrink():
    """The max-push table's bar: 80 coarse + at most 16 bisection steps, 88 run: it ends at 88/96 (was
    88/88, the total shrinking at the end)."""
    for why in (None, "80 coarse + 16 bisection"):
        buf = StringIO()
        bar = CountingBar(96, ProgressBar(buf, interval=0.0), *(() if why is None else (why,)))
        for _ in range(88):
            bar()
        bar.close()
        lines = buf.getvalue().splitlines()
        assert lines[0].split("]")[1].startswith(" 1/96 sims") and lines[-1].split("]")[1].startswith(" 88/96 sims")
        if why is not None:
            assert all("/96 sims (at most 96: 80 coarse + 16 bisection)" in x for x in lines)


# ------------------------------------------------------------------------------------------ the trial record
def test_trial_record_seed_and_fault_kind():
    """Every trial record carries seed (the noise seed, else None) and fault_kind; records of old stores
    are completed on load, the kind read back from a fault's reason."""
    rec = trials.survives(paper_push(40.0), "none", DEFAULT_SETTINGS)
    assert rec["seed"] is None and rec["fault_kind"] is None and rec["survived"]
    noisy = trials.survives(paper_push(40.0), "none", RunSettings(perturbation=PlantPerturbation(noise_q=1e-4, seed=3)))
    assert noisy["seed"] == 3 and noisy["fault_kind"] is None
    assert record.seed_of(PlantPerturbation(noise_q=1e-4, seed=7)) == 7
    assert record.seed_of(PlantPerturbation(torso_mass_scale=1.1, seed=7)) is None
    assert record.seed_of(RunSettings().perturbation) is None
    old = {"force": 50.0, "survived": False, "reason": "controller fault: controller 'x' at t = 0.300000 s: "
           "non-finite torque: torque [nan] (joints 1)", "cause": "controller_fault", "fall_time": None}
    assert record.complete(old) == {**old, "seed": None, "fault_kind": "non-finite torque"}
    assert record.complete({"reason": "fell: slip"}) == {"reason": "fell: slip", "seed": None, "fault_kind": None}
    with pytest.raises(record.TrialRecordError, match="seed"):
        record.complete({"reason": "survived", "seed": 1.5})
    with pytest.raises(record.TrialRecordError, match="fault_kind"):
        record.complete({"reason": "survived", "fault_kind": "bad luck"})


ROOT = Path(__file__).resolve().parents[1]
COMMITTED = sorted(ROOT.glob("results/**/*.jsonl"))


def _committed_maps() -> list[tuple[Path, Path]]:
    """(store, summary) of every committed map whose provenance command wrote both (results/*/provenance.json)."""
    pairs = set()
    for prov in ROOT.glob("results/*/provenance.json"):
        for entry in json.loads(prov.read_text()).values():
            cmd = entry.get("command", "") if isinstance(entry, dict) else ""
            words = cmd.split()
            if "capability_map" in cmd and "--store" in words and "--json" in words and "--report-only" not in words:
                st, js = ROOT / words[words.index("--store") + 1], ROOT / words[words.index("--json") + 1]
                if st.is_file() and js.is_file():
                    pairs.add((st, js))
    return sorted(pairs)


def test_committed_stores_load_with_the_new_fields_and_keep_their_keys():
    """Every committed store loads; each record gains seed None and fault_kind None (none of them faulted),
    and nothing else changes: its key and fingerprint are those of the file, so the maps resume."""
    assert COMMITTED
    for path in COMMITTED:
        raw = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
        got = cm.RecordStore(path).load()
        assert len(got) == len(raw), path
        for a, b in zip(raw, got):
            assert b == {**a, "seed": None, "fault_kind": None}, path
            assert cm.record_key(a) == cm.record_key(b) and a.get("fingerprint") == b.get("fingerprint")


@pytest.mark.parametrize("store, summary", _committed_maps(), ids=lambda p: p.name)
def test_committed_stores_give_their_committed_summaries(store, summary, monkeypatch):
    """A committed map replayed from its committed store (no simulation; the store's own fingerprint, since the
    settings moved on since it was made) gives the committed summary's boundaries and findings, every field,
    with the records completed by the new fields on load."""
    summ = json.loads(summary.read_text())
    m = summ["map"]
    from biped_controller.studies.capmap import driver
    monkeypatch.setattr(driver, "fingerprint", lambda spec: summ["fingerprint"])
    spec = cm.MapSpec(tuple(m["modes"]), tuple(m["directions"]), tuple(m["phases"]), tuple(m["durations"]),
                      cm.Search(m["coarse"], m["max"], m["resolution"], m["max_impulse"]), m["height"],
                      neighbours=m["search"] == "neighbours", island_window=m.get("island_window"),
                      bracket_check_below=m.get("bracket_check_below"))     # (None: the config's; a full search's
    #                                                                           maps predate the key and ignore it)
    run = cm.run_map(spec, store=cm.RecordStore(store), simulate=False)
    assert not run.missing and run.resumed > 0
    assert all(r["seed"] is None and r["fault_kind"] is None for recs in run.records.values() for r in recs.values())
    got = [cm.cell_summary(run, c) for c in spec.cells()]
    assert got == summ["boundaries"]
    assert cm.findings(got, spec.search.resolution) == summ["findings"]


def test_robustness_row_of_a_faulting_controller(tmp_path, capsys):
    """The robustness table's max-push cell of the five-torque controller: 0 N and the no-fall edge
    undefined (was "[no fall to 1200]", the scan's top), from the run and again from its store alone."""
    argv = ["--controller", FIVE, "--what", "push", "--levels", "nominal", "--workers", "1", "--store", str(tmp_path)]
    for extra in ([], ["--report-only"]):
        assert robustness.main(argv + extra) == 0
        row = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("| nominal"))
        assert row.split("|")[2].strip() == "0 [no-fall edge undefined: controller fault]", row


def test_plant_comparison_row_of_a_faulting_controller(tmp_path):
    """``plant_compare pushes`` from table files (reused, not run) holding the five-torque controller's row as
    the table writes it: its no-fall cell says undefined (was: a TypeError on the None edge)."""
    from biped_controller.studies import plant_compare
    res = search.max_push_modes((FIVE,), resolution=25.0, fmax=100.0, coarse=50.0, progress=False)[FIVE]
    builtin = {"max_force": 43.75, "failure_cause": "fell: tip_toe", "no_fall_edge": 43.75, "first_fall": 46.875,
               "fall_cause": "fell: tip_toe", "islands": [], "paper": None}
    rows = {**{m: builtin for m in ("none", "tau", "p", "both")}, FIVE: res}
    for obs in ("on", "off"):
        for plant in plant_compare.PLANTS:
            (tmp_path / f"table_{plant}_observer_{obs}.json").write_text(json.dumps({"modes": rows}))
    text, out = plant_compare.pushes_table(tmp_path, reuse=True, controllers=(FIVE,))
    row = next(x for x in text.splitlines() if f"| {FIVE} |" in x)
    assert row.count("undefined (controller fault)") == 2 and out[f"rigid/on/{FIVE}"]["no_fall"] is None
