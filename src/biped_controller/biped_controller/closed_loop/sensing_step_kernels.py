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
hands back (the QP, a non-finite torque).
"""
from __future__ import annotations

import numba

from biped_sim.plant import sensor_kernels as sn
from biped_controller.core.sensing import pipeline_kernels as sk


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
