"""Compiled (numba) MuJoCo steps of the MuJoCo plant: the bookkeeping of one step (what
``biped_sim.plant.mujoco.MujocoPlant.step`` does after each ``mj_step`` + ``mj_rnePostConstraint``) and
:func:`substeps`, a control period's MuJoCo steps in one call.

No side effects on import (load it through ``numba_cache.load``, as ``mujoco.load_kernels`` does, so its
cache is kept right and MuJoCo's shared library is loaded first). :func:`substeps` calls MuJoCo's C functions
``mj_step`` and ``mj_rnePostConstraint`` by name (numba external functions, resolved in the ``libmujoco``
the Python bindings ship and load: ``mujoco.load_kernels`` makes its symbols visible to numba before the
module is compiled or read from the cache) with the raw ``mjModel*`` / ``mjData*`` (``MjModel._address``,
``MjData._address``); the step length is written through a one-element view of ``mjModel.opt.timestep``.
These calls bypass the bindings' error interception: a MuJoCo *error* (not a warning) inside them ends the
process instead of raising (the plant's warnings are read after the period, as on the Python path).
Everything else is pure numerics. The arrays are MuJoCo's own (``MjData`` fields as
NumPy views, read only) and two of the plant's: ``acc`` (float64, the period's accumulators and the sensing
state, layout ``A_*`` below, read and written) and ``ip`` (int64 indices, ``I_*``); ``fp`` (float64, ``F_*``) the
period's constants. The operations and their order are those of the plant's Python reference
(``MujocoPlant._contacts`` for the contact rows, the module docstring of ``plant.mujoco`` for the rest): IEEE
double arithmetic, no fast-math, so the results are bit-identical to it (``plant_compare fingerprint``, and
``tests/test_mujoco_plant.py`` compares the rows with ``_contacts`` and with MuJoCo's contact list).

Per MuJoCo step [t0, t1] of length h, the step just taken (forces of t0 applied over [t0, t1]):

* contact rows per foot k (world frame, on the robot): F_x = f_x, F_z = f_z, the moment about the foot's ankle
  p, counter-clockwise, m = -(tau_y + (c_z - p_z) f_x - (c_x - p_x) f_z) (``cfrc_ext``: force f and moment tau
  about the subtree centre of mass c), and the normal force f_z; a thigh or shin with any external force, or
  a torso whose external force differs from the push (``xfrc_applied``) by more than 1e-9 (1 + |push_x|),
  touches the floor (``A_HIT``: its capsule's geom id, else -1);
* sums h [F_x, F_z, m] per foot about its own ankle (``A_OWN``) and about the stance ankle (``A_BY``; moment
  m + (x_k - x_a) F_z - (z_k - z_a) F_x), skipped for a foot with F_x = F_z = 0;
* actuator work h sum_i Gamma_i q'_i over the six joints with the step's end velocity (``A_WORK``; the push's
  work is added by the caller);
* contact diagnostics of the stance foot (``ContactDiagnostics``: ``A_DIAG``): unloaded (normal force below
  the touch threshold), centre of pressure l = m / F_z beyond the edge band, |F_x| >= 0.99 mu F_z, pitch
  (at the step's start, ``A_PITCH``) beyond the roll tilt, the largest |l|, |pitch| and ankle slip;
* touchdown sensing on the swing foot's normal force (``A_UNLOADED_SINCE``, NaN = loaded; ``A_ARMED``);
* the stance foot's pitch at the step's end (``A_PITCH``), the sum of the state (``A_STATE_SUM``: finite iff
  every entry is) and the fall pre-check.

Returns ``CONTINUE``, ``TOUCHDOWN`` (the swing foot loaded after its debounce) or ``MAYBE_FALL`` (a body
capsule on the floor, the hip below its height or the stance foot past its tilt: the caller names the fall).

:func:`substeps` runs a period's MuJoCo steps over its integration knots: per interval [t0, t1] the pushes
acting over it (``MujocoPlant._set_push``: force and moment on the torso), the step length t1 - t0, ``mj_step``,
``mj_rnePostConstraint``, :func:`after_step`, the pushes' impulse and work; the order and the operations of the
plant's Python loop (``MujocoPlant._substeps_python``), so the two are bit-identical (tested).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from biped_model import numba_cache

numba_cache.require_configured(__name__)   # a check: import this module with numba_cache.load

CONTINUE, TOUCHDOWN, MAYBE_FALL = 0, 1, 2

# row (float64): one period's record, its fields as views (StepRecord): the state at the period's start in
# paper order (q, qd) and floating (x, v; base = x[:3], base_dot = v[:3]), the applied paper-order torque, the
# mean ground wrench over the period, its centre of pressure
R_Q, R_QD, R_BASE, R_BASE_DOT, R_X, R_V, R_TORQUE, R_WRENCH, R_COP = 0, 6, 12, 15, 18, 27, 36, 42, 45
ROW_SIZE = 46

# acc (float64): the period's accumulators and the sensing state
A_BY = 0              # [6] per foot (left, right) sum h [F_x, F_z, m about the stance ankle]
A_OWN = 6             # [6] per foot sum h [F_x, F_z, m about its own ankle]
A_WORK = 12           # actuator (+ push, by the caller) work over the period [J]
A_PITCH = 13          # stance foot's pitch at the current step's start [rad]
A_UNLOADED_SINCE = 14  # swing foot unloaded since [s]; NaN: loaded
A_ARMED = 15          # 1.0: the swing foot has been unloaded for the debounce
A_ROWS = 16           # [8] the last step's rows per foot: F_x, F_z, m about its ankle, normal force
A_HIT = 24            # the last step's body capsule on the floor (geom id) or -1
A_DIAG = 25           # [9] steps, time, unloaded_time, edge_time, cone_time, tilt_time, max_cop, max_tilt, max_slip
A_STATE_SUM = 34      # sum of qpos and qvel at the step's end (finite iff the state is)
ACC_SIZE = 35

# ip (int64): indices
I_STANCE, I_FOOT_BODY, I_TORSO, I_J0, I_LEG_BODY, I_LEG_GEOM, I_TORSO_GEOM = 0, 1, 3, 4, 5, 9, 13
IP_SIZE = 14

# fp (float64): the period's constants
F_THR, F_DEBOUNCE, F_HIP_MIN, F_TILT_MAX, F_EDGE_LO, F_EDGE_HI, F_CONE, F_ROLL, F_ANCHOR_X = range(9)
FP_SIZE = 9

# MuJoCo's C API (mujoco.h): void mj_step(const mjModel* m, mjData* d); void mj_rnePostConstraint(const mjModel* m,
# mjData* d); resolved by name in the loaded libmujoco
_mj_step = numba.types.ExternalFunction("mj_step", numba.void(numba.types.voidptr, numba.types.voidptr))
_mj_rne_post_constraint = numba.types.ExternalFunction("mj_rnePostConstraint",
                                                       numba.void(numba.types.voidptr, numba.types.voidptr))

# out (float64) of substeps: the intervals done so far, the pushes' impulse so far [N s]
O_DONE, O_IMPULSE = 0, 1
OUT_SIZE = 2

_M2 = numba.types.Array(numba.float64, 2, "C")
_V = numba.types.Array(numba.float64, 1, "C")
_IV = numba.types.Array(numba.int64, 1, "C")


@numba.njit(numba.void(_M2, _V, _V, _V, _V), cache=True, nogil=True)
def joints_in_paper_order(p, x, v, q, qd):  # pragma: no cover (compiled)
    """The six joints in paper order from a floating state: ``q = P x[3:9]``, ``qd = P v[3:9]`` with the stance's
    permutation ``P`` (entries 0, +-1), each entry summed from +0.0 in column order as NumPy's matmul does it."""
    for i in range(6):
        s = 0.0
        sd = 0.0
        for j in range(6):
            s += p[i, j] * x[3 + j]
            sd += p[i, j] * v[3 + j]
        q[i] = s
        qd[i] = sd


