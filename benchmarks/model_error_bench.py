"""Cost of the legs' model-error estimator (issue 22, ``core/model_error.py``): ``AdaptiveController.compute``
per call in a closed loop on the rigid plant (1 s, perfect sensors, the compiled step with the compiled
momentum observer, K = 200), p50/p99 after the first 50 periods, side by side in one run: the observer alone
and the observer + the estimator (Python after the compiled observer: 7 Pinocchio RNEA calls a period for the
regressor). Printed, not stored, never asserted.

    .venv/bin/python -m benchmarks.model_error_bench [--seconds 1.0] [--rounds 3]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from biped_sim.robot.description import LEFT, load_description
from biped_sim.robot.gait_family import GaitFamily
from biped_sim.plant.rigid import Simulator

from biped_controller.core.controller import AdaptiveController, load_controller_config


def _case(fam, desc, seconds: float, estimator: bool) -> np.ndarray:
    sim = Simulator(desc)
    ctrl = AdaptiveController(load_controller_config(mode="both", momentum_observer=True,
                                                     model_error_estimator=estimator), fam, desc)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    ts = []
    while sim.t < seconds:
        o = sim.observe()
        t0 = time.perf_counter()
        out = ctrl.compute(o.t, o.q, o.qd, o.stance, o.pitch)
        ts.append(time.perf_counter() - t0)
        sim.step(out.torque)
    return np.array(ts[50:]) * 1e6


def main(argv: list[str] | None = None) -> int:
    a = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    a.add_argument("--seconds", type=float, default=1.0)
    a.add_argument("--rounds", type=int, default=3)
    args = a.parse_args(argv)
    fam, desc = GaitFamily.load(), load_description()
    out: dict[bool, list[np.ndarray]] = {False: [], True: []}
    for _ in range(args.rounds):                  # interleaved rounds: both cases see the same load
        for est in (False, True):
            out[est].append(_case(fam, desc, args.seconds, est))
    print(f"load average {os.getloadavg()[0]:.1f}")
    for est, name in ((False, "momentum observer (compiled)"), (True, "+ model_error_estimator")):
        ts = np.concatenate(out[est])
        print(f"{name:32s} p50 {np.percentile(ts, 50):8.1f} us   p99 {np.percentile(ts, 99):8.1f} us   ({len(ts)} calls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
