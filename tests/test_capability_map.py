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
from biped_controller.studies import experiment
from biped_sim.robot.description import load_description
from biped_sim.robot.floating import FloatingModel


# ------------------------------------------------------------------------------------------ synthetic
class Interrupted(RuntimeError):
    """Raised by the synthetic survival function to stop a map part-way (a killed run)."""


class FakeSurvives:
    """Stands in for ``experiment.survives`` (same signature and result keys): survival is a known
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

    def __call__(self, force, mode, duration=experiment.DEFAULT_DURATION, start=experiment.DEFAULT_START,
                 height=None, settings=experiment.DEFAULT_SETTINGS):
        if self.stop_after is not None and sum(self.calls.values()) >= self.stop_after:
            raise Interrupted("stopped")
        direction = "forward" if force > 0 else "backward"
        self.calls[(mode, direction, start, duration, abs(force))] += 1
        e, isl = self.edge(mode, direction, start, duration)
        f = abs(force)
        ok = f < e or any(a <= f <= b for a, b in isl)
        return {"force": float(force), "mode": mode, "survived": ok, "reason": "survived" if ok else "fell: tip_toe",
                "fall_cause": "" if ok else "tip_toe", "fall_time": None if ok else start + 0.01,
                "steps_walked": 11 if ok else 0}


SYN_SPEC = cm.MapSpec(modes=("tau", "p"), directions=("forward", "backward"), phases=(0.0, 0.5),
                      durations=(0.025,), search=cm.Search(coarse=50.0, fmax=500.0, resolution=5.0))


@pytest.fixture
def fake(monkeypatch):
    f = FakeSurvives()
    monkeypatch.setattr(experiment, "survives", f)
    return f


def test_search_edges_and_islands_on_a_synthetic_survival_function(fake):
    run = cm.run_map(SYN_SPEC)
    T = experiment.context().family.T
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
    monkeypatch.setattr(experiment, "survives", fake)
    spec = cm.MapSpec(modes=("both",), directions=("forward",), phases=(0.25,), durations=(0.1,),
                      search=cm.Search(coarse=100.0, fmax=300.0, resolution=5.0))
    run = cm.run_map(spec)
    b = run.boundaries[cm.Cell("both", "forward", 0.25, 0.1)]
    assert b == cm.Boundary(300.0, None, ())
    s = cm.cell_summary(run, cm.Cell("both", "forward", 0.25, 0.1))
    assert s["censored"] and s["cause"] is None and s["simulations"] == 3
    assert cm.island_ranges([100.0, 150.0, 200.0, 400.0], 50.0) == [[100.0, 200.0], [400.0, 400.0]]
    assert cm.island_ranges([], 50.0) == []


@pytest.mark.parametrize("mode,direction,phase", [("p", "forward", 0.5), ("p", "backward", 0.0), ("tau", "backward", 0.5)])
def test_search_equals_experiment_max_push(fake, mode, direction, phase):
    """The same synthetic function through experiment.max_push (coarse scan + bisect_edge) and through
    the map: the same edge, first failure and islands, to the last bit (same midpoints)."""
    spec = cm.MapSpec(modes=(mode,), directions=(direction,), phases=(phase,), durations=(0.025,),
                      search=cm.Search(coarse=50.0, fmax=500.0, resolution=5.0))
    run = cm.run_map(spec)
    b = run.boundaries[cm.Cell(mode, direction, phase, 0.025)]
    start = cm.onset_time(phase, experiment.context().family.T)
    ref = experiment.max_push(mode, 5.0, 500.0, 50.0, duration=0.025, start=start, workers=1, progress=False,
                              sign=cm.DIRECTIONS[direction])
    assert (b.lo, b.hi, list(b.islands)) == (ref["max_force"], ref["first_failure"], ref["islands"])
    assert sorted(r["force"] for r in ref["trials"]) == sorted(run.records[cm.Cell(mode, direction, phase, 0.025)])


def test_resume_after_an_interruption_does_no_simulation_twice(monkeypatch, tmp_path):
    ref_fake = FakeSurvives()
    monkeypatch.setattr(experiment, "survives", ref_fake)
    ref = cm.run_map(SYN_SPEC)
    n_total = ref.simulated
    k = 23
    store = cm.RecordStore(tmp_path / "records.jsonl")
    first = FakeSurvives(stop_after=k)
    monkeypatch.setattr(experiment, "survives", first)
    with pytest.raises(Interrupted):
        cm.run_map(SYN_SPEC, store=store)
    assert len(store.load()) == k                      # every completed simulation was stored at once
    with open(store.path, "a") as fh:                  # and a record torn by the kill
        fh.write('{"mode": "p", "direction": "forw')
    second = FakeSurvives()
    monkeypatch.setattr(experiment, "survives", second)
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
    monkeypatch.setattr(experiment, "survives", third)
    again = cm.run_map(SYN_SPEC, store=store)
    assert again.simulated == 0 and sum(third.calls.values()) == 0 and again.boundaries == ref.boundaries


def test_report_only_runs_nothing_and_leaves_incomplete_cells_out(monkeypatch, tmp_path):
    store = cm.RecordStore(tmp_path / "records.jsonl")
    monkeypatch.setattr(experiment, "survives", FakeSurvives(stop_after=30))
    with pytest.raises(Interrupted):
        cm.run_map(SYN_SPEC, store=store)
    counting = FakeSurvives()
    monkeypatch.setattr(experiment, "survives", counting)
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
    other = cm.MapSpec(**{**spec.__dict__, "settings": experiment.parse_overrides(["Kp=900"])})
    assert cm.fingerprint(other) != run.fingerprint
    before = sum(fake.calls.values())
    run2 = cm.run_map(other, store=store)
    assert run2.resumed == 0 and run2.ignored == run.simulated
    assert sum(fake.calls.values()) - before == run2.simulated > 0
    assert len(cm.load_records(store.path, run.fingerprint)) == run.simulated


def test_store_rejects_a_malformed_middle_line(tmp_path):
    p = tmp_path / "r.jsonl"
    p.write_text('{"a": 1}\nnot json\n{"b": 2}\n')
    with pytest.raises(cm.StoreError, match=":2:"):
        cm.RecordStore(p).load()
    q = tmp_path / "q.jsonl"
    q.write_text('{"a": 1}\n{"b": 2}')                # complete last record without its newline
    s = cm.RecordStore(q)
    assert s.load() == [{"a": 1}, {"b": 2}]
    s.append([{"c": 3}])
    assert s.load() == [{"a": 1}, {"b": 2}, {"c": 3}]


def test_failure_cause_from_experiment_survival_reasons():
    fam = experiment.context().family
    imp = [SimpleNamespace(t=1.0 + i) for i in range(experiment.SURVIVAL_STEPS)]

    def reason(**kw):
        st = SimpleNamespace(p=kw.get("p", fam.p_d), tau_dot=kw.get("tau_dot", 1.0))
        res = SimpleNamespace(fallen=False, impacts=kw.get("impacts", imp), statuses=[st])
        ok, why = experiment.survival(res, 0.5)
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
    assert cm.phases_of(20)[10] == 0.5 and cm.onset_time(0.5, 0.463) == experiment.DEFAULT_START
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
def test_ray_and_pool_give_identical_records(pool_store, tmp_path):
    import ray
    path, pool_run = pool_store
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        ex = cm.RayExecutor(None, 2)
        assert not ex.owned
        run = cm.run_map(REAL_SPEC, ex, cm.RecordStore(tmp_path / "ray.jsonl"), batch=2)
        ex.close()
    finally:
        ray.shutdown()
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
