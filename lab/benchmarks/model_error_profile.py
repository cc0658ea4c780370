"""Where the controller step's time goes with the legs' model-error estimator: each call of the
compiled step's sensing path wrapped by a timer (so every figure is high by its timer's cost), p50 per call
over ``--rounds`` closed loops of 1 s on the rigid plant (perfect sensors, momentum observer K = 200):

* ``--path python``: the estimator in Python after the compiled call (``use_model_error_kernel(False)``, the
  code before the estimator went into the kernel): ``CompiledSensing._model_error`` and inside it
  ``LegModelError.update`` (Pinocchio's model matrices, the joint torque regressor, the combine kernel's
  call), the torso point's Jacobian, the observer's wrench, then ``into_res``;
* ``--path kernel``: the estimator inside ``pipeline_kernels.sense`` (the default);
* ``--path off``: the observer alone.

    .venv/bin/python -m lab.benchmarks.model_error_profile [--path python|kernel|off] [--rounds 3]

Prints only (a profile, not a benchmark key).
"""
from __future__ import annotations

import argparse
import functools
import os
import time

import numpy as np

from biped_model.description import LEFT, load_description
from biped_model.gait_family import GaitFamily
from biped_sim.plant.rigid import Simulator

from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController


def _wrap(obj, name: str, label: str, times: dict) -> None:
    f = getattr(obj, name)

    @functools.wraps(f)
    def timed(*a, **k):
        t0 = time.perf_counter_ns()
        try:
            return f(*a, **k)
        finally:
            times.setdefault(label, []).append(time.perf_counter_ns() - t0)
    setattr(obj, name, timed)


class _Kernels:
    """``pipeline_kernels`` with ``sense`` timed (a module's attribute cannot be wrapped in place: it is
    shared by every pipeline)."""

    def __init__(self, ek, times: dict):
        self._ek = ek
        self.sense = ek.sense
        _wrap(self, "sense", "pipeline_kernels.sense (compiled call)", times)

    def __getattr__(self, name):
        return getattr(self._ek, name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--path", choices=("python", "kernel", "off"), default="python")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    fam, desc = GaitFamily.load(), load_description()
    on = args.path != "off"
    ctrl = AdaptiveController(load_controller_config(mode="both", momentum_observer=True, model_error_estimator=on),
                              fam, desc)
    s = ctrl._sensing
    times: dict[str, list[int]] = {}
    if on:
        s.use_model_error_kernel(args.path == "kernel")
    if args.path == "python":
        me = s.me
        _wrap(s, "_model_error", "CompiledSensing._model_error (all)", times)
        _wrap(me, "update", "  LegModelError.update", times)
        _wrap(me.model, "dynamics", "    FixedFootModel.dynamics (Pinocchio)", times)
        _wrap(me, "reg", "    LegRegressor (Pinocchio) call", times)
        _wrap(me, "_combine", "    combine_kernel call", times)
        _wrap(me.model, "torso_point_jacobian", "  torso_point_jacobian (Pinocchio)", times)
        _wrap(s, "_observer_wrench", "  _observer_wrench", times)
        _wrap(s, "_before", "CompiledSensing._before", times)
    s.ek = _Kernels(s.ek, times)
    _wrap(s, "into_res", "CompiledSensing.into_res", times)
    _wrap(s, "sense", "CompiledSensing.sense (all)", times)
    _wrap(ctrl._kernel, "compute", "CompiledPeriod.compute (into_res + the period)", times)
    sim = Simulator(desc)
    q0, qd0 = fam.initial_state()
    total = []
    for _ in range(args.rounds):
        sim.reset(q0, qd0, LEFT)
        ctrl.reset(LEFT)
        while sim.t < 1.0:
            o = sim.observe()
            t0 = time.perf_counter_ns()
            out = ctrl.compute(o.t, o.q, o.qd, o.stance, o.pitch)
            total.append(time.perf_counter_ns() - t0)
            sim.step(out.torque)
    print(f"path {args.path}, load average {os.getloadavg()[0]:.1f}; p50 per call [us], timers included")
    print(f"{'AdaptiveController.compute':52s} {np.median(total) / 1e3:7.1f}")
    for k, v in times.items():
        print(f"{k:52s} {np.median(v) / 1e3:7.1f}   ({len(v)} calls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
