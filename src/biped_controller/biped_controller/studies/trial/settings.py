"""A run's settings: a named profile, ``--set`` overrides of ``config/controller.yaml`` and
``config/simulator.yaml``, the plant's perturbation; their parsing and their printed form.

Precedence, lowest first: the configuration files, the profile (``config/profiles/NAME.yaml``,
:mod:`biped_model.profiles`), ``--set KEY=VALUE`` and ``--observer on|off``, ``--perturb FIELD=VALUE``
(over the profile's perturbation fields). Values are parsed as YAML scalars; the config loaders check
them (a bad value raises the config's error naming the key).
"""
from __future__ import annotations

import functools
import os
from dataclasses import asdict, dataclass

import yaml

from biped_sim.plant.config import SimConfig, load_sim_config
from biped_sim.plant.perturbation import PlantPerturbation
from biped_model.profiles import DEFAULT_PROFILE, ProfileError, load_profile, profile_names
from biped_model.settings import default_config_dir

from biped_controller.core.control.config import MODES, ControllerConfig, load_controller_config
from biped_controller.studies.trial.context import context, select_robot

__all__ = ["OverrideError", "ProfileError", "CONTROLLER_KEYS", "SIMULATOR_KEYS", "RunSettings", "DEFAULT_SETTINGS",
           "DEFAULT_PROFILE", "profile_names", "parse_overrides", "parse_perturbation", "run_settings",
           "check_settings", "differences", "print_settings"]


class OverrideError(ValueError):
    """A ``--set``/``--observer``/``--perturb`` override or a profile entry names an unknown key, is
    malformed, or contradicts another one (the message names the key)."""


#: keys ``--set`` may override: every ControllerConfig field but ``mode`` (chosen by the subcommand) and
#: ``period`` (it is the simulator's ``control_period``), and every SimConfig field
CONTROLLER_KEYS: tuple[str, ...] = tuple(k for k in ControllerConfig.__dataclass_fields__ if k not in ("mode", "period"))
SIMULATOR_KEYS: tuple[str, ...] = tuple(SimConfig.__dataclass_fields__)


@functools.lru_cache(maxsize=16)
def _sim_config(items: tuple[tuple[str, object], ...]) -> SimConfig:
    return context().sim_config if not items else load_sim_config(**dict(items))


@dataclass(frozen=True)
class RunSettings:
    """The settings of a run (hashable, picklable: it travels to the worker processes): the overrides of
    config/controller.yaml (``controller``) and config/simulator.yaml (``simulator``) as sorted (key,
    value) pairs, the profile's entries included; empty = the config files as they are. ``perturbation``:
    the plant's model error, friction and sensing, given to the simulator only (None: none).
    ``full_trials``: run every survival trial in full (no early stop). ``profile``: the name of the profile
    the overrides start from. Neither ``full_trials`` nor ``profile`` is part of :meth:`describe` (an
    early-stopped trial has the outcome of the full one; a profile is its overrides). ``robot``: the robot
    (a name under ``robots/`` or a path; "" the default robot), which every process that runs a trial with
    these settings selects (:meth:`activate`); :meth:`describe` names it only when it is not the default."""

    controller: tuple[tuple[str, object], ...] = ()
    simulator: tuple[tuple[str, object], ...] = ()
    perturbation: PlantPerturbation | None = None
    full_trials: bool = False
    profile: str = DEFAULT_PROFILE
    robot: str = ""

    def activate(self) -> "RunSettings":
        """Select this run's robot in this process (``trial.context.select_robot``); returns self."""
        select_robot(self.robot)
        return self

    def sim_config(self) -> SimConfig:
        return _sim_config(self.simulator)

    def ctrl_config(self, mode: str) -> ControllerConfig:
        """The controller settings for ``mode``; the period is the simulator's control period. Read again
        whenever ``config/controller.yaml`` or ``config/simulator.yaml`` changed (their modification
        times key a per-process cache: a YAML parse costs more than a failing simulation)."""
        return _ctrl_config(mode, self.controller, self.simulator, _config_stamp())

    def describe(self) -> dict:
        """JSON-ready: the overrides and the effective settings (every key of both files; the MuJoCo
        plant's keys left out on the rigid plant, where they do not act). The capability map's store
        fingerprint hashes this dict."""
        ctrl = asdict(self.ctrl_config(MODES[0]))
        del ctrl["mode"]
        sim = asdict(self.sim_config())
        if sim["plant"] == "rigid":
            sim = {k: v for k, v in sim.items() if k != "plant" and not k.startswith("mujoco_")}
        out = {"overrides": {**dict(self.controller), **dict(self.simulator)},
               "controller": ctrl, "simulator": sim}
        if self.perturbation is not None and not self.perturbation.is_zero:   # (absent: nominal plant)
            out["perturbation"] = self.perturbation.as_dict()
        if self.robot:                      # (absent: the default robot, as every record before robots)
            ctx = context(self.robot)
            out["robot"] = {"name": ctx.robot.name, "description_sha256": ctx.robot_hash}
        return out


