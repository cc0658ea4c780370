"""Command-line pieces every study's CLI shares: the settings flags (``--profile``, ``--set``,
``--observer``, ``--perturb``, ``--full-trials``), the parser whose errors are one line with exit status
2, and argparse type functions that check a value where it is read (the message names the value; argparse
adds the option's name)."""
from __future__ import annotations

import argparse
import math
import sys

from biped_sim.plant.config import SimConfigError
from biped_sim.plant.perturbation import PerturbationError
from biped_model.profiles import DEFAULT_PROFILE, ProfileError, profile_names
from biped_model.robot import RobotError
from biped_model.settings import DEFAULT_ROBOT, SettingsError

from biped_controller.core.control.config import MODES, ControllerConfigError
from biped_controller.studies.trial.settings import OverrideError, RunSettings, run_settings
from biped_controller.studies.trial.stop import StudySettingsError
from biped_controller.studies.trial.survival import survival_rule

__all__ = ["StudyArgumentParser", "add_settings_args", "add_robot_arg", "settings_from_args", "SETTINGS_ERRORS", "finite_float",
           "positive_float", "nonnegative_float", "positive_int", "nonnegative_int", "profile_arg", "modes_arg",
           "add_modes_arg", "controller_arg"]

#: the errors a bad settings flag raises (each names the key or the profile)
SETTINGS_ERRORS = (OverrideError, ProfileError, ControllerConfigError, SimConfigError, PerturbationError, SettingsError,
                   StudySettingsError, RobotError)


class StudyArgumentParser(argparse.ArgumentParser):
    """An ArgumentParser whose error is one line on stderr (``prog: error: message``) and exit status 2."""

    def error(self, message: str):
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        sys.exit(2)


def finite_float(text: str) -> float:
    """A finite number (no nan, no inf)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def positive_float(text: str) -> float:
    """A finite number > 0."""
    v = finite_float(text)
    if not v > 0.0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return v


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    v = finite_float(text)
    if v < 0.0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def positive_int(text: str) -> int:
    """An integer >= 1."""
    v = _int(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return v


def nonnegative_int(text: str) -> int:
    """An integer >= 0."""
    v = _int(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v


def profile_arg(text: str) -> str:
    """The name of a profile of ``config/profiles/``."""
    known = profile_names()
    if text not in known:
        raise argparse.ArgumentTypeError(f"unknown profile {text!r}; known profiles: {', '.join(known)}")
    return text


def modes_arg(text: str) -> tuple[str, ...]:
    """``--modes none,wbc,...``: known modes, each once, at least one."""
    modes = tuple(m.strip() for m in text.split(",") if m.strip())
    bad = [m for m in modes if m not in MODES]
    if not modes or bad or len(set(modes)) != len(modes):
        raise argparse.ArgumentTypeError(f"expected distinct modes out of {','.join(MODES)}, got {text!r}")
    return modes


class _ModesAction(argparse.Action):
    """``--modes`` of :func:`add_modes_arg`: the words given (each a comma-separated list, :func:`modes_arg`)
    joined into one tuple; a mode named twice is the option's error."""

    def __call__(self, parser, namespace, values, option_string=None):
        modes = tuple(m for v in values for m in v)
        twice = sorted({m for m in modes if modes.count(m) > 1})
        if twice:
            parser.error(f"argument {option_string}: {', '.join(twice)} given more than once in {' '.join(','.join(v) for v in values)!r}")
        setattr(namespace, self.dest, modes)


def add_modes_arg(a: argparse.ArgumentParser, default: tuple[str, ...] | None, default_text: str,
                  controller: bool = True) -> None:
    """``--modes``, one syntax for every study: the built-in modes comma-separated (``--modes both,tau``, the
    documented form); several words are accepted too and joined (``--modes both tau``, ``--modes both,tau p``:
    the form of earlier command lines, kept so that every recorded command still runs). Each mode known,
    each once; the value is a tuple of mode names (``default`` when the option is not given). ``controller``:
    the command also takes ``--controller`` (the help points there for other controllers)."""
    a.add_argument("--modes", nargs="+", type=modes_arg, action=_ModesAction, default=default, metavar="MODES",
                   help=f"built-in modes, comma-separated (e.g. both,tau; any of {','.join(MODES)}); default "
                        f"{default_text}" + ("; other controllers: --controller" if controller else ""))


