"""The policy's observation and action vectors: one definition shared by the Gymnasium environment
(``policy.env``) and the policy controller that runs a network in the plug-in loop (``policy.controller``),
so a policy sees the same numbers in training and as a controller.

Pure NumPy, no ROS. The observation is built from what a plug-in controller observes
(``plugin.interface.Observation``: the plant's sensor model applied) and nothing else; the action is the
six joint torques scaled to the robot's torque limits.

Observation (float64, shape (22,), :data:`OBS_FIELDS` in order; paper joint order q1..q6 of the sensed
stance: stance ankle, stance knee, stance hip, swing hip, swing knee, swing ankle):

==========  ======================  ============================================================
index       field                   meaning [unit]
==========  ======================  ============================================================
0-5         ``q1`` .. ``q6``        sensed joint angles [rad]
6-11        ``qd1`` .. ``qd6``      sensed joint rates [rad/s]
12          ``pitch``               IMU torso pitch in the world, counter-clockwise + [rad] (0 if none)
13          ``pitch_rate``          IMU gyro pitch rate [rad/s] (0 if none)
14          ``stance``              sensed stance foot: 0 = LEFT, 1 = RIGHT
15          ``time_in_stance``      time since the sensed stance began (reset or touchdown) [s]
16-21       ``last_torque1..6``     torque the plant applied over the previous plant period divided by
                                    the joint's torque limit [-] (paper order of that period's stance)
==========  ======================  ============================================================

``time_in_stance`` is what a controller computes from the observation's time and its ``on_touchdown``
calls; the times are the loop's stamped times (``interface.stamp_time``), so the controller and the
environment compute the same number. A plant that gives no IMU reading (NaN) is read as 0.

Action (float, shape (6,)), a_i in [-1, 1] (an entry outside is clipped to it), in paper order of the
observation's stance; what it means is the environment's ``action_mode`` (:data:`ACTION_MODES`):

* ``"torque"`` (the default): the torque tau_i = a_i * tau_max_i [N m] (``RobotDescription.torque_limits``),
  held over the policy period (:data:`ACTION_FIELDS`);
* ``"residual"``: an offset delta_i = a_i * s [rad] (s the ``residual_scale``) on the gait family's preferred
  reference q_d(p_d, time in stance), tracked by the computed-torque law at every plant period
  (``policy.residual``); a = 0 is mode ``none`` (:data:`RESIDUAL_ACTION_FIELDS`).
"""
from __future__ import annotations

import math

import numpy as np

from biped_model.description import RobotDescription
from biped_sim.plant.period_grid import grid_end

N_JOINTS = 6
OBS_FIELDS: tuple[str, ...] = (tuple(f"q{i}" for i in range(1, 7)) + tuple(f"qd{i}" for i in range(1, 7))
                               + ("pitch", "pitch_rate", "stance", "time_in_stance")
                               + tuple(f"last_torque{i}" for i in range(1, 7)))
OBS_UNITS: tuple[str, ...] = ("rad",) * 6 + ("rad/s",) * 6 + ("rad", "rad/s", "-", "s") + ("-",) * 6
ACTION_FIELDS: tuple[str, ...] = tuple(f"torque{i}/limit{i}" for i in range(1, 7))
RESIDUAL_ACTION_FIELDS: tuple[str, ...] = tuple(f"q_offset{i}/residual_scale" for i in range(1, 7))
#: what an action means (module docstring), the first the default
ACTION_MODES: tuple[str, ...] = ("torque", "residual")
OBS_SIZE = len(OBS_FIELDS)


class ActionError(ValueError):
    """An action of the wrong shape or with a non-finite entry (the message names it)."""


def action_fields(mode: str) -> tuple[str, ...]:
    """The action's field names under ``mode`` (:data:`ACTION_MODES`); ``ValueError`` naming an unknown one."""
    if mode == "torque":
        return ACTION_FIELDS
    if mode == "residual":
        return RESIDUAL_ACTION_FIELDS
    raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {mode!r}")


def torque_limits(desc: RobotDescription) -> np.ndarray:
    """tau_max (6,) [N m] in paper order q1..q6 (the same for either stance)."""
    return np.array(desc.torque_limits()[1], dtype=float)


def observation_vector(q: np.ndarray, qd: np.ndarray, pitch: float, pitch_rate: float, stance: int,
                       time_in_stance: float, last_torque: np.ndarray, limits: np.ndarray,
                       out: np.ndarray | None = None) -> np.ndarray:
    """The (22,) observation (module docstring) into ``out`` (a new array when None)."""
    v = np.empty(OBS_SIZE) if out is None else out
    v[0:6] = q
    v[6:12] = qd
    v[12] = 0.0 if math.isnan(pitch) else pitch
    v[13] = 0.0 if math.isnan(pitch_rate) else pitch_rate
    v[14] = float(stance)
    v[15] = time_in_stance
    np.divide(last_torque, limits, out=v[16:22])
    return v


def check_action(action: object) -> np.ndarray:
    """The action as a float (6,) array clipped to [-1, 1]; :class:`ActionError` naming the shape or the
    non-finite entries otherwise (nothing else changed)."""
    try:
        a = np.asarray(action, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ActionError(f"action: not numeric: {exc}") from None
    if a.shape != (N_JOINTS,):
        raise ActionError(f"action: shape {a.shape}, expected ({N_JOINTS},) (one value per joint, in [-1, 1])")
    if not np.all(np.isfinite(a)):
        bad = ", ".join(str(int(i) + 1) for i in np.flatnonzero(~np.isfinite(a)))
        raise ActionError(f"action: non-finite entries (joints {bad}): {a.tolist()}")
    return np.clip(a, -1.0, 1.0)


def decision_grid_end(t: float, policy_period: float) -> float:
    """The policy grid instant that ends a decision taken at ``t`` [s]: the first k * policy_period > t
    (the plant's own rule for its control grid, ``biped_sim.plant.period_grid.grid_end``)."""
    return grid_end(t, policy_period)


#: [s] a stamped time within this of a policy grid instant is on it (stamps round to 1 ns)
GRID_TOL = 1e-7


def check_policy_period(policy_period: float, control_period: float) -> float:
    """``policy_period`` [s] when it is a finite whole multiple (>= 1) of the plant's ``control_period``;
    ``ValueError`` naming it otherwise."""
    p = float(policy_period)
    if not math.isfinite(p) or p <= 0:
        raise ValueError(f"policy_period must be a finite number > 0 [s], got {policy_period!r}")
    n = p / control_period
    if round(n) < 1 or abs(n - round(n)) > 1e-9 * max(1.0, n):
        raise ValueError(f"policy_period must be a whole multiple of the plant's control_period "
                         f"({control_period} s), got {policy_period!r}")
    return p
