"""The built-in modes of :class:`biped_controller.core.control.controller.AdaptiveController` behind the controller
interface (``plugin.interface``): one adapter class per mode, each a thin wrapper over the existing
controller (its compiled period included), registered under the mode's name.

The adapter's ``compute`` is ``AdaptiveController.compute(t, q, q', stance, pitch, pitch_rate)`` on the
observation; its status is the scalar fields of ``ControllerStatusData`` (p [m], p_dot [m/s], tau [s],
tau_dot [-], p_ddot, tau_ddot, their second-task values, qp_status, tightest, zmp [m], stance,
max_tracking_error [rad], force_estimate [N], the whole-body stage's and the torso offset's fields).
``on_touchdown`` does nothing: the controller detects the stance change itself (tau restarts at 0).
The settings are ``config/controller.yaml``'s with the mode set, the period the setup's, and the
setup's options as overrides of its keys.

Every consumer reaches a built-in mode through this interface (``registry.make_controller``): the controller
node, the generic loop (``plugin.loop``) and the studies. The compiled fast path is this controller's own
optimisation: its period is the compiled period of ``AdaptiveController`` (``core.control.controller_compiled``),
and its class declares ``compiled_mode`` (:func:`compiled_mode`), which lets the studies run its trials on the
compiled closed loop (``closed_loop.runner``: many periods of controller and plant in one compiled call, the
records those of this class's ``compute`` through the generic loop bit for bit, tested) with the early stop of
a decided trial.
"""
from __future__ import annotations

import operator
from dataclasses import fields

import numpy as np

from biped_controller.core.control.config import MODES, ControllerConfigError, load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.control.status import ControllerStatusData
from biped_controller.plugin.interface import ControllerSetup, ControlResult, Observation

#: ControllerStatusData fields that are numbers or flags (margins and predicted_reaction are arrays; the
#: mode and the QP's message are text)
STATUS_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(ControllerStatusData)
                                       if f.name not in ("margins", "predicted_reaction", "mode", "qp_message"))


_STATUS_VALUES = operator.attrgetter(*STATUS_FIELDS)


def status_mapping(s: ControllerStatusData) -> dict[str, float | int | bool]:
    """The scalar fields of one period's status as the interface's status mapping (every period of the
    controller node: one attribute getter for all, about half the cost of a getattr per field)."""
    return dict(zip(STATUS_FIELDS, _STATUS_VALUES(s)))


class ModeController:
    """One mode of the adaptive controller (``mode`` a class attribute of the subclasses below)."""

    mode: str = ""
    description: str = ""

    def __init__(self, setup: ControllerSetup):
        if self.mode not in MODES:
            raise ControllerConfigError(f"{type(self).__name__}: mode must be one of {MODES}, got {self.mode!r}")
        cfg = load_controller_config(mode=self.mode, period=setup.period, **dict(setup.options))
        self.ctrl = AdaptiveController(cfg, setup.family, setup.desc)

    def reset(self, t: float, stance: int) -> None:
        self.ctrl.reset(stance)

    def on_touchdown(self, t: float, stance: int) -> None:
        """Nothing to do: the controller sees the stance change in the next observation."""

    def compute(self, obs: Observation) -> ControlResult:
        # writable copies: the compiled period takes writable arrays, the observation's are read-only
        out = self.ctrl.compute(obs.t, np.array(obs.q), np.array(obs.qd), obs.stance, obs.pitch, obs.pitch_rate)
        return ControlResult(np.asarray(out.torque, dtype=float), status_mapping(out.status), out.status)


def compiled_mode(cls: object) -> str | None:
    """The built-in mode a controller class is, when the class declares ``compiled_mode`` in its own body (the
    classes of this module do): then the compiled closed loop may run it (module docstring). None for any
    other class, a subclass of a built-in included (it may change ``compute``: the generic loop runs it)."""
    m = vars(cls).get("compiled_mode") if isinstance(cls, type) else None
    return m if isinstance(m, str) and m in MODES and issubclass(cls, ModeController) else None


def _mode_class(mode: str, text: str) -> type:
    name = "Mode" + mode.capitalize()
    return type(name, (ModeController,), {"mode": mode, "compiled_mode": mode, "description": text,
                                         "__module__": __name__, "__qualname__": name,
                                         "__doc__": f"Mode {mode!r}: {text}."})


_TEXT = {
    "none": "classical computed torque on the fixed reference q_d(p_d, t) (no adaptation)",
    "tau": "paper section 4: the QP adapts the time scaling tau'' under the 17 contact/torque rows",
    "p": "paper section 4: the QP adapts the stride p'' under the 17 rows",
    "both": "paper section 4: the QP adapts p'' and tau'' under the 17 rows",
    "wbc": "fixed reference, whole-body QP on the joint accelerations w under the 17 rows",
    "hybrid": "mode both, then the whole-body QP when the p/tau QP cannot hold its rows",
    "lambda": "the QP adapts the torso offset lambda'' of q_d(p, tau, lambda)",
    "all": "the QP adapts p'', tau'' and the torso offset lambda''",
}

ModeNone, ModeTau, ModeP, ModeBoth, ModeWbc, ModeHybrid, ModeLambda, ModeAll = (_mode_class(m, _TEXT[m]) for m in MODES)

#: mode name -> "module:Class" of its adapter (the registry's built-in entries)
BUILTIN: dict[str, str] = {m: f"{__name__}:Mode{m.capitalize()}" for m in MODES}
