"""``BipedPush-v0`` vectorised over processes, a batch of environments per worker: :class:`BatchVectorEnv`,
a ``gymnasium.vector.VectorEnv``. Guide: docs/policies.md ("Vectorised").

Why not ``gymnasium.vector.AsyncVectorEnv``: it runs one environment per process and exchanges one message
per environment and step (the action out, the observation, reward, flags and info dictionary back, the infos
stacked in the main process); an environment step here costs about a millisecond of plant time, and that
traffic took half of it (docs/policies.md, "Speed"). :class:`BatchVectorEnv` splits ``num_envs``
environments over ``workers`` processes (environment j in worker ``j * workers // num_envs``'s contiguous
slice, :attr:`BatchVectorEnv.worker_slices`); each step sends every worker one array of its environments'
actions and receives one array each of observations, rewards, terminations and truncations and the infos
already stacked, so the per-message cost is shared by the batch.

Semantics (those of ``gymnasium.vector.SyncVectorEnv`` with the same environments, environment by
environment; the tests check it against lone environments):

* ``reset(seed=s)``: environment j is reset with seed ``s + j`` (a list: seed ``s[j]``; None: unseeded), and
  ``options`` go to every environment, so environment j's episode is a lone environment's after
  ``env.reset(seed=s + j, options=options)``.
* autoreset: ``metadata["autoreset_mode"]``, Gymnasium 1.x's default ``AutoresetMode.NEXT_STEP``: the step
  after an environment's ``terminated or truncated`` does not step it: it calls its ``reset()`` (no seed: its
  generators go on, as a lone environment's second ``reset()`` would) and returns the reset's observation
  and info with reward 0 and both flags False; that step's action for it is ignored.
  ``autoreset_mode=AutoresetMode.SAME_STEP`` resets in the step that ended the episode instead: the
  observation returned is the new episode's first, the last one is in ``info["final_obs"]`` (object array,
  mask ``info["_final_obs"]``) and its info in ``info["final_info"]``. ``DISABLED`` is not offered.
* ``info``: Gymnasium's vector layout (each key an array over the environments with its mask ``"_key"``; a
  nested dictionary such as ``push`` a dictionary of such arrays), stacked in the workers. ``info_keys``
  keeps only the keys named (``()``: no infos, the leanest; None, the default: all keys).
* actions: an array of shape (num_envs, 6) (:attr:`action_space`), checked in this process before anything is
  sent: a wrong shape or a non-finite entry raises ``spec.ActionError`` naming it, and no environment moves.
  An error raised in a worker (a bad push option: ``pushes.PushOptionError``) is raised here, with its type,
  after every worker has answered; an environment reset raises before it changes anything, but a step error
  leaves the batch part-stepped: close the vector then.

Workers are started with ``context`` (a ``multiprocessing`` start method; None: the platform's default; use
"spawn" or "forkserver" when the main process runs threads, e.g. a JAX learner); the environment factories
go to them through cloudpickle (Gymnasium's ``CloudpickleWrapper``). Each worker builds its environments
once, then serves one request at a time. Pure Python, no ROS.
"""
from __future__ import annotations

import functools
import multiprocessing as mp
import pickle
import traceback
from typing import Any, Callable, Mapping, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import CloudpickleWrapper, batch_space

from biped_controller.policy.spec import ActionError

__all__ = ["BatchVectorEnv", "VectorWorkerError", "make_push_vector", "make_random_push_vector"]


class VectorWorkerError(RuntimeError):
    """A worker process failed in a way that cannot be re-raised as the original exception (it died, or its
    exception does not pickle); the message names the worker and carries the worker's traceback."""


