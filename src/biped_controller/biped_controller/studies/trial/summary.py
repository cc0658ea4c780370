"""The numbers of one closed-loop run (plain floats and lists, JSON-ready)."""
from __future__ import annotations

import math

import numpy as np

from biped_model.gait_family import GaitFamily

from biped_controller.core.qp.solver import STATUS_NAMES
from biped_controller.closed_loop.runner import RunResult
from biped_controller.studies.trial.context import context


def joint_errors(result: RunResult, family: GaitFamily | None = None) -> np.ndarray:
    """(N, 6) tracking errors q_d(p, tau, lambda) - q at every control instant [rad] (paper joint order;
    lambda = 0 outside modes lambda and all)."""
    fam = family if family is not None else context().family
    return np.array([fam.evaluate_torso(s.p, s.tau, s.lam).q - r.q for s, r in zip(result.statuses, result.records)])


def summarize(result: RunResult, family: GaitFamily | None = None, push_end: float | None = None) -> dict:
    """Numbers of one run (plain floats/lists, JSON-ready)."""
    fam = family if family is not None else context().family
    st, rec = result.statuses, result.records
    p = np.array([s.p for s in st])
    tau = np.array([s.tau for s in st])
    taud = np.array([s.tau_dot for s in st])
    err = np.array([s.max_tracking_error for s in st])
    t = np.array([r.t for r in rec])
    cop = np.array([r.cop for r in rec])
    ok = np.isfinite(cop) & ~np.array([r.fallen for r in rec])
    impacts = [float(i.t) for i in result.impacts]
    first = impacts[0] if impacts else math.inf
    qp_counts: dict[str, int] = {}
    for s in st:
        name = STATUS_NAMES.get(s.qp_status, "NO_ADAPTATION" if s.qp_status == 4 else str(s.qp_status))
        qp_counts[name] = qp_counts.get(name, 0) + 1
    out = {
        **_outcome(result),
        "max_tracking_error": float(err.max()) if err.size else 0.0,
        "max_tracking_error_before_first_impact": float(err[t < first].max()) if np.any(t < first) else 0.0,
        "max_tracking_error_after_first_impact": float(err[t >= first].max()) if np.any(t >= first) else 0.0,
        "p_min": float(p.min()), "p_max": float(p.max()),
        "max_p_excursion": float(np.max(np.abs(p - fam.p_d))),
        "tau_max": float(tau.max()),
        "tau_dot_min": float(taud.min()), "tau_dot_max": float(taud.max()),
        # the observer's |force estimate| over the run [N] (without a push: noise, model error, contact chatter)
        "force_estimate_abs_p50": float(np.percentile(np.abs([s.force_estimate for s in st]), 50)) if st else 0.0,
        "force_estimate_abs_p95": float(np.percentile(np.abs([s.force_estimate for s in st]), 95)) if st else 0.0,
        "force_estimate_abs_max": float(np.max(np.abs([s.force_estimate for s in st]))) if st else 0.0,
        "max_tau_dot_excursion": float(np.max(np.abs(taud - 1.0))),
        "max_abs_l": float(np.max(np.abs(cop[ok]))) if np.any(ok) else math.nan,
        "l_at_fall": float(rec[-1].cop) if result.fallen else None,
        "final_p": float(p[-1]), "final_tau_dot": float(taud[-1]),
        "max_abs_lambda": float(np.max(np.abs([s.lam for s in st]))) if st else 0.0,
        "final_lambda": float(st[-1].lam) if st else 0.0,
        "impact_times": impacts,
        "step_durations": [float(b - a) for a, b in zip([0.0] + impacts[:-1], impacts)],
        "qp_status_counts": qp_counts,
    }
    if push_end is not None:
        out["impacts_after_push"] = int(sum(1 for x in impacts if x >= push_end))
    return out


def _outcome(result) -> dict:
    """The plant's outcome of a run (either result kind): steps walked, the fall (cause, detail, time [s] or
    None) and the simulated time [s]."""
    rec = result.records
    return {
        "steps_walked": int(result.steps_walked),
        "fallen": bool(result.fallen),
        "fall_cause": result.fall_cause,
        "fall_detail": result.fall_detail,
        "fall_time": None if math.isnan(result.fall_time) else float(result.fall_time),
        "sim_time": float(rec[-1].t_end) if rec else 0.0,
    }

def _reduce(f, x: np.ndarray) -> float:
    """``f`` over the finite values of ``x``; NaN when there is none (a key the controller does not report)."""
    x = x[np.isfinite(x)]
    return float(f(x)) if x.size else math.nan


def summarize_reported(result, family: GaitFamily | None = None, push_end: float | None = None) -> dict:
    """:func:`summarize`'s numbers of a run of any interface controller (``plugin.result.RunResult``):
    the plant's (steps, fall, sim time, CoP l [m], impact times, step durations [s]) and, from the status keys
    the controller reports, ``max_tracking_error`` [rad], ``p`` [m], ``tau`` [s], ``tau_dot`` [-],
    ``force_estimate`` [N] and ``lam`` [rad]; a key it does not report is NaN (null in JSON). ``fault``: the
    controller fault that ended the run (its message; None without one); ``qp_status_counts`` is empty
    (the adaptive controller's QP)."""
    fam = family if family is not None else context().family
    rec = result.records
    p, tau, taud = result.series("p"), result.series("tau"), result.series("tau_dot")
    err, est, lam = result.series("max_tracking_error"), result.series("force_estimate"), result.series("lam")
    t = np.array([r.t for r in rec])
    cop = np.array([r.cop for r in rec])
    ok = np.isfinite(cop) & ~np.array([r.fallen for r in rec], dtype=bool)
    impacts = [float(i.t) for i in result.impacts]
    first = impacts[0] if impacts else math.inf

    def last(x: np.ndarray) -> float:
        return float(x[-1]) if x.size else math.nan
    out = {
        **_outcome(result),
        "max_tracking_error": _reduce(np.max, err),
        "max_tracking_error_before_first_impact": _reduce(np.max, err[t < first]) if err.size else math.nan,
        "max_tracking_error_after_first_impact": _reduce(np.max, err[t >= first]) if err.size else math.nan,
        "p_min": _reduce(np.min, p), "p_max": _reduce(np.max, p),
        "max_p_excursion": _reduce(np.max, np.abs(p - fam.p_d)),
        "tau_max": _reduce(np.max, tau),
        "tau_dot_min": _reduce(np.min, taud), "tau_dot_max": _reduce(np.max, taud),
        "force_estimate_abs_p50": _reduce(lambda x: np.percentile(x, 50), np.abs(est)),
        "force_estimate_abs_p95": _reduce(lambda x: np.percentile(x, 95), np.abs(est)),
        "force_estimate_abs_max": _reduce(np.max, np.abs(est)),
        "max_tau_dot_excursion": _reduce(np.max, np.abs(taud - 1.0)),
        "max_abs_l": float(np.max(np.abs(cop[ok]))) if np.any(ok) else math.nan,
        "l_at_fall": float(rec[-1].cop) if result.fallen and rec else None,
        "final_p": last(p), "final_tau_dot": last(taud),
        "max_abs_lambda": _reduce(np.max, np.abs(lam)), "final_lambda": last(lam),
        "impact_times": impacts,
        "step_durations": [float(b - a) for a, b in zip([0.0] + impacts[:-1], impacts)],
        "qp_status_counts": {},
        "fault": None if result.fault is None else str(result.fault),
    }
    if push_end is not None:
        out["impacts_after_push"] = int(sum(1 for x in impacts if x >= push_end))
    return out
