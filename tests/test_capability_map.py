"""Capability map (biped_controller.studies.capability_map): the search and its islands on synthetic survival
functions (and against experiment's own max-push search), resuming from the record store with no
simulation done twice, the unit conversions against closed forms and the momentum theorem, and the
real closed loop through a process pool and through Ray giving identical records."""
from __future__ import annotations

import json
import math
import shutil
from collections import Counter
from io import StringIO
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from helpers import assert_close, central_diff

from biped_controller.studies import capability_map as cm
from biped_controller.studies.trial import context as tcontext
from biped_controller.studies.trial import runs, stop, trials
from biped_controller.studies.trial import search as tsearch
from biped_controller.studies.trial import settings as ts
from biped_controller.studies.trial import survival as tsurv
from biped_model.settings import default_config_dir
from biped_controller.core.control.controller_layout import M_, MEMORY
from biped_model.description import load_description
from biped_model.floating import FloatingModel


# ------------------------------------------------------------------------------------------ synthetic
class Interrupted(RuntimeError):
    """Raised by the synthetic survival function to stop a map part-way (a killed run)."""


class FakeSurvives:
    """Stands in for ``trials.survives`` (same signature and result keys): survival is a known
    function of (signed force, mode, start, duration) with a lowest failing edge and islands above it.
    Counts every call by its key; raises :class:`Interrupted` once ``stop_after`` calls were made."""

    # per (mode, direction): (edge [N], islands as closed force intervals [N] above the edge)
    TABLE = {
        ("p", "forward"): (269.0, [(340.0, 360.0)]),          # one coarse island at 350 (the README's p case)
        ("p", "backward"): (121.0, [(190.0, 310.0), (420.0, 430.0)]),   # coarse 200-300 survive; 420-430 holds no coarse force
        ("tau", "forward"): (362.0, []),
        ("tau", "backward"): (18.0, []),                       # the first coarse force already fails
        ("both", "forward"): (1e9, []),                        # never fails: censored
    }

    def __init__(self, stop_after: int | None = None):
        self.calls: Counter = Counter()
        self.stop_after = stop_after

    def edge(self, mode: str, direction: str, start: float, duration: float) -> tuple[float, list]:
        e, isl = self.TABLE[(mode, direction)]
        # a phase/duration dependence, so cells differ: weaker late in the step and for long pushes
        return e * (1.0 - 0.3 * start) * (0.025 / duration) ** 0.5, isl

    def __call__(self, push, mode, settings=ts.DEFAULT_SETTINGS, pool=True):
        force, start, duration = push.force, push.start, push.duration
        if self.stop_after is not None and sum(self.calls.values()) >= self.stop_after:
            raise Interrupted("stopped")
        direction = "forward" if force > 0 else "backward"
        self.calls[(mode, direction, start, duration, abs(force))] += 1
        e, isl = self.edge(mode, direction, start, duration)
        f = abs(force)
        ok = f < e or any(a <= f <= b for a, b in isl)
        return {"force": float(force), "mode": mode, "survived": ok, "fell": not ok,
                "reason": "survived" if ok else "fell: tip_toe",
                "fall_cause": "" if ok else "tip_toe", "fall_time": None if ok else start + 0.01,
                "steps_walked": 11 if ok else 0}


SYN_SPEC = cm.MapSpec(modes=("tau", "p"), directions=("forward", "backward"), phases=(0.0, 0.5),
                      durations=(0.025,), search=cm.Search(coarse=50.0, fmax=500.0, resolution=5.0))


@pytest.fixture
def fake(monkeypatch):
    f = FakeSurvives()
    monkeypatch.setattr(trials, "survives", f)
    return f


def test_search_edges_and_islands_on_a_synthetic_survival_function(fake):
    run = cm.run_map(SYN_SPEC)
    T = tcontext.context().family.T
    assert len(run.boundaries) == 8
    for cell, b in run.boundaries.items():
        e, isl = fake.edge(cell.mode, cell.direction, cm.onset_time(cell.phase, T), cell.duration)
        assert b.hi is not None
        assert b.lo < e <= b.hi, (cell, b, e)
        assert b.hi - b.lo <= SYN_SPEC.search.resolution
        coarse = SYN_SPEC.search.coarse_forces()
        first_fail = min(f for f in coarse if not (f < e or any(a <= f <= c for a, c in isl)))
        expected = tuple(f for f in coarse if f > first_fail and any(a <= f <= c for a, c in isl))
        assert b.islands == expected, (cell, b.islands, expected)
    p_fwd = run.boundaries[cm.Cell("p", "forward", 0.0, 0.025)]
    assert p_fwd.islands == (350.0,)
    p_back = run.boundaries[cm.Cell("p", "backward", 0.0, 0.025)]
    assert p_back.islands == (200.0, 250.0, 300.0)
    assert cm.island_ranges(p_back.islands, 50.0) == [[200.0, 300.0]]
    tau_back = run.boundaries[cm.Cell("tau", "backward", 0.5, 0.025)]
    assert tau_back.lo < 50.0 and tau_back.islands == ()   # the first coarse force fails: bisected from 0
    # every simulation once, and exactly the ones the records hold
    assert max(fake.calls.values()) == 1
    assert sum(fake.calls.values()) == run.simulated == sum(len(r) for r in run.records.values())


def test_censored_cell_and_island_ranges(monkeypatch):
    fake = FakeSurvives()
    monkeypatch.setattr(trials, "survives", fake)
    spec = cm.MapSpec(modes=("both",), directions=("forward",), phases=(0.25,), durations=(0.1,),
                      search=cm.Search(coarse=100.0, fmax=300.0, resolution=5.0))
    run = cm.run_map(spec)
    b = run.boundaries[cm.Cell("both", "forward", 0.25, 0.1)]
    assert b == cm.Boundary(300.0, None, (), no_fall_lo=300.0)
    s = cm.cell_summary(run, cm.Cell("both", "forward", 0.25, 0.1))
    assert s["censored"] and s["cause"] is None and s["simulations"] == 3
    assert cm.island_ranges([100.0, 150.0, 200.0, 400.0], 50.0) == [[100.0, 200.0], [400.0, 400.0]]
    assert cm.island_ranges([], 50.0) == []


