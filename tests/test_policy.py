"""The Gymnasium environment and the policy controllers (biped_controller.policy; docs/policies.md).

- Gymnasium's own environment checker passes on both plants; the registered ids make the environment;
- a seeded episode (random push, reset noise) is reproduced exactly, and another seed differs;
- the environment's step is the plug-in loop's: the same policy run as a controller on the plug-in loop
  (``plugin.loop.PluginLoop``) gives the same plant records bit for bit (MuJoCo, MuJoCo with a noisy delayed
  sensor model, the rigid plant);
- an ONNX file run by onnxruntime equals a NumPy forward pass of the same weights on recorded observations,
  and as a controller gives the NumPy policy's run;
- a policy that returns NaN is the trial's controller fault and the search goes on;
- bad inputs (push options, actions, ONNX shapes, policy period, metadata) raise one error naming them and
  change nothing; a committed policy directory is a controller by its name.

The ONNX models are built here with the ``onnx`` package (a linear layer and a tanh).
"""
from __future__ import annotations

import json
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest

import biped_controller.policy  # noqa: F401  (registers the environments)
from biped_controller.plugin.interface import ControllerSetup
from biped_controller.plugin.loop import PluginLoop
from biped_controller.policy.controller import (OnnxPolicy, OnnxRunner, PolicyController, PolicyFileError,
                                                check_metadata)
from biped_controller.policy.env import BipedPushEnv
from biped_controller.policy.pushes import PushOptionError
from biped_controller.policy.spec import ACTION_FIELDS, OBS_FIELDS, OBS_SIZE, ActionError

PUSH = {"force": 120.0, "onset": 0.05, "duration": 0.025, "direction": "forward"}


