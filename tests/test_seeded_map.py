"""The capability map over seeds (studies.capmap.seeded, ``scripts/capability_map --seeds N``) on a synthetic
survival curve in place of the simulator: each cell is the seeded table of its push window, a rerun takes
finished cells from the store, and the band figure is written; deterministic settings keep the plain map."""
from __future__ import annotations

import math

import numpy as np

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
    rows = sm.crossing_table(res)
    assert len(rows) == 2 + 2 * 2 and "90 % crossing" in rows[0]
    assert sm.band_figure(res, tmp_path / "bands.png").stat().st_size > 0
