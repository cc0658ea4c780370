"""What every section of ``scripts/bench`` (``benchmarks.run``) shares: the run's profile and the controller and
simulator settings built over it, the hard run's push, the solvers' match tolerance, the targets (printed,
never asserted), the log line and the percentile summary of per-call times [us]."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: The run's named profile (``--profile``), as the studies' settings: its controller and simulator settings
#: apply to every controller and plant the bench builds (sections 0, 1, 2 and 4); the bench's own variants (the
#: engine, ``plant: mujoco`` for the MuJoCo rows) are set over it. None until ``benchmarks.run.main`` parses it.
SETTINGS = None


def robot_files():
    """(RobotDescription, GaitFamily) of the bench's robot (``--robot``: ``SETTINGS.robot``; the default robot
    without it), as the studies load it (``trial.context.context``)."""
    from biped_controller.studies.trial.context import context
    ctx = context(SETTINGS.robot if SETTINGS is not None else "")
    return ctx.desc, ctx.family


def ctrl_cfg(mode: str, **kw):
    """``load_controller_config`` with the profile's controller settings, then ``kw``."""
    from biped_controller.core.control.config import load_controller_config
    base = dict(SETTINGS.controller) if SETTINGS is not None else {}
    return load_controller_config(**{**base, "mode": mode, **kw})


def sim_cfg(**kw):
    """``load_sim_config`` with the profile's simulator settings (its ``plant`` too, unless ``kw`` names one)."""
    from biped_sim.plant.config import load_sim_config
    base = dict(SETTINGS.simulator) if SETTINGS is not None else {}
    return load_sim_config(**{**base, **kw})


PUSH_START, PUSH_DURATION = 0.2315, 0.025
MATCH_TOL = 1e-6
TARGETS = {
    "controller_step_p50_us": 30.0,
    "production_qp_vs_fastest_ratio": 1.5,
    "lockstep_vs_pingpong_fraction": 0.90,
    "lockstep_rate_hz": 1000.0,
    "inprocess_realtime_factor": 50.0,
    "max_push_table_s": 30.0,
    "sweep_map_full_wall_s": 60.0,
}


def log(msg: str) -> None:
    print(f"bench: {msg}", file=sys.stderr, flush=True)


def pct(a) -> dict:
    a = np.asarray(a, dtype=float)
    if a.size == 0:
        return {"n": 0, "p50": None, "p99": None, "mean": None}
    return {"n": int(a.size), "p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
            "mean": float(a.mean())}
