"""One survival trial: a pushed run, ended early once decided (:mod:`.stop`), judged by the survival rule
(:mod:`.survival`)."""
from __future__ import annotations

import functools
import math

from biped_sim.plant.push import Push

from biped_controller.core.control.controller import MODES
from biped_controller.studies import runner
from biped_controller.studies.trial import runs, stop
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings
from biped_controller.studies.trial.survival import model_error, noisy_sensing, survival


@functools.lru_cache(maxsize=32)
def reference_p(mode: str, steps: int, settings: RunSettings) -> float:
    """p [m] at the end of the unpushed walk of ``steps`` impacts with ``settings`` (the survival rule's
    reference under model error); NaN when that walk falls."""
    res = runs.run(steps, mode, (), settings=settings, keep_records=False)
    return math.nan if res.fallen else float(res.statuses[-1].p)


def p_reference(mode: str, push: Push, settings: RunSettings) -> float | None:
    """The survival rule's p reference for a trial of ``push``: the unpushed walk's (:func:`reference_p`,
    same number of impacts) under model error, None (p_d) otherwise."""
    if not model_error(settings):
        return None
    if mode not in MODES:
        from biped_controller.plugin.study import reference_p as plugin_reference_p
        return plugin_reference_p(mode, runs.trial_steps(push), settings)
    return reference_p(mode, runs.trial_steps(push), settings)


def survives(push: Push, mode: str, settings: RunSettings = DEFAULT_SETTINGS,
             pool: runner.LoopPool | None | bool = True) -> dict:
    """One survival trial of ``push`` (JSON-ready): force, survived, reason, and a few numbers. With the
    early stop (``config/studies.yaml``, unless ``settings.full_trials`` or a perturbed plant) the trial
    ends at the first impact where its outcome is decided (``stop.EarlyStop``): survived,
    ``decided_at_step`` = the impacts walked by then; otherwise ``decided_at_step`` is None (the trial ran
    in full). Under sensor noise survival uses the noise band. ``pool`` True: this process's
    ``runs.loop_pool`` (the loop and the walk up to the push reused, the outcome bit-identical); a
    ``runner.LoopPool``; None or False: a new plant and controller, walked from t = 0.

    A ``mode`` that is not one of the adaptive controller's modes names a plug-in controller
    (``plugin.registry``, resolved in this process): its trial is ``plugin.study.survives_push`` (run in
    full, the same rule; a controller fault is that trial's outcome)."""
    if mode not in MODES:
        from biped_controller.plugin.study import survives_push
        return survives_push(push, mode, settings)
    end = push.start + push.duration
    if pool is True:
        pool = runs.loop_pool()
    elif pool is False:
        pool = None
    on_impact = None
    fired: list[int] = []
    es = None if settings.full_trials else stop.early_stop()
    if es is not None and es.enabled and (settings.perturbation is None or settings.perturbation.is_zero):
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
        ok, why = True, "survived"
    else:
        ok, why = survival(res, end, noisy=noisy_sensing(settings), p_ref=p_reference(mode, push, settings))
    return {"force": float(push.force), "mode": mode, "survived": ok, "reason": why,
            "fall_cause": res.fall_cause, "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
            "steps_walked": int(res.steps_walked), "decided_at_step": int(res.steps_walked) if decided else None}
