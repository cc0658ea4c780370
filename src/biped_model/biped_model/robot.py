"""A robot is a directory: ``robots/<name>/`` (or any path) holding

- ``description.yaml`` -- its physical values (:mod:`biped_model.description`),
- ``gait.yaml``        -- the settings of its gait generation,
- ``gait_family.json`` -- its generated family q_d(p, tau), stamped with the hash of the description it was
  built for;
- ``settings.yaml``    -- optional: the keys of ``config/controller.yaml`` and ``config/simulator.yaml`` whose
  values depend on the robot's size (push and observer heights, MuJoCo's fall height and touch threshold,
  ``tau_dot_max``), each ``{value, reason}``, derived from the description by ``scripts/robot new``. They
  apply over the configuration files and under a profile and ``--set`` (:meth:`Robot.settings`). The default
  robot has none: its values are the configuration files'.

The URDF and the MJCF are generated from the description when asked (:meth:`Robot.urdf`,
:meth:`Robot.mjcf`); they are not stored.

**The stamp.** :func:`description_hash` is the sha256 of the description's physical values (every field of
:class:`~biped_model.description.RobotDescription` but ``source``, as sorted JSON; a reason's text or a
comment does not change it). A family built by ``scripts/robot build`` (or written by
``scripts/generate_gait_family``) carries it in the file itself, under ``robot_stamp`` (``description_sha256``); the default robot's committed family predates stamps and is kept
bit for bit, so its stamp lives beside it in ``gait_family.stamp.json``, which names the sha256 of the family
file's bytes as well (it stamps that file only). :meth:`Robot.family` refuses a family whose stamp names
another description, or that has no stamp at all, with one line naming both files.

Pure (no ROS); imports only ``biped_model``.
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

from biped_model.description import DescriptionError, RobotDescription, load_description
from biped_model.gait_family import GaitFamily, GaitFamilyError
from biped_model.settings import DEFAULT_ROBOT, robots_dir

DESCRIPTION_FILE = "description.yaml"
GAIT_FILE = "gait.yaml"
FAMILY_FILE = "gait_family.json"
STAMP_FILE = "gait_family.stamp.json"
STAMP_KEY = "robot_stamp"
SETTINGS_FILE = "settings.yaml"


class RobotError(ValueError):
    """A robot cannot be used: its directory, a file or a field is missing or wrong, or its family was built
    for another description. The message is one line naming the file (and the field)."""


def description_hash(desc: RobotDescription) -> str:
    """sha256 (64 hex digits) of the description's physical values (``source`` left out)."""
    values = {k: v for k, v in asdict(desc).items() if k != "source"}
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()


