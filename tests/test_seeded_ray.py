"""The seeded max-push table on Ray gives this process's numbers (issue 43: decisions on complete batches of
seeds, each trial a pure function of its settings, seed and push). A tiny case: mode tau, one batch of two
seeds at 0 N (spread over the two Ray workers), real-sensors on the rigid plant; the Ray workers' start
(imports, kernels) is most of its time."""
from __future__ import annotations

import pytest

from biped_controller.closed_loop.executor import RayExecutor, SerialExecutor
from biped_controller.studies.trial.seeded import seeded_table
from biped_controller.studies.trial.settings import run_settings


@pytest.mark.slow
def test_the_seeded_table_on_ray_is_the_local_one(ray_session):
    settings = run_settings("real-sensors")
    kw = dict(modes=("tau",), seeds=2, resolution=100.0, fmax=0.0, coarse=100.0, progress=False,
              settings=settings)
    local = seeded_table(executor=SerialExecutor(None), **kw)
    ex = RayExecutor(None, 2)
    assert not ex.owned
    try:
        on_ray = seeded_table(executor=ex, **kw)
    finally:
        ex.close()
    assert on_ray == local          # rates, intervals, crossings, every trial's record (force, seed index order)
    assert [r["force"] for r in local["tau"]["rates"]] == [0.0]
    trials = local["tau"]["trials"]
    assert len(trials) == 2 and [t["seed"] for t in trials] == local["tau"]["seed_list"]
    assert all(t["counted"] for t in trials)        # the seeds' unpushed walks held: the rates have trials


@pytest.mark.slow
def test_the_seeded_map_on_ray_is_the_local_one(ray_session):
    """``scripts/capability_map --seeds N --ray``: one cell (mode tau, mid-step, forward 25 ms), one batch of
    two seeds (to 100 N), on Ray and in this process: the same cell, rates and crossings."""
    from biped_controller.studies.capmap import seeded as sm
    from biped_controller.studies.capmap.spec import MapSpec, Search
    spec = MapSpec(("tau",), ("forward",), (0.5,), (0.025,), Search(100.0, 100.0, 100.0), None,
                   run_settings("real-sensors"))
    local = sm.seeded_map(spec, 2, workers=1, log=None)
    on_ray = sm.seeded_map(spec, 2, workers=2, ray="local", log=None)
    assert len(local["cells"]) == 1 and local["trials_run"] == on_ray["trials_run"] > 0
    strip = [{k: v for k, v in c.items() if k != "wall_time"} for c in local["cells"]]
    assert [{k: v for k, v in c.items() if k != "wall_time"} for c in on_ray["cells"]] == strip
    assert local["cells"][0]["modes"]["tau"]["rates"]
