"""The capability map's specification: cells (mode, direction, onset phase, duration), the force search
of a cell, the whole map, and their defaults. Units: forces [N], durations [s], impulses [N s], phases
as fractions of the first step."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from biped_model.settings import default_config_dir, read_settings

from biped_controller.core.control.config import MODES, PAPER_MODES
from biped_controller.studies.trial.search import coarse_forces
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings

#: direction name -> sign of the force (+ forward: on the back)
DIRECTIONS: dict[str, float] = {"forward": 1.0, "backward": -1.0}
DEFAULT_PHASES = 20
DEFAULT_DURATIONS: tuple[float, ...] = (0.025, 0.1, 0.2)
DEFAULT_RESOLUTION = 5.0      # bisection resolution [N] (experiment's max-push default)
DEFAULT_COARSE = 50.0         # coarse scan step [N] (experiment's max-push default)
DEFAULT_MAX = 2000.0          # largest force scanned [N] (experiment's max-push default)
DEFAULT_MAX_IMPULSE = 50.0    # largest impulse scanned [N s]: 2000 N x 0.025 s, the same range for every duration


class MapError(ValueError):
    """The map's specification, its store or its executor is unusable (the message says what)."""



@dataclass(frozen=True, order=True)
class Cell:
    """One boundary to find: adaptation mode, push direction, onset phase (fraction of the first step),
    push duration [s]."""

    mode: str
    direction: str
    phase: float
    duration: float


@dataclass(frozen=True)
class SimSpec:
    """One simulation: a cell and a force magnitude [N] (>= 0; the direction gives the sign)."""

    cell: Cell
    force: float

    def key(self) -> tuple:
        c = self.cell
        return (c.mode, c.direction, c.phase, c.duration, self.force)


