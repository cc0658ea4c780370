"""The whole-body baseline's slice tables (studies/baseline_wbc.py: no-fall edges from a map's store, the goal check
hybrid >= max(both, wbc)) on hand-made store records whose answers are known by construction."""
from __future__ import annotations

from biped_controller.studies.baseline_wbc import no_fall_slice, slice_report


def rec(mode, force, fell, phase=0.5, direction="forward"):
    return {"mode": mode, "direction": direction, "phase": phase, "force": float(force),
            "fall_time": 0.4 if fell else None, "cause": "foot_rotated" if fell else "", "survived": not fell}


def full_scan(mode, edge, coarse=100.0, top=1000.0, **kw):
    """Every coarse force up to ``top``; the ones above ``edge`` fall."""
    return [rec(mode, f, f > edge, **kw) for f in [coarse * k for k in range(1, int(top / coarse) + 1)]]


def test_no_fall_edge_full_scan_bisected_and_gaps():
    """Full scan: the largest coarse force below the first fall; a bisected bracket (within half a coarse
    step) counts; a gap below the first fall leaves the cell open (force None)."""
    cells = no_fall_slice(full_scan("both", 600.0), 100.0)
    c = cells[("both", "forward", 0.5)]
    assert (c["force"], c["first_fall"], c["complete"]) == (600.0, 700.0, True)
    bis = [rec("wbc", 400, False), rec("wbc", 450, False), rec("wbc", 456.25, True), rec("wbc", 500, True)]
    assert no_fall_slice(bis, 100.0)[("wbc", "forward", 0.5)]["force"] == 450.0
    gap = [rec("hybrid", 100, False), rec("hybrid", 300, False), rec("hybrid", 500, True)]   # 200, 400 missing
    g = no_fall_slice(gap, 100.0)[("hybrid", "forward", 0.5)]
    assert g["force"] is None and not g["complete"]


def test_goal_check_met_missed_and_unresolved():
    """hybrid 800 >= max(both 600, wbc 450): met; a cell with hybrid 300 (first fall 400) below both's 600:
    missed (negative control: the check does report a miss); hybrid's edge 500 below wbc's 530 with its first
    fall at 600: not resolved at the scan's step."""
    recs = (full_scan("both", 600.0) + full_scan("hybrid", 800.0)
            + [rec("wbc", 400, False), rec("wbc", 450, False), rec("wbc", 453.125, True)]
            + full_scan("both", 600.0, phase=0.0) + full_scan("hybrid", 300.0, phase=0.0)
            + [rec("wbc", 100, False, phase=0.0), rec("wbc", 103.125, True, phase=0.0), rec("wbc", 200, True, phase=0.0)]
            + full_scan("both", 200.0, phase=0.25) + full_scan("hybrid", 500.0, phase=0.25)
            + [rec("wbc", 530, False, phase=0.25), rec("wbc", 533.125, True, phase=0.25)])
    _, out = slice_report(no_fall_slice(recs, 100.0), "test")
    g = out["goal"]
    assert g["met"] == [["forward", 0.5]]
    assert [m[:2] for m in g["missed"]] == [["forward", 0.0]]
    assert [m[:2] for m in g["resolution"]] == [["forward", 0.25]]
