"""The imitation reward and reference state initialisation of BipedPush-v0, the teacher, and the training
config that asks for them (biped_controller.policy.env, biped_controller.policy.teacher, ppo_config;
docs/policies_training.md).

- with the imitation weights 0 (config/policy_env.yaml) the environment draws nothing more and its reward
  has no imitation term (the Walker2d-style reward alone: the seeded-episode test of test_policy.py holds);
- reference state initialisation: the reset state is the gait family's reference at the drawn phase, the
  observation's time in stance is that phase, and the imitation term at it is the sum of its weights (every
  error zero), and below it after a step away from the reference (an independent evaluation of the family);
- the teacher from the observation gives mode none's torques period by period on the plug-in loop (rigid plant);
- a training config with an unknown environment setting or push field is refused naming it.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from biped_controller.learning.ppo_config import TrainConfigError, load_config
from biped_controller.policy.env import BipedPushEnv

W = {"imitation_pose_weight": 0.65, "imitation_velocity_weight": 0.1, "imitation_speed_weight": 0.25}


def test_default_reward_has_no_imitation_and_draws_nothing_more():
    a = BipedPushEnv(plant="rigid")
    b = BipedPushEnv(plant="rigid", reference_state_init=0.0, **{k: 0.0 for k in W})
    oa, _ = a.reset(seed=5)
    ob, _ = b.reset(seed=5)
    np.testing.assert_array_equal(oa, ob)
    assert a.np_random.uniform() == b.np_random.uniform()      # the same draws so far
    _, r, _, _, info = a.step(np.zeros(6))
    assert info["reward_imitation"] == 0.0
    assert r == pytest.approx(info["reward_forward"] + info["reward_healthy"] + info["reward_ctrl"]
                              + info["reward_upright"], abs=1e-12)


def test_reference_state_init_starts_on_the_reference_at_the_drawn_phase():
    env = BipedPushEnv(plant="mujoco", reset_noise_scale=0.0, reference_state_init=1.0, **W)
    fam = env.family
    phases = []
    for seed in (1, 2):
        obs, _ = env.reset(seed=seed)
        s = env.reset_phase
        phases.append(s)
        assert 0.0 <= s < fam.T
        g = fam.evaluate(fam.p_d, s)
        np.testing.assert_allclose(obs[0:6], g.q, atol=1e-9)
        np.testing.assert_allclose(obs[6:12], g.dq_dtau, atol=1e-9)
        assert obs[15] == pytest.approx(s, abs=2e-9)
        assert env._imitation(env.v_pref) == pytest.approx(sum(W.values()), abs=1e-9)
    assert phases[0] != phases[1]
    # one step with zero torque leaves the reference: the term is the closed form of the state reached
    obs, r, term, _, info = env.step(np.zeros(6))
    g = fam.evaluate(fam.p_d, min(obs[15], fam.T))
    eq, eqd = obs[0:6] - g.q, obs[6:12] - g.dq_dtau
    v = info["x_velocity"]
    want = (0.65 * math.exp(-2.0 * eq @ eq) + 0.1 * math.exp(-0.1 * eqd @ eqd)
            + 0.25 * math.exp(-10.0 * (v - env.v_pref) ** 2)) * info["period"] / env.period
    assert info["reward_imitation"] == pytest.approx(want, rel=1e-12)
    assert info["reward_imitation"] < sum(W.values())


def test_teacher_is_mode_none_on_the_plugin_loop():
    from biped_controller.policy.teacher import TeacherPolicy
    from biped_controller.plugin.interface import ControllerSetup
    from biped_controller.plugin.loop import PluginLoop
    from biped_controller.policy.controller import PolicyController
    ref = PluginLoop("none")
    setup = ControllerSetup(ref.desc, ref.family, ref.scfg.control_period, {})
    ctrl = PolicyController(setup, TeacherPolicy(ref.desc, ref.family), policy_period=ref.scfg.control_period)
    loop = PluginLoop(ctrl, sim_config=ref.scfg, family=ref.family, desc=ref.desc)
    a, b = ref.run(2, limit=0.6), loop.run(2, limit=0.6)
    assert a.steps_walked >= 1 and len(a.records) == len(b.records)
    for ra, rb in zip(a.records, b.records):
        np.testing.assert_allclose(rb.torque, ra.torque, rtol=0, atol=1e-8)


@pytest.mark.parametrize("change, fragment", [
    ({"env_settings": {"no_such_weight": 1.0}}, "no_such_weight"),
    ({"env_settings": {"reference_state_init": 2.0}}, "reference_state_init"),
    ({"push_distribution": {"force_max": -1.0}}, "force_max"),
    ({"budget_spent_minutes": 500.0}, "budget_spent_minutes"),
])
def test_training_config_refuses_bad_environment_settings(change, fragment):
    cfg = load_config("ppo_baseline")
    with pytest.raises(TrainConfigError, match=fragment):
        replace(cfg, **change).validate()
