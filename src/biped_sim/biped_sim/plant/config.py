"""The plant's settings (``config/simulator.yaml``): :class:`SimConfig` and its one reader.

Pure Python, no ROS, no Pinocchio: the disturbance node reads the default push height here without
loading a simulator.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from biped_model.finite import finite_number
from biped_model.loop import LoopSettings, LoopSettingsError
from biped_model.settings import SettingsError, default_config_dir, read_settings


#: the engines a plant can be built on (``protocol.make_plant``): the rigid reference and MuJoCo
PLANT_NAMES = ("rigid", "mujoco")
#: MuJoCo's integrators and friction cones this project accepts (``mjOption`` names)
MUJOCO_INTEGRATORS = ("implicitfast", "implicit", "Euler", "RK4")
MUJOCO_CONES = ("elliptic", "pyramidal")
#: the string-valued settings (every other one is a finite number)
STRING_KEYS = ("engine", "plant", "mujoco_integrator", "mujoco_cone")


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
    plant: str                       # "rigid" (the reference) or "mujoco" (biped_sim.plant.mujoco)
    # --- MuJoCo plant only (see config/simulator.yaml for each reason)
    mujoco_timestep: float           # [s] MuJoCo step (a divisor of control_period)
    mujoco_integrator: str           # mjOption integrator
    mujoco_cone: str                 # friction cone
    mujoco_solver_tolerance: float   # Newton solver tolerance
    mujoco_solref_timeconst: float   # [s] contact time constant
    mujoco_solref_dampratio: float   # contact damping ratio
    mujoco_solimp_dmin: float        # impedance at zero penetration, in (0, 1)
    mujoco_solimp_dmax: float        # impedance at full width, in [dmin, 1)
    mujoco_solimp_width: float       # [m] width of the impedance transition
    mujoco_foot_thickness: float     # [m] collision box of a foot, sole on the ankle line
    mujoco_foot_width: float         # [m]
    mujoco_sole_points: int          # 0: each sole a box (contacts at its corners); n >= 2: n contact spheres heel to toe
    mujoco_body_radius: float        # [m] fall-detection capsules on torso, thighs, shins
    mujoco_shin_capsule_gap: float   # [m] the shin capsule ends this far above the ankle
    mujoco_touch_threshold: float    # [N] a foot is loaded above this normal force
    mujoco_swing_debounce: float     # [s] unloaded this long before a load is a touchdown
    mujoco_fall_hip_height: float    # [m] hip below: fall
    mujoco_fall_foot_tilt: float     # [rad] stance foot pitch beyond: fall

    def validate(self) -> "SimConfig":
        try:
            LoopSettings(self.control_period, self.engine).validate()
        except LoopSettingsError as exc:
            raise SimConfigError(str(exc)) from exc
        if not (isinstance(self.substeps, int) and 1 <= self.substeps <= 1000):
            raise SimConfigError(f"substeps must be an integer in [1, 1000], got {self.substeps}")
        for name in ("touchdown_tolerance", "clearance_before_touchdown", "liftoff_penetration", "event_time_tolerance"):
            v = getattr(self, name)
            finite_number(v, name, above=0, error=SimConfigError, message=f"{name} must be finite and > 0, got {v}")
        finite_number(self.push_height, "push_height", error=SimConfigError, message="push_height must be finite")
        if self.plant not in PLANT_NAMES:
            raise SimConfigError(f"plant must be one of {PLANT_NAMES}, got {self.plant!r}")
        if self.mujoco_integrator not in MUJOCO_INTEGRATORS:
            raise SimConfigError(f"mujoco_integrator must be one of {MUJOCO_INTEGRATORS}, got {self.mujoco_integrator!r}")
        if self.mujoco_cone not in MUJOCO_CONES:
            raise SimConfigError(f"mujoco_cone must be one of {MUJOCO_CONES}, got {self.mujoco_cone!r}")
        for name in ("mujoco_timestep", "mujoco_solver_tolerance", "mujoco_solref_timeconst", "mujoco_solref_dampratio",
                     "mujoco_solimp_width", "mujoco_foot_thickness", "mujoco_foot_width", "mujoco_body_radius",
                     "mujoco_shin_capsule_gap", "mujoco_touch_threshold", "mujoco_swing_debounce",
                     "mujoco_fall_hip_height", "mujoco_fall_foot_tilt"):
            v = getattr(self, name)
            finite_number(v, name, above=0, error=SimConfigError, message=f"{name} must be finite and > 0, got {v}")
        n = self.control_period / self.mujoco_timestep
        if self.plant == "mujoco" and (abs(n - round(n)) > 1e-9 * n or round(n) < 1):
            raise SimConfigError(f"mujoco_timestep must divide control_period ({self.control_period} s), "
                                 f"got {self.mujoco_timestep}")
        if not (isinstance(self.mujoco_sole_points, int) and (self.mujoco_sole_points == 0
                                                              or 2 <= self.mujoco_sole_points <= 101)):
            raise SimConfigError(f"mujoco_sole_points must be 0 (a box) or an integer in [2, 101], got "
                                 f"{self.mujoco_sole_points!r}")
        if not 0.0 < self.mujoco_solimp_dmin <= self.mujoco_solimp_dmax < 1.0:
            raise SimConfigError("mujoco_solimp_dmin and mujoco_solimp_dmax must satisfy 0 < dmin <= dmax < 1, got "
                                 f"{self.mujoco_solimp_dmin}, {self.mujoco_solimp_dmax}")
        if self.mujoco_shin_capsule_gap <= self.mujoco_body_radius:
            raise SimConfigError("mujoco_shin_capsule_gap must exceed mujoco_body_radius (the shin capsule would "
                                 "touch the floor under a flat foot)")
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
        if k in STRING_KEYS:
            if not isinstance(v, str):
                raise SimConfigError(f"{k} must be a word, got {v!r} ({p})")
            continue
        finite_number(v, k, error=SimConfigError, message=f"{k} must be a finite number, got {v!r} ({p})")
    if float(kw["substeps"]) != int(kw["substeps"]):
        raise SimConfigError(f"substeps must be an integer, got {kw['substeps']!r} ({p})")
    kw["substeps"] = int(kw["substeps"])
    for k in ("mujoco_sole_points",):
        if float(kw[k]) != int(kw[k]):
            raise SimConfigError(f"{k} must be an integer, got {kw[k]!r} ({p})")
        kw[k] = int(kw[k])
    return SimConfig(**kw).validate()