@pytest.mark.parametrize("mode,direction,phase", [("p", "forward", 0.5), ("p", "backward", 0.0), ("tau", "backward", 0.5)])
def test_search_equals_experiment_max_push(fake, mode, direction, phase):
    """The same synthetic function through tsearch.max_push (coarse scan + bisect_edge) and through
    the map: the same edge, first failure and islands, to the last bit (same midpoints)."""
    spec = cm.MapSpec(modes=(mode,), directions=(direction,), phases=(phase,), durations=(0.025,),
                      search=cm.Search(coarse=50.0, fmax=500.0, resolution=5.0))
    run = cm.run_map(spec)
    b = run.boundaries[cm.Cell(mode, direction, phase, 0.025)]
    start = cm.onset_time(phase, tcontext.context().family.T)
    ref = tsearch.max_push(mode, 5.0, 500.0, 50.0, duration=0.025, start=start, workers=1, progress=False,
                              sign=cm.DIRECTIONS[direction])
    assert (b.lo, b.hi, list(b.islands)) == (ref["max_force"], ref["first_failure"], ref["islands"])
    assert sorted(r["force"] for r in ref["trials"]) == sorted(run.records[cm.Cell(mode, direction, phase, 0.025)])


def test_resume_after_an_interruption_does_no_simulation_twice(monkeypatch, tmp_path):
    ref_fake = FakeSurvives()
    monkeypatch.setattr(trials, "survives", ref_fake)
    ref = cm.run_map(SYN_SPEC)
    n_total = ref.simulated
    k = 23
    store = cm.RecordStore(tmp_path / "records.jsonl")
    first = FakeSurvives(stop_after=k)
    monkeypatch.setattr(trials, "survives", first)
    with pytest.raises(Interrupted):
        cm.run_map(SYN_SPEC, store=store)
    assert len(store.load()) == k                      # every completed simulation was stored at once
    with open(store.path, "a") as fh:                  # and a record torn by the kill
        fh.write('{"mode": "p", "direction": "forw')
    second = FakeSurvives()
    monkeypatch.setattr(trials, "survives", second)
    run = cm.run_map(SYN_SPEC, store=store)
    assert store.repaired_bytes > 0
    assert run.resumed == k and run.simulated == n_total - k
    assert not set(first.calls) & set(second.calls)    # nothing simulated twice across the two runs
    assert max(second.calls.values()) == 1
    assert run.boundaries == ref.boundaries
    recs = store.load()
    assert len(recs) == n_total
    assert len({cm.record_key(r) for r in recs}) == n_total
    # a third run finds everything
    third = FakeSurvives()
    monkeypatch.setattr(trials, "survives", third)
    again = cm.run_map(SYN_SPEC, store=store)
    assert again.simulated == 0 and sum(third.calls.values()) == 0 and again.boundaries == ref.boundaries


def test_report_only_runs_nothing_and_leaves_incomplete_cells_out(monkeypatch, tmp_path):
    store = cm.RecordStore(tmp_path / "records.jsonl")
    monkeypatch.setattr(trials, "survives", FakeSurvives(stop_after=30))
    with pytest.raises(Interrupted):
        cm.run_map(SYN_SPEC, store=store)
    counting = FakeSurvives()
    monkeypatch.setattr(trials, "survives", counting)
    part = cm.run_map(SYN_SPEC, store=store, simulate=False)
    assert sum(counting.calls.values()) == 0 and part.simulated == 0 and part.resumed == 30
    assert part.missing and part.boundaries and set(part.missing) | set(part.boundaries) == set(SYN_SPEC.cells())
    full = cm.run_map(SYN_SPEC, store=store)
    assert {c: full.boundaries[c] for c in part.boundaries} == part.boundaries
    s = cm.summary(part)
    assert len(s["boundaries"]) == len(part.boundaries) and len(s["incomplete_cells"]) == len(part.missing)
    assert cm.figures(part, tmp_path / "fig")                        # NaN where the search is incomplete


def test_records_of_another_fingerprint_are_ignored(fake, tmp_path):
    store = cm.RecordStore(tmp_path / "r.jsonl")
    spec = cm.MapSpec(modes=("tau",), directions=("forward",), phases=(0.5,), durations=(0.025,),
                      search=cm.Search(coarse=100.0, fmax=400.0, resolution=25.0))
    run = cm.run_map(spec, store=store)
    other = cm.MapSpec(**{**spec.__dict__, "settings": ts.parse_overrides(["Kp=900"])})
    assert cm.fingerprint(other) != run.fingerprint
    before = sum(fake.calls.values())
    run2 = cm.run_map(other, store=store)
    assert run2.resumed == 0 and run2.ignored == run.simulated
    assert sum(fake.calls.values()) - before == run2.simulated > 0
    assert len(cm.load_records(store.path, run.fingerprint)) == run.simulated


def test_the_early_stop_settings_are_in_the_store_fingerprint(monkeypatch):
    """A store made under other early-stop tolerances is not resumed: they decide outcomes (a mode-lambda map
    without early_stop_lambda was wrong in 64 of 120 cells, docs/torso_parameter.md)."""
    import dataclasses
    spec = cm.MapSpec(modes=("lambda",), directions=("forward",), phases=(0.5,), durations=(0.025,),
                      search=cm.Search(coarse=100.0, fmax=400.0, resolution=25.0))
    base = cm.fingerprint(spec)
    es = stop.early_stop()
    monkeypatch.setattr(stop, "early_stop", lambda: dataclasses.replace(es))
    assert cm.fingerprint(spec) == base                       # the same tolerances: the same store
    monkeypatch.setattr(stop, "early_stop", lambda: dataclasses.replace(es, lam=2 * es.lam))
    assert cm.fingerprint(spec) != base


def test_store_rejects_a_malformed_middle_line(tmp_path):
    p = tmp_path / "r.jsonl"
    p.write_text('{"a": 1}\nnot json\n{"b": 2}\n')
    with pytest.raises(cm.StoreError, match=":2:"):
        cm.RecordStore(p).load()
    q = tmp_path / "q.jsonl"
    q.write_text('{"a": 1}\n{"b": 2}')                # complete last record without its newline
    s = cm.RecordStore(q)
    new = {"seed": None, "fault_kind": None}      # the trial record's fields, filled on load (trial.record)
    assert s.load() == [{"a": 1, **new}, {"b": 2, **new}]
    s.append([{"c": 3}])
    assert s.load() == [{"a": 1, **new}, {"b": 2, **new}, {"c": 3, **new}]


