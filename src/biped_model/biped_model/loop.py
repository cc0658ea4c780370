"""The closed loop's timing and numerical engine, which the plant and the controller share.

Pure Python, no ROS. Their one home is ``config/simulator.yaml`` (``control_period``, ``engine``): the
plant's :class:`~biped_sim.plant.rigid.SimConfig` holds them with the plant's other settings, and the
controller reads them here, so the controller side never imports the plant to learn its period.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from biped_model.finite import finite_number
from biped_model.settings import SettingsError, default_config_dir, read_settings

ENGINES = ("fast", "reference")   # "fast": compiled kernels (fast_engine); "reference": Pinocchio


class LoopSettingsError(ValueError):
    """The control period or the engine is missing or out of range (message names it)."""


@dataclass(frozen=True)
class LoopSettings:
    control_period: float   # [s] zero-order-hold period of the joint torques, one decision each
    engine: str             # one of ENGINES

    def validate(self) -> "LoopSettings":
        if self.engine not in ENGINES:
            raise LoopSettingsError(f"engine must be one of {ENGINES}, got {self.engine!r}")
        finite_number(self.control_period, "control_period", above=0, at_most=0.05, error=LoopSettingsError,
                      message=f"control_period must be in (0, 0.05] s, got {self.control_period}")
        return self


def load_loop_settings(path: str | Path | None = None) -> LoopSettings:
    """``control_period`` and ``engine`` of ``config/simulator.yaml`` (or ``path``), validated."""
    p = Path(path) if path is not None else default_config_dir() / "simulator.yaml"
    try:
        kw = read_settings(p, ("control_period", "engine"))
    except SettingsError as exc:
        raise LoopSettingsError(str(exc)) from exc
    period = kw["control_period"]
    if isinstance(period, bool) or not isinstance(period, (int, float)):
        raise LoopSettingsError(f"control_period must be a finite number, got {period!r} ({p})")
    return LoopSettings(float(period), kw["engine"]).validate()