@numba.njit(numba.void(_V, _V, _V, _M2, _M2, numba.boolean, _V, _V, _V, _V, _V), cache=True, nogil=True)
def begin_period(torque, lo, hi, p_told, p_true, remap, qpos, qvel, ctrl, acc, row):  # pragma: no cover (compiled)
    """A period's start: the paper-order torque ``torque`` clipped to [lo, hi] (NaN stays NaN, as np.clip), to
    URDF joint order for the stance the controller was told (tau_j = P_told^T applied), written to ``ctrl``; the
    applied torque back in the true stance's paper order (P_true tau_j) when the two stances differ (``remap``);
    the record's state (q = P_true x[3:], qd = P_true v[3:], x, v, base, base_dot) in ``row``; the period's sums
    in ``acc`` zeroed. The products with the permutations P (entries 0, +-1) are summed from +0.0 in column
    order, as NumPy's matmul gives them: exact, a zero is +0.0, a NaN or inf anywhere makes every entry NaN."""
    for i in range(6):
        a = torque[i]
        if a < lo[i]:
            a = lo[i]
        if a > hi[i]:
            a = hi[i]
        row[R_TORQUE + i] = a
    for j in range(6):
        s = 0.0
        for i in range(6):
            s += p_told[i, j] * row[R_TORQUE + i]
        ctrl[j] = s
    if remap:
        for i in range(6):
            s = 0.0
            for j in range(6):
                s += p_true[i, j] * ctrl[j]
            row[R_TORQUE + i] = s
    joints_in_paper_order(p_true, qpos, qvel, row[R_Q:R_Q + 6], row[R_QD:R_QD + 6])
    for i in range(9):
        row[R_X + i] = qpos[i]
        row[R_V + i] = qvel[i]
    for i in range(3):
        row[R_BASE + i] = qpos[i]
        row[R_BASE_DOT + i] = qvel[i]
    for i in range(A_PITCH):
        acc[i] = 0.0


