"""One period of real sensing in a compiled closed loop (numba), shared by the rigid loop (``loop_kernels``)
and the MuJoCo loop (``mujoco_loop_kernels``).

Pure numerics, no ROS. :func:`sense_period` takes the plant's sensor sample of the true joint state and torso
pitch (``biped_sim.plant.sensor_kernels.sample``: the row ``noise_row`` of pre-drawn noise, the encoders'
quantisation, the IMU) and runs the controller's compiled sensing pipeline on it
(``core.sensing.pipeline_kernels.sense``: the estimator, the momentum observer, the legs' model error),
writing the estimate (qe, qde) [rad, rad/s] in paper order of ``stance`` and the pipeline's 8 result values
into ``res`` from ``res0``. When the pipeline hands the period back to Python (a sensed touchdown, a singular
matrix) the pipeline's state is restored from before the period and 0 is returned; 1 when the estimate is
ready. ``sback`` keeps that state for the caller, which restores it too when a later stage of the same period
hands back (the QP, a non-finite torque). :func:`record_decision` writes the period's decision into the
pipeline's state once the controller has committed it (``CompiledSensing.record``: the time, the torque sent
[N m], the stance the controller was told).
"""
from __future__ import annotations

import numba

from biped_sim.plant import sensor_kernels as sn
from biped_controller.core.control.controller_layout import W_
from biped_controller.core.sensing import pipeline_kernels as sk
from biped_controller.core.sensing.pipeline_layout import S_ as SS_


@numba.njit(cache=True, nogil=True)
def sense_period(q, qd, pitch, pitch_rate, noise_row, nconf, qs, qds, sens, sback, s_ti, s_tf, sconf, sstate, t,
                 stance, qe, qde, res, res0):
    sn.sample(q, qd, pitch, pitch_rate, noise_row, nconf, qs, qds, sens)
    sback[:] = sstate
    if sk.sense(s_ti, s_tf, sconf, sstate, t, qs, qds, stance, sens[0], sens[1], qe, qde) != sk.DONE:
        sstate[:] = sback
        return 0
    sk.into_res(sstate, sconf, sens)
    for k in range(8):
        res[res0 + k] = sens[k]
    return 1


@numba.njit(cache=True, nogil=True)
def record_decision(sstate, t, work, stance):
    sstate[SS_.t_prev] = t
    for i in range(6):
        sstate[SS_.torque_prev + i] = work[W_.torque, i]
    sstate[SS_.told_prev] = stance
    sstate[SS_.decided] = 1.0
