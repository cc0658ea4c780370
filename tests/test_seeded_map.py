"""The capability map over seeds (studies.capmap.seeded, ``scripts/capability_map --seeds N``) on a synthetic
survival curve in place of the simulator: each cell is the seeded table of its push window, a rerun takes
finished cells from the store, and the band figure is written; deterministic settings keep the plain map."""
from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

from biped_controller.studies import robustness as rb
from biped_controller.studies.capmap import seeded as sm
from biped_controller.studies.capmap.spec import MapSpec, Search, onset_time
from biped_controller.studies.trial import seeded
from biped_controller.studies.trial import settings as ts
from biped_controller.studies.trial.context import context

SETTINGS = ts.run_settings("real-sensors")


def _trial(push, mode, settings):
    """Survival iff a draw of default_rng([seed mod 2^32, force in mN]) < 1 / (1 + exp((F - f50) / 30)),
    f50 = 400 N (both) or 300 N (wbc) plus 200 N x the push onset [s]."""
    f = abs(push.force)
    f50 = (400.0 if mode == "both" else 300.0) + 200.0 * push.start
    ok = bool(np.random.default_rng([settings.perturbation.seed % 2**32, int(round(f * 1000))]).random()
              < 1.0 / (1.0 + math.exp((f - f50) / 30.0)))
    return {"force": push.force, "mode": mode, "survived": ok, "seed": settings.perturbation.seed,
            "fault_kind": None, "unpushed_fall": "", "counted": True, "reason": "synthetic"}


def test_seeded_map_cells_resume_and_figure(monkeypatch, tmp_path):
    monkeypatch.setattr(seeded, "seeded_trial", _trial)
    spec = MapSpec(("both", "wbc"), ("forward",), (0.0, 0.5), (0.025,), Search(100.0, 800.0, 25.0), None, SETTINGS)
    store = tmp_path / "store.jsonl"
    res = sm.seeded_map(spec, 4, store=store, log=None)
    assert res["cells_resumed"] == 0 and res["trials_run"] > 0 and len(res["cells"]) == 2
    T = context().family.T
    for cell in res["cells"][1:]:
        alone = seeded.seeded_table(("both", "wbc"), 4, 25.0, 800.0, 100.0, start=onset_time(cell["phase"], T),
                                    settings=SETTINGS, progress=False)
        for m in ("both", "wbc"):
            assert cell["modes"][m]["crossings"] == alone[m]["crossings"]
            assert cell["modes"][m]["rates"] == alone[m]["rates"]
        assert cell["comparisons"] == alone["both"]["comparisons"]
    again = sm.seeded_map(spec, 4, store=store, log=None)
    assert again["trials_run"] == 0 and again["cells_resumed"] == 2 and again["cells"] == res["cells"]
    more = sm.seeded_map(MapSpec(("both", "wbc"), ("forward",), (0.0, 0.25, 0.5), (0.025,), Search(100.0, 800.0, 25.0),
                                 None, SETTINGS), 4, store=store, log=None)
    assert more["cells_resumed"] == 2 and [c["phase"] for c in more["cells"]] == [0.0, 0.25, 0.5]
    only = sm.seeded_map(MapSpec(("both", "wbc"), ("forward",), (0.0, 0.75), (0.025,), Search(100.0, 800.0, 25.0),
                                 None, SETTINGS), 4, store=store, log=None, simulate=False)
    assert only["trials_run"] == 0 and [c["phase"] for c in only["cells"]] == [0.0]
    assert only["cells_missing"] == [{"direction": "forward", "phase": 0.75, "duration": 0.025}]
    rows = sm.crossing_table(res)
    assert len(rows) == 2 + 2 * 2 and "90 % crossing" in rows[0]
    assert sm.band_figure(res, tmp_path / "bands.png").stat().st_size > 0


