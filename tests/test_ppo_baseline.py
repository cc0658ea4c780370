"""The learned baseline's export and trainer (biped_controller.learning; docs/policies_training.md).

In the default install: the committed ONNX policy equals the trained network's own recorded outputs and a
NumPy forward pass of its weights; an exported random network equals its NumPy pass; the training command's
bad input is one line and exit status 2. With the training extra (skrl, JAX; skipped without it): a checkpoint
restores the learner's whole state (the continuation after a restore equals the uninterrupted one).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from biped_controller.learning import ppo_train
from biped_controller.learning.mlp import MlpPolicy, WeightsError
from biped_controller.learning.onnx_export import export

ROOT = Path(__file__).resolve().parents[1]
POLICY = ROOT / "policies" / "ppo_baseline"


def _ort(path):
    import onnxruntime as ort
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def test_committed_onnx_equals_the_network_on_recorded_observations():
    """policy.onnx and the NumPy pass of weights.npz against the JAX network's outputs recorded at export."""
    rec = np.load(POLICY / "recorded.npz")
    obs, want = rec["observations"], rec["actions"]
    assert obs.shape[1:] == (22,) and want.shape == (len(obs), 6) and len(obs) >= 16
    assert float(np.std(want)) > 1e-3           # a network that says something, not all zeros
    got = _ort(POLICY / "policy.onnx").run(None, {"observation": obs.astype(np.float32)})[0]
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-5)
    mlp = MlpPolicy.load(POLICY / "weights.npz")
    np.testing.assert_allclose(mlp.mean_action(obs), want, rtol=0, atol=2e-5)
    # the recorded outputs depend on every layer: a changed output bias is seen
    arrays = dict(mlp.arrays())
    last = len(mlp.weights) - 1
    arrays[f"b{last}"] = arrays[f"b{last}"] + np.float32(1e-3)
    assert np.abs(MlpPolicy.from_arrays(arrays).mean_action(obs) - want).max() > 5e-4


def test_export_of_a_random_network_equals_its_numpy_pass(tmp_path):
    rng = np.random.default_rng(7)
    sizes = (22, 16, 9, 6)
    mlp = MlpPolicy(obs_mean=rng.normal(size=22).astype(np.float32),
                    obs_var=rng.uniform(0.1, 4.0, 22).astype(np.float32), obs_eps=1e-8, obs_clip=5.0,
                    weights=tuple(rng.normal(0, 0.5, (a, b)).astype(np.float32) for a, b in zip(sizes, sizes[1:])),
                    biases=tuple(rng.normal(0, 0.1, b).astype(np.float32) for b in sizes[1:]),
                    log_std=np.zeros(6, np.float32))
    obs = rng.normal(0, 3.0, (40, 22)).astype(np.float32)     # some beyond the clip of 5 standard deviations
    assert np.abs(mlp.standardise(obs)).max() == pytest.approx(5.0)
    path = export(mlp, tmp_path / "p.onnx")
    got = _ort(path).run(None, {"observation": obs})[0]
    # an independent float64 evaluation of the same maths
    x = np.clip((obs.astype(float) - mlp.obs_mean) / (np.sqrt(mlp.obs_var.astype(float)) + 1e-8), -5, 5)
    for k, (w, b) in enumerate(zip(mlp.weights, mlp.biases)):
        x = x @ w.astype(float) + b
        x = np.tanh(x) if k < 2 else x
    np.testing.assert_allclose(got, x, rtol=0, atol=2e-5)
    np.testing.assert_allclose(mlp.mean_action(obs), x, rtol=0, atol=2e-5)
    with pytest.raises(WeightsError, match="layer 1"):
        MlpPolicy(obs_mean=mlp.obs_mean, obs_var=mlp.obs_var, obs_eps=1e-8, obs_clip=5.0,
                  weights=(mlp.weights[0], mlp.weights[2]), biases=(mlp.biases[0], mlp.biases[2]),
                  log_std=mlp.log_std)


@pytest.mark.parametrize("argv, fragment", [
    (["no_such_baseline"], "unknown baseline 'no_such_baseline'"),
    (["ppo_baseline", "--budget-minutes", "-3"], "--budget-minutes"),
    (["ppo_baseline", "--budget-minutes", "nan"], "--budget-minutes"),
    (["ppo_baseline", "--resume", "--restart"], "exclude each other"),
    (["ppo_baseline", "--resume"], "no checkpoint"),
    (["ppo_baseline", "--bogus"], "unrecognized arguments"),
    (["ppo_baseline", "--robot", "no_such_robot"], "robot"),
])
def test_training_command_bad_input_is_one_line_and_exit_2(argv, fragment, tmp_path, monkeypatch, capsys):
    paths = ppo_train.Paths
    monkeypatch.setattr(ppo_train, "Paths", lambda name, smoke=False, root=None: paths(name, smoke, tmp_path))
    with pytest.raises(SystemExit) as e:
        ppo_train.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and fragment in err, err
    assert not any(tmp_path.iterdir())           # nothing written


