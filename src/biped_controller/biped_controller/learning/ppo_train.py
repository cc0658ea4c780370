"""Train a learned baseline with PPO (skrl's, JAX backend) on ``BipedRandomPush-v0``, resumable, within a
budget stated in advance; export it as an ONNX policy. Guide: docs/policies_training.md.

    scripts/train NAME [--resume] [--budget-minutes N] [--smoke] [--restart] [--robot NAME|PATH]

``NAME`` names ``config/training/NAME.yaml`` (``ppo_config``). A run writes, at every checkpoint (every
``checkpoint_minutes`` of wall time, at an update boundary, and when it stops):

* ``results/NAME/checkpoint.msgpack``: everything the run's continuation needs (policy and value parameters,
  both Adam states, both running scalers, the policy's sampling counter, JAX's key and NumPy's global
  generator state, which skrl's mini-batch shuffling draws from), flax.serialization's msgpack;
* ``results/NAME/run.json``: the settings, the totals (updates, environment steps, wall time) and one entry per
  sitting (``segment``), with the pins of the learner stack;
* ``results/NAME/curve.csv`` (``curve``: one row per update) and ``curve.png`` drawn from it;
* ``policies/NAME/``: ``policy.onnx`` (``onnx_export``: the Gaussian's mean, the deterministic action),
  ``weights.npz`` (``mlp``), ``recorded.npz`` (observations from the last rollout and the network's own
  JAX outputs on them: the default install's test compares the ONNX file and the NumPy pass with them) and
  ``policy.json`` (``policy.catalog``'s metadata and how it was made).

``--resume`` continues from the checkpoint: the environments start new episodes (seeded ``seed + 1000 *
segment``), so the continuation is not bit-identical to an uninterrupted run (episodes in flight are cut), but
the learner's state is restored exactly. ``--smoke`` runs ``smoke_updates`` updates into build/train-smoke/NAME/
(never the baseline's files). The budget: ``budget_minutes`` of training wall time summed over the sittings
(``--budget-minutes`` caps this sitting); a run stops at the first update boundary past either.

Bad input (an unknown NAME, a bad number, ``--resume`` without a checkpoint, a fresh start over an existing run
without ``--restart``): one line naming it, exit status 2, nothing written. Without the training extra: one line
saying to run ``scripts/setup-train``, exit status 2.

Networks (CleanRL's PPO details for continuous control): policy mean and value are separate tanh MLPs of
``hidden_sizes``, orthogonal initialisation (gain sqrt 2 in the hidden layers, 0.01 on the policy's output,
1 on the value's), biases 0; a state-independent log std starting at ``initial_log_std``. Actions are sampled
unclipped (the log-probability is the Gaussian's); the environment clips them to [-1, 1].
"""
from __future__ import annotations

import datetime as _dt
import functools
import hashlib
import json
import math
import os
import platform
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from biped_controller.learning.curve import draw, read_curve, write_curve
from biped_controller.learning.mlp import MlpPolicy
from biped_controller.learning.ppo_config import PpoConfig, TrainConfigError, load_config

EXTRA_MODULES = ("jax", "flax", "optax", "skrl")


class TrainError(ValueError):
    """A training request that cannot be carried out as asked (the message names why)."""


class ExtraMissing(RuntimeError):
    """The training extra (skrl, JAX) is not installed."""


def extra_available() -> bool:
    import importlib.util
    return all(importlib.util.find_spec(m) is not None for m in EXTRA_MODULES)


def _require_extra() -> None:
    if not extra_available():
        missing = [m for m in EXTRA_MODULES if __import__("importlib").util.find_spec(m) is None]
        raise ExtraMissing(f"the training extra is not installed (missing {', '.join(missing)}): run scripts/setup-train")


# ---------------------------------------------------------------------------------------------- paths
class Paths:
    """Where a run's files go (module docstring)."""

    def __init__(self, name: str, smoke: bool = False, root: Path | None = None):
        from biped_model.settings import repo_root
        r = Path(root) if root is not None else Path(repo_root())
        if smoke:
            self.results = r / "build" / "train-smoke" / name
            self.policy = self.results / "policy"
        else:
            self.results = r / "results" / name
            self.policy = r / "policies" / name
        self.checkpoint = self.results / "checkpoint.msgpack"
        self.run = self.results / "run.json"
        self.curve = self.results / "curve.csv"
        self.png = self.results / "curve.png"


