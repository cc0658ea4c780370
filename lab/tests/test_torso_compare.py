"""lab.torso_compare.map_comparison: a capability map's boundaries read back per duration and direction,
against sums done by hand on a small synthetic map (means over the phases both modes have, ratio of means,
higher / equal / lower phases, the best cell); the command line on a summary file."""
from __future__ import annotations

import json

import pytest

from lab import torso_compare


def _b(mode, direction, phase, force, duration=0.025, censored=False):
    return {"mode": mode, "direction": direction, "phase": phase, "duration": duration, "force": force,
            "censored": censored}


BOUNDS = [_b("both", "forward", 0.0, 400.0), _b("both", "forward", 0.5, 600.0),
          _b("all", "forward", 0.0, 500.0), _b("all", "forward", 0.5, 600.0),
          _b("both", "backward", 0.0, 1000.0), _b("both", "backward", 0.5, 200.0),
          _b("all", "backward", 0.0, 900.0),                       # phase 0.5 missing in mode all
          _b("both", "forward", 0.0, 100.0, 0.1), _b("all", "forward", 0.0, 150.0, 0.1, censored=True)]


def test_means_ratios_and_phases_by_hand():
    out = torso_compare.map_comparison(BOUNDS, "both", ("all",))
    g = {(x["duration"], x["direction"]): x for x in out["groups"]}
    assert list(g) == [(0.025, "forward"), (0.025, "backward"), (0.1, "forward")]
    f = g[(0.025, "forward")]["modes"]["all"]
    assert (f["mean"], f["base_mean"]) == (550.0, 500.0) and f["ratio"] == pytest.approx(1.1, rel=1e-15)
    assert (f["higher"], f["equal"], f["lower"]) == ([0.0], [0.5], [])
    assert f["best"] == {"phase": 0.0, "ratio": 1.25}
    b = g[(0.025, "backward")]["modes"]["all"]
    # the missing cell leaves both means: 900 vs 1000 (negative control: with it both's mean would be 600)
    assert (b["mean"], b["base_mean"], b["missing_phases"]) == (900.0, 1000.0, [0.5])
    assert b["lower"] == [0.0] and b["ratio"] == pytest.approx(0.9, rel=1e-15)
    assert g[(0.025, "backward")]["modes"]["both"]["mean"] == 600.0
    c = g[(0.1, "forward")]["modes"]["all"]
    assert c["censored"] == [True] and c["ratio"] == 1.5


def test_cli_reads_a_summary_and_names_a_bad_one(tmp_path, capsys):
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"boundaries": BOUNDS}))
    out = tmp_path / "cmp.json"
    assert torso_compare.main([str(path), "--modes", "all", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "all / both: mean 550.0 vs 500.0 N = 1.100x" in text
    assert json.loads(out.read_text())["groups"][0]["modes"]["all"]["mean"] == 550.0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"cells": []}))
    with pytest.raises(SystemExit):
        torso_compare.main([str(bad)])
    assert "boundaries" in capsys.readouterr().err
