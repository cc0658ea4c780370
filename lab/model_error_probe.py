"""The momentum observer under model error, period by period (docs/robustness.md, "Why (from the
table's run)"): one pushed run with the Python sensing pipeline, printing per period the ground force the QP
needed (the plant's actual minus the controller's prediction without the estimate), the estimate it used
(dR), the reading of the observer's whole r through the joint accelerations alone (B A^-1 r), and the
observer's r against the true generalized force of the error, tau_d = A_m q'' + H_m - Gamma with q'' the
plant's own acceleration (its model from ``PlantPerturbation.apply``, rigid stance foot). Forces [N],
torques [N m], l [m]; with the legs' model-error estimator, its theta divided by the prior std (model_error.py).

    .venv/bin/python -m lab.model_error_probe --force 200 --from 0.40 --to 0.46 \\
        --set momentum_observer=true --perturb torso_inertia_scale=1.3 ...
"""
from __future__ import annotations

import sys

import numpy as np

from biped_model.description import LEFT
from biped_model.fixed_foot import FixedFootModel
from biped_sim.plant.protocol import make_plant
from biped_sim.plant.push import Push

from biped_controller.core.control.controller import AdaptiveController
from biped_controller.studies.trial.args import (StudyArgumentParser, add_settings_args, finite_float, positive_int,
                                                 settings_from_args)
from biped_controller.studies.trial.context import context
from biped_controller.studies.trial.runs import paper_push
from biped_controller.studies.trial.settings import OverrideError, RunSettings


def probe_rows(push: Push, settings: RunSettings, steps: int = 2) -> tuple[list[dict], str]:
    """The rows of the module docstring for every period until ``steps`` impacts or a fall, and the outcome
    (``push`` with a zero force: none)."""
    ctx = context()
    scfg, ccfg = settings.sim_config(), settings.ctrl_config("both")
    P = settings.perturbation
    sim = make_plant(scfg.plant, ctx.desc, scfg, P)
    ctrl = AdaptiveController(ccfg, ctx.family, ctx.desc, python_sensing=True)
    mo = ctrl._sensing.mo if ctrl._sensing is not None else None
    me = ctrl._sensing.me if ctrl._sensing is not None else None
    sd0 = np.sqrt(np.diag(me.P0)) if me is not None else None
    if mo is None:
        raise OverrideError("the probe needs --set momentum_observer=true")
    plant = FixedFootModel(P.apply(ctx.desc) if P is not None else ctx.desc)
    model = FixedFootModel(ctx.desc)
    q0, qd0 = ctx.family.initial_state()
    sim.reset(q0, qd0, LEFT)
    ctrl.reset(LEFT)
    if push.force:
        sim.schedule_push(push.start, push.duration, float(push.force), push.height)
    rows = []
    while True:
        obs = sim.observe()
        out = ctrl.compute(obs.t, obs.q, obs.qd, obs.stance, obs.pitch)
        rec = sim.step(out.torque)
        w = ctrl.wrench
        dp, dm = plant.dynamics(rec.q, rec.qd), model.dynamics(rec.q, rec.qd)
        qdd = np.linalg.solve(dp.A, rec.torque - dp.H)
        s = out.status
        dyn = model.dynamics(obs.q, obs.qd)
        full = dyn.B @ np.linalg.solve(dyn.A, w.r) if w is not None else np.zeros(3)
        dR = w.dR if w is not None else np.zeros(2)
        rows.append(dict(t=rec.t, impacts=rec.impacts, push=rec.push_force, qp_status=int(s.qp_status),
                         l_pred=s.zmp, l_act=rec.cop,
                         needed=np.asarray(rec.wrench[:2]) - np.asarray(s.predicted_reaction) + dR, dR=dR,
                         full=full[:2], r=w.r if w is not None else np.zeros(6),
                         tau_d=dm.A @ qdd + dm.H - rec.torque,
                         theta=(me.theta / sd0) if me is not None else None))
        if rec.fallen or sim.fall is not None or sim.impact_count >= steps:
            break
    f = sim.fall
    return rows, (f"fell: {f.cause} at t = {f.t:.4f} s ({f.detail})" if f else f"{sim.impact_count} impacts, no fall")


def main(argv: list[str] | None = None) -> int:
    a = StudyArgumentParser(prog="python -m lab.model_error_probe",
                            description=__doc__.split("\n\n")[0])
    a.add_argument("--force", type=finite_float, default=0.0, help="[N] of the paper's push (0: none)")
    a.add_argument("--from", dest="t0", type=finite_float, default=0.0)
    a.add_argument("--to", dest="t1", type=finite_float, default=1.0)
    a.add_argument("--every", type=positive_int, default=3,
                   help="print every n-th period (and every period after an impact)")
    a.add_argument("--steps", type=positive_int, default=2)
    add_settings_args(a, observer=False, full_trials=False)
    args = a.parse_args(argv)
    settings = settings_from_args(a, args)
    try:
        rows, outcome = probe_rows(paper_push(args.force), settings, steps=args.steps)
    except OverrideError as exc:
        a.error(str(exc))
    f = lambda v: f"({v[0]:7.1f},{v[1]:7.1f})"   # noqa: E731
    print("t [s]   imp push qp  l_pred   l_act   needed dR (x,y)   used dR (x,y)   B A^-1 r (x,y)   r | true tau_d"
          " [| legs' theta / its prior std, with the model-error estimator]")
    last_imp = 0
    for k, r in enumerate(rows):
        if not args.t0 <= r["t"] <= args.t1:
            continue
        if k % args.every and r["impacts"] == last_imp:
            continue
        print(f"{r['t']:.4f} {r['impacts']:3d} {r['push']:4.0f} {r['qp_status']:2d} {r['l_pred']:+.4f} {r['l_act']:+.4f} "
              f"{f(r['needed'])} {f(r['dR'])} {f(r['full'])}  {np.round(r['r'], 1)} | {np.round(r['tau_d'], 1)}"
              + (f" | {np.round(r['theta'], 2)}" if r["theta"] is not None else ""))
        last_imp = r["impacts"]
    print(outcome)
    return 0


if __name__ == "__main__":
    sys.exit(main())
