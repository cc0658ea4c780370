"""Can the model-based teacher drive the policy environment at the policy period?

The teacher is the product's mode ``none`` (computed torque on the fixed reference q_d(p_d, tau), tau the
time in stance) written as a function of the policy observation alone
(``biped_controller.policy.teacher.TeacherPolicy``); held over each 10 ms policy period by the policy
controller (``policy.controller.PolicyController``) it runs on the plug-in loop like any ONNX policy.
``--period 0.001`` checks it against mode ``none`` itself (the same torques, period by period). ``--kp``
runs the 10 ms hold again with other joint gains (critically damped, Kv = 2 sqrt(Kp)): does a softer or
stiffer law survive the hold? ``--noise SIGMA`` adds seeded white noise N(0, SIGMA^2) to the teacher's action (a
fraction of the torque limit) at the plant's period, on every joint and on each joint alone: how precise must
a torque policy be?

    .venv/bin/python -m lab.ppo_teacher --periods 0.001 0.002 0.005 0.01 --kp 100 225 900 --plant mujoco \
        --steps 20 --noise 0.0005 0.002 --json F
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def run_teacher(period: float, plant: str, steps: int, kp: float | None = None, noise: float = 0.0,
                joints: tuple[int, ...] = tuple(range(6)), seed: int = 0) -> dict:
    from biped_controller.policy.teacher import TeacherPolicy
    from biped_controller.plugin.interface import ControllerSetup
    from biped_controller.plugin.loop import PluginLoop
    from biped_controller.policy.controller import PolicyController
    from biped_controller.studies.trial.context import context
    from biped_controller.studies.trial.settings import run_settings
    rs = run_settings(None, [f"plant={plant}"])
    ctx = context(rs.robot)
    scfg = rs.sim_config()
    setup = ControllerSetup(ctx.desc, ctx.family, scfg.control_period, {})
    from biped_controller.plugin.model import Gains
    gains = Gains(kp, 2.0 * kp ** 0.5) if kp is not None else Gains.from_config()
    teacher = TeacherPolicy(setup.desc, setup.family, gains)
    policy = teacher
    if noise > 0:
        rng = np.random.default_rng(seed)
        mask = np.zeros(6)
        mask[list(joints)] = 1.0

        def policy(obs):
            return teacher(obs) + noise * mask * rng.standard_normal(6)
    ctrl = PolicyController(setup, policy, policy_period=period)
    loop = PluginLoop(ctrl, sim_config=scfg, family=ctx.family, desc=ctx.desc, perturbation=rs.perturbation,
                      name=f"teacher@{period:g}s")
    r = loop.run(steps)
    out = {"policy_period": period, "Kp": gains.Kp, "Kv": gains.Kv, "noise": noise,
           "noise_joints": [j + 1 for j in joints] if noise > 0 else [], "plant": plant, "steps_walked": r.steps_walked, "fallen": r.fallen,
           "fall_cause": r.fall_cause, "fall_time": None if not r.fallen else r.fall_time,
           "periods": r.periods, "impact_times": [round(i.t, 4) for i in r.impacts[:3]],
           "fall_detail": r.fall_detail}
    if period == scfg.control_period and kp is None and noise == 0:
        ref = PluginLoop("none", sim_config=scfg, family=ctx.family, desc=ctx.desc,
                         perturbation=rs.perturbation).run(steps)
        n = min(len(ref.records), len(r.records))
        d = max(float(np.max(np.abs(a.torque - b.torque))) for a, b in zip(ref.records[:n], r.records[:n]))
        out["none_steps_walked"] = ref.steps_walked
        out["max_torque_diff_vs_none"] = d
        out["compared_periods"] = n
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--periods", type=float, nargs="+", default=[0.001, 0.01])
    ap.add_argument("--plant", default="mujoco")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--kp", type=float, nargs="*", default=[], help="gains to try at 10 ms (Kv = 2 sqrt(Kp))")
    ap.add_argument("--noise", type=float, nargs="*", default=[],
                    help="action noise (fraction of the limit) at the plant's period: all joints, then each alone")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from biped_controller.studies.provenance import Run
    prov = Run(argv, plant=a.plant, command="python -m lab.ppo_teacher " + " ".join(sys.argv[1:] if argv is None
                                                                                  else argv))
    rows = [run_teacher(p, a.plant, a.steps) for p in a.periods]
    rows += [run_teacher(0.01, a.plant, a.steps, kp) for kp in a.kp]
    for sigma in a.noise:
        rows += [run_teacher(0.001, a.plant, a.steps, noise=sigma, joints=js)
                 for js in [tuple(range(6))] + [(j,) for j in range(6)]]
    for r in rows:
        print(json.dumps(r))
    if a.json:
        with open(a.json, "w", encoding="utf-8") as f:
            json.dump({"command": prov.command, "runs": rows}, f, indent=1)
        prov.record(a.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