@pytest.mark.parametrize("module,argv,needle", [
    ("capability_map", ["--seeds", "0"], "--seeds"), ("capability_map", ["--seeds", "-2"], "--seeds"),
    ("capability_map", ["--seeds", "1.5"], "--seeds"), ("capability_map", ["--seeds", "4", "--levels", "1"], "--levels"),
    ("capability_map", ["--seeds", "4", "--resolution", "0"], "--resolution"),
    ("capability_map", ["--phases", "4", "--only-phases", "0.3"], "--only-phases"),
    ("robustness", ["--seeds", "0"], "--seeds"), ("robustness", ["--seeds", "3", "--survival-levels", "0.9,0"],
                                                  "--survival-levels"),
])
def test_bad_seed_counts_and_levels_are_one_line_exit_2(module, argv, needle, capsys, tmp_path):
    main = importlib.import_module(f"biped_controller.studies.{module}").main
    with pytest.raises(SystemExit) as e:
        main(argv + ["--json", str(tmp_path / "x.json")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err
    assert not (tmp_path / "x.json").exists()


def test_robustness_rows_lie_over_the_profile_perturbation():
    base = ts.run_settings("real-sensors").perturbation
    rows = {lv.key: lv for lv in rb.under_profile(rb.LEVELS, base)}
    assert rows["nominal"].perturbation == base
    t = rows["torso_mass-20"].perturbation
    assert t.torso_mass_scale == 0.8 and (t.noise_q, t.noise_qd, t.encoder_bits) == (5e-4, 5e-2, 14)
    n = rows["noise1e-3"].perturbation          # the row's noise replaces the profile's, its 14 bits stay
    assert (n.noise_q, n.noise_qd, n.encoder_bits) == (1e-3, 1e-1, 14)
    assert rb.under_profile(rb.LEVELS, None) == rb.LEVELS


def test_robustness_over_seeds_runs_only_the_noisy_rows(monkeypatch):
    monkeypatch.setattr(seeded, "seeded_trial", _trial)
    rows = (rb.LEVELS_BY_KEY["nominal"], rb.LEVELS_BY_KEY["noise5e-4"])
    recs = rb.run_seeded_pushes(rows, ("both",), (True,), 4, (0.9, 0.5), 1, False, log=lambda m: None)
    assert [(r["level"], r["mode"], r["observer"]) for r in recs] == [("noise 5e-4 rad, 5e-2 rad/s", "both", True)]
    assert [c["level"] for c in recs[0]["crossings"]] == [0.9, 0.5] and recs[0]["trials"] > 0
    md = rb.seeded_markdown(recs, 4)
    assert len([x for x in md if x.startswith("| noise")]) == 1


def test_robustness_over_seeds_resumes_from_its_store(monkeypatch, tmp_path):
    """Each seeded row is stored as it finishes; a rerun runs no trial and gives the same rows; other seeds
    are a new row; --report-only (simulate False) gives the stored rows only."""
    calls = []
    monkeypatch.setattr(seeded, "seeded_trial", lambda *a: calls.append(1) or _trial(*a))
    rows = (rb.LEVELS_BY_KEY["nominal"], rb.LEVELS_BY_KEY["noise5e-4"])
    store = rb.cmap.RecordStore(tmp_path / "seeded.jsonl")
    first = rb.run_seeded_pushes(rows, ("both",), (True,), 4, (0.9, 0.5), 1, False, log=lambda m: None, store=store)
    n = len(calls)
    assert n > 0 and len(store.load()) == 1
    again = rb.run_seeded_pushes(rows, ("both",), (True,), 4, (0.9, 0.5), 1, False, log=lambda m: None, store=store)
    assert len(calls) == n and again == first
    only = rb.run_seeded_pushes(rows, ("both",), (True,), 6, (0.9, 0.5), 1, False, log=lambda m: None, store=store,
                                simulate=False)
    assert only == [] and len(calls) == n
    six = rb.run_seeded_pushes(rows, ("both",), (True,), 6, (0.9, 0.5), 1, False, log=lambda m: None, store=store)
    assert len(calls) > n and len(store.load()) == 2 and six[0]["seeds"] == 6
