"""The plant seen from outside: what the graph, the studies and the tests may ask of any engine.

Pure Python, no ROS. Every engine (the rigid one, :class:`biped_sim.plant.rigid.Simulator`, the reference; MuJoCo,
:class:`biped_sim.plant.mujoco.MujocoPlant`) satisfies :class:`Plant`, and callers build one with :func:`make_plant` from a name, so a
second engine is one entry of :data:`PLANTS` and nothing else changes for its users.

Conventions (DESIGN.md): paper coordinates (q, q') of the current stance for what the controller
measures; the floating state x = [x_hip, z_hip, theta, lh, lk, la, rh, rk, ra], v = dx/dt [m, rad, m/s,
rad/s] for the truth; times in seconds of simulated time; torques [N m] in paper order for the stance.
"""
from __future__ import annotations

from typing import Callable, Protocol, runtime_checkable

import numpy as np

from biped_sim.plant.config import PLANT_NAMES, SimConfig
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.push import Push
from biped_sim.plant.records import FallInfo, ImpactRecord, Observation, StepRecord
from biped_model.description import RobotDescription

PLANTS = PLANT_NAMES   # ("rigid", "mujoco")


class PlantError(ValueError):
    """An unknown plant name (message names it and the choices)."""


@runtime_checkable
class Plant(Protocol):
    """One simulated robot and its world.

    * :meth:`reset` starts from paper (q, q') with the stance foot flat at (ankle_x, 0);
    * :meth:`schedule_push` books a horizontal push on the torso (raises ``push.Rejected`` naming the field,
      the plant unchanged);
    * :meth:`observe` is what the sensors report at the start of the coming period;
    * :meth:`step` holds the paper-order torque over one control period (or evaluates a torque function)
      and returns the period's :class:`StepRecord` (true state at its start, wrench, push, impacts);
    * ``impact_log`` every touchdown so far, ``fall`` the fall that ended the run (None while walking).
    """

    desc: RobotDescription          # the simulated (true) robot
    nominal_desc: RobotDescription  # the robot as given (what a controller's model knows)
    cfg: SimConfig
    t: float                        # [s] simulated time at the start of the coming period
    step_index: int                 # periods simulated since reset
    stance: int                     # LEFT / RIGHT: the foot on the ground
    x: np.ndarray                   # floating state, true
    v: np.ndarray
    anchor: np.ndarray              # (x, z, pitch) of the stance foot's ankle on the ground
    fall: FallInfo | None
    impact_count: int
    impact_log: list[ImpactRecord]

    def reset(self, q: np.ndarray, qd: np.ndarray, stance: int = ..., ankle_x: float = ...) -> None: ...

    @property
    def pushes(self) -> list[Push]: ...

    def schedule_push(self, start: float, duration: float, force: float, height: float | None = None,
                      push_id: int | None = None) -> Push: ...

    def interval_pushes(self, t0: float, t1: float) -> tuple[tuple[float, float], ...]: ...

    def observe(self) -> Observation: ...

    def step(self, torque: np.ndarray | Callable[[float, np.ndarray, np.ndarray, int], np.ndarray]) -> StepRecord: ...


def make_plant(name: str, desc: RobotDescription | None = None, config: SimConfig | None = None,
               perturbation: PlantPerturbation | None = None) -> Plant:
    """The plant called ``name`` (one of :data:`PLANTS`) for the robot ``desc`` (None: robots/biped7/description.yaml)."""
    if name == "rigid":
        from biped_sim.plant.rigid import Simulator
        return Simulator(desc, config, perturbation)
    if name == "mujoco":
        from biped_sim.plant.mujoco import MujocoPlant     # imports mujoco only when chosen
        return MujocoPlant(desc, config, perturbation)
    raise PlantError(f"plant must be one of {PLANTS}, got {name!r}")
