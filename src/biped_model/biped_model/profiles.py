"""Named profiles: sets of settings that differ from ``config/controller.yaml`` and ``config/simulator.yaml``
(pure: no ROS import).

A profile is ``config/profiles/NAME.yaml``::

    description: "one line: what this profile is"
    settings:                    # controller or simulator keys, each {value, reason}
      disturbance_observer: {value: false, reason: "why this differs from the default"}
    perturbation:                # optional: fields of biped_sim.plant.perturbation.PlantPerturbation
      delay: {value: 2, reason: "..."}

Only the settings that differ from the defaults are listed, each with its reason. ``default`` is the
profile with no entries (the configuration files as they are). Which keys are valid is decided by the
readers of the settings (the controller's and the simulator's configs, the plant perturbation): this
module checks the file's shape only.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from biped_model.settings import SettingsError, default_config_dir, load_yaml_tree

__all__ = ["DEFAULT_PROFILE", "Profile", "ProfileError", "profile_dir", "profile_names", "load_profile"]

#: the profile of a run that names none: the configuration files as they are
DEFAULT_PROFILE = "default"


class ProfileError(ValueError):
    """An unknown profile name (the message lists the known ones) or a malformed profile file (the message
    names the file and the entry)."""


@dataclass(frozen=True)
class Profile:
    """A named profile: ``settings`` (controller and simulator keys -> values) and ``perturbation`` (plant
    perturbation fields -> values), each a sorted tuple of (key, value) pairs (hashable); ``reasons``
    maps every key (perturbation keys prefixed ``perturbation.``) to its one-line reason."""

    name: str
    description: str
    settings: tuple[tuple[str, Any], ...] = ()
    perturbation: tuple[tuple[str, Any], ...] = ()
    reasons: tuple[tuple[str, str], ...] = ()


def profile_dir(config_dir: str | os.PathLike[str] | None = None) -> Path:
    return Path(config_dir if config_dir is not None else default_config_dir()) / "profiles"


def profile_names(config_dir: str | os.PathLike[str] | None = None) -> tuple[str, ...]:
    """The names of the profiles in ``config/profiles/`` (file names without ``.yaml``), sorted."""
    d = profile_dir(config_dir)
    return tuple(sorted(p.stem for p in d.glob("*.yaml"))) if d.is_dir() else ()


def _entries(path: Path, tree: dict, section: str) -> tuple[tuple[tuple[str, Any], ...], dict[str, str]]:
    sec = tree.get(section) or {}
    if not isinstance(sec, dict):
        raise ProfileError(f"{path}: '{section}' must be a mapping of key: {{value, reason}}")
    values, reasons = {}, {}
    for k, entry in sec.items():
        if not isinstance(entry, dict) or "value" not in entry:
            raise ProfileError(f"{path}: '{section}.{k}' must be {{value, reason}}, got {entry!r}")
        reason = str(entry.get("reason", "")).strip()
        if not reason:
            raise ProfileError(f"{path}: '{section}.{k}' has no reason")
        values[str(k)] = entry["value"]
        reasons[str(k)] = reason
    return tuple(sorted(values.items())), reasons


def load_profile(name: str, config_dir: str | os.PathLike[str] | None = None) -> Profile:
    """The profile ``name``; raises :class:`ProfileError` naming the known profiles when there is no such
    file, or naming the file and the entry when it is malformed."""
    known = profile_names(config_dir)
    if name not in known:
        raise ProfileError(f"unknown profile {name!r}; known profiles: {', '.join(known) or '(none)'}")
    path = profile_dir(config_dir) / f"{name}.yaml"
    try:
        tree = load_yaml_tree(path)
    except SettingsError as exc:
        raise ProfileError(str(exc)) from exc
    extra = set(tree) - {"description", "settings", "perturbation"}
    if extra:
        raise ProfileError(f"{path}: unknown entries {sorted(extra)} (expected description, settings, perturbation)")
    description = str(tree.get("description", "")).strip()
    if not description:
        raise ProfileError(f"{path}: 'description' is missing")
    settings, r1 = _entries(path, tree, "settings")
    perturbation, r2 = _entries(path, tree, "perturbation")
    reasons = {**r1, **{f"perturbation.{k}": v for k, v in r2.items()}}
    return Profile(name, description, settings, perturbation, tuple(sorted(reasons.items())))
