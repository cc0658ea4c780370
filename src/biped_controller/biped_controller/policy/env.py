"""The push-recovery benchmark as a Gymnasium environment: ``BipedPush-v0`` (:class:`BipedPushEnv`) and
``BipedRandomPush-v0`` (the same wrapped in :class:`RandomPushes`). Guide: docs/policies.md.

The physics is the plug-in loop's (``plugin.loop.PluginLoop``): the plant is built by the same
``make_plant(scfg.plant, desc, scfg, perturbation)`` from the same settings (``--profile``, ``--set``,
``--perturb``, ``--robot`` as the studies read them), reset to the gait family's periodic initial state
(LEFT stance, t = 0), pushes scheduled the same way, one ``plant.step(torque)`` per plant control period
with one ``plant.observe()`` per period (the sensor model samples every period, as in the loop), the fall
rule the plant's own. What the loop hands a controller each period the environment hands the policy
each policy period, as the vector of ``policy.spec``.

One environment step (a policy period, ``policy_period`` [s], default 10 ms, a whole multiple of the
plant's control period): with ``action_mode: torque`` (the default) the action a in [-1, 1]^6 becomes the
torques a * tau_max in paper order of the observed stance and is held over the plant periods from the step's
start to the next instant k * policy_period of the policy grid; with ``action_mode: residual`` the action is
an offset a * residual_scale [rad] on the gait family's preferred reference, held over the same periods, and
the torque of each plant period is the computed-torque law on the offset reference at that period's
observation (``policy.residual``; a = 0 walks as mode ``none``). A period cut short: when the sensed stance changes (a touchdown: the
plant ends its own control period at the touchdown instant, so the observation after it is the new
stance's, and the held torques, in paper order of the old stance, would act on the relabelled legs) the
step ends there, with ``info["touchdown"]`` True; the next step runs from the touchdown instant to the next
grid instant (a shorter step; the grid is not shifted). A fall ends the step and the episode
(``terminated``). ``info["period"]`` is the step's duration [s].

Reward of a step of duration dt (f = dt / policy_period, so a cut-short step earns its share):

    forward  = forward_reward_weight * (v_pref - |v - v_pref|) * f,  v = (x_hip(end) - x_hip(start)) / dt
    healthy  = healthy_reward * f                    (0 for the step that ends in a fall)
    ctrl     = ctrl_cost_weight * sum(a_i^2) * f
    upright  = upright_cost_weight * theta^2 * f,    theta the torso's pitch from the vertical at the end [rad]
    imitate  = (w_pose exp(-k_pose |q - q_d|^2) + w_vel exp(-k_vel |q' - q_d'|^2)
                + w_speed exp(-k_speed (v - v_pref)^2)) * f
    reward   = forward + healthy - ctrl - upright + imitate

with v_pref = p_d / T [m/s] the gait family's preferred speed (stride over step duration). The imitation
term is DeepMimic's (Peng et al. 2018: pose, velocity and centre-of-mass terms, each exp(-k error^2)) on the
gait family's preferred reference at the time in stance s: q_d = q_d(p_d, min(s, T)), q_d' = dq_d/dtau (tau'
= 1), q, q' the joint state at the step's end in paper order of its stance (as the plant reports it: the
true state under the default profile's ideal sensors), the hip's speed standing in for the centre of mass's;
its weights are 0 in config/policy_env.yaml (the Walker2d-style reward alone) and set by a trainer that asks
for imitation (config/training/ppo_baseline.yaml). The other terms read the plant's true state (the
trainer's view); the policy sees only its observation.

Reference state initialisation (DeepMimic's RSI): with probability ``reference_state_init`` a reset starts
at a uniformly drawn phase s0 in [0, T) of the preferred step instead of its start: (q_d(p_d, s0),
dq_d/dtau(p_d, s0)) plus the reset noise, LEFT stance, sim time 0, time in stance s0 (the phase drawn after
the noise, from the same generator; nothing drawn when the probability is 0, the default).

Termination: the plant's fall rule (``info["fall_cause"]`` names it: the rigid plant's take-off, slip, CoP
or body contact, MuJoCo's hip height, foot tilt or body contact), the same as in every study; the plant
cannot go on after a fall, so Walker2d's ``terminate_when_unhealthy=False`` is not offered. Truncation:
the registered time limit (``max_episode_steps``).

``info`` (the same keys after every reset and step, so a vector of environments stacks them): ``push`` (the
episode's first push, ``pushes.push_info``; force 0 and direction "none" without one), ``pushes`` (how many),
``fall_cause`` and ``fall_detail`` ("" while walking), ``t`` [s] sim time, ``plant_periods`` (plant control
periods since the reset), ``steps_walked`` (touchdowns), ``x_position`` [m] (hip), ``stance``; after a step
also ``period`` [s], ``touchdown``, ``x_velocity`` [m/s] and the reward's terms ``reward_forward``,
``reward_healthy``, ``reward_ctrl``, ``reward_upright`` (costs negative).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from biped_model.description import LEFT
from biped_model.settings import default_config_dir, read_settings
from biped_sim.plant.protocol import make_plant

from biped_controller.plugin.interface import stamp_time
from biped_controller.policy.pushes import (PushDistribution, PushOptionError, parse_push_option, push_info)
from biped_controller.policy.residual import ResidualLaw
from biped_controller.policy.spec import (ACTION_MODES, GRID_TOL, OBS_SIZE, check_action, check_policy_period,
                                          decision_grid_end, observation_vector, torque_limits)

ENV_ID = "BipedPush-v0"
RANDOM_PUSH_ENV_ID = "BipedRandomPush-v0"


class EnvConfigError(ValueError):
    """An environment setting is unknown or out of range (the message names it)."""


@dataclass(frozen=True)
class EnvConfig:
    """The environment's settings, their values and reasons in ``config/policy_env.yaml`` (module docstring)."""

    policy_period: float
    forward_reward_weight: float
    healthy_reward: float
    ctrl_cost_weight: float
    upright_cost_weight: float
    reset_noise_scale: float
    max_episode_steps: int
    imitation_pose_weight: float
    imitation_pose_scale: float
    imitation_velocity_weight: float
    imitation_velocity_scale: float
    imitation_speed_weight: float
    imitation_speed_scale: float
    reference_state_init: float
    action_mode: str
    residual_scale: tuple[float, ...]

    def validate(self) -> "EnvConfig":
        if self.action_mode not in ACTION_MODES:
            raise EnvConfigError(f"action_mode must be one of {ACTION_MODES}, got {self.action_mode!r}")
        rs = self.residual_scale
        rs = (rs,) * 6 if isinstance(rs, (int, float)) and not isinstance(rs, bool) else rs
        if (not isinstance(rs, (list, tuple)) or len(rs) != 6
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0
                       for v in rs)):
            raise EnvConfigError(f"residual_scale must be a number > 0 [rad] or six of them (paper joint order), "
                                 f"got {self.residual_scale!r}")
        object.__setattr__(self, "residual_scale", tuple(float(v) for v in rs))
        for f in fields(self):
            if f.name in ("action_mode", "residual_scale"):
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise EnvConfigError(f"{f.name} must be a finite number >= 0, got {v!r}")
        if self.policy_period <= 0:
            raise EnvConfigError(f"policy_period must be > 0 s, got {self.policy_period!r}")
        if self.reference_state_init > 1:
            raise EnvConfigError(f"reference_state_init is a probability in [0, 1], got {self.reference_state_init!r}")
        return self


