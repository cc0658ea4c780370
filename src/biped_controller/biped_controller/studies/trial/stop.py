"""The early stop: when a survival trial's outcome is decided before the end of its run
(``config/studies.yaml``)."""
from __future__ import annotations

import functools
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from biped_sim.plant.period_grid import last_grid_before
from biped_model.gait_family import GaitFamily
from biped_model.settings import default_config_dir, read_settings

from biped_controller.core.control.controller_layout import M_


class StudySettingsError(ValueError):
    """``config/studies.yaml`` holds a value out of range (the message names the key)."""


def _read_switch_and_positives(path, keys) -> tuple[Path, dict]:
    """``keys`` of ``config/studies.yaml`` (``path``: another file): the first a switch (true or false), the
    others finite numbers > 0; a value out of range raises :class:`StudySettingsError` naming the key.
    Returns (the file, the values)."""
    p = Path(path) if path is not None else default_config_dir() / "studies.yaml"
    v = read_settings(p, keys)
    if not isinstance(v[keys[0]], bool):
        raise StudySettingsError(f"{p}: '{keys[0]}' must be true or false, got {v[keys[0]]!r}")
    for k in keys[1:]:
        x = v[k]
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not (math.isfinite(x) and x > 0):
            raise StudySettingsError(f"{p}: '{k}' must be a finite number > 0, got {x!r}")
    return p, v


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
    plant, :func:`applies`); the MuJoCo plant has its own (:class:`MujocoEarlyStop`), a perturbed plant's
    trial runs in full."""

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

    def identity(self) -> dict:
        """JSON-ready: the settings (the capability map's store fingerprint hashes them)."""
        return asdict(self)

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> "EarlyStop":
        p, v = _read_switch_and_positives(path, cls.KEYS)
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
    """The rigid plant's early stop (:class:`EarlyStop`) may end a trial with these ``RunSettings``: the rigid
    plant, nominal, ideal sensors (the plant its tolerances were measured on)."""
    p = settings.perturbation
    return settings.sim_config().plant == "rigid" and (p is None or p.is_zero)


def applies_mujoco(settings) -> bool:
    """The MuJoCo plant's early stop (:class:`MujocoEarlyStop`) may end a trial with these ``RunSettings``: the
    MuJoCo plant, nominal, ideal sensors (a model error: the trial runs in full; sensor noise:
    :func:`applies_mujoco_sensors`)."""
    p = settings.perturbation
    return settings.sim_config().plant == "mujoco" and (p is None or p.is_zero)


def applies_mujoco_sensors(settings, mode: str | None = None) -> bool:
    """The MuJoCo plant's early stop may end a trial with these ``RunSettings`` under sensor noise: the MuJoCo
    plant, the nominal model (no mass, centre-of-mass, inertia or friction change), no measurement delay, a
    sensor model that draws noise or quantises (``PlantPerturbation.sensing_is_perfect`` False),
    ``early_stop_mujoco_sensors`` switched on in ``config/studies.yaml`` and, given a ``mode``, that mode among
    ``early_stop_mujoco_sensors_modes`` (the modes it was measured to hold for: mode p's noisy walks fall or
    leave their band long after a decided touchdown). A trial whose seed's unpushed walk fell is not stopped
    (``BuiltinMode.survives``): the argument below needs that walk to walk. The criterion is
    :class:`MujocoEarlyStop`'s on the plant's true state, with the trial's own band (its seed's unpushed walk).
    Why it may decide such a trial: the rest of the run is a noisy walk from a state on the gait's orbit, and
    its seed's unpushed walk is one. Not exact: the survival rule judges p and tau' at the run's last status, and
    under noise p keeps wandering after the decision (measured against the same trials run in full, 2 of 5869
    decisions on the 25 ms slice differed, each a walk that failed only that end check: ``lab.noisy_early_stop``,
    docs/robustness.md, "Early stop under sensor noise")."""
    p = settings.perturbation
    return (settings.sim_config().plant == "mujoco" and p is not None and p.model_is_nominal and p.delay == 0
            and not p.sensing_is_perfect and sensors_switch() and (mode is None or mode in sensors_modes()))


def stops_early(settings) -> bool:
    """A survival trial with these ``RunSettings`` may be ended by an early stop: not ``full_trials``, the
    plant's early stop switched on, and the trial's plant and sensing among those it applies to
    (:func:`applies`, :func:`applies_mujoco`, :func:`applies_mujoco_sensors`)."""
    if settings.full_trials or not enabled(settings):
        return False
    return applies(settings) or applies_mujoco(settings) or applies_mujoco_sensors(settings)


@functools.lru_cache(maxsize=4)
def _sensors_switch(stamp: int) -> bool:
    p = default_config_dir() / "studies.yaml"
    v = read_settings(p, ("early_stop_mujoco_sensors",))["early_stop_mujoco_sensors"]
    if not isinstance(v, bool):
        raise StudySettingsError(f"{p}: 'early_stop_mujoco_sensors' must be true or false, got {v!r}")
    return v


def sensors_switch() -> bool:
    """``config/studies.yaml``'s ``early_stop_mujoco_sensors`` (read again whenever the file changed)."""
    return _sensors_switch(os.stat(default_config_dir() / "studies.yaml").st_mtime_ns)


@functools.lru_cache(maxsize=4)
def _sensors_modes(stamp: int) -> tuple[str, ...]:
    from biped_controller.core.control.config import MODES
    p = default_config_dir() / "studies.yaml"
    v = read_settings(p, ("early_stop_mujoco_sensors_modes",))["early_stop_mujoco_sensors_modes"]
    if not isinstance(v, list) or not all(isinstance(m, str) and m in MODES for m in v):
        raise StudySettingsError(f"{p}: 'early_stop_mujoco_sensors_modes' must be a list of built-in modes "
                                 f"({', '.join(MODES)}), got {v!r}")
    return tuple(sorted(set(v)))


def sensors_modes() -> tuple[str, ...]:
    """``config/studies.yaml``'s ``early_stop_mujoco_sensors_modes``, sorted (read again whenever the file
    changed): the built-in modes whose trials the early stop may end under sensor noise."""
    return _sensors_modes(os.stat(default_config_dir() / "studies.yaml").st_mtime_ns)


@functools.lru_cache(maxsize=4)
def _early_stop(stamp: int) -> EarlyStop:
    return EarlyStop.load()


def early_stop() -> EarlyStop:
    """``config/studies.yaml``'s early stop, read again whenever the file changed."""
    return _early_stop(os.stat(default_config_dir() / "studies.yaml").st_mtime_ns)


@dataclass(frozen=True)
class MujocoEarlyStop:
    """When a survival trial's outcome is decided on the MuJoCo plant (``config/studies.yaml``, keys
    ``early_stop_mujoco*``; measured: docs/mujoco_plant.md, "Sweeps on MuJoCo").

    MuJoCo's touchdown is not an instant: the landing foot's contact builds up over a few milliseconds, so
    one control period after the sensed touchdown (``runner.run``'s ``on_impact``; 0.125-1 ms after it on
    the 1 ms control grid) the joint velocities are still part way through the impact, 0.82-3.5 rad/s from
    the orbit's post-impact velocity in the unpushed walks, depending on that delay. The state is
    therefore compared with the gait's orbit where MuJoCo's walk follows it closely:

    * the configuration now (t, one period after the touchdown at t_i): |q - q_d(p_d, t - t_i)|_inf <= ``q``
      [rad] (the impact does not move the joints);
    * the state entering the touchdown, (q, q') at the start t_0 of the control period in which it was
      sensed (``ImpactRecord.x_minus``, ``v_minus`` on this plant), against the orbit at the same time into
      the step, s = t_0 - t_(i-1) (t_(i-1) the previous touchdown, 0 for the first):
      |q - q_d(p_d, s)|_inf <= ``q``, |q' - dq_d/dtau(p_d, s)|_inf <= ``qd`` [rad/s]; this period must
      start at or after the push's end (a step much longer than the gait's T, e.g. right after a backward
      push, meets the orbit's polynomial continued past T: far from the walk, that touchdown is not decided);

    and the controller as in :class:`EarlyStop`: |p - p_d| <= e_p = ``band`` x the trial's band ``p_tol`` [m],
    |tau' - 1| <= ``band`` x its ``tau_dot_tol`` (``survival.Band``: the same plant, profile and mode's
    unpushed walk's, known before the trial), |p'| <= ``p_dot_rate`` x e_p [m/s] (``p_dot_rate`` [1/s]),
    |force estimate| <= ``force`` [N],
    |lambda| <= ``lam`` [rad], |lambda'| <= ``lam_dot`` [rad/s] (the rigid plant's ``early_stop_lambda``,
    ``early_stop_lambda_dot``). The walk then enters the rest of the trial as the unpushed walk does, its
    p and tau' inside a fraction of the band the rule judges its end with. Applied to the nominal MuJoCo
    plant with ideal sensors (:func:`applies_mujoco`), and under sensor noise (:func:`applies_mujoco_sensors`, with
    the seed's band: an approximation there, measured)."""

    enabled: bool
    q: float
    qd: float
    band: float
    p_dot_rate: float
    force: float
    lam: float
    lam_dot: float

    KEYS = ("early_stop_mujoco", "early_stop_mujoco_q", "early_stop_mujoco_qd", "early_stop_mujoco_band",
            "early_stop_mujoco_p_dot_rate", "early_stop_mujoco_force", "early_stop_lambda", "early_stop_lambda_dot")

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> "MujocoEarlyStop":
        """The settings of ``config/studies.yaml`` (``path``: another file); a value out of range raises
        :class:`StudySettingsError` naming the key."""
        p, v = _read_switch_and_positives(path, cls.KEYS)
        if not v["early_stop_mujoco_band"] < 1.0:
            raise StudySettingsError(f"{p}: 'early_stop_mujoco_band' must be < 1 (a fraction of the survival band: "
                                     f"the end must stay inside it), got {v['early_stop_mujoco_band']!r}")
        return cls(v["early_stop_mujoco"], *(float(v[k]) for k in cls.KEYS[1:]))

    def identity(self) -> dict:
        """JSON-ready: the settings (the capability map's store fingerprint hashes them)."""
        return {"mujoco": asdict(self)}

    @staticmethod
    def distances(sim, ctrl, push_end: float, family: GaitFamily, dt: float) -> dict:
        """The quantities the criterion bounds, at the latest impact of ``sim`` (``dt`` [s] the control period):
        ``q`` [rad] the configuration's distance to the orbit now, ``q_in`` [rad] and ``qd_in`` [rad/s] the
        state's entering the touchdown, ``qd`` [rad/s] the velocity's now (recorded, not bounded),
        ``p`` [m], ``p_dot`` [m/s], ``tau_dot`` [-], ``force`` [N], ``lam`` [rad], ``lam_dot`` [rad/s] the
        controller's distances, ``delay`` [s] t - t_i, ``after_push`` the period entering the touchdown
        starts at or after the push's end."""
        log = sim.impact_log
        imp = log[-1]
        prev = log[-2].t if len(log) > 1 else 0.0
        t0 = max(last_grid_before(imp.t, dt), prev)       # the start of the period the touchdown ended
        if t0 == imp.t:                                   # a touchdown on the grid: the period before it
            t0 = max(imp.t - dt, prev)
        q, qd = sim.fm.paper_from_state(sim.x, sim.v, sim.stance)
        g = family.evaluate(family.p_d, sim.t - imp.t)
        q0, qd0 = sim.fm.paper_from_state(imp.x_minus, imp.v_minus, imp.old_stance)
        g0 = family.evaluate(family.p_d, t0 - prev)
        s = ctrl.state
        mem = ctrl.memory
        return {"delay": float(sim.t - imp.t), "after_push": bool(t0 >= push_end and imp.t >= push_end),
                "q": float(np.max(np.abs(q - g.q))), "qd": float(np.max(np.abs(qd - g.dq_dtau))),
                "q_in": float(np.max(np.abs(q0 - g0.q))), "qd_in": float(np.max(np.abs(qd0 - g0.dq_dtau))),
                "p": abs(s.p - family.p_d), "p_dot": abs(s.p_dot), "tau_dot": abs(s.tau_dot - 1.0),
                "force": abs(ctrl.force_estimate), "lam": abs(float(mem[M_.lam])), "lam_dot": abs(float(mem[M_.lam_dot]))}

    def inside(self, d: dict, band) -> bool:
        """The criterion on :meth:`distances`' ``d`` with the trial's ``band`` (``survival.Band``)."""
        return bool(d["after_push"] and d["q"] <= self.q and d["q_in"] <= self.q and d["qd_in"] <= self.qd
                    and d["p"] <= self.band * band.p_tol and d["tau_dot"] <= self.band * band.tau_dot_tol
                    and d["p_dot"] <= self.p_dot_rate * self.band * band.p_tol and d["force"] <= self.force
                    and d["lam"] <= self.lam and d["lam_dot"] <= self.lam_dot)

    def decided(self, sim, ctrl, push_end: float, family: GaitFamily, band, dt: float) -> bool:
        """The criterion above on the latest impact of ``sim``, its state now and the state of ``ctrl``, with
        the trial's ``band`` and the control period ``dt`` [s]."""
        if sim.impact_log[-1].t < push_end:
            return False
        return self.inside(self.distances(sim, ctrl, push_end, family, dt), band)


@functools.lru_cache(maxsize=4)
def _mujoco_early_stop(stamp: int) -> MujocoEarlyStop:
    return MujocoEarlyStop.load()


def mujoco_early_stop() -> MujocoEarlyStop:
    """``config/studies.yaml``'s MuJoCo early stop, read again whenever the file changed."""
    return _mujoco_early_stop(os.stat(default_config_dir() / "studies.yaml").st_mtime_ns)


def identity(settings) -> dict:
    """JSON-ready: the early stop's settings for trials with these ``RunSettings`` (the capability map's store
    fingerprint hashes them): the rigid plant's on the rigid plant (the dict it always was), the MuJoCo
    plant's on MuJoCo, with ``"sensors"``: the modes whose trials it ends under sensor noise, where it does
    (:func:`applies_mujoco_sensors`: a store of such trials run in full is not resumed by one stopped early)."""
    if settings.sim_config().plant == "mujoco":
        out = mujoco_early_stop().identity()
        if applies_mujoco_sensors(settings):
            out["sensors"] = list(sensors_modes())
        return out
    return early_stop().identity()


def enabled(settings) -> bool:
    """The early stop of the plant of these ``RunSettings`` is switched on in ``config/studies.yaml``
    (``early_stop`` for the rigid plant, ``early_stop_mujoco`` for MuJoCo)."""
    if settings.sim_config().plant == "mujoco":
        return mujoco_early_stop().enabled
    return early_stop().enabled
