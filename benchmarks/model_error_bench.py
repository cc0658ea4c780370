"""Cost of the legs' model-error estimator (``core/sensing/model_error.py``): ``AdaptiveController.compute``
per call, the compiled step with the compiled sensing pipeline, p50/p99 after the first 50 periods, side by
side in one run. Each case's observations come from its own closed loop on the rigid plant (1 s); they are
then replayed through a fresh controller of every case, the cases in turn by blocks of ``BLOCK`` periods
(case 1's periods k..k+99, case 2's, ...: every case sees the same load within milliseconds, the shared
2-core machine's load moves by 2x within seconds; blocks, not single periods, so that a case does not start
each period on the caches the previous case left, the Python one's 150 us of Pinocchio and NumPy added
about 5 us to the next case's p50 when measured period by period), in several rounds:

* perfect sensors, momentum observer K = 200: the observer alone (``observer``); + the estimator in Python
  after the compiled call (``estimator_python``: ``LegModelError`` with Pinocchio's joint torque regressor,
  the code before the estimator went into the kernel, run now through ``use_model_error_kernel(False)``);
  + the estimator inside the compiled call (``estimator``, key ``controller.step_p50_us_model_error``);
* the real-sensor profile (estimator + observer K = 50, noise 5e-4 rad, 5e-2 rad/s, 14 bits, IMU 1e-3 rad,
  ``estimation_bench``'s ``controller.step_p50_us_estimation``) without (``real``) and with the model-error
  estimator in the kernel (``real_model_error``, key ``controller.step_p50_us_estimation_model_error``: the
  profile that meets every MuJoCo row); the ratios with / without, pooled and as the median over the rounds
of the ratio of the two p50 in the same round (the machine is shared: a round's cases share its load).

Also the three regressors' calls alone (p50 over the loop's states, a seeded acceleration): the RNEA
differences (``RneaLegRegressor``), Pinocchio's joint torque regressor (``LegRegressor``), the closed form
(``CompiledLegRegressor``, from Python: the call's dispatch included). Written to
``results/benchmarks/model_error.json`` and the keys merged into ``--results`` (``keys``, section
``model_error_step``); targets printed, never asserted.

    .venv/bin/python -m benchmarks.model_error_bench [--seconds 1.0] [--rounds 9] [--out PATH] [--results PATH]
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from biped_model.description import LEFT, load_description
from biped_model.gait_family import GaitFamily
from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.rigid import Simulator

from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.core.sensing.model_error import CompiledLegRegressor, LegRegressor, RneaLegRegressor
from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR

OUT = RESULTS_DIR / "model_error.json"
RESULTS = RESULTS_DIR / "results.json"
PERFECT = dict(momentum_observer=True)
REAL = dict(momentum_observer=True, state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14,
            sensor_noise_qd=5e-2, sensor_noise_pitch=1e-3, momentum_observer_gain=50.0)
NOISY = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14)
# name: (label, controller settings, plant perturbation, estimator on, estimator in the kernel)
CASES = {
    "observer": ("momentum observer (compiled), perfect sensors", PERFECT, None, False, True),
    "estimator_python": ("+ estimator in Python after the kernel (before)", PERFECT, None, True, False),
    "estimator": ("+ estimator inside the kernel (now)", PERFECT, None, True, True),
    "real": ("real-sensor profile (estimator + observer)", REAL, NOISY, False, True),
    "real_model_error": ("real-sensor profile + model-error estimator", REAL, NOISY, True, True),
}
BLOCK = 100     # periods of one case replayed in a row
KEYS = {"controller.step_p50_us_model_error": "estimator",
        "controller.step_p50_us_model_error_python": "estimator_python",
        "controller.step_p50_us_estimation_model_error": "real_model_error",
        "controller.step_p50_us_estimation_same_run": "real"}


def _controller(fam, desc, case: str) -> AdaptiveController:
    _, over, _, on, kernel = CASES[case]
    ctrl = AdaptiveController(load_controller_config(mode="both", model_error_estimator=on, **over), fam, desc)
    if on:
        ctrl._sensing.use_model_error_kernel(kernel)
    ctrl.reset(LEFT)
    return ctrl


def _observations(fam, desc, seconds: float, case: str) -> list:
    """The case's closed loop on the rigid plant: its observations (t, q, q', stance, pitch) per period."""
    sim = Simulator(desc, perturbation=CASES[case][2])
    ctrl = _controller(fam, desc, case)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    obs = []
    while sim.t < seconds and sim.fall is None:
        o = sim.observe()
        obs.append((o.t, o.q.copy(), o.qd.copy(), o.stance, o.pitch))
        sim.step(ctrl.compute(o.t, o.q, o.qd, o.stance, o.pitch).torque)
    return obs


def _replay(fam, desc, obs: dict) -> dict[str, np.ndarray]:
    """One round: a fresh controller per case, fed its observations in order, the cases in turn by blocks of
    ``BLOCK`` periods; per-call times [us] after the first 50 periods."""
    ctrls = {c: _controller(fam, desc, c) for c in CASES}
    ts = {c: [] for c in CASES}
    n = min(len(v) for v in obs.values())
    gc.collect()
    for k0 in range(0, n, BLOCK):
        for c, ctrl in ctrls.items():
            for k in range(k0, min(k0 + BLOCK, n)):
                t, q, qd, st, pitch = obs[c][k]
                t0 = time.perf_counter_ns()
                ctrl.compute(t, q, qd, st, pitch)
                ts[c].append(time.perf_counter_ns() - t0)
    return {c: np.array(v[50:]) * 1e-3 for c, v in ts.items()}


def _regressor_calls(desc, states) -> dict[str, float]:
    """p50 [us] of one call of each regressor over the loop's states (acceleration: a seeded draw)."""
    rng = np.random.default_rng(0)
    acc = rng.normal(0.0, 20.0, (len(states), 6))
    out = {}
    for name, reg in (("rnea", RneaLegRegressor(desc)), ("joint_torque_regressor", LegRegressor(desc)),
                      ("closed_form_compiled", CompiledLegRegressor(desc))):
        ts = []
        for (q, qd), a in zip(states, acc):
            t0 = time.perf_counter_ns()
            reg(q, qd, a)
            ts.append(time.perf_counter_ns() - t0)
        out[name] = round(float(np.percentile(ts, 50)) * 1e-3, 2)
    return out


