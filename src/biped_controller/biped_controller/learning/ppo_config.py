"""The training settings of a learned baseline: ``config/training/<name>.yaml`` ({value, reason} per key,
read with ``biped_model.settings.read_settings``). Guide: docs/policies_training.md."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path

from biped_model.settings import default_config_dir, read_settings


class TrainConfigError(ValueError):
    """A training setting is missing, unknown or out of range (the message names it)."""


@dataclass(frozen=True)
class PpoConfig:
    """PPO and run settings (their meanings and reasons: the YAML file)."""

    seed: int
    plant: str
    robot: str
    num_envs: int
    workers: int
    rollouts: int
    learning_epochs: int
    mini_batches: int
    learning_rate: float
    discount_factor: float
    gae_lambda: float
    ratio_clip: float
    value_clip: float
    grad_norm_clip: float
    entropy_loss_scale: float
    value_loss_scale: float
    time_limit_bootstrap: bool
    hidden_sizes: tuple[int, ...]
    initial_log_std: float
    normalize_observations: bool
    normalize_values: bool
    checkpoint_minutes: float
    budget_minutes: float
    smoke_updates: int
    record_observations: int
    env_settings: dict
    push_distribution: dict
    budget_spent_minutes: float

    def validate(self) -> "PpoConfig":
        ints = ("seed", "num_envs", "workers", "rollouts", "learning_epochs", "mini_batches", "smoke_updates",
                "record_observations")
        for k in ints:
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, int) or v < (0 if k == "seed" else 1):
                raise TrainConfigError(f"{k} must be an integer >= {0 if k == 'seed' else 1}, got {v!r}")
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ints or f.name in ("plant", "robot", "hidden_sizes", "env_settings",
                                                        "push_distribution") or isinstance(v, bool):
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise TrainConfigError(f"{f.name} must be a finite number, got {v!r}")
        for k in ("time_limit_bootstrap", "normalize_observations", "normalize_values"):
            if not isinstance(getattr(self, k), bool):
                raise TrainConfigError(f"{k} must be true or false, got {getattr(self, k)!r}")
        if self.plant not in ("mujoco", "rigid"):
            raise TrainConfigError(f"plant must be mujoco or rigid, got {self.plant!r}")
        from biped_model.robot import RobotError, resolve_robot
        try:
            resolve_robot(self.robot).description()
        except RobotError as exc:
            raise TrainConfigError(f"robot: {exc}") from None
        if not self.hidden_sizes or any(isinstance(h, bool) or not isinstance(h, int) or h < 1
                                        for h in self.hidden_sizes):
            raise TrainConfigError(f"hidden_sizes must be a list of integers >= 1, got {self.hidden_sizes!r}")
        if self.workers > self.num_envs:
            raise TrainConfigError(f"workers ({self.workers}) must be at most num_envs ({self.num_envs})")
        if (self.rollouts * self.num_envs) % self.mini_batches:
            raise TrainConfigError(f"mini_batches ({self.mini_batches}) must divide rollouts x num_envs "
                                   f"({self.rollouts * self.num_envs})")
        for k in ("learning_rate", "checkpoint_minutes", "budget_minutes"):
            if not getattr(self, k) > 0:
                raise TrainConfigError(f"{k} must be > 0, got {getattr(self, k)!r}")
        if not isinstance(self.env_settings, dict):
            raise TrainConfigError(f"env_settings must be a mapping of environment settings, got {self.env_settings!r}")
        from biped_controller.policy.env import EnvConfigError, load_env_config
        try:
            load_env_config(**self.env_settings)
        except (EnvConfigError, TypeError) as exc:
            raise TrainConfigError(f"env_settings: {exc}") from None
        from biped_controller.policy.pushes import PushDistribution, PushOptionError
        try:
            PushDistribution(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in dict(self.push_distribution).items()})
        except (PushOptionError, TypeError, ValueError) as exc:
            raise TrainConfigError(f"push_distribution: {exc}") from None
        if not 0 <= self.budget_spent_minutes < self.budget_minutes:
            raise TrainConfigError(f"budget_spent_minutes must be in [0, budget_minutes), got {self.budget_spent_minutes!r}")
        for k in ("discount_factor", "gae_lambda"):
            if not 0 <= getattr(self, k) <= 1:
                raise TrainConfigError(f"{k} must be in [0, 1], got {getattr(self, k)!r}")
        return self


def config_path(name: str) -> Path:
    return default_config_dir() / "training" / f"{name}.yaml"


def known_names() -> list[str]:
    d = default_config_dir() / "training"
    return sorted(p.stem for p in d.glob("*.yaml")) if d.is_dir() else []


def load_config(name: str, **overrides) -> PpoConfig:
    """``config/training/<name>.yaml`` with ``overrides`` (None ignored); :class:`TrainConfigError` naming an
    unknown name or a bad value."""
    p = config_path(name)
    if not p.is_file():
        raise TrainConfigError(f"unknown baseline {name!r}: no config/training/{name}.yaml "
                               f"(known: {', '.join(known_names()) or 'none'})")
    kw = read_settings(p, PpoConfig.__dataclass_fields__)
    kw["hidden_sizes"] = tuple(kw["hidden_sizes"]) if isinstance(kw["hidden_sizes"], list) else kw["hidden_sizes"]
    cfg = PpoConfig(**kw)
    extra = {k: v for k, v in overrides.items() if v is not None}
    unknown = [k for k in extra if k not in PpoConfig.__dataclass_fields__]
    if unknown:
        raise TrainConfigError(f"unknown training setting {unknown[0]!r}")
    return replace(cfg, **extra).validate()
