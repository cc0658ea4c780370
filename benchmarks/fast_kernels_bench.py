"""Per-call times of the fast engine's kernels against the Pinocchio reference, measured in one run.

    python -m benchmarks.fast_kernels_bench [--states N] [--rounds R] [--json FILE]

For each of N seeded states on the stance foot's contact manifold, R rounds; in every round each
variant is timed over a batch of calls at that state (``time.perf_counter_ns``, per-call time = batch
time / batch size), the variants interleaved so that a slow moment of the shared machine hits all of
them alike. Reported: p50 and p99 of the per-call times [us] and the reference / fast ratio of p50s.

Variants:
  period           one 1 ms control period as the simulator runs it: 2 RK4 substeps of 0.5 ms with
                   the contact wrench at each substep start (fast: one ``rk4_steps`` call, n = 2;
                   reference: wrench + RK4 + wrench + RK4 with ``FloatingModel`` as ``Simulator``)
  rk4_step         one RK4 substep incl. projection and start wrench
  contact_dynamics M a + h = tau + J^T lambda, J a + J' v = 0
  controller_terms A, H, B, h_b and the torso point's x row (FixedFootModel.dynamics +
                   torso_point_jacobian for the reference)
"kernel" = the numba function called directly with preallocated outputs (what a hot loop does);
"wrapper" = the ``FastFloatingModel`` / ``FastFixedFootModel`` method (allocates its results).
Nothing is asserted: speed lives here, not in the tests.
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path
from time import perf_counter_ns

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `python benchmarks/fast_kernels_bench.py`
    sys.path.insert(0, str(ROOT))

from biped_model.fixed_foot import FixedFootModel  # noqa: E402
from biped_model.description import load_description  # noqa: E402
from biped_model.fast_engine import FastFixedFootModel, FastFloatingModel  # noqa: E402
from biped_model.floating import FloatingModel  # noqa: E402
from biped_controller.studies import provenance

H_SUB = 5e-4          # substep [s]: control period 1 ms, 2 substeps
PUSH = ((60.0, 0.3125),)  # one push acting over the whole period (force [N], height [m])


def ref_accel(ref: FloatingModel, x, v, tau_j, pushes, foot):
    tau = np.zeros(9)
    tau[3:] = tau_j
    for f, height in pushes:
        tau += ref.push_jacobian(x, height).T @ np.array([f, 0.0])
    sol = ref.contact_dynamics(x, v, tau, foot)
    return sol.a, sol.wrench


def ref_project(ref: FloatingModel, x, v, foot, anchor):
    x = x.copy()
    pose = ref.foot_pose(x, foot)
    x[2] += anchor[2] - pose[2]
    pose = ref.foot_pose(x, foot)
    x[0] += anchor[0] - pose[0]
    x[1] += anchor[1] - pose[1]
    J = ref.contact_jacobian(x, foot)
    MiJt = ref.inverse_mass_matrix(x) @ J.T
    return x, v - MiJt @ np.linalg.solve(J @ MiJt, J @ v)


def ref_rk4(ref: FloatingModel, x, v, tau_j, pushes, foot, anchor, h):
    """As ``Simulator._rk4`` with constant torque and pushes (the reference engine's work per substep)."""
    k1v, _ = ref_accel(ref, x, v, tau_j, pushes, foot)
    k2x = v + 0.5 * h * k1v
    k2v, _ = ref_accel(ref, x + 0.5 * h * v, k2x, tau_j, pushes, foot)
    k3x = v + 0.5 * h * k2v
    k3v, _ = ref_accel(ref, x + 0.5 * h * k2x, k3x, tau_j, pushes, foot)
    k4x = v + h * k3v
    k4v, _ = ref_accel(ref, x + h * k3x, k4x, tau_j, pushes, foot)
    xn = x + (h / 6.0) * (v + 2 * k2x + 2 * k3x + k4x)
    vn = v + (h / 6.0) * (k1v + 2 * k2v + 2 * k3v + k4v)
    return ref_project(ref, xn, vn, foot, anchor)


def ref_period(ref, x, v, tau_j, pushes, foot, anchor):
    _, w0 = ref_accel(ref, x, v, tau_j, pushes, foot)
    x1, v1 = ref_rk4(ref, x, v, tau_j, pushes, foot, anchor, H_SUB)
    _, w1 = ref_accel(ref, x1, v1, tau_j, pushes, foot)
    return ref_rk4(ref, x1, v1, tau_j, pushes, foot, anchor, H_SUB), w0, w1


def per_call_us(fn, batch: int) -> float:
    t0 = perf_counter_ns()
    for _ in range(batch):
        fn()
    return (perf_counter_ns() - t0) / batch / 1e3


def run(n_states: int, rounds: int) -> dict:
    desc = load_description()
    ref, fast = FloatingModel(desc), FastFloatingModel(desc)
    ref_ctrl, fast_ctrl = FixedFootModel(desc), FastFixedFootModel(desc)
    ti, tf, cti, ctf = fast.ti, fast.tf, fast_ctrl.ti, fast_ctrl.tf
    pk = fast.pk
    forces = np.array([f for f, _ in PUSH])
    heights = np.array([hh for _, hh in PUSH])
    xo, vo, w = np.empty(9), np.empty(9), np.empty(3)
    X, V, W, P = np.empty((2, 9)), np.empty((2, 9)), np.empty((2, 3)), np.empty((2, 3))
    a, lam = np.empty(9), np.empty(3)
    A, Hv, B, hb, jp = np.empty((6, 6)), np.empty(6), np.empty((3, 6)), np.empty(3), np.empty(9)
    times: dict[str, list[float]] = {}

    def rec(name, fn, batch):
        times.setdefault(name, []).append(per_call_us(fn, batch))

    rng = np.random.default_rng(20261123)
    states = []
    for _ in range(n_states):
        stance = int(rng.integers(0, 2))
        q, qd = rng.uniform(-0.5, 0.5, 6), rng.normal(0.0, 1.0, 6)
        x, v = ref.state_from_paper(q, qd, stance)
        states.append((x, v, stance, np.zeros(3), rng.normal(0.0, 30.0, 6), q, qd))
    # warm-up (caches, branch predictors) and a check that the variants compute the same period
    for x, v, stance, anchor, tau_j, q, qd in states[:3]:
        (xr, vr), w0, _ = ref_period(ref, x, v, tau_j, PUSH, stance, anchor)
        pk.rk4_steps(ti, tf, x, v, tau_j, forces, heights, stance, anchor, H_SUB, X, V, W, P)
        assert np.allclose(X[1], xr, atol=1e-10) and np.allclose(V[1], vr, atol=1e-9) and np.allclose(W[0], w0)
    for _ in range(rounds):
        for x, v, stance, anchor, tau_j, q, qd in states:
            tau = np.concatenate([np.zeros(3), tau_j])
            rec("period.fast_kernel", lambda: pk.rk4_steps(ti, tf, x, v, tau_j, forces, heights, stance, anchor,
                                                           H_SUB, X, V, W, P), 20)
            rec("period.fast_wrapper", lambda: fast.rk4_steps(x, v, tau_j, PUSH, stance, anchor, H_SUB, 2), 20)
            rec("period.reference", lambda: ref_period(ref, x, v, tau_j, PUSH, stance, anchor), 2)
            rec("rk4_step.fast_kernel", lambda: pk.rk4_step(ti, tf, x, v, tau_j, forces, heights, stance, anchor,
                                                            H_SUB, xo, vo, w), 20)
            rec("rk4_step.fast_wrapper", lambda: fast.rk4_step(x, v, tau_j, PUSH, stance, anchor, H_SUB), 20)
            rec("rk4_step.reference", lambda: ref_rk4(ref, x, v, tau_j, PUSH, stance, anchor, H_SUB), 2)
            rec("contact_dynamics.fast_kernel", lambda: pk.contact_dynamics(ti, tf, x, v, tau, stance, a, lam), 50)
            rec("contact_dynamics.fast_wrapper", lambda: fast.contact_dynamics(x, v, tau, stance), 50)
            rec("contact_dynamics.reference", lambda: ref.contact_dynamics(x, v, tau, stance), 10)
            rec("controller_terms.fast_kernel", lambda: pk.fixed_root_terms(cti, ctf, q, qd, 0.3125, A, Hv, B, hb, jp), 50)
            rec("controller_terms.fast_wrapper", lambda: fast_ctrl.terms(q, qd, 0.3125), 50)
            rec("controller_terms.reference",
                lambda: (ref_ctrl.dynamics(q, qd), ref_ctrl.torso_point_jacobian(q, 0.3125)[0]), 10)
            rec("call_floor.swing_probe_kernel", lambda: pk.swing_probe(ti, tf, x, v, 1 - stance, w), 50)
    out: dict = {"states": n_states, "rounds": rounds, "python": sys.version.split()[0],
                 "machine": platform.machine(), "numba": pk.numba.__version__, "per_call_us": {}}
    for name, ts in times.items():
        arr = np.asarray(ts)
        out["per_call_us"][name] = {"p50": float(np.percentile(arr, 50)), "p99": float(np.percentile(arr, 99)),
                                    "n": int(arr.size)}
    pc = out["per_call_us"]
    out["ratio_reference_over_fast_kernel_p50"] = {
        k: pc[f"{k}.reference"]["p50"] / pc[f"{k}.fast_kernel"]["p50"]
        for k in ("period", "rk4_step", "contact_dynamics", "controller_terms")
    }
    out["realtime_factor_bound"] = {  # 1 ms of simulated time per period, physics alone
        "fast_kernel": 1000.0 / pc["period.fast_kernel"]["p50"],
        "reference": 1000.0 / pc["period.reference"]["p50"],
    }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--states", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None, help="also write the results to this file")
    args = ap.parse_args(argv)
    provenance.track(args.json, argv=argv)   # record of each file written (results/README.md)
    res = run(args.states, args.rounds)
    print(f"{'variant':40s} {'p50 [us]':>10s} {'p99 [us]':>10s}")
    for name, r in res["per_call_us"].items():
        print(f"{name:40s} {r['p50']:10.2f} {r['p99']:10.2f}")
    for k, r in res["ratio_reference_over_fast_kernel_p50"].items():
        print(f"reference / fast kernel, {k}: {r:.1f}x")
    b = res["realtime_factor_bound"]
    print(f"physics-only real-time factor bound (1 ms / period p50): fast {b['fast_kernel']:.0f}x, "
          f"reference {b['reference']:.1f}x")
    if args.json is not None:
        args.json.write_text(json.dumps(res, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
