"""Where controllers are found by name: the built-in modes, the ``biped.controllers`` entry points of the
installed distributions, and ``module:Class`` strings.

A package registers a controller in its ``pyproject.toml``::

    [project.entry-points."biped.controllers"]
    my_controller = "my_package.controller:MyController"

or a catalog of controllers found at run time (group ``biped.controller_catalogs``: a function returning
``[(name, "module:attribute"), ...]``; the product's own lists the committed policies, ``policy.catalog``).

:func:`load_controller` resolves a name (a built-in mode first, then an entry point, then a
``module:Class`` string), imports the class and checks it against the interface
(``interface.check_controller_class``); :func:`make_controller` builds it from a setup, wrapped in
``interface.GuardedController``. An unknown name raises :class:`UnknownControllerError` listing the
known ones; a name whose module or class cannot be imported raises :class:`ControllerLoadError`.
"""
from __future__ import annotations

import importlib
import importlib.metadata as md
import inspect
from dataclasses import dataclass

from biped_controller.plugin.builtin import BUILTIN
from biped_controller.plugin.interface import ControllerSetup, GuardedController, check_controller_class

ENTRY_POINT_GROUP = "biped.controllers"
#: entry points of functions that list controllers found at run time (``_catalog_entries``)
CATALOG_GROUP = "biped.controller_catalogs"


class UnknownControllerError(LookupError):
    """No controller of that name (the message lists the registered names)."""


class ControllerLoadError(ImportError):
    """A registered controller's module or class cannot be imported (the message names the entry)."""


@dataclass(frozen=True)
class Registration:
    """One registered controller: ``name``, ``target`` (``module:Class``), ``source`` (``builtin`` or the
    distribution that declares the entry point)."""

    name: str
    target: str
    source: str


def _entry_points() -> list[Registration]:
    out = []
    for ep in md.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep, "dist", None)
        out.append(Registration(ep.name, ep.value, dist.name if dist is not None else "entry point"))
    return out + _catalog_entries()


def _catalog_entries() -> list[Registration]:
    """The controllers of the installed catalogs (entry-point group :data:`CATALOG_GROUP`): each entry point
    names a function returning ``[(name, "module:attribute"), ...]``, the controllers it offers now (e.g. the
    committed policies under ``policies/``). A catalog that fails is left out of the listing (its error is
    the name's: loading it by ``module:attribute`` raises)."""
    out = []
    for ep in md.entry_points(group=CATALOG_GROUP):
        dist = getattr(ep, "dist", None)
        try:
            pairs = ep.load()()
        except Exception:            # a broken catalog must not hide every other controller
            continue
        src = f"{dist.name if dist is not None else 'entry point'} catalog {ep.name}"
        out.extend(Registration(str(n), str(t), src) for n, t in pairs)
    return out


def registered() -> list[Registration]:
    """Every registered controller: the built-in modes, then the entry points sorted by name (an entry
    point with a built-in's name is listed, but the built-in wins in :func:`load_controller`)."""
    builtin = [Registration(n, t, "builtin") for n, t in BUILTIN.items()]
    return builtin + sorted(_entry_points(), key=lambda r: (r.name, r.source))


def _import_target(target: str, what: str) -> object:
    module, sep, attr = target.partition(":")
    if not sep or not module or not attr:
        raise ControllerLoadError(f"{what}: {target!r} is not of the form 'module:Class'")
    try:
        obj = importlib.import_module(module)
    except ImportError as exc:
        raise ControllerLoadError(f"{what}: cannot import module {module!r}: {exc}") from exc
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ControllerLoadError(f"{what}: module {module!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    return obj


def load_controller(name: str) -> type:
    """The controller class registered as ``name`` (built-in mode, entry point, or ``module:Class``),
    checked against the interface. Raises :class:`UnknownControllerError` (the message lists the known
    names), :class:`ControllerLoadError`, or ``interface.InterfaceError`` naming the class."""
    if not isinstance(name, str) or not name:
        raise UnknownControllerError(f"a controller name must be a non-empty string, got {name!r}")
    if name in BUILTIN:
        return check_controller_class(_import_target(BUILTIN[name], f"built-in controller {name!r}"))
    eps = [r for r in _entry_points() if r.name == name]
    if len(eps) > 1:
        raise ControllerLoadError(f"controller {name!r} is registered by more than one distribution: "
                                  + ", ".join(f"{r.source} ({r.target})" for r in eps))
    if eps:
        return check_controller_class(_import_target(eps[0].target, f"controller {name!r} ({eps[0].source})"))
    if ":" in name:
        return check_controller_class(_import_target(name, f"controller {name!r}"))
    known = ", ".join(r.name for r in registered())
    raise UnknownControllerError(f"unknown controller {name!r}; registered: {known} "
                                 f"(or give 'module:Class'; entry-point group {ENTRY_POINT_GROUP!r})")


def load_registration(r: Registration) -> type:
    """The class of one :func:`registered` entry, checked against the interface."""
    return check_controller_class(_import_target(r.target, f"controller {r.name!r} ({r.source})"))


def make_controller(name: str, setup: ControllerSetup) -> GuardedController:
    """The controller ``name`` built from ``setup``, its results checked (``GuardedController``)."""
    return GuardedController(load_controller(name)(setup), name)


def summary(cls: type) -> str:
    """One line about a controller class: its ``description`` attribute, else its docstring's first line."""
    text = getattr(cls, "description", "") or (inspect.getdoc(cls) or "").strip().split("\n")[0]
    return text or "(no description)"