def weights(seed: int = 3, scale: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return scale * rng.standard_normal((OBS_SIZE, 6)), scale * rng.standard_normal(6)


def numpy_policy(W: np.ndarray, b: np.ndarray):
    return lambda obs: np.tanh(obs @ W + b)


def onnx_file(path, W, b, dtype=np.float64, in_shape=("batch", OBS_SIZE), out_shape=("batch", 6)):
    """A linear layer and a tanh as an ONNX file: action = tanh(obs W + b)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper
    T = TensorProto.DOUBLE if dtype == np.float64 else TensorProto.FLOAT
    x = helper.make_tensor_value_info("obs", T, list(in_shape))
    y = helper.make_tensor_value_info("action", T, list(out_shape))
    nodes = [helper.make_node("MatMul", ["obs", "W"], ["h"]), helper.make_node("Add", ["h", "b"], ["z"]),
             helper.make_node("Tanh", ["z"], ["action"])]
    g = helper.make_graph(nodes, "policy", [x], [y], [numpy_helper.from_array(np.asarray(W, dtype), "W"),
                                                      numpy_helper.from_array(np.asarray(b, dtype), "b")])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    onnx.save(m, str(path))
    return path


@pytest.fixture(scope="module")
def mujoco_env():
    return BipedPushEnv(plant="mujoco", keep_records=True)


def episode(env, policy, seed=None, options=None, max_steps=400):
    obs, info = env.reset(seed=seed, options=options)
    out = [obs]
    rewards = []
    while True:
        obs, r, term, trunc, info = env.step(policy(obs))
        out.append(obs)
        rewards.append(r)
        if term or trunc or len(rewards) >= max_steps:
            return np.array(out), np.array(rewards), info


# ---------------------------------------------------------------------- Gymnasium
@pytest.mark.parametrize("plant", ["mujoco", "rigid"])
def test_env_checker(plant):
    from gymnasium.utils.env_checker import check_env
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")        # the unbounded Box's advice (joint rates have no bound)
        check_env(BipedPushEnv(plant=plant), skip_render_check=True)


def test_registered_ids_make_the_environment():
    env = gym.make("BipedPush-v0", plant="rigid")
    assert isinstance(env.unwrapped, BipedPushEnv) and env.spec.max_episode_steps == 1000
    env2 = gym.make("biped_controller.policy:BipedRandomPush-v0", plant="rigid")
    assert isinstance(env2.unwrapped, BipedPushEnv)
    _, info = env2.reset(seed=1)
    assert "push" in info and "fall_cause" in info


def test_seeded_episode_reproduced_exactly():
    env = gym.make("BipedRandomPush-v0", plant="mujoco",
                   distribution={"onset_min": 0.02, "onset_max": 0.08, "force_min": 50, "force_max": 150, "p_none": 0})
    pol = numpy_policy(*weights())
    a = episode(env, pol, seed=7)
    b = episode(env, pol, seed=7)
    c = episode(env, pol, seed=8)
    assert a[2]["push"] == b[2]["push"] and a[2]["push"]["force"] > 0
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[2]["push"] != c[2]["push"]
    assert not np.array_equal(a[0][0], c[0][0])      # another seed: another reset noise


def _random_push_env():
    from biped_controller.policy.env import make_random_push_env
    return make_random_push_env({"onset_min": 0.0, "onset_max": 0.05, "p_none": 0.5}, seed=0, plant="mujoco")


def test_vector_env_over_two_processes_is_the_single_env():
    """AsyncVectorEnv (two worker processes) gives each environment's episode as a lone environment does
    (same seeds, same actions), autoresets included."""
    vec = gym.vector.AsyncVectorEnv([_random_push_env, _random_push_env], context="fork")
    try:
        obs, _ = vec.reset(seed=[3, 4])
        got = [obs]
        for _ in range(40):
            obs, r, term, trunc, info = vec.step(np.zeros((2, 6)))
            got.append(obs)
    finally:
        vec.close()
    got = np.array(got)
    for i, seed in enumerate((3, 4)):
        env = _random_push_env()
        o, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(got[0, i], o)
        for k in range(1, 41):
            o, r, term, trunc, _ = env.step(np.zeros(6))
            np.testing.assert_array_equal(got[k, i], o)
            if term or trunc:
                break
        assert term                      # the zero action falls within 40 policy periods


# ---------------------------------------------------------------------- the plug-in loop's physics
def loop_records(env, policy, pushes, t_end):
    setup = ControllerSetup(env.desc, env.family, env.scfg.control_period, {})
    ctrl = PolicyController(setup, policy, policy_period=env.period, action_mode=env.config.action_mode,
                            residual_scale=env.config.residual_scale)
    loop = PluginLoop(ctrl, sim_config=env.scfg, family=env.family, desc=env.desc, perturbation=env.perturbation)
    return loop.run(1000, pushes, limit=t_end - 1e-9)


def computed_torque_policy(env):
    """Mode none's law as a policy of the observation vector: w = q_d'' + Kv (q_d' - q') + Kp (q_d - q) on
    the fixed gait q_d(p_d, time in stance), torque A w + H, over the limits (the rigid plant, which
    takes off at once under a torque that does not carry the robot, walks with it at a 1 ms policy period)."""
    setup = ControllerSetup(env.desc, env.family, env.scfg.control_period, {})
    model, ref, g, lim = setup.model, setup.reference, setup.gains, env.limits

    def f(vec):
        q, qd = vec[:6], vec[6:12]
        r = ref.at(ref.p_d, min(vec[15], ref.T))
        d = model.dynamics(q, qd)
        return (d.A @ (r.d2q_dtau2 + g.Kv * (r.dq_dtau - qd) + g.Kp * (r.q - q)) + d.H) / lim
    return f


@pytest.mark.parametrize("case", ["mujoco", "mujoco_sensors", "rigid", "mujoco_residual"])
def test_env_step_is_the_plugin_loop(case, mujoco_env):
    if case == "mujoco":
        env = mujoco_env
    elif case == "mujoco_residual":      # the law recomputed every plant period on that period's observation
        env = BipedPushEnv(plant="mujoco", action_mode="residual", keep_records=True,
                           perturbation={"noise_q": 2e-4, "noise_qd": 2e-3, "seed": 4})
    elif case == "mujoco_sensors":
        env = BipedPushEnv(plant="mujoco", perturbation={"noise_q": 5e-4, "noise_qd": 5e-2, "delay": 2, "seed": 4},
                           keep_records=True)
    else:
        env = BipedPushEnv(plant="rigid", policy_period=0.001, keep_records=True)
    env.config = env.config.__class__(**{**env.config.__dict__, "reset_noise_scale": 0.0})
    if case == "rigid":                  # walks through its first touchdown, pushed
        pol = computed_torque_policy(env)
        _, _, info = episode(env, pol, options={"push": {**PUSH, "force": 50.0}}, max_steps=520)
        assert info["steps_walked"] >= 1 and not info["fall_cause"]
    elif case == "mujoco_residual":      # small residuals: walks through a touchdown, then a push fells it
        pol = numpy_policy(*weights(2, 0.002))
        _, _, info = episode(env, pol, options={"push": {**PUSH, "onset": 0.6, "force": 400.0}}, max_steps=120)
        assert info["steps_walked"] >= 1 and info["fall_cause"]
    else:
        pol = numpy_policy(*weights(2, 0.01))      # falls after a touchdown on MuJoCo (a cut-short period)
        _, _, info = episode(env, pol, options={"push": PUSH}, max_steps=60)
    recs = env.records
    res = loop_records(env, pol, env._pushes, info["t"])
    assert len(res.records) == len(recs) and res.fault is None
    for r, s in zip(recs, res.records):
        assert r.t == s.t and r.stance == s.stance
        np.testing.assert_array_equal(r.x, s.x)
        np.testing.assert_array_equal(r.v, s.v)
        np.testing.assert_array_equal(r.torque, s.torque)
    if case == "mujoco":                 # this run crosses a touchdown (a cut-short period)
        assert info["steps_walked"] >= 1
    if case == "mujoco_residual":        # the torque changes within a policy period (the law runs beneath it)
        assert not np.array_equal(recs[1].torque, recs[2].torque)
    assert res.steps_walked == info["steps_walked"]
    assert res.fall_cause == info["fall_cause"]


def test_zero_residual_is_mode_none():
    """action_mode residual with a = 0 is mode none's computed-torque law on the preferred reference: the
    environment's torques equal those of the built-in mode none run on the plug-in loop (an independent
    implementation: plugin.builtin over the controller core) to rounding, over a walk through a touchdown."""
    env = BipedPushEnv(plant="mujoco", action_mode="residual", reset_noise_scale=0.0, keep_records=True)
    _, _, info = episode(env, lambda o: np.zeros(6), max_steps=60)
    assert info["steps_walked"] >= 1 and not info["fall_cause"]
    res = PluginLoop("none", sim_config=env.scfg, family=env.family, desc=env.desc).run(
        1000, (), limit=info["t"] - 1e-9)
    assert len(res.records) == len(env.records)
    ta = np.array([r.torque for r in env.records])
    tb = np.array([r.torque for r in res.records])
    np.testing.assert_allclose(ta, tb, rtol=0, atol=1e-6)
    assert np.abs(ta).max() > 10.0


def test_residual_offset_moves_the_law_by_kp_a_delta():
    """One period of the residual law against its closed form: torque(delta) - torque(0) = A(q) Kp delta
    (inside the limits), the reference and model read independently (plugin.model, the gait family)."""
    from biped_controller.plugin.model import Gains, RobotModel
    from biped_controller.policy.residual import ResidualLaw
    env = BipedPushEnv(plant="mujoco", action_mode="residual", reset_noise_scale=0.0)
    obs, _ = env.reset(seed=0)
    law = env.residual
    delta = law.offset(np.array([0.5, -0.5, 0.2, -0.3, 0.4, -1.5]))
    np.testing.assert_array_equal(delta, np.array([0.5, -0.5, 0.2, -0.3, 0.4, -1.0]) * law.scale)
    A = RobotModel(env.desc).dynamics(obs[:6], obs[6:12]).A
    got = law.torque(obs, delta) - law.torque(obs, np.zeros(6))
    np.testing.assert_allclose(got, Gains.from_config().Kp * A @ delta, rtol=1e-9, atol=1e-9)
    assert np.isnan(law.torque(obs, law.offset(np.full(6, np.nan)))).all()
    with pytest.raises(ValueError, match="residual_scale"):
        ResidualLaw(env.desc, env.family, [0.1, 0.1, -0.1, 0.1, 0.1, 0.1])


def test_residual_onnx_controller_runs_the_numpy_policy(tmp_path):
    """A residual policy's file (policy.json action_mode residual) runs the residual law as a controller: the
    same plant records as the NumPy policy in the environment; bad residual metadata is named."""
    from biped_controller.policy.spec import RESIDUAL_ACTION_FIELDS
    env = BipedPushEnv(plant="mujoco", action_mode="residual", reset_noise_scale=0.0, keep_records=True)
    W, b = weights(2, 0.002)
    f = onnx_file(tmp_path / "policy.onnx", W, b)
    meta = {"observation": list(OBS_FIELDS), "action": list(RESIDUAL_ACTION_FIELDS), "policy_period": 0.01,
            "action_mode": "residual", "residual_scale": list(env.config.residual_scale)}
    (tmp_path / "policy.json").write_text(json.dumps(meta))
    _, _, info = episode(env, numpy_policy(W, b), max_steps=30)
    res = PluginLoop("onnx_policy", sim_config=env.scfg, family=env.family, desc=env.desc,
                     options={"file": str(f)}).run(2, (), limit=info["t"] - 1e-9)
    assert len(res.records) == len(env.records) == 300
    np.testing.assert_allclose([r.torque for r in res.records], [r.torque for r in env.records], rtol=0, atol=1e-6)
    for bad, what in (({**meta, "residual_scale": None}, "residual_scale"),
                      ({**meta, "residual_scale": [0.1, -1, 0.1, 0.1, 0.1, 0.1]}, "residual_scale"),
                      ({**meta, "action": list(ACTION_FIELDS)}, "action lists"),
                      ({**meta, "action_mode": "position"}, "action_mode"),
                      ({**meta, "gains": {"Kp": 400}}, "gains")):
        with pytest.raises(PolicyFileError, match=what):
            check_metadata(bad, "policy.json")
    with pytest.raises(Exception, match="action_mode"):
        BipedPushEnv(plant="rigid", action_mode="position")


# ---------------------------------------------------------------------- ONNX
def test_onnx_equals_numpy_on_recorded_observations(tmp_path, mujoco_env):
    W, b = weights(5, 0.2)
    obs, _, _ = episode(mujoco_env, numpy_policy(*weights()), seed=2, max_steps=40)
    run64 = OnnxRunner(onnx_file(tmp_path / "p64.onnx", W, b))
    run32 = OnnxRunner(onnx_file(tmp_path / "p32.onnx", W, b, np.float32, in_shape=(OBS_SIZE,), out_shape=(6,)))
    ref = np.tanh(obs @ W + b)
    got64 = np.array([run64(o) for o in obs])
    got32 = np.array([run32(o) for o in obs])
    np.testing.assert_allclose(got64, ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got32, ref, rtol=0, atol=2e-5)
    assert np.abs(ref).max() > 0.1                 # not a trivially small output


def test_onnx_controller_runs_the_numpy_policy(tmp_path, mujoco_env):
    W, b = weights()
    f = onnx_file(tmp_path / "policy.onnx", W, b)
    (tmp_path / "policy.json").write_text(json.dumps({"observation": list(OBS_FIELDS), "action": list(ACTION_FIELDS),
                                                      "policy_period": 0.01}))
    env = mujoco_env
    from biped_sim.plant.push import Push
    pushes = (Push(0.05, 0.025, 120.0),)
    onnx_loop = PluginLoop("onnx_policy", sim_config=env.scfg, family=env.family, desc=env.desc,
                           options={"file": str(f)})
    a = onnx_loop.run(2, pushes, limit=0.3)
    b_ = loop_records(env, numpy_policy(W, b), pushes, 0.3 + 1e-9)
    assert len(a.records) == len(b_.records) > 50 and a.fall_cause == b_.fall_cause
    # onnxruntime's tanh and summation order differ from NumPy's in the last bits (1e-10 relative), which the
    # falling robot then carries: the same run to that size
    ta = np.array([r.torque for r in a.records])
    tb = np.array([r.torque for r in b_.records])
    print("largest torque difference [N m]", np.abs(ta - tb).max())
    np.testing.assert_allclose(ta, tb, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose([r.x for r in a.records], [r.x for r in b_.records], rtol=0, atol=1e-9)


def test_nan_policy_is_a_fault_of_the_trial(tmp_path):
    from biped_controller.studies.trial.plugin_trials import PushTrials
    f = onnx_file(tmp_path / "nan.onnx", np.zeros((OBS_SIZE, 6)), np.full(6, np.nan))
    tr = PushTrials("onnx_policy", options={"file": str(f)})
    r = tr.max_push(resolution=50, fmax=100, coarse=50)
    assert len(r["trials"]) == 2                         # every force tried: the search went on
    for t in r["trials"]:
        assert t["fault"] == "non-finite torque" and not t["survived"] and not t["fell"]
        assert "controller fault" in t["reason"] and "onnx_policy" in t["reason"]


# ---------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize("push, field", [
    ({"force": 100, "onset": 0.1, "duration": -0.01}, "duration"),
    ({"force": math.inf, "onset": 0.1, "duration": 0.02}, "force"),
    ({"force": math.nan, "onset": 0.1, "duration": 0.02}, "force"),
    ({"force": 100, "onset": -0.05, "duration": 0.02}, "onset"),
    ({"force": 100, "onset": 0.1, "duration": 0.02, "direction": "up"}, "direction"),
    ({"force": -100, "onset": 0.1, "duration": 0.02, "direction": "forward"}, "force"),
    ({"force": 100, "onset": 0.1}, "duration"),
    ({"force": 100, "onset": 0.1, "duration": 0.02, "height": 9.0}, "height"),
    ({"force": 100, "onset": 0.1, "duration": 0.02, "when": 1}, "when"),
])
def test_bad_push_option_names_it_and_changes_nothing(push, field, mujoco_env):
    env = mujoco_env
    obs0, _ = env.reset(seed=0)
    env.step(np.zeros(6))
    t, x = env.sim.t, env.sim.x.copy()
    with pytest.raises(PushOptionError, match=field) as e:
        env.reset(options={"push": push})
    assert e.value.field == field
    assert env.sim.t == t and np.array_equal(env.sim.x, x)


@pytest.mark.parametrize("action, what", [(np.zeros(5), "shape"), (np.zeros((1, 6)), "shape"),
                                          (np.array([0, 0, np.nan, 0, 0, 0]), "non-finite"), ("a", "not numeric")])
def test_bad_action_names_it(action, what, mujoco_env):
    mujoco_env.reset(seed=0)
    t = mujoco_env.sim.t
    with pytest.raises(ActionError, match=what):
        mujoco_env.step(action)
    assert mujoco_env.sim.t == t


@pytest.mark.parametrize("shapes, what", [((("batch", 21), ("batch", 6)), "input"),
                                          ((("batch", OBS_SIZE), ("batch", 5)), "output"),
                                          (((2, OBS_SIZE), (2, 6)), "input")])
def test_onnx_shape_mismatch_names_the_file(tmp_path, shapes, what):
    n_in = shapes[0][1]
    n_out = shapes[1][1]
    f = onnx_file(tmp_path / "bad.onnx", np.zeros((n_in, n_out)), np.zeros(n_out), in_shape=shapes[0],
                  out_shape=shapes[1])
    with pytest.raises(PolicyFileError, match=f"bad.onnx.*{what}"):
        OnnxRunner(f)


def test_bad_policy_files_and_settings(tmp_path):
    with pytest.raises(PolicyFileError, match="no such file"):
        OnnxRunner(tmp_path / "missing.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not onnx")
    with pytest.raises(PolicyFileError, match="junk.onnx.*cannot load"):
        OnnxRunner(tmp_path / "junk.onnx")
    with pytest.raises(PolicyFileError, match="observation"):
        check_metadata({"observation": ["q1"]}, "policy.json")
    with pytest.raises(ValueError, match="policy_period"):
        BipedPushEnv(plant="rigid", policy_period=0.0105)
    setup = ControllerSetup(*[getattr(BipedPushEnv(plant="rigid"), k) for k in ("desc", "family")], 0.001, {})
    with pytest.raises(PolicyFileError, match="file=PATH"):
        OnnxPolicy(setup)


def test_committed_policy_is_a_controller_by_name(tmp_path, monkeypatch):
    from biped_controller.plugin.registry import load_controller, registered
    d = tmp_path / "policies" / "tiny_pd"
    d.mkdir(parents=True)
    onnx_file(d / "policy.onnx", *weights())
    (d / "policy.json").write_text(json.dumps({"description": "a test policy", "observation": list(OBS_FIELDS),
                                               "action": list(ACTION_FIELDS), "policy_period": 0.02}))
    monkeypatch.setenv("BIPED_POLICIES", str(tmp_path / "policies"))
    regs = {r.name: r for r in registered()}
    assert "tiny_pd" in regs and "catalog" in regs["tiny_pd"].source
    cls = load_controller("tiny_pd")
    assert issubclass(cls, OnnxPolicy) and cls.description == "a test policy"
    import argparse
    from biped_controller.studies.trial.args import controller_arg
    assert controller_arg("tiny_pd") == "tiny_pd"              # the studies take it by name
    with pytest.raises(argparse.ArgumentTypeError, match="onnx_policy.*option.*file"):
        controller_arg("onnx_policy")                         # the studies pass no file option
    res = PluginLoop("tiny_pd", options={}).run(1, limit=0.05)
    assert res.fault is None and res.periods > 0
    assert PluginLoop("tiny_pd").ctrl.inner.policy_period == 0.02


def test_a_policy_is_not_run_on_another_robot(tmp_path):
    """A ``policy.json`` naming the robot it was trained on: the ONNX controller on that robot's description
    builds; on another robot's it stops naming both robots and the file; without a robot in the file, or for a
    description built in code (no source), nothing is checked."""
    from dataclasses import replace
    from biped_controller.policy.controller import check_robot
    from biped_model.robot import resolve_robot
    env = BipedPushEnv(plant="rigid")
    f = onnx_file(tmp_path / "p.onnx", *weights())
    (tmp_path / "policy.json").write_text(json.dumps({"robot": "biped7"}))
    ok = ControllerSetup(env.desc, env.family, 0.001, {"file": str(f)})
    assert OnnxPolicy(ok).metadata["robot"] == "biped7"
    other = ControllerSetup(resolve_robot("biped7_foot05").description(), env.family, 0.001, {"file": str(f)})
    with pytest.raises(PolicyFileError, match="p.onnx.*'biped7'.*'biped7_foot05'"):
        OnnxPolicy(other)
    check_robot({}, other, f)
    check_robot({"robot": "biped7"}, ControllerSetup(replace(env.desc, source=""), env.family, 0.001, {}), f)
