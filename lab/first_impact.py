"""Why modes none and capture_point fall unpushed on the rigid plant on the new robots, at their first impact.

    .venv/bin/python -m lab.first_impact [--robots biped7,biped7_foot10,biped7_foot05,human70] [--labels A,B,...] --json F

For each robot, unpushed, on the rigid plant (the robot's own settings, the default profile):

* **design at t = 0** (the start of the preferred step, q_d(p_d, 0) with tau' = 1): the ankle torque
  Gamma_1 [N m], the vertical reaction R_y [N] and the centre of pressure l = Gamma_1 / R_y [m] of the fixed-foot
  inverse dynamics, the heel l_min [m] and the slack l(0) - l_min [m]; the gait NLP's constraint rows active at
  the grid's first instant (``take_off``: R_y >= min_normal_force M g; ``zmp_heel``: l >= l_min + margin) at p_d;
* **the first control period after the first impact**, mode none (computed torque on q_d(p_d, t)): the
  plant's Gamma_1, R_y and l; the tracking error there (max |q - q_d| [rad], max |q' - q_d'| [rad/s]); and
  the decomposition of its Gamma_1 by inverse dynamics at the plant's state: with the reference's own
  acceleration q_d'' only (``feedforward``) and with the PD term of eq. (16) added (``with_pd``, which is the
  controller's law: it equals the plant's Gamma_1);
* the unpushed 10-step walks of modes none and both and of the ``capture_point`` example (steps, fall cause,
  first post-impact l), and mode none with the joint PD gains a quarter and four times the configured ones
  (one change at a time).

Writes the JSON (``--json``) with the provenance record of the file. Nothing here is imported by the product.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROW = ["take_off", "slide_forward", "slide_backward", "zmp_heel", "zmp_toe"]


def _active_at_start(robot) -> list[str]:
    """The gait NLP's contact rows active (scaled margin < 1e-6) at the first grid instant, at p_d."""
    from biped_controller.gaits.fast_eval import FastStepOptimizer
    from biped_controller.gaits.optimizer import load_gait_settings
    opt = FastStepOptimizer(desc=robot.description(), settings=load_gait_settings(robot.gait_path))
    data = json.loads(robot.family_path.read_text(encoding="utf-8"))
    rec = min(data["strides"], key=lambda r: abs(r["stride"] - data["family"]["p_d"]))
    opt.p = rec["stride"]
    g = opt.evaluate(np.asarray(rec["c"], float).ravel())["ineq"][:17 * (opt.n + 1)].reshape(opt.n + 1, 17)
    return [ROW[i] for i in range(5) if g[0, i] < 1e-6]


def _first_post_impact(result):
    k = next((i for i, rec in enumerate(result.records) if rec.stance != result.records[0].stance), None)
    return (None, None) if k is None else (result.records[k], result.statuses[k] if result.statuses else None)


def _walk_row(result) -> dict:
    rec, _ = _first_post_impact(result)
    return {"steps": int(result.steps_walked), "fallen": bool(result.fallen), "cause": result.fall_cause or None,
            "first_post_impact_cop": None if rec is None else float(rec.cop)}


