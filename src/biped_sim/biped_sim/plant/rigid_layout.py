"""The rigid simulator's per-period state and limits, declared once.

Pure Python + NumPy, no ROS, no Pinocchio. :class:`biped_sim.plant.rigid.Simulator` keeps its state in a
``SIM_STATE`` array (properties over it) and its fixed limits in a ``SIM_LIMITS`` array; the compiled
closed loop (``biped_controller.closed_loop.loop_kernels``) takes the same arrays and reads the offsets from
``SIM_STATE.at`` / ``SIM_LIMITS.at`` (compile-time constants for numba).

* ``SIM_STATE``: time t [s] at the start of the current period, period index, stance foot (0 left, 1 right),
  whether the swing foot has cleared the ground since the last impact (0/1), the stance foot's anchor
  (x [m], z [m], pitch [rad], world frame), the floating state x = [x_hip, z_hip, theta_torso, lh, lk, la,
  rh, rk, ra] (m, rad) and its velocity v = dx/dt.
* ``SIM_LIMITS``: friction coefficient mu [-], the sole's extent l_min, l_max [m] along the foot, the
  touchdown tolerance [m], the clearance before a touchdown counts [m], the lift-off penetration that is a
  fall [m], the control period [s], RK4 substeps per period, the torque limits [N m] (paper order).
"""
from __future__ import annotations

from biped_model.layout import Layout

N_STATE = 9
N_JOINTS = 6

SIM_STATE = Layout("sim_state", [
    ("t", 1), ("step", 1), ("stance", 1), ("cleared", 1), ("anchor", 3), ("x", N_STATE), ("v", N_STATE)])

SIM_LIMITS = Layout("sim_limits", [
    ("mu", 1), ("l_min", 1), ("l_max", 1), ("touchdown_tolerance", 1), ("clearance", 1), ("liftoff_penetration", 1),
    ("dt", 1), ("substeps", 1), ("torque_min", N_JOINTS), ("torque_max", N_JOINTS)])

S_ = SIM_STATE.at
L_ = SIM_LIMITS.at