@numba.njit(numba.void(_V, _V, _M2, numba.int64, _V), cache=True, nogil=True)
def measure(x, v, p, j0, out):  # pragma: no cover (compiled)
    """(q, q') as the robot measures them (``MujocoPlant.measured``) in ``out[:6]``, ``out[6:]``: the encoders in
    paper order (P x[3:], P v[3:], P the stance's permutation, summed as ``begin_period`` does), then q1 (q1')
    plus the stance foot's pitch (rate) x[2] + (x[j0] + x[j0 + 1] + x[j0 + 2]), j0 its leg's first joint."""
    joints_in_paper_order(p, x, v, out[:6], out[6:])
    out[0] = out[0] + (x[2] + (x[j0] + x[j0 + 1] + x[j0 + 2]))
    out[6] = out[6] + (v[2] + (v[j0] + v[j0 + 1] + v[j0 + 2]))


@numba.njit(numba.void(_V, _V, numba.int64, numba.boolean, numba.float64), cache=True, nogil=True)
def end_period(acc, row, stance, touchdown, dt):  # pragma: no cover (compiled)
    """A period's end: the mean ground wrench over the period ``dt`` [s] in ``row`` -- both feet's sums about
    the stance ankle (stance first), the landing foot's left out when the period ends in a touchdown (its
    impact carries it) -- and its centre of pressure m / F_z (NaN when F_z = 0)."""
    s3 = 3 * stance
    w3 = 3 - s3
    for i in range(3):
        if touchdown:
            tot = acc[A_BY + s3 + i] + 0.0
        else:
            tot = acc[A_BY + s3 + i] + acc[A_BY + w3 + i]
        row[R_WRENCH + i] = tot / dt
    if row[R_WRENCH + 1] != 0.0:
        row[R_COP] = row[R_WRENCH + 2] / row[R_WRENCH + 1]
    else:
        row[R_COP] = np.nan


@numba.njit(numba.int64(_M2, _M2, _M2, _V, _V, _M2, _V, _V, _IV, _V, numba.float64, numba.float64),
            cache=True, nogil=True)
