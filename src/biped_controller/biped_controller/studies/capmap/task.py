"""What one simulation of the map is (the pure task function every executor runs) and its record."""
from __future__ import annotations

import math
from typing import Callable, Mapping, Sequence

from biped_sim.plant.push import Push

from biped_controller.closed_loop import runner
from biped_controller.studies.capmap.spec import DIRECTIONS, MapError, SimSpec, onset_time
from biped_controller.studies.trial import trials
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.settings import DEFAULT_SETTINGS, RunSettings

#: the parameter excursion each record carries (``trials.parameter_excursion``)
EXCURSION_FIELDS = ("max_abs_p_minus_pd", "min_p", "max_p", "min_tau_dot", "max_tau_dot")


def worker_init() -> None:
    """Run once in each worker process: load the description, family and settings once."""
    context()


def failure_cause(trial: Mapping) -> str:
    """The cause of a failed trial of ``trials.survives``: the simulator's fall cause when it fell,
    otherwise which part of the survival rule (``trial.survival``) failed (``p_not_back``, ``tau_dot_not_back``,
    ``time_limit``) or ``controller_fault`` (a plug-in controller's result the plant cannot apply); ``""`` when it survived."""
    if trial["survived"]:
        return ""
    if trial.get("fall_cause"):
        return str(trial["fall_cause"])
    reason = str(trial["reason"])
    if reason.startswith("p ="):
        return "p_not_back"
    if reason.startswith("tau'"):
        return "tau_dot_not_back"
    if reason.startswith("only"):
        return "time_limit"
    if reason.startswith("controller fault"):
        return "controller_fault"
    raise MapError(f"unrecognised failure reason from the survival rule: {reason!r}")


def simulate(spec: SimSpec, settings: RunSettings = DEFAULT_SETTINGS, height: float | None = None,
             pool: runner.LoopPool | bool = True) -> dict:
    """One simulation (the pure task function): ``trials.survives`` with the push of ``spec``; the
    record (JSON-ready, deterministic: the same spec gives the same record in any process, on new objects
    or on a worker's objects after any other trials: tests/test_history.py). ``pool``: ``trials.survives``'s
    (True: this process's loop pool, as the map's workers run)."""
    c = spec.cell
    T = context(settings.activate().robot).family.T
    start = onset_time(c.phase, T)
    signed = DIRECTIONS[c.direction] * spec.force
    trial = trials.survives(Push(start, c.duration, float(signed), height), c.mode, settings, pool)
    return {
        "mode": c.mode, "direction": c.direction, "phase": c.phase, "duration": c.duration,
        "force": spec.force, "start": start, "signed_force": signed, "height": height,
        "survived": bool(trial["survived"]), "reason": trial["reason"], "cause": failure_cause(trial),
        "fall_time": trial["fall_time"], "steps_walked": int(trial["steps_walked"]),
        "decided_at_step": trial.get("decided_at_step"),
        # the trial record's seed (null: nothing random drawn) and fault kind (null: no controller fault;
        # ``trial.record``), outside the record's key and the store's fingerprint; null when the trial function
        # does not report them
        "seed": trial.get("seed"), "fault_kind": trial.get("fault_kind"),
        # the controller's parameter excursion over the trial (``trials.parameter_excursion``); null when the
        # trial function does not report it or it was NaN (the store is strict JSON), which
        # ``trials.out_of_range`` reports as not recorded
        **{k: _finite_or_none(trial.get(k)) for k in EXCURSION_FIELDS},
    }


def _finite_or_none(v) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def simulate_batch(batch: Sequence[SimSpec], settings: RunSettings = DEFAULT_SETTINGS,
                   height: float | None = None) -> list[dict]:
    """The unit of work of every executor: :func:`simulate` on each spec, in order."""
    return [simulate(s, settings, height) for s in batch]


TaskFn = Callable[[Sequence[SimSpec], RunSettings, "float | None"], list]


def record_key(rec: Mapping) -> tuple:
    return (rec["mode"], rec["direction"], float(rec["phase"]), float(rec["duration"]), float(rec["force"]))
