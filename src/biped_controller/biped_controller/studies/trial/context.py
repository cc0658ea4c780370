"""What every run needs that is loaded once per process and robot: robot description, gait family,
simulator settings.

The robot travels with the run's settings (``RunSettings.robot``, a name under ``robots/`` or a path; ""
the default robot): every task function a pool runs calls ``settings.activate()`` (:func:`select_robot`)
before it touches :func:`context`, so a worker process uses the robot of the settings it was given, never
one set in the parent only."""
from __future__ import annotations

import functools
from dataclasses import dataclass

from biped_sim.plant.config import SimConfig, load_sim_config
from biped_model.description import RobotDescription
from biped_model.gait_family import GaitFamily
from biped_model.robot import Robot, resolve_robot


@dataclass(frozen=True)
class Context:
    """Everything a run needs that can be loaded once per process (for one robot)."""

    desc: RobotDescription
    family: GaitFamily
    sim_config: SimConfig
    robot: Robot
    robot_hash: str


_selected: list[str] = [""]


def select_robot(robot: str | None) -> None:
    """Make ``robot`` (name or path; "" or None: the default robot) the one :func:`context` returns in this
    process (called from the run's settings in each process that runs a trial)."""
    _selected[0] = "" if robot is None else str(robot)


def selected_robot() -> str:
    """The robot :func:`context` returns in this process ("" = the default robot)."""
    return _selected[0]


def context(robot: str | None = None) -> Context:
    """The :class:`Context` of ``robot`` (None: this process's selected robot, :func:`select_robot`); its
    files read once per process (its family checked against its description's stamp)."""
    return _context(selected_robot() if robot is None else str(robot))


@functools.lru_cache(maxsize=4)
def _context(robot: str) -> Context:
    r = resolve_robot(robot)
    return Context(r.description(), r.family(), load_sim_config(), r, r.description_hash())


def robot_in_process(settings) -> dict:
    """The robot a process runs a trial of ``settings`` (a ``RunSettings``) on, as a pool's task sees it:
    ``settings.activate()`` then :func:`context`. JSON-ready: ``robot`` (the directory's name), ``directory``,
    ``robot_hash`` (its description's sha256), ``mass`` [kg] and ``pid``."""
    import os
    settings.activate()
    ctx = context()
    return {"robot": ctx.robot.name, "directory": str(ctx.robot.directory), "robot_hash": ctx.robot_hash,
            "mass": ctx.desc.total_mass, "pid": os.getpid()}


def force_scale(robot: str | None = None) -> float:
    """How the push searches' force ranges scale for ``robot`` (None: this process's selected robot): the
    ratio of its M sqrt(g L) to the default robot's (M the total mass [kg], L the leg length [m]: a push of
    the same dimensionless impulse F dt / (M sqrt(g L)) and duration). Exactly 1.0 for a robot with the
    default robot's description, so its search ranges are the committed ones bit for bit."""
    import math
    ctx, base = context(robot), context("")
    if ctx.robot_hash == base.robot_hash:
        return 1.0
    d, b = ctx.desc, base.desc
    return (d.total_mass * math.sqrt(d.gravity * d.leg_length)) / (b.total_mass * math.sqrt(b.gravity * b.leg_length))


def scaled_force(value: float, robot: str | None = None) -> float:
    """``value`` [N or N s] of a default search range for ``robot`` (:func:`force_scale`; rounded to 1e-3:
    unchanged for the default robot)."""
    k = force_scale(robot)
    return value if k == 1.0 else round(value * k, 3)
