"""One path for every controller in the studies: :func:`resolve` turns a controller's name into the one
object the studies call, whatever the controller is.

Every name goes through the controller interface's registry (``plugin.registry.load_controller``: a built-in
mode of the adaptive controller -- ``none``, ``tau``, ``p``, ``both``, ``wbc``, ``hybrid``, ``lambda``,
``all`` -- first, then a ``biped.controllers`` entry point, then ``module:Class``). :func:`resolve` checks it
once, here (an unknown name, a class that cannot be imported or that does not satisfy the interface raises
one of :data:`RESOLVE_ERRORS`, the message naming it) and returns a :class:`TrialController`:

* ``walk(steps, settings, pushes)``: one closed-loop run with a run's settings (plant, profile,
  perturbation), records kept or not;
* ``band(settings, steps)``: the survival rule's band of a trial of ``steps`` impacts (``trial.survival``),
  from the controller's own unpushed walk, once per process;
* ``verdict(result, push_end, band)``: the one survival rule on a run;
* ``survives(push, settings, pool)``: one survival trial, the record every study stores;
* ``summary(result, push_end)``: the numbers of one run (``trial.summary``).

How a class is run is its own: a class that declares the compiled closed loop (``plugin.builtin.compiled_mode``:
the built-in modes' classes, whichever name reached them) is :class:`BuiltinMode`, its trials on the studies'
compiled fast path (``runner.run``: the compiled loop -- the same records as the class through the generic
loop, bit for bit --, the reused loop pool, the early stop of a decided trial), so its trials are
bit-identical to those of ``runner.run`` (the fingerprints). Any other class is :class:`PluginController`: the
generic in-process loop (``plugin.loop``) with its interface, run in full (the early stop reads the adaptive
controller's parameters), a controller fault being that trial's outcome. The same survival rule judges both:
the band is the controller's own unpushed walk's excursion of the ``p`` [m] and ``tau_dot`` [-] it reports
(none reported: the floors).
"""
from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from dataclasses import replace

from biped_sim.plant.push import Push

from biped_controller.core.control.config import MODES
from biped_controller.plugin.builtin import compiled_mode
from biped_controller.plugin.interface import InterfaceError
from biped_controller.plugin.result import RunResult
from biped_controller.plugin.registry import ControllerLoadError, UnknownControllerError, load_controller
from biped_controller.closed_loop import runner
from biped_controller.studies.trial import plugin_trials, runs, stop
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings, _config_stamp
from biped_controller.studies.trial.summary import summarize, summarize_reported
from biped_controller.studies.trial.survival import Band, SurvivalRule, Verdict, survival_rule

#: what :func:`resolve` raises for a name it cannot use (each message names it)
RESOLVE_ERRORS = (UnknownControllerError, ControllerLoadError, InterfaceError)


def parameter_excursion(res: runner.RunResult) -> dict:
    """The run's parameter excursion (JSON-ready): ``max_abs_p_minus_pd`` [m], the largest |p - p_d| of the
    controller's committed p, ``min_p``, ``max_p`` [m] its extremes, and ``min_tau_dot``, ``max_tau_dot`` [-],
    the extremes of its tau' (at every decision from t = 0 to the run's end, early stop included; NaN when
    one was NaN). The valid range: p in the family's [p_min, p_max], tau' in [tau_dot_min, tau_dot_max]
    (``config/controller.yaml``; ``trials.out_of_range``)."""
    p_lo, p_hi, td_lo, td_hi = res.param_range
    p_d = context().family.p_d
    return {"max_abs_p_minus_pd": max(abs(p_hi - p_d), abs(p_lo - p_d)), "min_p": p_lo, "max_p": p_hi,
            "min_tau_dot": td_lo, "max_tau_dot": td_hi}


