"""What every run needs that is loaded once per process: robot description, gait family, simulator settings."""
from __future__ import annotations

import functools
from dataclasses import dataclass

from biped_sim.plant.config import SimConfig, load_sim_config
from biped_model.description import RobotDescription, load_description
from biped_model.gait_family import GaitFamily


@dataclass(frozen=True)
class Context:
    """Everything a run needs that can be loaded once per process."""

    desc: RobotDescription
    family: GaitFamily
    sim_config: SimConfig


@functools.lru_cache(maxsize=1)
def context() -> Context:
    """This process's :class:`Context` (config/ files read once)."""
    return Context(load_description(), GaitFamily.load(), load_sim_config())