def controller_arg(text: str) -> str:
    """``--controller NAME``: a built-in mode, a ``biped.controllers`` entry point or ``module:Class``
    satisfying the controller interface, checked by the studies' one resolution step
    (``trial.controller.resolve``; resolved again by name in each worker process)."""
    from biped_controller.studies.trial.controller import RESOLVE_ERRORS, resolve
    from biped_controller.plugin.registry import load_controller
    try:
        resolve(text)
        required = tuple(getattr(load_controller(text), "required_options", ()) or ())
    except RESOLVE_ERRORS as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if required:                # a controller that cannot be built without options the studies do not pass
        raise argparse.ArgumentTypeError(
            f"controller {text!r} needs the option(s) {', '.join(required)}, which this command does not pass "
            f"(a committed policy is a controller by its name: docs/policies.md)")
    return text


def add_settings_args(a: argparse.ArgumentParser, *, observer: bool = True, perturb: bool = True,
                      full_trials: bool = True) -> None:
    """The settings flags: ``--robot``, ``--profile``, ``--set`` and, unless switched off, ``--observer``,
    ``--perturb`` and ``--full-trials`` (read them back with :func:`settings_from_args`)."""
    add_robot_arg(a)
    a.add_argument("--profile", type=profile_arg, default=DEFAULT_PROFILE,
                   help=f"named settings of config/profiles/ (one of {', '.join(profile_names())}; default "
                        f"{DEFAULT_PROFILE}); --set and --observer override it")
    if observer:
        a.add_argument("--observer", choices=("on", "off"), default=None,
                       help="the controller's disturbance observer (default: the profile's, else "
                            "config/controller.yaml); off = the paper's controller as published")
    a.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of config/controller.yaml or config/simulator.yaml (repeatable)")
    if full_trials:
        a.add_argument("--full-trials", action="store_true",
                       help="run every survival trial in full (no early stop: config/studies.yaml early_stop)")
    if perturb:
        a.add_argument("--perturb", dest="perturb", action="append", default=[], metavar="FIELD=VALUE",
                       help="a field of the plant's PlantPerturbation, e.g. torso_mass_scale=0.8, noise_q=5e-4, "
                            "encoder_bits=14, delay=2 (repeatable; biped_sim.plant.perturbation)")


def add_robot_arg(a: argparse.ArgumentParser) -> None:
    """``--robot NAME|PATH``: a robot under ``robots/`` by name, or a robot directory by path (default the
    default robot, ``robots/biped7``); checked in :func:`settings_from_args` (its description and its
    family's stamp: a bad one is one line naming the file, exit status 2)."""
    a.add_argument("--robot", default=None, metavar="NAME|PATH",
                   help=f"the robot: a directory name under robots/ or a path to a robot directory (default "
                        f"{DEFAULT_ROBOT}; docs/robots.md)")


def settings_from_args(ap: argparse.ArgumentParser, args: argparse.Namespace) -> RunSettings:
    """The :class:`RunSettings` of the flags of :func:`add_settings_args`; a bad one is ``ap.error`` (exit
    status 2) with the message naming the key or the profile; the survival rule's settings
    (``config/studies.yaml``) are checked here too."""
    try:
        survival_rule()
        return run_settings(getattr(args, "profile", None), getattr(args, "overrides", ()),
                            getattr(args, "observer", None), getattr(args, "perturb", ()),
                            getattr(args, "full_trials", False), getattr(args, "robot", None))
    except SETTINGS_ERRORS as exc:
        ap.error(str(exc))
