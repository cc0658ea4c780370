"""One-change MuJoCo walks that the product's settings cannot express (a research script, not product code):
the torques the plant applies, or the MJCF, patched for one run, then the figures of
``lab.foot_quiet``. Usage (from the repository root)::

    .venv/bin/python -m lab.benchmarks.foot_patches NAME [--sole N] [--steps 20] [--json FILE]

NAME: ``ankle_lowpass=TAU`` (the stance-ankle torque through a first-order low-pass of time constant TAU [s],
per control period), ``all_lowpass=TAU`` (all six torques), ``cop_clamp=M`` (the stance-ankle torque clipped to
[(l_min + M) F_z, (l_max - M) F_z] with F_z the last period's measured normal force: the CoP kept M [m]
inside the sole), ``ankle_armature=A`` (MJCF: armature A [kg m^2] on both ankle hinges, the controller
unchanged), ``reference_lead=D`` (after the controller's first decision of each new step, its tau advanced by
D [s]: the reference restarted D later than the sensed touchdown). ``--sole N``: ``mujoco_sole_points`` (default
0, the box).
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

from biped_sim.plant import mujoco as pm
from biped_sim.plant.config import load_sim_config
from biped_controller.core.control.config import load_controller_config
from biped_controller.studies import provenance as provenance_records
from biped_controller.closed_loop import runner
from lab.foot_quiet import measure, provenance


def patch(kind: str, value: float) -> None:
    if kind != "ankle_armature":
        # the patches act on the objects' calls (the controller's compute, the plant's step): the runs take
        # every period through them, not through the compiled closed loop
        from biped_controller.closed_loop import segment
        segment.MujocoSegment.eligible = staticmethod(lambda sim, ctrl: False)
    step = pm.MujocoPlant.step
    state: dict = {"g": None, "stance": None, "fz": None}
    if kind == "reference_lead":
        from biped_controller.core.control import controller as ctl
        from biped_controller.core.control.controller_layout import M_
        compute = ctl.AdaptiveController.compute

        def lead(self, t, q, qd, stance, *a, **k):
            before = self.stance
            out = compute(self, t, q, qd, stance, *a, **k)
            if before is not None and before != stance:
                self.memory[M_.tau] += value
            return out
        ctl.AdaptiveController.compute = lead
        return
    if kind == "ankle_armature":
        make = pm.make_mjcf
        pm.make_mjcf = lambda desc, c: re.sub(r'(<joint name="(left|right)_ankle" type="hinge")',
                                              rf'\1 armature="{value!r}"', make(desc, c))
        return

    def patched(self, torque):
        tq = np.array(torque, dtype=float)
        if kind in ("ankle_lowpass", "all_lowpass"):
            sl = slice(0, 1) if kind == "ankle_lowpass" else slice(0, 6)
            if state["stance"] == self.stance and state["g"] is not None:
                a = self.cfg.control_period / (value + self.cfg.control_period)
                tq[sl] = state["g"] + a * (tq[sl] - state["g"])
            state["g"], state["stance"] = tq[sl].copy(), self.stance
        elif kind == "cop_clamp":
            f = state["fz"]
            ft = self.desc.foot
            if f is not None and f > 0.0:
                tq[0] = min(max(tq[0], (ft.l_min + value) * f), (ft.l_max - value) * f)
        rec = step(self, tq)
        state["fz"] = float(rec.wrench[1]) if rec.stance == self.stance else None
        return rec
    pm.MujocoPlant.step = patched


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("name")
    ap.add_argument("--sole", type=int, default=0)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    run = provenance_records.Run(argv, plant="mujoco", profile="default",
                                 command=".venv/bin/python -m lab.benchmarks.foot_patches " + " ".join(argv))
    kind, _, v = a.name.partition("=")
    if kind not in ("ankle_lowpass", "all_lowpass", "cop_clamp", "ankle_armature", "reference_lead"):
        ap.error(f"unknown patch {kind!r}")
    patch(kind, float(v))
    scfg = load_sim_config(plant="mujoco", mujoco_sole_points=a.sole)
    r = runner.run(steps=a.steps, mode="both", sim_config=scfg,
                   ctrl_config=load_controller_config(mode="both", period=scfg.control_period))
    res = {"plant": "mujoco", "mode": "both", "steps": a.steps, "patch": a.name, "sole_points": a.sole, **measure(r)}
    o = res["overall"]
    print(f"{a.name} sole {a.sole}: {res['steps_walked']} steps{' fell ' + res['fall_cause'] if res['fallen'] else ''}; "
          f"unloaded {100 * o['unloaded']:.1f} %, edge {100 * o['edge']:.1f} %, |dF_z| p99 {o['dfz_p99']:.0f} N, "
          f"max pitch {o['max_pitch']:.4f} rad")
    if a.json is not None:
        prov = provenance(argv)
        prov["command"] = ".venv/bin/python -m lab.benchmarks.foot_patches " + " ".join(argv)
        a.json.write_text(json.dumps({"provenance": prov, **res}, indent=1) + "\n", encoding="utf-8")
        run.record(a.json)     # the directory's provenance.json (results/README.md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
