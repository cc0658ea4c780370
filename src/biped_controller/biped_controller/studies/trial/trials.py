"""One survival trial: a pushed run, ended early once decided (:mod:`.stop`), judged by the survival rule
(:mod:`.survival`) with the band of its unpushed walk."""
from __future__ import annotations

import math

from biped_sim.plant.push import Push

from biped_controller.studies import runner
from biped_controller.studies.trial import runs, stop
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings
from biped_controller.studies.trial.survival import Band, survival_rule


def band(mode: str, push: Push, settings: RunSettings) -> Band:
    """The survival rule's band for a trial of ``push`` in ``mode`` with ``settings``: the unpushed walk's of
    the same impacts (``runs.trial_steps``), computed once per process."""
    return survival_rule().band(mode, settings, runs.trial_steps(push))


def survives(push: Push, mode: str, settings: RunSettings = DEFAULT_SETTINGS,
             pool: runner.LoopPool | None | bool = True) -> dict:
    """One survival trial of ``push`` (JSON-ready): force, survived, reason, and a few numbers. With the
    early stop (``config/studies.yaml``, unless ``settings.full_trials`` or a perturbed plant) the trial
    ends at the first impact where its outcome is decided (``stop.EarlyStop``): survived,
    ``decided_at_step`` = the impacts walked by then; otherwise ``decided_at_step`` is None (the trial ran
    in full). ``fell``: the plant's fall before the end (the no-fall edge's outcome). ``pool`` True: this process's
    ``runs.loop_pool`` (the loop and the walk up to the push reused, the outcome bit-identical); a
    ``runner.LoopPool``; None or False: a new plant and controller, walked from t = 0."""
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
            "steps_walked": int(res.steps_walked), "decided_at_step": int(res.steps_walked) if decided else None}
