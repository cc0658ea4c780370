"""The touchdown band's spread against the truth (``core/sensing/touchdown_band.py``): on a noisy walk with
the issue's delay row (real-sensor profile, predictor d, the touchdown delayed, noise 5e-4 rad, 5e-2 rad/s,
14 bits, seed 0), every period where the compiled pipeline evaluated the band (the swing sole descending),
the predicted sole height without a touchdown z, its standard deviation sigma_z, and the true sole height of
the plant at that instant (same stance): the error's rms [m], and the error over sigma_z (rms, quantiles,
maximum): is sigma_z an honest statement of the height error, to the tails the band's k must cover? Writes
``results/benchmarks/touchdown_band.json``; nothing is asserted.

    .venv/bin/python -m benchmarks.touchdown_band_bench [--steps 20] [--delay 2] [--seed 0]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from biped_sim.plant.perturbation import PlantPerturbation
from biped_sim.plant.rigid import Simulator
from biped_model.description import LEFT, load_description
from biped_model.gait_family import GaitFamily

from biped_controller.core.control.config import load_controller_config
from biped_controller.core.control.controller import AdaptiveController
from biped_controller.studies import provenance
from benchmarks import RESULTS_DIR

REAL = dict(momentum_observer=True, state_estimator=True, sensor_noise_q=5e-4, sensor_encoder_bits=14,
            sensor_noise_qd=5e-2, sensor_noise_pitch=1e-3, momentum_observer_gain=50.0)


def heights(steps: int, delay: int, seed: int) -> dict:
    fam, desc = GaitFamily.load(), load_description()
    pert = PlantPerturbation(noise_q=5e-4, noise_qd=5e-2, encoder_bits=14, delay=delay, touchdown_delayed=True,
                             seed=seed)
    sim = Simulator(desc, perturbation=pert)
    ctrl = AdaptiveController(load_controller_config(mode="both", delay_compensation=delay, **REAL), fam, desc)
    sens = ctrl._sensing
    ek, ti, tf = sens.ek, sens.ti, sens.tf
    q0, qd0 = fam.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    err, z_over = [], []
    while sim.impact_count < steps and sim.fall is None:
        qt, _ = sim.fm.paper_from_state(sim.x, sim.v, sim.stance)
        st = sim.stance
        obs = sim.observe()
        sens.last_height = None
        out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch, obs.pitch_rate)
        h = sens.last_height
        if h is not None and h[1] == st:
            zt = float(ek.lowest_sole(ti, tf, np.ascontiguousarray(qt)))
            err.append(h[2] - zt)
            z_over.append((h[2] - zt) / h[3])
        sim.step(out.torque)
    e, z = np.array(err), np.array(z_over)
    return {"steps": sim.impact_count, "fallen": sim.fall is not None, "periods": int(e.size),
            "band_periods": ctrl.band_periods, "band_changed": ctrl.band_changed,
            "err_rms_m": float(np.sqrt((e ** 2).mean())), "over_sigma_rms": float(np.sqrt((z ** 2).mean())),
            "over_sigma_abs_q50_q90_q99": np.quantile(np.abs(z), [0.5, 0.9, 0.99]).round(3).tolist(),
            "over_sigma_abs_max": float(np.abs(z).max())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.touchdown_band_bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--delay", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, default=RESULTS_DIR / "touchdown_band.json")
    args = ap.parse_args(argv)
    provenance.track(args.json, argv=argv)   # record of each file written (results/README.md)
    res = {"when": time.strftime("%Y-%m-%d %H:%M:%S"), "delay": args.delay, "seed": args.seed,
           **heights(args.steps, args.delay, args.seed)}
    for k, v in res.items():
        print(f"{k}: {v}")
    args.json.write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
