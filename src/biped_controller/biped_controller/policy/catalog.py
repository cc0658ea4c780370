"""The committed policies: each directory ``policies/<name>/`` of the repository holding ``policy.onnx``
and ``policy.json`` is a controller named ``<name>`` (an :class:`~biped_controller.policy.controller.OnnxPolicy`
bound to that file), listed among the controllers and taken by every study, the capability map and the
controller node by that name (``--controller <name>``).

``policy.json`` (its fields checked by ``controller.check_metadata``): ``description`` (one line),
``observation`` (the environment's observation names, ``policy.spec.OBS_FIELDS``), ``action``
(``policy.spec.ACTION_FIELDS``), ``policy_period`` [s], and whatever the trainer records of how it was made
(plant, robot, steps, provenance). The directory is ``$BIPED_POLICIES`` when set, else ``policies/`` of the
repository (``biped_model.settings.repo_root``).

The registry finds the names through the catalog entry point (``plugin.registry.CATALOG_GROUP``):
:func:`registrations` lists them, and ``biped_controller.policy.catalog:<name>`` (this module's
``__getattr__``) is the bound class.
"""
from __future__ import annotations

import functools
import json
import os
import re
from pathlib import Path

from biped_model.settings import repo_root

from biped_controller.policy.controller import OnnxPolicy

NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def policies_dir() -> Path:
    """Where the committed policies are (module docstring)."""
    env = os.environ.get("BIPED_POLICIES")
    return Path(env) if env else repo_root() / "policies"


def policy_names() -> list[str]:
    """The names of the committed policies (directories with ``policy.onnx`` and a valid name), sorted."""
    d = policies_dir()
    if not d.is_dir():
        return []
    return sorted(p.name for p in d.iterdir()
                  if NAME.match(p.name) and (p / "policy.onnx").is_file() and (p / "policy.json").is_file())


def registrations() -> list[tuple[str, str]]:
    """``[(name, "biped_controller.policy.catalog:name"), ...]``: the catalog the registry reads."""
    return [(n, f"{__name__}:{n}") for n in policy_names()]


@functools.lru_cache(maxsize=32)
def policy_class(name: str, path: str) -> type:
    """An :class:`OnnxPolicy` subclass bound to the file ``path``, named after the policy."""
    meta_path = Path(path).with_name("policy.json")
    try:
        desc = str(json.loads(meta_path.read_text(encoding="utf-8")).get("description", ""))
    except (OSError, ValueError, AttributeError):
        desc = ""
    return type(f"Policy_{name}", (OnnxPolicy,), {
        "policy_file": path, "required_options": (), "__module__": __name__, "__qualname__": f"Policy_{name}",
        "description": desc or f"committed ONNX policy {name} ({path})"})


def __getattr__(name: str) -> type:
    if name.startswith("__") or not NAME.match(name):
        raise AttributeError(name)
    f = policies_dir() / name / "policy.onnx"
    if not f.is_file():
        raise AttributeError(f"no committed policy {name!r} ({f} is missing)")
    return policy_class(name, str(f))
