"""Cost of the legs' model-error estimator (issue 22, ``core/model_error.py``): ``AdaptiveController.compute``
per call in a closed loop on the rigid plant (1 s, perfect sensors, the compiled step with the compiled
momentum observer, K = 200), p50/p99 after the first 50 periods, side by side in one run (interleaved rounds,
so every case sees the same load): the observer alone; the observer + the estimator with its first regressor
(``RneaLegRegressor``: 7 Pinocchio RNEA calls on 7 models a period); the observer + the estimator as shipped
(``LegRegressor``: one ``pin.computeJointTorqueRegressor`` and one product). Also the two regressors' calls
alone (p50 over the loop's states). Written to ``benchmarks/model_error_results.json``, never asserted.

    .venv/bin/python -m benchmarks.model_error_bench [--seconds 1.0] [--rounds 3] [--out PATH]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from biped_sim.robot.description import LEFT, load_description
from biped_sim.robot.gait_family import GaitFamily
from biped_sim.plant.rigid import Simulator

from biped_controller.core.controller import AdaptiveController, load_controller_config
from biped_controller.core.model_error import LegRegressor, RneaLegRegressor

OUT = Path(__file__).with_name("model_error_results.json")
CASES = (("observer", "momentum observer (compiled)"),
         ("estimator_rnea", "+ estimator, RNEA regressor (old)"),
         ("estimator", "+ estimator, joint torque regressor"))


def _case(fam, desc, seconds: float, case: str) -> tuple[np.ndarray, list]:
    sim = Simulator(desc)
    ctrl = AdaptiveController(load_controller_config(mode="both", momentum_observer=True,
                                                     model_error_estimator=case != "observer"), fam, desc)
    if case == "estimator_rnea":
        ctrl._sensing.me.reg = RneaLegRegressor(desc)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    ts, states = [], []
    while sim.t < seconds:
        o = sim.observe()
        t0 = time.perf_counter()
        out = ctrl.compute(o.t, o.q, o.qd, o.stance, o.pitch)
        ts.append(time.perf_counter() - t0)
        states.append((o.q.copy(), o.qd.copy()))
        sim.step(out.torque)
    return np.array(ts[50:]) * 1e6, states


def _regressor_calls(desc, states) -> dict[str, float]:
    """p50 [us] of one call of each regressor over the loop's states (acceleration: a seeded draw)."""
    rng = np.random.default_rng(0)
    acc = rng.normal(0.0, 20.0, (len(states), 6))
    out = {}
    for name, reg in (("rnea", RneaLegRegressor(desc)), ("joint_torque_regressor", LegRegressor(desc))):
        ts = []
        for (q, qd), a in zip(states, acc):
            t0 = time.perf_counter()
            reg(q, qd, a)
            ts.append(time.perf_counter() - t0)
        out[name] = round(float(np.percentile(ts, 50)) * 1e6, 2)
    return out


def main(argv: list[str] | None = None) -> int:
    a = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    a.add_argument("--seconds", type=float, default=1.0)
    a.add_argument("--rounds", type=int, default=3)
    a.add_argument("--out", type=Path, default=OUT)
    args = a.parse_args(argv)
    fam, desc = GaitFamily.load(), load_description()
    load0 = os.getloadavg()[0]
    out: dict[str, list[np.ndarray]] = {c: [] for c, _ in CASES}
    states: list = []
    for _ in range(args.rounds):                  # interleaved rounds: every case sees the same load
        for c, _ in CASES:
            ts, st = _case(fam, desc, args.seconds, c)
            out[c].append(ts)
            states = st
    calls = _regressor_calls(desc, states)
    load1 = os.getloadavg()[0]
    print(f"load average {load0:.1f} -> {load1:.1f}")
    res = {"meta": {"date": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()), "cpus": os.cpu_count(),
                    "load_avg_1min": load0, "load_avg_1min_end": load1, "python": platform.python_version(),
                    "seconds": args.seconds, "rounds": args.rounds},
           "step": {}, "regressor_call_p50_us": calls}
    for c, name in CASES:
        ts = np.concatenate(out[c])
        p50, p99 = float(np.percentile(ts, 50)), float(np.percentile(ts, 99))
        res["step"][c] = {"p50_us": round(p50, 2), "p99_us": round(p99, 2), "calls": len(ts)}
        print(f"{name:38s} p50 {p50:8.1f} us   p99 {p99:8.1f} us   ({len(ts)} calls)")
    print(f"regressor call alone p50: RNEA {calls['rnea']:.1f} us, joint torque regressor "
          f"{calls['joint_torque_regressor']:.1f} us")
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
