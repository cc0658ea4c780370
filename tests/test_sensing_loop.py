"""Real sensing in the compiled closed loops (``loop_kernels.run_segment``'s and
``mujoco_loop_kernels.run_mujoco_segment``'s ``sensing``, issue 43): the plant's sensor noise drawn ahead in
blocks is the generators' one-by-one draws, and a noisy run with the compiled loop is the objects' run
(``SensorModel.sample`` + ``AdaptiveController.compute`` on the compiled sensing pipeline + ``Simulator.step`` or
``MujocoPlant.step``) record for record, status for status (the statuses carry the pipeline's outputs: the
observer's dR, F_x and the rows' widening), on either plant."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from biped_sim.plant.perturbation import PlantPerturbation, SensorModel
from biped_sim.plant.push import Push

from biped_controller.closed_loop import runner, segment
from biped_controller.studies.trial import context as tcontext
from biped_controller.studies.trial.settings import run_settings

from test_sweep_speed import digest


def test_block_draws_are_the_one_by_one_draws_and_a_compiled_take_skips_them():
    """Row i of the pre-drawn noise is what period i drew one by one from default_rng(seed) (joints),
    default_rng([seed, 1]) (pitch), default_rng([seed, 2]) (rate), across block refills and after rows
    a compiled loop took (``taken``)."""
    p = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, noise_pitch=1e-3, noise_pitch_rate=2e-3,
                          seed=11)
    m = SensorModel(p)
    rj, rp, rr = (np.random.default_rng(s) for s in (11, [11, 1], [11, 2]))
    q, qd = np.linspace(-0.3, 0.4, 6), np.linspace(-1.0, 2.0, 6)
    step = 0
    for k in range(2 * SensorModel.BLOCK + 7):
        if k % 500 == 499:          # a compiled loop takes 37 periods: their rows are skipped
            rows = m.noise_rows(37)[:37].copy()
            m.taken(37, step + 36, 0)
            step += 37
            for row in rows:
                assert np.array_equal(row[:6], rj.standard_normal(6))
                assert np.array_equal(row[6:12], rj.standard_normal(6))
                assert row[12] == rp.standard_normal() and row[13] == rr.standard_normal()
            continue
        _, qs, qds = m.sample(step, 0, q, qd, 0.05, -0.2)
        want_q = q + 5e-4 * rj.standard_normal(6)
        want_q = p.encoder_step * np.round(want_q / p.encoder_step)
        assert np.array_equal(qs, want_q)
        assert np.array_equal(qds, qd + 5e-2 * rj.standard_normal(6))
        assert m.imu_reading(step) == (0.05 + 1e-3 * rp.standard_normal(), -0.2 + 2e-3 * rr.standard_normal())
        step += 1


def _run(settings, mode, pushes, compiled_loop, steps=3):
    settings.activate()
    ctx = tcontext.context()
    return runner.run(steps, mode, pushes, sim_config=settings.sim_config(), ctrl_config=settings.ctrl_config(mode),
                      family=ctx.family, desc=ctx.desc, perturbation=settings.perturbation,
                      compiled_loop=compiled_loop)


# (profile, mode, settings overrides, plant perturbation overrides, push force [N], steps): the design point with
# the QP's periods (both, pushed backward), the whole-body stage (wbc), the observer without the estimator and an
# IMU; on the rigid plant and on MuJoCo (two steps there: its objects cost more; a touchdown in each)
CASES = [("both", (), {"seed": 5}, -250.0), ("wbc", (), {"seed": 6}, 100.0),
         ("tau", ("state_estimator=false",), {"seed": 7, "noise_pitch": 1e-3, "noise_pitch_rate": 1e-2}, 50.0)]


@pytest.mark.parametrize("profile,mode,overrides,perturb,force,steps",
                         [("real-sensors", *c, 3) for c in CASES] + [("real-sensors-mujoco", *c, 2) for c in CASES])
def test_the_compiled_loop_with_real_sensing_is_the_objects_run(monkeypatch, profile, mode, overrides, perturb, force,
                                                                steps):
    settings = run_settings(profile, list(overrides))
    settings = replace(settings, perturbation=replace(settings.perturbation, **perturb))
    pushes = (Push(0.2315, 0.05, force),)
    ran, ends = [], []
    kind = segment.MujocoSegment if settings.sim_config().plant == "mujoco" else segment.Segment
    orig = kind.run

    def counting(self, *a, **k):
        out = orig(self, *a, **k)
        ran.append(self.n)
        ends.append(self.ended)
        return out
    monkeypatch.setattr(kind, "run", counting)
    if mode == "wbc":           # few noise rows handed to the compiled loop: its segments end there (END_NOISE)
        rows = SensorModel.noise_rows
        monkeypatch.setattr(SensorModel, "noise_rows", lambda self, n: rows(self, n)[:7])
    loops = {}
    for cl in (True, False):
        loops[cl] = _run(settings, mode, pushes, cl, steps)
    fast, objects = loops[True], loops[False]
    # the compiled loop ran most periods, and handed the sensed touchdowns back (with the estimator)
    assert sum(ran) >= 0.7 * len(objects.records), (sum(ran), len(objects.records))
    if "state_estimator=false" not in overrides:
        assert any(e.startswith("sensing needs Python") for e in ends)
    if mode == "wbc":
        assert ends.count("noise rows used up") >= 20
    assert len(fast.records) == len(objects.records)
    assert digest(fast.records, fast.statuses, fast.impacts, fast) == \
        digest(objects.records, objects.statuses, objects.impacts, objects)
    assert fast.param_range == objects.param_range
    assert fast.steps_walked >= 1       # an impact in every case (the tau case then falls)


def test_a_delay_keeps_the_objects():
    """A measurement delay (the plant's delay line, the controller's predictor) is not the compiled loop's, on
    either plant."""
    ctx = tcontext.context()
    for kind, extra in ((segment.Segment, []), (segment.MujocoSegment, ["plant=mujoco"])):
        settings = run_settings("delay2", extra, perturb=["noise_q=5e-4"])
        loop = runner.ClosedLoop(settings.sim_config(), settings.ctrl_config("both"), ctx.family, ctx.desc,
                                 settings.perturbation)
        assert loop.sim.sensor.compiled_noise is None
        assert not kind.eligible(loop.sim, loop.ctrl)
        real = run_settings("real-sensors", extra)
        loop = runner.ClosedLoop(real.sim_config(), real.ctrl_config("both"), ctx.family, ctx.desc, real.perturbation)
        assert kind.eligible(loop.sim, loop.ctrl)


def test_an_outcome_only_run_with_real_sensing_keeps_its_last_status():
    """``keep_records`` False on the objects (a delay, here the compiled loop off): the run's last status is
    the full run's (the survival rule checks p and tau' on it; without it they went unchecked)."""
    settings = run_settings("real-sensors")
    ctx = tcontext.context()
    kw = dict(sim_config=settings.sim_config(), ctrl_config=settings.ctrl_config("both"), family=ctx.family,
              desc=ctx.desc, perturbation=settings.perturbation, compiled_loop=False)
    full = runner.run(2, "both", (), keep_records=True, **kw)
    lean = runner.run(2, "both", (), keep_records=False, **kw)
    assert len(lean.statuses) == 1 and len(lean.records) == 1
    assert digest(lean.records, lean.statuses, lean.impacts, lean) == \
        digest(full.records[-1:], full.statuses[-1:], full.impacts, full)