def after_step(cfrc, xpos, scom, qpos, qvel, xfrc, ctrl, acc, ip, fp, t0, t1):  # pragma: no cover (compiled)
    """The bookkeeping of the MuJoCo step [t0, t1] just taken (module docstring)."""
    h = t1 - t0
    stance = ip[I_STANCE]
    swing = 1 - stance
    torso = ip[I_TORSO]
    # contact rows per foot (MujocoPlant._contacts)
    cx = scom[torso, 0]
    cz = scom[torso, 2]
    for k in range(2):
        b = ip[I_FOOT_BODY + k]
        ty = cfrc[b, 1]
        fx = cfrc[b, 3]
        fz = cfrc[b, 5]
        px = xpos[b, 0]
        pz = xpos[b, 2]
        acc[A_ROWS + 4 * k] = fx
        acc[A_ROWS + 4 * k + 1] = fz
        acc[A_ROWS + 4 * k + 2] = -(ty + (cz - pz) * fx - (cx - px) * fz)
        acc[A_ROWS + 4 * k + 3] = fz
    hit = -1
    for i in range(4):
        b = ip[I_LEG_BODY + i]
        if cfrc[b, 3] != 0.0 or cfrc[b, 4] != 0.0 or cfrc[b, 5] != 0.0:
            hit = ip[I_LEG_GEOM + i]
            break
    if hit < 0:
        dmax = abs(cfrc[torso, 3] - xfrc[torso, 0])
        e = abs(cfrc[torso, 4] - xfrc[torso, 1])
        if e > dmax:
            dmax = e
        e = abs(cfrc[torso, 5] - xfrc[torso, 2])
        if e > dmax:
            dmax = e
        if dmax > 1e-9 * (1.0 + abs(xfrc[torso, 0])):
            hit = ip[I_TORSO_GEOM]
    acc[A_HIT] = hit
    # actuator work with the step's end velocity (the positions advance with it)
    acc[A_WORK] += h * (0.0 + ctrl[0] * qvel[3] + ctrl[1] * qvel[4] + ctrl[2] * qvel[5] + ctrl[3] * qvel[6]
                        + ctrl[4] * qvel[7] + ctrl[5] * qvel[8])
    # the feet's sums
    bst = ip[I_FOOT_BODY + stance]
    ax = xpos[bst, 0]
    az = xpos[bst, 2]
    for k in range(2):
        fx = acc[A_ROWS + 4 * k]
        fz = acc[A_ROWS + 4 * k + 1]
        my = acc[A_ROWS + 4 * k + 2]
        if fz == 0.0 and fx == 0.0:
            continue
        acc[A_OWN + 3 * k] += h * fx
        acc[A_OWN + 3 * k + 1] += h * fz
        acc[A_OWN + 3 * k + 2] += h * my
        bk = ip[I_FOOT_BODY + k]
        kx = xpos[bk, 0]
        kz = xpos[bk, 2]
        acc[A_BY + 3 * k] += h * fx
        acc[A_BY + 3 * k + 1] += h * fz
        acc[A_BY + 3 * k + 2] += h * (my + (kx - ax) * fz - (kz - az) * fx)
    # contact diagnostics of the stance foot (its state at the step's start for the pitch)
    fx = acc[A_ROWS + 4 * stance]
    fz = acc[A_ROWS + 4 * stance + 1]
    my = acc[A_ROWS + 4 * stance + 2]
    fn = acc[A_ROWS + 4 * stance + 3]
    acc[A_DIAG] += 1.0
    acc[A_DIAG + 1] += h
    if fn < fp[F_THR]:
        acc[A_DIAG + 2] += h
    else:
        l = my / fz
        if abs(l) > acc[A_DIAG + 6]:
            acc[A_DIAG + 6] = abs(l)
        if l < fp[F_EDGE_LO] or l > fp[F_EDGE_HI]:
            acc[A_DIAG + 3] += h
        if abs(fx) >= fp[F_CONE] * fz:
            acc[A_DIAG + 4] += h
    tilt = abs(acc[A_PITCH])
    if tilt > acc[A_DIAG + 7]:
        acc[A_DIAG + 7] = tilt
    if tilt > fp[F_ROLL]:
        acc[A_DIAG + 5] += h
    slip = abs(ax - fp[F_ANCHOR_X])
    if slip > acc[A_DIAG + 8]:
        acc[A_DIAG + 8] = slip
    # touchdown sensing on the swing foot's normal force
    touchdown = False
    if acc[A_ROWS + 4 * swing + 3] < fp[F_THR]:
        if acc[A_UNLOADED_SINCE] != acc[A_UNLOADED_SINCE]:     # NaN: was loaded
            acc[A_UNLOADED_SINCE] = t0
        if t1 - acc[A_UNLOADED_SINCE] >= fp[F_DEBOUNCE]:
            acc[A_ARMED] = 1.0
    elif acc[A_ARMED] != 0.0:
        touchdown = True
    else:
        acc[A_UNLOADED_SINCE] = np.nan
    total = 0.0
    for i in range(qpos.shape[0]):
        total += qpos[i] + qvel[i]
    acc[A_STATE_SUM] = total
    j0 = ip[I_J0]
    pitch = qpos[2] + (qpos[j0] + qpos[j0 + 1] + qpos[j0 + 2])
    acc[A_PITCH] = pitch
    if touchdown:
        return TOUCHDOWN
    if hit >= 0 or qpos[1] < fp[F_HIP_MIN] or abs(pitch) > fp[F_TILT_MAX]:
        return MAYBE_FALL
    return CONTINUE