def file_sha256(path: os.PathLike | str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@dataclass(frozen=True)
class Robot:
    """One robot's directory. ``name`` is the directory's name (``biped7`` for the default robot)."""

    name: str
    directory: Path

    @property
    def description_path(self) -> Path:
        return self.directory / DESCRIPTION_FILE

    @property
    def gait_path(self) -> Path:
        return self.directory / GAIT_FILE

    @property
    def family_path(self) -> Path:
        return self.directory / FAMILY_FILE

    @property
    def stamp_path(self) -> Path:
        return self.directory / STAMP_FILE

    @property
    def is_default(self) -> bool:
        return self.directory.resolve() == (robots_dir() / DEFAULT_ROBOT).resolve()

    def description(self) -> RobotDescription:
        """The validated description (:class:`RobotError` naming the file and the field otherwise)."""
        return _description(self.description_path, _mtime(self.description_path))

    def description_hash(self) -> str:
        return description_hash(self.description())

    def has_family(self) -> bool:
        return self.family_path.is_file()

    def family_stamp(self) -> str | None:
        """The description hash the family is stamped with (None: no stamp). Raises :class:`RobotError`
        when there is no family file."""
        if not self.family_path.is_file():
            raise RobotError(f"{self.family_path}: no gait family built (run scripts/robot build {self.directory})")
        try:
            data = json.loads(self.family_path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise RobotError(f"{self.family_path}: does not parse as JSON: {exc}") from exc
        stamp = data.get(STAMP_KEY) if isinstance(data, dict) else None
        if isinstance(stamp, dict) and "description_sha256" in stamp:
            return str(stamp["description_sha256"])
        if self.stamp_path.is_file():
            side = json.loads(self.stamp_path.read_text(encoding="utf-8"))
            if side.get("family_sha256") == file_sha256(self.family_path):
                return str(side.get("description_sha256"))
        return None

    def check_stamp(self) -> str:
        """The description hash, after checking that the family was built for this description; raises
        :class:`RobotError` (one line naming both files) otherwise."""
        want = self.description_hash()
        got = self.family_stamp()
        if got is None:
            raise RobotError(f"{self.family_path}: has no stamp of the description it was built for; refused for "
                             f"{self.description_path} (rebuild: scripts/robot build {self.directory})")
        if got != want:
            raise RobotError(f"{self.family_path} was built for another description than {self.description_path} "
                             f"(stamp {got[:12]}, description {want[:12]}; rebuild: scripts/robot build {self.directory})")
        return want

    def family(self) -> GaitFamily:
        """The gait family, checked against the description's hash."""
        self.check_stamp()
        return _family(self.family_path, _mtime(self.family_path))

    @property
    def settings_path(self) -> Path:
        return self.directory / SETTINGS_FILE

    def settings(self) -> tuple[tuple[str, object], ...]:
        """The robot's own settings (``settings.yaml``: key -> value, sorted; empty without the file). Each
        entry must be ``{value, reason}`` with a reason (:class:`RobotError` naming the file and the key);
        whether a key is a controller or simulator key is checked where they are applied."""
        if not self.settings_path.is_file():
            return ()
        from biped_model.settings import SettingsError, load_yaml_tree, read_settings
        try:
            tree = load_yaml_tree(self.settings_path)
            values = read_settings(self.settings_path, list(tree))
        except SettingsError as exc:
            raise RobotError(str(exc)) from exc
        return tuple(sorted(values.items()))

    def urdf(self) -> str:
        from biped_model.description import make_urdf
        return make_urdf(self.description())

    def mjcf(self, **kwargs) -> str:
        from biped_model.mjcf import make_mjcf
        return make_mjcf(self.description(), **kwargs)


def _mtime(p: Path) -> int:
    try:
        return p.stat().st_mtime_ns
    except OSError:
        return -1


@functools.lru_cache(maxsize=16)
def _description(path: Path, mtime: int) -> RobotDescription:
    try:
        return load_description(path)
    except DescriptionError as exc:
        raise RobotError(f"{path}: {str(exc).removeprefix('biped description: ')}") from exc


@functools.lru_cache(maxsize=16)
def _family(path: Path, mtime: int) -> GaitFamily:
    try:
        return GaitFamily.load(path)
    except GaitFamilyError as exc:
        raise RobotError(str(exc)) from exc


def is_path_spec(spec: str) -> bool:
    """True when ``spec`` names a path (has a separator or starts with '.' or '~'), False for a bare name."""
    return os.sep in spec or "/" in spec or spec.startswith((".", "~"))


def resolve_robot(spec: str | os.PathLike | None = None) -> Robot:
    """The robot ``spec`` names: None or "" the default (``robots/biped7``); a bare name ``robots/<name>``;
    a path (with a '/', or starting with '.' or '~') that directory. Raises :class:`RobotError` naming the
    directory or its missing description."""
    if spec is None or str(spec) == "":
        d = robots_dir() / DEFAULT_ROBOT
    else:
        s = str(spec)
        d = Path(s).expanduser() if is_path_spec(s) else robots_dir() / s
    if not d.is_dir():
        known = ", ".join(robot_names()) or "none"
        raise RobotError(f"{d}: no such robot directory (robots: {known})")
    if not (d / DESCRIPTION_FILE).is_file():
        raise RobotError(f"{d / DESCRIPTION_FILE}: missing (a robot directory holds {DESCRIPTION_FILE}, {GAIT_FILE}, "
                         f"{FAMILY_FILE})")
    return Robot(d.resolve().name, d.resolve())


def robot_names() -> list[str]:
    """The robots under ``robots/`` (directories holding a ``description.yaml``), sorted."""
    root = robots_dir()
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if (p / DESCRIPTION_FILE).is_file())


def robot_label(spec: str | os.PathLike | None) -> str:
    """The name a record gives the robot ``spec`` names: the directory's name under ``robots/``, else its path."""
    r = resolve_robot(spec)
    return r.name if r.directory.parent.resolve() == robots_dir().resolve() else str(r.directory)