def _stack(infos: list[Mapping[str, Any]]) -> dict:
    """The infos of a batch of environments in Gymnasium's vector layout, as ``VectorEnv._add_info`` builds
    it environment by environment, built here key by key (one array per key, not one assignment per
    environment and key): each key an array over the batch (dtype that of the first environment's value: a
    Python or NumPy number its type, an array (n, *shape), anything else an object array; ``final_obs``
    always an object array) with its mask ``"_key"``; a nested dictionary the same, recursively; an
    environment without the key holds zeros (None) and False. The masks that are all True are one array
    (``_merge`` copies them into arrays of their own)."""
    n = len(infos)
    full = np.ones(n, dtype=bool)      # the mask of every key all environments have: one object, pickled once
    keys: dict[str, None] = {}
    for d in infos:
        keys.update(dict.fromkeys(d))
    out: dict[str, Any] = {}
    for k in keys:
        have = [k in d for d in infos]
        vals = [d[k] for d in infos if k in d]
        first = vals[0]
        if k != "final_obs" and isinstance(first, dict):
            arr = _stack([d.get(k, {}) for d in infos])
        else:
            t = type(first)
            if k != "final_obs" and (t in (int, float, bool) or issubclass(t, np.number)):
                arr = np.zeros(n, dtype=t)
            elif k != "final_obs" and isinstance(first, np.ndarray):
                arr = np.zeros((n, *first.shape), dtype=first.dtype)
            else:
                arr = np.full(n, None, dtype=object)
            where = range(n) if len(vals) == n else [i for i, h in enumerate(have) if h]
            if arr.dtype == object:
                for i, v in zip(where, vals):
                    arr[i] = v
            else:
                arr[list(where)] = vals
        out[k] = arr
        out[f"_{k}"] = full if len(vals) == n else np.array(have, dtype=bool)
    return out


def _pick(info: Mapping[str, Any], keys: tuple[str, ...] | None) -> dict:
    return dict(info) if keys is None else {k: info[k] for k in keys if k in info}


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a :class:`VectorWorkerError` with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:   # noqa: BLE001 - any failure to round-trip means: send the text instead
        return VectorWorkerError(f"{type(exc).__name__}: {exc}")


def _worker(conn, fns: list, same_step: bool, info_keys: tuple[str, ...] | None) -> None:
    """One worker: builds its environments, then answers ``(command, argument)`` messages with
    ``("ok", payload)`` or ``("error", (exception, traceback text))`` (module docstring)."""
    try:
        envs = [fn() for fn in fns]
        n = len(envs)
        autoreset = np.zeros(n, dtype=bool)
        e0 = envs[0]
        conn.send(("ok", (e0.observation_space, e0.action_space, dict(e0.metadata), e0.render_mode)))
    except BaseException as exc:  # noqa: BLE001 - reported to the main process, which raises it
        conn.send(("error", (_portable(exc), traceback.format_exc())))
        conn.close()
        return
    while True:
        try:
            cmd, arg = conn.recv()
        except (EOFError, KeyboardInterrupt):
            break
        try:
            if cmd == "step":
                obs, infos = [], []
                rew, term, trunc = np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
                for i, env in enumerate(envs):
                    if autoreset[i] and not same_step:
                        o, info = env.reset()
                        info = _pick(info, info_keys)
                    else:
                        o, rew[i], term[i], trunc[i], info = env.step(arg[i])
                        info = _pick(info, info_keys)
                        if same_step and (term[i] or trunc[i]):
                            last, last_info = o, info
                            o, info = env.reset()
                            info = {**_pick(info, info_keys), "final_obs": last, "final_info": last_info}
                    obs.append(o)
                    infos.append(info)
                np.logical_or(term, trunc, out=autoreset)
                conn.send(("ok", (np.stack(obs), rew, term, trunc, _stack(infos))))
            elif cmd == "reset":
                seeds, options = arg
                obs, infos = [], []
                for env, s in zip(envs, seeds):
                    o, info = env.reset(seed=s, options=options)
                    obs.append(o)
                    infos.append(_pick(info, info_keys))
                autoreset[:] = False
                conn.send(("ok", (np.stack(obs), _stack(infos))))
            elif cmd == "call":
                name, args, kwargs = arg
                out = []
                for env in envs:
                    f = env.get_wrapper_attr(name)
                    out.append(f(*args, **kwargs) if callable(f) else f)
                conn.send(("ok", out))
            elif cmd == "get_attr":
                conn.send(("ok", [env.get_wrapper_attr(arg) for env in envs]))
            elif cmd == "set_attr":
                name, values = arg
                for env, v in zip(envs, values):
                    env.set_wrapper_attr(name, v)
                conn.send(("ok", None))
            elif cmd == "close":
                break
            else:
                raise ValueError(f"unknown command {cmd!r}")
        except BaseException as exc:  # noqa: BLE001 - reported to the main process, which raises it
            conn.send(("error", (_portable(exc), traceback.format_exc())))
    for env in envs:
        env.close()
    conn.close()


