"""The compiled twin (numba) of :meth:`biped_sim.plant.perturbation.SensorModel.sample` without a delay: the
plant's sensors' sample of one control period, for the compiled closed loops that carry real sensing
(``biped_controller.closed_loop.loop_kernels`` on the rigid plant, ``mujoco_loop_kernels`` on MuJoCo), which
import it. The same sums in the same order as the Python home (IEEE double, no fast-math), the angles rounded
half to even as ``np.round``: the samples are bit-identical to it (tested through the closed loops' records,
``tests/test_sensing_loop.py``).

Pure numerics, no side effects on import (it is loaded through ``numba_cache.load`` as a dependency of the
loops' kernels).
"""
from __future__ import annotations

import numba
import numpy as np

from biped_model import numba_cache

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

# the sensors' noise (``SensorModel.compiled_noise``): noise_q, noise_q', encoder step, noise_pitch, noise_pitch_rate
(NZ_Q, NZ_QD, NZ_STEP, NZ_PITCH, NZ_RATE) = range(5)


@numba.njit(cache=True, nogil=True)
def sample(q, qd, pitch, rate, z, nconf, qs, qds, out):  # pragma: no cover (compiled)
    """The plant's sensors' sample of (q [rad], q' [rad/s], torso pitch [rad], its rate [rad/s]) with the
    standard normal draws ``z`` (z_q (6), z_q' (6), z_p, z_r) and the noise's sizes ``nconf`` (NZ_*):
    ``SensorModel.sample``'s sums in its order, the angles quantised half to even; qs, qds <- the joints,
    out[0], out[1] <- the pitch and its rate."""
    for i in range(6):
        a = q[i]
        if nconf[NZ_Q] > 0.0:
            a = a + nconf[NZ_Q] * z[i]
        if nconf[NZ_STEP] > 0.0:
            a = nconf[NZ_STEP] * np.rint(a / nconf[NZ_STEP])
        qs[i] = a
        b = qd[i]
        if nconf[NZ_QD] > 0.0:
            b = b + nconf[NZ_QD] * z[6 + i]
        qds[i] = b
    th = pitch
    if nconf[NZ_PITCH] > 0.0:
        th += nconf[NZ_PITCH] * z[12]
    rt = rate
    if nconf[NZ_RATE] > 0.0:
        rt += nconf[NZ_RATE] * z[13]
    out[0] = th
    out[1] = rt