def test_failure_cause_from_experiment_survival_reasons():
    fam = tcontext.context().family
    imp = [SimpleNamespace(t=1.0 + i) for i in range(tsurv.SURVIVAL_STEPS)]

    def reason(**kw):
        st = SimpleNamespace(p=kw.get("p", fam.p_d), tau_dot=kw.get("tau_dot", 1.0))
        res = SimpleNamespace(fallen=False, impacts=kw.get("impacts", imp), statuses=[st])
        ok, why = tsurv.survival(res, 0.5)
        return {"survived": ok, "reason": why, "fall_cause": ""}

    assert cm.failure_cause(reason()) == ""
    assert cm.failure_cause(reason(impacts=imp[:3])) == "time_limit"
    assert cm.failure_cause(reason(p=fam.p_d + 0.01)) == "p_not_back"
    assert cm.failure_cause(reason(tau_dot=1.01)) == "tau_dot_not_back"
    assert cm.failure_cause({"survived": False, "reason": "fell: slip", "fall_cause": "slip"}) == "slip"
    with pytest.raises(cm.MapError):
        cm.failure_cause({"survived": False, "reason": "something new", "fall_cause": ""})


def test_progress_bar_reports_done_rate_and_time_left():
    buf = StringIO()
    bar = cm.ProgressBar(buf, interval=0.0)
    bar.update(10, 5, 30, force=True)
    line = buf.getvalue()
    assert "15/45 sims" in line and "(5 resumed)" in line and "sims/s" in line and "left ~" in line


def test_spec_validation():
    with pytest.raises(cm.MapError, match="mode"):
        cm.MapSpec(modes=("fast",))
    with pytest.raises(cm.MapError, match="direction"):
        cm.MapSpec(directions=("sideways",))
    with pytest.raises(cm.MapError, match="phases"):
        cm.MapSpec(phases=(1.0,))
    with pytest.raises(cm.MapError, match="resolution"):
        cm.Search(resolution=0.0)
    with pytest.raises(cm.MapError, match="max"):
        cm.Search(coarse=100.0, fmax=50.0)
    with pytest.raises(cm.MapError, match="max_impulse"):
        cm.Search(max_impulse=0.0)
    # the impulse bound: 50 N s scans 2000 N at 0.025 s, 500 N at 0.1 s, 250 N at 0.2 s; a prefix of the
    # unbounded coarse grid (records serve either); never below one coarse step
    s = cm.Search()
    assert [len(s.for_duration(d).coarse_forces()) for d in (0.025, 0.1, 0.2, 5.0)] == [40, 10, 5, 1]
    for d in (0.1, 0.2):
        short = s.for_duration(d).coarse_forces()
        assert short == s.coarse_forces()[:len(short)]
    assert cm.Search(max_impulse=math.inf).for_duration(0.2).fmax == 2000.0
    assert cm.phases_of(4) == (0.0, 0.25, 0.5, 0.75)
    assert cm.phases_of(20)[10] == 0.5 and cm.onset_time(0.5, 0.463) == runs.DEFAULT_START
    assert set(cm.phases_of(10)) <= set(cm.phases_of(20))   # a 10-phase map's records serve the 20-phase map


# ------------------------------------------------------------------------------------------ conversions
def test_conversions_closed_forms_and_momentum_theorem():
    desc = load_description()
    fm = FloatingModel(desc)
    M = desc.total_mass
    assert_close(M, fm.mass, 1e-12, "total mass: description vs Pinocchio model")
    F, d = 362.0, 0.025
    assert cm.impulse(F, d) == F * d
    assert_close(cm.com_velocity_change(F, d, M), F * d / M, 1e-15, "delta v_com")
    assert_close(cm.body_weight_fraction(F, M, desc.gravity), F / (M * desc.gravity), 1e-15, "fraction of weight")
    # momentum theorem on the free robot: an impulse P at the torso point changes the velocities by
    # M(x)^-1 J_p^T P, and the centre of mass's velocity by J_com M^-1 J_p^T P = P / M, in any posture
    rng = np.random.default_rng(12)
    for _ in range(5):
        x = np.concatenate([[rng.uniform(-1, 1), rng.uniform(0.5, 1.0), rng.uniform(-0.5, 0.5)],
                            rng.uniform(-1.0, 1.0, 6)])
        h = rng.uniform(0.0, desc.torso.length)
        J_com = central_diff(fm.com, x, 1e-6)
        dv = fm.inverse_mass_matrix(x) @ fm.push_jacobian(x, h).T @ np.array([cm.impulse(F, d), 0.0])
        assert_close(J_com @ dv, [cm.com_velocity_change(F, d, M), 0.0], 1e-7, "J_com M^-1 J_p^T P vs F d / M")
    # negative control: the impulse on the torso alone (its mass instead of the robot's) is far off
    assert abs(F * d / desc.torso.mass - cm.com_velocity_change(F, d, M)) > 0.1


def test_summary_numbers_follow_the_closed_forms(fake):
    run = cm.run_map(SYN_SPEC)
    s = cm.summary(run)
    desc = load_description()
    M, g = desc.total_mass, desc.gravity
    assert len(s["boundaries"]) == 8 and s["robot"]["mass"] == M
    for b in s["boundaries"]:
        assert b["impulse"] == b["force"] * b["duration"]
        assert_close(b["delta_v_com"], b["force"] * b["duration"] / M, 1e-15, "dv")
        assert_close(b["body_weight_fraction"], b["force"] / (M * g), 1e-15, "bw")
        assert b["cause"] == "tip_toe"
    f = s["findings"]
    assert {(w["mode"], w["direction"]) for w in f["weakest"]} == {(m, d) for m in ("tau", "p") for d in ("forward", "backward")}
    pt = {x["direction"]: x for x in f["p_vs_tau"]}
    # synthetic: backward p (edge 121) beats tau (edge 18) at both phases; forward tau (362) beats p (269)
    assert pt["backward"]["p_better"] == [0.0, 0.5] and pt["forward"]["tau_better"] == [0.0, 0.5]
    json.dumps(s, allow_nan=False)


# ------------------------------------------------------------------------------------------ real runs
REAL_SPEC = cm.MapSpec(modes=("none",), directions=("forward",), phases=cm.phases_of(2), durations=(0.025,),
                       search=cm.Search(coarse=60.0, fmax=120.0, resolution=30.0))


def _sorted(recs):
    return sorted(recs, key=cm.record_key)