def load_env_config(path: str | Path | None = None, **overrides: Any) -> EnvConfig:
    """``config/policy_env.yaml`` (or ``path``) with ``overrides`` (None values ignored) applied."""
    p = Path(path) if path is not None else default_config_dir() / "policy_env.yaml"
    kw = read_settings(p, EnvConfig.__dataclass_fields__)
    for k, v in overrides.items():
        if k not in kw:
            raise EnvConfigError(f"unknown environment setting {k!r}; settings: {', '.join(kw)}")
        if v is not None:
            kw[k] = v
    return EnvConfig(**kw).validate()


def _override_items(settings: Mapping[str, object] | None, plant: str | None) -> list[str]:
    items = [f"{k}={v}" for k, v in dict(settings or {}).items()]
    if plant is not None:
        if settings and "plant" in settings:
            raise EnvConfigError("plant: given both as plant= and in settings")
        items.append(f"plant={plant}")
    return items


class BipedPushEnv(gym.Env):
    """The planar biped walking and pushed, as a Gymnasium environment (module docstring; docs/policies.md).

    ``plant``: ``"mujoco"`` (default) or ``"rigid"``; ``robot``: a name under ``robots/`` or a path (None:
    biped7); ``profile``: a profile of ``config/profiles/`` (its simulator settings and plant perturbation:
    the sensor model the observation goes through); ``settings``: simulator keys of
    ``config/simulator.yaml`` -> value (as ``--set``); ``perturbation``: plant perturbation fields -> value (as
    ``--perturb``, over the profile's). The reward and reset settings (``policy_period`` [s],
    ``forward_reward_weight``, ``healthy_reward``, ``ctrl_cost_weight``, ``upright_cost_weight``,
    ``reset_noise_scale``, and as keywords the imitation terms' ``imitation_*`` and ``reference_state_init``)
    default to ``config/policy_env.yaml``. ``keep_records``: keep every plant period's
    ``StepRecord`` of the episode in :attr:`records` (tests, analysis)."""

    metadata = {"render_modes": []}

    def __init__(self, plant: str | None = "mujoco", robot: str | None = None, profile: str | None = None,
                 settings: Mapping[str, object] | None = None, perturbation: Mapping[str, object] | None = None,
                 policy_period: float | None = None, forward_reward_weight: float | None = None,
                 healthy_reward: float | None = None, ctrl_cost_weight: float | None = None,
                 upright_cost_weight: float | None = None, reset_noise_scale: float | None = None,
                 keep_records: bool = False, render_mode: str | None = None, **reward_settings: float):
        from biped_controller.studies.trial.context import context
        from biped_controller.studies.trial.settings import run_settings
        if render_mode is not None:
            raise EnvConfigError(f"render_mode: this environment does not render, got {render_mode!r} "
                                 f"(record a run with the studies or the ROS graph instead)")
        self.config = load_env_config(policy_period=policy_period, forward_reward_weight=forward_reward_weight,
                                      healthy_reward=healthy_reward, ctrl_cost_weight=ctrl_cost_weight,
                                      upright_cost_weight=upright_cost_weight, reset_noise_scale=reset_noise_scale,
                                      **reward_settings)
        pert_items = [f"{k}={v}" for k, v in dict(perturbation or {}).items()]
        self.run_settings = run_settings(profile, _override_items(settings, plant), perturb=pert_items, robot=robot)
        ctx = context(self.run_settings.robot)
        self.desc, self.family = ctx.desc, ctx.family
        self.scfg = self.run_settings.sim_config()
        self.perturbation = self.run_settings.perturbation
        self.period = check_policy_period(self.config.policy_period, self.scfg.control_period)
        # the plug-in loop's plant (plugin.loop.PluginLoop.__init__): the same call
        self.sim = make_plant(self.scfg.plant, self.desc, self.scfg, self.perturbation)
        self.limits = torque_limits(self.desc)
        self.v_pref = self.family.p_d / self.family.T
        c = self.config
        self._imitate = (c.imitation_pose_weight > 0 or c.imitation_velocity_weight > 0
                         or c.imitation_speed_weight > 0)
        self.keep_records = bool(keep_records)
        self.records: list = []
        self.render_mode = None
        self.observation_space = spaces.Box(-np.inf, np.inf, (OBS_SIZE,), dtype=np.float64)
        self.action_space = spaces.Box(-1.0, 1.0, (6,), dtype=np.float32)
        self._identity = self.sim.sensor.identity
        self._pushes: tuple = ()
        self._ended = True
        self.residual = (ResidualLaw(self.desc, self.family, c.residual_scale)
                         if c.action_mode == "residual" else None)

    # ------------------------------------------------------------------ helpers
    def _observe(self):
        raw = self.sim.observe()
        self._raw, self._t_obs = raw, stamp_time(raw.t)
        return raw

    def _obs(self) -> np.ndarray:
        raw = self._raw
        return observation_vector(raw.q, raw.qd, raw.pitch, raw.pitch_rate, raw.stance, self._t_obs - self._t_stance,
                                  self._last_torque, self.limits)

    def _imitation(self, v: float) -> float:
        """The imitation term per full period (module docstring) at the current observation."""
        c, fam, raw = self.config, self.family, self._raw
        g = fam.evaluate(fam.p_d, min(max(self._t_obs - self._t_stance, 0.0), fam.T))
        eq, eqd = raw.q - g.q, raw.qd - g.dq_dtau
        return (c.imitation_pose_weight * math.exp(-c.imitation_pose_scale * float(eq @ eq))
                + c.imitation_velocity_weight * math.exp(-c.imitation_velocity_scale * float(eqd @ eqd))
                + c.imitation_speed_weight * math.exp(-c.imitation_speed_scale * (v - self.v_pref) ** 2))

    def _info(self) -> dict:
        fall = self.sim.fall
        return {"push": push_info(self._pushes[0] if self._pushes else None, self.scfg.push_height),
                "pushes": len(self._pushes),
                "fall_cause": fall.cause if fall is not None else "",
                "fall_detail": fall.detail if fall is not None else "",
                "t": float(self.sim.t), "plant_periods": int(self.sim.step_index),
                "steps_walked": int(self.sim.impact_count),
                "x_position": float(self.sim.x[0]), "stance": int(self._raw.stance)}

    # ------------------------------------------------------------------ the Gymnasium API
    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None):
        """Start an episode at the gait family's periodic initial state (LEFT stance, t = 0) plus seeded
        uniform noise U(-s, s) on each joint angle and rate (s = ``reset_noise_scale``; angles drawn first),
        with the pushes of ``options["push"]`` (``policy.pushes``). A bad option raises
        :class:`~biped_controller.policy.pushes.PushOptionError` naming it, before anything changes."""
        options = dict(options or {})
        unknown = [k for k in options if k != "push"]
        if unknown:
            raise PushOptionError(str(unknown[0]), f"reset options: unknown key {unknown[0]!r} (known: 'push')")
        pushes = parse_push_option(options.get("push"))
        for p in pushes:
            if not math.isnan(p.height) and p.height > self.desc.torso.length:
                raise PushOptionError("height", f"push: height {p.height} m is above the torso "
                                                f"({self.desc.torso.length} m above the hip)")
        super().reset(seed=seed)
        q0, qd0 = self.family.initial_state()
        s = self.config.reset_noise_scale
        nq, nqd = np.zeros_like(q0), np.zeros_like(qd0)
        if s > 0:
            nq = self.np_random.uniform(-s, s, q0.shape)
            nqd = self.np_random.uniform(-s, s, qd0.shape)
        phase = 0.0
        if self.config.reference_state_init > 0 and self.np_random.uniform() < self.config.reference_state_init:
            phase = float(self.np_random.uniform(0.0, self.family.T))
            g = self.family.evaluate(self.family.p_d, phase)
            q0, qd0 = g.q.copy(), g.dq_dtau.copy()
        q0, qd0 = q0 + nq, qd0 + nqd
        sim = self.sim
        self.initial_state = (q0, qd0)
        sim.reset(q0, qd0, LEFT)
        for p in pushes:                 # as PluginLoop.run schedules them
            sim.schedule_push(p.start, p.duration, p.force, p.height)
        self._pushes = pushes
        self._last_torque = np.zeros(6)
        self._observe()
        self._t_stance = self._t_obs - phase
        self.reset_phase = phase
        self._ended = False
        self.records = []
        return self._obs(), self._info()

    def step(self, action):
        """Hold the action over one policy period (module docstring); returns (obs, reward, terminated,
        truncated = False, info). A wrong shape or a non-finite entry raises ``spec.ActionError``."""
        a = check_action(action)
        if self._ended:
            raise RuntimeError("BipedPushEnv.step: the episode has ended (a fall) or was never started: call reset()")
        sim, cfg = self.sim, self.config
        law = self.residual
        if law is None:
            torque = a * self.limits
        else:
            delta = law.offset(a)
            torque = law.torque(self._obs(), delta)
        stance = self._raw.stance
        t_next = decision_grid_end(self._t_obs, self.period)
        t0, x0 = sim.t, float(sim.x[0])
        touchdown = fell = observed = False
        identity, keep = self._identity, self.keep_records
        while True:
            observed = False
            rec = sim.step(torque)
            if keep:
                self.records.append(rec)
            self._last_torque = rec.torque
            if rec.fallen or sim.fall is not None:
                fell = True
                break
            # the next period's observation, as the plug-in loop takes it (the sensor model samples each period)
            # (the grid test on the plant's time: its stamp differs by < 1 ns, GRID_TOL is 100 ns)
            if law is None:
                st = sim.stance if identity else sim.observe().stance
            else:                        # the residual law reads the whole observation every period
                st = self._observe().stance
                observed = True
            if st != stance:
                touchdown = True
                break
            if sim.t >= t_next - GRID_TOL:
                break
            if law is not None:
                torque = law.torque(self._obs(), delta)
        if not observed:
            self._observe()
        if touchdown:
            self._t_stance = self._t_obs
        dt = sim.t - t0
        f = dt / self.period
        v = (float(sim.x[0]) - x0) / dt if dt > 0 else 0.0
        theta = float(sim.x[2])
        r_fwd = cfg.forward_reward_weight * (self.v_pref - abs(v - self.v_pref)) * f
        r_healthy = 0.0 if fell else cfg.healthy_reward * f
        c_ctrl = cfg.ctrl_cost_weight * float(np.dot(a, a)) * f
        c_up = cfg.upright_cost_weight * theta * theta * f
        r_im = self._imitation(v) * f if self._imitate else 0.0
        reward = r_fwd + r_healthy - c_ctrl - c_up + r_im
        self._ended = fell
        info = self._info()
        info.update(period=dt, touchdown=touchdown, x_velocity=v, reward_forward=r_fwd, reward_healthy=r_healthy,
                    reward_ctrl=-c_ctrl, reward_upright=-c_up, reward_imitation=r_im)
        return self._obs(), float(reward), fell, False, info


