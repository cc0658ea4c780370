"""The whole-body baseline's slice table (lab/wbc_slice.py: capability-map summaries merged into one
25 ms slice, the goal check hybrid >= max(both, wbc)) on hand-made summaries whose answers are known by
construction."""
from __future__ import annotations

import json

import pytest

from lab.wbc_slice import main, map_slice, slice_report


def boundary(mode, force, phase=0.5, direction="forward", duration=0.025):
    return {"mode": mode, "direction": direction, "phase": phase, "duration": duration, "force": float(force),
            "cause": "foot_rotated", "fall_time": 0.4, "island_ranges": []}


def summary(*bounds, plant=None):
    return {"settings": {"profile": "default", "differs": {} if plant is None else {"plant": plant}},
            "boundaries": list(bounds)}


def test_summaries_merge_into_one_slice_of_the_25ms_cells():
    """One summary per mode: the cells of all of them, the 25 ms ones only."""
    cells = map_slice([("a", summary(boundary("both", 600), boundary("both", 900, duration=0.1))),
                       ("b", summary(boundary("wbc", 450), boundary("hybrid", 800)))])
    assert sorted(cells) == [("both", "forward", 0.5), ("hybrid", "forward", 0.5), ("wbc", "forward", 0.5)]
    assert cells[("both", "forward", 0.5)]["force"] == 600.0


def test_a_cell_given_twice_or_two_plants_is_an_error_naming_it():
    with pytest.raises(ValueError, match="b gives the cell both forward phase 0.5 a second time"):
        map_slice([("a", summary(boundary("both", 600))), ("b", summary(boundary("both", 650)))])
    with pytest.raises(ValueError, match="different plants: a \\(rigid\\), b \\(mujoco\\)"):
        map_slice([("a", summary(boundary("both", 600))), ("b", summary(boundary("wbc", 450), plant="mujoco"))])


def test_goal_check_met_missed_and_unknown():
    """hybrid 800 >= max(both 600, wbc 450): met; hybrid 300 below both's 600: missed (negative control: the
    check does report a miss); a phase without wbc, and every backward phase: not measured for all three."""
    cells = map_slice([("s", summary(boundary("both", 600), boundary("hybrid", 800), boundary("wbc", 450),
                                     boundary("both", 600, phase=0.0), boundary("hybrid", 300, phase=0.0),
                                     boundary("wbc", 100, phase=0.0),
                                     boundary("both", 200, phase=0.25), boundary("hybrid", 500, phase=0.25)))])
    lines, out = slice_report(cells, "test")
    g = out["goal"]
    assert g["met"] == [["forward", 0.5]]
    assert g["missed"] == [["forward", 0.0, {"wbc": 100.0, "both": 600.0, "hybrid": 300.0}]]
    assert g["unknown"] == [["forward", 0.25], ["backward", 0.0], ["backward", 0.25], ["backward", 0.5]]
    assert "met in 1 cells, missed in 1; missed forward 0: wbc 100, both 600, hybrid 300" in "\n".join(lines)


def test_command_line_writes_the_slice_under_its_plant(tmp_path):
    a, b = tmp_path / "both.json", tmp_path / "hybrid_wbc.json"
    a.write_text(json.dumps(summary(boundary("both", 600), plant="mujoco")))
    b.write_text(json.dumps(summary(boundary("hybrid", 800), boundary("wbc", 450), plant="mujoco")))
    out = tmp_path / "slice.json"
    assert main([str(a), str(b), "--json", str(out)]) == 0
    got = json.loads(out.read_text())
    assert list(got) == ["mujoco"] and got["mujoco"]["goal"]["met"] == [["forward", 0.5]]
    assert main([str(a), str(a)]) == 2          # the same cell twice: refused
