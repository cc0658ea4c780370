"""Plug-in controllers in the sweeps' worker processes and on Ray: the capability map of the example's
``capture_point`` (registered through its entry point, resolved by name inside each worker) gives the same
records in this process, on a pool of two processes and on a local Ray instance of two CPUs.

The map is small (forward, onsets 0 and 0.5 of the first step, 25 ms; coarse 30 N up to 60 N, bisected to
15 N) but real: its records hold both outcomes (the example survives 30 N and falls at 60 N at the paper's
cell: docs/controllers.md), so equal records are not equal by being all alike. The robustness study's
plug-in row takes the same path (``robustness.walk_record`` of a plug-in: its walk fields).
"""
from __future__ import annotations

import pytest

from biped_controller.studies import capability_map as cm

pytest.importorskip("capture_point_stepper")

SPEC = cm.MapSpec(modes=("capture_point",), directions=("forward",), phases=cm.phases_of(2), durations=(0.025,),
                  search=cm.Search(coarse=30.0, fmax=60.0, resolution=15.0))


def _sorted(recs):
    return sorted(recs, key=cm.record_key)


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    path = tmp_path_factory.mktemp("serial") / "records.jsonl"
    run = cm.run_map(SPEC, cm.SerialExecutor(), cm.RecordStore(path))
    recs = _sorted(cm.RecordStore(path).load())
    assert len(recs) == run.simulated >= 4
    assert any(r["survived"] for r in recs) and any(not r["survived"] for r in recs)
    assert {r["mode"] for r in recs} == {"capture_point"}
    return recs, run


def test_pool_workers_resolve_the_plugin_by_name(serial, tmp_path):
    recs, run = serial
    ex = cm.PoolExecutor(2)
    try:
        got = cm.run_map(SPEC, ex, cm.RecordStore(tmp_path / "pool.jsonl"))
    finally:
        ex.close()
    assert _sorted(cm.RecordStore(tmp_path / "pool.jsonl").load()) == recs
    assert got.boundaries == run.boundaries


@pytest.mark.slow
def test_ray_tasks_resolve_the_plugin_by_name(serial, tmp_path, ray_session):
    recs, run = serial
    ex = cm.RayExecutor(None, 2)
    got = cm.run_map(SPEC, ex, cm.RecordStore(tmp_path / "ray.jsonl"), batch=2)
    ex.close()
    assert _sorted(cm.RecordStore(tmp_path / "ray.jsonl").load()) == recs
    assert got.boundaries == run.boundaries


def test_robustness_walk_of_a_plugin():
    from biped_controller.studies import robustness
    from biped_sim.plant.perturbation import PlantPerturbation
    r = robustness.walk_record(PlantPerturbation(), "capture_point", False, steps=3)
    assert r["mode"] == "capture_point" and r["survived"] and r["steps_walked"] == 3
    assert abs(r["final_tau_dot"] - 1.0) < 1e-3 and r["max_force_estimate"] is None
    assert robustness.single_observer("capture_point") and not robustness.single_observer("both")
