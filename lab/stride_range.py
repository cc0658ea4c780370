"""Which constraints bind where a robot's valid stride range ends: the gait NLP's active rows stride by stride.

    .venv/bin/python -m lab.stride_range ROBOT [--from 0.43 --to 0.49] --json F

For each fitted and held-out stride of ROBOT's committed family in [from, to]: its criterion, the fit error of
the fitted family there (held-out strides: the optimum against the family's interpolation; fitted strides:
round-off), and the NLP's inequality rows active at the stored solution (scaled margin < 1e-6), named by row and
grid instant (0 = touchdown, ``grid_intervals`` = the next one): the 17 contact and torque rows of eqs. (5)-(8)
(``take_off`` is R_y >= min_normal_force M g, ``zmp_heel``/``zmp_toe`` the centre of pressure within the design
margin of the heel/toe), the swing foot's heel/toe clearance, the knee limits (``knee``) and the end-of-step
rows (``end``). The family's valid range and the fit tolerance are copied from the file and its gait.yaml.
Writes the JSON with its provenance record; prints one line per stride.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROW = (["take_off", "slide_forward", "slide_backward", "zmp_heel", "zmp_toe"]
       + [f"gamma{i + 1}_max" for i in range(6)] + [f"gamma{i + 1}_min" for i in range(6)])


def active_rows(opt, rec: dict, tol: float = 1e-6) -> list[str]:
    """The inequality rows of ``opt``'s NLP active at the stored solution ``rec`` (its stride and c)."""
    n = opt.n
    opt.p = float(rec["stride"])
    opt.penalty_target, opt.penalty_weight, opt._cache_key = None, 0.0, None
    g = opt.evaluate(np.asarray(rec["c"], float).ravel())["ineq"]
    G = g[:17 * (n + 1)].reshape(n + 1, 17)
    out = [f"{ROW[r]}@{k}" for k, r in zip(*np.nonzero(G < tol))]
    off = 17 * (n + 1)
    cl = g[off:off + 2 * (n - 1)].reshape(n - 1, 2)
    out += [f"clearance_{'heel' if j == 0 else 'toe'}@{k + 1}" for k, j in zip(*np.nonzero(cl < tol))]
    off += 2 * (n - 1)
    kn = g[off:off + 4 * (n + 1)].reshape(4, n + 1)
    out += [f"knee_{('stance_min', 'stance_max', 'swing_min', 'swing_max')[j]}@{k}" for j, k in zip(*np.nonzero(kn < tol))]
    off += 4 * (n + 1)
    end = ("touchdown_speed", "touchdown_descent", "impulse_normal", "impulse_friction_fwd", "impulse_friction_bwd",
           "liftoff_speed")
    out += [f"end_{end[j]}" for j in np.nonzero(g[off:] < tol)[0]]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.stride_range", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("robot")
    ap.add_argument("--from", dest="lo", type=float, default=0.43)
    ap.add_argument("--to", dest="hi", type=float, default=0.49)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    from biped_model.robot import resolve_robot
    from biped_controller.gaits.fast_eval import FastStepOptimizer
    from biped_controller.gaits.optimizer import load_gait_settings
    from biped_controller.studies import provenance
    provenance.track(args.json, robot=args.robot, argv=argv)
    robot = resolve_robot(args.robot)
    st = load_gait_settings(robot.gait_path)
    opt = FastStepOptimizer(desc=robot.description(), settings=st)
    data = json.loads(robot.family_path.read_text(encoding="utf-8"))
    fit = {r["stride"]: r for r in data["validation"]["strides"]}
    held = {r["stride"]: r for r in data["validation"]["held_out"]}
    rows = []
    recs = [(r, False) for r in data["strides"]] + [(r, True) for r in data.get("held_out", [])]
    for rec, is_held in sorted(recs, key=lambda x: x[0]["stride"]):
        p = rec["stride"]
        if not args.lo <= p <= args.hi:
            continue
        v = (held if is_held else fit).get(p, {})
        rows.append({"stride": p, "held_out": is_held, "criterion": rec["criterion"],
                     "fit_error_q": v.get("fit_error_q"), "fit_error_qdot": v.get("fit_error_qdot"),
                     "within_tolerance": (v.get("fit_error_q", np.inf) <= st.fit_tolerance_q
                                          and v.get("fit_error_qdot", np.inf) <= st.fit_tolerance_qdot),
                     "active": active_rows(opt, rec)})
        r = rows[-1]
        print(f"{p:.4f}{'h' if is_held else ' '} C {r['criterion']:8.1f} fit q {r['fit_error_q']:.1e} "
              f"qd {r['fit_error_qdot']:.1e} {'ok ' if r['within_tolerance'] else 'OUT'} active: {' '.join(r['active'])}")
    out = {"robot": robot.name, "p_d": data["family"]["p_d"], "valid_range": [data["family"]["p_min"], data["family"]["p_max"]],
           "fit_tolerance_q": st.fit_tolerance_q, "fit_tolerance_qdot": st.fit_tolerance_qdot,
           "zmp_margin": st.zmp_margin, "min_normal_force": st.min_normal_force, "grid_intervals": opt.n, "rows": rows}
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