class TrialController(ABC):
    """A controller as the studies call it (module docstring). ``name``: the name it was resolved from;
    ``adaptive``: it is the adaptive controller (its full status, the disturbance observer, the QP, the
    torque law at the integration rate); ``uses_observer``: the ``disturbance_observer`` setting changes
    its runs."""

    name: str = ""
    adaptive: bool = False
    uses_observer: bool = False

    @abstractmethod
    def walk(self, steps: int, settings: RunSettings = DEFAULT_SETTINGS, pushes: tuple[Push, ...] = (), *,
             keep_records: bool = True, integration_rate: bool = False) -> RunResult:
        """One run of ``steps`` impacts with ``settings`` and ``pushes`` (``keep_records`` False: the outcome
        and the last period only)."""

    @abstractmethod
    def band(self, settings: RunSettings, steps: int) -> Band:
        """The survival band of a trial of ``steps`` impacts with ``settings`` (the unpushed walk's)."""

    @abstractmethod
    def verdict(self, result, push_end: float, band: Band) -> Verdict:
        """The survival rule on ``result``, a run pushed until ``push_end`` [s], with ``band``."""

    @abstractmethod
    def survives(self, push: Push, settings: RunSettings = DEFAULT_SETTINGS,
                 pool: runner.LoopPool | None | bool = True) -> dict:
        """One survival trial of ``push`` (JSON-ready: force, mode, survived, fell, reason, fall cause and
        time, steps walked, decided_at_step)."""

    def give_band(self, settings: RunSettings, steps: int, band: Band) -> None:
        """Hand this process a band computed elsewhere (``BuiltinMode.give_band``); by default ignored (the
        controller computes its own)."""

    @abstractmethod
    def summary(self, result, push_end: float | None = None) -> dict:
        """The numbers of one run (``trial.summary``; the same keys for every controller)."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class BuiltinMode(TrialController):
    """A built-in mode (a class with ``plugin.builtin.compiled_mode``): ``runner.run`` (the compiled loop, the
    loop pool, the early stop)."""

    adaptive = True

    def __init__(self, mode: str):
        if mode not in MODES:
            raise UnknownControllerError(f"{mode!r} is not a built-in mode ({', '.join(MODES)})")
        self.name = mode
        self.uses_observer = mode != "none"        # mode none's torque never uses the estimate

    def walk(self, steps: int, settings: RunSettings = DEFAULT_SETTINGS, pushes: tuple[Push, ...] = (), *,
             keep_records: bool = True, integration_rate: bool = False) -> runner.RunResult:
        """``runs.run``: ``runner.run`` with the settings (the compiled loop where it applies)."""
        return runs.run(int(steps), self.name, tuple(pushes), settings=settings, keep_records=keep_records,
                        integration_rate=integration_rate)

    def band(self, settings: RunSettings, steps: int) -> Band:
        """``SurvivalRule.band_from_walk`` of the unpushed walk, once per process (settings, impacts, the
        config files' modification times), or the band :meth:`give_band` handed this process for them."""
        settings.activate()
        key = (survival_rule(), self.name, replace(settings, full_trials=False), int(steps), _config_stamp())
        given = _GIVEN_BANDS.get(key)
        if given is not None:
            return given
        return _walk_band(*key)

    def give_band(self, settings: RunSettings, steps: int, band: Band) -> None:
        """Hand this process the band of (``settings``, ``steps``) computed elsewhere by :meth:`band` (another
        worker of the same code and config files: the walk is a pure function of them), so that its walk is
        not run again here. The last :data:`GIVEN_BANDS_KEPT` bands are kept."""
        settings.activate()
        key = (survival_rule(), self.name, replace(settings, full_trials=False), int(steps), _config_stamp())
        if len(_GIVEN_BANDS) >= GIVEN_BANDS_KEPT:
            del _GIVEN_BANDS[next(iter(_GIVEN_BANDS))]
        _GIVEN_BANDS[key] = band

    def verdict(self, result: runner.RunResult, push_end: float, band: Band) -> Verdict:
        return survival_rule().verdict(result, push_end, band)

    def survives(self, push: Push, settings: RunSettings = DEFAULT_SETTINGS,
                 pool: runner.LoopPool | None | bool = True) -> dict:
        """One survival trial (``trials.survives``): with the early stop (``config/studies.yaml``, unless
        ``settings.full_trials`` or a perturbed plant) the trial ends at the first impact where its outcome is
        decided (``stop.EarlyStop`` on the rigid plant, ``stop.MujocoEarlyStop`` on MuJoCo, there also under
        sensor noise where ``stop.applies_mujoco_sensors`` for this mode and the seed's unpushed walk walked);
        ``pool`` True:
        this process's ``runs.loop_pool``."""
        settings.activate()
        mode = self.name
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
        mj = None if settings.full_trials else stop.mujoco_early_stop()
        noisy = stop.applies_mujoco_sensors(settings, mode)
        if mj is not None and mj.enabled and (stop.applies_mujoco(settings) or noisy):
            fam, dt = context().family, settings.sim_config().control_period
            band = self.band(settings, runs.trial_steps(push))      # the trial's band, known before it

            def stop_if_decided_mujoco(sim, ctrl) -> bool:
                if mj.decided(sim, ctrl, end, fam, band, dt):
                    fired.append(sim.impact_count)
                    return True
                return False
            if not (noisy and band.unpushed_fall):      # under noise: only where the seed's own walk walks
                on_impact = stop_if_decided_mujoco
        res = runs.push_run(push, mode, settings=settings, keep_records=False, on_impact=on_impact, pool=pool)
        decided = bool(fired) and not res.fallen
        if decided:
            ok, fell, why = True, False, "survived"
        else:
            v = self.verdict(res, end, self.band(settings, runs.trial_steps(push)))
            ok, fell, why = v.survived, v.fell, v.reason
        return {"force": float(push.force), "mode": mode, "survived": ok, "fell": fell, "reason": why,
                "fall_cause": res.fall_cause,
                "fall_time": None if math.isnan(res.fall_time) else float(res.fall_time),
                "steps_walked": int(res.steps_walked), "decided_at_step": int(res.steps_walked) if decided else None,
                **parameter_excursion(res)}

    def summary(self, result: runner.RunResult, push_end: float | None = None) -> dict:
        return summarize(result, push_end=push_end)


#: how many handed bands (:meth:`BuiltinMode.give_band`) a process keeps: a seeded cell's seeds x modes, and more
GIVEN_BANDS_KEPT = 256
_GIVEN_BANDS: dict[tuple, Band] = {}


@functools.lru_cache(maxsize=256)
def _walk_band(rule: SurvivalRule, mode: str, settings: RunSettings, steps: int, stamp: tuple) -> Band:
    return rule.band_from_walk(runs.run(steps, mode, (), settings=settings, keep_records=True))


class PluginController(TrialController):
    """Any other registered controller: the in-process loop of ``plugin.loop`` (``trial.plugin_trials``),
    its trials run in full."""

    def __init__(self, name: str):
        load_controller(name)           # an unknown or unusable name raises here, naming it (cached by the import)
        self.name = name

    def walk(self, steps: int, settings: RunSettings = DEFAULT_SETTINGS, pushes: tuple[Push, ...] = (), *,
             keep_records: bool = True, integration_rate: bool = False) -> RunResult:
        """``PluginLoop.run`` of this process's loop for ``settings`` (``plugin_trials.trials_for``). The
        loop holds torques over the control period: ``integration_rate`` is the adaptive controller's."""
        settings.activate()
        if integration_rate:
            raise ValueError(f"controller {self.name!r}: the torque law at the integration rate is the adaptive "
                             f"controller's (a plug-in's torque is held over the control period)")
        return plugin_trials.trials_for(self.name, settings).loop.run(int(steps), tuple(pushes),
                                                                      keep_records=keep_records)

    def band(self, settings: RunSettings, steps: int) -> Band:
        return plugin_trials.plugin_band(self.name, settings, int(steps))

    def verdict(self, result: RunResult, push_end: float, band: Band) -> Verdict:
        return Verdict(*plugin_trials.survival(result, push_end, band))

    def survives(self, push: Push, settings: RunSettings = DEFAULT_SETTINGS,
                 pool: runner.LoopPool | None | bool = True) -> dict:
        """``plugin_trials.survives_push`` (the loop of this process reused; ``pool`` is the compiled path's)."""
        return plugin_trials.survives_push(push, self.name, settings)

    def summary(self, result: RunResult, push_end: float | None = None) -> dict:
        return summarize_reported(result, push_end=push_end)


@functools.lru_cache(maxsize=64)
def resolve(name: str) -> TrialController:
    """The :class:`TrialController` of ``name`` (module docstring), once per process: the registry's class for
    ``name``; a class that declares the compiled closed loop resolves to its mode's :class:`BuiltinMode` (the
    same object for the mode's name and its ``module:Class``). Raises one of :data:`RESOLVE_ERRORS`, the
    message naming ``name``."""
    if not isinstance(name, str) or not name:
        raise UnknownControllerError(f"a controller name must be a non-empty string, got {name!r}")
    mode = compiled_mode(load_controller(name))
    if mode is None:
        return PluginController(name)
    return BuiltinMode(mode) if mode == name else resolve(mode)
