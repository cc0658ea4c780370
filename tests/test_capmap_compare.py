"""Capability-map slices side by side (``biped_controller.studies.capmap.compare`` and
``python -m biped_controller.studies.controllers slices``) on small hand-made summaries."""
from __future__ import annotations

import json

import pytest

from biped_controller.studies.capmap.compare import CompareError, compare, markdown
from biped_controller.studies.controllers import main


def _cell(mode, direction, phase, force, *, no_fall=None, first_fall=None, censored=False, cause="tip_toe",
          duration=0.025):
    b = {"mode": mode, "direction": direction, "phase": phase, "duration": duration, "force": force,
         "censored": censored, "cause": cause}
    if no_fall is not None:
        b["no_fall_edge"], b["first_fall"] = no_fall, first_fall
    return b


def _summary(cells, plant=None, resolution=5.0):
    return {"map": {"resolution": resolution}, "settings": {"differs": {} if plant is None else {"plant": plant}},
            "boundaries": cells}


def _pair():
    a = _summary([_cell("both", "forward", 0.0, 100.0, no_fall=103.0, first_fall=106.0),
                  _cell("both", "forward", 0.5, 300.0, no_fall=320.0, first_fall=323.0),
                  _cell("both", "backward", 0.0, 50.0, no_fall=50.0, first_fall=53.0),
                  _cell("both", "backward", 0.5, 60.0, no_fall=60.0, first_fall=None, censored=True),
                  _cell("both", "forward", 0.0, 999.0, duration=0.1)])
    b = _summary([_cell("mine", "forward", 0.0, 110.0), _cell("mine", "forward", 0.5, 298.0),
                  _cell("mine", "backward", 0.0, 20.0, cause="slip"), _cell("mine", "backward", 0.5, 60.0)])
    return a, b


def test_stats_leads_and_pairs():
    a, b = _pair()
    cmp = compare([("a", a), ("b", b)], 0.025, "rigid", tie=2.0)
    p = cmp["plants"]["rigid"]
    assert p["controllers"] == ["both", "mine"]
    f = p["stats"]["both"]["forward"]
    assert f["mean"] == pytest.approx(200.0) and f["min"] == 100.0 and f["min_phases"] == [0.0]
    assert f["max"] == 300.0 and f["max_phases"] == [0.5]
    # 103 - 100 <= 5 agrees, 320 - 300 does not
    assert (f["cells_with_no_fall_edge"], f["cells_within_resolution_of_no_fall"], f["phases_below_no_fall"]) == (2, 1, [0.5])
    bk = p["stats"]["both"]["backward"]
    assert bk["cells_within_resolution_of_no_fall"] == 2 and bk["censored_phases"] == [0.5]
    assert p["stats"]["mine"]["backward"]["causes"] == {"slip": 1, "tip_toe": 1}
    assert p["stats"]["mine"]["forward"]["cells_with_no_fall_edge"] == 0
    # forward 0: mine 110 leads; 0.5: 300 vs 298 within the 2 N tie: both lead
    assert p["leaders"]["forward"] == {"0": ["mine"], "0.5": ["both", "mine"]}
    assert p["leads"]["forward"] == {"both": 1, "mine": 2}
    assert p["leads"]["backward"] == {"both": 2, "mine": 1}
    (v,) = p["versus"]
    assert (v["a"], v["b"]) == ("both", "mine")
    assert v["forward"]["b_ahead"] == ["0"] and v["forward"]["equal"] == ["0.5"] and v["forward"]["a_ahead"] == []
    assert v["backward"]["a_ahead"] == ["0"] and v["backward"]["mean_difference"] == pytest.approx(15.0)
    text = markdown(cmp)
    assert "| rigid | both | 200.0 | 100 (0) | 1 of 2 | 55.0 (1 censored) | 50 (0) | 2 of 2 | 3 of 4 |" in text
    assert "| rigid | mine |" in text and "not searched" in text
    assert "| rigid | both vs mine | 0 / 1 / 1 (-4.0) | 1 / 0 / 1 (+15.0) |" in text


def test_plants_come_from_the_settings():
    a, b = _pair()
    cmp = compare([("a", a), ("b", _summary(b["boundaries"], plant="mujoco"))], 0.025, "rigid")
    assert list(cmp["plants"]) == ["rigid", "mujoco"]
    assert cmp["plants"]["mujoco"]["controllers"] == ["mine"]


def test_bad_inputs_are_named():
    a, b = _pair()
    short = _summary([c for c in b["boundaries"] if c["phase"] == 0.0])
    with pytest.raises(CompareError, match="onset phases differ"):
        compare([("a", a), ("short", short)], 0.025, "rigid")
    with pytest.raises(CompareError, match="b: cell .* given twice"):
        compare([("a", a), ("b", _summary(b["boundaries"] * 2))], 0.025, "rigid")
    with pytest.raises(CompareError, match="no cell of duration 0.2 s"):
        compare([("a", a)], 0.2, "rigid")
    with pytest.raises(CompareError, match="x: not a capability-map summary"):
        compare([("x", {"map": {}})], 0.025, "rigid")
    with pytest.raises(CompareError, match="has no backward cells"):
        compare([("a", a), ("f", _summary([c for c in b["boundaries"] if c["direction"] == "forward"]))],
                0.025, "rigid")
    with pytest.raises(CompareError, match="tie"):
        compare([("a", a)], 0.025, "rigid", tie=-1.0)


def test_command_writes_json_and_markdown(tmp_path, capsys):
    a, b = _pair()
    pa, pb = tmp_path / "a.json", tmp_path / "b.json"
    pa.write_text(json.dumps(a))
    pb.write_text(json.dumps(b))
    out, md = tmp_path / "out" / "cmp.json", tmp_path / "out" / "cmp.md"
    assert main(["slices", str(pa), str(pb), "--json", str(out), "--markdown", str(md)]) == 0
    printed = capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["maps"] == [str(pa), str(pb)] and data["duration"] == 0.025
    assert md.read_text() == printed
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["slices", str(bad)]) == 2
    assert "bad.json" in capsys.readouterr().err
    pb.write_text(json.dumps({"map": {"resolution": 5.0}, "boundaries": [{"mode": "x"}]}))
    assert main(["slices", str(pb)]) == 2
    assert "lacks the field" in capsys.readouterr().err
