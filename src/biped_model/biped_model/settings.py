"""The one reader of the project's ``{value, reason}`` settings files (pure: no ROS import).

Every number the software assumes lives in ``config/*.yaml`` as ``key: {value: V, reason: "why"}``
(``robots/biped7/description.yaml`` nests such leaves in groups). This module is the only place that opens those
files; the dataclasses that hold settings (``SimConfig``, ``ControllerConfig``, ``GaitSettings``,
``RobotDescription``) carry no default values of their own, so a bare ``Simulator()`` and a node
read the very same numbers.

``repo_root()`` is the project's root (``BIPED_ROOT`` overrides it); ``config/`` lives there.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Iterable

import yaml


class SettingsError(ValueError):
    """A settings file is missing, does not parse, or an entry is not ``{value, reason}`` (message names
    the file and the key)."""


def repo_root() -> Path:
    """The project's root (``config/`` lives there). ``BIPED_ROOT`` overrides it."""
    env = os.environ.get("BIPED_ROOT")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3]


def default_config_dir() -> Path:
    return repo_root() / "config"


DEFAULT_ROBOT = "biped7"


def robots_dir() -> Path:
    """Where robots live: ``robots/<name>/`` holds a robot's ``description.yaml`` (its physical values),
    ``gait.yaml`` (the settings of its gait generation) and ``gait_family.json`` (the generated family)."""
    return repo_root() / "robots"


def default_robot_dir() -> Path:
    """The default robot's directory, ``robots/biped7`` (the 41 kg seven-link biped with 0.2 m feet)."""
    return robots_dir() / DEFAULT_ROBOT


# libyaml's parser under PyYAML's safe constructor (the same tree as yaml.safe_load, about 10x faster: the
# settings files are read at every config load); PyYAML's own parser where the wheel lacks libyaml
YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_yaml_tree(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The parsed YAML mapping of a settings file (empty file -> {})."""
    p = Path(path)
    if not p.is_file():
        raise SettingsError(f"{p}: settings file not found")
    try:
        with open(p, encoding="utf-8") as fh:
            tree = yaml.load(fh, Loader=YAML_LOADER)
    except yaml.YAMLError as exc:
        raise SettingsError(f"{p}: does not parse as YAML: {exc}") from exc
    if tree is None:
        return {}
    if not isinstance(tree, dict):
        raise SettingsError(f"{p}: expected a mapping of key: {{value, reason}}, got {type(tree).__name__}")
    return tree


def read_settings(path: str | os.PathLike[str], keys: Iterable[str]) -> dict[str, Any]:
    """``{key: value}`` for each of ``keys`` (e.g. a dataclass's ``__dataclass_fields__``).

    Every requested key must be present as ``{value, reason}`` with a non-empty reason; a missing key,
    a bare value or an empty reason raises :class:`SettingsError` naming the file and the key. Keys of
    the file that are not requested are ignored (another reader may own them)."""
    tree = load_yaml_tree(path)
    out: dict[str, Any] = {}
    for k in keys:
        if k not in tree:
            raise SettingsError(f"{path}: '{k}' is missing (every setting is {{value, reason}})")
        entry = tree[k]
        if not isinstance(entry, dict) or "value" not in entry:
            raise SettingsError(f"{path}: '{k}' must be {{value, reason}}, got {entry!r}")
        if not str(entry.get("reason", "")).strip():
            raise SettingsError(f"{path}: '{k}' has no reason")
        out[k] = entry["value"]
    return out


def iter_reasons(tree: dict[str, Any], prefix: str = ""):
    """Yield (dotted key, value, reason) for every ``{value, reason}`` leaf of a (nested) tree."""
    for k, v in tree.items():
        key = f"{prefix}.{k}" if prefix else k
        if isinstance(v, dict) and "value" in v:
            yield key, v["value"], v.get("reason", "")
        elif isinstance(v, dict):
            yield from iter_reasons(v, key)