# ---------------------------------------------------------------------------------------------- environments
STAT_KEYS = ("x_position", "t", "steps_walked", "fell", "pushed")


def _make_one(env_kwargs: dict):
    import gymnasium as gym

    import biped_controller.policy  # noqa: F401  (registers the environments)
    return gym.make("BipedRandomPush-v0", **env_kwargs)


def env_kwargs(cfg: PpoConfig) -> dict:
    """The training environment's keyword arguments: the plant, the config's ``push_distribution`` (the random
    pushes' ``policy.pushes.PushDistribution`` fields over its defaults) and ``env_settings``."""
    dist = {k: (tuple(v) if isinstance(v, list) else v) for k, v in cfg.push_distribution.items()}
    return {"plant": cfg.plant, "robot": cfg.robot, "distribution": dist, **cfg.env_settings}


class EnvBatch:
    """``n`` training environments (``BipedRandomPush-v0``: the random-push wrapper with its default
    distribution and the registered time limit) stepped one after the other in one process, with their own
    autoreset: ``step(actions (n, 6))`` returns observations (n, 22) (a reset one where an episode ended),
    rewards, terminated, truncated (n,) and ``stats`` (n, 2 * 5): per environment the episode's
    :data:`STAT_KEYS` at the step's end (x [m], t [s], touchdowns, fell 0/1, pushed 0/1) and, for an episode
    that ended, the same at its last step (else the first five again), then the final observation in
    ``final_obs`` (n, 22). A worker process holds one batch (``VecWorkers``): skrl's JAX PPO compiles its
    advantage loop unrolled over the rollout (compile time grows faster than linearly with the rollout: 2.5 s
    at 16 steps, 46 s at 128 here), so it wants many environments and short rollouts, as Isaac Lab runs it."""

    def __init__(self, env_kwargs: dict, n: int):
        self.envs = [_make_one(env_kwargs) for _ in range(n)]
        self.pushed = np.zeros(n)

    def _stats(self, info, i):
        return [float(info.get("x_position", 0.0)), float(info.get("t", 0.0)), float(info.get("steps_walked", 0)),
                float(bool(info.get("fall_cause", ""))), self.pushed[i]]

    def _reset(self, i, seed=None):
        obs, info = self.envs[i].reset(seed=seed)
        self.pushed[i] = float(info["push"]["direction"] != "none")
        return obs, info

    def reset(self, seed: int):
        obs, stats = [], []
        for i in range(len(self.envs)):
            o, info = self._reset(i, seed + i)
            obs.append(o)
            stats.append(self._stats(info, i) * 2)
        return np.array(obs), np.array(stats)

    def step(self, actions):
        n = len(self.envs)
        obs, final = np.empty((n, 22)), np.empty((n, 22))
        rew, term, trunc = np.empty(n), np.zeros(n, bool), np.zeros(n, bool)
        stats = np.empty((n, 2 * len(STAT_KEYS)))
        for i, env in enumerate(self.envs):
            o, r, te, tr, info = env.step(actions[i])
            rew[i], term[i], trunc[i], final[i] = r, te, tr, o
            end = self._stats(info, i)
            if te or tr:
                o, info = self._reset(i)
            obs[i] = o
            stats[i] = self._stats(info, i) + end
        return obs, rew, term, trunc, stats, final


def _worker(conn, env_kwargs: dict, n: int) -> None:
    batch = EnvBatch(env_kwargs, n)
    try:
        while True:
            cmd, arg = conn.recv()
            if cmd == "reset":
                conn.send(batch.reset(arg))
            elif cmd == "step":
                conn.send(batch.step(arg))
            else:
                break
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        conn.close()