DEFAULT_SETTINGS = RunSettings()


def _config_stamp() -> tuple[int, int]:
    d = default_config_dir()
    return (os.stat(d / "controller.yaml").st_mtime_ns, os.stat(d / "simulator.yaml").st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _ctrl_config(mode: str, controller: tuple, simulator: tuple, stamp: tuple[int, int]) -> ControllerConfig:
    return load_controller_config(mode=mode, period=_sim_config(simulator).control_period, **dict(controller))


def _scalar(text: str) -> object:
    """A YAML scalar, with numbers such as ``5e-4`` that YAML 1.1 reads as words taken as numbers."""
    v = yaml.safe_load(text)
    if isinstance(v, str):
        for conv in (int, float):
            try:
                return conv(v)
            except ValueError:
                pass
    return v


def _parse_value(key: str, text: str) -> object:
    try:
        v = _scalar(text)
    except yaml.YAMLError as exc:
        raise OverrideError(f"--set {key}={text}: the value does not parse: {exc}") from exc
    if not isinstance(v, (bool, int, float, str)):
        raise OverrideError(f"--set {key}={text}: expected a number, true/false or a word, got {text!r}")
    return v


def _place(key: str, value: object, ctrl: dict, sim: dict, origin: str) -> None:
    """Put ``key`` = ``value`` into the controller or simulator overrides (``origin`` names the source in errors)."""
    if key in CONTROLLER_KEYS:
        ctrl[key] = value
    elif key in SIMULATOR_KEYS:
        sim[key] = value
    elif key in ("mode", "period"):
        raise OverrideError(f"{origin} {key}: not overridable here ("
                            + ("use the subcommand's --mode" if key == "mode" else "set control_period") + ")")
    else:
        raise OverrideError(f"{origin} {key}: unknown setting {key!r}; controller keys: {', '.join(CONTROLLER_KEYS)}; "
                            f"simulator keys: {', '.join(SIMULATOR_KEYS)}")


def parse_overrides(items: list[str] | tuple[str, ...] = (), observer: str | bool | None = None,
                    full_trials: bool = False, profile: str | None = None, robot: str | None = None) -> RunSettings:
    """``RunSettings`` from the profile ``profile`` (None: ``default``), ``KEY=VALUE`` strings over it and
    the observer switch ("on"/"off"/bool/None = as the profile and the config file say). The profile's
    plant perturbation is set too. Raises :class:`ProfileError` naming the known profiles for an unknown
    one, :class:`OverrideError` naming an unknown or repeated key or a malformed item; a value out of
    range raises the config's own error (ControllerConfigError / SimConfigError, naming the key) when
    :func:`check_settings` builds the configs."""
    name = DEFAULT_PROFILE if profile is None else profile
    prof = load_profile(name)
    ctrl: dict[str, object] = {}
    sim: dict[str, object] = {}
    robot = canonical_robot(robot)
    if robot:                           # the robot's own settings (robots/<name>/settings.yaml), under the profile
        from biped_model.robot import resolve_robot
        r = resolve_robot(robot)
        for key, value in r.settings():
            _place(key, value, ctrl, sim, f"{r.settings_path}:")
    for key, value in prof.settings:
        _place(key, value, ctrl, sim, f"profile {name}:")
    given: set[str] = set()
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise OverrideError(f"--set expects KEY=VALUE, got {item!r}")
        if key in given:
            raise OverrideError(f"--set {key}: given twice")
        given.add(key)
        _place(key, _parse_value(key, text), ctrl, sim, "--set")
    if observer is not None:
        on = observer if isinstance(observer, bool) else {"on": True, "off": False}.get(str(observer))
        if on is None:
            raise OverrideError(f"--observer must be on or off, got {observer!r}")
        if "disturbance_observer" in given and ctrl["disturbance_observer"] != on:
            raise OverrideError("disturbance_observer: --observer and --set disagree")
        ctrl["disturbance_observer"] = on
    pert = None
    if prof.perturbation:
        try:
            pert = PlantPerturbation.from_dict(dict(prof.perturbation))
        except ValueError as exc:
            raise OverrideError(f"profile {name}: perturbation: {exc}") from exc
    return RunSettings(tuple(sorted(ctrl.items())), tuple(sorted(sim.items())), pert, full_trials=bool(full_trials),
                       profile=name, robot=robot)


def canonical_robot(robot: str | None) -> str:
    """The ``RunSettings.robot`` of ``--robot`` ``robot``: "" for None, "" or the default robot (so that its
    settings equal the settings before robots existed), else the name under ``robots/`` or the absolute path.
    Raises ``RobotError`` (one line naming the directory or file) for a robot that cannot be used."""
    from biped_model.robot import resolve_robot
    from biped_model.settings import robots_dir
    if robot is None or str(robot) == "":
        return ""
    r = resolve_robot(robot)
    if r.is_default:
        return ""
    context(r.name if r.directory.parent == robots_dir().resolve() else str(r.directory))    # fails now, not in a worker
    return r.name if r.directory.parent == robots_dir().resolve() else str(r.directory)


def parse_perturbation(items: list[str] | tuple[str, ...] = (),
                       base: PlantPerturbation | None = None) -> PlantPerturbation | None:
    """A ``PlantPerturbation`` from ``FIELD=VALUE`` strings over ``base`` (a profile's; values parsed as
    YAML scalars; ``base`` when empty). The item ``none`` drops ``base`` (the profile's plant perturbation,
    e.g. the sensor noise of ``real-sensors``): the other items then apply to the unperturbed plant, and
    ``none`` alone gives None. Raises :class:`OverrideError` for a malformed or repeated item and
    ``PerturbationError`` naming a bad field or value."""
    vals: dict[str, object] = {}
    if "none" in (str(i).strip() for i in items):
        if sum(1 for i in items if str(i).strip() == "none") > 1:
            raise OverrideError("--perturb none: given twice")
        items = [i for i in items if str(i).strip() != "none"]
        base = None
        if not items:
            return None
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise OverrideError(f"--perturb expects FIELD=VALUE, got {item!r}")
        if key in vals:
            raise OverrideError(f"--perturb {key}: given twice")
        try:
            v = _scalar(text)
        except yaml.YAMLError as exc:
            raise OverrideError(f"--perturb {key}={text}: the value does not parse: {exc}") from exc
        vals[key] = v
    if not vals:
        return base
    merged = {**(base.as_dict() if base is not None else {}), **vals}
    return PlantPerturbation.from_dict(merged)


def run_settings(profile: str | None = None, overrides: list[str] | tuple[str, ...] = (),
                 observer: str | bool | None = None, perturb: list[str] | tuple[str, ...] = (),
                 full_trials: bool = False, robot: str | None = None) -> RunSettings:
    """:func:`parse_overrides` and :func:`parse_perturbation` together, the configs built once
    (:func:`check_settings`): the settings of a command line (``robot``: ``--robot``, selected in this
    process too). Raises what those raise."""
    settings = parse_overrides(overrides, observer, full_trials, profile, robot)
    pert = parse_perturbation(perturb, settings.perturbation)
    if pert is not settings.perturbation:
        settings = RunSettings(settings.controller, settings.simulator, pert, settings.full_trials, settings.profile,
                               settings.robot)
    settings.activate()
    check_settings(settings)
    return settings


def check_settings(settings: RunSettings) -> dict:
    """Build both configs once (a bad value raises the config's error naming the key); the description."""
    return settings.describe()


def differences(settings: RunSettings) -> dict:
    """JSON-ready: the profile's name, the effective controller and simulator settings that differ from
    the configuration files (key -> value), and the plant perturbation's non-zero fields (absent when
    none)."""
    ctrl = asdict(settings.ctrl_config(MODES[0]))
    base_ctrl = asdict(DEFAULT_SETTINGS.ctrl_config(MODES[0]))
    sim = asdict(settings.sim_config())
    base_sim = asdict(DEFAULT_SETTINGS.sim_config())
    diff = {k: v for k, v in ctrl.items() if k != "mode" and v != base_ctrl[k]}
    diff.update({k: v for k, v in sim.items() if v != base_sim[k]})
    out = {"profile": settings.profile, "differs": dict(sorted(diff.items()))}
    if settings.perturbation is not None and not settings.perturbation.is_zero:
        out["perturbation"] = settings.perturbation.changed()
    if settings.robot:                  # (absent: the default robot)
        out["robot"] = settings.robot
    return out


def print_settings(settings: RunSettings) -> None:
    """One line: the profile and the settings that differ from the configuration files; one more for a
    plant perturbation."""
    d = differences(settings)
    diff = d["differs"]
    print((f"robot {d['robot']}; " if "robot" in d else "") + f"profile {d['profile']}; settings differing from config/: "
          + (", ".join(f"{k}={v}" for k, v in diff.items()) if diff else "none"))
    if settings.perturbation is not None and not settings.perturbation.is_zero:
        print("plant perturbation: " + settings.perturbation.label())
