"""The controller's per-period state and arrays, declared once.

Pure Python + NumPy, no ROS. Each layout is a :class:`biped_model.layout.Layout`: named fields of
a flat float64 array (2-D arrays: named rows of 6 columns), offsets generated from the declaration.
:class:`controller.AdaptiveController` keeps its state in a ``MEMORY`` array (properties over it),
``controller_kernels`` (one compiled period) and ``loop_kernels`` (many periods) take the same arrays and
read the offsets from the ``*.at`` NamedTuples below (frozen as compile-time constants by numba).

* ``GAINS`` (fixed per controller): K_p, K_v of eq. (16) [1/s^2, 1/s], k_p, k_v of eq. (20) [1/s^2, 1/s],
  p_d [m], the control period dt [s], the family's p range [m], tau_dot_min [-], the observer switch
  and height [m], which parameters are adapted (0/1), the momentum observer switch (its
  estimate comes from the compiled sensing pipeline, ``pipeline_kernels``, through RES.sens_*); the torso modes'
  torso parameter: its switches, the step duration T [s] and lambda's gains and range.
* ``CONS`` (fixed per controller): the QP's margins of the 17 rows, the rows' scales, the torque limits
  [N m], the 5 contact rows of the QP (controller's mu and foot range) and the robot's own 5, each row
  (C_x, C_y, e) of ``fixed_foot.contact_rows``: C (R_x, R_y) + e Gamma_1 < 0.
* ``MEMORY`` (the controller's state between periods): the parameters (p [m], p' [m/s], tau [s],
  tau' [-]) at the last decision (the start of the period being applied), the decision (p'' [m/s^2],
  tau'' [1/s]) held over it, whether a decision was taken since the reset, its time t_last [s], the
  stance of the last decision (or of the reset; -1 none), the force estimate F [N], the period index,
  and the observer's memory of the last period: q'_prev [rad/s], w_prev [rad/s^2], A_prev (6 x 6); then
  (modes lambda and all; 0 otherwise) the torso offset lambda [rad], lambda' [rad/s] at the last
  decision and its decision lambda'' [rad/s^2]; the smallest and largest p [m] and tau' [-] committed since
  the reset (NaN once a committed value was NaN).
* ``RES`` (one period's answer; also the status row of the compiled loop): the period's parameters,
  x = (p'', tau'', lambda'') (lambda'' = 0 outside modes lambda, all), x*, F, max |q_d - q|, the ZMP l [m], the tightest row, R = (R_x, R_y) [N], h_b and
  h_b,c, the 17 margins (positive = satisfied), and the observer mode and elapsed time of the period;
  with the momentum observer the sensing pipeline's inputs to the period, written before it:
  the shift dR [N] of the predicted (R_x, R_y), the force estimate F_x [N] and the widening [N] of the
  five contact rows stated with the estimate; (torso modes) the period's lambda [rad], lambda' [rad/s].
* ``WORK`` (rows of 6): torque Gamma [N m], w [rad/s^2], v, e = q_d - q, dq_d/dp, dq_d/dtau, A (6 rows),
  H, B (3 rows), dq_d/dlambda (written in modes lambda and all only).
"""
from __future__ import annotations

from biped_model.fixed_foot import N_CONSTRAINTS
from biped_model.layout import Layout

N_JOINTS = 6
# rows of the adaptation QP: the 17 constraints with the estimated push force, the same without it,
# and 3 parameter-range rows (p within the family's range, tau' >= tau_dot_min)
QP_ROWS = 2 * N_CONSTRAINTS + 3
# modes lambda and all: four more rows, lambda and lambda' after one period within +-lambda_max,
# +-lambda_dot_max, and a third column (lambda'')
TORSO_ROWS = 4
TORSO_QP_ROWS = QP_ROWS + TORSO_ROWS