class VecWorkers:
    """``workers`` processes (spawned: the parent runs JAX's threads), each an :class:`EnvBatch` of
    ``num_envs / workers`` environments; ``reset(seed)`` seeds environment j with ``seed + j``."""

    def __init__(self, env_kwargs: dict, num_envs: int, workers: int):
        import multiprocessing as mp
        ctx = mp.get_context("spawn")
        self.sizes = [num_envs // workers + (1 if w < num_envs % workers else 0) for w in range(workers)]
        self.conns, self.procs = [], []
        for n in self.sizes:
            a, b = ctx.Pipe()
            p = ctx.Process(target=_worker, args=(b, env_kwargs, n), daemon=True)
            p.start()
            b.close()
            self.conns.append(a)
            self.procs.append(p)

    def reset(self, seed: int):
        off = 0
        for c, n in zip(self.conns, self.sizes):
            c.send(("reset", seed + off))
            off += n
        parts = [c.recv() for c in self.conns]
        return tuple(np.concatenate(x) for x in zip(*parts))

    def step(self, actions: np.ndarray):
        off = 0
        for c, n in zip(self.conns, self.sizes):
            c.send(("step", actions[off:off + n]))
            off += n
        parts = [c.recv() for c in self.conns]
        return tuple(np.concatenate(x) for x in zip(*parts))

    def close(self) -> None:
        for c in self.conns:
            try:
                c.send(("close", None))
            except (OSError, BrokenPipeError):
                pass
        for p in self.procs:
            p.join(timeout=10)
            if p.is_alive():
                p.terminate()
                p.join()


# ---------------------------------------------------------------------------------------------- learner
@functools.lru_cache(maxsize=None)
def _model_classes(hidden: tuple[int, ...], initial_log_std: float):
    """The flax policy and value classes for ``hidden`` and ``initial_log_std`` (flax re-creates a module from
    its constructor's keyword arguments, so the sizes are the classes', not constructor arguments)."""
    import flax.linen as nn
    import jax.numpy as jnp
    from skrl.models.jax import DeterministicMixin, GaussianMixin, Model

    def _mlp(x, hidden, out, out_gain):
        for k, h in enumerate(hidden):
            x = nn.tanh(nn.Dense(h, kernel_init=nn.initializers.orthogonal(math.sqrt(2.0)),
                                 bias_init=nn.initializers.zeros, name=f"hidden_{k}")(x))
        return nn.Dense(out, kernel_init=nn.initializers.orthogonal(out_gain), bias_init=nn.initializers.zeros,
                        name="out")(x)

    class Policy(GaussianMixin, Model):
        def __init__(self, observation_space=None, action_space=None, device=None, **kwargs):
            Model.__init__(self, observation_space=observation_space, action_space=action_space, device=device,
                           **kwargs)
            GaussianMixin.__init__(self, clip_actions=False, clip_log_std=True, min_log_std=-20.0, max_log_std=2.0,
                                   reduction="sum")

        @nn.compact
        def __call__(self, inputs, role):
            mean = _mlp(inputs["observations"], hidden, self.num_actions, 0.01)
            log_std = self.param("log_std", lambda _: jnp.full(self.num_actions, initial_log_std))
            return mean, {"log_std": log_std}

    class Value(DeterministicMixin, Model):
        def __init__(self, observation_space=None, action_space=None, device=None, **kwargs):
            Model.__init__(self, observation_space=observation_space, action_space=action_space, device=device,
                           **kwargs)
            DeterministicMixin.__init__(self, clip_actions=False)

        @nn.compact
        def __call__(self, inputs, role):
            return _mlp(inputs["observations"], hidden, 1, 1.0), {}

    return Policy, Value


def build_agent(cfg: PpoConfig, obs_space, act_space, directory: Path):
    """skrl's PPO with the networks of the module docstring and ``cfg``'s settings (the seed set first)."""
    from skrl.agents.jax.ppo import PPO, PPO_CFG
    from skrl.memories.jax import RandomMemory
    from skrl.resources.preprocessors.jax import RunningStandardScaler
    from skrl import config as skrl_config
    from skrl.utils import set_seed
    skrl_config.jax.device = "cpu"
    set_seed(cfg.seed)
    Policy, Value = _model_classes(tuple(cfg.hidden_sizes), float(cfg.initial_log_std))
    policy = Policy(observation_space=obs_space, action_space=act_space, device="cpu")
    value = Value(observation_space=obs_space, action_space=act_space, device="cpu")
    for m, role in ((policy, "policy"), (value, "value")):
        m.init_state_dict(role=role)
    memory = RandomMemory(memory_size=cfg.rollouts, num_envs=cfg.num_envs, device="cpu")
    pcfg = PPO_CFG(rollouts=cfg.rollouts, learning_epochs=cfg.learning_epochs, mini_batches=cfg.mini_batches,
                   discount_factor=cfg.discount_factor, gae_lambda=cfg.gae_lambda, learning_rate=cfg.learning_rate,
                   grad_norm_clip=cfg.grad_norm_clip, ratio_clip=cfg.ratio_clip, value_clip=cfg.value_clip,
                   entropy_loss_scale=cfg.entropy_loss_scale, value_loss_scale=cfg.value_loss_scale,
                   time_limit_bootstrap=cfg.time_limit_bootstrap,
                   observation_preprocessor=RunningStandardScaler if cfg.normalize_observations else None,
                   observation_preprocessor_kwargs={"size": obs_space, "device": "cpu"},
                   value_preprocessor=RunningStandardScaler if cfg.normalize_values else None,
                   value_preprocessor_kwargs={"size": 1, "device": "cpu"})
    pcfg.experiment.directory = str(directory)
    pcfg.experiment.experiment_name = "skrl"
    pcfg.experiment.write_interval = 0          # our own curve file instead of TensorBoard events
    pcfg.experiment.checkpoint_interval = 0     # our own checkpoint (skrl's load does not restore optimisers)
    agent = PPO(models={"policy": policy, "value": value}, memory=memory, observation_space=obs_space,
                action_space=act_space, device="cpu", cfg=pcfg)
    agent.init()
    agent.enable_training_mode(True)
    return agent


def _scalers(agent) -> dict:
    out = {}
    for key, attr in (("obs_scaler", "_observation_preprocessor"), ("value_scaler", "_value_preprocessor")):
        s = getattr(agent, attr)
        if hasattr(s, "state_dict"):
            out[key] = s
    return out


def learner_state(agent) -> dict:
    """The learner's whole state as a tree of arrays (module docstring)."""
    import flax.serialization as fs
    from skrl import config as skrl_config
    st = {"policy": agent.policy.state_dict.params, "value": agent.value.state_dict.params,
          "policy_optimizer": fs.to_state_dict(agent.policy_optimizer),
          "value_optimizer": fs.to_state_dict(agent.value_optimizer),
          "policy_sample_counter": np.int64(agent.policy._g_i),
          "jax_key": np.asarray(skrl_config.jax.key)}
    for k, s in _scalers(agent).items():
        st[k] = {n: np.asarray(v) for n, v in s.state_dict.params.items()}
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    st["numpy_rng"] = {"keys": np.asarray(keys), "pos": np.int64(pos), "has_gauss": np.int64(has_gauss),
                       "cached_gaussian": np.float64(cached)}
    return st


def restore_learner_state(agent, st: dict) -> None:
    """Put a :func:`learner_state` tree back into ``agent`` (and NumPy's global generator)."""
    import flax.serialization as fs
    import jax.numpy as jnp
    from skrl import config as skrl_config
    for name, model in (("policy", agent.policy), ("value", agent.value)):
        params = fs.from_state_dict(model.state_dict.params, st[name])
        model.state_dict = model.state_dict.replace(params=params)
    agent.policy_optimizer = fs.from_state_dict(agent.policy_optimizer, st["policy_optimizer"])
    agent.value_optimizer = fs.from_state_dict(agent.value_optimizer, st["value_optimizer"])
    agent.policy._g_i = int(st["policy_sample_counter"])
    skrl_config.jax.key = jnp.asarray(st["jax_key"])
    for k, s in _scalers(agent).items():
        s.state_dict = {n: jnp.asarray(v) for n, v in st[k].items()}
    r = st["numpy_rng"]
    np.random.set_state(("MT19937", np.asarray(r["keys"], dtype=np.uint32), int(r["pos"]), int(r["has_gauss"]),
                         float(r["cached_gaussian"])))


def save_checkpoint(agent, path: Path) -> str:
    """Write :func:`learner_state` (msgpack) atomically; returns its sha256."""
    import flax.serialization as fs
    import jax
    data = fs.msgpack_serialize(jax.tree_util.tree_map(np.asarray, learner_state(agent)))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
    return hashlib.sha256(data).hexdigest()


def load_checkpoint(agent, path: Path) -> None:
    import flax.serialization as fs
    restore_learner_state(agent, fs.msgpack_restore(path.read_bytes()))


# ---------------------------------------------------------------------------------------------- export
def mlp_of(agent, cfg: PpoConfig) -> MlpPolicy:
    """The trained policy's mean network and observation scaler as an :class:`MlpPolicy`."""
    p = agent.policy.state_dict.params["params"]
    n = len(cfg.hidden_sizes)
    names = [f"hidden_{k}" for k in range(n)] + ["out"]
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    s = _scalers(agent).get("obs_scaler")
    n_obs = int(np.asarray(p["hidden_0"]["kernel"]).shape[0])
    if s is not None:
        mean, var = f32(s.running_mean), f32(s.running_variance)
        eps, clip = float(s.epsilon), float(s.clip_threshold)
    else:     # the identity: (o - 0) / (1 + 0), clipped far outside any observation
        mean, var, eps, clip = np.zeros(n_obs, np.float32), np.ones(n_obs, np.float32), 0.0, 3.0e38
    return MlpPolicy(obs_mean=mean, obs_var=var, obs_eps=eps, obs_clip=clip,
                     weights=tuple(f32(p[k]["kernel"]) for k in names), biases=tuple(f32(p[k]["bias"]) for k in names),
                     log_std=f32(p["log_std"]))


def network_mean(agent, obs: np.ndarray) -> np.ndarray:
    """The trained network's own deterministic action on ``obs`` (N, 22): skrl's scaler and the flax policy
    applied by JAX (not the exported file)."""
    import jax.numpy as jnp
    x = agent._observation_preprocessor(jnp.asarray(obs, dtype=jnp.float32))
    mean, _ = agent.policy.apply(agent.policy.state_dict.params, {"observations": x}, "policy")
    return np.asarray(mean, dtype=np.float32)


def export_policy(agent, cfg: PpoConfig, name: str, out: Path, meta: dict) -> None:
    """``policies/NAME/`` (module docstring) from the agent's current parameters."""
    from biped_controller.learning.onnx_export import export
    from biped_controller.policy.env import load_env_config
    from biped_controller.policy.residual import config_gains
    from biped_controller.policy.spec import OBS_FIELDS, action_fields
    env_cfg = load_env_config(**cfg.env_settings)
    mlp = mlp_of(agent, cfg)
    out.mkdir(parents=True, exist_ok=True)
    obs_all = np.asarray(agent.memory.get_tensor_by_name("observations")).reshape(-1, mlp.n_obs)
    idx = np.linspace(0, len(obs_all) - 1, min(cfg.record_observations, len(obs_all))).round().astype(int)
    obs = obs_all[idx].astype(np.float32)
    mlp.save(out / "weights.npz")
    np.savez(out / "recorded.npz", observations=obs, actions=network_mean(agent, obs))
    export(mlp, out / "policy.onnx", doc=f"{name}: PPO (skrl, JAX) policy mean; see policy.json")
    info = {"description": f"{name}: PPO (skrl {meta['stack'].get('skrl')}) on BipedRandomPush-v0, "
                           f"{cfg.plant} plant, {meta['totals']['env_steps']} env steps "
                           f"({meta['totals']['wall_s'] / 60:.0f} min of a {cfg.budget_minutes:.0f} min budget)",
            "observation": list(OBS_FIELDS), "action": list(action_fields(env_cfg.action_mode)),
            "action_mode": env_cfg.action_mode, "policy_period": env_cfg.policy_period,
            "plant": cfg.plant, "robot": cfg.robot,
            "deterministic_action": "the Gaussian policy's mean (unclipped; the controller clips to [-1, 1])",
            "trainer": "biped_controller.learning.ppo_train (scripts/train)", "config": f"config/training/{name}.yaml",
            "totals": meta["totals"], "stack": meta["stack"], "curve": f"results/{name}/curve.csv",
            "files": {"weights.npz": "biped_controller.learning.mlp", "recorded.npz":
                      "observations (float32) and the JAX network's mean actions on them"}}
    if env_cfg.action_mode == "residual":       # the inner loop the policy was trained over (policy.residual)
        info.update(residual_scale=list(env_cfg.residual_scale), gains=config_gains(),
                    inner_loop="mode none's computed-torque law on the preferred reference offset by "
                               "action * residual_scale [rad], every plant period (policy.residual)")
    (out / "policy.json").write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")


# ---------------------------------------------------------------------------------------------- loop
def _stack_versions() -> dict:
    import importlib.metadata as md
    out = {}
    for d in ("skrl", "jax", "jaxlib", "flax", "optax", "gymnasium", "onnx"):
        try:
            out[d] = md.version(d)
        except md.PackageNotFoundError:
            out[d] = None
    return out


def _utc() -> str:
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()


class _Episodes:
    """Per-environment episode accumulators and the episodes that ended in the current rollout."""

    def __init__(self, n: int, stats: np.ndarray):
        self.ret = np.zeros(n)
        self.len = np.zeros(n, dtype=int)
        self.x0 = stats[:, 0].copy()
        self.done: list[dict] = []

    def step(self, rew, term, trunc, stats):
        self.ret += rew
        self.len += 1
        k = len(STAT_KEYS)
        ended = np.flatnonzero(np.logical_or(term, trunc))
        for i in ended:
            x, t, steps, fell, pushed = stats[i, k:]
            self.done.append({"return": float(self.ret[i]), "length": int(self.len[i]), "duration": float(t),
                              "speed": (float(x) - self.x0[i]) / t if t > 0 else 0.0, "steps_walked": int(steps),
                              "fell": int(fell), "pushed": int(pushed)})
            self.ret[i], self.len[i], self.x0[i] = 0.0, 0, stats[i, 0]
        return ended

    def summary(self) -> dict:
        d, self.done = self.done, []
        if not d:
            return {"episodes": 0}
        m = lambda k: float(np.mean([e[k] for e in d]))  # noqa: E731
        return {"episodes": len(d), "return_mean": m("return"), "length_mean": m("length"),
                "duration_mean": m("duration"), "speed_mean": m("speed"), "steps_walked_mean": m("steps_walked"),
                "fall_frac": m("fell"), "pushed_frac": m("pushed")}


def train(name: str, *, resume: bool = False, restart: bool = False, budget_minutes: float | None = None,
          smoke: bool = False, root: Path | None = None, log=print, robot: str | None = None) -> dict:
    """Train ``name`` (module docstring) on the config's robot, or ``robot`` (a name under robots/ or a
    path) when given; returns the final ``run.json`` contents."""
    cfg = load_config(name, robot=robot)
    paths = Paths(name, smoke=smoke, root=root)
    if resume and not paths.checkpoint.is_file():
        raise TrainError(f"--resume: no checkpoint at {paths.checkpoint}")
    if resume and paths.run.is_file():
        ran = json.loads(paths.run.read_text()).get("config", {}).get("robot", "biped7")
        if ran != cfg.robot:
            raise TrainError(f"--resume: the run at {paths.results} trained robot {ran!r}, not {cfg.robot!r} "
                             f"(another robot: another config/training/NAME.yaml, or --restart)")
    if not resume and paths.checkpoint.is_file() and not restart:
        raise TrainError(f"a run exists at {paths.checkpoint}: --resume it, or --restart to start over")
    _require_extra()
    import jax.numpy as jnp
    from biped_controller.studies.provenance import Run
    prov = Run(plant=cfg.plant, robot=cfg.robot)

    meta = json.loads(paths.run.read_text()) if resume else None
    rows = []
    if resume:
        rows = [r for r in read_curve(paths.curve) if r["update"] <= meta["totals"]["updates"]] \
            if paths.curve.is_file() else []
    totals = dict(meta["totals"]) if resume else {"updates": 0, "env_steps": 0, "wall_s": 0.0}
    segment = len(meta["segments"]) if resume else 0
    left_total = (cfg.budget_minutes - cfg.budget_spent_minutes) * 60.0 - totals["wall_s"]
    sitting = budget_minutes * 60.0 if budget_minutes is not None else math.inf
    if left_total <= 0 and not smoke:
        raise TrainError(f"the budget of {cfg.budget_minutes} min is spent ({totals['wall_s'] / 60:.1f} min trained, "
                         f"{cfg.budget_spent_minutes} min before this run)")
    stop_after = min(left_total, sitting)
    max_updates = cfg.smoke_updates if smoke else None

    import gymnasium as gym
    from biped_controller.policy.spec import OBS_SIZE
    vec = VecWorkers(env_kwargs(cfg), cfg.num_envs, cfg.workers)
    try:
        agent = build_agent(cfg, gym.spaces.Box(-np.inf, np.inf, (OBS_SIZE,), np.float32),
                            gym.spaces.Box(-1.0, 1.0, (6,), np.float32), paths.results)
        if resume:
            load_checkpoint(agent, paths.checkpoint)
            log(f"train: resumed {name} at update {totals['updates']}, {totals['env_steps']} env steps, "
                f"{totals['wall_s'] / 60:.1f} min trained")
        seg = {"segment": segment, "started": _utc(), "commit": prov.fields()["commit"],
               "updates_start": totals["updates"], "env_steps_start": totals["env_steps"]}
        meta = {"name": name, "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
                "stack": _stack_versions(), "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                                        "python": platform.python_version()},
                "segments": (meta["segments"] if resume else []), "totals": totals, "smoke": smoke}
        obs, stats = vec.reset(cfg.seed + 1000 * segment)
        eps = _Episodes(cfg.num_envs, stats)
        t_start = time.monotonic()
        t_ckpt = t_start
        wall0 = totals["wall_s"]
        sitting_updates = 0
        T = 10**12                                  # skrl's "timesteps" (only schedulers read it)
        while True:
            t_roll = time.monotonic()
            rew_sum = 0.0
            for k in range(cfg.rollouts):
                ts = totals["env_steps"] // cfg.num_envs
                obs_j = jnp.asarray(obs, dtype=jnp.float32)
                actions, _ = agent.act(obs_j, None, timestep=ts, timesteps=T)
                nobs, rew, term, trunc, stats, rec_next = vec.step(np.asarray(actions, dtype=np.float64))
                eps.step(rew, term, trunc, stats)
                agent.record_transition(observations=obs_j, states=None, actions=actions,
                                        rewards=jnp.asarray(rew, dtype=jnp.float32)[:, None],
                                        next_observations=jnp.asarray(rec_next, dtype=jnp.float32), next_states=None,
                                        terminated=jnp.asarray(term)[:, None], truncated=jnp.asarray(trunc)[:, None],
                                        infos={}, timestep=ts, timesteps=T)
                rew_sum += float(np.sum(rew))
                totals["env_steps"] += cfg.num_envs
                if k + 1 < cfg.rollouts:
                    agent.post_interaction(timestep=ts, timesteps=T)
                obs = nobs
            roll_s = time.monotonic() - t_roll
            t_upd = time.monotonic()
            agent.post_interaction(timestep=ts, timesteps=T)      # the rollouts-th: skrl's PPO update
            upd_s = time.monotonic() - t_upd
            totals["updates"] += 1
            sitting_updates += 1
            totals["wall_s"] = wall0 + (time.monotonic() - t_start)
            std = float(np.mean(np.exp(np.asarray(agent.policy.state_dict.params["params"]["log_std"]))))
            row = {"update": totals["updates"], "env_steps": totals["env_steps"], "wall_s": totals["wall_s"],
                   "segment": segment, **{k: math.nan for k in ("return_mean", "length_mean", "duration_mean",
                                                                 "speed_mean", "steps_walked_mean", "fall_frac",
                                                                 "pushed_frac")},
                   **eps.summary(), "reward_mean": rew_sum / (cfg.rollouts * cfg.num_envs), "policy_std": std,
                   "env_steps_per_s": cfg.rollouts * cfg.num_envs / roll_s, "update_s": upd_s}
            rows.append(row)
            log(f"train: update {row['update']} env_steps {row['env_steps']} wall {row['wall_s'] / 60:.1f} min | "
                f"episodes {row['episodes']} return {row['return_mean']:.1f} length {row['length_mean']:.1f} "
                f"speed {row['speed_mean']:.3f} m/s steps {row['steps_walked_mean']:.2f} | "
                f"{row['env_steps_per_s']:.0f} env steps/s, update {upd_s:.1f} s, std {std:.3f}")
            elapsed = time.monotonic() - t_start
            done = (max_updates is not None and sitting_updates >= max_updates) or elapsed >= stop_after
            if done or time.monotonic() - t_ckpt >= cfg.checkpoint_minutes * 60.0:
                _write_all(agent, cfg, name, paths, meta, seg, rows, totals, prov)
                t_ckpt = time.monotonic()
            if done:
                break
        return meta
    finally:
        vec.close()


def _write_all(agent, cfg, name, paths, meta, seg, rows, totals, prov) -> None:
    sha = save_checkpoint(agent, paths.checkpoint)
    seg.update(ended=_utc(), updates_end=totals["updates"], env_steps_end=totals["env_steps"],
               wall_s_total=round(totals["wall_s"], 1))
    segs = [s for s in meta["segments"] if s["segment"] != seg["segment"]] + [dict(seg)]
    meta.update(segments=segs, totals={k: (round(v, 1) if isinstance(v, float) else v) for k, v in totals.items()},
                checkpoint_sha256=sha, written=_utc())
    paths.run.write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
    write_curve(paths.curve, rows)
    draw(read_curve(paths.curve), paths.png, title=name)
    export_policy(agent, cfg, name, paths.policy, meta)
    if not meta["smoke"]:
        prov.record(paths.checkpoint, paths.run, paths.curve, paths.png)


# ---------------------------------------------------------------------------------------------- CLI
def main(argv: list[str] | None = None) -> int:
    from biped_controller.studies.trial.args import StudyArgumentParser, positive_float
    ap = StudyArgumentParser(prog="train", description="Train a learned baseline (PPO) on BipedRandomPush-v0 "
                             "and export it as an ONNX policy (docs/policies_training.md).")
    ap.add_argument("name", help="the baseline: config/training/NAME.yaml (e.g. ppo_baseline)")
    ap.add_argument("--resume", action="store_true", help="continue from results/NAME/checkpoint.msgpack")
    ap.add_argument("--restart", action="store_true", help="start over, replacing an existing run")
    ap.add_argument("--budget-minutes", type=positive_float, default=None,
                    help="wall minutes for this sitting (the config's budget_minutes caps the total)")
    ap.add_argument("--smoke", action="store_true", help="a short check run into build/train-smoke/NAME/")
    ap.add_argument("--robot", default=None, metavar="NAME|PATH",
                    help="the robot (default the config's robot; docs/robots.md)")
    a = ap.parse_args(argv)
    if a.resume and a.restart:
        ap.error("--resume and --restart exclude each other")
    try:
        load_config(a.name, robot=a.robot)
        meta = train(a.name, resume=a.resume, restart=a.restart, budget_minutes=a.budget_minutes, smoke=a.smoke,
                     log=lambda s: print(s, flush=True), robot=a.robot)
    except (TrainConfigError, TrainError, ExtraMissing) as exc:
        ap.error(str(exc))
    t = meta["totals"]
    print(f"train: {a.name}: {t['updates']} updates, {t['env_steps']} env steps, {t['wall_s'] / 60:.1f} min trained")
    return 0


if __name__ == "__main__":
    sys.exit(main())
