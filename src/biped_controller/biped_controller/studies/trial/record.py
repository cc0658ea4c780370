"""The fields every survival-trial record carries beside its outcome, whoever stores it (the max-push
table's ``trials``, the capability map's and the robustness table's JSON Lines stores):

* ``seed``: the integer that seeds the trial's random draws, or None (null) when the trial draws none.
  Today the only random draw is the plant's sensor noise (``PlantPerturbation.seed``: ``numpy.random.
  default_rng(seed)``), so ``seed`` is that seed when the settings put noise on the sensors
  (``PlantPerturbation.changed`` lists it then) and None for a deterministic profile.
* ``fault_kind``: None when the controller applied a torque every period, else the kind of the
  ``plugin.interface.ControllerFault`` that ended the trial (one of ``interface.FAULT_KINDS``). A faulted
  trial is neither a survival nor a fall: no torque was applied from the fault on, so whether the robot
  would have fallen is unknown.

Records written before these fields existed lack them: :func:`complete` fills them when a record is read
back (``seed`` None: no store of that time holds a noisy trial's seed, a noisy profile's records are told
apart by the store's fingerprint; ``fault_kind`` from the reason text of a ``controller fault`` record,
which names the kind). Neither field enters a record's key or a store's fingerprint, so a store resumes
across the change.
"""
from __future__ import annotations

from typing import Mapping

from biped_sim.plant.perturbation import PlantPerturbation

from biped_controller.plugin.interface import FAULT_KINDS, ControllerFault

#: the record fields this module defines
RECORD_FIELDS = ("seed", "fault_kind")

#: the reason text of a faulted trial starts with this (``plugin_trials.survival``)
FAULT_REASON = "controller fault: "


class TrialRecordError(ValueError):
    """A record's ``seed`` or ``fault_kind`` is not of its type (the message names the field and value)."""


def seed_of(pert: PlantPerturbation | None) -> int | None:
    """The seed of a trial on a plant perturbed by ``pert`` (a run's ``RunSettings.perturbation``): its
    noise seed when its sensors are noisy, else None (nothing random is drawn)."""
    if pert is None:
        return None
    seed = pert.changed().get("seed")
    return None if seed is None else int(seed)


def fault_kind_of(fault: ControllerFault | str | None) -> str | None:
    """The kind of a controller fault (a ``ControllerFault`` or its kind), None without one; an unknown
    kind raises :class:`TrialRecordError`."""
    if fault is None:
        return None
    kind = fault.kind if isinstance(fault, ControllerFault) else fault
    if kind not in FAULT_KINDS:
        raise TrialRecordError(f"fault_kind {kind!r} is not one of {', '.join(FAULT_KINDS)}")
    return kind


def kind_from_reason(reason: str) -> str | None:
    """The fault kind named in a faulted trial's reason (``controller fault: controller 'X' at t = ... s:
    KIND: detail``), None for any other reason."""
    if not reason.startswith(FAULT_REASON):
        return None
    for kind in FAULT_KINDS:
        if f" s: {kind}: " in reason:
            return kind
    raise TrialRecordError(f"a controller fault's reason names no known kind ({', '.join(FAULT_KINDS)}): {reason!r}")


def complete(rec: Mapping) -> dict:
    """``rec`` with ``seed`` and ``fault_kind`` (a new dict): kept where present and checked (``seed`` an
    int or None, ``fault_kind`` None or a known kind), filled where absent (module docstring)."""
    out = dict(rec)
    if "seed" not in out:
        out["seed"] = None
    seed = out["seed"]
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise TrialRecordError(f"seed must be an integer or null, got {seed!r}")
    if "fault_kind" not in out:
        out["fault_kind"] = kind_from_reason(str(out.get("reason", "")))
    else:
        out["fault_kind"] = fault_kind_of(out["fault_kind"])
    return out


def faulted(rec: Mapping) -> bool:
    """The record's trial ended in a controller fault (also a record from before ``fault_kind``)."""
    kind = rec.get("fault_kind") if "fault_kind" in rec else kind_from_reason(str(rec.get("reason", "")))
    return kind is not None
