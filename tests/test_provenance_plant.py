"""The provenance record's ``plant`` field: a run under a named profile records the plant that profile runs on
(its own ``plant`` setting, else the configured default), and a side-by-side table of maps records every plant
it compares (results/README.md, "Provenance")."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from biped_controller.studies import controllers, provenance

ROOT = Path(__file__).resolve().parents[1]


def test_a_profile_run_records_its_plant():
    default = provenance.default_plant()
    assert default in ("rigid", "mujoco")
    ns = lambda profile, *sets: argparse.Namespace(profile=profile, overrides=list(sets))   # noqa: E731
    assert provenance._plant_of(ns("paper")) == default                   # the profile sets no plant
    assert provenance._plant_of(ns("default")) == default
    assert provenance._plant_of(ns("real-sensors-mujoco")) == "mujoco"    # the profile's own plant
    assert provenance._plant_of(ns("paper", "plant=mujoco")) == "mujoco"  # --set overrides the profile
    assert provenance._plant_of(ns("no-such-profile")) == provenance.UNKNOWN
    assert provenance._plant_of(argparse.Namespace(json=None)) is None   # a command without settings


def test_the_maps_side_by_side_record_both_plants(tmp_path, monkeypatch):
    maps = [ROOT / "results" / "capability_map_rigid" / "summary.json",
            ROOT / "results" / "capability_map_mujoco" / "summary.json"]
    out = tmp_path / "maps.json"
    runs = []
    track = provenance.track
    monkeypatch.setattr(provenance, "track", lambda *a, **k: runs.append(track(*a, **k)) or runs[-1])
    assert controllers.main(["slices", *map(str, maps), "--duration", "0.025", "--json", str(out)]) == 0
    assert len(runs) == 1
    runs[0].finish()                     # what the exit hook does
    assert {name: rec["plant"] for name, rec in provenance.read_records(tmp_path).items()} == {"maps.json": "rigid,mujoco"}
    assert json.loads(out.read_text())["plants"].keys() == {"rigid", "mujoco"}


def test_the_committed_paper_table_records_name_their_plant():
    """The records of results/paper_table/ hold the plant each file's own settings name."""
    recs = provenance.read_records(ROOT / "results" / "paper_table")
    for name, rec in recs.items():
        if name.startswith("maps_"):
            assert rec["plant"] == "rigid,mujoco", name
        else:
            settings = json.loads((ROOT / "results" / "paper_table" / name).read_text())["modes"]["none"]["settings"]
            assert rec["plant"] == settings["differs"].get("plant", "rigid"), name
