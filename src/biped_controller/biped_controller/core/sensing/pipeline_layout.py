"""The compiled sensing pipeline's state and settings arrays, declared once.

Pure Python + NumPy, no ROS. Two :class:`biped_model.layout.Layout` records that the Python wrapper
(``pipeline_compiled.CompiledSensing``) and the numba kernels (``pipeline_kernels``) share, so the two
sides cannot disagree on where a field lives (the same pattern as ``controller_layout``):

* ``SCONF`` (fixed per controller): which parts run (estimator, momentum observer: 0/1), the observer's gain
  K [1/s] and wrench height [m] above the hip, the estimator's process noise sigma_a [rad/s^2], the
  measurement variances it assumes (encoder var_q [rad^2] including the quantisation Delta^2 / 12, rate
  sensor var_qd [rad^2/s^2], IMU pitch var_pitch [rad^2], IMU gyro pitch rate var_pitch_rate [rad^2/s^2];
  -1: the sensor is not used), the rate std added
  at a touchdown [rad/s], the rate noise std the observer assumes without an estimator [rad/s], the QP's
  confidence k [-] and its five contact rows' (C_x, C_y) (``fixed_foot.contact_rows`` with the controller's
  margins), the torque limits [N m] (the applied torque is the sent one clipped), and the Smith
  predictor's control period [s], RK4 steps per period, touchdown height [m], clearance [m] and time
  tolerance [s] (``predictor``).
* ``SENS`` (the pipeline's state between periods and its outputs): the estimate x = (q, q') [rad, rad/s]
  and its covariance P (12 x 12, row-major), whether a sample was used and its stance, the last decision
  (time [s], torque sent [N m] in the paper order of the stance it was told, that stance), the momentum
  observer's memory (started, stance, r [N m], W [N, N, N m], the integral I [N m s], p(0) [N m s],
  beta [N m], the wrench carried over at the last restart, the time since it [s]) and its outputs for the
  QP (cov_W (3 x 3), dR [N] and cov_dR (2 x 2) of the predicted ground force, S (2 x 3), the five contact
  rows' widening k sigma [N]), and A (6 x 6), H [N m] of the model at the estimate the observer last saw
  (the estimator's next time update starts there), the predictor's memory of its sample: the stance
  (-1 none) and whether the swing foot has cleared the ground since that stance began (0/1).
* the legs' model-error estimator (``model_error``; ``SCONF.me`` 1: on, run inside the compiled pipeline by
  ``model_error_kernels.update``): in ``SCONF`` its residual variance s_res^2 [N^2 m^2], its settling time
  after the observer's restart [s] and the residual variance that holds a sample (``HOLD_VARIANCE``), the prior
  covariance P0 (6 x 6) of theta and the combination D (2 nb x 6) of the fixed-foot tree's bodies' unit-mass
  and unit-inertia columns into the six leg parameters (``model_error.body_combination``); in ``SENS`` its
  state (theta [kg, kg m^2], P, the filtered regressor Y_f and the last sample's joint rows Y_prev (6 x 6
  each), the torso wrench carried at the observer's last restart, the last torque applied [N m], flags: a
  previous Y, a last torque, RLS updates made) and its outputs for the QP (the torso wrench W_t [N, N, N m],
  its covariance (3 x 3), dR [N], cov_dR (2 x 2), the five contact rows' widening k sigma [N]).
"""
from __future__ import annotations

from biped_model.layout import Layout

N_STATE = 12
N_LEG_PARAMETERS = 6   # len(model_error.LEG_PARAMETERS) (checked by CompiledSensing)
N_TREE_BODIES = 7      # bodies of fast_engine.fixed_foot_tree (checked by CompiledSensing)

SCONF = Layout("sensing_conf", [
    ("estimator", 1), ("observer", 1), ("K", 1), ("height", 1), ("sigma_acc", 1), ("var_q", 1), ("var_qd", 1),
    ("var_pitch", 1), ("var_pitch_rate", 1), ("sigma_impact", 1), ("noise_qd", 1), ("confidence", 1), ("qp_rows", 10),
    ("torque_min", 6), ("torque_max", 6),
    ("period", 1), ("pred_substeps", 1), ("pred_td_height", 1), ("pred_clearance", 1), ("pred_t_tol", 1),
    ("me", 1), ("me_var_res", 1), ("me_settle", 1), ("me_var_hold", 1), ("me_P0", N_LEG_PARAMETERS ** 2),
    ("me_D", 2 * N_TREE_BODIES * N_LEG_PARAMETERS)])

SENS = Layout("sensing", [
    ("x", N_STATE), ("P", N_STATE * N_STATE), ("started", 1), ("stance", 1),
    ("decided", 1), ("t_prev", 1), ("torque_prev", 6), ("told_prev", 1),
    ("mo_started", 1), ("mo_stance", 1), ("r", 6), ("W", 3), ("I", 6), ("p0", 6), ("beta", 6), ("W_restart", 3),
    ("since", 1), ("cov_W", 9), ("dR", 2), ("cov_dR", 4), ("S", 6), ("extra", 5), ("A_est", 36), ("H_est", 6),
    ("pred_sample_stance", 1), ("pred_cleared", 1),
    ("me_theta", N_LEG_PARAMETERS), ("me_P", N_LEG_PARAMETERS ** 2), ("me_Yf", N_LEG_PARAMETERS ** 2),
    ("me_Yprev", N_LEG_PARAMETERS ** 2), ("me_W_restart", 3), ("me_last_torque", 6), ("me_flags", 3),
    ("me_W", 3), ("me_cov_W", 9), ("me_dR", 2), ("me_cov_dR", 4), ("me_extra", 5)])

SC_ = SCONF.at
S_ = SENS.at
