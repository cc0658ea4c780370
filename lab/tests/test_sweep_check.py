"""``lab.sweep_check`` on small maps: the bracketed search replayed on a full search's records (no
simulation) against the bracketed map itself, on the synthetic survival functions of
``tests/test_capability_map.py``; ``replay`` of a small rigid store (a record replays unchanged, an edited
one is reported changed, one of another fingerprint is skipped)."""
from __future__ import annotations

import pytest

from biped_controller.closed_loop import runner
from biped_controller.studies import capability_map as cm
from biped_controller.studies.capmap import task
from biped_controller.studies.capmap.spec import Cell, SimSpec
from biped_controller.studies.trial import settings as ts
from biped_controller.studies.trial import trials

from lab import sweep_check
from lab.sweep_check import replay

from test_capability_map import NB_SPEC, NEAR_HOLE_SPEC, NearHoleSurvives, SteepSurvives


@pytest.mark.parametrize("fake_cls,spec", [(NearHoleSurvives, NEAR_HOLE_SPEC), (SteepSurvives, NB_SPEC)])
def test_replay_on_full_records_gives_the_bracketed_maps_simulations_and_differences(monkeypatch, fake_cls, spec):
    """sweep_check.bracket_replay (the bracketed search run on a full search's records, no simulation) against the
    bracketed map itself for each island window and bracket check: the same simulations wherever every
    force it needs is recorded, and the same cells differing from the full search (a hole one survivable
    step under the edge: check 1 differs, 2 does not; islands beyond a window of 0 differ)."""
    monkeypatch.setattr(trials, "survives", fake_cls())
    full = cm.run_map(cm.MapSpec(**{**spec.__dict__, "neighbours": False}))
    records = [r for rs in full.records.values() for r in rs.values()]
    out = sweep_check.bracket_replay(records, (0, 2), (1, 2), spec.search)
    assert out["cells"] == len(spec.cells()) and out["simulations_full"] == full.simulated
    answer = lambda b: (b.lo, b.hi, tuple(b.islands), b.no_fall_lo, b.no_fall_hi)  # noqa: E731
    counts = {}
    for run in out["runs"]:
        w, b = run["island_window"], run["bracket_check_below"]
        monkeypatch.setattr(trials, "survives", fake_cls())
        nb = cm.run_map(cm.MapSpec(**{**spec.__dict__, "neighbours": True, "island_window": w, "bracket_check_below": b}))
        want = {(c.mode, c.direction, c.duration, c.phase) for c, bb in nb.boundaries.items()
                if answer(bb) != answer(full.boundaries[c])}
        assert {tuple(d["cell"]) for d in run["differing"]} == want, (w, b)
        if not any(isinstance(d["bracketed"], str) for d in run["differing"]):
            assert run["simulations"] == nb.simulated, (w, b)
        counts[(w, b)] = run["cells_differing"]
    if fake_cls is NearHoleSurvives:
        assert counts[(2, 1)] == 3 and counts[(2, 2)] == 0
    else:
        assert counts[(0, 2)] > 0 and counts[(2, 2)] < counts[(0, 2)]


def test_replay_reports_changed_records_and_skips_other_fingerprints():
    """``sweep_check replay`` on a small rigid store: a record as the map wrote it replays unchanged, one
    with a field edited is reported changed (old, new, relative change), one of another fingerprint is
    counted and not replayed; no record depends on the trials replayed before it."""
    from biped_controller.studies.capmap.spec import MapSpec
    from biped_controller.studies.capmap.store import fingerprint
    fp = fingerprint(MapSpec(modes=("both",), settings=ts.DEFAULT_SETTINGS, neighbours=False, island_window=0))
    a = dict(task.simulate(SimSpec(Cell("both", "forward", 0.25, 0.025), 700.0), pool=runner.LoopPool()),
             fingerprint=fp)
    b = dict(task.simulate(SimSpec(Cell("both", "backward", 0.5, 0.025), 900.0), pool=runner.LoopPool()),
             fingerprint=fp)
    edited = dict(b, min_p=b["min_p"] * (1 + 1e-9))
    other = dict(a, fingerprint="0" * 16)
    out = replay([a, edited, other], ts.DEFAULT_SETTINGS)
    assert (out["replayed"], out["other_fingerprint"], out["history_dependent"]) == (2, 1, [])
    assert [c["key"] for c in out["changed"]] == [["both", "backward", 0.5, 0.025, 900.0]]
    ch = out["changed"][0]["fields"]
    assert list(ch) == ["min_p"] and ch["min_p"]["new"] == b["min_p"]
    assert ch["min_p"]["relative"] == pytest.approx(1e-9, rel=1e-3)
    assert out["outcome_changed"] == 0 and out["changed_fields"]["min_p"]["records"] == 1