def main(argv: list[str] | None = None) -> int:
    a = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    a.add_argument("--seconds", type=float, default=1.0)
    a.add_argument("--rounds", type=int, default=9)
    a.add_argument("--out", type=Path, default=OUT)
    a.add_argument("--results", type=Path, default=RESULTS, help="merge the keys here (skipped if missing)")
    args = a.parse_args(argv)
    provenance.track(args.out, args.results, argv=argv)   # record of each file written (results/README.md)
    fam, desc = GaitFamily.load(), load_description()
    obs = {c: _observations(fam, desc, args.seconds, c) for c in CASES}    # also compiles / loads the kernels
    load0 = os.getloadavg()[0]
    out: dict[str, list[np.ndarray]] = {c: [] for c in CASES}
    for _ in range(args.rounds):
        for c, ts in _replay(fam, desc, obs).items():
            out[c].append(ts)
    calls = _regressor_calls(desc, [(q, qd) for _, q, qd, _, _ in obs["estimator"]])
    load1 = os.getloadavg()[0]
    print(f"load average {load0:.1f} -> {load1:.1f}")
    res = {"meta": {"date": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()), "cpus": os.cpu_count(),
                    "load_avg_1min": load0, "load_avg_1min_end": load1, "python": platform.python_version(),
                    "seconds": args.seconds, "rounds": args.rounds},
           "step": {}, "round_p50_us": {}, "regressor_call_p50_us": calls}
    for c, (name, *_rest) in CASES.items():
        ts = np.concatenate(out[c])
        p50, p99 = float(np.percentile(ts, 50)), float(np.percentile(ts, 99))
        res["step"][c] = {"label": name, "p50_us": round(p50, 2), "p99_us": round(p99, 2), "calls": len(ts)}
        res["round_p50_us"][c] = [round(float(np.percentile(u, 50)), 2) for u in out[c]]
        print(f"{name:50s} p50 {p50:8.1f} us   p99 {p99:8.1f} us   ({len(ts)} calls)")
    S, RP = res["step"], res["round_p50_us"]
    res["ratios"] = {}
    for name, num, den in (("estimator_over_observer", "estimator", "observer"),
                           ("estimator_python_over_estimator", "estimator_python", "estimator"),
                           ("real_model_error_over_real", "real_model_error", "real")):
        res["ratios"][name] = round(S[num]["p50_us"] / S[den]["p50_us"], 3)
        res["ratios"][name + "_median_of_rounds"] = round(float(np.median(np.array(RP[num]) / np.array(RP[den]))), 3)
    res["keys"] = {k: S[c]["p50_us"] for k, c in KEYS.items()}
    res["target"] = {k: {"value": res["keys"][k], "target": "<= 30", "met": res["keys"][k] <= 30}
                     for k in ("controller.step_p50_us_model_error", "controller.step_p50_us_estimation_model_error")}
    print(f"ratios (p50): {res['ratios']}")
    print(f"regressor call alone p50 [us]: {calls}")
    print(f"targets (<= 30 us p50): {json.dumps(res['target'])}")
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"written {args.out}")
    if args.results is not None and args.results.exists():
        merged = json.loads(args.results.read_text())
        merged["model_error_step"] = res
        merged.setdefault("keys", {}).update(res["keys"])
        args.results.write_text(json.dumps(merged, indent=1, default=float) + "\n", encoding="utf-8")
        print(f"keys merged into {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