@pytest.fixture(scope="module")
def pool_store(tmp_path_factory):
    """The small real map on a local pool of two processes."""
    path = tmp_path_factory.mktemp("pool") / "records.jsonl"
    ex = cm.PoolExecutor(2)
    try:
        run = cm.run_map(REAL_SPEC, ex, cm.RecordStore(path))
    finally:
        ex.close()
    assert run.simulated == len(cm.RecordStore(path).load()) >= 4
    return path, run


@pytest.mark.slow
def test_ray_and_pool_give_identical_records(pool_store, tmp_path, ray_session):
    path, pool_run = pool_store
    ex = cm.RayExecutor(None, 2)
    assert not ex.owned
    run = cm.run_map(REAL_SPEC, ex, cm.RecordStore(tmp_path / "ray.jsonl"), batch=2)
    ex.close()
    a = _sorted(cm.RecordStore(path).load())
    b = _sorted(cm.RecordStore(tmp_path / "ray.jsonl").load())
    assert len(a) == len(b) == run.simulated
    assert a == b
    assert run.boundaries == pool_run.boundaries
    assert any(r["survived"] for r in a) and any(not r["survived"] for r in a)


@pytest.mark.slow
def test_real_map_resumes_after_truncation(pool_store, tmp_path):
    path, pool_run = pool_store
    full = _sorted(cm.RecordStore(path).load())
    k = 2
    lines = path.read_text().splitlines(keepends=True)
    trunc = tmp_path / "records.jsonl"
    trunc.write_text("".join(lines[:k]) + lines[k][: len(lines[k]) // 2])     # killed while writing record k+1
    ran: list[tuple] = []

    def counting(batch, settings, height):
        ran.extend(s.key() for s in batch)
        return cm.simulate_batch(batch, settings, height)

    run = cm.run_map(REAL_SPEC, cm.SerialExecutor(counting), cm.RecordStore(trunc))
    kept = {cm.record_key(json.loads(x)) for x in lines[:k]}
    assert run.resumed == k and len(ran) == len(full) - k == run.simulated
    assert len(set(ran)) == len(ran) and not set(ran) & kept
    assert _sorted(cm.RecordStore(trunc).load()) == full
    assert run.boundaries == pool_run.boundaries


@pytest.mark.slow
def test_cli_resumes_everything_and_writes_summary_and_figures(pool_store, tmp_path):
    path, pool_run = pool_store
    store = tmp_path / "records.jsonl"
    shutil.copy(path, store)
    out, js = tmp_path / "fig", tmp_path / "summary.json"
    rc = cm.main(["--modes", "none", "--directions", "forward", "--phases", "2", "--durations", "0.025",
                  "--coarse", "60", "--max", "120", "--resolution", "30", "--workers", "1", "--store", str(store),
                  "--out", str(out), "--json", str(js), "--no-progress"])
    assert rc == 0
    s = json.loads(js.read_text())
    assert s["run"]["simulations_run"] == 0 and s["run"]["simulations_resumed"] == pool_run.simulated
    got = {(b["phase"], b["force"], b["first_failure"]) for b in s["boundaries"]}
    want = {(c.phase, b.lo, b.hi) for c, b in pool_run.boundaries.items()}
    assert got == want
    for name in ("boundary_none.png", "heatmap_none.png", "modes.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------------------------------------------------ faster sweeps
class HoleySurvives(FakeSurvives):
    """FakeSurvives with extra failing force intervals below the edge (a "hole": survival not monotone
    below the edge), per (mode, direction), for pushes starting after 0.05 s (not at phase 0)."""

    HOLES = {("tau", "forward"): [(140.0, 160.0)]}

    def __call__(self, push, mode, settings=ts.DEFAULT_SETTINGS, pool=True):
        r = super().__call__(push, mode, settings, pool)
        force, start = push.force, push.start
        direction = "forward" if force > 0 else "backward"
        if start > 0.05 and any(a <= abs(force) <= b for a, b in self.HOLES.get((mode, direction), [])):
            r.update(survived=False, reason="fell: tip_heel", fall_cause="tip_heel", fall_time=start + 0.01, steps_walked=0)
        return r


class SteepSurvives(FakeSurvives):
    """FakeSurvives with an edge that swings with the onset (up and down, by several coarse steps between
    neighbouring phases of a 10-phase map), so the bracket has to move both ways."""

    def edge(self, mode, direction, start, duration):
        e, isl = self.TABLE[(mode, direction)]
        T = tcontext.context().family.T
        return e * (0.6 + 0.4 * math.cos(4.0 * math.pi * start / T)) * (0.025 / duration) ** 0.5, isl


NB_SPEC = cm.MapSpec(modes=("tau", "p"), directions=("forward", "backward"), phases=cm.phases_of(10),
                     durations=(0.025, 0.1), search=cm.Search(coarse=50.0, fmax=600.0, resolution=5.0))


def _edges(run):
    return {c: (b.lo, b.hi) for c, b in run.boundaries.items()}


def test_neighbour_search_finds_the_full_searchs_edges_with_fewer_simulations(monkeypatch):
    """On a synthetic survival function whose edge moves with the phase (by up to several coarse steps
    between neighbours: the bracket must move) and with islands above it: the bracketed search gives the
    full search's boundary and first failure in every cell, its islands are the full search's up to the
    first run of 2 failing coarse forces above the edge (the island window; the first phase of each row
    is searched in full and keeps them all), and it needs fewer simulations."""
    full_fake, nb_fake = SteepSurvives(), SteepSurvives()
    monkeypatch.setattr(trials, "survives", full_fake)
    full = cm.run_map(cm.MapSpec(**{**NB_SPEC.__dict__, "neighbours": False}))
    monkeypatch.setattr(trials, "survives", nb_fake)
    nb = cm.run_map(cm.MapSpec(**{**NB_SPEC.__dict__, "neighbours": True, "island_window": 2}))
    assert len(full.boundaries) == len(nb.boundaries) == len(NB_SPEC.cells())
    assert _edges(nb) == _edges(full)
    def windowed(c):
        """The full search's islands that the window reaches: scan up from the edge, stop after 2 fails."""
        fb, rec = full.boundaries[c], full.records[c]
        out, fails = [], 0
        for f in sorted(x for x in NB_SPEC.search.for_duration(c.duration).coarse_forces() if x > fb.hi):
            if fails == 2:
                break
            if rec[f]["survived"]:
                out.append(f)
                fails = 0
            else:
                fails += 1
        return tuple(out)
    far = 0
    for c, b in nb.boundaries.items():
        assert b.full == (c.phase == 0.0)              # the first phase of a row is searched in full
        if b.full:
            assert b.islands == full.boundaries[c].islands, c
        else:   # the window's, plus those the bracket's walk down from a higher neighbour passed
            assert set(windowed(c)) <= set(b.islands) <= set(full.boundaries[c].islands), c
        far += b.islands != full.boundaries[c].islands
        first = nb.records[c].get(b.hi)
        assert (first or {}).get("cause") == (full.records[c].get(full.boundaries[c].hi) or {}).get("cause")
    assert far > 0                                       # islands beyond the window exist here, and are missed
    assert nb.simulated < full.simulated, (nb.simulated, full.simulated)
    assert max(nb_fake.calls.values()) == 1
    # the bracket moved (edges of neighbouring phases differ by more than a coarse step somewhere)
    moved = [c for c in nb.boundaries if c.phase > 0 and abs(
        nb.boundaries[c].hi - nb.boundaries[cm.Cell(c.mode, c.direction, round(c.phase - 0.1, 10), c.duration)].hi) > 50.0]
    assert moved and any(nb.boundaries[c].hi > full.boundaries[cm.Cell(c.mode, c.direction, round(c.phase - 0.1, 10),
                                                                       c.duration)].hi for c in moved) \
        and any(nb.boundaries[c].hi < full.boundaries[cm.Cell(c.mode, c.direction, round(c.phase - 0.1, 10),
                                                                      c.duration)].hi for c in moved)


def test_island_window_zero_misses_islands_the_full_search_finds(monkeypatch):
    """Negative control of the island comparison: with no window above the edge the bracketed search
    reports no island where the full search finds some (the comparison above can fail)."""
    monkeypatch.setattr(trials, "survives", FakeSurvives())
    full = cm.run_map(cm.MapSpec(**{**NB_SPEC.__dict__, "neighbours": False}))
    nb = cm.run_map(cm.MapSpec(**{**NB_SPEC.__dict__, "neighbours": True, "island_window": 0}))
    assert _edges(nb) == _edges(full)
    missed = [c for c in nb.boundaries if nb.boundaries[c].islands != full.boundaries[c].islands]
    assert missed and all(not nb.boundaries[c].islands for c in missed)


def test_a_hole_below_the_bracket_is_what_the_bracket_assumes_away(monkeypatch):
    """The bracket does not simulate the coarse forces more than bracket_check_below steps under it (2
    here, the config's): a failing force there (a hole four steps under the edge) gives another first
    failure than the full search -- the assumption, shown; the full search finds the hole."""
    monkeypatch.setattr(trials, "survives", HoleySurvives())
    spec = cm.MapSpec(modes=("tau",), directions=("forward",), phases=cm.phases_of(4), durations=(0.025,),
                      search=cm.Search(coarse=50.0, fmax=600.0, resolution=5.0))
    full = cm.run_map(cm.MapSpec(**{**spec.__dict__, "neighbours": False}))
    nb = cm.run_map(cm.MapSpec(**{**spec.__dict__, "neighbours": True, "island_window": 2, "bracket_check_below": 2}))
    later = [c for c in nb.boundaries if c.phase > 0]
    assert later and all(full.boundaries[c].hi <= 150.0 for c in later)   # the hole is the full search's edge
    assert all(nb.boundaries[c].hi > 300.0 for c in later)                # the bracket, from phase 0's edge, is above it
    assert nb.boundaries[cm.Cell("tau", "forward", 0.0, 0.025)] == full.boundaries[cm.Cell("tau", "forward", 0.0, 0.025)]


def test_bracket_moves_up_down_and_censors():
    """plan_cell from a hint, on a monotone survival function with its edge at 275 N (coarse 50): from
    below, from above and from the edge itself it ends on the same coarse interval and the same
    bisection; a survival function that never fails is censored at the scan's maximum."""
    s = cm.Search(coarse=50.0, fmax=500.0, resolution=5.0)

    def solve(surv, hint, window=2):
        known: dict[float, bool] = {}
        sims = 0
        while True:
            forces, b = cm.plan_cell(s, known, hint, window, 1)
            if b is not None:
                return b, sims
            for f in forces:
                known[f] = surv(f)
                sims += 1

    edge = lambda f: f < 275.0  # noqa: E731
    ref, n_full = solve(edge, None)
    for hint in (1, 3, 6, 7, 10, math.inf):
        b, n = solve(edge, hint)
        assert (b.lo, b.hi) == (ref.lo, ref.hi) and not b.full, hint
    assert ref.full and 271.0 < ref.hi <= 275.0 + 5.0
    b, n = solve(edge, 6)
    assert n < n_full
    cen, n_cen = solve(lambda f: True, 3)
    assert cen == cm.Boundary(500.0, None, ()) and n_cen == 10     # censored only after the full scan
    # survivable again at the top (islands 450, 500 N above an edge at 150 N): a bracket started at the
    # top does not call it censored, it falls back to the full search
    top = lambda f: f < 128.0 or f >= 440.0  # noqa: E731
    full_top, _ = solve(top, None)
    assert solve(top, 10)[0] == full_top and full_top.islands == (450.0, 500.0) and full_top.hi < 150.0
    assert cm.edge_index(ref, 50.0) == 6.0 and cm.edge_index(cen, 50.0) == math.inf


def _solve(search, surv, hint, window=2, below=1):
    """Run plan_cell to its end on the survival function ``surv`` (force [N] -> survived): (boundary, the
    forces simulated in order); after every batch coarse_edge on the records so far is None or the final
    edge (the twin of the bracket never names another edge)."""
    from biped_controller.studies.capmap.search import coarse_edge
    known: dict[float, bool] = {}
    order: list[float] = []
    seen = []
    while True:
        forces, b = cm.plan_cell(search, known, hint, window, below)
        seen.append(coarse_edge(search, known, hint, window, below))
        if b is not None:
            final = cm.edge_index(b, search.coarse)
            assert all(e is None or e == final for e in seen), (seen, final)
            assert coarse_edge(search, known, hint, window, below) == final
            return b, order
        assert forces and not any(f in known for f in forces)
        for f in forces:
            known[f] = surv(f)
            order.append(f)


def _not_monotone(f: float) -> bool:
    """The MuJoCo case (docs/mujoco_plant.md, "Sweeps on MuJoCo"): 650 N fails under a survivable 700 N,
    the neighbour's edge is 750 N (coarse step 15 of 50 N)."""
    return f < 643.0 or 690.0 <= f <= 710.0


def test_bracket_checks_below_itself_and_finds_the_failure_the_old_bracket_missed():
    """A failure two coarse steps under the neighbour's edge, a survivable force between (650 N fails,
    700 N survives, the hint 750 N): the bracket that checks only its lower force (below = 1) holds at
    (700, 750] and misses the lower edge, the bracket that checks 2 under itself moves down to it and gives
    the full search's boundary; a failure under 2 survivable forces needs below = 3 (the check's depth is
    what it says)."""
    s = cm.Search(coarse=50.0, fmax=1000.0, resolution=5.0)
    surv = _not_monotone
    full, _ = _solve(s, surv, None)
    assert 640.0 < full.hi <= 650.0 and full.islands == (700.0,)
    old, order_old = _solve(s, surv, 15, below=1)
    assert 700.0 <= old.lo < old.hi <= 750.0
    assert 650.0 not in order_old                                   # never tried: assumed to survive
    new, order_new = _solve(s, surv, 15, below=2)
    assert (new.lo, new.hi) == (full.lo, full.hi) and 650.0 in order_new and not new.full
    assert new.islands == (700.0,)                                  # the survivable force passed on the way down
    # two survivable coarse forces over the failure: below = 2 misses it, below = 3 finds it
    deeper = lambda f: f < 643.0 or 690.0 <= f <= 760.0  # noqa: E731
    full2, _ = _solve(s, deeper, None)
    assert 640.0 < full2.hi <= 650.0
    assert _solve(s, deeper, 16, below=2)[0].hi > 750.0
    assert (_solve(s, deeper, 16, below=3)[0].lo, _solve(s, deeper, 16, below=3)[0].hi) == (full2.lo, full2.hi)


@pytest.mark.parametrize("edge", [25.0, 275.0, 480.0])
def test_bracket_check_below_changes_nothing_on_a_monotone_map(edge):
    """Survival monotone in the force (edge at ``edge`` N, coarse 50 N): from every hint, checking 1, 2 or 4
    coarse steps under the bracket gives the full search's boundary, first failure and bisection; the
    deeper check adds at most its extra coarse forces."""
    s = cm.Search(coarse=50.0, fmax=500.0, resolution=5.0)
    surv = lambda f: f < edge  # noqa: E731
    full, _ = _solve(s, surv, None)
    for hint in (1, 2, 3, 6, 9, 10, math.inf):
        ref, order1 = _solve(s, surv, hint, below=1)
        assert (ref.lo, ref.hi) == (full.lo, full.hi), hint
        for below in (2, 4):
            b, order = _solve(s, surv, hint, below=below)
            assert b == ref, (hint, below)
            assert set(order1) <= set(order) and len(order) <= len(order1) + below - 1, (hint, below)


def test_bracket_and_coarse_edge_agree_on_random_survival_maps():
    """The twins (plan_cell's bracket and coarse_edge) on seeded random survival maps on the coarse grid
    (several failures and islands), every hint and every check depth: coarse_edge never names an edge
    before the search ends other than the one it ends on (checked inside _solve), and the bracket equals the
    full search whenever no coarse step between the full search's edge and the hint has ``below``
    survivable coarse forces right under it (where one has, the walk down stops there: counted, both
    kinds occur)."""
    rng = np.random.default_rng(7)
    s = cm.Search(coarse=50.0, fmax=600.0, resolution=12.5)
    n = len(s.coarse_forces())
    equal = differ = 0
    for _ in range(60):
        ok = rng.random(n) < 0.6
        surv = lambda f, ok=ok: bool(ok[min(int(math.ceil(f / 50.0 - 1e-9)), n) - 1])  # noqa: E731
        full, _ = _solve(s, surv, None)
        k0 = cm.edge_index(full, 50.0)
        for hint in range(1, n + 1):
            for below in (1, 2, 3):
                b, _ = _solve(s, surv, hint, below=below)
                # a step j in (k0, hint] with `below` survivors under it: the walk down stops at or above it
                trap = any(all(ok[i - 1] for i in range(j - below, j))
                           for j in range(int(k0) + 1, hint + 1) if j - below >= 1) if k0 < hint else False
                if not trap:
                    assert cm.edge_index(b, 50.0) == k0, (ok, hint, below)
                    equal += 1
                else:
                    differ += 1
    assert equal > 0 and differ > 0


def test_bracket_check_below_is_validated_naming_the_key(tmp_path):
    src = (Path(default_config_dir()) / "studies.yaml").read_text()
    assert cm.MapSpec().bracket_check_below == cm.search_settings()["bracket_check_below"] >= 1
    p = tmp_path / "studies.yaml"
    for bad in ("0", "-1", "true", "1.5", "'2'"):
        p.write_text(src.replace("bracket_check_below: {value: 2", f"bracket_check_below: {{value: {bad}"))
        with pytest.raises(cm.MapError, match="bracket_check_below"):
            cm.search_settings(p)
    for bad in (0, -2, True, 1.0):
        with pytest.raises(cm.MapError, match="bracket_check_below"):
            cm.MapSpec(bracket_check_below=bad)
        with pytest.raises(cm.MapError, match="bracket_check_below"):
            cm.plan_cell(cm.Search(), {}, 3, 2, bad)


class NearHoleSurvives(HoleySurvives):
    """An edge at 330 N and, after phase 0, a failing 250 N under the survivable 300 N (coarse 50 N): the
    full search's edge is 250 N after phase 0, 350 N at phase 0."""

    HOLES = {("tau", "forward"): [(245.0, 255.0)]}

    def edge(self, mode, direction, start, duration):
        return 330.0, []


NEAR_HOLE_SPEC = cm.MapSpec(modes=("tau",), directions=("forward",), phases=cm.phases_of(4), durations=(0.025,),
                            search=cm.Search(coarse=50.0, fmax=600.0, resolution=5.0))


def test_a_hole_within_the_check_is_found_by_the_map(monkeypatch):
    """The driver passes the spec's check depth: a failing force one survivable coarse step under the
    neighbour's edge (a hole just below it, after phase 0) is the full search's edge; with
    bracket_check_below 2 the bracketed map finds it in every cell, with 1 it does not."""
    monkeypatch.setattr(trials, "survives", NearHoleSurvives())
    spec = NEAR_HOLE_SPEC
    full = cm.run_map(cm.MapSpec(**{**spec.__dict__, "neighbours": False}))
    two = cm.run_map(cm.MapSpec(**{**spec.__dict__, "neighbours": True, "bracket_check_below": 2}))
    one = cm.run_map(cm.MapSpec(**{**spec.__dict__, "neighbours": True, "bracket_check_below": 1}))
    later = [c for c in spec.cells() if c.phase > 0]
    assert all(full.boundaries[c].hi <= 250.0 for c in later)
    assert _edges(two) == _edges(full)
    assert all(one.boundaries[c].hi > 300.0 for c in later)


def test_run_maps_serves_several_maps_as_their_own_runs(monkeypatch, tmp_path):
    """Two one-cell maps of different settings at once on one store: the boundaries and records of
    run_map on each, each under its own fingerprint."""
    monkeypatch.setattr(trials, "survives", FakeSurvives())
    a = cm.MapSpec(modes=("tau",), directions=("forward",), phases=(0.5,), durations=(0.025,),
                   search=cm.Search(coarse=40.0, fmax=800.0, resolution=20.0))
    b = cm.MapSpec(**{**a.__dict__, "modes": ("p",), "settings": ts.parse_overrides(["Kp=900"])})
    store = cm.RecordStore(tmp_path / "r.jsonl")
    ra, rb = cm.run_maps([a, b], store=store)
    assert ra.fingerprint != rb.fingerprint
    assert ra.boundaries == cm.run_map(a).boundaries and rb.boundaries == cm.run_map(b).boundaries
    assert len(store.load()) == ra.simulated + rb.simulated
    again = cm.run_maps([a, b], store=store)
    assert [r.simulated for r in again] == [0, 0] and [r.boundaries for r in again] == [ra.boundaries, rb.boundaries]


def test_spec_search_settings_come_from_the_config():
    cfg = cm.search_settings()
    spec = cm.MapSpec()
    assert (spec.neighbours, spec.island_window, spec.bracket_check_below) == \
        (cfg["search_from_neighbours"], cfg["island_window"], cfg["bracket_check_below"])
    with pytest.raises(cm.MapError, match="island_window"):
        cm.MapSpec(island_window=-1)
    with pytest.raises(cm.MapError, match="neighbours"):
        cm.MapSpec(neighbours="yes")


# real trials
#: (force, mode, duration, phase): a 0.2 s push on mode none whose post-impact state is on the gait but
#: whose first post-impact period tips the robot over the heel (the criterion waits for that period)
EARLY_CASES = [(15.625, "none", 0.2, 0.25), (6.25, "none", 0.2, 0.45)]
EARLY_FORCES = {"both": (40.0, 300.0, 550.0, 700.0), "tau": (100.0, 300.0, 400.0), "p": (40.0, 300.0, 400.0),
                "none": (10.0, 40.0, 100.0)}


@pytest.mark.slow
def test_early_stop_gives_the_full_trials_outcome():
    """A trial stopped at its decided impact has the outcome of the same trial run in full (survived,
    reason, cause, fall time), for survivals and failures of every mode; the survivals stop earlier."""
    full = ts.RunSettings(full_trials=True)
    stopped = 0
    for mode, forces in EARLY_FORCES.items():
        for F in forces:
            a = trials.survives(runs.paper_push(F), mode)
            b = trials.survives(runs.paper_push(F), mode, settings=full)
            assert (a["survived"], a["reason"], a["fall_cause"], a["fall_time"]) == \
                   (b["survived"], b["reason"], b["fall_cause"], b["fall_time"]), (mode, F)
            assert b["decided_at_step"] is None
            if a["survived"]:
                assert a["decided_at_step"] is not None and a["decided_at_step"] < b["steps_walked"], (mode, F)
                stopped += 1
            else:
                assert a["decided_at_step"] is None and a["steps_walked"] == b["steps_walked"]
    assert stopped >= 6
    T = tcontext.context().family.T
    for F, mode, d, ph in EARLY_CASES:
        a = trials.survives(runs.paper_push(F, start=ph * T, duration=d), mode)
        b = trials.survives(runs.paper_push(F, start=ph * T, duration=d), mode, settings=full)
        assert not b["survived"] and b["fall_time"] < 0.5                      # falls just after the first impact
        assert (a["survived"], a["reason"], a["fall_cause"]) == (b["survived"], b["reason"], b["fall_cause"])


@pytest.mark.slow
def test_loose_early_stop_tolerances_would_change_an_outcome(monkeypatch):
    """Negative control: with unbounded tolerances a trial is 'decided' one period after the first impact
    after the push, and a push after which the robot falls a step later (mode both, 1293.75 N backward at
    phase 0.9: one impact, then a take-off at t = 1.556 s) would be reported survived -- the comparison
    above can fail, the tolerances matter."""
    T = tcontext.context().family.T
    args = (runs.paper_push(-1293.75, start=0.9 * T, duration=0.025), "both")
    full = trials.survives(*args, settings=ts.RunSettings(full_trials=True))
    assert not full["survived"] and full["fall_cause"] and full["steps_walked"] >= 1
    inf = math.inf
    monkeypatch.setattr(stop, "early_stop", lambda: stop.EarlyStop(True, inf, inf, inf, inf, inf, inf, inf, inf))
    loose = trials.survives(*args)
    assert loose["survived"] and loose["decided_at_step"] == full["steps_walked"]


def test_early_stop_criterion_checks_every_tolerance_and_the_push_end():
    """EarlyStop.decided on a synthetic state 0.7 ms after an impact: on the gait's orbit it holds; each
    quantity just outside its tolerance (and an impact before the push's end) makes it fail."""
    from biped_model.description import LEFT
    from biped_model.floating import FloatingModel, urdf_from_paper
    fam = tcontext.context().family
    es = stop.early_stop()
    g = fam.evaluate(fam.p_d, 0.0007)

    def state(dq=0.0, dqd=0.0, dp=0.0, dpd=0.0, dtd=0.0, F=0.0, t_imp=1.0, lam=0.0, lam_dot=0.0):
        dqv, dqdv = np.zeros(6), np.zeros(6)
        dqv[2], dqdv[4] = dq, dqd
        x = np.concatenate([np.zeros(3), urdf_from_paper(g.q + dqv, LEFT)])
        v = np.concatenate([np.zeros(3), urdf_from_paper(g.dq_dtau + dqdv, LEFT)])
        sim = SimpleNamespace(impact_log=[SimpleNamespace(t=t_imp)], t=t_imp + 0.0007, x=x, v=v, stance=LEFT,
                              fm=FloatingModel)
        mem = MEMORY.new()
        mem[M_.lam], mem[M_.lam_dot] = lam, lam_dot
        ctrl = SimpleNamespace(state=SimpleNamespace(p=fam.p_d + dp, p_dot=dpd, tau_dot=1.0 + dtd), force_estimate=F,
                               memory=mem)
        return sim, ctrl

    assert es.decided(*state(), 0.5, fam)
    assert es.decided(*state(dq=0.9 * es.q, dqd=-0.9 * es.qd, dp=0.9 * es.p, dpd=-0.9 * es.p_dot,
                             dtd=0.9 * es.tau_dot, F=-0.9 * es.force, lam=0.9 * es.lam, lam_dot=-0.9 * es.lam_dot),
                      0.5, fam)
    for kw in (dict(dq=1.1 * es.q), dict(dqd=-1.1 * es.qd), dict(dp=1.1 * es.p), dict(dpd=1.1 * es.p_dot),
               dict(dtd=-1.1 * es.tau_dot), dict(F=1.1 * es.force), dict(t_imp=0.4), dict(lam=-1.1 * es.lam),
               dict(lam_dot=1.1 * es.lam_dot)):
        assert not es.decided(*state(**kw), 0.5, fam), kw


def test_early_stop_settings_are_checked_naming_the_key(tmp_path):
    src = (Path(default_config_dir()) / "studies.yaml").read_text()
    p = tmp_path / "studies.yaml"
    p.write_text(src.replace("early_stop_qd: {value: 1.0e-1", "early_stop_qd: {value: -1.0"))
    with pytest.raises(stop.StudySettingsError, match="early_stop_qd"):
        stop.EarlyStop.load(p)
    p.write_text(src.replace("early_stop: {value: true", "early_stop: {value: 3"))
    with pytest.raises(stop.StudySettingsError, match="'early_stop'"):
        stop.EarlyStop.load(p)
    assert stop.EarlyStop.load() == stop.early_stop()


SMALL_SPEC = cm.MapSpec(modes=("tau", "p"), directions=("backward",), phases=cm.phases_of(4), durations=(0.1,),
                        search=cm.Search(coarse=50.0, fmax=500.0, resolution=12.5))


@pytest.mark.slow
def test_fast_map_gives_the_full_maps_answers_on_a_small_real_map():
    """Both speed-ups (early stop, bracketed search) against the full search with full-length trials on
    a small real map: the same boundary, first failure and cause in every cell, fewer simulations."""
    full = cm.run_map(cm.MapSpec(**{**SMALL_SPEC.__dict__, "neighbours": False,
                                    "settings": ts.RunSettings(full_trials=True)}))
    fast = cm.run_map(cm.MapSpec(**{**SMALL_SPEC.__dict__, "neighbours": True}))
    assert len(full.boundaries) == len(fast.boundaries) == 8
    for c, b in full.boundaries.items():
        f = fast.boundaries[c]
        assert (f.lo, f.hi) == (b.lo, b.hi), c
        cause = lambda run, bb: None if bb.hi is None else run.records[c][bb.hi]["cause"]  # noqa: E731
        assert cause(fast, f) == cause(full, b), c
    assert fast.simulated < full.simulated
    assert any(r.get("decided_at_step") for rs in fast.records.values() for r in rs.values())


class SteepHoleySurvives(SteepSurvives):
    """SteepSurvives with a failing band one to two coarse steps under the edge (survival not monotone
    just below it), after phase 0: the bracket's check under itself moves it down there."""

    def __call__(self, push, mode, settings=ts.DEFAULT_SETTINGS, pool=True):
        r = super().__call__(push, mode, settings, pool)
        direction = "forward" if push.force > 0 else "backward"
        e, _ = self.edge(mode, direction, push.start, push.duration)
        if push.start > 0.05 and e - 100.0 <= abs(push.force) <= e - 60.0:
            r.update(survived=False, reason="fell: tip_heel", fall_cause="tip_heel", fall_time=push.start + 0.01,
                     steps_walked=0)
        return r


@pytest.mark.parametrize("below,fake_cls", [(1, SteepSurvives), (2, SteepSurvives), (2, SteepHoleySurvives),
                                            (1, SteepHoleySurvives)])
def test_coarse_edge_is_known_before_the_cell_ends_and_equals_its_final_edge(monkeypatch, below, fake_cls):
    """The driver starts a cell's neighbour from this cell's coarse edge as soon as the bracket (or the
    coarse scan) holds (search.coarse_edge), before its islands and bisection end: that index equals
    edge_index of the finished boundary in every cell, with the bracket checking ``below`` coarse steps
    under itself (also where failures below the edge move it down); without the bisection's records it is
    already known, without the bracket's upper force or one of those under it it is not (None)."""
    from biped_controller.studies.capmap.search import coarse_edge, edge_index
    fake = fake_cls()
    monkeypatch.setattr(trials, "survives", fake)
    spec = cm.MapSpec(**{**NB_SPEC.__dict__, "neighbours": True, "island_window": 2, "bracket_check_below": below})
    run = cm.run_map(spec)
    ph = sorted(spec.phases)
    checked = unknown = 0
    for c, b in run.boundaries.items():
        search = spec.search.for_duration(c.duration)
        left = cm.Cell(c.mode, c.direction, ph[ph.index(c.phase) - 1], c.duration) if c.phase != ph[0] else None
        hint = None if left is None else edge_index(run.boundaries[left], search.coarse)
        surv = {f: r["survived"] for f, r in run.records[c].items()}
        want = edge_index(b, search.coarse)
        assert coarse_edge(search, surv, hint, 2, below) == want, c
        coarse_only = {f: s for f, s in surv.items() if abs(f / search.coarse - round(f / search.coarse)) < 1e-9}
        assert coarse_edge(search, coarse_only, hint, 2, below) == want, c        # the bisection does not move it
        checked += 1
        if b.hi is not None and hint is not None:
            k = int(want)
            for j in range(k - below, k + 1):         # the upper force and those under it the bracket checks
                if j >= 1:
                    dropped = {f: s for f, s in coarse_only.items() if f != j * search.coarse}
                    assert coarse_edge(search, dropped, hint, 2, below) is None, (c, j)
            unknown += 1
    assert checked == len(spec.cells()) and unknown > 0