@dataclass(frozen=True)
class Search:
    """The force search of a cell: coarse step and largest force [N], bisection resolution [N]; and the
    largest impulse scanned [N s] (inf: no bound), which lowers the largest force of long pushes to
    ``max_impulse / duration`` (never below one coarse step): :meth:`for_duration`."""

    coarse: float = DEFAULT_COARSE
    fmax: float = DEFAULT_MAX
    resolution: float = DEFAULT_RESOLUTION
    max_impulse: float = DEFAULT_MAX_IMPULSE

    def __post_init__(self):
        for name in ("coarse", "fmax", "resolution"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise MapError(f"{name} must be a finite number > 0 [N], got {v!r}")
        if self.fmax < self.coarse:
            raise MapError(f"max ({self.fmax} N) must be >= the coarse step ({self.coarse} N)")
        if not (isinstance(self.max_impulse, (int, float)) and self.max_impulse > 0):
            raise MapError(f"max_impulse must be > 0 [N s] (inf: no bound), got {self.max_impulse!r}")

    def coarse_forces(self) -> tuple[float, ...]:
        return tuple(coarse_forces(self.fmax, self.coarse))

    def for_duration(self, duration: float) -> "Search":
        """The search of a push of ``duration`` [s]: largest force min(max, max_impulse / duration), at
        least one coarse step. Its coarse forces are a prefix of the unbounded ones, so records serve
        searches of any bound."""
        fmax = max(self.coarse, min(self.fmax, self.max_impulse / duration))
        return Search(self.coarse, fmax, self.resolution)


@dataclass(frozen=True)
class MapSpec:
    """A whole map: the cells are the product modes x directions x phases x durations."""

    modes: tuple[str, ...] = PAPER_MODES
    directions: tuple[str, ...] = tuple(DIRECTIONS)
    phases: tuple[float, ...] = tuple(k / DEFAULT_PHASES for k in range(DEFAULT_PHASES))
    durations: tuple[float, ...] = DEFAULT_DURATIONS
    search: Search = field(default_factory=Search)
    height: float | None = None          # push point above the hip [m]; None: push_height of the config
    settings: RunSettings = DEFAULT_SETTINGS
    neighbours: bool | None = None       # bracket each cell from its lower-phase neighbour; None: config/studies.yaml
    island_window: int | None = None     # coarse steps scanned above a bracketed edge; None: config/studies.yaml
    bracket_check_below: int | None = None   # coarse steps a bracket checks under itself; None: config/studies.yaml

    def __post_init__(self):
        if self.neighbours is None or self.island_window is None or self.bracket_check_below is None:
            cfg = search_settings()
            for name, key in (("neighbours", "search_from_neighbours"), ("island_window", "island_window"),
                              ("bracket_check_below", "bracket_check_below")):
                if getattr(self, name) is None:
                    object.__setattr__(self, name, cfg[key])
        if not isinstance(self.neighbours, bool):
            raise MapError(f"neighbours must be true or false, got {self.neighbours!r}")
        if isinstance(self.island_window, bool) or not (isinstance(self.island_window, int) and self.island_window >= 0):
            raise MapError(f"island_window must be an integer >= 0 [coarse steps], got {self.island_window!r}")
        b = self.bracket_check_below
        if isinstance(b, bool) or not (isinstance(b, int) and b >= 1):
            raise MapError(f"bracket_check_below must be an integer >= 1 [coarse steps], got {b!r}")
        def nonempty_unique(name, seq):
            if not seq:
                raise MapError(f"{name}: at least one is needed")
            if len(set(seq)) != len(seq):
                raise MapError(f"{name}: repeated values in {list(seq)}")
        for name in ("modes", "directions", "phases", "durations"):
            nonempty_unique(name, getattr(self, name))
        for m in self.modes:
            _check_controller(m)
        for d in self.directions:
            if d not in DIRECTIONS:
                raise MapError(f"directions: unknown direction {d!r}; choose from {', '.join(DIRECTIONS)}")
        for ph in self.phases:
            if not (isinstance(ph, float) and 0.0 <= ph < 1.0):
                raise MapError(f"phases: each must be a float in [0, 1) (a fraction of the step), got {ph!r}")
        for d in self.durations:
            if not (isinstance(d, float) and math.isfinite(d) and d > 0):
                raise MapError(f"durations: each must be a float > 0 [s], got {d!r}")
        if self.height is not None and not (math.isfinite(self.height) and self.height >= 0):
            raise MapError(f"height must be >= 0 [m] above the hip, got {self.height!r}")

    def cells(self) -> list[Cell]:
        return [Cell(m, d, ph, du) for m in self.modes for d in self.directions for ph in self.phases
                for du in self.durations]


def search_settings(path=None) -> dict:
    """``search_from_neighbours``, ``island_window`` and ``bracket_check_below`` of ``config/studies.yaml``
    (a bad value raises :class:`MapError` naming the key)."""
    p = Path(path) if path is not None else default_config_dir() / "studies.yaml"
    v = read_settings(p, ("search_from_neighbours", "island_window", "bracket_check_below"))
    if not isinstance(v["search_from_neighbours"], bool):
        raise MapError(f"{p}: 'search_from_neighbours' must be true or false, got {v['search_from_neighbours']!r}")
    for key, least in (("island_window", 0), ("bracket_check_below", 1)):
        w = v[key]
        if isinstance(w, bool) or not (isinstance(w, int) and w >= least):
            raise MapError(f"{p}: '{key}' must be an integer >= {least}, got {w!r}")
    return v


def phases_of(n: int) -> tuple[float, ...]:
    """``n`` onset phases k / n, k = 0 .. n - 1 (fractions of the step)."""
    if not (isinstance(n, int) and n >= 1):
        raise MapError(f"--phases must be an integer >= 1, got {n!r}")
    return tuple(k / n for k in range(n))


def onset_time(phase: float, T: float) -> float:
    """Push start [s] for an onset ``phase`` of the first step of period ``T`` [s]: ``phase * T``."""
    return phase * T



def _check_controller(name: str) -> None:
    """A map's "mode" names a controller the studies can run: a built-in mode or a registered controller
    (``trial.controller.resolve``: an entry point or ``module:Class`` satisfying the interface); MapError
    otherwise."""
    from biped_controller.studies.trial.controller import RESOLVE_ERRORS, resolve
    try:
        resolve(name)
    except RESOLVE_ERRORS as exc:
        raise MapError(f"modes: {name!r} is neither a mode ({', '.join(MODES)}) nor a usable controller: {exc}") from None