def robot_row(name: str) -> dict:
    from biped_model.fixed_foot import FixedFootModel
    from biped_model.robot import resolve_robot
    from biped_controller.closed_loop import runner
    from biped_controller.studies.trial.context import context
    from biped_controller.studies.trial.plugin_trials import trials_for
    from biped_controller.studies.trial.runs import run
    from biped_controller.studies.trial.settings import parse_overrides
    s = parse_overrides((), robot=name)
    ctx = context(s.activate().robot)
    fam, desc = ctx.family, ctx.desc
    ff = FixedFootModel(desc)
    q0, qd0, qdd0 = fam.reference(fam.p_d, 0.0, 0.0, 1.0)
    g0, r0 = ff.inverse_dynamics(q0, qd0, qdd0)
    out = {"robot": name, "mass": desc.total_mass, "foot": [desc.foot.l_min, desc.foot.l_max], "p_d": fam.p_d,
           "design_t0": {"gamma1": float(g0[0]), "ry": float(r0[1]), "cop": float(g0[0] / r0[1]),
                         "ry_over_mg": float(r0[1] / (desc.total_mass * desc.gravity)),
                         "slack_to_heel": float(g0[0] / r0[1] - desc.foot.l_min),
                         "active_rows_at_t0": _active_at_start(resolve_robot(name))}}
    none = run(10, "none", settings=s)
    rec, st = _first_post_impact(none)
    ccfg = s.ctrl_config("none")
    q, qd = np.asarray(rec.q), np.asarray(rec.qd)
    qr, qdr, qddr = fam.reference(st.p, st.p_dot, st.tau, st.tau_dot)
    ga, ra = ff.inverse_dynamics(q, qd, qddr)
    gb, rb = ff.inverse_dynamics(q, qd, qddr - ccfg.Kv * (qd - qdr) - ccfg.Kp * (q - qr))
    out["first_period_after_impact_none"] = {
        "t": float(rec.t), "gamma1": float(rec.torque[0]), "ry": float(rec.wrench[1]), "cop": float(rec.cop),
        "max_abs_e_q": float(np.max(np.abs(q - qr))), "max_abs_e_qdot": float(np.max(np.abs(qd - qdr))),
        "feedforward": {"gamma1": float(ga[0]), "cop": float(ga[0] / ra[1])},
        "with_pd": {"gamma1": float(gb[0]), "cop": float(gb[0] / rb[1])},
        "pd_share_gamma1": float(gb[0] - ga[0]), "Kp": ccfg.Kp, "Kv": ccfg.Kv}
    walks = {"none": _walk_row(none), "both": _walk_row(run(10, "both", settings=s)),
             "capture_point": _walk_row(trials_for("capture_point", s).loop.run(10, ()))}
    for scale in (0.25, 4.0):
        kp, kv = ccfg.Kp * scale, ccfg.Kv * np.sqrt(scale)
        sg = parse_overrides((f"Kp={kp}", f"Kv={kv}"), robot=name)
        r = runner.run(10, "none", (), sim_config=sg.sim_config(), ctrl_config=sg.ctrl_config("none"),
                       family=fam, desc=desc)
        walks[f"none_Kp{kp:g}_Kv{kv:g}"] = _walk_row(r)
    out["walks"] = walks
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.first_impact", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", default="biped7,biped7_foot10,biped7_foot05,human70")
    ap.add_argument("--labels", default=None, help="a name for each robot's row (default the robot as given)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    from biped_controller.studies import provenance
    provenance.track(args.json, plant="rigid", argv=argv)
    names = args.robots.split(",")
    labels = args.labels.split(",") if args.labels else names
    if len(labels) != len(names):
        ap.error("--labels: one label per robot")
    rows = [{"label": lab, **robot_row(n)} for n, lab in zip(names, labels)]
    for r in rows:
        d, f = r["design_t0"], r["first_period_after_impact_none"]
        print(f"{r['robot']:14s} design l(0) {d['cop']:+.4f} (heel {r['foot'][0]:+.3f}, slack {d['slack_to_heel']:.4f} m, "
              f"R_y {d['ry']:.1f} N = {d['ry_over_mg']:.2f} Mg, active {d['active_rows_at_t0']}) | after impact: "
              f"Gamma1 {f['gamma1']:+.2f} (feedforward {f['feedforward']['gamma1']:+.2f}, PD {f['pd_share_gamma1']:+.2f}) "
              f"R_y {f['ry']:.1f} l {f['cop']:+.4f} | " + ", ".join(f"{k}: {w['steps']}{' ' + w['cause'] if w['fallen'] else ''}"
                                                               for k, w in r["walks"].items()))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"rows": rows}, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
