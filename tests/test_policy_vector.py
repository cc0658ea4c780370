"""``BipedPush-v0`` vectorised over processes, a batch per worker (biped_controller.policy.vector;
docs/policies.md, "Vectorised").

- ``gymnasium.make_vec`` gives :class:`BatchVectorEnv`; each of its environments (4 over 2 workers) gives the
  episode a lone ``gymnasium.make`` environment gives with the same seed and actions, through Gymnasium's
  next-step autoreset (the lone environment reset without a seed after its episode ends); the same in
  same-step mode (``final_obs`` the lone episode's last observation, the returned one the next episode's first);
- bad input: actions of the wrong shape or non-finite raise ``ActionError`` naming it and move no environment;
  a bad push option raised in a worker arrives with its type and field; a wrong ``workers`` is named.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import biped_controller.policy  # noqa: F401  (registers the environments)
from biped_controller.policy.pushes import PushOptionError
from biped_controller.policy.spec import ActionError
from biped_controller.policy.vector import BatchVectorEnv

# pushes early and often, and short episodes: every environment ends an episode within the steps run
KW = {"plant": "mujoco", "distribution": {"onset_min": 0.0, "onset_max": 0.05, "p_none": 0.3}}
STEPS = 36


def actions(k: int, n: int) -> np.ndarray:
    """Step k's actions: a different constant per environment (so a mix-up of environments shows)."""
    return np.array([np.full(6, 0.05 * ((j + k) % 3 - 1)) for j in range(n)])


def lone(seed: int, j: int, n: int, same_step: bool):
    """Environment j alone: what the vector should return for it, step by step (obs, reward, term, trunc,
    plant_periods, final_obs or None)."""
    env = gym.make("BipedRandomPush-v0", **KW)
    o, info = env.reset(seed=seed)
    out = [(o, 0.0, False, False, info["plant_periods"], None)]
    ended = False
    for k in range(STEPS):
        if ended and not same_step:
            o, info = env.reset()
            out.append((o, 0.0, False, False, info["plant_periods"], None))
            ended = False
            continue
        o, r, te, tr, info = env.step(actions(k, n)[j])
        final = None
        ended = te or tr
        if ended and same_step:
            final = o
            o, info = env.reset()
        out.append((o, r, te, tr, info["plant_periods"], final))
    env.close()
    return out


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_each_environment_is_a_lone_environment(mode):
    n = 4
    # the lone environments first (this process has then imported and loaded everything the forked workers need)
    wants = [lone(20 + j, j, n, mode == AutoresetMode.SAME_STEP) for j in range(n)]
    vec = gym.make_vec("BipedRandomPush-v0", num_envs=n, workers=2, context="fork", autoreset_mode=mode, **KW)
    try:
        assert isinstance(vec.unwrapped, BatchVectorEnv) and vec.metadata["autoreset_mode"] == mode
        assert [s.stop - s.start for s in vec.unwrapped.worker_slices] == [2, 2]
        assert vec.observation_space.shape == (n, 22) and vec.action_space.shape == (n, 6)
        o, info = vec.reset(seed=20)
        got = [(o, np.zeros(n), np.zeros(n, bool), np.zeros(n, bool), info["plant_periods"], None)]
        for k in range(STEPS):
            o, r, te, tr, info = vec.step(actions(k, n))
            got.append((o, r, te, tr, info["plant_periods"], info.get("final_obs")))
            assert info["_plant_periods"].all() and info["push"]["_force"].all()
    finally:
        vec.close()
    ends = 0
    for j, want in enumerate(wants):
        for k, (g, w) in enumerate(zip(got, want)):
            np.testing.assert_array_equal(g[0][j], w[0], err_msg=f"env {j} step {k}")
            assert (g[1][j], g[2][j], g[3][j], g[4][j]) == w[1:5], (j, k)
            if w[5] is not None:
                np.testing.assert_array_equal(g[5][j], w[5])
                ends += 1
        ends += sum(1 for w in want if w[2] and w[5] is None)
    assert ends >= n            # autoresets exercised in every environment, on average


def test_bad_input_named_and_nothing_moves():
    vec = gym.make_vec("BipedRandomPush-v0", num_envs=3, workers=2, context="fork", **KW)
    try:
        o0, _ = vec.reset(seed=5)
        with pytest.raises(ActionError, match=r"shape \(3,\), expected \(3, 6\)"):
            vec.step(np.zeros(3))
        with pytest.raises(ActionError, match=r"shape \(2, 6\), expected \(3, 6\)"):
            vec.step(np.zeros((2, 6)))
        bad = np.zeros((3, 6))
        bad[2, 4] = np.nan
        with pytest.raises(ActionError, match=r"non-finite entries for environment\(s\) \[2\]"):
            vec.step(bad)
        with pytest.raises(PushOptionError, match="duration") as e:
            vec.reset(options={"push": {"force": 10.0, "onset": 0.1, "duration": -1.0}})
        assert e.value.field == "duration"
        o1, _, _, _, info = vec.step(np.zeros((3, 6)))      # the first step after the reset: nothing moved
        assert (info["plant_periods"] == info["plant_periods"][0]).all() and info["t"][0] == pytest.approx(0.01)
    finally:
        vec.close()
    env = gym.make("BipedRandomPush-v0", **KW)
    env.reset(seed=7)
    np.testing.assert_array_equal(env.step(np.zeros(6))[0], o1[2])
    with pytest.raises(ValueError, match="workers must be an integer in"):
        BatchVectorEnv([lambda: env] * 2, workers=3)


class _Vec(gym.vector.VectorEnv):
    def __init__(self, n):
        self.num_envs = n


def _same(a, b, where="info"):
    assert list(a) == list(b) or set(a) == set(b), (where, set(a) ^ set(b))
    for k in a:
        if isinstance(a[k], dict):
            _same(a[k], b[k], f"{where}[{k}]")
        else:
            assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, (where, k, a[k], b[k])
            for x, y in zip(a[k], b[k]):
                assert np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y, (where, k, x, y)


def test_infos_stacked_as_gymnasium_stacks_them():
    """The workers' key-by-key stacking equals Gymnasium's own ``VectorEnv._add_info`` environment by
    environment, on the environment's infos: after a reset and a step (keys only one has), a same-step
    ``final_obs``/``final_info``, a nested ``push``."""
    from biped_controller.policy.vector import _merge, _stack
    env = gym.make("BipedRandomPush-v0", **KW)
    o, i0 = env.reset(seed=1)
    o1, _, _, _, i1 = env.step(np.zeros(6))
    infos = [i1, i0, {**i0, "final_obs": o1, "final_info": i1}, i1, {"x": np.arange(3.0), "tag": ("a", 1)}]
    want = {}
    for j, info in enumerate(infos):
        want = _Vec(len(infos))._add_info(want, info, j)
    got = _stack(infos)
    _same(got, want)
    _same(_merge([_stack(infos[:2]), _stack(infos[2:])], [2, 3]), want)
