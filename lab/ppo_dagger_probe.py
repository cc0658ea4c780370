"""Probe: would a demonstration-initialised policy walk at a shorter policy period?

The teacher (mode none from the observation, ``biped_controller.policy.teacher``) walks 20 steps on MuJoCo when
held over 2 ms but not over 10 ms (``lab.ppo_teacher``; results/ppo_baseline/teacher_hold.json). Here DAgger
(Ross et al. 2011) fits the baseline's network (standardised observation, tanh 128 x 128, linear output; the
standardisation from the data) to the teacher's actions on the states the student visits, at ``--period``: the
first iteration on the teacher's own rollouts, each later one on the student's rollouts (from reference states
at random phases of the step, the environment's reference state initialisation), all labels the teacher's,
aggregated, the network refitted (Adam, mean squared error). After each iteration the student walks unpushed
on the plug-in loop (MuJoCo, held over the period), as ``scripts/experiment walk`` would. A probe for the next
design decision, not the product's baseline (no PPO, no pushes).

    .venv/bin/python -m lab.ppo_dagger_probe --period 0.002 --iterations 6 --epochs 300 [--standardise-targets] --json F

``--standardise-targets`` fits each joint's action standardised by its spread in the data (the de-standardisation
folded into the output layer, so the network is the baseline's), so the light swing ankle's small torques weigh
as much as the stance leg's large ones.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def rollout(env, policy, teacher, seed, max_steps):
    obs, _ = env.reset(seed=seed)
    X, Y = [], []
    for _ in range(max_steps):
        X.append(obs)
        Y.append(teacher(obs))
        obs, _, term, _, _ = env.step(policy(obs))
        if term:
            break
    return X, Y


def fit(X, Y, hidden, epochs, seed, lr=1e-3, batch=256, standardise_targets=False):
    import jax
    import jax.numpy as jnp
    import optax
    X = np.asarray(X, np.float32)
    Y = np.asarray(Y, np.float32)
    mu, sd = X.mean(0), X.std(0) + 1e-6
    ym, ys = (Y.mean(0), Y.std(0) + 1e-6) if standardise_targets else (np.zeros(Y.shape[1], np.float32),
                                                                        np.ones(Y.shape[1], np.float32))
    Yn = (Y - ym) / ys
    sizes = [X.shape[1], *hidden, Y.shape[1]]
    key = jax.random.PRNGKey(seed)
    params = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        key, k = jax.random.split(key)
        params.append((jax.random.normal(k, (a, b)) * np.sqrt(1.0 / a), jnp.zeros(b)))

    def forward(p, x):
        h = jnp.clip((x - mu) / sd, -5.0, 5.0)
        for w, b in p[:-1]:
            h = jnp.tanh(h @ w + b)
        w, b = p[-1]
        return h @ w + b

    def loss(p, x, y):
        return jnp.mean((forward(p, x) - y) ** 2)

    opt = optax.adam(lr)
    state = opt.init(params)

    @jax.jit
    def step(p, s, x, y):
        l, g = jax.value_and_grad(loss)(p, x, y)
        u, s = opt.update(g, s)
        return optax.apply_updates(p, u), s, l

    rng = np.random.default_rng(seed)
    n = len(X)
    for _ in range(epochs):
        perm = rng.permutation(n)
        for i in range(0, n - batch + 1, batch):
            j = perm[i:i + batch]
            params, state, l = step(params, state, X[j], Yn[j])
    pn = [(np.asarray(w), np.asarray(b)) for w, b in params]
    pn[-1] = (pn[-1][0] * ys, pn[-1][1] * ys + ym)       # the output's de-standardisation folded into its layer
    pred = np.asarray(forward(params, X)) * ys + ym
    full = float(np.mean((pred - Y) ** 2))
    per_joint = np.sqrt(np.mean((pred - Y) ** 2, axis=0))

    def policy(o):
        h = np.clip((np.asarray(o, np.float32) - mu) / sd, -5.0, 5.0)
        for w, b in pn[:-1]:
            h = np.tanh(h @ w + b)
        return np.clip(h @ pn[-1][0] + pn[-1][1], -1.0, 1.0).astype(float)
    return policy, full, per_joint


def walk(policy, period, steps):
    from biped_controller.plugin.interface import ControllerSetup
    from biped_controller.plugin.loop import PluginLoop
    from biped_controller.policy.controller import PolicyController
    from biped_controller.studies.trial.context import context
    from biped_controller.studies.trial.settings import run_settings
    rs = run_settings(None, ["plant=mujoco"])
    ctx = context(rs.robot)
    scfg = rs.sim_config()
    setup = ControllerSetup(ctx.desc, ctx.family, scfg.control_period, {})
    ctrl = PolicyController(setup, policy, policy_period=period)
    r = PluginLoop(ctrl, sim_config=scfg, family=ctx.family, desc=ctx.desc, perturbation=rs.perturbation,
                   name="student").run(steps, keep_records=False)
    return {"steps_walked": r.steps_walked, "fallen": r.fallen, "fall_cause": r.fall_cause,
            "fall_time": r.fall_time if r.fallen else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--period", type=float, default=0.002)
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--rollouts", type=int, default=4, help="student rollouts per iteration")
    ap.add_argument("--max-seconds", type=float, default=3.0, help="sim time per rollout [s]")
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--standardise-targets", action="store_true",
                    help="fit the teacher's actions standardised per joint (each joint's error weighed by its spread)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from biped_controller.policy.teacher import TeacherPolicy
    from biped_controller.policy.env import BipedPushEnv
    from biped_controller.studies.provenance import Run
    prov = Run(argv, plant="mujoco", command="python -m lab.ppo_dagger_probe " + " ".join(
        sys.argv[1:] if argv is None else argv))
    env = BipedPushEnv(plant="mujoco", policy_period=a.period, reference_state_init=1.0)
    teacher = TeacherPolicy(env.desc, env.family)
    max_steps = int(round(a.max_seconds / a.period))
    X, Y, rows = [], [], []
    t0 = time.monotonic()
    policy = teacher
    for it in range(a.iterations):
        for r in range(a.rollouts):
            x, y = rollout(env, policy, teacher, a.seed + 100 * it + r, max_steps)
            X += x
            Y += y
        policy, mse, rms = fit(X, Y, (128, 128), a.epochs, a.seed + it, standardise_targets=a.standardise_targets)
        w = walk(policy, a.period, 20)
        rows.append({"iteration": it, "samples": len(X), "fit_mse": mse, "fit_rms_per_joint": rms.tolist(), **w,
                     "wall_s": round(time.monotonic() - t0, 1)})
        print(json.dumps(rows[-1]), flush=True)
    if a.json:
        with open(a.json, "w", encoding="utf-8") as f:
            json.dump({"command": prov.command, "period": a.period, "standardise_targets": a.standardise_targets,
                       "iterations": rows}, f, indent=1)
        prov.record(a.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
