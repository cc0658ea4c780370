"""Cost of the controller's period with real sensing: ``AdaptiveController.compute`` per call in
a closed loop on the rigid plant, p50/p99, side by side in one run: the plain compiled step (estimation
off), the compiled step with the compiled sensing pipeline (``controller.step_p50_us_estimation``: the
real-sensor profile, estimator + momentum observer, under noise 5e-4 rad, 5e-2 rad/s and 14 bits; and the
momentum observer alone on perfect sensors; the observer and the predictor for a delay of 2 periods; the
real-sensor profile with the gyro fused, ``_estimation_gyro``; and with the predictor for a delay of 2 periods,
the touchdown delayed, and the touchdown band, ``_estimation_predictor_d2_band``), and
the Python pipeline with the Python steps (the oracle). Writes ``results/benchmarks/estimation.json``; targets are printed,
never asserted.

    .venv/bin/python -m benchmarks.estimation_bench [--seconds 1.0] [--rounds 3]

Also the estimator's accuracy on a 2 s noisy walk (``accuracy``: errors against the true state, and the
momentum observer's wrench without a push), stored under ``accuracy``.
"""
from __future__ import annotations

import argparse
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
from biped_controller.core.sensing.estimation import Estimate
from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR

REAL = dict(momentum_observer=True, state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14,
            sensor_noise_qd=5e-2, sensor_noise_pitch=1e-3, momentum_observer_gain=50.0)
NOISY = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14)
GYRO = dict(REAL, estimator_gyro=True, sensor_noise_pitch_rate=5e-3)
NOISY_GYRO = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, noise_pitch_rate=5e-3)
# the delay row with real sensors: the predictor d = 2 and the touchdown band (touchdown_band.py)
DELAY_ROW = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, delay=2, touchdown_delayed=True)
# key: (controller settings, plant perturbation, Python pipeline and steps)
CASES = {
    "controller.step_p50_us_compiled_no_estimation": (dict(), PlantPerturbation(), False),
    "controller.step_p50_us_estimation": (REAL, NOISY, False),
    "controller.step_p50_us_estimation_gyro": (GYRO, NOISY_GYRO, False),
    "controller.step_p50_us_estimation_predictor_d2_band": (dict(REAL, delay_compensation=2), DELAY_ROW, False),
    "controller.step_p50_us_momentum_observer": (dict(momentum_observer=True), PlantPerturbation(), False),
    "controller.step_p50_us_predictor_d2": (dict(momentum_observer=True, delay_compensation=2),
                                            PlantPerturbation(delay=2), False),
    "controller.step_p50_us_momentum_observer_python": (dict(momentum_observer=True), PlantPerturbation(), True),
    "controller.step_p50_us_estimation_python": (REAL, NOISY, True),
    "controller.step_p50_us_predictor_d2_python": (dict(momentum_observer=True, delay_compensation=2),
                                                   PlantPerturbation(delay=2), True),
}


def time_case(over: dict, pert: PlantPerturbation, seconds: float, python_sensing: bool = False) -> np.ndarray:
    fam, desc = GaitFamily.load(), load_description()
    sim = Simulator(desc, perturbation=pert)
    ctrl = AdaptiveController(load_controller_config(mode="both", **over), fam, desc, python_sensing=python_sensing)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    out = []
    while sim.t < seconds and sim.fall is None:
        obs = sim.observe()
        t0 = time.perf_counter_ns()
        o = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch, obs.pitch_rate)
        out.append(time.perf_counter_ns() - t0)
        sim.step(o.torque)
    return np.array(out[10:]) * 1e-3


def accuracy(seconds: float = 2.0) -> dict:
    """A noisy walk (5e-4 rad, 5e-2 rad/s, 14 bits, seed 0) with the real-sensor profile: the estimator's
    errors against the true state (rms, and divided by its own standard deviations), the raw rate
    sensor's error, and the momentum observer's wrench (no push: all of it is noise and model error)."""
    fam, desc = GaitFamily.load(), load_description()
    sim = Simulator(desc, perturbation=PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14))
    ctrl = AdaptiveController(load_controller_config(mode="both", **REAL), fam, desc)
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    eq, eqd, zq, zqd, raw, W = [], [], [], [], [], []
    while sim.t < seconds and sim.fall is None:
        qt, qdt = sim.fm.paper_from_state(sim.x, sim.v, sim.stance)
        st = sim.stance
        obs = sim.observe()
        out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch)
        sp = ctrl._sensing
        e = sp.est.estimate() if hasattr(sp, "est") else Estimate(q=sp.state[:6].copy(), qd=sp.state[6:12].copy(),
                                                                   P=sp.P)
        if obs.stance == st:
            eq.append(e.q - qt)
            eqd.append(e.qd - qdt)
            zq.append((e.q - qt) / e.std_q)
            zqd.append((e.qd - qdt) / e.std_qd)
            raw.append(obs.qd - qdt)
        if ctrl.wrench is not None:
            W.append(ctrl.wrench.W)
        sim.step(out.torque)
    rms = lambda a: np.sqrt((np.array(a) ** 2).mean(axis=0)).round(6).tolist()  # noqa: E731
    Wa = np.array(W)
    return {"fallen": sim.fall is not None, "impacts": sim.impact_count, "q_err_rms_rad": rms(eq),
            "qd_err_rms_rad_s": rms(eqd), "q_err_over_std_rms": rms(zq), "qd_err_over_std_rms": rms(zqd),
            "raw_qd_err_rms_rad_s": rms(raw), "wrench_std": Wa.std(axis=0).round(2).tolist(),
            "wrench_p95_abs": np.percentile(np.abs(Wa), 95, axis=0).round(2).tolist()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.estimation_bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=1.0, help="simulated time per case [s]")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of all the cases, interleaved; times pooled")
    ap.add_argument("--json", type=Path, default=RESULTS_DIR / "estimation.json")
    args = ap.parse_args(argv)
    provenance.track(args.json, argv=argv)   # record of each file written (results/README.md)
    res = {"when": time.strftime("%Y-%m-%d %H:%M:%S"), "cpus": os.cpu_count(), "machine": platform.machine(),
           "seconds": args.seconds, "keys": {}}
    times = {key: [] for key in CASES}
    for _ in range(args.rounds):            # the cases interleaved, so that a load spike meets all of them
        for key, (over, pert, python) in CASES.items():
            times[key].append(time_case(over, pert, args.seconds, python))
    res["rounds"] = args.rounds
    res["round_p50_us"] = {key: [round(float(np.percentile(u, 50)), 2) for u in v] for key, v in times.items()}
    for key in CASES:
        us = np.concatenate(times[key])
        res["keys"][key] = float(np.percentile(us, 50))
        res["keys"][key.replace("p50", "p99")] = float(np.percentile(us, 99))
        print(f"{key:<52} p50 {np.percentile(us, 50):8.1f} us  p99 {np.percentile(us, 99):8.1f} us  ({us.size} calls)")
    p50 = res["keys"]["controller.step_p50_us_estimation"]
    print(f"target: the compiled step with estimation <= 30 us p50: {p50:.1f} us "
          f"({'met' if p50 <= 30 else 'not met'} on this run)")
    res["accuracy"] = accuracy()
    for k, v in res["accuracy"].items():
        print(f"accuracy {k}: {v}")
    args.json.write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