class RandomPushes(gym.Wrapper):
    """Draws a random push (``policy.pushes.PushDistribution``) at every reset that names none; the draws
    come from this wrapper's generator, seeded by ``seed`` and again by every ``reset(seed=...)``
    (``numpy.random.default_rng([seed, 1])``), so a seeded episode is reproduced with its push."""

    def __init__(self, env: gym.Env, distribution: PushDistribution | None = None, seed: int = 0, **kwargs):
        super().__init__(env)
        self.distribution = distribution if distribution is not None else PushDistribution(**kwargs)
        self._rng = np.random.default_rng([int(seed), 1])

    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None):
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), 1])
        options = dict(options or {})
        if "push" not in options:
            options["push"] = self.distribution.draw(self._rng)
        return self.env.reset(seed=seed, options=options)


def make_random_push_env(distribution: Mapping[str, object] | PushDistribution | None = None, seed: int = 0,
                         **env_kwargs) -> gym.Env:
    """``BipedRandomPush-v0``: :class:`BipedPushEnv` (``env_kwargs``) wrapped in :class:`RandomPushes`
    (``distribution``: a :class:`PushDistribution` or its fields)."""
    dist = distribution if isinstance(distribution, PushDistribution) else PushDistribution(**dict(distribution or {}))
    return RandomPushes(BipedPushEnv(**env_kwargs), dist, seed=seed)

