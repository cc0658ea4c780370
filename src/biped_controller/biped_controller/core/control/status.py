"""What one period of the adaptive controller reports: :class:`ControllerStatusData` (every field of
``biped_msgs_py/ControllerStatus``, units in its comments), :func:`status_records` (its one builder, from
rows of the ``controller_layout.RES`` layout), :class:`ControlOutput` (torque [N m] in paper order, status,
the QP instance), and the status and messages of a period without adaptation. Pure Python, no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from biped_controller.core.control.config import TORSO_MODES
from biped_controller.core.control.controller_layout import RES, R_
from biped_controller.core.control.wbc import WBC_MODES

NO_ADAPTATION = 4
NO_ADAPTATION_STATUS = NO_ADAPTATION
MSG_NO_ADAPTATION = "mode none: classical computed torque"
MSG_FIXED_REFERENCE = {"none": MSG_NO_ADAPTATION, "wbc": "mode wbc: fixed reference, whole-body QP on w"}
MSG_X_STAR_FEASIBLE = "x* feasible"


@dataclass(frozen=True)
class ControllerStatusData:
    """Every field of biped_msgs_py/ControllerStatus (pure-Python mirror)."""

    step: int
    t: float
    mode: str
    p: float
    p_dot: float
    tau: float
    tau_dot: float
    p_ddot: float
    tau_ddot: float
    p_ddot_star: float
    tau_ddot_star: float
    qp_status: int
    qp_message: str
    margins: np.ndarray
    tightest: int
    zmp: float
    stance: int
    max_tracking_error: float
    predicted_reaction: np.ndarray = field(default_factory=lambda: np.zeros(2))
    force_estimate: float = 0.0
    wbc_status: int = NO_ADAPTATION_STATUS   # whole-body stage (modes wbc, hybrid): problem status, or 4 = not run
    wbc_active: int = 0                      # bit i: row CONSTRAINT_NAMES[i] active in the whole-body QP's answer
    wbc_deviation: float = 0.0               # [rad/s^2] |w - w*| of the whole-body stage (0 when w* held)
    lam: float = 0.0                         # [rad] torso offset lambda of the period (modes lambda, all; else 0)
    lam_dot: float = 0.0                     # [rad/s] lambda'
    lam_ddot: float = 0.0                    # [rad/s^2] lambda'' chosen
    lam_ddot_star: float = 0.0               # [rad/s^2] lambda''* of the second task


_NEW = object.__new__
_MG = RES.slice("margins")
_RR = RES.slice("reaction")


def status_records(rows: np.ndarray, steps: Sequence[int], times: Sequence[float], mode: str, stance: int,
                   qp_status: int, qp_message: str) -> list[ControllerStatusData]:
    """The one builder of :class:`ControllerStatusData`: from rows of the ``RES`` layout (n, RES.size), one a
    period (the period's p, p', tau, tau', x = (p'', tau''), x*, margins, tightest row, l, max |e|, R, F),
    with their period indices ``steps``, times [s], the mode, the stance and the QP's status and message.
    Each instance's ``__dict__`` is filled at once (the frozen dataclass's ``__init__`` costs ~4 us, as
    much as a compiled period); every field is set here, and ``margins`` / ``predicted_reaction`` are views
    of ``rows`` (pass rows nobody writes again)."""
    c = rows.T.tolist()     # columns, as exact Python floats
    P, PD, TA, TAD, X0, X1, XS0, XS1 = (c[R_.p], c[R_.p_dot], c[R_.tau], c[R_.tau_dot], c[R_.x], c[R_.x + 1],
                                        c[R_.x_star], c[R_.x_star + 1])
    TIGHT, ZMP, ERR, F = [int(v) for v in c[R_.tightest]], c[R_.zmp], c[R_.max_error], c[R_.force]
    MG, RR = rows[:, _MG], rows[:, _RR]
    wbc = mode in WBC_MODES       # the whole-body stage's fields (RES wbc_*); the class defaults otherwise
    if wbc:
        WS, WA, WD = ([int(v) for v in c[R_.wbc_status]], [int(v) for v in c[R_.wbc_active]], c[R_.wbc_deviation])
    torso = mode in TORSO_MODES   # torso modes: lambda, lambda', lambda'', lambda''* (RES lam, x[2], x_star[2])
    if torso:
        LA, LD, X2, XS2 = c[R_.lam], c[R_.lam + 1], c[R_.x + 2], c[R_.x_star + 2]
    out = []
    for j in range(len(P)):
        s = _NEW(ControllerStatusData)
        s.__dict__.update(
            step=steps[j], t=times[j], mode=mode, p=P[j], p_dot=PD[j], tau=TA[j], tau_dot=TAD[j], p_ddot=X0[j],
            tau_ddot=X1[j], p_ddot_star=XS0[j], tau_ddot_star=XS1[j], qp_status=qp_status, qp_message=qp_message,
            margins=MG[j], tightest=TIGHT[j], zmp=ZMP[j], stance=stance, max_tracking_error=ERR[j],
            predicted_reaction=RR[j], force_estimate=F[j])
        if wbc:
            s.__dict__.update(wbc_status=WS[j], wbc_active=WA[j], wbc_deviation=WD[j])
        if torso:
            s.__dict__.update(lam=LA[j], lam_dot=LD[j], lam_ddot=X2[j], lam_ddot_star=XS2[j])
        out.append(s)
    return out


@dataclass(frozen=True)
class ControlOutput:
    torque: np.ndarray            # paper q1..q6 [N m]
    status: ControllerStatusData
    G: np.ndarray | None = None   # the QP instance (for benchmarks/tests); None in mode 'none'
    h: np.ndarray | None = None
    x_star: np.ndarray | None = None
