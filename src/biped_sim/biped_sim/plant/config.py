"""The plant's settings (``config/simulator.yaml``): :class:`SimConfig` and its one reader.

Pure Python, no ROS, no Pinocchio: the disturbance node reads the default push height here without
loading a simulator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from biped_sim.robot.loop import LoopSettings, LoopSettingsError
from biped_sim.robot.settings import SettingsError, default_config_dir, read_settings


class SimConfigError(ValueError):
    """A simulator setting is missing or out of range (message names it)."""


@dataclass(frozen=True)
class SimConfig:
    """Simulator settings; the values (and the reason for each) live in ``config/simulator.yaml`` only:
    build one with :func:`load_sim_config` (no defaults here, so nothing repeats the file)."""

    control_period: float            # [s] zero-order-hold period of the joint torques
    substeps: int                    # RK4 steps per control period
    touchdown_tolerance: float       # [m] a sole point below this height touches the ground
    clearance_before_touchdown: float  # [m] swing foot rise needed before a contact counts as touchdown
    liftoff_penetration: float       # [m] a released foot sinking deeper than this is a fall
    event_time_tolerance: float      # [s] touchdown time bisection precision
    push_height: float               # [m] default push point above the hip on the torso
    engine: str                      # "fast": compiled kernels (fast_engine); "reference": Pinocchio

    def validate(self) -> "SimConfig":
        try:
            LoopSettings(self.control_period, self.engine).validate()
        except LoopSettingsError as exc:
            raise SimConfigError(str(exc)) from exc
        if not (isinstance(self.substeps, int) and 1 <= self.substeps <= 1000):
            raise SimConfigError(f"substeps must be an integer in [1, 1000], got {self.substeps}")
        for name in ("touchdown_tolerance", "clearance_before_touchdown", "liftoff_penetration", "event_time_tolerance"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise SimConfigError(f"{name} must be finite and > 0, got {v}")
        if not math.isfinite(self.push_height):
            raise SimConfigError("push_height must be finite")
        return self


def load_sim_config(path: str | Path | None = None, **overrides) -> SimConfig:
    """``config/simulator.yaml`` (or ``path``) with ``overrides`` applied, validated."""
    p = Path(path) if path is not None else default_config_dir() / "simulator.yaml"
    try:
        kw = read_settings(p, SimConfig.__dataclass_fields__)
    except SettingsError as exc:
        raise SimConfigError(str(exc)) from exc
    kw.update(overrides)
    for k, v in kw.items():
        if k == "engine":
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise SimConfigError(f"{k} must be a finite number, got {v!r} ({p})")
    if float(kw["substeps"]) != int(kw["substeps"]):
        raise SimConfigError(f"substeps must be an integer, got {kw['substeps']!r} ({p})")
    kw["substeps"] = int(kw["substeps"])
    return SimConfig(**kw).validate()
