"""The early stop: when a survival trial's outcome is decided before the end of its run
(``config/studies.yaml``)."""
from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biped_sim.robot.gait_family import GaitFamily
from biped_sim.robot.settings import default_config_dir, read_settings

from biped_controller.core.control.controller_layout import M_


class StudySettingsError(ValueError):
    """``config/studies.yaml`` holds a value out of range (the message names the key)."""


@dataclass(frozen=True)
class EarlyStop:
    """When a survival trial's outcome is decided (``config/studies.yaml``).

    Once a control period after an impact at or after the end of the push has completed without a fall
    (``runner.run``'s ``on_impact``: the controller's own post-impact torque has acted and passed the
    plant's checks), the trial is *decided* (survived) when the walk is back on the preferred gait: the
    plant's state (q, q') at that instant t within ``q`` [rad] and ``qd`` [rad/s] (max norm) of the
    gait's orbit at the same time into the step, q_d(p_d, t - t_impact) and dq_d/dtau(p_d, t - t_impact)
    (``GaitFamily.evaluate``; the same in either stance), and the controller's parameters as last decided
    within ``p`` [m] of p_d, ``p_dot`` [m/s] of 0, ``tau_dot`` of 1, its observer's force estimate within
    ``force`` [N] of 0, and its torso offset (modes lambda and all; 0 in the others) within ``lam``
    [rad] and ``lam_dot`` [rad/s] of 0: the offset's profile phi vanishes at the impact, so q and q' do not
    show lambda there, and in mode lambda p and tau' never leave the gait's. The rest of the trial would be the undisturbed walk from such a state, which walks
    on and ends with p, tau' inside the survival rule's floors ``survival.P_FLOOR``, ``survival.TAU_DOT_FLOOR``,
    hence inside every band of the rule (measured: docs/capability_map.md, "Early stop"); ``p`` and ``tau_dot``
    are half the floors. Applied to the nominal rigid plant with ideal sensors only (the measurement's
    plant, :func:`applies`): a perturbed plant's trial, and a MuJoCo trial, run in full."""

    enabled: bool
    q: float
    qd: float
    p: float
    p_dot: float
    tau_dot: float
    force: float
    lam: float
    lam_dot: float

    KEYS = ("early_stop", "early_stop_q", "early_stop_qd", "early_stop_p", "early_stop_p_dot",
            "early_stop_tau_dot", "early_stop_force", "early_stop_lambda", "early_stop_lambda_dot")

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> "EarlyStop":
        p = Path(path) if path is not None else default_config_dir() / "studies.yaml"
        v = read_settings(p, cls.KEYS)
        if not isinstance(v["early_stop"], bool):
            raise StudySettingsError(f"{p}: 'early_stop' must be true or false, got {v['early_stop']!r}")
        for k in cls.KEYS[1:]:
            x = v[k]
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not (math.isfinite(x) and x > 0):
                raise StudySettingsError(f"{p}: '{k}' must be a finite number > 0, got {x!r}")
        return cls(v["early_stop"], *(float(v[k]) for k in cls.KEYS[1:]))

    def decided(self, sim, ctrl, push_end: float, family: GaitFamily) -> bool:
        """The criterion above, on the latest impact of ``sim``, its state now and the state of ``ctrl``."""
        imp = sim.impact_log[-1]
        if imp.t < push_end:
            return False
        s = ctrl.state
        if not (abs(s.p - family.p_d) <= self.p and abs(s.p_dot) <= self.p_dot and abs(s.tau_dot - 1.0) <= self.tau_dot
                and abs(ctrl.force_estimate) <= self.force):
            return False
        mem = ctrl.memory       # the torso offset lambda, lambda' at the last decision (0 outside its modes)
        if not (abs(mem[M_.lam]) <= self.lam and abs(mem[M_.lam_dot]) <= self.lam_dot):
            return False
        q, qd = sim.fm.paper_from_state(sim.x, sim.v, sim.stance)
        g = family.evaluate(family.p_d, sim.t - imp.t)
        return bool(np.max(np.abs(q - g.q)) <= self.q and np.max(np.abs(qd - g.dq_dtau)) <= self.qd)


def applies(settings) -> bool:
    """The early stop may end a trial with these ``RunSettings``: the rigid plant, nominal, ideal sensors.
    Not on MuJoCo: one control period after its touchdown (spread over several MuJoCo steps, the stance foot
    chattering) the state is far from the gait's orbit even unpushed, and no tolerances were measured for
    it (docs/mujoco_plant.md, "Sweeps on MuJoCo")."""
    p = settings.perturbation
    return settings.sim_config().plant == "rigid" and (p is None or p.is_zero)


@functools.lru_cache(maxsize=4)
def _early_stop(stamp: int) -> EarlyStop:
    return EarlyStop.load()


def early_stop() -> EarlyStop:
    """``config/studies.yaml``'s early stop, read again whenever the file changed."""
    return _early_stop(os.stat(default_config_dir() / "studies.yaml").st_mtime_ns)

