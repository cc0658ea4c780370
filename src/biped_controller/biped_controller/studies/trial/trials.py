"""One survival trial: a pushed run, ended early once decided (:mod:`.stop`), judged by the survival rule
(:mod:`.survival`) with the band of its unpushed walk; of any controller, through its
:class:`~.controller.TrialController` (:func:`.controller.resolve`: a built-in mode on the compiled path,
any other registered controller through the generic loop)."""
from __future__ import annotations

import math

from biped_sim.plant.push import Push

from biped_controller.closed_loop import runner
from biped_controller.studies.trial import record, runs
from biped_controller.studies.trial.controller import parameter_excursion, resolve
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings
from biped_controller.studies.trial.survival import Band

__all__ = ["band", "give_band", "walk_band", "survives", "parameter_excursion", "out_of_range", "RANGE_TOL"]


def band(mode: str, push: Push, settings: RunSettings) -> Band:
    """The survival rule's band for a trial of ``push`` by the controller ``mode`` with ``settings``: the
    unpushed walk's of the same impacts (``runs.trial_steps``), computed once per process."""
    settings.activate()
    return walk_band(mode, settings, runs.trial_steps(push))


def give_band(mode: str, push: Push, settings: RunSettings, band: Band) -> None:
    """Hand this process the band :func:`band` returns for (``mode``, ``push``, ``settings``), computed in
    another process (``TrialController.give_band``): its unpushed walk is then not run here."""
    settings.activate()
    resolve(mode).give_band(settings, runs.trial_steps(push), band)


def walk_band(mode: str, settings: RunSettings, steps: int) -> Band:
    """The band of a trial of ``steps`` impacts by the controller ``mode`` (a built-in mode or any registered
    controller's name) with ``settings`` (plant, profile, perturbation): its unpushed walk, run once per
    process (``TrialController.band``)."""
    return resolve(mode).band(settings, int(steps))


def survives(push: Push, mode: str, settings: RunSettings = DEFAULT_SETTINGS,
             pool: runner.LoopPool | None | bool = True) -> dict:
    """One survival trial of ``push`` by the controller ``mode`` (JSON-ready): force, survived, reason, and a
    few numbers (``TrialController.survives``). A built-in mode's, with the early stop
    (``config/studies.yaml``, unless ``settings.full_trials`` or a perturbed plant), ends at the first impact
    where its outcome is decided (``stop.EarlyStop``): survived, ``decided_at_step`` = the impacts walked by
    then; otherwise ``decided_at_step`` is None (the trial ran in full). ``fell``: the plant's fall before
    the end (the no-fall edge's outcome). ``pool`` True: this process's ``runs.loop_pool`` (the loop and
    the walk up to the push reused, the outcome bit-identical); a ``runner.LoopPool``; None or False: a new
    plant and controller, walked from t = 0. Any other controller's trial runs in full through the generic
    loop (a controller fault is that trial's outcome, recorded as ``fault``). Every record also carries the
    trial record's ``seed`` and ``fault_kind`` (:mod:`.record`)."""
    settings.activate()
    rec = resolve(mode).survives(push, settings, pool)
    rec["seed"] = record.seed_of(settings.perturbation)
    rec["fault_kind"] = record.fault_kind_of(rec.get("fault"))
    return rec


#: [m for p, - for tau'] how far past a bound a committed value may lie and still be on it: an active range row
#: (the QP's or the hold's) puts p + p' dt + p'' dt^2 / 2 on the bound up to the rounding of that sum
#: (measured: up to 2.9e-15 past tau_dot_min in results/parameter_range/mujoco_slice.json)
RANGE_TOL = 1e-12


def out_of_range(rec: dict, p_min: float, p_max: float, tau_dot_min: float, tau_dot_max: float) -> str:
    """What of a record's parameter excursion (:func:`parameter_excursion`'s fields) leaves the valid range
    p in [p_min, p_max] [m], tau' in [tau_dot_min, tau_dot_max] [-], each to :data:`RANGE_TOL` ("" when nothing;
    a NaN counts as leaving it; a record without them, or with null ones, says so)."""
    if any(rec.get(k) is None for k in ("min_p", "max_p", "min_tau_dot", "max_tau_dot")):
        return "parameter excursion not recorded"
    bad = []
    lo, hi = rec.get("min_p", math.nan), rec.get("max_p", math.nan)
    td, tu = rec.get("min_tau_dot", math.nan), rec.get("max_tau_dot", math.nan)
    if not lo >= p_min - RANGE_TOL:
        bad.append(f"p = {lo!r} < p_min = {p_min!r}")
    if not hi <= p_max + RANGE_TOL:
        bad.append(f"p = {hi!r} > p_max = {p_max!r}")
    if not td >= tau_dot_min - RANGE_TOL:
        bad.append(f"tau' = {td!r} < tau_dot_min = {tau_dot_min!r}")
    if not tu <= tau_dot_max + RANGE_TOL:
        bad.append(f"tau' = {tu!r} > tau_dot_max = {tau_dot_max!r}")
    return "; ".join(bad)
