"""How far a committed policy walks unpushed: seeded episodes of ``BipedPushEnv`` (no push, the environment's
reset noise) driven by the policy's ONNX file (``policy.controller.OnnxRunner``, the deterministic action),
each until a fall, ``--steps`` touchdowns, or the registered time limit. Default install only.

    python -m biped_controller.learning.evaluate ppo_baseline [--episodes 5] [--steps 20] [--plant mujoco]
        [--pushes-of ppo_baseline] [--zero] [--json results/ppo_baseline/eval_mujoco.json]

Per episode: ``length`` [policy steps], ``duration`` [s], ``steps_walked`` (touchdowns), ``distance`` (hip x
travelled [m]), ``speed`` (distance / duration [m/s]), ``return`` (the environment's reward summed), ``ended``
(``fall: <cause>``, ``steps`` or ``time_limit``), the episode's push; their means, and how many fell.
``--pushes-of NAME`` draws a random push per episode from the training distribution of
config/training/NAME.yaml (seeded by the episode's seed); ``--zero`` runs the action a = 0 on the same
environment and seeds (a residual policy's inner loop alone, mode none), the reference for what the network
adds. The acceptance check of the issue is the
product's own ``scripts/experiment walk --steps 20 --controller NAME --set plant=mujoco``; this is the
environment's view of the same policy, with the reward it was trained on.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def evaluate(name: str, episodes: int = 5, steps: int = 20, plant: str = "mujoco", seed: int = 0,
             pushes: dict | None = None, zero: bool = False) -> dict:
    """``episodes`` seeded episodes (seeds ``seed``, ``seed + 1``, ...) of the policy ``name``; ``pushes``: the
    fields of a ``PushDistribution`` (random pushes drawn per episode by ``RandomPushes``, seeded by the
    episode's seed), None: unpushed; ``zero``: the action a = 0 instead of the policy, on the same environment
    and seeds (for a residual policy, the model-based inner loop alone: mode none)."""
    from biped_controller.policy.catalog import policies_dir
    from biped_controller.policy.controller import OnnxRunner
    from biped_controller.policy.env import BipedPushEnv, RandomPushes, load_env_config
    from biped_controller.policy.pushes import PushDistribution
    path = policies_dir() / name / "policy.onnx"
    run = OnnxRunner(path)
    if zero:
        run = lambda obs: np.zeros(6)  # noqa: E731
    meta = json.loads((policies_dir() / name / "policy.json").read_text())
    kw = {"action_mode": meta["action_mode"], "residual_scale": meta["residual_scale"]} \
        if meta.get("action_mode", "torque") == "residual" else {}
    env = BipedPushEnv(plant=plant, robot=meta.get("robot"), **kw)       # the robot it was trained on
    if pushes is not None:
        dist = PushDistribution(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in pushes.items()})
        env = RandomPushes(env, dist, seed=seed)
    limit = int(load_env_config().max_episode_steps)
    out = []
    for k in range(episodes):
        obs, info = env.reset(seed=seed + k)
        x0, ret, n, ended = info["x_position"], 0.0, 0, "time_limit"
        while n < limit:
            obs, r, term, _, info = env.step(run(obs))
            ret += r
            n += 1
            if term:
                ended = f"fall: {info['fall_cause']}"
                break
            if info["steps_walked"] >= steps:
                ended = "steps"
                break
        d = float(info["x_position"] - x0)
        push = info["push"]
        out.append({"seed": seed + k, "push_force": push["force"], "push_direction": push["direction"],
                    "push_onset": round(push["onset"], 4), "length": n, "duration": round(info["t"], 4), "steps_walked": info["steps_walked"],
                    "distance": round(d, 4), "speed": round(d / info["t"], 4) if info["t"] > 0 else 0.0,
                    "return": round(ret, 3), "ended": ended})
    mean = {k: round(float(np.mean([e[k] for e in out])), 4)
            for k in ("length", "duration", "steps_walked", "distance", "speed", "return")}
    falls = sum(e["ended"].startswith("fall") for e in out)
    return {"policy": name, "action": "zero (a = 0)" if zero else "the policy's mean", "plant": plant,
            "episodes": episodes, "steps_asked": steps, "push": pushes, "policy_totals": meta.get("totals"),
            "mean": mean, "falls": falls, "walked_all": all(e["ended"] == "steps" for e in out), "per_episode": out}


def main(argv: list[str] | None = None) -> int:
    from biped_controller.studies.trial.args import StudyArgumentParser, positive_int
    ap = StudyArgumentParser(prog="evaluate", description="Seeded unpushed episodes of a committed policy.")
    ap.add_argument("name", help="a committed policy (policies/NAME/)")
    ap.add_argument("--episodes", type=positive_int, default=5)
    ap.add_argument("--steps", type=positive_int, default=20, help="touchdowns that end an episode as walked")
    ap.add_argument("--plant", choices=("mujoco", "rigid"), default="mujoco")
    ap.add_argument("--pushes-of", metavar="NAME", default=None,
                    help="random pushes from config/training/NAME.yaml's push_distribution (default: unpushed)")
    ap.add_argument("--zero", action="store_true", help="the action a = 0 instead of the policy (same seeds)")
    ap.add_argument("--json", help="write the result here (with its provenance record)")
    a = ap.parse_args(argv)
    pushes = None
    if a.pushes_of is not None:
        from biped_controller.learning.ppo_config import TrainConfigError, load_config
        try:
            pushes = dict(load_config(a.pushes_of).push_distribution)
        except TrainConfigError as exc:
            ap.error(f"--pushes-of: {exc}")
    from biped_controller.policy.catalog import policies_dir
    if not (policies_dir() / a.name / "policy.onnx").is_file():
        ap.error(f"no committed policy {a.name!r} (policies/{a.name}/policy.onnx)")
    from biped_controller.studies.provenance import Run
    meta = json.loads((policies_dir() / a.name / "policy.json").read_text())
    prov = Run(argv, plant=a.plant, robot=meta.get("robot"))
    res = evaluate(a.name, a.episodes, a.steps, a.plant, pushes=pushes, zero=a.zero)
    m = res["mean"]
    for e in res["per_episode"]:
        print(f"seed {e['seed']}: {e['length']} policy steps, {e['duration']} s, {e['steps_walked']} steps walked, "
              f"{e['distance']} m at {e['speed']} m/s, return {e['return']}, ended {e['ended']}")
    print(f"mean: {m['length']} policy steps, {m['steps_walked']} steps walked, {m['speed']} m/s, return {m['return']}; "
          f"{res['falls']} of {res['episodes']} episodes fell")
    if a.json:
        p = Path(a.json)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
        prov.record(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
