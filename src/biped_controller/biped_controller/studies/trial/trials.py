"""One survival trial: a pushed run, ended early once decided (:mod:`.stop`), judged by the survival rule
(:mod:`.survival`) with the band of its unpushed walk."""
from __future__ import annotations

import functools
import math
from dataclasses import replace

from biped_sim.plant.push import Push

from biped_controller.core.control.controller import MODES
from biped_controller.studies import runner
from biped_controller.studies.trial import plugin_trials, runs, stop
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings, _config_stamp
from biped_controller.studies.trial.survival import Band, SurvivalRule, survival_rule


def band(mode: str, push: Push, settings: RunSettings) -> Band:
    """The survival rule's band for a trial of ``push`` in ``mode`` with ``settings``: the unpushed walk's of
    the same impacts (``runs.trial_steps``), computed once per process."""
    return walk_band(mode, settings, runs.trial_steps(push))


def walk_band(mode: str, settings: RunSettings, steps: int) -> Band:
    """The band of a trial of ``steps`` impacts in ``mode`` (a built-in mode or a plug-in controller's name)
    with ``settings`` (plant, profile, perturbation): its unpushed walk, run once per process
    (``SurvivalRule.band_from_walk``; a plug-in's: ``plugin_trials.plugin_band``)."""
    if mode not in MODES:
        return plugin_trials.plugin_band(mode, settings, int(steps))
    return _walk_band(survival_rule(), mode, replace(settings, full_trials=False), int(steps), _config_stamp())


@functools.lru_cache(maxsize=256)
def _walk_band(rule: SurvivalRule, mode: str, settings: RunSettings, steps: int, stamp: tuple) -> Band:
    return rule.band_from_walk(runs.run(steps, mode, (), settings=settings, keep_records=True))


def survives(push: Push, mode: str, settings: RunSettings = DEFAULT_SETTINGS,
             pool: runner.LoopPool | None | bool = True) -> dict:
    """One survival trial of ``push`` (JSON-ready): force, survived, reason, and a few numbers. With the
    early stop (``config/studies.yaml``, unless ``settings.full_trials`` or a perturbed plant) the trial
    ends at the first impact where its outcome is decided (``stop.EarlyStop``): survived,
    ``decided_at_step`` = the impacts walked by then; otherwise ``decided_at_step`` is None (the trial ran
    in full). ``fell``: the plant's fall before the end (the no-fall edge's outcome). ``pool`` True: this process's
    ``runs.loop_pool`` (the loop and the walk up to the push reused, the outcome bit-identical); a
    ``runner.LoopPool``; None or False: a new plant and controller, walked from t = 0.

    A ``mode`` that is not one of the adaptive controller's modes names a plug-in controller
    (``plugin.registry``, resolved in this process): its trial is ``trial.plugin_trials.survives_push`` (run in
    full, the same rule; a controller fault is that trial's outcome)."""
    if mode not in MODES:
        return plugin_trials.survives_push(push, mode, settings)
    end = push.start + push.duration
    if pool is True:
        pool = runs.loop_pool()
    elif pool is False:
        pool = None
    on_impact = None
    fired: list[int] = []
    es = None if settings.full_trials else stop.early_stop()
    if es is not None and es.enabled and stop.applies(settings):
        fam = context().family

        def stop_if_decided(sim, ctrl) -> bool:
            if es.decided(sim, ctrl, end, fam):
                fired.append(sim.impact_count)
                return True
            return False
        on_impact = stop_if_decided
    res = runs.push_run(push, mode, settings=settings, keep_records=False, on_impact=on_impact, pool=pool)
    decided = bool(fired) and not res.fallen
    if decided:
        ok, fell, why = True, False, "survived"
    else:
        v = survival_rule().verdict(res, end, band(mode, push, settings))
        ok, fell, why = v.survived, v.fell, v.reason
    return {"force": float(push.force), "mode": mode, "survived": ok, "fell": fell, "reason": why,
            "fall_cause": res.fall_cause, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
            "steps_walked": int(res.steps_walked), "decided_at_step": int(res.steps_walked) if decided else None,
            **parameter_excursion(res)}


def parameter_excursion(res: runner.RunResult) -> dict:
    """The run's parameter excursion (JSON-ready): ``max_abs_p_minus_pd`` [m], the largest |p - p_d| of the
    controller's committed p, ``min_p``, ``max_p`` [m] its extremes, and ``min_tau_dot``, ``max_tau_dot`` [-],
    the extremes of its tau' (at every decision from t = 0 to the run's end, early stop included; NaN when
    one was NaN). The valid range: p in the family's [p_min, p_max], tau' >= tau_dot_min
    (``config/controller.yaml``; :func:`out_of_range`)."""
    p_lo, p_hi, td_lo, td_hi = res.param_range
    p_d = context().family.p_d
    return {"max_abs_p_minus_pd": max(abs(p_hi - p_d), abs(p_lo - p_d)), "min_p": p_lo, "max_p": p_hi,
            "min_tau_dot": td_lo, "max_tau_dot": td_hi}


#: [m for p, - for tau'] how far past a bound a committed value may lie and still be on it: an active range row
#: (the QP's or the hold's) puts p + p' dt + p'' dt^2 / 2 on the bound up to the rounding of that sum
#: (measured: up to 2.9e-15 past tau_dot_min in results/parameter_range/mujoco_slice.json)
RANGE_TOL = 1e-12


def out_of_range(rec: dict, p_min: float, p_max: float, tau_dot_min: float) -> str:
    """What of a record's parameter excursion (:func:`parameter_excursion`'s fields) leaves the valid range
    p in [p_min, p_max] [m], tau' >= tau_dot_min [-], each to :data:`RANGE_TOL` ("" when nothing; a NaN counts as
    leaving it; a record without them, or with null ones, says so)."""
    if any(rec.get(k) is None for k in ("min_p", "max_p", "min_tau_dot")):
        return "parameter excursion not recorded"
    bad = []
    lo, hi, td = rec.get("min_p", math.nan), rec.get("max_p", math.nan), rec.get("min_tau_dot", math.nan)
    if not lo >= p_min - RANGE_TOL:
        bad.append(f"p = {lo!r} < p_min = {p_min!r}")
    if not hi <= p_max + RANGE_TOL:
        bad.append(f"p = {hi!r} > p_max = {p_max!r}")
    if not td >= tau_dot_min - RANGE_TOL:
        bad.append(f"tau' = {td!r} < tau_dot_min = {tau_dot_min!r}")
    return "; ".join(bad)