def _merge(parts: list[dict], sizes: list[int]) -> dict:
    """The workers' stacked infos (Gymnasium's layout, each over its own batch) joined over all
    environments; a key a worker lacks is zeros (None for objects) with its mask False there."""
    keys: list[str] = []
    for p in parts:
        keys.extend(k for k in p if k not in keys)
    out = {}
    for k in keys:
        sample = next(p[k] for p in parts if k in p)
        if isinstance(sample, dict):
            out[k] = _merge([p.get(k, {}) for p in parts], sizes)
            continue
        cols = []
        for p, n in zip(parts, sizes):
            if k in p:
                cols.append(p[k])
            elif sample.dtype == object:
                cols.append(np.full((n, *sample.shape[1:]), None, dtype=object))
            else:
                cols.append(np.zeros((n, *sample.shape[1:]), dtype=sample.dtype))
        out[k] = np.concatenate(cols)
    return out


class BatchVectorEnv(VectorEnv):
    """``len(env_fns)`` environments in ``workers`` processes, a contiguous batch each (module docstring).

    ``env_fns``: callables that each build one environment (the same spaces); ``workers``: processes, at most
    ``len(env_fns)``; ``autoreset_mode``: ``NEXT_STEP`` (default, Gymnasium's) or ``SAME_STEP``;
    ``info_keys``: the info keys kept (None: all; ``()``: none); ``context``: the multiprocessing start method
    (None: the default)."""

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], workers: int = 2,
                 autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
                 info_keys: Sequence[str] | None = None, context: str | None = None):
        self._conns: list = []
        self._procs: list = []
        self.closed = False
        fns = list(env_fns)
        if not fns:
            raise ValueError("env_fns: need at least one environment factory")
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or not 1 <= workers <= len(fns):
            raise ValueError(f"workers must be an integer in [1, {len(fns)}] (one environment at least each), "
                             f"got {workers!r}")
        mode = autoreset_mode if isinstance(autoreset_mode, AutoresetMode) else AutoresetMode(autoreset_mode)
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ValueError(f"autoreset_mode: NEXT_STEP or SAME_STEP, got {mode}")
        if isinstance(info_keys, str):
            raise ValueError(f"info_keys: a sequence of key names (or None for all), got the string {info_keys!r}")
        self.num_envs = len(fns)
        self.autoreset_mode = mode
        self.info_keys = None if info_keys is None else tuple(info_keys)
        bounds = [self.num_envs * w // int(workers) for w in range(int(workers) + 1)]
        self.worker_slices = tuple(slice(a, b) for a, b in zip(bounds, bounds[1:]))
        self._sizes = [s.stop - s.start for s in self.worker_slices]
        ctx = mp.get_context(context)
        try:
            for sl in self.worker_slices:
                parent, child = ctx.Pipe()
                p = ctx.Process(target=_worker, daemon=True, name=f"BatchVectorEnv-worker-{len(self._procs)}",
                                args=(child, [CloudpickleWrapper(f) for f in fns[sl]],
                                      mode == AutoresetMode.SAME_STEP, self.info_keys))
                p.start()
                child.close()
                self._conns.append(parent)
                self._procs.append(p)
            first = self._receive()
        except BaseException:
            self.close()
            raise
        obs_space, act_space, metadata, render_mode = first[0]
        for o, a, _, _ in first[1:]:
            if o != obs_space or a != act_space:
                self.close()
                raise ValueError(f"env_fns: the environments' spaces differ ({o}, {a} beside {obs_space}, {act_space})")
        if not isinstance(obs_space, spaces.Box) or not isinstance(act_space, spaces.Box):
            self.close()
            raise TypeError(f"BatchVectorEnv stacks Box spaces, got {obs_space} and {act_space}")
        self.single_observation_space, self.single_action_space = obs_space, act_space
        self.observation_space = batch_space(obs_space, self.num_envs)
        self.action_space = batch_space(act_space, self.num_envs)
        self.metadata = {**metadata, "autoreset_mode": mode}
        self.render_mode = render_mode

    # ------------------------------------------------------------------ messaging
    def _receive(self) -> list:
        """Every worker's answer (all are read, so the pipes stay in step), then the first error raised."""
        answers, error = [], None
        for w, (c, p) in enumerate(zip(self._conns, self._procs)):
            try:
                status, payload = c.recv()
            except (EOFError, OSError):
                status, payload = "error", (VectorWorkerError(
                    f"worker {w} (pid {p.pid}) ended without an answer (exit code {p.exitcode})"), "")
            if status == "error" and error is None:
                error = (w, *payload)
            answers.append(payload)
        if error is not None:
            w, exc, tb = error
            if isinstance(exc, VectorWorkerError) and tb:
                raise VectorWorkerError(f"worker {w}: {exc}\n{tb}")
            raise exc
        return answers

    def _ask(self, cmd: str, args: Sequence) -> list:
        if self.closed:
            raise RuntimeError("BatchVectorEnv: closed")
        for c, a in zip(self._conns, args):
            c.send((cmd, a))
        return self._receive()

    def _check_actions(self, actions) -> np.ndarray:
        a = np.asarray(actions)          # kept in its own dtype, as each environment would receive it alone
        if a.dtype.kind not in "fiu":
            raise ActionError(f"actions: not numeric (dtype {a.dtype})")
        want = (self.num_envs, *self.single_action_space.shape)
        if a.shape != want:
            raise ActionError(f"actions: shape {a.shape}, expected {want} (one action per environment, "
                              f"each {self.single_action_space.shape})")
        bad = ~np.isfinite(a)
        if bad.any():
            env = sorted({int(i) for i in np.flatnonzero(bad.reshape(self.num_envs, -1).any(axis=1))})
            raise ActionError(f"actions: non-finite entries for environment(s) {env}")
        return a

    # ------------------------------------------------------------------ the VectorEnv API
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: Mapping[str, Any] | None = None):
        """Reset every environment (module docstring: environment j gets seed ``seed + j``)."""
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + j for j in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed: a list of {self.num_envs} seeds (one per environment), got {len(seeds)}")
        if options is not None and "reset_mask" in options:
            raise ValueError("options: reset_mask (AutoresetMode.DISABLED) is not offered; "
                             "the environments autoreset")
        super().reset(seed=seeds[0] if seed is not None else None)
        parts = self._ask("reset", [(seeds[s], options) for s in self.worker_slices])
        return np.concatenate([p[0] for p in parts]), _merge([p[1] for p in parts], self._sizes)

    def step(self, actions):
        """One step of every environment (module docstring: autoreset; actions checked first)."""
        a = self._check_actions(actions)
        parts = self._ask("step", [a[s] for s in self.worker_slices])
        obs, rew, term, trunc, infos = zip(*parts)
        return (np.concatenate(obs), np.concatenate(rew), np.concatenate(term), np.concatenate(trunc),
                _merge(list(infos), self._sizes))

    def call(self, name: str, *args, **kwargs) -> tuple:
        """``name`` called on every environment (an attribute: its value), a tuple in environment order."""
        parts = self._ask("call", [(name, args, kwargs)] * len(self._conns))
        return tuple(x for p in parts for x in p)

    def get_attr(self, name: str) -> tuple:
        """The attribute ``name`` of every environment, in environment order."""
        return tuple(x for p in self._ask("get_attr", [name] * len(self._conns)) for x in p)

    def set_attr(self, name: str, values) -> None:
        """Set ``name`` on every environment: one value for all, or a list of ``num_envs``."""
        if not isinstance(values, (list, tuple)):
            values = [values] * self.num_envs
        if len(values) != self.num_envs:
            raise ValueError(f"set_attr: {self.num_envs} values (one per environment), got {len(values)}")
        self._ask("set_attr", [(name, list(values[s])) for s in self.worker_slices])

    def close_extras(self, **kwargs) -> None:
        for c in self._conns:
            try:
                c.send(("close", None))
            except (OSError, BrokenPipeError):
                pass
        for p in self._procs:
            p.join(timeout=10)
            if p.is_alive():
                p.terminate()
                p.join()
        for c in self._conns:
            c.close()
        self._conns, self._procs = [], []

    def close(self, **kwargs) -> None:
        if not self.closed:
            self.close_extras(**kwargs)
            self.closed = True

    def __del__(self):
        if not getattr(self, "closed", True):
            self.close()

    def __repr__(self) -> str:
        spec = f"{self.spec.id}, " if self.spec is not None else ""
        return f"BatchVectorEnv({spec}num_envs={self.num_envs}, workers={len(self.worker_slices)})"