def test_a_fresh_start_over_an_existing_run_is_refused(tmp_path, monkeypatch, capsys):
    paths = ppo_train.Paths
    monkeypatch.setattr(ppo_train, "Paths", lambda name, smoke=False, root=None: paths(name, smoke, tmp_path))
    ck = paths("ppo_baseline", False, tmp_path).checkpoint
    ck.parent.mkdir(parents=True)
    ck.write_bytes(b"x")
    with pytest.raises(SystemExit) as e:
        ppo_train.main(["ppo_baseline"])
    assert e.value.code == 2 and "--restart" in capsys.readouterr().err
    assert ck.read_bytes() == b"x"


def test_without_the_extra_the_command_says_so(tmp_path, monkeypatch, capsys):
    if ppo_train.extra_available():
        pytest.skip("the training extra is installed here")
    paths = ppo_train.Paths
    monkeypatch.setattr(ppo_train, "Paths", lambda name, smoke=False, root=None: paths(name, smoke, tmp_path))
    with pytest.raises(SystemExit) as e:
        ppo_train.main(["ppo_baseline", "--smoke"])
    assert e.value.code == 2 and "scripts/setup-train" in capsys.readouterr().err


# ------------------------------------------------------------------------------------- with the extra
def _tiny_agent(tmp_path):
    import gymnasium as gym
    from dataclasses import replace
    from biped_controller.learning.ppo_config import load_config
    cfg = replace(load_config("ppo_baseline"), num_envs=2, workers=1, rollouts=2, mini_batches=1, learning_epochs=2,
                  hidden_sizes=(8,))
    agent = ppo_train.build_agent(cfg, gym.spaces.Box(-np.inf, np.inf, (22,), np.float32),
                                  gym.spaces.Box(-1.0, 1.0, (6,), np.float32), tmp_path)
    return cfg, agent


def _one_update(agent, cfg, seed):
    """One PPO update on synthetic transitions (observations and rewards from ``seed``; actions sampled)."""
    import jax.numpy as jnp
    rng = np.random.default_rng(seed)
    for k in range(cfg.rollouts):
        obs = jnp.asarray(rng.normal(size=(cfg.num_envs, 22)), dtype=jnp.float32)
        act, _ = agent.act(obs, None, timestep=k, timesteps=100)
        z = jnp.zeros((cfg.num_envs, 1), dtype=bool)
        agent.record_transition(observations=obs, states=None, actions=act,
                                rewards=jnp.asarray(rng.normal(size=(cfg.num_envs, 1)), dtype=jnp.float32),
                                next_observations=obs, next_states=None, terminated=z, truncated=z, infos={},
                                timestep=k, timesteps=100)
        agent.post_interaction(timestep=k, timesteps=100)


def _leaves(agent, counter: bool = True):
    """The learner state's arrays; ``counter=False`` leaves out the policy's sampling counter, which skrl's
    GaussianMixin also advances when JAX traces its update (once per new learner), not only per sample."""
    import jax
    st = ppo_train.learner_state(agent)
    if not counter:
        st.pop("policy_sample_counter")
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(st)]


def test_checkpoint_resume_restores_the_learner_state(tmp_path):
    pytest.importorskip("skrl", reason="the training extra is not installed (scripts/setup-train)")
    cfg, a = _tiny_agent(tmp_path)
    _one_update(a, cfg, seed=1)
    ck = tmp_path / "ck.msgpack"
    ppo_train.save_checkpoint(a, ck)
    before = _leaves(a)
    _, b = _tiny_agent(tmp_path)                 # a fresh learner (same seed: the initial parameters)
    fresh = _leaves(b)
    assert len(fresh) == len(before)
    assert any(f.shape == x.shape and not np.array_equal(f, x) for f, x in zip(fresh, before))
    ppo_train.load_checkpoint(b, ck)
    for x, y in zip(before, _leaves(b)):
        np.testing.assert_array_equal(x, y)
    # the continuation is the same (parameters, Adam moments, scalers, sampling counter and shuffling restored),
    # to float32 rounding (XLA's compiled update in a second learner may order a sum differently)
    restored = _leaves(b, counter=False)
    _one_update(a, cfg, seed=2)
    _one_update(b, cfg, seed=2)
    after_a, after_b = _leaves(a, counter=False), _leaves(b, counter=False)
    moved = max(float(np.abs(x.astype(float) - y).max()) for x, y in zip(restored, after_b) if x.dtype.kind == "f")
    assert moved > 1e-4
    for x, y in zip(after_a, after_b):
        if x.dtype.kind == "f":
            np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-7)
        else:
            np.testing.assert_array_equal(x, y)