GAINS = Layout("gains", [
    ("Kp", 1), ("Kv", 1), ("kp", 1), ("kv", 1), ("p_d", 1), ("dt", 1), ("p_min", 1), ("p_max", 1),
    ("tau_dot_min", 1), ("observer", 1), ("observer_height", 1), ("adapt_p", 1), ("adapt_tau", 1),
    ("momentum", 1),
    # the torso parameter lambda (modes lambda, all; 0 otherwise): whether the reference has it, whether
    # the QP adapts it, the family's step duration T [s] (phi(tau / T)), kp_lambda [1/s^2], kv_lambda [1/s],
    # lambda_max [rad], lambda_dot_max [rad/s]
    ("torso", 1), ("adapt_lam", 1), ("T", 1), ("kp_lam", 1), ("kv_lam", 1), ("lam_max", 1), ("lam_dot_max", 1)])

CONTACT_ROWS = 5
CONS = Layout("cons", [
    ("margin", N_CONSTRAINTS), ("row_scale", N_CONSTRAINTS), ("torque_min", N_JOINTS), ("torque_max", N_JOINTS),
    ("qp_rows", 3 * CONTACT_ROWS), ("true_rows", 3 * CONTACT_ROWS)])

MEMORY = Layout("memory", [
    ("p", 1), ("p_dot", 1), ("tau", 1), ("tau_dot", 1), ("p_ddot", 1), ("tau_ddot", 1),
    ("decided", 1), ("t_last", 1), ("stance", 1), ("force", 1), ("step", 1),
    ("prev_qd", N_JOINTS), ("prev_w", N_JOINTS), ("prev_A", N_JOINTS * N_JOINTS),
    ("lam", 1), ("lam_dot", 1), ("lam_ddot", 1),
    # the extremes of the committed p [m] and tau' [-] since the reset (a run's range, for the studies' records)
    ("p_lo", 1), ("p_hi", 1), ("tau_dot_lo", 1), ("tau_dot_hi", 1)])

RES = Layout("res", [
    ("p", 1), ("p_dot", 1), ("tau", 1), ("tau_dot", 1), ("x", 3), ("x_star", 3), ("force", 1), ("max_error", 1),
    ("zmp", 1), ("tightest", 1), ("reaction", 2), ("h_b", 3), ("h_b_c", 3), ("margins", N_CONSTRAINTS),
    ("obs_mode", 1), ("obs_dt", 1),
    ("sens_dR", 2), ("sens_force", 1), ("sens_margin", 5),
    # the whole-body stage (core/control/wbc_kernels.py): its problem status (4: not run), the active rows
    # as a bit mask over the 17 (folded over both blocks), |w - w*| [rad/s^2]
    ("wbc_status", 1), ("wbc_active", 1), ("wbc_deviation", 1),
    # the period's torso offset lambda [rad] and lambda' [rad/s] (0 outside modes lambda, all)
    ("lam", 2)])

WORK = Layout("work", [
    ("torque", 1), ("w", 1), ("v", 1), ("e", 1), ("dq_dp", 1), ("dq_dtau", 1), ("A", N_JOINTS), ("H", 1), ("B", 3),
    ("dq_dlam", 1)])

# the offsets, as numba reads them (module globals: compile-time constants)
G_ = GAINS.at
C_ = CONS.at
M_ = MEMORY.at
R_ = RES.at
W_ = WORK.at

# RES.obs_mode: the observer's input this period
OBS_NONE, OBS_RESIDUAL, OBS_KEEP = 0, 1, 2      # no memory | residual of the last period | keep F (impact)

# the whole-body stage's constants (core/control/wbc_kernels.py): its mode (WBC_MODE_*), its weight M and
# M^-1 (6 x 6, row-major; M = wbc_weight_joint I + wbc_weight_torso s s^T, core/control/wbc.py)
WBC = Layout("wbc", [("mode", 1), ("M", N_JOINTS * N_JOINTS), ("Minv", N_JOINTS * N_JOINTS)])
WB_ = WBC.at
WBC_MODE_OFF, WBC_MODE_WBC, WBC_MODE_HYBRID = 0, 1, 2
