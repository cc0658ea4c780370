"""What a plant reports, per control period and per impact (the one layout every engine fills).

Pure Python + NumPy, no ROS. Frames, units and signs as in DESIGN.md; the instants each field describes
are stated on each record.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Observation:
    """What the controller may measure at the start of a control period (paper coordinates); ``pitch``
    the IMU's torso pitch in the world [rad], counter-clockwise positive, ``pitch_rate`` its gyro's rate
    [rad/s] (NaN: no IMU reading given)."""

    step: int
    t: float
    stance: int
    q: np.ndarray
    qd: np.ndarray
    pitch: float = float("nan")
    pitch_rate: float = float("nan")


@dataclass(frozen=True, eq=False)
class StepRecord:
    """Record of one control period [t, t_end), taken at its start t (after any impact of the previous one).

    ``q, qd`` paper coordinates of the current stance; ``x, v`` the floating state; ``torque`` the paper-order
    torques applied over the period (after clipping to the limits); ``wrench`` = [F_x, F_z, m] the ground's
    action on the stance foot at its ankle [N, N, N m] at the period start, under the period's torque and
    push (the reaction the controller's decision produces); ``cop`` = m / F_z [m] ahead of the stance ankle;
    ``push_force`` the horizontal push [N] acting at the period start; ``push_impulse`` = integral of the push
    force over [t, t_end) [N s] (exact: the force is constant on each integration interval); ``t_end`` the
    end of the period: the next grid instant, the impact instant, or the instant of a fall.
    """

    step: int
    t: float
    stance: int
    q: np.ndarray
    qd: np.ndarray
    base: np.ndarray
    base_dot: np.ndarray
    x: np.ndarray
    v: np.ndarray
    torque: np.ndarray
    wrench: np.ndarray
    cop: float
    push_force: float
    impacts: int
    fallen: bool
    fall_cause: str
    fall_detail: str
    t_end: float
    push_impulse: float


@dataclass
class FallInfo:
    cause: str
    t: float
    detail: str
    values: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ImpactRecord:
    """One touchdown, every stage of it (floating coordinates x = [x_hip, z_hip, theta, lh, lk, la, rh, rk,
    ra], v = dx/dt; see ``floating``):

    * ``x_minus, v_minus``: the state reached by the integration when the sole touches the ground (t);
    * ``foot_tilt`` [rad]: the landing foot's pitch at that instant; it is laid flat by subtracting it from
      its ankle joint (``x_flat``: a configuration jump of one joint, velocities unchanged);
    * ``impulse`` [N s, N s, N m s]: the ground's impulse on the landing foot (x, z, moment about its ankle),
      ``v_plus`` the post-impact velocity in ``x_flat``: M(x_flat) (v_plus - v_minus) = J_c^T impulse,
      J_c v_plus = 0;
    * ``energy_loss`` [J] = 1/2 v_minus^T M v_minus - 1/2 v_plus^T M v_plus (at x_flat);
    * ``x_plus, v_plus_projected``: the state the next period starts from (base re-placed so the new foot
      sits exactly on its anchor, velocity projected on its contact: both changes are at round-off level);
    * ``old_foot_velocity``: (x, z, pitch) rates of the released foot after the impact (z rate >= 0 lifts).
    """

    index: int
    t: float
    old_stance: int
    new_stance: int
    x_minus: np.ndarray
    v_minus: np.ndarray
    foot_tilt: float
    x_flat: np.ndarray
    v_plus: np.ndarray
    x_plus: np.ndarray
    v_plus_projected: np.ndarray
    impulse: np.ndarray
    energy_loss: float
    old_foot_velocity: np.ndarray
    ankle_x: float
