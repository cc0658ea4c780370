"""Probe: how much random residual (policy.residual) the preferred walk of mode none takes on MuJoCo, per joint
group, before its stance foot turns. It chose the per-joint residual_scale of config/training/ppo_baseline.yaml.

A zero-mean Gaussian action a ~ N(0, std^2) per joint and policy period (10 ms), clipped to [-1, 1], times the
per-joint scale s [rad], on the unpushed BipedPush-v0 (MuJoCo, action_mode residual), 3 seeded episodes of at
most 500 policy periods (5 s): how long each walked. std 0.37 is the learner's initial exploration
(initial_log_std -1), 0.135 is log std -2.

    .venv/bin/python lab/ppo_residual_probe.py --json results/ppo_baseline/residual_noise_probe.json
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from biped_controller.policy.env import BipedPushEnv
from biped_controller.studies import provenance


def episode(env, scale, std, seed, limit=500):
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    n, info = 0, {}
    while n < limit:
        _, _, term, _, info = env.step(np.clip(rng.normal(0.0, std, 6), -1.0, 1.0) * scale / env.residual.scale)
        n += 1
        if term:
            break
    return {"policy_periods": n, "steps_walked": int(info["steps_walked"]), "fall_cause": info["fall_cause"]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    run = provenance.Run(plant="mujoco", profile="default")
    env = BipedPushEnv(plant="mujoco", action_mode="residual", residual_scale=1.0)
    rows = []
    t0 = time.time()
    for stance_s, swing_s in ((0.1, 0.1), (0.01, 0.1), (0.005, 0.1), (0.003, 0.1), (0.002, 0.1), (0.0, 0.1),
                              (0.0, 0.2)):
        scale = np.array([stance_s] * 3 + [swing_s] * 3)
        for std in (0.135, 0.37):
            eps = [episode(env, scale, std, seed) for seed in range(3)]
            rows.append({"stance_scale_rad": stance_s, "swing_scale_rad": swing_s, "std": std, "episodes": eps})
            print(f"stance joints s={stance_s:<6} swing joints s={swing_s:<4} std={std:<5} periods walked:",
                  [e["policy_periods"] for e in eps], [e["fall_cause"] or "-" for e in eps])
    q0, qd0 = env.family.initial_state()
    a_diag = np.diag(env.residual.teacher.model.dynamics(q0, qd0).A)
    out = {"what": __doc__.splitlines()[0], "plant": "mujoco", "limit_policy_periods": 500, "seeds": [0, 1, 2],
           "mass_matrix_diagonal_at_start_kg_m2": [round(float(x), 4) for x in a_diag],
           "kp": float(env.residual.gains.Kp),
           "kp_a11_n_m_per_rad": round(float(env.residual.gains.Kp * a_diag[0]), 1),
           "rows": rows, "wall_s": round(time.time() - t0, 1)}
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
            f.write("\n")
        run.record(a.json)


if __name__ == "__main__":
    main()