def _make_registered(env_id: str, max_episode_steps: int | None, kwargs: dict) -> gym.Env:
    import biped_controller.policy  # noqa: F401 - registers the ids in a spawned worker
    return gym.make(env_id, max_episode_steps=max_episode_steps, **kwargs)


def _vector(env_id: str, num_envs: int, workers: int, autoreset_mode, info_keys, context,
            max_episode_steps, env_kwargs) -> BatchVectorEnv:
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
    fn = functools.partial(_make_registered, env_id, max_episode_steps, dict(env_kwargs))
    return BatchVectorEnv([fn] * int(num_envs), workers=min(int(workers), int(num_envs)),
                          autoreset_mode=autoreset_mode, info_keys=info_keys, context=context)


def make_push_vector(num_envs: int = 1, workers: int = 2, autoreset_mode=AutoresetMode.NEXT_STEP,
                     info_keys: Sequence[str] | None = None, context: str | None = None,
                     max_episode_steps: int | None = None, **env_kwargs) -> BatchVectorEnv:
    """``BipedPush-v0``'s vector entry point: ``gymnasium.make_vec("BipedPush-v0", num_envs, workers=...,
    **env_kwargs)`` gives ``num_envs`` environments ``gymnasium.make("BipedPush-v0", **env_kwargs)`` (with its
    time limit) over ``min(workers, num_envs)`` processes."""
    from biped_controller.policy.env import ENV_ID
    return _vector(ENV_ID, num_envs, workers, autoreset_mode, info_keys, context, max_episode_steps, env_kwargs)


def make_random_push_vector(num_envs: int = 1, workers: int = 2, autoreset_mode=AutoresetMode.NEXT_STEP,
                            info_keys: Sequence[str] | None = None, context: str | None = None,
                            max_episode_steps: int | None = None, **env_kwargs) -> BatchVectorEnv:
    """``BipedRandomPush-v0``'s vector entry point (as :func:`make_push_vector`)."""
    from biped_controller.policy.env import RANDOM_PUSH_ENV_ID
    return _vector(RANDOM_PUSH_ENV_ID, num_envs, workers, autoreset_mode, info_keys, context, max_episode_steps,
                   env_kwargs)