@numba.njit(numba.int64(numba.int64, numba.int64, _V, _V, numba.int64, _M2, numba.float64, _M2, _M2, _M2, _V, _V,
                        _M2, _V, _V, _IV, _V, _V), cache=True, nogil=True)
def substeps(model, data, timestep, knots, i0, pushes, torso_com, cfrc, xpos, scom, qpos, qvel, xfrc, ctrl, acc, ip,
             fp, out):  # pragma: no cover (compiled)
    """The MuJoCo steps of a period over the intervals [knots[i], knots[i + 1]], i = i0, i0 + 1, ... (module
    docstring), until the last one or the first step whose :func:`after_step` does not return ``CONTINUE``;
    returns that code (``CONTINUE`` after the last interval) with ``out[O_DONE]`` the intervals done so far
    (i0 + those of this call). ``model``, ``data``: the ``mjModel*`` and ``mjData*`` addresses; ``timestep`` a
    view of ``mjModel.opt.timestep``; ``pushes`` (n, 4) the scheduled pushes in the plant's order (start, end
    [s], force [N], height [m] above the hip), n = 0: ``xfrc`` is left as it is; a push acts over an interval
    whose midpoint lies in [start, end): force on the torso x, moment (height - ``torso_com``) cos(theta) F
    about y at the step's start; its impulse F h is added to ``out[O_IMPULSE]`` and its work h F (x' -
    height cos(theta) theta') with the step's end state to ``acc[A_WORK]``."""
    torso = ip[I_TORSO]
    n_push = pushes.shape[0]
    n = knots.shape[0] - 1
    i = i0
    while i < n:
        t0 = knots[i]
        t1 = knots[i + 1]
        tm = 0.5 * (t0 + t1)
        if n_push > 0:
            th = qpos[2]
            for c in range(6):
                xfrc[torso, c] = 0.0
            for k in range(n_push):
                if pushes[k, 0] <= tm < pushes[k, 1]:
                    f = pushes[k, 2]
                    xfrc[torso, 0] += f
                    xfrc[torso, 4] += (pushes[k, 3] - torso_com) * math.cos(th) * f
        timestep[0] = t1 - t0
        _mj_step(model, data)
        _mj_rne_post_constraint(model, data)          # cfrc_ext: the forces of t0, applied over [t0, t1]
        code = after_step(cfrc, xpos, scom, qpos, qvel, xfrc, ctrl, acc, ip, fp, t0, t1)
        if n_push > 0:
            h = t1 - t0
            xv = qvel[0]
            thv = qvel[2]
            th = qpos[2]
            for k in range(n_push):
                if pushes[k, 0] <= tm < pushes[k, 1]:
                    f = pushes[k, 2]
                    out[O_IMPULSE] += f * h
                    acc[A_WORK] += h * f * (xv - pushes[k, 3] * math.cos(th) * thv)
        i += 1
        if code != CONTINUE:
            out[O_DONE] = i
            return code
    out[O_DONE] = i
    return CONTINUE
