"""A trained policy's deterministic action as plain NumPy: the standardised observation through a tanh MLP
to the mean of the Gaussian policy. The weights file (``weights.npz``) is what the exporter and the tests read.

Maths (float32, as trained), for an observation o (22,) [the units of ``policy.spec``]:

    x   = clip((o - mu) / (sqrt(var) + eps), -c, c)         (skrl's RunningStandardScaler; identity if absent)
    h_1 = tanh(x W_1 + b_1), ..., h_n = tanh(h_{n-1} W_n + b_n)
    a   = h_n W_out + b_out                                 (6,) torque / limit, not clipped (the environment
                                                             and the controller clip to [-1, 1])

``weights.npz`` keys: ``obs_mean``, ``obs_var`` (22,), ``obs_eps``, ``obs_clip`` (scalars), ``W0``, ``b0``, ...,
``W{n}``, ``b{n}`` (the last pair the output layer; W_k of shape (in, out)), ``log_std`` (6,) (the Gaussian's
state-independent log standard deviation, not used by the mean), ``activation`` ("tanh").
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


class WeightsError(ValueError):
    """A weights file or array set that is not a tanh MLP from 22 observations to 6 actions (message names it)."""


@dataclass(frozen=True)
class MlpPolicy:
    """The weights of module docstring's network (float32 arrays)."""

    obs_mean: np.ndarray
    obs_var: np.ndarray
    obs_eps: float
    obs_clip: float
    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    log_std: np.ndarray

    def __post_init__(self):
        n_in = self.obs_mean.shape[0]
        if self.obs_var.shape != (n_in,):
            raise WeightsError(f"obs_var has shape {self.obs_var.shape}, expected ({n_in},)")
        if len(self.weights) != len(self.biases) or not self.weights:
            raise WeightsError(f"{len(self.weights)} weight matrices and {len(self.biases)} bias vectors")
        width = n_in
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            if w.ndim != 2 or w.shape[0] != width or b.shape != (w.shape[1],):
                raise WeightsError(f"layer {k}: W{k} {w.shape}, b{k} {b.shape} after a width of {width}")
            width = w.shape[1]
        if self.log_std.shape != (width,):
            raise WeightsError(f"log_std has shape {self.log_std.shape}, expected ({width},)")

    @property
    def n_obs(self) -> int:
        return int(self.obs_mean.shape[0])

    @property
    def n_act(self) -> int:
        return int(self.weights[-1].shape[1])

    def standardise(self, obs: np.ndarray) -> np.ndarray:
        """x of the module docstring, float32, (N, 22) or (22,)."""
        o = np.asarray(obs, dtype=np.float32)
        return np.clip((o - self.obs_mean) / (np.sqrt(self.obs_var) + np.float32(self.obs_eps)),
                       -np.float32(self.obs_clip), np.float32(self.obs_clip))

    def mean_action(self, obs: np.ndarray) -> np.ndarray:
        """The deterministic action a (the module docstring), float32, for (N, 22) or (22,) observations."""
        h = self.standardise(obs)
        last = len(self.weights) - 1
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = h @ w + b
            if k < last:
                h = np.tanh(h)
        return h

    def arrays(self) -> dict[str, np.ndarray]:
        """The ``weights.npz`` arrays (module docstring)."""
        out = {"obs_mean": self.obs_mean, "obs_var": self.obs_var, "obs_eps": np.float32(self.obs_eps),
               "obs_clip": np.float32(self.obs_clip), "log_std": self.log_std, "activation": np.array("tanh")}
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            out[f"W{k}"], out[f"b{k}"] = w, b
        return out

    def save(self, path: str | Path) -> None:
        np.savez(path, **self.arrays())

    @classmethod
    def from_arrays(cls, arrays) -> "MlpPolicy":
        """From a mapping of the ``weights.npz`` keys (a loaded npz file or a dict)."""
        keys = set(arrays.keys())
        missing = [k for k in ("obs_mean", "obs_var", "obs_eps", "obs_clip", "log_std", "W0", "b0") if k not in keys]
        if missing:
            raise WeightsError(f"weights: missing {', '.join(missing)}")
        if "activation" in keys and str(arrays["activation"]) != "tanh":
            raise WeightsError(f"weights: activation {str(arrays['activation'])!r}, only 'tanh' is known")
        n = 0
        while f"W{n}" in keys:
            n += 1
        f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
        return cls(obs_mean=f32(arrays["obs_mean"]), obs_var=f32(arrays["obs_var"]),
                   obs_eps=float(arrays["obs_eps"]), obs_clip=float(arrays["obs_clip"]),
                   weights=tuple(f32(arrays[f"W{k}"]) for k in range(n)),
                   biases=tuple(f32(arrays[f"b{k}"]) for k in range(n)), log_std=f32(arrays["log_std"]))

    @classmethod
    def load(cls, path: str | Path) -> "MlpPolicy":
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls.from_arrays(z)
        except (OSError, ValueError) as exc:
            if isinstance(exc, WeightsError):
                raise
            raise WeightsError(f"weights file {path}: {exc}") from None
